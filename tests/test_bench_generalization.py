"""benchmarks/bench_generalization.py: held-out worlds are not looked into, and the loss report adds up."""

import numpy as np
import pytest
from rich.console import Console

from featmap.evaluation.observation_metrics import UncoveredStretches
from featmap.simulation.splits import HELDOUT_SPLITS
from tests.repo_scripts import repo_script


@pytest.fixture(scope="module")
def bench():
    with repo_script("benchmarks/bench_generalization.py") as module:
        yield module


@pytest.mark.parametrize("split", list(HELDOUT_SPLITS))
def test_losses_and_variants_are_refused_on_held_out_worlds(bench, tmp_path, capsys, split):
    # refused before anything is simulated or extracted
    assert bench.main(["--split", split, "--losses", "5", "--sim-root", str(tmp_path)]) == 2
    out = capsys.readouterr().out
    assert out.count("\n") == 1 and "--losses" in out and "held-out" in out
    assert bench.main(["--split", split, "--variant", "fusion.proposed.gamma=0.3", "--sim-root", str(tmp_path)]) == 2
    out = capsys.readouterr().out
    assert out.count("\n") == 1 and "--variant" in out and "held-out" in out
    assert not any(tmp_path.iterdir())


def test_held_out_seeds_are_refused_as_tuning_worlds(bench, tmp_path, capsys):
    assert bench.main(["--seeds", "11", "7115", "--sim-root", str(tmp_path)]) == 2
    out = capsys.readouterr().out
    assert out.count("\n") == 1 and "[7115]" in out and "--split heldout2" in out
    assert bench.main(["--split", "heldout2", "--seeds", "7101", "--sim-root", str(tmp_path)]) == 2
    assert "not in the heldout2 split" in capsys.readouterr().out
    assert not any(tmp_path.iterdir())


def test_losses_count_must_not_be_negative(bench, tmp_path, capsys):
    assert bench.main(["--losses", "-1", "--sim-root", str(tmp_path)]) == 2
    assert "--losses -1" in capsys.readouterr().out and not any(tmp_path.iterdir())


def _stretches(lengths, views, nearest, best):
    n = len(lengths)
    return UncoveredStretches(wall=np.arange(n), start=np.zeros(n), end=np.array(lengths, float),
                              n_views=np.array(views), nearest_m=np.array(nearest, float),
                              nearest_incidence_deg=np.array(best, float), best_incidence_deg=np.array(best, float),
                              max_hits=np.full(n, 100), observed_m=500.0)


def test_loss_report_adds_the_kinds_up(bench):
    a = _stretches([4.0, 1.0], [5, 1], [30.0, 20.0], [86.0, 10.0])     # grazing 4 m, few views 1 m
    b = _stretches([2.5, 0.5], [9, 9], [95.0, 40.0], [5.0, 30.0])      # far 2.5 m, other 0.5 m
    loss = lambda filtered, fit, gained, wall, other: {  # noqa: E731
        "fusion_loss": {"observed_m": 500.0, "segments_m": 490.0, "fused_m": 490.0 - filtered - fit + gained,
                        "filtered_m": filtered, "fit_m": fit, "gained_m": gained, "dropped_wall_m": wall,
                        "dropped_other_m": other}}
    fusion = {1: loss(3.0, 1.0, 0.5, 10.0, 40.0), 2: loss(1.5, 0.0, 0.0, 2.0, 8.0)}
    results = [bench.WorldResult(seed, "sensor", 1, 1, 1, (0, 0), (0, 0), 1.0, 1.0, 0.99, 1, [], [],
                                 {"proposed": fusion[seed]}, lost)
               for seed, lost in ((1, a), (2, b))]
    console = Console(record=True, width=250)
    bench.print_losses(results, 3, ["proposed"], console)
    text = console.export_text()
    rows = {line.split("│")[1].strip(): [c.strip() for c in line.split("│")[2:-1]]
            for line in text.splitlines() if line.startswith("│")}
    assert rows["grazing"][:4] == ["1", "4.0", "0.50", "0.0040"]
    assert rows["far"][:4] == ["1", "2.5", "0.31", "0.0025"]
    assert rows["few views"][:4] == ["1", "1.0", "0.12", "0.0010"]
    assert rows["other"][:4] == ["1", "0.5", "0.06", "0.0005"]
    assert rows["all"][:4] == ["4", "8.0", "1.00", "0.0080"]
    # the fused map's loss against the segments' coverage, pooled: 5.0 m = 4.5 filtered + 1.0 fit - 0.5 gained
    assert rows["proposed"] == ["5.0 (0.0050)", "4.5", "1.0", "0.5", "1 (3.0), 2 (1.5)", "12", "48"]
    # the longest three, longest first (seed, length, kind)
    longest = [(cells[0].strip(), cells[4].strip(), cells[10].strip()) for cells in
               (line.split("│")[1:-1] for line in text.splitlines() if line.startswith("│"))
               if cells[0].strip() in ("1", "2")]
    assert longest == [("1", "4.0", "grazing"), ("2", "2.5", "far"), ("1", "1.0", "few views")]


