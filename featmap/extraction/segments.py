"""What every extractor returns: the wall segments of one scan (velodyne frame), and how to move them.

Kept apart from the extractors so that any of them (and the configuration, which composes their
config models) can import it without importing the others.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ScanSegments:
    """Wall segments of one scan, in the velodyne frame.

    Attributes:
        segments: (K, 4) ``x1, y1, x2, y2`` in metres (velodyne frame, projected to its x-y plane).
        z_mean: (K,) mean height of each piece's points (velodyne frame): where to lift the endpoints
            before moving them to the world frame.
        n_points: (K,) points in each piece (after down-sampling).
        z_min, z_max: (K,) vertical extent of each piece (velodyne frame).
        rms: (K,) root-mean-square distance of the piece's points to its fitted line (metres).
    """

    segments: np.ndarray
    z_mean: np.ndarray
    n_points: np.ndarray
    z_min: np.ndarray
    z_max: np.ndarray
    rms: np.ndarray

    def __len__(self) -> int:
        return len(self.segments)

    @staticmethod
    def empty() -> "ScanSegments":
        z = np.zeros(0)
        return ScanSegments(np.zeros((0, 4)), z, np.zeros(0, np.int64), z, z, z)


def segments_to_world(scan_segments: ScanSegments, T_w_velo: np.ndarray) -> np.ndarray:
    """Move a scan's segments to the world frame.

    Each endpoint is lifted to its piece's mean height, transformed by ``T_w_velo`` (4, 4) and
    projected to the world's x-y plane. Returns (K, 4) world-frame ``x1, y1, x2, y2``.
    """
    seg = scan_segments.segments
    if len(seg) == 0:
        return np.zeros((0, 4))
    R, t = T_w_velo[:3, :3], T_w_velo[:3, 3]
    p1 = np.column_stack([seg[:, 0], seg[:, 1], scan_segments.z_mean]) @ R.T + t
    p2 = np.column_stack([seg[:, 2], seg[:, 3], scan_segments.z_mean]) @ R.T + t
    return np.column_stack([p1[:, :2], p2[:, :2]])


class StageClock:
    """Adds the seconds since the previous lap to ``timings[stage]`` (no-op when timings is None)."""

    def __init__(self, timings: dict[str, float] | None):
        self.timings = timings
        self.last = time.perf_counter()

    def lap(self, stage: str) -> None:
        if self.timings is not None:
            now = time.perf_counter()
            self.timings[stage] = self.timings.get(stage, 0.0) + now - self.last
            self.last = now
