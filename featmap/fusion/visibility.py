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

from featmap.fusion.link_forest import compiled

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


NEAREST_ROUNDS = (32, 512)
"""The other scans are tested nearest first: this many for every candidate still open, each round in one
compiled pass, then every scan within reach of those the rounds leave open."""


@compiled()
def _shares_kernel(positions, todo, pair_start, pair_scan, mids, normals, sides, cos_limits, reaches,
                   near_start, near_scan, near_dist, every_scan_in_range, blockers, blocker_lo, blocker_hi,
                   room_share, is_member, out, decided):
    """For each candidate ``todo[i]`` (its (2,) ``mids[i]``, ``normals[i]``, ``sides[i]``, ``cos_limits[i]``
    and ``reaches[i]``, see :func:`seen_share`): its members' visible views and then the other scans
    ``near_scan[near_start[i]:near_start[i + 1]]`` (at ``near_dist`` from ``mids[i]``, ascending unless
    ``every_scan_in_range[i]``: then they are all the scans within reach), until the share cannot reach
    ``room_share`` (NaN: never). Writes ``out[i]`` and ``decided[i]`` (False when the scans given were all
    within reach, not all of them, and the share could still reach it: more scans must be counted)."""
    n_blockers = blockers.shape[0]
    near_blockers = np.empty(n_blockers, dtype=np.int64)
    for i in range(todo.shape[0]):
        c = todo[i]
        mx, my = mids[i, 0], mids[i, 1]
        nx, ny = normals[i, 0], normals[i, 1]
        reach = reaches[i]
        n_near = 0                                # the blockers whose box meets the square of reach around mid
        for b in range(n_blockers):
            if (blocker_hi[b, 0] >= mx - reach and blocker_hi[b, 1] >= my - reach
                    and blocker_lo[b, 0] <= mx + reach and blocker_lo[b, 1] <= my + reach):
                near_blockers[n_near] = b
                n_near += 1
        saw = 0
        for k in range(pair_start[c], pair_start[c + 1]):
            if _sees(positions[pair_scan[k]], mx, my, nx, ny, sides[i], cos_limits[i], blockers, near_blockers, n_near):
                saw += 1
        if saw == 0:
            out[i] = 0.0
            decided[i] = True
            continue
        room = np.inf
        if not np.isnan(room_share):
            room = np.floor(saw * (1.0 - room_share) / room_share + 1e-9)
        for k in range(pair_start[c], pair_start[c + 1]):
            is_member[pair_scan[k]] = True
        others = 0
        complete = every_scan_in_range[i]
        for j in range(near_start[i], near_start[i + 1]):
            s = near_scan[j]
            if near_dist[j] > reach:
                complete = True
                break
            if is_member[s]:
                continue
            if _sees(positions[s], mx, my, nx, ny, sides[i], cos_limits[i], blockers, near_blockers, n_near):
                others += 1
                if others > room:
                    complete = True
                    break
        for k in range(pair_start[c], pair_start[c + 1]):
            is_member[pair_scan[k]] = False
        out[i] = saw / (saw + others)
        decided[i] = complete


@compiled()
def _sees(xy, mx, my, nx, ny, side, cos_limit, blockers, near_blockers, n_near):
    """Whether a sensor at ``xy`` (2,) could see the midpoint (mx, my) of a line with unit normal (nx, ny)
    from ``side`` within ``cos_limit``, its sight line crossing none of ``blockers[near_blockers[:n_near]]``
    ((B, 4) segments; a crossing within the sight line's first or last 2 %, at the sensor or at the line
    itself, does not count)."""
    rx, ry = xy[0] - mx, xy[1] - my
    facing = side * (rx * nx + ry * ny)
    if not (facing > 0 and facing >= cos_limit * np.hypot(rx, ry)):
        return False
    dx, dy = mx - xy[0], my - xy[1]                   # the sight line, sensor to midpoint
    for q in range(n_near):
        b = near_blockers[q]
        ax, ay = blockers[b, 0], blockers[b, 1]
        sx, sy = blockers[b, 2] - ax, blockers[b, 3] - ay
        den = dx * sy - dy * sx
        if den == 0:
            continue
        px, py = ax - xy[0], ay - xy[1]
        t = (px * sy - py * sx) / den
        u = (px * dy - py * dx) / den
        if t > 0.02 and t < 0.98 and u >= 0.0 and u <= 1.0:
            return False
    return True


