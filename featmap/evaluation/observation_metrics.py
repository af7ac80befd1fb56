"""Per-scan extraction metrics against the simulator's per-scan observations (numpy in, numpy out).

Definitions (tolerances of EVALUATION.md: ``TOL = 0.30 m``, ``ANG = 10 deg``, samples every 0.10 m):

- An **observation** (scan k, wall w) *counts* when scan k hit wall w with at least 50 rays over at
  least 2 m of observed length (:class:`featmap.io.sim_truth.ScanObservations`).
- A sample of an observation's observed stretches *lies on* a segment as in EVALUATION.md: within
  ``TOL`` of it perpendicularly, its projection inside the segment extended by ``TOL`` at both
  ends, the wall and the segment within ``ANG`` of each other.
- Scan k's extraction **returns a segment for** observation (k, w) when one segment of scan k
  (moved to the world frame with the scan's pose) has at least :data:`MATCH_MIN_M` = 1 m of the
  observation's observed length lying on it. **Observation recall** is the share of counting
  observations for which that holds.
- **Per-scan coverage** of an observation: the share of its observed length lying on the union of
  scan k's segments.
- The **drive truth** for fused maps is built from the same observations: a wall's observed part is
  the union of its counting observations' stretches over the selected scans (no range cap), and
  **segment coverage** is the share of that length lying on the union of all scans' segments:
  the recall an ideal fusion of these segments could reach (the ceiling for fusion).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from featmap.evaluation.truth_metrics import ANG_DEG, STEP_M, TOL_M, GroundTruth, observed_samples
from featmap.io.sim_truth import ScanObservations

MATCH_MIN_M = 1.0


@dataclass(frozen=True)
class ObservationMatch:
    """How one extraction did on every observation (O observations).

    Attributes:
        found: (O,) a segment of the observation's scan has >= ``MATCH_MIN_M`` of its observed length on it.
        covered_m: (O,) observed length lying on the union of the scan's segments (metres).
        best_m: (O,) the most observed length lying on a single segment of the scan (metres).
        sampled_m: (O,) the observed length as sampled (metres; equals ``observed_m`` up to rounding).
        min_distance_m: (O,) distance from the scan's sensor to the nearest observed sample (metres).
    """

    found: np.ndarray
    covered_m: np.ndarray
    best_m: np.ndarray
    sampled_m: np.ndarray
    min_distance_m: np.ndarray

    @property
    def coverage(self) -> np.ndarray:
        """(O,) share of each observation's observed length lying on the scan's segments."""
        return np.divide(self.covered_m, self.sampled_m, out=np.zeros(len(self.found)), where=self.sampled_m > 0)


def observation_samples(walls: np.ndarray, obs: ScanObservations, step: float = STEP_M
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Samples every ``step`` along every observed stretch.

    Args:
        walls: (W, 4) walls ``x1, y1, x2, y2`` (the frame the samples come out in).
        obs: the observations (their ``wall`` indexes ``walls``).
    Returns:
        (points (S, 2), observation index (S,), length weight (S,)); zero-length stretches give none.
    """
    counts = np.diff(obs.interval_offset)
    owner_of_interval = np.repeat(np.arange(len(obs)), counts)
    start, end = obs.interval_start, obs.interval_end
    length = end - start
    keep = length > 0
    owner_of_interval, start, length = owner_of_interval[keep], start[keep], length[keep]
    n = np.maximum(1, np.ceil(length / step).astype(np.int64))
    interval = np.repeat(np.arange(len(n)), n)
    first = np.concatenate([[0], np.cumsum(n)[:-1]])
    t = start[interval] + (np.arange(n.sum()) - first[interval] + 0.5) * (length / n)[interval]
    wall = obs.wall[owner_of_interval[interval]]
    p = walls[wall, :2]
    d = walls[wall, 2:] - p
    u = d / np.hypot(d[:, 0], d[:, 1])[:, None]
    return p + t[:, None] * u, owner_of_interval[interval], (length / n)[interval]


def lies_on_matrix(points: np.ndarray, directions: np.ndarray, segments: np.ndarray,
                   tol: float = TOL_M, ang_deg: float = ANG_DEG) -> np.ndarray:
    """(S, K) True where point s (with unit direction ``directions[s]``) lies on segment k (EVALUATION.md)."""
    segments = np.asarray(segments, float).reshape(-1, 4)
    p = segments[:, :2]
    d = segments[:, 2:] - p
    length = np.hypot(d[:, 0], d[:, 1])
    u = d / np.where(length > 0, length, 1.0)[:, None]
    rel = points[:, None, :] - p[None, :, :]
    along = rel[..., 0] * u[None, :, 0] + rel[..., 1] * u[None, :, 1]
    perp = np.abs(rel[..., 0] * u[None, :, 1] - rel[..., 1] * u[None, :, 0])
    cos = np.abs(directions @ u.T)
    return ((perp <= tol) & (along >= -tol) & (along <= length[None, :] + tol)
            & (cos >= np.cos(np.deg2rad(ang_deg))) & (length[None, :] > 0))


