import csv
import json

import pytest
from typer.testing import CliRunner

from featmap.cli import app
from featmap.datasets import KittiRawDataset
from featmap.errors import ConfigError
from featmap.pipeline import MappingPipeline, SegmentStore, load_config
from featmap.plotting.sweep_plots import pareto_front
from featmap.sweep import MAX_COMBINATIONS, expand, load_sweep, run_sweep_file

runner = CliRunner()


@pytest.fixture(scope="module")
def case1_run(case1_drive, tmp_path_factory):
    out = tmp_path_factory.mktemp("sweeprun")
    ds = KittiRawDataset(case1_drive.root, case1_drive.drive)
    MappingPipeline(load_config(None, ["output.plots=false"]), ["proposed"], SegmentStore(out / "c")).run(ds, out / "run")
    return out / "run"


def _write(tmp_path, text):
    path = tmp_path / "s.yaml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("grid,match", [
    ("  fusion.proposed.delta: [1, 2]", r"grid key 'fusion.proposed.delta' does not exist; did you mean 'fusion.proposed.delta_deg'"),
    ("  fusion.proposed.eta_m: {start: 2, stop: 1, num: 3}", r"stop 1.0 < start 2.0"),
    ("  fusion.proposed.gamma: ['high', 0.5]", r"'fusion.proposed.gamma' input should be a valid number"),
    ("  fusion.proposed.gamma: []", r"grid key 'fusion.proposed.gamma' has no values"),
    ("  extraction.ransac_planes.voxel_size_m: [0.1, 0.2]", r"never re-extracts"),
    ("  fusion.proposed.gamma: [0.5, 1.5]", r"'fusion.proposed.gamma' input should be less than or equal to 1"),
    ("  fusion.proposed.delta_deg: [5, 5.0, 3]", r"grid key 'fusion.proposed.delta_deg' lists the value 5.0 more than once"),
    ("  fusion.proposed: [1, 2]", r"grid key 'fusion.proposed' is a section; sweep its settings, e.g. 'fusion.proposed."),
    ("  fusion.density.lateral_eps_m: [0.2, 0.5]", r"grid key 'fusion.density.lateral_eps_m' applies to none of the methods swept \(proposed\)"),
])
def test_bad_sweeps_fail_before_anything_runs(tmp_path, case1_run, grid, match):
    path = _write(tmp_path, f"input: {case1_run / 'segments.csv'}\nmethods: [proposed]\ngrid:\n{grid}\n")
    with pytest.raises(ConfigError, match=match):
        run_sweep_file(path, tmp_path / "out")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("base, says", [("nosuch", "no such file, nor a preset \\(default, indoor_2d, paper\\)"),
                                        ("missing.yaml", "config file not found"),
                                        ("sub/missing", "config file not found")])
