"""The fusion-only job (``featmap fuse``) end to end through the typer app."""

import numpy as np
from typer.testing import CliRunner

from featmap.cli import app
from featmap.pipeline.config import load_config
from featmap.io.segments_csv import SegmentTable, read_fused_csv, write_segments_csv
from featmap.simulation.segments import observe_walls
from featmap.pipeline.run_folder import MANIFEST

runner = CliRunner()


def _segments_csv(path):
    rng = np.random.default_rng(0)
    walls = np.array([[0, 0, 30, 0], [0, 15, 30, 15], [30, 0, 30, -20]], float)
    segs, scan = observe_walls(walls, 15, 0.03, rng, first_scan=np.zeros(3, int))
    write_segments_csv(path, SegmentTable(scan=scan, segments=segs))
    return path


def test_fuse_writes_fused_csv_and_config(tmp_path):
    seg = _segments_csv(tmp_path / "segments.csv")
    out = tmp_path / "out"
    res = runner.invoke(app, ["fuse", str(seg), "--method", "proposed", "--out", str(out),
                              "--set", "fusion.proposed.delta_deg=4"])
    assert res.exit_code == 0, res.output
    fused, support = read_fused_csv(out / "fused_proposed.csv")
    assert len(fused) == 3 and support.tolist() == [15, 15, 15]
    assert load_config(out / "config.yaml").fusion.proposed.delta_deg == 4
    assert "features out" in res.output


def test_fuse_keeps_a_lone_clean_view_by_the_rms_column_of_segments_csv(tmp_path):
    """A lone 2 m segment in scan 99 is dropped by the support rule unless segments.csv says it was fitted
    twice as tightly as the typical segment (the clean-view clause reads the ``rms`` column)."""
    rng = np.random.default_rng(0)
    walls = np.array([[0, 0, 30, 0], [0, 15, 30, 15], [30, 0, 30, -20]], float)
    segs, scan = observe_walls(walls, 15, 0.03, rng, first_scan=np.zeros(3, int))
    segs = np.vstack([segs, [[10.0, 7.0, 12.0, 7.0]]])
    scan = np.r_[scan, 99]
    counts = {}
    for name, lone_rms in [("clean", 0.004), ("rough", 0.02)]:
        path = write_segments_csv(tmp_path / f"{name}.csv", SegmentTable(
            scan=scan, segments=segs, extra={"rms": np.r_[np.full(len(segs) - 1, 0.01), lone_rms]}))
        res = runner.invoke(app, ["fuse", str(path), "--method", "proposed", "--out", str(tmp_path / name)])
        assert res.exit_code == 0, res.output
        counts[name] = len(read_fused_csv(tmp_path / name / "fused_proposed.csv")[0])
    assert counts == {"clean": 4, "rough": 3}
    # without the column the clause has nothing to compare, and the user is told
    bare = write_segments_csv(tmp_path / "bare.csv", SegmentTable(scan=scan, segments=segs))
    res = runner.invoke(app, ["fuse", str(bare), "--method", "proposed", "--out", str(tmp_path / "bare")])
    assert res.exit_code == 0 and "no rms column" in res.output
    assert len(read_fused_csv(tmp_path / "bare" / "fused_proposed.csv")[0]) == 3


def test_fuse_without_a_max_gap_column_names_the_settings_it_idles(tmp_path):
    """The default refinement's cut at unresolved gaps reads max_gap, and so does coarse_gap_m when set: a
    segments.csv without the column is fused, with a warning naming what does nothing."""
    seg = _segments_csv(tmp_path / "segments.csv")
    res = runner.invoke(app, ["fuse", str(seg), "--method", "proposed", "--out", str(tmp_path / "a"),
                              "--set", "fusion.proposed.coarse_gap_m=null"])
    assert res.exit_code == 0 and "resolved_gap_m cuts nothing" in res.output and "coarse_gap_m" not in res.output
    res = runner.invoke(app, ["fuse", str(seg), "--method", "proposed", "--out", str(tmp_path / "b"),
                              "--set", "fusion.proposed.coarse_gap_m=2.0", "--set", "fusion.refine.resolved_gap_m=0"])
    assert res.exit_code == 0 and "fusion.proposed.coarse_gap_m finds no coarse view" in res.output
    # without the length rule (the paper's count rule) the clause could not act anyway: nothing to warn of
    res = runner.invoke(app, ["fuse", str(seg), "--method", "proposed", "--out", str(tmp_path / "c"),
                              "--set", "fusion.proposed.coarse_gap_m=2.0", "--set", "fusion.refine.resolved_gap_m=0",
                              "--set", "fusion.proposed.min_support_length_m=null"])
    assert res.exit_code == 0 and "no max_gap column" not in res.output
    assert "resolved_gap_m" not in res.output


