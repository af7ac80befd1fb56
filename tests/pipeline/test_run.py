"""MappingPipeline and ``featmap run`` on a small simulated drive."""

import csv
import json
import shutil

import numpy as np
import pytest
from typer.testing import CliRunner

from featmap.cli import app
from featmap.datasets import KittiRawDataset
from featmap.errors import DatasetError
from featmap.io.run_metrics import read_run_metrics, write_run_metrics
from featmap.io.sim_truth import read_walls_csv
from featmap.pipeline import MappingPipeline, SegmentStore, load_config
from featmap.reporting import RecordingReporter
from featmap.pipeline.run_folder import MANIFEST

runner = CliRunner()


def test_run_writes_the_output_contract_and_scores_against_truth(run_case1, tmp_path):
    result = run_case1()
    out = tmp_path / "run"
    header = next(csv.reader(open(out / "segments.csv")))
    assert header == ["scan", "x1", "y1", "x2", "y2", "n_points", "z_min", "z_max", "rms", "max_gap", "sensor_x", "sensor_y"]
    for m in ("proposed", "density"):
        assert next(csv.reader(open(out / f"fused_{m}.csv")))[:5] == ["x1", "y1", "x2", "y2", "support"]
        fc = json.loads((out / f"fused_{m}.geojson").read_text())
        assert fc["type"] == "FeatureCollection"
        props = fc["features"][0]["properties"]
        assert {"method", "support", "length_m", "scans"} <= set(props)
        assert 1 <= props["scans"] <= props["support"]
        lon, lat = fc["features"][0]["geometry"]["coordinates"][0]
        assert 8.3 < lon < 8.5 and 48.9 < lat < 49.1
    assert load_config(out / "config.yaml").fusion == load_config(None).fusion
    saved = read_run_metrics(out / "metrics.json")
    assert saved == result.metrics
    assert saved.scans.processed == 40 and saved.segments > 40
    assert set(saved.timings_s) >= {"extraction", "fusion_library_loading", "fusion_proposed", "total"}
    assert saved.primary == "truth" and saved.references["truth"].endswith("truth")
    proposed = saved.primary_scores("proposed")
    # 32 m of driving along the south wall a-b of the one building: that wall, once, on the truth
    assert proposed["observable_walls"] >= 1
    assert proposed["precision"] > 0.95 and proposed["recall"] > 0.9
    assert proposed["offset_cm"] < 5
    assert saved.methods["proposed"].count <= proposed["observable_walls"] + 1
    # the report names exactly the files written (plots are off here)
    assert "map_overview.png" not in result.files and not (out / "map_overview.png").exists()
    assert sorted([*result.files, MANIFEST]) == sorted(p.name for p in out.iterdir())


def test_refusing_never_reextracts_and_an_interrupted_run_resumes(run_case1, tmp_path):
    first = run_case1().metrics
    assert first.scans.extracted_now == 40 and first.scans.from_cache == 0
    second = run_case1(["fusion.proposed.delta_deg=3", "fusion.proposed.eta_m=0.3"]).metrics
    assert second.scans.extracted_now == 0 and second.scans.from_cache == 40
    # an interrupted extraction leaves some scans uncached: only those are extracted again
    entries = sorted((tmp_path / "cache").glob("*/*.npz"))
    assert len(entries) == 40
    for entry in entries[:3]:
        entry.unlink()
    third = run_case1().metrics
    assert third.scans.extracted_now == 3
    assert third.segments == first.segments
    # the settings of the extractor in use are part of the key; another extractor's are not
    assert run_case1(["extraction.ransac_planes.max_gap_m=2.0"]).metrics.scans.extracted_now == 0
    fourth = run_case1(["extraction.vertical_structure.max_gap_m=2.0"]).metrics
    assert fourth.scans.extracted_now == 40


def test_parallel_workers_give_the_same_segments(run_case1, tmp_path):
    run_case1(workers=1, out=tmp_path / "a", cache=tmp_path / "ca")
    run_case1(workers=2, out=tmp_path / "b", cache=tmp_path / "cb")
    a = (tmp_path / "a" / "segments.csv").read_bytes()
    assert a == (tmp_path / "b" / "segments.csv").read_bytes()
    for m in ("proposed", "density"):
        assert (tmp_path / "a" / f"fused_{m}.csv").read_bytes() == (tmp_path / "b" / f"fused_{m}.csv").read_bytes()


