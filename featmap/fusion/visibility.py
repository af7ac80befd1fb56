"""Which share of the scans that could see a cluster's line saw it: the visibility clause of a support filter.

A cluster with few members is weak evidence of a wall when many scans had it in view and only a few of them
returned a segment on it (a tree crown or a parked car, extracted now and then); it is good evidence when
only a few scans could see it at all (a facade seen through a gap between two houses, or around a corner)
and those few all saw it. The count rule (``min_support``) cannot tell the two apart; this clause measures
the share. A scan *could see* a line when its sensor stood on the side of the line its members were seen
from, no farther away than ``RANGE_FACTOR`` times their farthest view, no more obliquely than their most
oblique view plus ``INCIDENCE_SLACK_DEG`` (at least ``MIN_WINDOW_DEG`` from head-on), and the sight line
from the sensor to the line's midpoint crosses no blocker (the features already kept: walls hide what lies
behind them). Approximate by design: one sight line per cluster (to its midpoint), the scans that returned
no segment at all are not counted, and what hides a line is only what the map holds (a parked car or a
tree in front is not in it, so such a line counts as visible).

All positions are in the local metric world frame (metres); numpy in, numpy out.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
from scipy.spatial import cKDTree

RANGE_FACTOR = 1.2
"""A scan could see a line from up to this many times the range of the farthest scan that saw it."""
INCIDENCE_SLACK_DEG = 5.0
"""... and up to this much more obliquely (degrees from head-on) than the most oblique scan that saw it ..."""
MIN_WINDOW_DEG = 60.0
"""... but in any case up to this far from head-on."""
SENSOR_COLUMNS = ("sensor_x", "sensor_y")
"""The per-segment columns (segments.csv, :func:`sensor_columns`) holding the world-frame position of the
sensor when the segment's scan was taken (metres)."""


def sensor_columns(T_world_sensor: np.ndarray, n_segments: int) -> dict[str, np.ndarray]:
    """The ``sensor_x``, ``sensor_y`` columns (each (K,)) of K segments of one scan: the translation of its
    (4, 4) ``T_world_sensor``."""
    return {name: np.full(n_segments, float(T_world_sensor[axis, 3])) for axis, name in enumerate(SENSOR_COLUMNS)}


def sensor_xy_column(columns: Mapping[str, np.ndarray], n_segments: int) -> np.ndarray | None:
    """(N, 2) the sensor positions of N segments from their ``sensor_x`` and ``sensor_y`` columns, or None
    when either is absent.

    Raises:
        ValueError: a column of another length than ``n_segments``.
    """
    if not all(name in columns for name in SENSOR_COLUMNS):
        return None
    xy = np.column_stack([np.asarray(columns[name], dtype=float).reshape(-1) for name in SENSOR_COLUMNS])
    if len(xy) != n_segments:
        raise ValueError(f"sensor_x / sensor_y have {len(xy)} entries for {n_segments} segments")
    return xy


def _crosses_any(start: np.ndarray, end: np.ndarray, blockers: np.ndarray) -> np.ndarray:
    """(K,) whether the sight line from each ``start`` (K, 2) to ``end`` (2,) crosses one of ``blockers``
    (B, 4); a crossing within the sight line's first or last 2 % (at the sensor, or at the line itself)
    does not count."""
    if len(blockers) == 0 or len(start) == 0:
        return np.zeros(len(start), dtype=bool)
    r = (end - start)[:, None, :]                         # (K, 1, 2) sight lines
    a = blockers[None, :, :2]
    s = blockers[None, :, 2:] - blockers[None, :, :2]     # (1, B, 2)
    den = r[..., 0] * s[..., 1] - r[..., 1] * s[..., 0]
    ap = a - start[:, None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ap[..., 0] * s[..., 1] - ap[..., 1] * s[..., 0]) / den
        u = (ap[..., 0] * r[..., 1] - ap[..., 1] * r[..., 0]) / den
    return ((den != 0) & (t > 0.02) & (t < 0.98) & (u >= 0.0) & (u <= 1.0)).any(axis=1)


