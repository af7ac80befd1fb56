"""What a pose-refinement method takes and returns, how it is registered, and planar corrections.

Refinement works in the world frame's x-y plane. Each scan ``i`` gets a *correction*
``c_i = (dx, dy, dyaw)``: the planar rigid motion that turns the scan about its own sensor position
``o_i`` (the x, y of its input pose) by ``dyaw`` and then moves it by ``(dx, dy)``:

    p' = o_i + (dx, dy) + R(dyaw) (p - o_i)        for every world point p of scan i.

Applied to a pose it is a left multiplication ``T' = C_i @ T`` (z, roll and pitch are untouched), so a
correction of zero is the input pose exactly, and two corrections compose by adding (the anchor
moves with the scan).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from featmap.config import Section


@dataclass(frozen=True)
class RefinementInput:
    """The scans of one run as refinement sees them, all in the world frame of the input poses.

    Attributes:
        segments: (N, 4) every extracted segment ``x1, y1, x2, y2`` in the world frame (input poses).
        scan: (N,) position of each segment's scan in ``poses`` (0..F-1, not the frame number).
        poses: (F, 4, 4) input ``T_world_sensor`` of the scans, in time order.
        timestamps: (F,) seconds of each scan (None: the scans are taken as 1 s apart).
        slam_poses: the poses are a SLAM result (consistent to centimetres), not odometry or GPS/INS:
            the methods then use their ``slam_absolute_*`` priors where set.
    """

    segments: np.ndarray
    scan: np.ndarray
    poses: np.ndarray
    timestamps: np.ndarray | None = None
    slam_poses: bool = False

    def __post_init__(self) -> None:
        seg = np.asarray(self.segments, float).reshape(-1, 4)
        scan = np.asarray(self.scan, np.int64).reshape(-1)
        poses = np.asarray(self.poses, float).reshape(-1, 4, 4)
        if len(seg) != len(scan):
            raise ValueError(f"{len(seg)} segments but {len(scan)} scan indices")
        if len(scan) and (scan.min() < 0 or scan.max() >= len(poses)):
            raise ValueError(f"scan indices must lie in 0..{len(poses) - 1}")
        if self.timestamps is not None and len(self.timestamps) != len(poses):
            raise ValueError(f"{len(self.timestamps)} timestamps for {len(poses)} poses")
        object.__setattr__(self, "segments", seg)
        object.__setattr__(self, "scan", scan)
        object.__setattr__(self, "poses", poses)

    @property
    def n_scans(self) -> int:
        return len(self.poses)

    @property
    def anchors(self) -> np.ndarray:
        """(F, 2) the sensor positions the corrections turn about."""
        return self.poses[:, :2, 3]

    @property
    def yaw(self) -> np.ndarray:
        """(F,) input headings (radians, world frame)."""
        return np.arctan2(self.poses[:, 1, 0], self.poses[:, 0, 0])

    def time_steps(self) -> np.ndarray:
        """(F - 1,) seconds between consecutive scans (1 s each without timestamps). A step that is not
        positive (a repeated or out-of-order timestamp) counts as a tenth of the median step."""
        if self.timestamps is None or self.n_scans < 2:
            return np.ones(max(self.n_scans - 1, 0))
        dt = np.diff(np.asarray(self.timestamps, float))
        positive = dt[dt > 0]
        floor = 0.1 * float(np.median(positive)) if len(positive) else 1.0
        return np.maximum(dt, floor)

    def subset(self, keep: np.ndarray) -> "RefinementInput":
        """The input restricted to the scans at positions ``keep`` (sorted), renumbered 0..len(keep)-1."""
        keep = np.asarray(keep, np.int64)
        new = np.full(self.n_scans, -1, np.int64)
        new[keep] = np.arange(len(keep))
        rows = new[self.scan] >= 0
        return RefinementInput(self.segments[rows], new[self.scan[rows]], self.poses[keep],
                               None if self.timestamps is None else np.asarray(self.timestamps)[keep],
                               slam_poses=self.slam_poses)


@dataclass(frozen=True)
class RefinementResult:
    """What a method found.

    Attributes:
        corrections: (F, 3) ``dx, dy`` (metres) and ``dyaw`` (radians) per scan (see the module doc).
        poses: (F, 4, 4) the refined ``T_world_sensor``.
        iterations: solver iterations run (0 for ``none``).
        matches: segment matches used in the last iteration.
        converged: whether the last update was below the method's tolerance.
        stats: further numbers worth recording (method-specific, JSON-ready).
    """

    corrections: np.ndarray
    poses: np.ndarray
    iterations: int = 0
    matches: int = 0
    converged: bool = True
    stats: dict = field(default_factory=dict)

    @property
    def translation_m(self) -> np.ndarray:
        """(F,) length of each scan's translation correction (metres)."""
        return np.hypot(self.corrections[:, 0], self.corrections[:, 1])

    @property
    def rotation_deg(self) -> np.ndarray:
        """(F,) size of each scan's rotation correction (degrees)."""
        return np.rad2deg(np.abs(self.corrections[:, 2]))


@dataclass(frozen=True)
class RefinementMethod:
    """A refinement method as the registry knows it (:mod:`featmap.refinement.registry`).

    Attributes:
        name: registry key and config section ``refinement.<name>``.
        title: human-readable name.
        config_type: its config section (None for a method without settings).
        refine: ``refine(input, config) -> RefinementResult``.
    """

    name: str
    title: str
    config_type: type[Section] | None
    refine: Callable[[RefinementInput, Any], RefinementResult]


