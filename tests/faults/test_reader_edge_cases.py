"""Edge cases of the scan and segment readers: a bad record, file name or value is one line naming the file
(and line), never a traceback or a silently wrong result."""

import json

import numpy as np
import pytest

from featmap.errors import DatasetError, InputFileError
from featmap.io.carmen import read_carmen
from featmap.io.kitti_raw import format_oxts_packet, read_oxts_packet, read_timestamps
from featmap.io.segments_csv import read_fused_csv
from tests.faults.conftest import QUIET, cli, one_line_error

TAIL = "1 2 0.5 1 2 0.5 10.5 host 10.6"          # pose, odometry, timestamp, host, logger timestamp


def _flaser(n_declared: int, ranges: list[str], tail: str = TAIL) -> str:
    return f"FLASER {n_declared} " + " ".join(ranges) + " " + tail + "\n"


def _robotlaser(n_declared: int, ranges: list[str], tail: str = "0 0 0 0 0 0 0 0 0 0 0 12.5 host 12.6") -> str:
    return " ".join(["ROBOTLASER1", "0", "-1.0", "2.0", "0.5", "20.0", "0.01", "0", str(n_declared), *ranges,
                     "0", tail]) + "\n"


# --- CARMEN ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("record,needle", [
    # two more ranges than declared: without the check, ranges were read as the pose and the timestamp
    (_flaser(10, ["3"] * 12), "x.log:1: FLASER declares 10 beams but has 22 values after the type"),
    (_robotlaser(5, ["3"] * 5 + ["0", "0"]), "x.log:1: ROBOTLASER1 declares 5 beams but has 30 values after the type"),
])
def test_a_laser_record_with_more_values_than_its_beam_count_is_refused(tmp_path, record, needle):
    path = tmp_path / "x.log"
    path.write_text(record)
    with pytest.raises(InputFileError) as exc:
        read_carmen(path)
    assert needle in str(exc.value)


@pytest.mark.parametrize("tail", ["1 2 0.5 1 2 0.5 10.5", "1 2 0.5 1 2 0.5 10.5 host", TAIL])
def test_laser_records_with_or_without_host_and_logger_timestamp_still_read(tmp_path, tail):
    path = tmp_path / "x.log"
    path.write_text(_flaser(10, ["3"] * 10, tail) + _robotlaser(5, ["3"] * 5))
    log = read_carmen(path)
    assert len(log) == 2 and log.timestamp[0] == 10.5 and np.allclose(log.pose[0], [1, 2, 0.5])


@pytest.mark.parametrize("value", ["1e300", "1e12", "2e4"])
def test_a_laser_range_farther_than_any_laser_reaches_names_its_line(tmp_path, value):
    path = tmp_path / "far.log"
    path.write_text(_flaser(10, ["3"] * 10) + _flaser(10, ["3"] * 9 + [value]) + _flaser(10, ["3"] * 10))
    with pytest.raises(InputFileError, match=r"far.log:2: FLASER: a range of .* m is farther than"):
        read_carmen(path)
    # through the CLI (1e300 used to overflow in the map metric with a traceback)
    one_line_error(cli("run", "--carmen", path, "--out", tmp_path / "r", "--cache-dir", tmp_path / "c",
                       "--workers", "1", *QUIET), "far.log:2: FLASER: a range of")
    assert not (tmp_path / "r").exists()


def test_a_repeated_largest_range_is_still_the_no_return_value(tmp_path):
    path = tmp_path / "x.log"
    path.write_text(_flaser(10, ["3"] * 8 + ["1e300"] * 2) + _flaser(10, ["1e300"] + ["3"] * 9))
    log = read_carmen(path)
    assert log.valid.sum() == 17 and log.max_range[0] == 1e300


# --- KITTI raw ------------------------------------------------------------------------------------------

def _run(root, drive, tmp_path):
    return ["run", "--drive", drive, "--data-dir", root, "--out", tmp_path / "r", "--cache-dir", tmp_path / "c",
            "--workers", "1", *QUIET]


@pytest.mark.parametrize("folder,name", [("velodyne_points", "abc.bin"), ("oxts", "scan_9.txt")])
def test_a_scan_or_oxts_file_not_named_by_its_frame_number_is_one_line(drive_copy, tmp_path, folder, name):
    root, drive = drive_copy
    data = root / drive[:10] / f"{drive}_sync" / folder / "data"
    last = sorted(data.iterdir())[-1]
    last.rename(data / name)
    res = cli(*_run(root, drive, tmp_path))
    one_line_error(res, f"{data / name}: expected frame")


@pytest.mark.parametrize("field,value", [("yaw", 1e300), ("roll", -90.0), ("pitch", 7.0)])
def test_oxts_angles_beyond_a_full_turn_are_refused(tmp_path, field, value):
    # a finite but meaningless angle (or one in degrees) used to give a silently wrong pose
    path = tmp_path / "0000000000.txt"
    path.write_text(format_oxts_packet({"lat": 49.0, "lon": 8.4, "alt": 110.0, field: value, "navstat": 4,
                                        "numsats": 8}))
    with pytest.raises(DatasetError, match=r"0000000000.txt: OXTS roll .* beyond a full turn"):
        read_oxts_packet(path)
    path.write_text(format_oxts_packet({"lat": 49.0, "lon": 8.4, "alt": 110.0, "yaw": -3.14159, "pitch": 0.2}))
    assert read_oxts_packet(path)["yaw"] == -3.14159


