"""CARMEN 2D laser logs (Radish, Freiburg) as a scan source: one scan per FLASER/ROBOTLASER1 record.

``CarmenSource("intel-corrected.log.gz")`` reads the log (:mod:`featmap.io.carmen`) and yields each
scan's valid returns in the laser frame, in beam order, with the record's first pose (the SLAM-corrected
one in the ``*-corrected`` logs, raw odometry in raw ``.clf`` logs) as ``T_world_sensor``. Coordinates
stay in the log's own frame (no geo origin, so a run writes no WGS84 output). A log whose scan poses
are a SLAM result (the ``*-corrected`` logs with their NEFF records, or a log whose ODOM records are all
zero: :attr:`~featmap.io.carmen.CarmenLog.slam_poses`) declares so (``slam_poses``), and pose
refinement holds the map near them (``refinement.pose_graph.slam_absolute_sigma_*``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from featmap.datasets.base import TIME_GOES_BACK, FrameSource, Scan, SourceNotes, frames_back_in_time, select_frames
from featmap.errors import ConfigError
from featmap.io.carmen import read_carmen

SUFFIXES = (".gz", ".bz2", ".log", ".clf")


def pose_matrix(pose: np.ndarray) -> np.ndarray:
    """(4, 4) ``T_world_sensor`` of a 2D pose ``x, y, theta`` (3,)."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:2, 3] = pose[:2]
    return T


def log_name(path: str | Path) -> str:
    """``intel-corrected.log.gz`` -> ``intel-corrected``."""
    name = Path(path).name
    while Path(name).suffix in SUFFIXES:
        name = name[: -len(Path(name).suffix)]
    return name


class CarmenSource(FrameSource):
    """A CARMEN log as a sequence of :class:`Scan` ((N, 2) points, laser frame, beam order).

    Args:
        path: a ``.log``, ``.log.gz``, ``.clf`` or ``.clf.bz2`` file.
        frames: a selection of its scans (``"start:stop:step"`` or a slice; default all).
    """

    kind = "carmen"
    dimension = 2
    geo_origin = None

    def __init__(self, path: str | Path, frames: slice | str | None = None):
        self.log = read_carmen(path)
        self.name = log_name(path)
        self.location = Path(path).resolve()
        self.frames = select_frames(len(self.log), frames, self.name)
        back = frames_back_in_time(self.log.timestamp, self.frames)
        self.notes = SourceNotes(flags={TIME_GOES_BACK: back} if back else {})
        self.slam_poses = self.log.slam_poses
        self._t0 = float(self.log.timestamp[0]) if len(self.log) else 0.0

    def scan(self, frame: int) -> Scan:
        return Scan(index=frame, points=self.log.points(frame), T_world_sensor=self.pose(frame),
                    timestamp=float(self.log.timestamp[frame]) - self._t0)

    def pose(self, frame: int) -> np.ndarray:
        return pose_matrix(self.log.pose[frame])


def open_log(location: str | Path, frames: str | None = None, skip_bad_scans: bool = False,
             reporter=None) -> CarmenSource:
    """The registry's opener. A CARMEN log is one file read whole: there are no per-scan files to skip, so
    ``skip_bad_scans`` is refused (a bad record is reported with its line number, to fix or delete)."""
    if skip_bad_scans:
        raise ConfigError(f"{location}: --skip-bad-scans (skip_bad_scans) leaves out unreadable scan files of a "
                          "drive; a CARMEN log is read whole, and a bad record is reported with its line to fix")
    return CarmenSource(location, frames)
