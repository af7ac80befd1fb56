"""``featmap run --online N``: scans extracted and fused one at a time; the last map is the offline one."""

import csv

import numpy as np
import pytest
from typer.testing import CliRunner

from featmap.cli import app
from featmap.datasets import KittiRawDataset
from featmap.errors import ConfigError, DatasetError
from featmap.io.run_metrics import read_run_metrics
from featmap.pipeline import MappingPipeline, SegmentStore, load_config
from featmap.pipeline.online import map_online
from featmap.reporting import RecordingReporter

runner = CliRunner()
QUIET = ["--set", "output.plots=false", "--set", "output.html=false", "--set", "output.kml=false"]


def _run(drive, out, *extra):
    return runner.invoke(app, ["run", "--drive", drive.drive, "--data-dir", str(drive.root), "--out", str(out),
                               "--cache-dir", str(out.parent / "cache"), "-j", "1", *QUIET, *map(str, extra)])


def test_online_run_writes_the_offline_map_of_the_same_scans_and_each_scans_times(case1_drive, tmp_path):
    online = _run(case1_drive, tmp_path / "online", "--online", 7)
    assert online.exit_code == 0, online.output
    offline = _run(case1_drive, tmp_path / "offline", "--method", "proposed", "--set", "refinement.method=fixed_lag")
    assert offline.exit_code == 0, offline.output
    for name in ("segments.csv", "fused_proposed.csv", "trajectory.csv", "trajectory_refined.csv", "pose_corrections.csv"):
        assert (tmp_path / "online" / name).read_bytes() == (tmp_path / "offline" / name).read_bytes(), name
    rows = list(csv.DictReader(open(tmp_path / "online" / "online.csv")))
    assert [int(r["frame"]) for r in rows] == list(range(40))
    made = [k for k, r in enumerate(rows) if r["features"]]
    assert made == [6, 13, 20, 27, 34, 39]                          # every 7th scan, and the last
    fused = sum(1 for _ in open(tmp_path / "online" / "fused_proposed.csv")) - 1
    assert int(rows[-1]["features"]) == fused > 0
    assert all(float(r["extract_ms"]) > 0 and float(r["link_ms"]) >= 0 and float(r["refine_ms"]) >= 0 for r in rows)
    metrics = read_run_metrics(tmp_path / "online" / "metrics.json")
    assert metrics.online.every == 7 and metrics.online.maps == 6 and metrics.timings_s["online_link_per_scan_median"] >= 0
    assert metrics.scans.extracted_now == 40 and metrics.scans.from_cache == 0     # no cache: each scan's real cost
    assert list(metrics.methods) == ["proposed"] and metrics.refinement.method == "fixed_lag"
    assert metrics.refinement.applied is False                     # exact poses: kept as they were
    assert "online: 40 scans one at a time" in online.output


def test_the_map_after_each_scan_is_the_offline_map_of_the_scans_so_far(case1_drive):
    from featmap.fusion import fuse

    ds = KittiRawDataset(case1_drive.root, case1_drive.drive)
    cfg = load_config(None, ["refinement.method=none"])
    mapping = map_online(ds, cfg, 1, RecordingReporter())
    assert np.isfinite(mapping.fused_s).all() and len(mapping.frames) == 40
    table = mapping.extraction.world_table()
    for k in (0, 9, 25, 39):
        prefix = table.scan <= mapping.frames[k]
        offline = fuse("proposed", table.segments[prefix], table.scan[prefix], cfg.fusion, rms=table.extra["rms"][prefix])
        assert mapping.features[k] == len(offline)
    assert np.array_equal(mapping.result.segments, offline.segments)


def test_online_refuses_what_it_cannot_do_in_one_line(case1_drive, tmp_path):
    res = _run(case1_drive, tmp_path / "o", "--online", 5, "--method", "density")
    assert res.exit_code == 2
    assert res.output.strip().splitlines()[-1].startswith("featmap: error: --online fuses one scan at a time with proposed only")
    res = _run(case1_drive, tmp_path / "o", "--online", 5, "--set", "refinement.method=pose_graph")
    assert res.exit_code == 2
    assert res.output.strip().splitlines()[-1] == (
        "featmap: error: --online corrects the poses causally (refinement.method=fixed_lag) or not at all (none), "
        "but --set asks for refinement.method=pose_graph (it needs the whole drive)")
    res = _run(case1_drive, tmp_path / "o", "--online", 0)
    assert res.exit_code == 2 and "featmap: error:" in res.output and "--online" in res.output
    cfg = load_config(None, [])                                     # the library: refinement must be causal or off
    with pytest.raises(ConfigError, match="refinement.method=fixed_lag"):
        MappingPipeline(cfg, ["proposed"], SegmentStore(None), online_every=5)


