"""What every per-scan extractor returns, how it is registered, and how its segments reach the world frame."""

from __future__ import annotations

import time
from dataclasses import dataclass, fields
from typing import Any, Callable

import numpy as np

from featmap.config import Section


@dataclass(frozen=True)
class ScanSegments:
    """Wall segments of one scan, in the sensor frame.

    Attributes:
        segments: (K, 4) ``x1, y1, x2, y2`` in metres, in the sensor's x-y plane (for a 3D LiDAR the
            velodyne frame projected to its x-y plane; for a 2D laser its scan plane).
        n_points: (K,) points supporting each segment (after any down-sampling).
        rms: (K,) root-mean-square distance of those points to the fitted line (metres).
        z_mean: (K,) mean height of each piece's points (3D only, sensor frame): where to lift the
            endpoints before moving them to the world frame. None for a 2D laser.
        z_min, z_max: (K,) vertical extent of each piece (3D only, sensor frame). None for a 2D laser.
        support_points: (P, 2) the scan's structure points in the sensor's x-y plane (every return of a
            2D laser; the wall candidates of a 3D LiDAR), for the truth-free map metric; None when the
            extractor does not provide them.
        max_gap: (K,) the longest stretch of each segment's line between two consecutive returns along it
            (metres): how long a gap in the wall the view could have missed (a far wall seen at grazing
            incidence is sampled in columns metres apart). None when the extractor does not measure it.
    """

    segments: np.ndarray
    n_points: np.ndarray
    rms: np.ndarray
    z_mean: np.ndarray | None = None
    z_min: np.ndarray | None = None
    z_max: np.ndarray | None = None
    support_points: np.ndarray | None = None
    max_gap: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.segments)

    @property
    def dimension(self) -> int:
        return 2 if self.z_mean is None else 3

    def support_points_world(self, T_world_sensor: np.ndarray) -> np.ndarray | None:
        """(P, 2) support points in the world frame's x-y plane (lifted to z = 0 of the sensor), or None."""
        if self.support_points is None:
            return None
        pts = np.column_stack([self.support_points, np.zeros(len(self.support_points))])
        return (pts @ T_world_sensor[:3, :3].T + T_world_sensor[:3, 3])[:, :2]

    @staticmethod
    def empty(dimension: int = 3) -> "ScanSegments":
        z = np.zeros(0) if dimension == 3 else None
        return ScanSegments(np.zeros((0, 4)), np.zeros(0, np.int64), np.zeros(0), z, z, z)

    def arrays(self) -> dict[str, np.ndarray]:
        """The fields that are set, by name (for storing)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}

    @staticmethod
    def from_arrays(arrays: dict[str, np.ndarray]) -> "ScanSegments":
        """Inverse of :meth:`arrays`; raises ValueError when the arrays do not fit together."""
        seg = np.asarray(arrays["segments"], float).reshape(-1, 4)
        k = len(seg)
        out = {}
        for f in fields(ScanSegments):
            if f.name == "segments" or f.name not in arrays:
                continue
            value = np.asarray(arrays[f.name])
            if f.name == "support_points":
                if value.ndim != 2 or value.shape[1] != 2:
                    raise ValueError(f"'support_points' has shape {value.shape}, expected (P, 2)")
            elif value.shape != (k,):
                raise ValueError(f"'{f.name}' has shape {value.shape}, expected ({k},)")
            out[f.name] = value
        if "n_points" not in out or "rms" not in out:
            raise ValueError("'n_points' and 'rms' are required")
        return ScanSegments(segments=seg, **out)


@dataclass(frozen=True)
class Extractor:
    """A per-scan extractor as the registry knows it (:mod:`featmap.extraction.registry`).

    Attributes:
        name: registry key and config section ``extraction.<name>``.
        dimension: 3 for 3D LiDAR scans ((N, 3|4) points), 2 for 2D laser scans ((N, 2) points in beam order).
        config_type: its config section.
        extract: ``extract(points, config) -> ScanSegments`` in the sensor frame.
        version: bump when the same input and config would give different segments (invalidates caches).
    """

    name: str
    dimension: int
    config_type: type[Section]
    extract: Callable[[np.ndarray, Any], ScanSegments]
    version: int = 1


WORLD_FIELDS_3D = ("n_points", "z_min", "z_max", "rms")
WORLD_FIELDS_2D = ("n_points", "rms")


def segments_to_world(scan_segments: ScanSegments, T_world_sensor: np.ndarray) -> np.ndarray:
    """Move a scan's segments to the world frame.

    Each endpoint is lifted to its piece's mean height (0 for a 2D laser), transformed by
    ``T_world_sensor`` (4, 4) and projected to the world's x-y plane. Returns (K, 4) world-frame
    ``x1, y1, x2, y2``.
    """
    seg = scan_segments.segments
    if len(seg) == 0:
        return np.zeros((0, 4))
    z = scan_segments.z_mean if scan_segments.z_mean is not None else np.zeros(len(seg))
    R, t = T_world_sensor[:3, :3], T_world_sensor[:3, 3]
    p1 = np.column_stack([seg[:, 0], seg[:, 1], z]) @ R.T + t
    p2 = np.column_stack([seg[:, 2], seg[:, 3], z]) @ R.T + t
    return np.column_stack([p1[:, :2], p2[:, :2]])


def world_fields(scan_segments: ScanSegments, T_world_sensor: np.ndarray) -> dict[str, np.ndarray]:
    """Per-segment columns that go with the world-frame segments: point counts, rms, (3D) heights
    shifted by the sensor's height in the world frame, and ``max_gap`` when the extractor measures it.
    Each (K,)."""
    if scan_segments.dimension == 2:
        out = {"n_points": scan_segments.n_points, "rms": scan_segments.rms}
    else:
        z_off = T_world_sensor[2, 3]
        out = {"n_points": scan_segments.n_points, "z_min": scan_segments.z_min + z_off,
               "z_max": scan_segments.z_max + z_off, "rms": scan_segments.rms}
    if scan_segments.max_gap is not None:
        out["max_gap"] = scan_segments.max_gap
    return out


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