def test_bad_scan_fails_at_once_or_is_skipped_and_reported(drive_copy, tmp_path):
    root, drive = drive_copy
    scan = root / drive[:10] / f"{drive}_sync" / "velodyne_points" / "data" / "0000000005.bin"
    pts = np.fromfile(scan, dtype=np.float32).reshape(-1, 4)
    pts[0, 0] = np.nan
    pts.tofile(scan)
    cfg = load_config(None, ["output.plots=false"])
    reporter = RecordingReporter()
    pipe = MappingPipeline(cfg, ["proposed"], SegmentStore(tmp_path / "c"), reporter=reporter)
    with pytest.raises(DatasetError, match="0000000005.bin: 1 point.*NaN.*--skip-bad-scans"):
        pipe.run(KittiRawDataset(root, drive), tmp_path / "out")
    assert not (tmp_path / "out").exists()                      # nothing written when the run fails
    assert not list(tmp_path.glob(".out.partial*"))
    assert len(list((tmp_path / "c").glob("*/*.npz"))) == 5      # it stopped at scan 5, not after all 40
    pipe = MappingPipeline(cfg, ["proposed"], SegmentStore(tmp_path / "c"), reporter=reporter, skip_bad_scans=True)
    metrics = pipe.run(KittiRawDataset(root, drive, skip_bad_scans=True), tmp_path / "out").metrics
    assert list(metrics.source.skipped) == ["5"] and metrics.scans.processed == 39
    assert any("skipped 1 bad scan" in w for w in reporter.warnings)


def test_a_moved_run_folder_still_finds_its_truth(run_case1, tmp_path):
    from featmap.pipeline.run_folder import load_run

    run_case1()
    moved = tmp_path / "elsewhere" / "run"
    moved.parent.mkdir()
    (tmp_path / "run").rename(moved)
    run = load_run(moved)
    assert run.truth is not None and len(run.truth.walls) == 4
    assert run.metrics.source.frames_processed == list(range(40))


def test_cli_run_on_a_given_drive_and_missing_drive(case1_drive, tmp_path):
    res = runner.invoke(app, ["run", "--drive", case1_drive.drive, "--data-dir", str(case1_drive.root),
                              "--frames", "0:40:2", "--method", "proposed", "--out", str(tmp_path / "r"),
                              "--workers", "1", "--cache-dir", str(tmp_path / "c"), "--set", "output.plots=false"])
    assert res.exit_code == 0, res.output
    assert read_run_metrics(tmp_path / "r" / "metrics.json").scans.processed == 20
    assert "proposed" in res.output and "precision" in res.output
    res = runner.invoke(app, ["run", "--drive", "2011_09_30_drive_0018", "--data-dir", str(tmp_path / "nokitti"),
                              "--out", str(tmp_path / "r2")])
    assert res.exit_code == 2
    assert "featmap download" in res.output and len(res.output.strip().splitlines()) == 1
    assert not (tmp_path / "r2").exists()


def test_cli_run_through_the_dataset_registry(case1_drive, tmp_path):
    args = ["run", "--dataset", "kitti_raw", "--source", str(case1_drive.drive_dir), "--frames", "0:10",
            "--method", "proposed", "--out", str(tmp_path / "r"), "--workers", "1", "--cache-dir", str(tmp_path / "c"),
            "--set", "output.plots=false"]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    assert read_run_metrics(tmp_path / "r" / "metrics.json").source.kind == "kitti_raw"
    res = runner.invoke(app, ["run", "--dataset", "kitti_raw", "--out", str(tmp_path / "r3")])
    assert res.exit_code == 2 and "give its --source LOCATION" in res.output
    res = runner.invoke(app, ["run", "--drive", case1_drive.drive, "--world", "residential"])
    assert res.exit_code == 2 and "--drive and --world: give one source" in res.output


def test_cli_evaluate_against_footprints(run_case1, case1_drive, tmp_path):
    run_case1()
    truth = case1_drive.drive_dir / "truth" / "footprints.geojson"
    res = runner.invoke(app, ["evaluate", str(tmp_path / "run" / "fused_proposed.csv"), "--truth", str(truth),
                              "--out", str(tmp_path / "m.json")])
    assert res.exit_code == 0, res.output
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["precision"] > 0.95 and m["observable_walls"] == 4    # footprints: every wall counts
    res = runner.invoke(app, ["evaluate", str(tmp_path / "run" / "fused_proposed.geojson"), "--truth", str(truth)])
    assert res.exit_code == 0 and "precision" in res.output


def test_cli_evaluate_scores_a_run_of_selected_frames_as_the_run_did(run_case1, case1_drive, tmp_path):
    """A run of a few frames observed only part of the building: evaluate scores it against the walls of
    those frames, as the run did (and against the whole drive's when the truth is not the run's own)."""
    result = run_case1(frames=slice(37, 40))
    truth = case1_drive.drive_dir / "truth"
    res = runner.invoke(app, ["evaluate", str(tmp_path / "run" / "fused_proposed.csv"), "--truth", str(truth),
                              "--out", str(tmp_path / "m.json")])
    assert res.exit_code == 0, res.output
    m, own = json.loads((tmp_path / "m.json").read_text()), result.metrics.primary_scores("proposed")
    for key in ("observable_walls", "count_ratio", "precision", "recall"):
        assert m[key] == pytest.approx(own[key]), key
    assert "np.str_" not in res.output
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "fused_proposed.csv").write_text((tmp_path / "run" / "fused_proposed.csv").read_text())
    res = runner.invoke(app, ["evaluate", str(elsewhere / "fused_proposed.csv"), "--truth", str(truth),
                              "--origin", f"{result.metrics.geo_frame.lat0_deg},{result.metrics.geo_frame.lon0_deg}",
                              "--out", str(tmp_path / "m2.json")])
    assert res.exit_code == 0, res.output
    assert json.loads((tmp_path / "m2.json").read_text())["observable_walls"] >= m["observable_walls"]