def test_a_missing_base_names_the_sweep_file(tmp_path, case1_run, base, says):
    path = _write(tmp_path, f"base: {base}\ninput: {case1_run / 'segments.csv'}\ngrid: {{fusion.proposed.gamma: [0.5]}}\n")
    with pytest.raises(ConfigError, match=rf"^{path}: base: {base}: {says}$"):
        run_sweep_file(path, tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_empty_grid_and_unknown_keys(tmp_path):
    with pytest.raises(ConfigError, match="the grid is empty"):
        load_sweep(_write(tmp_path, "input: x.csv\ngrid: {}\n"))
    with pytest.raises(ConfigError, match="methods: List should have at least 1 item"):
        load_sweep(_write(tmp_path, "input: x.csv\nmethods: []\ngrid: {fusion.proposed.gamma: [0.5]}\n"))
    with pytest.raises(ConfigError, match="unknown key 'gird'"):
        load_sweep(_write(tmp_path, "input: x.csv\ngird: {a: [1]}\ngrid: {fusion.proposed.gamma: [0.1]}\n"))


def test_expansion_per_method_and_random_samples(tmp_path):
    spec = load_sweep(_write(tmp_path, """
input: x.csv
methods: [proposed, meanshift]
grid:
  fusion.proposed.delta_deg: [2, 5]
  fusion.proposed.eta_m: {start: 0.2, stop: 1.0, step: 0.4}
  fusion.meanshift.center_bandwidth_m: [1, 3, 5]
"""))
    combos, configs = expand(spec, {})
    assert len([c for c in combos if c.method == "proposed"]) == 2 * 3
    assert len([c for c in combos if c.method == "meanshift"]) == 3
    assert configs[combos[0].key].fusion.proposed.eta_m == 0.2
    spec = spec.model_copy(update={"samples": 4})
    combos2, _ = expand(spec, {})
    assert len(combos2) == 4 and {c.key for c in combos2} <= {c.key for c in combos}


def test_sweep_runs_resumes_and_writes_best(tmp_path, case1_run):
    path = _write(tmp_path, f"""
input: {case1_run / 'segments.csv'}
methods: [proposed, density]
grid:
  fusion.proposed.delta_deg: [2, 5, 10]
  fusion.proposed.gamma: [0.0, 0.5]
  fusion.density.lateral_eps_m: [0.5, 20]
""")
    out = tmp_path / "out"
    res = runner.invoke(app, ["sweep", str(path), "--out", str(out), "--workers", "2"])
    assert res.exit_code == 0, res.output
    rows = list(csv.DictReader(open(out / "sweep.csv")))
    assert len(rows) == 3 * 2 + 2
    assert {"method", "fusion.proposed.delta_deg", "count", "precision", "recall", "quality", "seconds"} <= set(rows[0])
    # best.yaml holds the settings of the row with the highest quality, and they reproduce its score
    top = max(rows, key=lambda r: float(r["quality"]))
    best = load_config(out / "best.yaml")
    assert f"= {float(top['quality']):.4f} (method {top['method']})" in (out / "best.yaml").read_text()
    if top["method"] == "proposed":
        assert best.fusion.proposed.delta_deg == float(top["fusion.proposed.delta_deg"])
        assert best.fusion.proposed.gamma == float(top["fusion.proposed.gamma"])
    else:
        assert best.fusion.density.lateral_eps_m == float(top["fusion.density.lateral_eps_m"])
    for name in ("heatmap_delta_gamma.png", "curves.png", "pareto.png"):
        assert (out / name).stat().st_size > 5000
    # resume: drop three finished results; only those are evaluated again
    lines = (out / "results.jsonl").read_text().splitlines()
    (out / "results.jsonl").write_text("\n".join(lines[:-3]) + "\n" + lines[-3][:10])   # last line cut short
    rows2, _ = run_sweep_file(path, out)
    new_lines = (out / "results.jsonl").read_text().splitlines()
    assert len(new_lines) == len(lines)
    assert new_lines[:-3] == lines[:-3]                      # kept, not evaluated again
    assert all(json.loads(line)["key"] for line in new_lines[1:])
    assert len(rows2) == 8
    # the wide density bandwidth merges the building's parallel walls: worse precision than the narrow one
    dens = {float(r["fusion.density.lateral_eps_m"]): r for r in rows if r["method"] == "density"}
    assert float(dens[20.0]["count"]) <= float(dens[0.5]["count"])


def test_a_sweep_of_another_grid_into_the_same_folder_leaves_no_plot_of_the_first(tmp_path, case1_run):
    """The folder then holds this sweep's plots only (the first grid's heatmap and curves are removed, as is
    its best.yaml when this one has none); files featmap does not write stay. The log resumes across both."""
    from featmap.plotting.sweep_plots import PLOT_NAMES

    out = tmp_path / "out"
    first = _write(tmp_path, f"input: {case1_run / 'segments.csv'}\nmethods: [proposed]\n"
                             "grid:\n  fusion.proposed.delta_deg: [2, 5]\n  fusion.proposed.gamma: [0.0, 0.5]\n")
    run_sweep_file(first, out)
    assert {p.name for p in out.iterdir()} >= set(PLOT_NAMES) | {"best.yaml"}
    (out / "notes.txt").write_text("mine")
    (out / "heatmap_mine.png").write_bytes(b"x")
    # one combination (no curve, no heatmap), selected by a metric a ground truth does not give (the
    # truth-free compression): no best either
    second = tmp_path / "second.yaml"
    second.write_text(f"input: {case1_run / 'segments.csv'}\nmethods: [proposed]\n"
                      "grid:\n  fusion.proposed.delta_deg: [5]\nselect: {metric: compression}\n")
    rows, best = run_sweep_file(second, out)
    assert len(rows) == 1 and best is None
    assert sorted(p.name for p in out.iterdir()) == ["heatmap_mine.png", "notes.txt", "pareto.png", "results.jsonl",
                                                     "sweep.csv"]
    assert (out / "notes.txt").read_text() == "mine" and (out / "heatmap_mine.png").read_bytes() == b"x"
    assert len(list(csv.DictReader(open(out / "sweep.csv")))) == 1
    log = (out / "results.jsonl").read_text().splitlines()
    assert len(log) == 1 + 4 + 1 and "sweep" in json.loads(log[0])     # one header, both grids' rows


def test_a_sweep_interrupted_while_it_writes_its_table_and_plots_leaves_the_earlier_set(tmp_path, case1_run, monkeypatch):
    """Ctrl-C after the table and best.yaml of a second grid were written, while its plots are drawn: the
    folder keeps the first sweep's table, best.yaml and plots, byte for byte, and no staging folder."""
    import featmap.plotting.sweep_plots as sweep_plots

    out = tmp_path / "out"
    first = _write(tmp_path, f"input: {case1_run / 'segments.csv'}\nmethods: [proposed]\n"
                             "grid:\n  fusion.proposed.delta_deg: [2, 5]\n  fusion.proposed.gamma: [0.0, 0.5]\n")
    run_sweep_file(first, out)
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.name != "results.jsonl"}
    assert {"sweep.csv", "best.yaml", "pareto.png"} <= set(before)

    def interrupted(rows, keys, stage, metric):
        (stage / "curves.png").write_bytes(b"half-drawn")
        raise KeyboardInterrupt

    monkeypatch.setattr(sweep_plots, "draw_sweep_plots", interrupted)
    second = tmp_path / "second.yaml"
    second.write_text(f"input: {case1_run / 'segments.csv'}\nmethods: [proposed]\n"
                      "grid:\n  fusion.proposed.delta_deg: [3]\n")
    with pytest.raises(KeyboardInterrupt):
        run_sweep_file(second, out)
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.name != "results.jsonl"} == before


