"""The refinement stage of a run: what it writes, what it records, and that it fixes drifting OXTS poses."""

import csv

import numpy as np
import pytest

from featmap.datasets import KittiRawDataset
from featmap.io.run_metrics import read_run_metrics
from featmap.pipeline import MappingPipeline, SegmentStore, load_config
from featmap.reporting import RecordingReporter
from featmap.simulation.sensors import SENSORS
from featmap.simulation.simulate import simulate_drive
from featmap.simulation.worlds import load_world


def _rows(path):
    return list(csv.DictReader(open(path)))


def test_an_exact_drive_is_left_unchanged(case1_drive, tmp_path):
    result, reporter = _run(case1_drive, tmp_path, "run")
    out = tmp_path / "run"
    record = result.metrics.refinement
    assert record.method == "pose_graph" and record.applied is False
    assert record.correction_max_m == 0 and record.rotation_max_deg == 0
    assert record.loops is None                   # the loop search is off outside the indoor preset
    assert (out / "trajectory_refined.csv").read_text() == (out / "trajectory.csv").read_text()
    corrections = _rows(out / "pose_corrections.csv")
    assert len(corrections) == 40 and all(float(r[k]) == 0 for r in corrections for k in ("dx_m", "dy_m", "dyaw_deg"))
    assert "trajectory_refined.geojson" in result.files
    assert any("pose refinement (pose_graph): kept the source poses" in m for m in reporter.infos)


@pytest.fixture(scope="module")
def drifting_drive(tmp_path_factory):
    """prescan_case1, 40 frames, OXTS poses with 0.3 m / 0.5 deg Gauss-Markov drift (1 s correlation)."""
    root = tmp_path_factory.mktemp("drift")
    return simulate_drive(load_world("prescan_case1"), root, SENSORS["vlp32"], n_frames=40, seed=3,
                          pose_noise=(0.3, 0.5), pose_noise_tau_s=1.0)


def _run(drive, tmp_path, name, *overrides):
    ds = KittiRawDataset(drive.root, drive.drive)
    cfg = load_config(None, ["output.plots=false", "output.html=false", "output.kml=false", *overrides])
    reporter = RecordingReporter()
    result = MappingPipeline(cfg, ["proposed"], SegmentStore(tmp_path / "cache"), reporter=reporter).run(ds, tmp_path / name)
    return result, reporter


def test_drifting_oxts_poses_are_refined_and_the_map_gets_sharper(drifting_drive, tmp_path):
    off, _ = _run(drifting_drive, tmp_path, "off", "refinement.method=none")
    on, reporter = _run(drifting_drive, tmp_path, "on")
    assert off.metrics.refinement.method == "none" and not (tmp_path / "off" / "pose_corrections.csv").exists()
    record = read_run_metrics(tmp_path / "on" / "metrics.json").refinement
    assert record == on.metrics.refinement
    assert record.applied and record.residual_after_mm < record.residual_before_mm / 3
    assert 0.05 < record.correction_mean_m < 1.0 and record.seconds > 0
    assert "refinement" in on.metrics.timings_s
    assert any("pose refinement (pose_graph): moved 40 scans" in m for m in reporter.infos)
    before, after = off.metrics.primary_scores("proposed"), on.metrics.primary_scores("proposed")
    assert after["offset_cm"] < before["offset_cm"]
    # The refined trajectory is the source trajectory moved by the recorded corrections.
    src = np.array([[float(r[k]) for k in ("x", "y", "yaw")] for r in _rows(tmp_path / "on" / "trajectory.csv")])
    ref = np.array([[float(r[k]) for k in ("x", "y", "yaw")] for r in _rows(tmp_path / "on" / "trajectory_refined.csv")])
    cor = np.array([[float(r[k]) for k in ("dx_m", "dy_m", "dyaw_deg")] for r in _rows(tmp_path / "on" / "pose_corrections.csv")])
    assert np.allclose(ref[:, :2], src[:, :2] + cor[:, :2], atol=2e-4)
    assert np.allclose(np.rad2deg(ref[:, 2] - src[:, 2]), cor[:, 2], atol=1e-3)
    assert np.isclose(np.hypot(cor[:, 0], cor[:, 1]).mean(), record.correction_mean_m, atol=1e-3)


def test_online_mapping_corrects_drifting_poses_causally(drifting_drive, tmp_path):
    """``--online``: the fixed-lag smoother's map of the drifting drive is sharper than the map of the poses
    as they come, and is the map the offline run with the same (causal) refinement makes."""
    def online(name, *overrides):
        ds = KittiRawDataset(drifting_drive.root, drifting_drive.drive)
        cfg = load_config(None, ["output.plots=false", "output.html=false", "output.kml=false", *overrides])
        reporter = RecordingReporter()
        result = MappingPipeline(cfg, ["proposed"], SegmentStore(None), reporter=reporter, online_every=10).run(
            ds, tmp_path / name)
        return result, reporter

    raw, _ = online("raw", "refinement.method=none")
    causal, reporter = online("causal", "refinement.method=fixed_lag")
    offline, _ = _run(drifting_drive, tmp_path, "offline", "refinement.method=fixed_lag")
    record = causal.metrics.refinement
    assert record.method == "fixed_lag" and record.applied and 0.05 < record.correction_mean_m < 1.0
    assert record.residual_after_mm < record.residual_before_mm / 3
    before, after = raw.metrics.primary_scores("proposed"), causal.metrics.primary_scores("proposed")
    assert after["offset_cm"] < before["offset_cm"] and after["precision"] >= before["precision"]
    assert (tmp_path / "causal" / "fused_proposed.csv").read_bytes() == (tmp_path / "offline" / "fused_proposed.csv").read_bytes()
    assert offline.metrics.refinement.correction_mean_m == record.correction_mean_m
    assert any("pose correction" in m and "(fixed_lag)" in m for m in reporter.infos)
