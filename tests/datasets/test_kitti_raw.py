import numpy as np
import pytest

from featmap.datasets import KittiRawDataset, ScanSource, SourceSpec, open_source, parse_drive, parse_frames
from featmap.errors import DatasetError
from featmap.io.kitti_raw import (OXTS_FIELDS, format_oxts_packet, read_calib_file, read_oxts_packet,
                                  read_rigid_calib, read_velo_bin, write_velo_bin)
from tests.conftest import shared_data


def test_items_match_pykitti_poses(case1_drive):
    import pykitti

    ds = KittiRawDataset(case1_drive.root, case1_drive.drive, parse_frames("5:20:5"))
    assert len(ds) == 3 and ds.frames == [5, 10, 15]
    raw = pykitti.raw(str(case1_drive.root), case1_drive.date, case1_drive.drive_id)
    item = ds[1]
    expected = raw.oxts[10].T_w_imu @ np.linalg.inv(raw.calib.T_velo_imu)
    assert item.index == 10
    assert np.allclose(item.T_world_sensor, expected)
    assert np.allclose(ds.poses()[1], expected)
    assert item.points.shape[1] == 4 and item.points.dtype == np.float32
    assert item.timestamp == pytest.approx(1.0)
    # a frame selection does not move the world frame: it stays at the drive's first packet
    assert np.allclose(KittiRawDataset(case1_drive.root, case1_drive.drive)[10].T_world_sensor, item.T_world_sensor)


def test_it_is_a_scan_source_opened_by_the_registry(case1_drive):
    folder = case1_drive.drive_dir
    ds = open_source(SourceSpec("kitti_raw", str(folder), "0:10:3"))
    assert isinstance(ds, ScanSource)
    assert ds.kind == "kitti_raw" and ds.dimension == 3 and ds.name == case1_drive.drive
    assert ds.location == folder.resolve() and ds.frames == [0, 3, 6, 9]
    assert ds.geo_origin is not None and 48.9 < ds.geo_origin.lat0_deg < 49.1
    with pytest.raises(DatasetError, match="unknown format; allowed: kitti_raw, simulated"):
        open_source(SourceSpec("velodyne_pcap", str(folder)))


def test_frame_selections_past_the_end_are_errors(case1_drive):
    with pytest.raises(DatasetError, match=r"--frames 25:100: .* has 40 frames \(0..39\)"):
        KittiRawDataset(case1_drive.root, case1_drive.drive, "25:100")
    with pytest.raises(DatasetError, match=r"--frames 50: .* has 40 frames"):
        KittiRawDataset(case1_drive.root, case1_drive.drive, "50")
    assert KittiRawDataset(case1_drive.root, case1_drive.drive, "30:").frames == list(range(30, 40))


def test_parse_drive_and_frames():
    assert parse_drive("2011_09_30_drive_0018") == ("2011_09_30", "0018")
    assert parse_frames("0:100:2") == slice(0, 100, 2)
    assert parse_frames(None) is None
    with pytest.raises(DatasetError, match="expected YYYY_MM_DD_drive_NNNN"):
        parse_drive("drive18")
    with pytest.raises(DatasetError, match="step must be positive"):
        parse_frames("0:10:0")


def test_missing_drive_says_where_it_looked_and_how_to_get_it(tmp_path):
    with pytest.raises(DatasetError) as info:
        KittiRawDataset(tmp_path, "2011_09_30_drive_0018")
    msg = str(info.value)
    assert "2011_09_30/2011_09_30_drive_0018_sync" in msg
    assert "featmap download --drive 2011_09_30_drive_0018" in msg and "cvlibs.net" in msg


def _drive_dir(root, drive):
    date = drive[:10]
    return root / date / f"{drive}_sync"


@pytest.mark.parametrize("damage,match", [
    (lambda d, c: (d / "velodyne_points/data/0000000003.bin").write_bytes(b"\0" * 70), r"0000000003.bin: truncated scan \(70 bytes"),
    (lambda d, c: (d / "velodyne_points/data/0000000004.bin").write_bytes(b""), r"0000000004.bin: empty scan"),
    (lambda d, c: (d / "oxts/data/0000000002.txt").write_text("1 2 3\n"), r"0000000002.txt: OXTS packet has 3 fields, expected 30"),
    (lambda d, c: (d / "oxts/data/0000000039.txt").unlink(), r"40 scans .* but 39 OXTS packets"),
    (lambda d, c: (c / "calib_imu_to_velo.txt").write_text("R: 1 0 0\n"), r"calib_imu_to_velo.txt: expected 'R:' with 9 values"),
    (lambda d, c: (c / "calib_velo_to_cam.txt").unlink(), r"calib_velo_to_cam.txt: calibration file missing"),
    (lambda d, c: (c / "calib_cam_to_cam.txt").write_bytes(b"\xff\xfe\x00garbage"), r"calib_cam_to_cam.txt: cannot read"),
    (lambda d, c: (c / "calib_imu_to_velo.txt").write_text("R: 0 0 0 0 0 0 0 0 0\nT: 0 0 0\n"),
     r"calib_imu_to_velo.txt: 'R' is not a rotation matrix"),
    (lambda d, c: (c / "calib_imu_to_velo.txt").write_text("R: 1 0 0 0 1 0 0 0 1\nT: nan 0 0\n"),
     r"calib_imu_to_velo.txt: 'R' and 'T' must be finite"),
])
def test_bad_drives_fail_in_one_line_naming_the_file(drive_copy, damage, match):
    root, drive = drive_copy
    damage(_drive_dir(root, drive), root / drive[:10])
    with pytest.raises(DatasetError, match=match) as info:
        KittiRawDataset(root, drive)
    assert "\n" not in str(info.value)