def test_footprints_from_the_config_score_a_run_on_the_walls_its_scans_saw(run_case1, case1_drive, tmp_path):
    """Footprints carry no observation record: the run takes it from its scans' points, so it scores the two
    walls the drive saw (of the building's four) as the simulator's truth does, writes the record, and
    evaluate, figures and sweeps read it back (a footprints file the run did not observe counts whole)."""
    from featmap.pipeline.run_folder import load_run
    from featmap.sweep import run_sweep_file

    footprints = case1_drive.drive_dir / "truth" / "footprints.geojson"
    metrics = run_case1([f"evaluation.footprints={footprints}"]).metrics
    assert metrics.primary == "truth" and set(metrics.references) == {"truth", "footprints", "map"}
    fp, truth = metrics.methods["proposed"].scores["footprints"], metrics.methods["proposed"].scores["truth"]
    assert fp["observable_walls"] == truth["observable_walls"] == 2 and fp["precision"] > 0.95
    assert fp["recall"] == pytest.approx(truth["recall"], abs=0.01) and fp["recall"] > 0.95
    assert (tmp_path / "run" / "footprint_walls.csv").exists()
    for fused in ("fused_proposed.csv", "fused_proposed.geojson"):
        res = runner.invoke(app, ["evaluate", str(tmp_path / "run" / fused), "--truth", str(footprints),
                                  "--out", str(tmp_path / "m.json")])
        assert res.exit_code == 0, res.output
        m = json.loads((tmp_path / "m.json").read_text())
        assert m["observable_walls"] == 2 and m["recall"] == pytest.approx(fp["recall"], abs=1e-6), fused
    record = read_run_metrics(tmp_path / "run" / "metrics.json")     # a run scored against footprints only
    shutil.copytree(tmp_path / "run", tmp_path / "fp_only")
    write_run_metrics(tmp_path / "fp_only" / "metrics.json", record.model_copy(
        update={"references": {"footprints": str(footprints)}, "primary": "footprints"}))
    assert load_run(tmp_path / "fp_only").truth.observable().sum() == 2
    spec = tmp_path / "s.yaml"
    spec.write_text(f"input: {tmp_path / 'run' / 'segments.csv'}\ntruth: {footprints}\nmethods: [proposed]\n"
                    "grid: {fusion.proposed.gamma: [0.5]}\n")
    rows, _ = run_sweep_file(spec, tmp_path / "sweep")
    assert rows[0]["count_ratio"] == pytest.approx(rows[0]["count"] / 2)
    # a town's footprints around the drive's: the run keeps the walls near its scans, and scores the same
    town = json.loads(footprints.read_text())
    lon0, lat0 = town["features"][0]["geometry"]["coordinates"][0][0]
    for k in range(400):
        x, y = 1e-3 * (k % 20 - 10) + 3e-4, 1e-3 * (k // 20 - 10) + 3e-4      # every ~100 m, none on the drive's
        square = [[lon0 + x, lat0 + y], [lon0 + x + 1e-4, lat0 + y], [lon0 + x + 1e-4, lat0 + y + 1e-4],
                  [lon0 + x, lat0 + y + 1e-4], [lon0 + x, lat0 + y]]
        town["features"].append({"type": "Feature", "properties": {"id": f"t{k}"},
                                 "geometry": {"type": "Polygon", "coordinates": [square]}})
    (tmp_path / "town.geojson").write_text(json.dumps(town))
    in_town = run_case1([f"evaluation.footprints={tmp_path / 'town.geojson'}"], out=tmp_path / "town_run").metrics
    assert in_town.methods["proposed"].scores["footprints"] == fp
    kept = read_walls_csv(tmp_path / "town_run" / "footprint_walls.csv")
    assert set(kept.building) <= {f["properties"].get("id", "") for f in json.loads(footprints.read_text())["features"]}
    res = runner.invoke(app, ["evaluate", str(tmp_path / "town_run" / "fused_proposed.csv"), "--truth",
                              str(tmp_path / "town.geojson"), "--out", str(tmp_path / "m.json")])
    assert res.exit_code == 0 and json.loads((tmp_path / "m.json").read_text())["recall"] == pytest.approx(fp["recall"])
    other = tmp_path / "copy.geojson"                       # the same footprints elsewhere: not the run's
    other.write_text(footprints.read_text())
    res = runner.invoke(app, ["evaluate", str(tmp_path / "run" / "fused_proposed.csv"), "--truth", str(other),
                              "--out", str(tmp_path / "m.json")])
    assert res.exit_code == 0 and json.loads((tmp_path / "m.json").read_text())["observable_walls"] == 4