@pytest.mark.parametrize("stamp", ["2011-09-26 13:02:25.1e5", "2011-09-26 13:02:25.1_5", "2011-09-26 13:02:25.\u0661",
                                   "2011-09-26 13:02:25."])
def test_a_timestamp_whose_fraction_is_not_digits_is_refused(tmp_path, stamp):
    path = tmp_path / "timestamps.txt"
    path.write_text("2011-09-26 13:02:25.000000000\n" + stamp + "\n", encoding="utf-8")
    with pytest.raises(DatasetError, match=r"timestamps.txt:2: not a KITTI timestamp"):
        read_timestamps(path)


def test_kitti_timestamps_keep_nanoseconds(tmp_path):
    path = tmp_path / "timestamps.txt"
    path.write_text("2011-09-26 13:02:25.964389445\n2011-09-26 13:02:26.064389445\n")
    assert np.allclose(read_timestamps(path), [0.0, 0.1])


@pytest.mark.parametrize("keep", [0, 5])
def test_velodyne_timestamps_that_do_not_match_the_scans_are_one_line(drive_copy, tmp_path, keep):
    root, drive = drive_copy
    stamps = root / drive[:10] / f"{drive}_sync" / "velodyne_points" / "timestamps.txt"
    stamps.write_text("".join(stamps.read_text().splitlines(keepends=True)[:keep]))
    res = cli(*_run(root, drive, tmp_path))
    one_line_error(res, f"{stamps}: {keep} timestamps for 40 scans")


# --- fused maps -----------------------------------------------------------------------------------------

@pytest.mark.parametrize("row,needle", [
    ("1e13,0,0,10,1", "fused.csv: a coordinate beyond 1e+12 m"),
    ("0,0,10,0,1\n3e7,0,3e7,10,1", "fused.csv: the segments span"),
])
def test_a_fused_map_beyond_any_map_of_the_earth_is_one_line(tmp_path, row, needle):
    path = tmp_path / "fused.csv"
    path.write_text("x1,y1,x2,y2,support\n" + row + "\n")
    with pytest.raises(InputFileError, match="fused.csv: "):
        read_fused_csv(path)
    ring = [[8.42, 49.01], [8.4205, 49.01], [8.4205, 49.0105], [8.42, 49.0105], [8.42, 49.01]]
    truth = tmp_path / "fp.geojson"
    truth.write_text(json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {}, "geometry": {"type": "Polygon", "coordinates": [ring]}}]}))
    # evaluate used to try to sample a 1e13 m segment every 10 cm (a MemoryError traceback)
    one_line_error(cli("evaluate", path, "--truth", truth, "--origin", "49.01,8.42"), needle)


def test_a_drive_without_velodyne_timestamps_takes_the_oxts_ones(drive_copy):
    """Not 0.1 s times the frame number: the OXTS packets' timestamps, one per frame, synchronised with the scans."""
    from featmap.datasets import KittiRawDataset

    root, drive = drive_copy
    data = root / drive[:10] / f"{drive}_sync"
    oxts = read_timestamps(data / "oxts" / "timestamps.txt")
    # a 5 Hz drive (0.2 s between frames), so that a fallback of 0.1 s per frame shows
    (data / "oxts" / "timestamps.txt").write_text("".join(f"2011-09-26 13:02:{25 + k // 5:02d}.{(k % 5) * 2 * 10**8 + 7:09d}\n"
                                                          for k in range(len(oxts))))
    (data / "velodyne_points" / "timestamps.txt").unlink()
    ds = KittiRawDataset(root, drive)
    assert ds[0].timestamp == pytest.approx(read_timestamps(data / "oxts" / "timestamps.txt")[0])
    assert ds[13].timestamp - ds[3].timestamp == pytest.approx(2.0, abs=1e-6)


def test_a_fused_map_with_a_support_below_one_names_its_row(tmp_path):
    path = tmp_path / "f.csv"
    path.write_text("x1,y1,x2,y2,support\n0,0,1,0,3\n0,1,1,1,0\n")
    with pytest.raises(InputFileError, match=r"f.csv:3: column 'support': 0 \(a feature is supported by at least one"):
        read_fused_csv(path)


def test_a_carmen_line_of_control_bytes_is_named_without_them(tmp_path):
    path = tmp_path / "x.log"
    path.write_bytes(b"\x00\x01junk 1 2 3\n")
    with pytest.raises(InputFileError) as err:
        read_carmen(path)
    assert "line starts with '\\x00\\x01junk'" in str(err.value) and "\x00" not in str(err.value)


@pytest.mark.parametrize("start,resolution", [("-1.0", "1e308"), ("1e300", "0.01"), ("-1.0", "-7")])
def test_robotlaser_angles_that_are_no_angles_name_their_line(tmp_path, start, resolution):
    # a resolution of 1e308 rad made every beam angle inf and every point NaN, used without a word
    record = _robotlaser(5, ["3"] * 5).replace("ROBOTLASER1 0 -1.0 2.0 0.5", f"ROBOTLASER1 0 {start} 2.0 {resolution}")
    path = tmp_path / "x.log"
    path.write_text(_robotlaser(5, ["3"] * 5) + record)
    with pytest.raises(InputFileError, match=r"x.log:2: ROBOTLASER1: start angle .* must be radians within \+-2 pi"):
        read_carmen(path)