def rotations(angles: np.ndarray) -> np.ndarray:
    """(K, 2, 2) rotation matrices of (K,) angles (radians)."""
    c, s = np.cos(angles), np.sin(angles)
    return np.stack([np.stack([c, -s], axis=-1), np.stack([s, c], axis=-1)], axis=-2)


def correct_points(points: np.ndarray, scan: np.ndarray, anchors: np.ndarray, corrections: np.ndarray) -> np.ndarray:
    """(P, 2) world points of scans ``scan`` (P,) moved by their scans' corrections (F, 3) about ``anchors`` (F, 2)."""
    points = np.asarray(points, float).reshape(-1, 2)
    if not len(points):
        return points.copy()
    o = anchors[scan]
    rot = rotations(corrections[scan, 2])
    return o + corrections[scan, :2] + np.einsum("kij,kj->ki", rot, points - o)


def correct_segments(segments: np.ndarray, scan: np.ndarray, anchors: np.ndarray, corrections: np.ndarray) -> np.ndarray:
    """(N, 4) world segments moved by their scans' corrections (see :func:`correct_points`)."""
    segments = np.asarray(segments, float).reshape(-1, 4)
    return np.column_stack([correct_points(segments[:, :2], scan, anchors, corrections),
                            correct_points(segments[:, 2:], scan, anchors, corrections)])


def apply_corrections(poses: np.ndarray, corrections: np.ndarray) -> np.ndarray:
    """(F, 4, 4) ``C_i @ T_i``: each pose turned by ``dyaw`` about its own x-y position and moved by ``dx, dy``."""
    poses = np.asarray(poses, float).reshape(-1, 4, 4)
    corrections = np.asarray(corrections, float).reshape(-1, 3)
    out = poses.copy()
    rot = rotations(corrections[:, 2])
    out[:, :2, :] = np.einsum("fij,fjk->fik", rot, poses[:, :2, :])
    out[:, :2, 3] = poses[:, :2, 3] + corrections[:, :2]
    return out


def keyframes(poses: np.ndarray, distance_m: float, angle_deg: float) -> np.ndarray:
    """(K,) positions of the scans to refine: the first and last scan, and every scan that moved at least
    ``distance_m`` or turned at least ``angle_deg`` from the previous keyframe (input poses (F, 4, 4))."""
    poses = np.asarray(poses, float).reshape(-1, 4, 4)
    n = len(poses)
    if n <= 2 or (distance_m <= 0 and angle_deg <= 0):
        return np.arange(n)
    xy = poses[:, :2, 3]
    yaw = np.arctan2(poses[:, 1, 0], poses[:, 0, 0])
    max_turn = np.deg2rad(angle_deg)
    keep = [0]
    last = 0
    for k in range(1, n - 1):
        turn = abs(np.mod(yaw[k] - yaw[last] + np.pi, 2 * np.pi) - np.pi)
        if np.hypot(*(xy[k] - xy[last])) >= distance_m or turn >= max_turn:
            keep.append(k)
            last = k
    keep.append(n - 1)
    return np.asarray(keep, np.int64)


def reanchor(corrections: np.ndarray, anchors: np.ndarray, new_anchors: np.ndarray) -> np.ndarray:
    """(K, 3) the same planar motions as ``corrections`` (K, 3) about ``anchors`` (K, 2), expressed about
    ``new_anchors`` (K, 2)."""
    rot = rotations(corrections[:, 2])
    arm = new_anchors - anchors
    d = corrections[:, :2] + np.einsum("kij,kj->ki", rot, arm) - arm
    return np.column_stack([d, corrections[:, 2]])


def interpolate_corrections(anchors: np.ndarray, keys: np.ndarray, key_corrections: np.ndarray) -> np.ndarray:
    """(F, 3) corrections of every scan from those of the keyframes at positions ``keys`` (K,).

    A scan between two keyframes gets the motion of each (re-anchored at its own position),
    blended linearly by its position in the sequence between them; scans outside take the nearest.
    """
    F = len(anchors)
    keys = np.asarray(keys, np.int64)
    if len(keys) == F:
        return np.asarray(key_corrections, float).copy()
    idx = np.arange(F)
    hi = np.clip(np.searchsorted(keys, idx), 1, len(keys) - 1) if len(keys) > 1 else np.zeros(F, np.int64)
    lo = np.maximum(hi - 1, 0)
    ka, kb = keys[lo], keys[hi]
    span = np.maximum(kb - ka, 1)
    w = np.clip((idx - ka) / span, 0.0, 1.0)
    from_a = reanchor(key_corrections[lo], anchors[ka], anchors)
    from_b = reanchor(key_corrections[hi], anchors[kb], anchors)
    return (1 - w)[:, None] * from_a + w[:, None] * from_b


def planar_difference(poses: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(F, 3) ``dx, dy, dyaw`` of each pose relative to ``reference`` (F, 4, 4): position difference in
    the world frame and the heading difference wrapped to (-pi, pi]."""
    poses, reference = np.asarray(poses, float).reshape(-1, 4, 4), np.asarray(reference, float).reshape(-1, 4, 4)
    yaw = np.arctan2(poses[:, 1, 0], poses[:, 0, 0]) - np.arctan2(reference[:, 1, 0], reference[:, 0, 0])
    yaw = np.mod(yaw + np.pi, 2 * np.pi) - np.pi
    return np.column_stack([poses[:, :2, 3] - reference[:, :2, 3], yaw])