def test_fuse_reads_the_sensor_columns_for_the_visibility_clause_and_warns_without_them(tmp_path):
    """A wall seen through a gap by the only scans that could see it is kept with visible_share from a
    segments.csv that has the sensor_x / sensor_y columns; without them it is dropped and the user is told."""
    from tests.fusion.test_visibility import _gap_scene

    segs, scan, xy = _gap_scene()
    counts = {}
    for name, extra in (("with", {"sensor_x": xy[:, 0], "sensor_y": xy[:, 1]}), ("without", {})):
        path = write_segments_csv(tmp_path / f"{name}.csv", SegmentTable(scan=scan, segments=segs, extra=extra))
        res = runner.invoke(app, ["fuse", str(path), "--method", "proposed", "--out", str(tmp_path / name),
                                  "--set", "fusion.proposed.visible_share=0.5"])
        assert res.exit_code == 0, res.output
        assert ("no sensor_x / sensor_y columns" in res.output) == (name == "without")
        counts[name] = len(read_fused_csv(tmp_path / name / "fused_proposed.csv")[0])
    assert counts == {"with": 3, "without": 2}


def test_fuse_all_methods(tmp_path):
    seg = _segments_csv(tmp_path / "segments.csv")
    res = runner.invoke(app, ["fuse", str(seg), "--method", "all", "--out", str(tmp_path / "o")])
    assert res.exit_code == 0, res.output
    for m in ("proposed", "meanshift", "density"):
        assert (tmp_path / "o" / f"fused_{m}.csv").exists()


def test_bad_inputs_fail_in_one_line_and_write_nothing(tmp_path):
    seg = _segments_csv(tmp_path / "segments.csv")
    bad = tmp_path / "bad.csv"
    bad.write_text("scan,x1,y1,x2,y2\n0,1,2,3,4\n1,1,2,nan,4\n")
    cases = [
        (["fuse", str(bad), "--out", str(tmp_path / "o1")], "bad.csv:3: column 'x2'"),
        (["fuse", str(seg), "--out", str(tmp_path / "o2"), "--set", "fusion.proposed.gamma=2"], "fusion.proposed.gamma"),
        (["fuse", str(seg), "--out", str(tmp_path / "o3"), "--set", "fusion.proposed.eta_m=-0.1"], "fusion.proposed.eta_m"),
        (["fuse", str(seg), "--out", str(tmp_path / "o4"), "--set", "fusion.bogus.x=1"], "unknown key 'fusion.bogus.x'"),
        (["fuse", str(seg), "--out", str(tmp_path / "o5"), "--method", "kmeans"], "allowed: proposed, meanshift, density"),
        (["fuse", str(tmp_path / "none.csv"), "--out", str(tmp_path / "o6")], "none.csv: file not found"),
    ]
    for n, (args, needle) in enumerate(cases, start=1):
        res = runner.invoke(app, args)
        assert res.exit_code == 2, (args, res.output)
        lines = [line for line in res.output.splitlines() if line.strip()]
        assert len(lines) == 1 and needle in lines[0], res.output
        assert not (tmp_path / f"o{n}").exists()


def test_a_second_fusion_replaces_the_folder_whole_and_never_a_run_folder(tmp_path):
    seg = _segments_csv(tmp_path / "segments.csv")
    out = tmp_path / "o"
    assert runner.invoke(app, ["fuse", str(seg), "--method", "all", "--out", str(out)]).exit_code == 0
    res = runner.invoke(app, ["fuse", str(seg), "--method", "proposed", "--out", str(out),
                              "--set", "fusion.meanshift.center_bandwidth_m=50"])
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "config.yaml", "fuse.json", "fused_proposed.csv"]
    # a folder holding anything else (a run folder, say), or the input itself, is left alone
    run = tmp_path / "run"
    run.mkdir()
    (run / "metrics.json").write_text("{}")
    for target, needle in ((run, "not a featmap output folder"), (tmp_path, "an input of this run")):
        res = runner.invoke(app, ["fuse", str(seg), "--method", "proposed", "--out", str(target)])
        assert res.exit_code == 2 and needle in res.output, res.output
    assert (run / "metrics.json").read_text() == "{}" and seg.is_file()
