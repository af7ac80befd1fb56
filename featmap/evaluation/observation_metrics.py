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
- Where that ceiling is lost: the **uncovered stretches** (:func:`uncovered_stretches`), each with the
  views that observed it (how many scans, from how far, how far from head-on), sorted into kinds by
  its best view (:meth:`UncoveredStretches.kind`).
- Where a fused map falls short of the ceiling: :func:`fusion_losses` splits the observed length the
  segments cover and the map does not into what the fusion's support filter dropped and what its fit
  lost, and measures the dropped segments on and off the walls.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from featmap.evaluation.truth_metrics import ANG_DEG, STEP_M, TOL_M, GroundTruth, building_samples, observed_samples
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


def covered_samples(segments: np.ndarray, truth: GroundTruth, chunk: int = 64, samples: tuple | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Samples along the observable walls' observed parts and whether one of ``segments`` (K, 4) covers each.

    ``samples``: those samples, ``observed_samples(truth, truth.observable())``, when made already.

    Returns:
        (points (S, 2), wall index (S,), length weight (S,), covered (S,) bool), in the frame of ``truth``.
    """
    points, wall, weight = observed_samples(truth, truth.observable()) if samples is None else samples
    covered = np.zeros(len(points), bool)
    if not len(points):
        return points, wall, weight, covered
    segments = np.asarray(segments, float).reshape(-1, 4)
    mid = (segments[:, :2] + segments[:, 2:]) / 2
    segments = segments[np.lexsort((mid[:, 1], np.floor(mid[:, 0] / 25.0)))]     # spatially compact chunks
    d = truth.walls[wall, 2:] - truth.walls[wall, :2]
    d = d / np.hypot(d[:, 0], d[:, 1])[:, None]
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
    return points, wall, weight, covered


def union_coverage(segments: np.ndarray, truth: GroundTruth, chunk: int = 64) -> float | None:
    """Share of the observable walls' observed length lying on at least one of ``segments`` (K, 4)."""
    _, _, weight, covered = covered_samples(segments, truth, chunk)
    if not len(weight):
        return None
    return float(weight[covered].sum() / weight.sum())


# --- where coverage is lost -----------------------------------------------------------------------------

GRAZING_VIEW_DEG = 84.0
"""An uncovered stretch is *grazing* when its most head-on view is at least this far from head-on (degrees)."""
FAR_VIEW_M = 80.0
"""... *far* when its nearest view is farther than this (metres) ..."""
FEW_VIEWS = 2
"""... and *few views* when at most this many scans observed it (else *other*)."""
LOSS_KINDS = ("grazing", "far", "few views", "other")
"""The kinds of :meth:`UncoveredStretches.kind`, in the order they are tested."""


@dataclass(frozen=True)
class UncoveredStretches:
    """Stretches of observed wall that no segment covers (U stretches), and how the drive saw each.

    Attributes:
        wall: (U,) wall index; start, end: (U,) metres along the wall (from its first vertex).
        n_views: (U,) counting observations (one per scan) whose observed stretches overlap it.
        nearest_m: (U,) distance from the nearest of those scans' sensor to its midpoint (metres).
        nearest_incidence_deg: (U,) that view's angle from head-on (0 = facing the wall).
        best_incidence_deg: (U,) the smallest angle from head-on of all its views.
        max_hits: (U,) the most rays one of those scans put on the wall (all of it, not the stretch).
        observed_m: the observed length of all the observable walls, covered or not (metres).
    NaN distances and angles (and 0 views) where no view is known (no sensor position for its scans).
    """

    wall: np.ndarray
    start: np.ndarray
    end: np.ndarray
    n_views: np.ndarray
    nearest_m: np.ndarray
    nearest_incidence_deg: np.ndarray
    best_incidence_deg: np.ndarray
    max_hits: np.ndarray
    observed_m: float = 0.0

    def __len__(self) -> int:
        return len(self.wall)

    @property
    def length(self) -> np.ndarray:
        return self.end - self.start

    def kind(self) -> np.ndarray:
        """(U,) how the drive saw each stretch at best (:data:`LOSS_KINDS`): ``grazing`` (every view at least
        :data:`GRAZING_VIEW_DEG` from head-on), else ``far`` (every view beyond :data:`FAR_VIEW_M`), else
        ``few views`` (at most :data:`FEW_VIEWS` scans), else ``other``."""
        out = np.full(len(self), LOSS_KINDS[3], dtype=object)
        out[self.n_views <= FEW_VIEWS] = LOSS_KINDS[2]
        out[self.nearest_m > FAR_VIEW_M] = LOSS_KINDS[1]
        out[self.best_incidence_deg >= GRAZING_VIEW_DEG] = LOSS_KINDS[0]
        return out


def uncovered_stretches(segments: np.ndarray, truth: GroundTruth, obs: ScanObservations,
                        sensor_xy: dict[int, np.ndarray], join_m: float = 2.5 * STEP_M) -> UncoveredStretches:
    """The observed wall length that no segment covers, as stretches, with the views that observed them.

    Args:
        segments: (K, 4) segments in the frame of ``truth`` (e.g. every scan's, for the fusion's ceiling).
        truth: walls and their observed parts (:func:`truth_from_observations` of ``obs``).
        obs: the counting observations behind ``truth`` (their ``wall`` indexes ``truth.walls``).
        sensor_xy: frame -> (2,) sensor position in the same frame.
        join_m: uncovered samples of one wall this close along it form one stretch.
    Returns:
        The stretches, longest first; their lengths add up to the uncovered observed length (to a sample).
    """
    points, wall, weight, covered = covered_samples(segments, truth)
    rows = []
    lost = np.flatnonzero(~covered)
    p_all, q_all = truth.walls[:, :2], truth.walls[:, 2:]
    for w in np.unique(wall[lost]):
        mine = lost[wall[lost] == w]
        p, q = p_all[w], q_all[w]
        u = (q - p) / np.hypot(*(q - p))
        normal = np.array([-u[1], u[0]])
        t = (points[mine] - p) @ u
        order = np.argsort(t)
        t, half = t[order], weight[mine][order] / 2
        cut = np.flatnonzero(np.diff(t) > join_m) + 1
        seen_by = [(o, obs.intervals(o)) for o in np.flatnonzero(obs.wall == w) if int(obs.frame[o]) in sensor_xy]
        for a_idx, b_idx in zip(np.concatenate([[0], cut]), np.concatenate([cut, [len(t)]])):
            a, b = float(t[a_idx] - half[a_idx]), float(t[b_idx - 1] + half[b_idx - 1])
            mid = p + (a + b) / 2 * u
            views = [o for o, intervals in seen_by if any(s < b and e > a for s, e in intervals)]
            if views:
                ray = mid - np.array([np.asarray(sensor_xy[int(obs.frame[o])])[:2] for o in views])
                dist = np.hypot(ray[:, 0], ray[:, 1])
                incidence = np.degrees(np.arccos(np.clip(np.abs(ray @ normal) / np.maximum(dist, 1e-9), 0.0, 1.0)))
                k = int(np.argmin(dist))
                rows.append((w, a, b, len(views), dist[k], incidence[k], incidence.min(), int(obs.n_hits[views].max())))
            else:
                rows.append((w, a, b, 0, np.nan, np.nan, np.nan, 0))
    rows.sort(key=lambda r: r[1] - r[2])
    cols = list(zip(*rows)) if rows else [[]] * 8
    return UncoveredStretches(wall=np.array(cols[0], np.int64), start=np.array(cols[1], float),
                              end=np.array(cols[2], float), n_views=np.array(cols[3], np.int64),
                              nearest_m=np.array(cols[4], float), nearest_incidence_deg=np.array(cols[5], float),
                              best_incidence_deg=np.array(cols[6], float), max_hits=np.array(cols[7], np.int64),
                              observed_m=float(weight.sum()))


# --- where a fused map loses the segments' coverage ------------------------------------------------------

@dataclass(frozen=True)
class FusionLoss:
    """Where a fused map's recall falls short of its input segments' coverage (metres).

    Lengths of observed wall (the observable walls' observed parts, as for recall):

    Attributes:
        observed_m: all of it.
        segments_m: lying on an input segment (segment coverage x ``observed_m``).
        fused_m: lying on a fused feature (recall x ``observed_m``).
        filtered_m: lying on dropped input segments only (on none the fusion kept) and on no fused feature:
            what the fusion's support filter took away.
        fit_m: lying on a kept input segment but on no fused feature: what the clusters' fit lost.
        gained_m: lying on a fused feature but on no input segment.
        dropped_wall_m, dropped_other_m: the dropped segments' own length lying on a building wall and
            elsewhere (summed over the segments, so overlapping views of one place add up).

    ``segments_m - fused_m == filtered_m + fit_m - gained_m`` (to rounding).
    """

    observed_m: float
    segments_m: float
    fused_m: float
    filtered_m: float
    fit_m: float
    gained_m: float
    dropped_wall_m: float
    dropped_other_m: float


def fusion_losses(segments: np.ndarray, dropped: np.ndarray, fused: np.ndarray, truth: GroundTruth) -> FusionLoss:
    """Split the observed wall length the input segments cover and the fused map does not.

    Args:
        segments: (N, 4) the fusion's input segments (every scan's), in the frame of ``truth``.
        dropped: (N,) True for the segments in no fused feature (``FusionResult.labels < 0``).
        fused: (M, 4) the fused map, same frame.
        truth: walls and their observed parts.
    """
    segments = np.asarray(segments, float).reshape(-1, 4)
    dropped = np.asarray(dropped, bool).reshape(-1)
    if len(dropped) != len(segments):
        raise ValueError(f"dropped has {len(dropped)} entries for {len(segments)} segments")
    samples = observed_samples(truth, truth.observable())          # (made once for the three)
    _, _, weight, on_kept = covered_samples(segments[~dropped], truth, samples=samples)
    on_dropped = covered_samples(segments[dropped], truth, samples=samples)[3]
    on_fused = covered_samples(fused, truth, samples=samples)[3]
    on_segment = on_kept | on_dropped
    _, _, seg_weight, _, seg_wall, _ = building_samples(segments[dropped], truth)
    metres = lambda mask: float(weight[mask].sum())  # noqa: E731
    return FusionLoss(observed_m=float(weight.sum()), segments_m=metres(on_segment), fused_m=metres(on_fused),
                      filtered_m=metres(on_dropped & ~on_kept & ~on_fused), fit_m=metres(on_kept & ~on_fused),
                      gained_m=metres(on_fused & ~on_segment),
                      dropped_wall_m=float(seg_weight[seg_wall >= 0].sum()),
                      dropped_other_m=float(seg_weight[seg_wall < 0].sum()))