def seen_share(lines: np.ndarray, labels: np.ndarray, scan: np.ndarray, sensor_xy: np.ndarray,
               candidates: np.ndarray, blockers: np.ndarray, at_least: float | None = None) -> np.ndarray:
    """For each candidate cluster, the share of the scans that could see its line (see the module docstring)
    that returned one of its members.

    The members' own views are tested first, then the other scans within range, nearest first (the
    ``NEAREST_ROUNDS`` nearest of every candidate still open, each round in one compiled pass, then all of
    them); with ``at_least`` the counting stops as soon as the share cannot reach it, so a
    cluster seen by few of many scans in range (a crown passed by every drive of a revisited street) costs
    about as much as one seen once.

    Args:
        lines: (C, 4) each cluster's fitted line ``x1, y1, x2, y2``.
        labels: (N,) the cluster of each segment (-1: in none).
        scan: (N,) the scan of each segment; sensor_xy: (N, 2) where the sensor stood when it was taken.
        candidates: (C,) bool, the clusters to measure.
        blockers: (B, 4) the features that hide what lies behind them.
        at_least: the share a caller keeps a cluster at, or None. A share below it is then returned as
            some value below it (the share over the scans counted when the counting stopped, an upper bound
            of the true one); a share at or above it is exact, so ``share >= at_least`` decides as the full
            count does.
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
    positions = np.ascontiguousarray(np.asarray(sensor_xy, dtype=float)[first])     # (S, 2), one per scan
    n_scans = len(positions)
    member = np.flatnonzero(labels >= 0)
    member = member[np.isin(labels[member], todo)]          # the candidates' members only
    pairs = np.unique(labels[member] * n_scans + np.searchsorted(scan_ids, scan[member]))   # (cluster, scan)
    pair_cluster, pair_scan = np.divmod(pairs, n_scans)
    pair_start = np.searchsorted(pair_cluster, np.arange(len(lines) + 1))
    blockers = np.ascontiguousarray(np.asarray(blockers, dtype=float).reshape(-1, 4))
    blocker_lo = np.minimum(blockers[:, :2], blockers[:, 2:])
    blocker_hi = np.maximum(blockers[:, :2], blockers[:, 2:])

    # per candidate, from its members' views: the side they saw it from, how obliquely a scan may look, how far
    direction = lines[todo, 2:] - lines[todo, :2]
    length = np.hypot(direction[:, 0], direction[:, 1])
    n_members = pair_start[todo + 1] - pair_start[todo]
    measurable = (n_members > 0) & (length > 0)
    out[todo[~measurable]] = 0.0
    todo, direction, length = todo[measurable], direction[measurable], length[measurable]
    if len(todo) == 0:
        return out
    mids = (lines[todo, :2] + lines[todo, 2:]) / 2
    normals = np.column_stack([-direction[:, 1], direction[:, 0]]) / length[:, None]
    position_in_todo = np.full(len(lines), -1)
    position_in_todo[todo] = np.arange(len(todo))
    of_todo = position_in_todo[pair_cluster] >= 0
    which = position_in_todo[pair_cluster[of_todo]]                     # (P',) the candidate of each of its views
    seen_by = pair_scan[of_todo]
    to_sensor = positions[seen_by] - mids[which]
    ranges = np.hypot(to_sensor[:, 0], to_sensor[:, 1])
    along_normal = np.einsum("ij,ij->i", to_sensor, normals[which])
    sides = np.where(np.bincount(which, along_normal, len(todo)) >= 0, 1.0, -1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        head_on = np.abs(along_normal) / ranges                          # cosine of each view's incidence
    widest = np.ones(len(todo))
    np.fmin.at(widest, which, head_on)                                   # (NaN views, at range 0, skipped)
    slack, floor = np.radians(INCIDENCE_SLACK_DEG), np.cos(np.radians(MIN_WINDOW_DEG))
    cos_limits = np.minimum(np.cos(np.minimum(np.arccos(np.clip(widest, 0, 1)) + slack, np.pi / 2)), floor)
    reaches = np.zeros(len(todo))
    np.maximum.at(reaches, which, ranges)
    reaches *= RANGE_FACTOR

    tree = cKDTree(positions)
    room_share = np.nan if at_least is None else float(at_least)
    is_member = np.zeros(n_scans, dtype=bool)
    share = np.empty(len(todo))
    left = np.arange(len(todo))             # the candidates still open
    for k in (*NEAREST_ROUNDS, None):       # the k nearest scans of each, then every scan within its reach
        if k is not None and k >= n_scans:
            continue
        if k is None:
            in_range = tree.query_ball_point(mids[left], np.nextafter(reaches[left], np.inf),   # (as <= reach)
                                             return_sorted=False)
            counts = np.array([len(scans) for scans in in_range], dtype=np.int64)
            near_scan = np.concatenate([np.asarray(scans, dtype=np.int64) for scans in in_range])
            near_start, near_dist = np.concatenate([[0], np.cumsum(counts)]), np.zeros(len(near_scan))
        else:
            near_dist, near_scan = tree.query(mids[left], k=k)
            near_start, near_scan = np.arange(0, k * len(left) + 1, k), near_scan.reshape(-1).astype(np.int64)
            near_dist = near_dist.reshape(-1)
        part, part_decided = np.empty(len(left)), np.zeros(len(left), dtype=bool)
        _shares_kernel(positions, todo[left], pair_start, pair_scan, mids[left], normals[left], sides[left],
                       cos_limits[left], reaches[left], near_start, near_scan, near_dist,
                       np.full(len(left), k is None), blockers, blocker_lo, blocker_hi, room_share, is_member,
                       part, part_decided)
        share[left] = part
        left = left[~part_decided]
        if len(left) == 0:
            break
    out[todo] = share
    return out


def prepare() -> None:
    """Load the compiled code of :func:`seen_share` (a one-off cost per process; from numba's disk cache
    when it has one)."""
    seen_share(np.array([[0.0, 5.0, 2.0, 5.0]]), np.array([0, -1]), np.array([0, 1]),
               np.array([[1.0, 0.0], [3.0, 0.0]]), np.array([True]), np.array([[0.0, 2.0, 2.0, 2.5]]), 0.5)