def test_pareto_front():
    import numpy as np

    pts = np.array([[1.0, 0.9], [1.2, 0.95], [1.1, 0.8], [0.9, 0.5], [1.5, 0.94]])
    assert sorted(pareto_front(pts).tolist()) == [0, 1, 3]


def test_a_sweep_of_other_inputs_into_the_same_folder_is_refused(tmp_path, case1_run):
    path = _write(tmp_path, f"input: {case1_run / 'segments.csv'}\nmethods: [proposed]\n"
                            "grid:\n  fusion.proposed.delta_deg: [2, 5]\n")
    out = tmp_path / "out"
    run_sweep_file(path, out)
    before = (out / "results.jsonl").read_text()
    other = tmp_path / "other.csv"
    lines = (case1_run / "segments.csv").read_text().splitlines()
    other.write_text("\n".join(lines[:-5]) + "\n")                 # another input
    path2 = _write(tmp_path, f"input: {other}\nmethods: [proposed]\ngrid:\n  fusion.proposed.delta_deg: [2, 5]\n")
    with pytest.raises(ConfigError, match="holds the results of another sweep"):
        run_sweep_file(path2, out)
    with pytest.raises(ConfigError, match="holds the results of another sweep"):   # another base config
        run_sweep_file(path, out, overrides=["fusion.proposed.eta_m=0.7"])
    assert (out / "results.jsonl").read_text() == before


def test_a_huge_grid_is_refused_before_expanding_or_sampled(tmp_path):
    grid = "".join(f"  fusion.proposed.{k}: {{start: 0, stop: 1, num: 1000}}\n" for k in ("gamma", "eta_m"))
    grid += "  fusion.proposed.delta_deg: {start: 0, stop: 90, num: 1000}\n"
    spec = load_sweep(_write(tmp_path, f"input: x.csv\nmethods: [proposed]\ngrid:\n{grid}"))
    with pytest.raises(ConfigError, match=r"1,000,000,000 combinations .* use 'samples: N'"):
        expand(spec, {})
    combos, _ = expand(spec.model_copy(update={"samples": 50}), {})
    assert len(combos) == 50 and len({c.key for c in combos}) == 50
    assert MAX_COMBINATIONS < 1e9