def match_observations(walls: np.ndarray, obs: ScanObservations, segments: np.ndarray, segment_scan: np.ndarray,
                       sensor_xy: dict[int, np.ndarray] | None = None, min_match_m: float = MATCH_MIN_M
                       ) -> ObservationMatch:
    """Which observations each scan's extraction returned a segment for.

    Args:
        walls: (W, 4) walls in the frame of ``segments``.
        obs: observations of the scans to score.
        segments: (K, 4) per-scan segments in the same (world) frame.
        segment_scan: (K,) frame of each segment (the same numbering as ``obs.frame``).
        sensor_xy: frame -> (2,) sensor position, for ``min_distance_m`` (NaN without it).
        min_match_m: observed length one segment must cover to count as returned.
    """
    segments = np.asarray(segments, float).reshape(-1, 4)
    segment_scan = np.asarray(segment_scan)
    n_obs = len(obs)
    covered, best = np.zeros(n_obs), np.zeros(n_obs)
    sampled, distance = np.zeros(n_obs), np.full(n_obs, np.nan)
    points, owner, weight = observation_samples(walls, obs)
    if len(points):
        np.add.at(sampled, owner, weight)
    wall_dir = walls[:, 2:] - walls[:, :2]
    wall_dir = wall_dir / np.hypot(wall_dir[:, 0], wall_dir[:, 1])[:, None]
    sample_frame = obs.frame[owner]
    order = np.argsort(sample_frame, kind="stable")
    frames, starts = np.unique(sample_frame[order], return_index=True)
    ends = np.concatenate([starts[1:], [len(order)]])
    seg_order = np.argsort(segment_scan, kind="stable")
    seg_frames, seg_starts = np.unique(segment_scan[seg_order], return_index=True)
    seg_ends = np.concatenate([seg_starts[1:], [len(seg_order)]])
    seg_slice = {int(f): seg_order[a:b] for f, a, b in zip(seg_frames, seg_starts, seg_ends)}
    for frame, a, b in zip(frames, starts, ends):
        idx = order[a:b]
        own = owner[idx]
        if sensor_xy is not None and int(frame) in sensor_xy:
            dist = np.hypot(*(points[idx] - np.asarray(sensor_xy[int(frame)])[:2]).T)
            np.fmin.at(distance, own, dist)
        mine = seg_slice.get(int(frame))
        if mine is None or not len(mine):
            continue
        ok = lies_on_matrix(points[idx], wall_dir[obs.wall[own]], segments[mine])
        w = weight[idx]
        np.add.at(covered, own, np.where(ok.any(axis=1), w, 0.0))
        for k in range(ok.shape[1]):
            on = ok[:, k]
            if on.any():
                per_obs = np.bincount(own[on], weights=w[on], minlength=n_obs)
                np.maximum(best, per_obs, out=best)
    return ObservationMatch(found=best >= min_match_m - 1e-9, covered_m=covered, best_m=best, sampled_m=sampled,
                            min_distance_m=distance)


def merge_intervals(intervals: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """The union of (start, end) intervals, sorted, as disjoint intervals."""
    out: list[list[float]] = []
    for a, b in sorted(intervals):
        if out and a <= out[-1][1]:
            out[-1][1] = max(out[-1][1], b)
        else:
            out.append([a, b])
    return [(a, b) for a, b in out]


def truth_from_observations(base: GroundTruth, obs: ScanObservations, counting: np.ndarray | None = None) -> GroundTruth:
    """``base`` (walls, labels, clutter) with what the scans observed: per wall the union of the stretches of its
    counting observations and the sum of their hits (walls with none are unobserved)."""
    counting = obs.counting() if counting is None else np.asarray(counting, bool)
    per_wall: list[list[tuple[float, float]]] = [[] for _ in range(len(base.walls))]
    hits = np.zeros(len(base.walls), np.int64)
    for o in np.flatnonzero(counting):
        per_wall[obs.wall[o]].extend(obs.intervals(o))
        hits[obs.wall[o]] += obs.n_hits[o]
    return replace(base, observed=[merge_intervals(iv) for iv in per_wall], n_returns=hits)


def union_coverage(segments: np.ndarray, truth: GroundTruth, chunk: int = 64) -> float | None:
    """Share of the observable walls' observed length lying on at least one of ``segments`` (K, 4)."""
    points, wall, weight = observed_samples(truth, truth.observable())
    if not len(points):
        return None
    segments = np.asarray(segments, float).reshape(-1, 4)
    mid = (segments[:, :2] + segments[:, 2:]) / 2
    segments = segments[np.lexsort((mid[:, 1], np.floor(mid[:, 0] / 25.0)))]     # spatially compact chunks
    d = truth.walls[wall, 2:] - truth.walls[wall, :2]
    d = d / np.hypot(d[:, 0], d[:, 1])[:, None]
    covered = np.zeros(len(points), bool)
    for a in range(0, len(segments), chunk):
        part = segments[a:a + chunk]
        todo = np.flatnonzero(~covered)
        if not len(todo):
            break
        lo = np.minimum(part[:, :2], part[:, 2:]).min(axis=0) - TOL_M
        hi = np.maximum(part[:, :2], part[:, 2:]).max(axis=0) + TOL_M
        near = todo[np.all((points[todo] >= lo) & (points[todo] <= hi), axis=1)]
        if len(near):
            covered[near] |= lies_on_matrix(points[near], d[near], part).any(axis=1)
    return float(weight[covered].sum() / weight.sum())
