"""The segment cache never serves a stale or broken entry."""

import shutil

import numpy as np

from featmap.io.run_metrics import read_run_metrics
from featmap.simulation.sensors import SENSORS
from featmap.simulation.simulate import simulate_drive
from featmap.simulation.worlds import load_world
from tests.faults.conftest import cli, contract_files, one_line_error, run_args


def test_a_resimulated_drive_at_the_same_path_is_extracted_again(tmp_path):
    world = load_world("prescan_case1")
    drive = simulate_drive(world, tmp_path / "kitti", SENSORS["vlp32"], n_frames=8, noise_m=0.01, seed=1)
    assert cli(*run_args(drive, tmp_path / "r1", tmp_path / "cache", "--method", "proposed")).exit_code == 0
    first = (tmp_path / "r1" / "segments.csv").read_bytes()
    shutil.rmtree(tmp_path / "kitti")
    drive = simulate_drive(world, tmp_path / "kitti", SENSORS["vlp32"], n_frames=8, noise_m=0.03, seed=2)
    res = cli(*run_args(drive, tmp_path / "r2", tmp_path / "cache", "--method", "proposed"))
    assert res.exit_code == 0, res.output
    metrics = read_run_metrics(tmp_path / "r2" / "metrics.json")
    assert metrics.scans.extracted_now == 8 and metrics.scans.from_cache == 0
    assert (tmp_path / "r2" / "segments.csv").read_bytes() != first


def test_a_bad_calibration_fails_before_extraction_and_poisons_nothing(drive_copy, tmp_path):
    root, drive_name = drive_copy
    calib = root / drive_name[:10] / "calib_imu_to_velo.txt"
    good = calib.read_text()
    lines = good.splitlines()
    calib.write_text("\n".join(line if not line.startswith("T:") else "T: nan 0 0" for line in lines) + "\n")
    args = ["run", "--drive", drive_name, "--data-dir", root, "--out", tmp_path / "r", "--cache-dir", tmp_path / "c",
            "--workers", "1", "--set", "output.plots=false"]
    one_line_error(cli(*args), "calib_imu_to_velo.txt: 'R' and 'T' must be finite")
    assert not (tmp_path / "c").exists() or not list((tmp_path / "c").rglob("*.npz"))
    calib.write_text(good)                                       # fixed: the run works, nothing to delete by hand
    assert cli(*args).exit_code == 0


def test_truncated_and_empty_cache_entries_are_remade_with_a_warning(case1_drive, tmp_path):
    args = run_args(case1_drive, tmp_path / "r", tmp_path / "cache", "--method", "proposed", "--frames", "0:12")
    assert cli(*args).exit_code == 0
    before = contract_files(tmp_path / "r")
    entries = sorted((tmp_path / "cache").rglob("*.npz"))
    entries[0].write_bytes(entries[0].read_bytes()[:50])
    entries[1].write_bytes(b"")
    res = cli(*args)
    assert res.exit_code == 0, res.output
    assert res.output.count("discarded a corrupt cache entry") == 2
    assert read_run_metrics(tmp_path / "r" / "metrics.json").scans.extracted_now == 2
    assert contract_files(tmp_path / "r") == before


def test_an_unusable_cache_dir_fails_at_once(case1_drive, tmp_path):
    (tmp_path / "cachefile").write_text("x")
    one_line_error(cli(*run_args(case1_drive, tmp_path / "r", tmp_path / "cachefile")), "--cache-dir")
    assert not (tmp_path / "r").exists()


def test_a_nan_in_a_scan_with_two_workers_fails_at_that_scan(drive_copy, tmp_path):
    root, drive_name = drive_copy
    path = root / drive_name[:10] / f"{drive_name}_sync" / "velodyne_points" / "data" / "0000000002.bin"
    pts = np.fromfile(path, dtype=np.float32)
    pts[10] = np.nan
    pts.tofile(path)
    args = ["run", "--drive", drive_name, "--data-dir", root, "--out", tmp_path / "r", "--cache-dir", tmp_path / "c",
            "--workers", "2", "--set", "output.plots=false"]
    one_line_error(cli(*args), "0000000002.bin: 1 point(s) with NaN")
    assert len(list((tmp_path / "c").rglob("*.npz"))) <= 2 + 4        # at most the scans in flight, not all 40