def test_nan_points_are_caught_when_the_scan_is_read(drive_copy):
    root, drive = drive_copy
    path = _drive_dir(root, drive) / "velodyne_points/data/0000000001.bin"
    pts = read_velo_bin(path).copy()
    pts[5, 1] = np.nan
    write_velo_bin(path, pts)
    ds = KittiRawDataset(root, drive)
    with pytest.raises(DatasetError, match=r"0000000001.bin: 1 point\(s\) with NaN"):
        ds[1]



def test_far_points_are_caught_but_a_large_reflectance_is_not(tmp_path):
    pts = np.zeros((6, 4), np.float32)
    pts[:, 0] = np.arange(6) + 5.0
    pts[2, 3] = 65535.0                          # reflectance as a 16-bit intensity: a value, not a distance
    path = tmp_path / "0000000000.bin"
    write_velo_bin(path, pts)
    np.testing.assert_array_equal(read_velo_bin(path), pts)
    for column, value in ((0, 2e4), (2, -3e4)):
        far = pts.copy()
        far[[1, 4], column] = value
        write_velo_bin(path, far)
        with pytest.raises(DatasetError, match=r"0000000000.bin: 2 point\(s\) farther than 10000 m"):
            read_velo_bin(path)

def test_skip_bad_scans_leaves_them_out(drive_copy):
    root, drive = drive_copy
    d = _drive_dir(root, drive)
    (d / "velodyne_points/data/0000000003.bin").write_bytes(b"\0" * 70)
    (d / "oxts/data/0000000007.txt").write_text("1 2 3\n")
    ds = KittiRawDataset(root, drive, skip_bad_scans=True)
    assert len(ds) == 38 and 3 not in ds.frames and 7 not in ds.frames
    assert set(ds.notes.skipped) == {3, 7}


def test_poor_gps_is_flagged(drive_copy):
    root, drive = drive_copy
    path = _drive_dir(root, drive) / "oxts/data/0000000005.txt"
    packet = read_oxts_packet(path)
    packet.update(numsats=2, pos_accuracy=3.0)
    path.write_text(format_oxts_packet(packet))
    assert KittiRawDataset(root, drive).notes.flags == {"poor_gps": [5]}


def test_parsers_on_real_kitti_files():
    folder = shared_data("kitti_raw_calib_2011_09_26")
    T = read_rigid_calib(folder / "calib_imu_to_velo.txt")
    assert T[:3, 3] == pytest.approx([-0.8086759, 0.3195559, -0.7997231])
    assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-5)
    cam = read_calib_file(folder / "calib_cam_to_cam.txt")
    assert cam["P_rect_02"].size == 12 and cam["R_rect_00"].size == 9
    packet = read_oxts_packet(folder / "oxts_2011_09_26_drive_0001_0000000000.txt")
    assert packet["lat"] == pytest.approx(49.015003823272) and packet["numsats"] == 11
    assert len(packet) == len(OXTS_FIELDS)
    # the writer reproduces what the reader parsed
    assert read_oxts_packet_text(format_oxts_packet(packet)) == packet


def read_oxts_packet_text(text):
    return dict(zip(OXTS_FIELDS, [float(v) for v in text.split()]))


def test_a_bad_scan_outside_the_selected_frames_does_not_matter(drive_copy):
    root, drive = drive_copy
    (root / drive[:10] / f"{drive}_sync" / "velodyne_points" / "data" / "0000000030.bin").write_bytes(b"")
    ds = KittiRawDataset(root, drive, "0:10")
    assert ds.frames == list(range(10)) and ds.notes.skipped == {}
    assert np.allclose(ds.poses(), KittiRawDataset(root, drive, "0:10", skip_bad_scans=True).poses())
    with pytest.raises(DatasetError, match="0000000030.bin: empty scan"):
        KittiRawDataset(root, drive, "25:35")
    ds = KittiRawDataset(root, drive, "25:35", skip_bad_scans=True)
    assert list(ds.notes.skipped) == [30] and 30 not in ds.frames and len(ds) == 9


def test_scans_whose_clock_stepped_back_are_flagged(drive_copy):
    from featmap.datasets.base import TIME_GOES_BACK

    root, drive = drive_copy
    assert KittiRawDataset(root, drive).notes.flags == {}
    stamps = root / drive[:10] / f"{drive}_sync" / "velodyne_points" / "timestamps.txt"
    lines = stamps.read_text().splitlines()
    lines[7] = lines[5]                                        # frame 7 stamped as frame 5
    stamps.write_text("\n".join(lines) + "\n")
    assert KittiRawDataset(root, drive).notes.flags == {TIME_GOES_BACK: [7]}
    assert KittiRawDataset(root, drive, "8:20").notes.flags == {}          # not among the frames selected