def test_clutter_report_pools_the_worlds(bench):
    kinds = bench.CLUTTER_KINDS               # hedge, fence, car, pole, tree, beside a wall, nothing near
    clutter = lambda on, metres: {"segments_on": on, "metres": metres}  # noqa: E731
    worlds = {1: (200, clutter([3, 0, 1, 0, 2, 0, 0], [9.0, 0, 2.0, 0, 4.0, 1.0, 0]),
                  clutter([1, 0, 0, 0, 0, 0, 0], [2.5, 0, 0, 0, 0, 0.5, 0])),
              2: (100, clutter([0, 0, 5, 0, 1, 0, 1], [0, 0, 12.0, 0, 1.5, 0, 3.0]),
                  clutter([0, 0, 1, 0, 0, 0, 0], [0, 0, 3.0, 0, 0, 0, 0]))}
    results = [bench.WorldResult(seed, "sensor", scans, 1, 1, (0, 0), (0, 0), 1.0, 1.0, 0.99, 1, [], [],
                                 {"proposed": {"clutter": fused}}, None, per_scan)
               for seed, (scans, per_scan, fused) in worlds.items()]
    console = Console(record=True, width=250)
    console.print(bench.clutter_table(results, ["proposed"]))
    rows = {line.split("│")[1].strip(): [c.strip() for c in line.split("│")[2:-1]]
            for line in console.export_text().splitlines() if line.startswith("│")}
    assert set(rows) == set(kinds)
    # per-scan segments, per 100 of the 300 scans, per-scan metres, proposed features and metres, worlds
    assert rows["hedge"] == ["3", "1.0", "9", "1", "2.5", "1 (3)"]
    assert rows["car"] == ["6", "2.0", "14", "1", "3.0", "2 (5), 1 (1)"]
    assert rows["tree"] == ["3", "1.0", "6", "0", "0.0", "1 (2), 2 (1)"]
    assert rows["beside a wall"] == ["0", "0.0", "1", "0", "0.5", ""]
    assert rows["nothing near"] == ["1", "0.3", "3", "0", "0.0", "2 (1)"]


def test_variants_are_refused_on_held_out_worlds_with_docs_and_bad_keys(bench, tmp_path, capsys):
    # each refused in one line before anything is simulated or extracted
    for argv, words in ((["--split", "heldout", "--variant", "extraction.vertical_structure.tall_m=2"], ("--variant", "held-out")),
                        (["--variant", "extraction.vertical_structure.tall_m=2", "--docs"], ("--variant", "--docs")),
                        (["--variant", "extraction.vertical_structure.no_such_key=2"], ("no_such_key",)),
                        (["--variant", " "], ("--variant", "KEY=VALUE"))):
        assert bench.main([*argv, "--sim-root", str(tmp_path)]) == 2, argv
        out = capsys.readouterr().out
        assert out.count("\n") == 1 and all(w in out for w in words), (argv, out)
        assert not any(tmp_path.iterdir())


def _world(bench, seed, coverage, precision, recall, found=90, n_obs=100):
    methods = {"proposed": {"precision": precision, "recall": recall, "redundancy": 1.0}}
    return bench.WorldResult(seed, "sensor", 10, n_obs, found, (0, 0), (0, 0), 1.0, 1.0, coverage, 5, [], [], methods)


def test_variant_tables_compare_each_setting_with_the_configuration_without_it(bench):
    baseline = [_world(bench, 1, 0.990, 0.995, 0.986), _world(bench, 2, 0.980, 0.975, 0.978)]
    variant = [_world(bench, 1, 0.991, 0.995, 0.987, found=95), _world(bench, 2, 0.987, 0.969, 0.985, found=97)]
    console = Console(record=True, width=250)
    for table in bench.variant_tables(baseline, [("a.b=1", variant)], ["proposed"]):
        console.print(table)
    rows = [[c.strip() for c in line.split("│")[1:-1]] for line in console.export_text().splitlines()
            if line.startswith("│")]
    assert rows[0] == ["as configured", "proposed", "0.900", "0.985 / 0.980 (2)", "0.985 / 0.975 (2)",
                       "0.982 / 0.978 (2)", "1.000 / 1.000 (1)"]
    assert rows[1] == ["a.b=1", "proposed", "0.960", "0.989 / 0.987 (2)", "0.982 / 0.969 (2)",
                       "0.986 / 0.985 (2)", "1.000 / 1.000 (1)"]
    # world 1 moved by less than 0.002 everywhere: only world 2 is listed
    assert rows[2:] == [["a.b=1", "2", "proposed", "0.975 -> 0.969", "0.978 -> 0.985", "0.980 -> 0.987"]]