def seen_share(lines: np.ndarray, labels: np.ndarray, scan: np.ndarray, sensor_xy: np.ndarray,
               candidates: np.ndarray, blockers: np.ndarray) -> np.ndarray:
    """For each candidate cluster, the share of the scans that could see its line (see the module docstring)
    that returned one of its members.

    Args:
        lines: (C, 4) each cluster's fitted line ``x1, y1, x2, y2``.
        labels: (N,) the cluster of each segment (-1: in none).
        scan: (N,) the scan of each segment; sensor_xy: (N, 2) where the sensor stood when it was taken.
        candidates: (C,) bool, the clusters to measure.
        blockers: (B, 4) the features that hide what lies behind them.
    Returns:
        (C,) the share in [0, 1] for each candidate, 0 when no scan of its members sees its midpoint (it lies
        behind a blocker from where it was seen), NaN for the other clusters.
    """
    lines = np.asarray(lines, dtype=float).reshape(-1, 4)
    out = np.full(len(lines), np.nan)
    todo = np.flatnonzero(np.asarray(candidates, dtype=bool))
    if len(todo) == 0:
        return out
    scan_ids, first = np.unique(scan, return_index=True)
    positions = np.asarray(sensor_xy, dtype=float)[first]                 # (S, 2), one per scan
    tree = cKDTree(positions)
    member = labels >= 0
    pairs = np.unique(labels[member] * len(scan_ids) + np.searchsorted(scan_ids, scan[member]))   # (cluster, scan)
    pair_cluster, pair_scan = np.divmod(pairs, len(scan_ids))
    starts = np.searchsorted(pair_cluster, np.arange(len(lines) + 1))
    blockers = np.asarray(blockers, dtype=float).reshape(-1, 4)
    blocker_lo = np.minimum(blockers[:, :2], blockers[:, 2:])
    blocker_hi = np.maximum(blockers[:, :2], blockers[:, 2:])
    cos_floor = np.cos(np.radians(MIN_WINDOW_DEG))
    is_member = np.zeros(len(positions), dtype=bool)          # of the cluster at hand (set and reset per cluster)
    for c in todo:
        seen_by = pair_scan[starts[c]:starts[c + 1]]
        direction = lines[c, 2:] - lines[c, :2]
        length = float(np.hypot(*direction))
        if len(seen_by) == 0 or length == 0:
            out[c] = 0.0
            continue
        mid = (lines[c, :2] + lines[c, 2:]) / 2
        normal = np.array([-direction[1], direction[0]]) / length
        to_sensor = positions[seen_by] - mid
        ranges = np.hypot(to_sensor[:, 0], to_sensor[:, 1])
        side = 1.0 if (to_sensor @ normal).sum() >= 0 else -1.0
        with np.errstate(invalid="ignore", divide="ignore"):
            head_on = np.abs(to_sensor @ normal) / ranges                 # cosine of each view's incidence
        widest = np.nanmin(head_on, initial=1.0)
        cos_limit = min(np.cos(min(np.arccos(np.clip(widest, 0, 1)) + np.radians(INCIDENCE_SLACK_DEG), np.pi / 2)),
                        cos_floor)
        reach = RANGE_FACTOR * float(ranges.max())
        near = np.asarray(tree.query_ball_point(mid, reach), dtype=np.int64)
        rel = positions[near] - mid
        dist = np.hypot(rel[:, 0], rel[:, 1])
        facing = side * (rel @ normal)
        could = near[(facing > 0) & (facing >= cos_limit * dist)]
        in_box = ((blocker_hi >= mid - reach) & (blocker_lo <= mid + reach)).all(axis=1)
        visible = could[~_crosses_any(positions[could], mid, blockers[in_box])]
        is_member[seen_by] = True
        saw = int(is_member[visible].sum())
        is_member[seen_by] = False
        out[c] = saw / len(visible) if saw else 0.0
    return out
