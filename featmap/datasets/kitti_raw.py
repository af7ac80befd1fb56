"""KITTI raw drives (real or simulated) through pykitti, checked before pykitti can fail late.

``KittiRawDataset(data_dir, "2011_09_30_drive_0018", frames=slice(0, 100, 2))`` validates the layout
(drive folder, the three calibration files, scan and OXTS counts, ``.bin`` sizes, every OXTS packet)
with one-line :class:`DatasetError` messages naming the file, then hands poses and calibration to
pykitti. Poses are pykitti's: ``T_w_velo = T_w_imu @ inv(T_velo_imu)``, world = the local metric
frame whose origin is the drive's first OXTS packet (always the first frame of the *drive*, so a
frame selection does not move the map). It implements :class:`featmap.datasets.base.ScanSource`
(3D scans, sensor = the velodyne).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from featmap.datasets.base import TIME_GOES_BACK, FrameSource, Scan, SourceNotes, frames_back_in_time, select_frames
from featmap.errors import ConfigError, DatasetError
from featmap.geo import GeoFrame
from featmap.io.kitti_raw import (CALIB_FILES, drive_paths, read_calib_file, read_oxts_packet, read_rigid_calib,
                                  read_timestamps, read_velo_bin)

KITTI_RAW_URL = "https://www.cvlibs.net/datasets/kitti/raw_data.php"
DRIVE_RE = re.compile(r"^(\d{4}_\d{2}_\d{2})_drive_(\d{4})(?:_sync)?$")

# An OXTS packet is flagged as poor GPS when any of these holds (KITTI's OXTS RT3003 conventions).
POOR_NAVSTAT = 4          # navstat below 4: not in full navigation mode
POOR_NUMSATS = 4          # fewer satellites than this
POOR_POS_ACCURACY_M = 0.5


def parse_drive(drive: str, flag: str = "--drive") -> tuple[str, str]:
    """``"2011_09_30_drive_0018"`` -> ``("2011_09_30", "0018")``; ``flag`` names the input in the error."""
    match = DRIVE_RE.match(drive.strip())
    if not match:
        raise DatasetError(f"{flag} {drive!r}: expected YYYY_MM_DD_drive_NNNN, e.g. 2011_09_30_drive_0018")
    return match.group(1), match.group(2)


@dataclass(frozen=True)
class DriveCheck:
    """What validating a drive found."""

    n_frames: int
    bad_scans: dict[int, str] = field(default_factory=dict)     # frame -> reason
    bad_oxts: dict[int, str] = field(default_factory=dict)
    poor_gps: list[int] = field(default_factory=list)


class KittiRawDataset(FrameSource):
    """A KITTI raw drive as a sequence of :class:`Scan` (``len(ds)``, ``ds[i]``).

    Args:
        data_dir: KITTI raw root (contains ``YYYY_MM_DD/``).
        drive: ``YYYY_MM_DD_drive_NNNN``.
        frames: a slice of the drive's frames (default: all), or its text ``"start:stop:step"``.
        skip_bad_scans: leave out frames whose scan or OXTS packet is unreadable (reported in
            ``notes.skipped``) instead of failing.
    """

    kind = "kitti_raw"
    dimension = 3

    def __init__(self, data_dir: str | Path, drive: str, frames: slice | str | None = None,
                 skip_bad_scans: bool = False):
        import pykitti

        self.data_dir = Path(data_dir)
        self.drive = self.name = drive
        self.date, self.drive_id = parse_drive(drive)
        self.calib_dir, self.drive_dir = drive_paths(self.data_dir, self.date, self.drive_id)
        self.skip_bad_scans = skip_bad_scans
        check = self._check_layout()
        bad = set(check.bad_oxts) | set(check.bad_scans)
        wanted = select_frames(check.n_frames, frames, drive)
        bad_wanted = sorted(bad.intersection(wanted))      # a bad frame outside --frames does not matter
        if bad_wanted and not skip_bad_scans:
            frame = bad_wanted[0]
            raise DatasetError(check.bad_oxts.get(frame) or check.bad_scans[frame])
        selected = [k for k in wanted if k not in bad]
        good = [k for k in range(check.n_frames) if k not in bad]
        if not good:
            raise DatasetError(f"{self.drive_dir}: no readable frame")
        skipped = {k: check.bad_oxts.get(k) or check.bad_scans[k] for k in bad_wanted}
        poor_gps = [k for k in check.poor_gps if k not in bad]
        self.notes = SourceNotes(skipped=skipped, flags={"poor_gps": poor_gps} if poor_gps else {})
        self.location = self.drive_dir.resolve()
        try:
            with np.errstate(divide="ignore", invalid="ignore"):    # its stereo baselines divide by the rectified
                # camera projections, which an all-zero camera calibration makes 0 (featmap uses no camera)
                self._raw = pykitti.raw(str(self.data_dir), self.date, self.drive_id,
                                        frames=good if bad else None)
        except Exception as exc:  # pykitti's own failures, after our checks: name the drive
            raise DatasetError(f"{self.drive_dir}: pykitti could not load the drive ({type(exc).__name__}: {exc})") from None
        if not selected:
            raise DatasetError(f"--frames selects no readable frame of {drive} ({check.n_frames} frames)")
        self._position = {frame: i for i, frame in enumerate(good)}
        self.frames = selected
        self.T_velo_imu = np.asarray(self._raw.calib.T_velo_imu)
        self._T_imu_velo = np.linalg.inv(self.T_velo_imu)
        velo_stamps = self.drive_dir / "velodyne_points" / "timestamps.txt"
        # without the scans' own timestamps, the OXTS packets' (one per frame, synchronised with the scans)
        self._stamps = read_timestamps(velo_stamps if velo_stamps.exists() else self.drive_dir / "oxts" / "timestamps.txt")
        back = frames_back_in_time(self._stamps, self.frames)     # (one stamp per frame: _check_layout)
        if back:
            self.notes = replace(self.notes, flags={**self.notes.flags, TIME_GOES_BACK: back})
        first = self._raw.oxts[0].packet
        try:
            self.geo_origin = GeoFrame(float(first.lat), float(first.lon), float(first.alt))
        except ConfigError as exc:
            raise DatasetError(f"{self.drive_dir / 'oxts' / 'data'}: the first OXTS packet: {exc}") from None

    # -- validation -----------------------------------------------------------------------------------
    def _check_layout(self) -> DriveCheck:
        if not self.drive_dir.is_dir():
            raise DatasetError(
                f"drive {self.drive} not found: looked for {self.drive_dir}; get it with "
                f"`featmap download --drive {self.drive} --data-dir {self.data_dir}` or from {KITTI_RAW_URL}")
        for name in CALIB_FILES:
            path = self.calib_dir / name
            if not path.is_file():
                raise DatasetError(f"{path}: calibration file missing (it comes with {self.date}_calib.zip)")
        read_rigid_calib(self.calib_dir / "calib_imu_to_velo.txt")
        read_rigid_calib(self.calib_dir / "calib_velo_to_cam.txt")
        cam = read_calib_file(self.calib_dir / "calib_cam_to_cam.txt")
        for key, size in [("R_rect_00", 9)] + [(f"P_rect_0{k}", 12) for k in range(4)]:
            if key not in cam or cam[key].size != size:
                raise DatasetError(f"{self.calib_dir / 'calib_cam_to_cam.txt'}: '{key}' missing or not {size} numbers")
        velo_dir = self.drive_dir / "velodyne_points" / "data"
        oxts_dir = self.drive_dir / "oxts" / "data"
        for folder in (velo_dir, oxts_dir):
            if not folder.is_dir():
                raise DatasetError(f"{folder}: folder missing from the drive")
        scans = sorted(velo_dir.glob("*.bin"))
        packets = sorted(oxts_dir.glob("*.txt"))
        if not scans:
            raise DatasetError(f"{velo_dir}: no .bin scan files")
        if len(scans) != len(packets):
            raise DatasetError(f"{self.drive_dir}: {len(scans)} scans in velodyne_points/data but {len(packets)} "
                               "OXTS packets in oxts/data; the drive is incomplete (re-download or unzip again)")
        for k, (s, o) in enumerate(zip(scans, packets)):
            for path in (s, o):
                if not (path.stem.isascii() and path.stem.isdigit() and int(path.stem) == k):
                    raise DatasetError(f"{path}: expected frame {k:010d} (files must be numbered 0..N-1)")
        stamps = self.drive_dir / "oxts" / "timestamps.txt"
        if not stamps.is_file():
            raise DatasetError(f"{stamps}: timestamps file missing")
        n_stamps = len(read_timestamps(stamps))
        if n_stamps != len(packets):
            raise DatasetError(f"{stamps}: {n_stamps} timestamps for {len(packets)} OXTS packets")
        velo_stamps = self.drive_dir / "velodyne_points" / "timestamps.txt"
        if velo_stamps.exists() and (n_velo := len(read_timestamps(velo_stamps))) != len(scans):
            raise DatasetError(f"{velo_stamps}: {n_velo} timestamps for {len(scans)} scans")
        bad_scans, bad_oxts, poor = {}, {}, []
        for k, s in enumerate(scans):
            size = s.stat().st_size
            if size == 0:
                bad_scans[k] = f"{s}: empty scan (0 points)"
            elif size % 16:
                bad_scans[k] = f"{s}: truncated scan ({size} bytes is not a multiple of 16 = 4 float32 per point)"
        for k, o in enumerate(packets):
            try:
                p = read_oxts_packet(o)
            except DatasetError as exc:
                bad_oxts[k] = str(exc)
                continue
            if p["navstat"] < POOR_NAVSTAT or p["numsats"] < POOR_NUMSATS or p["pos_accuracy"] > POOR_POS_ACCURACY_M:
                poor.append(k)
        return DriveCheck(len(scans), bad_scans, bad_oxts, poor)

    # -- frames ---------------------------------------------------------------------------------------
    def scan(self, frame: int) -> Scan:
        points = read_velo_bin(self._raw.velo_files[self._position[frame]])
        stamp = float(self._stamps[frame])
        return Scan(index=frame, points=points, T_world_sensor=self.pose(frame), timestamp=stamp)

    def pose(self, frame: int) -> np.ndarray:
        """``T_w_velo = T_w_imu @ inv(T_velo_imu)`` of ``frame`` (pykitti's poses)."""
        return np.asarray(self._raw.oxts[self._position[frame]].T_w_imu) @ self._T_imu_velo


def open_drive_folder(location: str | Path, frames: str | None = None, skip_bad_scans: bool = False,
                      reporter=None) -> KittiRawDataset:
    """A KITTI raw drive from its folder ``ROOT/YYYY_MM_DD/YYYY_MM_DD_drive_NNNN_sync`` (the registry's opener)."""
    folder = Path(location)
    drive = folder.name.removesuffix("_sync")
    if not DRIVE_RE.match(drive.strip()):
        raise DatasetError(f"--source {location}: not a KITTI raw drive folder "
                           "(expected ROOT/YYYY_MM_DD/YYYY_MM_DD_drive_NNNN_sync)")
    return KittiRawDataset(folder.parent.parent, drive, frames, skip_bad_scans)


def drive_folder(data_dir: str | Path, drive: str) -> Path:
    """``DATA_DIR/YYYY_MM_DD/YYYY_MM_DD_drive_NNNN_sync`` of ``drive`` (``--drive`` + ``--data-dir``)."""
    date, drive_id = parse_drive(drive)
    return drive_paths(data_dir, date, drive_id)[1]
