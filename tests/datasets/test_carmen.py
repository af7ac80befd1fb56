"""CARMEN logs as a scan source: beam-order points in the laser frame, the first pose, frame selections."""

import numpy as np
import pytest

from featmap.datasets import ScanSource, SourceSpec, open_source
from featmap.datasets.carmen import CarmenSource, log_name, pose_matrix
from featmap.errors import DatasetError, InputFileError
from tests.conftest import shared_data


def _log(tmp_path):
    ranges = " ".join(["2.0"] * 90 + ["81.83"] * 90)      # half the beams see a wall 2 m away, half nothing
    lines = [f"FLASER 180 {ranges} {x:.1f} 0.5 {th:.4f} 0 0 0 {t:.1f} host {t:.1f}"
             for x, th, t in ((0.0, 0.0, 10.0), (1.0, np.pi / 2, 10.5), (2.0, np.pi, 11.0))]
    path = tmp_path / "tiny.log"
    path.write_text("# a comment\nPARAM x 1 nohost 0\n" + "\n".join(lines) + "\n")
    return path


def test_scans_poses_and_selection(tmp_path):
    source = open_source(SourceSpec("carmen", str(_log(tmp_path)), "1:3"))
    assert isinstance(source, ScanSource) and source.dimension == 2 and source.geo_origin is None
    assert source.name == "tiny" and source.frames == [1, 2] and len(source) == 2
    scan = source[0]
    assert scan.index == 1 and scan.points.shape == (90, 2) and scan.timestamp == pytest.approx(0.5)
    # beam k at -90 deg + k deg: the first beam looks along -y of the laser
    assert scan.points[0] == pytest.approx([0.0, -2.0], abs=1e-9)
    assert np.hypot(*scan.points.T) == pytest.approx(np.full(90, 2.0))
    assert scan.T_world_sensor[:2, 3] == pytest.approx([1.0, 0.5])
    assert np.allclose(source.poses()[1], pose_matrix(np.array([2.0, 0.5, np.pi])), atol=1e-4)
    with pytest.raises(DatasetError, match="--frames 2:9: tiny has 3 frames"):
        CarmenSource(_log(tmp_path), "2:9")


def test_names_and_bad_files(tmp_path):
    assert log_name("intel-corrected.log.gz") == "intel-corrected" and log_name("aces.clf.bz2") == "aces"
    bad = tmp_path / "bad.log"
    bad.write_text("FLASER 180 1 2 3\n")
    with pytest.raises(InputFileError, match=r"bad.log:1"):
        CarmenSource(bad)


def test_the_shipped_intel_log():
    path = shared_data("carmen_2d", "intel-corrected.log.gz")
    source = CarmenSource(path, "0:100")
    assert len(source) == 100 and 100 < len(source[0].points) <= 180


def test_a_log_says_whether_its_scan_poses_are_a_slam_result(tmp_path):
    """NEFF records (the particle filter that corrected the log) or ODOM records that are all zero: a SLAM
    result. Real odometry (even when it follows the scan poses closely, as in a corrected log), no ODOM
    at all, or zero ODOM records only before the first scan among real ones: not."""
    from featmap.io.carmen import flaser_log_text

    poses = np.column_stack([np.linspace(1.0, 6.0, 6), np.full(6, 2.0), np.zeros(6)])
    ranges, stamps = np.full((6, 180), 3.0), np.arange(6) * 0.5

    def lines(odometry):
        return flaser_log_text(ranges, poses, stamps, odometry).splitlines()

    with_neff = [line for pair in zip(lines(poses + 0.03)[0::2], lines(poses + 0.03)[1::2])
                 for line in (*pair, "NEFF 12.5")]
    cases = {"odometry": (lines(poses + 0.01), False), "zeroed": (lines(None), True), "neff": (with_neff, True),
             "no ODOM": ([line for line in lines(None) if not line.startswith("ODOM")], False),
             "zeros first": (["ODOM 0 0 0 0 0 0 0.0 h 0.0"] + lines(poses), False)}
    for name, (text, slam) in cases.items():
        path = tmp_path / f"{name.replace(' ', '_')}.log"
        path.write_text("\n".join(text) + "\n")
        assert CarmenSource(path).slam_poses is slam, name


@pytest.mark.parametrize("path, slam", [(("carmen_2d", "intel-corrected.log.gz"), True),
                                        (("carmen_2d", "aces-corrected.log.gz"), True),
                                        (("carmen_2d", "fhw-corrected.log.gz"), True),
                                        (("carmen_2d_raw", "intel.clf.bz2"), False),
                                        (("carmen_2d_raw", "aces.clf.bz2"), False)])
def test_the_shipped_logs_say_what_their_poses_are(path, slam):
    assert CarmenSource(shared_data(*path)).slam_poses is slam


def test_frames_whose_clock_stepped_back_are_flagged_and_reported(tmp_path):
    from typer.testing import CliRunner

    from featmap.cli import app
    from featmap.datasets.base import TIME_GOES_BACK, frames_back_in_time
    from featmap.io.carmen import flaser_log_text
    from tests.conftest import write_room_log

    assert frames_back_in_time(np.array([0.0, 0.2, 0.1, 0.3, 0.3, 0.5]), range(6)) == [2, 4]
    assert frames_back_in_time(np.array([0.0, 0.2, 0.1, 0.3]), [0, 1, 3]) == []     # frame 2 not selected
    assert frames_back_in_time(np.array([1.0]), [0]) == []
    good = write_room_log(tmp_path / "good.log", np.random.default_rng(0), n_scans=12)
    assert CarmenSource(good).notes.flags == {}
    log = CarmenSource(good).log
    stamps = np.asarray(log.timestamp, float).copy()
    stamps[5] = stamps[3]                                  # the clock stepped back at scan 5
    path = tmp_path / "back.log"
    path.write_text(flaser_log_text(np.asarray([log.ranges[k] for k in range(len(log))]), np.asarray(log.pose),
                                    stamps))
    assert CarmenSource(path).notes.flags == {TIME_GOES_BACK: [5]}
    res = CliRunner().invoke(app, ["run", "--carmen", str(path), "--out", str(tmp_path / "r"), "--cache-dir",
                                   str(tmp_path / "c"), "--workers", "1", "--set", "output.plots=false"])
    assert res.exit_code == 0, res.output
    assert "1 frame(s) whose timestamp is not after the one before (first: frame 5)" in " ".join(res.output.split())