def test_an_unreadable_scan_stops_the_online_run_or_is_left_out(drive_copy, tmp_path):
    root, drive = drive_copy
    bad = root / drive[:10] / f"{drive}_sync" / "velodyne_points" / "data" / "0000000012.bin"
    points = np.fromfile(bad, dtype=np.float32).reshape(-1, 4)
    points[3, 1] = np.nan                                          # found when the scan is read, mid-drive
    points.tofile(bad)
    cfg = load_config(None, ["refinement.method=none"])
    with pytest.raises(DatasetError, match="0000000012.bin: 1 point.*NaN.*--skip-bad-scans"):
        map_online(KittiRawDataset(root, drive), cfg, 5)
    mapping = map_online(KittiRawDataset(root, drive, skip_bad_scans=True), cfg, 5, skip_bad_scans=True)
    assert 12 not in mapping.frames.tolist() and list(mapping.extraction.skipped) == [12]
    assert mapping.features[-1] == len(mapping.result) > 0


def test_a_non_finite_pose_stops_the_online_run_at_its_scan_only_when_the_scan_is_read(drive_copy):
    """As offline: the pose of a scan left out (unreadable, --skip-bad-scans) is not looked at."""
    root, drive = drive_copy
    data = root / drive[:10] / f"{drive}_sync"
    points = np.fromfile(data / "velodyne_points" / "data" / "0000000012.bin", dtype=np.float32).reshape(-1, 4)
    points[3, 1] = np.nan
    points.tofile(data / "velodyne_points" / "data" / "0000000012.bin")

    class NanPose(KittiRawDataset):
        def poses(self):
            poses = super().poses()
            poses[self.frames.index(frame), 0, 3] = np.nan
            return poses

    cfg = load_config(None, ["refinement.method=none"])
    frame = 12                                          # its scan is unreadable and left out: its pose does not matter
    mapping = map_online(NanPose(root, drive, skip_bad_scans=True), cfg, 5, skip_bad_scans=True)
    assert len(mapping.frames) == 39
    frame = 20                                          # a scan that is read
    with pytest.raises(DatasetError, match="frame 20: its pose has NaN or inf values"):
        map_online(NanPose(root, drive, skip_bad_scans=True), cfg, 5, skip_bad_scans=True)


@pytest.mark.parametrize("every", [1, 5])
def test_scans_waiting_for_their_correction_reach_the_map_when_the_last_scans_are_unreadable(drive_copy, every):
    """The drive's last scan cannot be read: the scans still waiting for their correction are decided and
    linked after the loop, whether or not a map was made at the last scan read (with every = 1 none were)."""
    from featmap.fusion import fuse

    root, drive = drive_copy
    bad = root / drive[:10] / f"{drive}_sync" / "velodyne_points" / "data" / "0000000039.bin"
    points = np.fromfile(bad, dtype=np.float32).reshape(-1, 4)
    points[3, 1] = np.nan                                          # found when the scan is read, at the end
    points.tofile(bad)
    cfg = load_config(None, ["refinement.method=fixed_lag"])
    mapping = map_online(KittiRawDataset(root, drive, skip_bad_scans=True), cfg, every, skip_bad_scans=True)
    assert len(mapping.frames) == 39 and list(mapping.extraction.skipped) == [39]
    table = mapping.extraction.world_table(mapping.refinement.poses)
    offline = fuse("proposed", table.segments, table.scan, cfg.fusion, rms=table.extra["rms"],
                   max_gap=table.extra.get("max_gap"))
    assert len(offline) > 0 and np.array_equal(mapping.result.segments, offline.segments)
    assert mapping.features[-1] == len(offline)


def test_a_config_that_turns_refinement_off_is_kept_online(case1_drive, tmp_path):
    """``--config paper`` (refinement.method: none) maps online with the source's poses; the default config's
    whole-drive pose_graph becomes the causal fixed_lag."""
    res = _run(case1_drive, tmp_path / "paper", "--online", 10, "--config", "paper")
    assert res.exit_code == 0, res.output
    assert read_run_metrics(tmp_path / "paper" / "metrics.json").refinement.method == "none"
    res = _run(case1_drive, tmp_path / "default", "--online", 10, "--set", "fusion.proposed.eta_m=0.5")
    assert res.exit_code == 0, res.output
    assert read_run_metrics(tmp_path / "default" / "metrics.json").refinement.method == "fixed_lag"