def test_porous_foliage_is_checked_and_its_drives_are_cached_apart(bench, tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        bench.main(["--foliage", "1,0.3,0.1,0.2", "--sim-root", str(tmp_path)])     # a porosity of 1: nothing stops
    assert exit_.value.code == 2 and "--foliage" in capsys.readouterr().err
    assert bench.main(["--foliage", "0.3,0.3,0.15,0.2", "--docs", "--losses", "3", "--sim-root", str(tmp_path)]) == 2
    assert "--losses with --foliage and --docs" in capsys.readouterr().out
    assert not any(tmp_path.iterdir())
    foliage = (0.3, 0.3, 0.15, 0.2)
    plain, porous = bench.drive_root(tmp_path, "tuning", 11), bench.drive_root(tmp_path, "tuning", 11, foliage)
    assert plain.name == porous.name and plain.parent != porous.parent
    assert bench._fingerprint(11) != bench._fingerprint(11, foliage)
    trees = [o for o in bench._generated(11, foliage).world.objects if o.kind == "tree"]
    assert trees and all(t.crown_porosity == 0.3 and t.crown_depth_m == 0.3 for t in trees)
    drawn = bench.drive_root(tmp_path, "tuning", 11, "drawn")
    assert drawn.parent.name == "tuning_foliage_drawn" and drawn.parent != porous.parent
    assert bench._fingerprint(11, "drawn") not in (bench._fingerprint(11), bench._fingerprint(11, foliage))
    trees = [o for o in bench._generated(11, "drawn").world.objects if o.kind == "tree"]
    assert len(trees) > 1 and len({t.crown_porosity for t in trees}) > len(trees) // 2   # each its own


def test_drop_drives_keeps_at_most_workers_drives_on_disk(bench, tmp_path, monkeypatch, capsys):
    # simulation and scoring faked: each batch's drives exist while scored (with the variant too) and are gone after
    on_disk_while_scored = []

    def fake_simulate(args, seeds, workers, missing, console):
        for seed in seeds:
            bench.drive_root(args.sim_root, args.split, seed, args.foliage).mkdir(parents=True)
        return 0.0

    def fake_score(args, seeds, config, methods, store, workers, losses=False):
        on_disk_while_scored.append((tuple(seeds), sorted(p.name for p in (args.sim_root / args.split).iterdir())))
        metrics = {"count": 1, "observable_walls": 1, "precision": 1.0, "recall": 1.0, "redundancy": 1.0,
                   "offset_cm": 0.0, "corner_err_cm": 0.0, "fusion_seconds": 0.0}
        return ([bench.WorldResult(seed, "sensor", 1, 1, 1, (0, 0), (0, 0), 1.0, 1.0, 1.0, 1, [1.0], [10],
                                   {name: metrics for name in methods}) for seed in seeds], 1.0, 0, len(seeds))

    monkeypatch.setattr(bench, "simulate_worlds", fake_simulate)
    monkeypatch.setattr(bench, "score_split", fake_score)
    argv = ["--seeds", "1", "2", "3", "--workers", "2", "--methods", "proposed", "--sim-root", str(tmp_path),
            "--cache-dir", str(tmp_path / "cache"), "--variant", "fusion.proposed.gamma=0.3", "--drop-drives"]
    assert bench.main(argv) == 0
    assert on_disk_while_scored == [((1, 2), ["procedural_1", "procedural_2"])] * 2 + [((3,), ["procedural_3"])] * 2
    assert not any((tmp_path / "tuning").iterdir())
    out = capsys.readouterr().out           # each variant's run of each batch is announced before it starts
    assert "variant fusion.proposed.gamma=0.3 (worlds 1, 2):" in out
    assert "variant fusion.proposed.gamma=0.3 (worlds 3):" in out
    # without the flag every drive is simulated first and kept
    on_disk_while_scored.clear()
    assert bench.main(argv[:-1]) == 0
    assert on_disk_while_scored[0] == ((1, 2, 3), ["procedural_1", "procedural_2", "procedural_3"])
    assert len(list((tmp_path / "tuning").iterdir())) == 3
    assert "variant fusion.proposed.gamma=0.3:" in capsys.readouterr().out
