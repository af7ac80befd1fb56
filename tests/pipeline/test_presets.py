"""The shipped presets: the paper's method as published, featmap's 2D defaults, on a synthetic 2D log."""

from pathlib import Path

import numpy as np

from typer.testing import CliRunner

from featmap.cli import app
from featmap.datasets.carmen import CarmenSource
from featmap.evaluation.map_metric import truth_free_metrics
from featmap.fusion import fuse
from featmap.io.run_metrics import read_run_metrics
from featmap.io.segments_csv import read_fused_csv, read_segments_csv
from featmap.pipeline import SegmentStore, load_config
from featmap.pipeline.extract import extract_source
from tests.conftest import write_room_log

ROOT = Path(__file__).resolve().parents[2]


def test_paper_preset_is_the_published_method():
    cfg = load_config("paper")
    assert cfg == load_config(ROOT / "configs" / "paper.yaml")
    p = cfg.fusion.proposed
    assert (p.min_support, p.min_support_length_m, p.fit_weighting) == (4, None, "none")
    assert cfg.fusion.refine.max_offset_m == 0 and cfg.fusion.refine.split_gap_m == 0
    assert cfg.fusion.corners.mode == "midpoint"


def test_a_2d_log_runs_through_the_pipeline_with_the_2d_preset(tmp_path):
    """``featmap run --carmen`` on a synthetic log: the 2D extractor, the indoor preset, the truth-free
    metric in metrics.json, no WGS84 output; every method maps the room without a line across the door.
    Two scans (one of them the last) saw nothing (every beam at max range): they have no segments."""
    path = tmp_path / "room.log"
    write_room_log(path, np.random.default_rng(0))
    lines = path.read_text().splitlines()
    flaser = [k for k, line in enumerate(lines) if line.startswith("FLASER")]
    for k in (flaser[10], flaser[-1]):
        fields = lines[k].split()
        fields[2:182] = ["81.83"] * 180
        lines[k] = " ".join(fields)
    path.write_text("\n".join(lines) + "\n")
    res = CliRunner().invoke(app, ["run", "--carmen", str(path), "--out", str(tmp_path / "run"),
                                   "--cache-dir", str(tmp_path / "c"), "--workers", "1"])
    assert res.exit_code == 0, res.output
    assert "using the indoor_2d preset" in res.output
    out = tmp_path / "run"
    metrics = read_run_metrics(out / "metrics.json")
    assert metrics.source.kind == "carmen" and metrics.source.dimension == 2 and metrics.geo_frame is None
    assert metrics.primary == "map" and not list(out.glob("*.geojson")) and not (out / "map.kml").exists()
    assert load_config(out / "config.yaml") == load_config("indoor_2d")
    for method in ("proposed", "density", "meanshift"):
        m = metrics.primary_scores(method)
        assert m["precision"] > 0.99 and m["recall"] > 0.97 and m["redundancy"] < 0.02, (method, m)
        fused, _ = read_fused_csv(out / f"fused_{method}.csv")
        on_north = [s for s in fused if abs(s[1] - 8) < 0.05 and abs(s[3] - 8) < 0.05]
        assert on_north and all(max(s[0], s[2]) <= 5.55 or min(s[0], s[2]) >= 6.45 for s in on_north), method
    segments = read_segments_csv(out / "segments.csv")
    assert segments.extra.keys() == {"n_points", "rms", "sensor_x", "sensor_y"}
    assert {10, 59} - set(segments.scan.tolist()) == {10, 59} and len(set(segments.scan.tolist())) == 58


def test_the_paper_preset_keeps_mean_shifts_published_weakness(tmp_path):
    """As published, mean shift's 3 m centre bandwidth mixes surfaces (duplicates, lines off the walls);
    the shared refinement of the 2D preset is what repairs it."""
    path = tmp_path / "room.log"
    write_room_log(path, np.random.default_rng(0))
    source = CarmenSource(path)
    extraction = extract_source(source, load_config("indoor_2d").extraction, SegmentStore(None))
    table, points = extraction.world_table(), extraction.world_points()
    paper = fuse("meanshift", table.segments, table.scan, load_config("paper").fusion)
    m = truth_free_metrics(paper.segments, points, table.segments)
    assert m.redundancy > 0.1 and m.recall < 0.96


def test_a_slam_corrected_log_stays_where_its_poses_put_it(tmp_path):
    """The first scan logged 0.2 m / 1 deg off, the other 39 exact. In an odometry log (scan poses = ODOM)
    the indoor preset holds the first scan and moves the map after it; in a SLAM-corrected log (ODOM
    records elsewhere) it holds the map where the other scans put it and moves the first scan back."""
    from featmap.io.pose_csv import read_trajectory_xy

    phi = 2 * np.pi * np.arange(40) / 40
    true = np.column_stack([6.5 + 4.0 * np.cos(phi), 3.5 + 2.2 * np.sin(phi)])
    error = {}
    for slam in (False, True):
        path = write_room_log(tmp_path / f"room_{slam}.log", np.random.default_rng(0), n_scans=40, slam=slam,
                              first_pose_error=(0.2, -0.1, np.deg2rad(1.0)))
        out = tmp_path / f"run_{slam}"
        res = CliRunner().invoke(app, ["run", "--carmen", str(path), "--out", str(out), "--method", "proposed",
                                       "--cache-dir", str(tmp_path / "c"), "--workers", "1"])
        assert res.exit_code == 0, res.output
        metrics = read_run_metrics(out / "metrics.json")
        assert metrics.refinement.slam_poses is slam and metrics.refinement.applied
        error[slam] = np.hypot(*(read_trajectory_xy(out / "trajectory_refined.csv") - true).T)
    assert error[False][0] < 0.25 and error[False][1:].min() > 0.1       # the map followed the first scan
    assert error[True][0] < 0.03 and error[True][1:].max() < 0.02        # the first scan came back
