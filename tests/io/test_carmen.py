import bz2
import gzip

import numpy as np
import pytest

from featmap.errors import InputFileError
from featmap.io.carmen import carmen_beam_angles, read_carmen, read_relations
from tests.conftest import shared_data

# Two 180-beam scans; every beam reads 2 m except the no-returns at 81.83 (the SICK max value).
RANGES_1 = ["2.0"] * 178 + ["81.83", "81.83"]
RANGES_2 = ["81.83"] + ["3.5"] * 179
LOG = "\n".join([
    "# message formats defined: PARAM SYNC ODOM FLASER RLASER TRUEPOS",
    "PARAM robot_frontlaser_offset 0.0 nohost 0",
    "ODOM 0.1 0.2 0.3 0.5 0.01 0 10.0 pippo 10.0",
    "FLASER 180 " + " ".join(RANGES_1) + " 1.0 2.0 0.5 1.1 2.1 0.6 10.5 pippo 10.6",
    "NEFF 15",
    "SOMETHINGNEW 1 2 3",
    "",
    "FLASER 180 " + " ".join(RANGES_2) + " 3.0 4.0 -1.0 3.1 4.1 -1.1 11.5 pippo 11.6",
    "ODOM 1.1 1.2 1.3 0.4 0.02 0 11.0 pippo 11.0",
]) + "\n"


def test_flaser_records_poses_odometry_and_no_returns(tmp_path):
    path = tmp_path / "a.log"
    path.write_text(LOG)
    log = read_carmen(path)
    assert len(log) == 2 and log.ranges.shape == (2, 180)
    assert np.allclose(log.pose, [[1.0, 2.0, 0.5], [3.0, 4.0, -1.0]])
    assert np.allclose(log.odometry, [[1.1, 2.1, 0.6], [3.1, 4.1, -1.1]])
    assert np.allclose(log.timestamp, [10.5, 11.5]) and np.allclose(log.logger_timestamp, [10.6, 11.6])
    assert log.line.tolist() == [4, 8]
    assert log.message.tolist() == ["FLASER", "FLASER"]
    assert np.allclose(log.max_range, 81.83)
    assert log.valid[0].sum() == 178 and not log.valid[0, -2:].any()
    assert log.valid[1].sum() == 179 and not log.valid[1, 0]
    assert np.allclose(log.odom_pose, [[0.1, 0.2, 0.3], [1.1, 1.2, 1.3]])
    assert np.allclose(log.odom_velocity, [[0.5, 0.01], [0.4, 0.02]])
    assert log.odom_line.tolist() == [3, 9]
    assert dict(log.skipped) == {"NEFF": 1, "PARAM": 1, "SOMETHINGNEW": 1}


def test_beam_angles_follow_carmen():
    # 180 beams: -90 deg to +89 deg in 1 deg steps (CARMEN ignores the 181st beam); 361: -90..+90 by 0.5.
    a = carmen_beam_angles(180)
    assert np.isclose(a[0], -np.pi / 2) and np.isclose(a[-1], np.deg2rad(89.0))
    b = carmen_beam_angles(361)
    assert np.isclose(b[0], -np.pi / 2) and np.isclose(b[-1], np.pi / 2)


def test_points_and_world_points(tmp_path):
    path = tmp_path / "a.log"
    path.write_text(LOG)
    log = read_carmen(path)
    pts = log.points(0)
    assert pts.shape == (178, 2)
    # Beam 90 looks straight ahead (angle 0): 2 m along the laser's x axis.
    assert np.allclose(pts[90], [2.0, 0.0])
    # Beam 0 looks to the right (-90 deg): y = -2 in the laser frame.
    assert np.allclose(pts[0], [0.0, -2.0], atol=1e-12)
    world, scan = log.world_points()
    assert len(world) == 178 + 179 and scan.tolist() == [0] * 178 + [1] * 179
    heading = 0.5  # scan 0 pose theta; beam 90 is straight ahead
    assert np.allclose(world[90], [1.0 + 2 * np.cos(heading), 2.0 + 2 * np.sin(heading)])


@pytest.mark.parametrize("compress", [gzip.compress, bz2.compress])
def test_compressed_logs_read_like_plain_ones(tmp_path, compress):
    plain, packed = tmp_path / "a.log", tmp_path / "a.packed"
    plain.write_text(LOG)
    packed.write_bytes(compress(LOG.encode()))
    a, b = read_carmen(plain), read_carmen(packed)
    assert np.array_equal(a.ranges, b.ranges) and np.array_equal(a.pose, b.pose)


def test_robotlaser1_uses_its_own_geometry_and_max_range(tmp_path):
    n = 5
    line = " ".join(["ROBOTLASER1", "0", "-1.0", "2.0", "0.5", "20.0", "0.01", "0", str(n),
                     "1", "2", "20", "3", "4", "0",
                     "1.0", "2.0", "0.1", "0.9", "1.9", "0.1", "0", "0", "0", "0", "0", "12.5", "host", "12.6"])
    path = tmp_path / "r.log"
    path.write_text(line + "\n")
    log = read_carmen(path)
    assert np.allclose(log.angles[0], [-1.0, -0.5, 0.0, 0.5, 1.0])
    assert log.valid[0].tolist() == [True, True, False, True, True]
    assert np.allclose(log.pose[0], [1.0, 2.0, 0.1]) and np.allclose(log.odometry[0], [0.9, 1.9, 0.1])
    assert log.max_range[0] == 20.0 and log.timestamp[0] == 12.5