def test_a_sweep_of_a_2d_log_scores_the_maps_a_run_makes(tmp_path):
    """A source without ground truth is scored with the truth-free metric, on the poses a run would use;
    the shared ``fusion.refine.*`` keys vary every method; a row equals ``featmap run`` with its settings
    (without a ``base:``, the sweep starts from the preset a run of that format uses: indoor_2d)."""
    import numpy as np

    from featmap.io.run_metrics import read_run_metrics
    from tests.conftest import write_room_log

    log = write_room_log(tmp_path / "room.log", np.random.default_rng(0))
    path = _write(tmp_path, f"""
dataset: carmen
location: {log}
methods: [proposed, density]
grid:
  fusion.proposed.eta_m: [0.2, 0.5]
  fusion.refine.split_gap_m: [0.0, 0.3]
""")
    out = tmp_path / "out"
    res = runner.invoke(app, ["sweep", str(path), "--out", str(out), "--workers", "1", "--cache-dir", str(tmp_path / "c")])
    assert res.exit_code == 0, res.output
    assert "base config: indoor_2d" in res.output
    rows = list(csv.DictReader(open(out / "sweep.csv")))
    assert len(rows) == 2 * 2 + 2                       # density varies with the shared key too
    assert {"precision", "recall", "redundancy", "compression", "f1", "quality"} <= set(rows[0])
    assert "count_ratio" not in rows[0]
    for r in rows:
        p, rc, red = float(r["precision"]), float(r["recall"]), float(r["redundancy"])
        assert float(r["quality"]) == pytest.approx(2 * p * rc / (p + rc) / (1 + red))
    # the doorway of the north wall: spanned without the gap split, cut with it (one more feature)
    by = {(r["method"], r.get("fusion.proposed.eta_m"), r["fusion.refine.split_gap_m"]): r for r in rows}
    assert int(by[("density", "", "0.3")]["count"]) > int(by[("density", "", "0.0")]["count"])
    assert (out / "best.yaml").exists() and (out / "pareto.png").stat().st_size > 5000
    # the same settings through featmap run give the same map and the same scores
    run = runner.invoke(app, ["run", "--carmen", str(log), "--out", str(tmp_path / "run"), "--workers", "1",
                              "--cache-dir", str(tmp_path / "c"), "--set", "fusion.proposed.eta_m=0.5",
                              "--set", "fusion.refine.split_gap_m=0.0", "--method", "proposed,density"])
    assert run.exit_code == 0, run.output
    metrics = read_run_metrics(tmp_path / "run" / "metrics.json")
    for method, row in (("proposed", by[("proposed", "0.5", "0.0")]), ("density", by[("density", "", "0.0")])):
        scores = metrics.primary_scores(method)
        assert int(row["count"]) == metrics.methods[method].count
        for key in ("precision", "recall", "redundancy", "compression"):
            assert float(row[key]) == pytest.approx(scores[key], rel=1e-9), (method, key)
    # a run's segments.csv carries no scan points: counts only, and the sweep says so
    path2 = _write(tmp_path, f"input: {tmp_path / 'run' / 'segments.csv'}\nmethods: [proposed]\n"
                             "grid:\n  fusion.proposed.eta_m: [0.2, 0.5]\n")
    res = runner.invoke(app, ["sweep", str(path2), "--out", str(tmp_path / "out2"), "--workers", "1"])
    assert res.exit_code == 0, res.output
    assert "nothing to score against" in " ".join(res.output.split())
    assert "precision" not in (tmp_path / "out2" / "sweep.csv").read_text().splitlines()[0]
    # ... re-fused as that run fused them (its config.yaml), so a row at the run's settings gives its count
    assert f"base config: {tmp_path / 'run' / 'config.yaml'}" in " ".join(res.output.split())
    counts = {r["fusion.proposed.eta_m"]: int(r["count"]) for r in csv.DictReader(open(tmp_path / "out2" / "sweep.csv"))}
    assert counts["0.5"] == metrics.methods["proposed"].count
    # a preset name is a base too, like everywhere else --config is taken
    path3 = tmp_path / "paper.yaml"
    path3.write_text(f"dataset: carmen\nlocation: {log}\nmethods: [proposed]\ngrid:\n  fusion.proposed.eta_m: [0.2, 0.5]\n")
    res = runner.invoke(app, ["sweep", str(path3), "--out", str(tmp_path / "out3"), "--workers", "1", "--config", "paper",
                              "--cache-dir", str(tmp_path / "c")])
    assert res.exit_code == 0, res.output
    assert "base config" not in res.output and "mode: midpoint" in (tmp_path / "out3" / "best.yaml").read_text()


def test_an_edited_truth_never_serves_the_old_rows(tmp_path, case1_run):
    import shutil

    from featmap.io.run_metrics import read_run_metrics

    truth_dir = read_run_metrics(case1_run / "metrics.json").reference_path("truth", case1_run)
    truth = shutil.copytree(truth_dir, tmp_path / "truth")
    path = _write(tmp_path, f"input: {case1_run / 'segments.csv'}\ntruth: {truth}\nmethods: [proposed]\n"
                            "grid:\n  fusion.proposed.delta_deg: [2, 5]\n")
    out = tmp_path / "out"
    run_sweep_file(path, out)
    run_sweep_file(path, out)                                              # unchanged: resumes
    walls = (truth / "walls.csv").read_text().splitlines()
    last = walls[-1].split(",")
    last[3] = str(float(last[3]) + 1.0)                                    # one wall moved, same path
    (truth / "walls.csv").write_text("\n".join(walls[:-1] + [",".join(last)]) + "\n")
    with pytest.raises(ConfigError, match="holds the results of another sweep"):
        run_sweep_file(path, out)
