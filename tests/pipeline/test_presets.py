"""The shipped presets: the paper's method as published, featmap's 2D defaults, on a synthetic 2D log."""

from pathlib import Path

import numpy as np

from typer.testing import CliRunner

from featmap.cli import app
from featmap.datasets.carmen import CarmenSource
from featmap.evaluation.map_metric import truth_free_metrics
from featmap.fusion import fuse
from featmap.io.carmen import carmen_beam_angles
from featmap.io.run_metrics import read_run_metrics
from featmap.io.segments_csv import read_fused_csv, read_segments_csv
from featmap.pipeline import SegmentStore, load_config
from featmap.pipeline.extract import extract_source
from featmap.simulation.segments import cast_rays_2d

ROOT = Path(__file__).resolve().parents[2]


def test_paper_preset_is_the_published_method():
    cfg = load_config("paper")
    assert cfg == load_config(ROOT / "configs" / "paper.yaml")
    p = cfg.fusion.proposed
    assert (p.min_support, p.min_support_length_m, p.fit_weighting) == (4, None, "none")
    assert cfg.fusion.refine.max_offset_m == 0 and cfg.fusion.refine.split_gap_m == 0
    assert cfg.fusion.corners.mode == "midpoint"


# A 12 m x 8 m room: a 1 m doorway in the north wall, a 1 m x 1 m pillar in the middle.
ROOM = np.array([[0, 0, 12, 0], [12, 0, 12, 8], [12, 8, 6.5, 8], [5.5, 8, 0, 8], [0, 8, 0, 0],
                 [5.5, 8, 5.5, 9], [6.5, 8, 6.5, 9],
                 [6, 3, 7, 3], [7, 3, 7, 4], [7, 4, 6, 4], [6, 4, 6, 3]], float)


def _write_log(path, rng, n_scans=60):
    """A CARMEN log of a robot driving a loop around the pillar (1 cm range noise, exact poses)."""
    angles = carmen_beam_angles(180)
    lines = ["# synthetic", "PARAM robot_frontlaser_offset 0.0 nohost 0"]
    for k in range(n_scans):
        phi = 2 * np.pi * k / n_scans
        pose = np.array([6.5 + 4.0 * np.cos(phi), 3.5 + 2.2 * np.sin(phi), phi + np.pi / 2])
        r = cast_rays_2d(ROOM, pose, angles, max_range=81.83)
        r = np.where(r < 81.83, r + rng.normal(0, 0.01, len(r)), r)
        fields = " ".join(f"{v:.3f}" for v in r)
        p = " ".join(f"{v:.6f}" for v in pose)
        lines.append(f"FLASER 180 {fields} {p} {p} {k * 0.2:.3f} host {k * 0.2:.3f}")
        lines.append(f"ODOM {p} 0 0 0 {k * 0.2:.3f} host {k * 0.2:.3f}")
    path.write_text("\n".join(lines) + "\n")


def test_a_2d_log_runs_through_the_pipeline_with_the_2d_preset(tmp_path):
    """``featmap run --carmen`` on a synthetic log: the 2D extractor, the indoor preset, the truth-free
    metric in metrics.json, no WGS84 output; every method maps the room without a line across the door."""
    path = tmp_path / "room.log"
    _write_log(path, np.random.default_rng(0))
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
    assert read_segments_csv(out / "segments.csv").extra.keys() == {"n_points", "rms"}


def test_the_paper_preset_keeps_mean_shifts_published_weakness(tmp_path):
    """As published, mean shift's 3 m centre bandwidth mixes surfaces (duplicates, lines off the walls);
    the shared refinement of the 2D preset is what repairs it."""
    path = tmp_path / "room.log"
    _write_log(path, np.random.default_rng(0))
    source = CarmenSource(path)
    extraction = extract_source(source, load_config("indoor_2d").extraction, SegmentStore(None))
    table, points = extraction.world_table(), extraction.world_points()
    paper = fuse("meanshift", table.segments, table.scan, load_config("paper").fusion)
    m = truth_free_metrics(paper.segments, points, table.segments)
    assert m.redundancy > 0.1 and m.recall < 0.96