def test_a_largest_range_seen_once_is_a_real_return(tmp_path):
    ranges = ["2.0"] * 179 + ["7.5"]
    path = tmp_path / "a.log"
    path.write_text("FLASER 180 " + " ".join(ranges) + " 0 0 0 0 0 0 1.0 h 1.0\n")
    log = read_carmen(path)
    assert log.valid.all() and np.isinf(log.max_range[0])
    assert read_carmen(path, max_range_m=7.5).valid.sum() == 179


def _flaser(ranges, pose="1 2 0.5 1 2 0.5 10.5 h 10.6"):
    return f"FLASER {len(ranges)} " + " ".join(ranges) + " " + pose


@pytest.mark.parametrize("content,match", [
    ("PARAM a b\n" + _flaser(["1"] * 10, "1 2 0.5 1 2") + "\n", r"x.log:2: FLASER with 10 beams needs at least"),
    ("PARAM a b\n" + _flaser(["1"] * 9 + ["nan"]) + "\n", r"x.log:2: FLASER: NaN or infinite value"),
    (_flaser(["1"] * 10, "nan 2 0.5 1 2 0.5 10.5 h 10.6") + "\n", r"x.log:1: FLASER: NaN or infinite value"),
    (_flaser(["1"] * 9 + ["abc"]) + "\n", r"x.log:1: FLASER: 'abc' is not a number"),
    ("FLASER ten 1 2 3\n", r"x.log:1: FLASER: beam count 'ten' is not an integer"),
    ("# comment\nPARAM a b\nODOM 0 0 0 0 0 0 1 h 1\n", r"x.log:3: no FLASER or ROBOTLASER1 record in 3 lines"),
    ("", r"x.log:1: no FLASER or ROBOTLASER1 record"),
    ("scan,x1,y1,x2,y2\n0,1,2,3,4\n", r"x.log:1: not a CARMEN log: line starts with 'scan,x1,y1,x2,y2'"),
    ("PARAM a b\nODOM 0 0 0\n", r"x.log:2: ODOM needs at least 7 values"),
    # positions beyond any map: the first such record in the file is named, whatever its type
    (_flaser(["1"] * 10) + "\nODOM 1e30 0 0 0 0 0 1 h 1\n" + _flaser(["1"] * 10, "2e13 2 0.5 1 2 0.5 10.5 h 10.6") + "\n",
     r"x.log:2: ODOM: pose coordinate 1e\+30 m is beyond"),
    (_flaser(["1"] * 10, "1 2 0.5 -3e12 2 0.5 10.5 h 10.6") + "\nODOM 1e30 0 0 0 0 0 1 h 1\n",
     r"x.log:1: FLASER: pose coordinate 3e\+12 m is beyond"),
])
def test_bad_logs_name_file_and_line(tmp_path, content, match):
    path = tmp_path / "x.log"
    path.write_text(content)
    with pytest.raises(InputFileError, match=match):
        read_carmen(path)


def test_binary_file_is_not_a_carmen_log(tmp_path):
    path = tmp_path / "x.log"
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)))
    with pytest.raises(InputFileError, match=r"x.log:1: not a CARMEN log"):
        read_carmen(path)


@pytest.mark.parametrize("compress,kind", [(gzip.compress, "gzip"), (bz2.compress, "bz2")])
def test_truncated_compressed_log_names_the_line(tmp_path, compress, kind):
    text = "".join(_flaser([f"{1 + k % 7}.25" for k in range(180)]) + "\n" for _ in range(300))
    data = compress(text.encode())
    path = tmp_path / "x.log.z"
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputFileError, match=rf"x.log.z:\d+: truncated or corrupt {kind} data after line \d+"):
        read_carmen(path)


def test_missing_file(tmp_path):
    with pytest.raises(InputFileError, match="nope.log: file not found"):
        read_carmen(tmp_path / "nope.log")


def test_relations(tmp_path):
    path = tmp_path / "a.relations"
    path.write_text("90.2 90.7 0.42 -0.0007 0 0 0 0.017\n94.3 94.7 0.27 0.06 0 0 0 0.097\n")
    rel = read_relations(path)
    assert np.allclose(rel.t1, [90.2, 94.3]) and np.allclose(rel.delta[0], [0.42, -0.0007, 0.017])
    path.write_text("90.2 90.7 0.42\n")
    with pytest.raises(InputFileError, match="a.relations:1: expected 8 values"):
        read_relations(path)


def _consistency(log, angles, step=5):
    """Share of returns within 5 cm of a return of a scan 3-10 records away (world frame)."""
    from scipy.spatial import cKDTree

    heading = log.pose[:, 2:3] + angles
    x = log.pose[:, 0:1] + log.ranges * np.cos(heading)
    y = log.pose[:, 1:2] + log.ranges * np.sin(heading)
    shares = []
    for i in range(10, len(log) - 10, step):
        p = np.c_[x[i, log.valid[i]], y[i, log.valid[i]]]
        others = [j for j in range(i - 10, i + 11) if abs(j - i) >= 3]
        q = np.concatenate([np.c_[x[j, log.valid[j]], y[j, log.valid[j]]] for j in others])
        shares.append(np.mean(cKDTree(q).query(p)[0] < 0.05))
    return float(np.mean(shares))


def test_intel_beam_order_matches_the_published_map():
    """Walls seen from nearby poses coincide with CARMEN's angles; a mirrored beam order smears them."""
    log = read_carmen(shared_data("carmen_2d", "intel-corrected.log.gz"))
    assert len(log) == 910 and log.ranges.shape == (910, 180)
    assert np.allclose(log.max_range, 81.83)
    k = np.arange(180)
    ours = _consistency(log, carmen_beam_angles(180))
    mirrored = _consistency(log, np.pi / 2 - k * np.pi / 180)
    evenly_180 = _consistency(log, -np.pi / 2 + k * np.pi / 179)
    assert ours > 0.7 and mirrored < 0.2 and ours > evenly_180 + 0.02
