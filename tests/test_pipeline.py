"""MappingPipeline and ``featmap run`` on a small simulated drive."""

import csv
import json

import numpy as np
import pytest
from typer.testing import CliRunner

from featmap.cli import app
from featmap.config import load_config
from featmap.datasets import KittiRawDataset
from featmap.errors import DatasetError
from featmap.pipeline import MappingPipeline

runner = CliRunner()


def _run(case1_drive, tmp_path, overrides=(), **kwargs):
    ds = KittiRawDataset(case1_drive.root, case1_drive.drive, skip_bad_scans=kwargs.pop("skip", False))
    cfg = load_config(None, ["output.plots=false", *overrides])   # no basemap fetches in these tests
    pipe = MappingPipeline(ds, cfg, tmp_path / "run", ["proposed", "density"], cache_dir=tmp_path / "cache",
                           skip_bad_scans=ds.skip_bad_scans, **kwargs)
    return pipe, pipe.run()


def test_run_writes_the_output_contract_and_scores_against_truth(case1_drive, tmp_path):
    pipe, metrics = _run(case1_drive, tmp_path)
    out = tmp_path / "run"
    header = next(csv.reader(open(out / "segments.csv")))
    assert header[:5] == ["scan", "x1", "y1", "x2", "y2"] and "n_points" in header and "rms" in header
    for m in ("proposed", "density"):
        assert next(csv.reader(open(out / f"fused_{m}.csv")))[:5] == ["x1", "y1", "x2", "y2", "support"]
        fc = json.loads((out / f"fused_{m}.geojson").read_text())
        assert fc["type"] == "FeatureCollection"
        props = fc["features"][0]["properties"]
        assert {"method", "support", "length_m", "scans"} <= set(props)
        assert 1 <= props["scans"] <= props["support"]
        lon, lat = fc["features"][0]["geometry"]["coordinates"][0]
        assert 8.3 < lon < 8.5 and 48.9 < lat < 49.1
    assert load_config(out / "config.yaml") == pipe.config
    saved = json.loads((out / "metrics.json").read_text())
    assert saved["scans_processed"] == 40 and saved["segments"] > 40
    assert set(saved["timings_s"]) >= {"extraction", "fusion_proposed", "total"}
    proposed = saved["methods"]["proposed"]
    # 32 m of driving along the south wall a-b of the one building: that wall, once, on the truth
    assert proposed["observable_walls"] >= 1
    assert proposed["precision"] > 0.95 and proposed["recall"] > 0.9
    assert proposed["offset_cm"] < 5
    assert proposed["count"] <= proposed["observable_walls"] + 1


def test_refusing_never_reextracts_and_an_interrupted_run_resumes(case1_drive, tmp_path):
    pipe, first = _run(case1_drive, tmp_path)
    assert first["scans_extracted_now"] == 40 and first["scans_from_cache"] == 0
    _, second = _run(case1_drive, tmp_path, ["fusion.proposed.delta_deg=3", "fusion.proposed.eta_m=0.3"])
    assert second["scans_extracted_now"] == 0 and second["scans_from_cache"] == 40
    # an interrupted extraction leaves some scans uncached: only those are extracted again
    for frame in (3, 17, 30):
        (pipe.cache / f"{frame:010d}.npy").unlink()
    _, third = _run(case1_drive, tmp_path)
    assert third["scans_extracted_now"] == 3
    assert third["segments"] == first["segments"]
    # a different extraction config is a different cache
    _, fourth = _run(case1_drive, tmp_path, ["extraction.max_gap_m=2.0"])
    assert fourth["scans_extracted_now"] == 40


def test_parallel_workers_give_the_same_segments(case1_drive, tmp_path):
    _, one = _run(case1_drive, tmp_path / "a", workers=1)
    _, two = _run(case1_drive, tmp_path / "b", workers=2)
    a = np.loadtxt(tmp_path / "a" / "run" / "segments.csv", delimiter=",", skiprows=1)
    b = np.loadtxt(tmp_path / "b" / "run" / "segments.csv", delimiter=",", skiprows=1)
    assert np.array_equal(a, b)


def test_bad_scan_fails_or_is_skipped_and_reported(drive_copy, tmp_path):
    root, drive = drive_copy
    scan = root / drive[:10] / f"{drive}_sync" / "velodyne_points" / "data" / "0000000005.bin"
    pts = np.fromfile(scan, dtype=np.float32).reshape(-1, 4)
    pts[0, 0] = np.nan
    pts.tofile(scan)
    ds = KittiRawDataset(root, drive)
    cfg = load_config(None, ["output.plots=false"])
    with pytest.raises(DatasetError, match="0000000005.bin: 1 point.*NaN.*--skip-bad-scans"):
        MappingPipeline(ds, cfg, tmp_path / "out", ["proposed"], cache_dir=tmp_path / "c").run()
    assert not (tmp_path / "out").exists()                      # nothing written when the run fails
    ds = KittiRawDataset(root, drive, skip_bad_scans=True)
    metrics = MappingPipeline(ds, cfg, tmp_path / "out", ["proposed"], cache_dir=tmp_path / "c",
                              skip_bad_scans=True).run()
    assert list(metrics["scans_skipped"]) == ["5"] and metrics["scans_processed"] == 39


def test_cli_run_on_a_given_drive_and_missing_drive(case1_drive, tmp_path):
    res = runner.invoke(app, ["run", "--drive", case1_drive.drive, "--data-dir", str(case1_drive.root),
                              "--frames", "0:40:2", "--method", "proposed", "--out", str(tmp_path / "r"),
                              "--workers", "1", "--cache-dir", str(tmp_path / "c"), "--set", "output.plots=false"])
    assert res.exit_code == 0, res.output
    assert json.loads((tmp_path / "r" / "metrics.json").read_text())["scans_processed"] == 20
    assert "proposed" in res.output and "precision" in res.output
    res = runner.invoke(app, ["run", "--drive", "2011_09_30_drive_0018", "--data-dir", str(tmp_path / "nokitti"),
                              "--out", str(tmp_path / "r2")])
    assert res.exit_code == 2
    assert "featmap download" in res.output and len(res.output.strip().splitlines()) == 1
    assert not (tmp_path / "r2").exists()


def test_cli_evaluate_against_footprints(case1_drive, tmp_path):
    _run(case1_drive, tmp_path)
    truth = case1_drive.drive_dir / "truth" / "footprints.geojson"
    res = runner.invoke(app, ["evaluate", str(tmp_path / "run" / "fused_proposed.csv"), "--truth", str(truth),
                              "--out", str(tmp_path / "m.json")])
    assert res.exit_code == 0, res.output
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["precision"] > 0.95 and m["observable_walls"] == 4    # footprints: every wall counts
    res = runner.invoke(app, ["evaluate", str(tmp_path / "run" / "fused_proposed.geojson"), "--truth", str(truth)])
    assert res.exit_code == 0 and "precision" in res.output
