"""Map-quality metrics of ``shared/EVALUATION.md`` against ground-truth building footprints.

Tolerances: ``TOL = 0.30 m``, ``ANG = 10 deg``, sampling step 0.10 m. A point *lies on* a segment
when its perpendicular distance is at most TOL, its projection falls inside the segment extended by
TOL at both ends, and the two directions differ by at most ANG.

Pure functions of arrays: the ground truth itself is read by :mod:`featmap.evaluation.references`
(a simulated drive's ``truth/`` folder, or building footprints such as OpenStreetMap's).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from featmap.geometry import segment_directions

TOL_M = 0.30
ANG_DEG = 10.0
STEP_M = 0.10
MIN_RETURNS = 50            # an observable wall has at least this many LiDAR returns ...
MIN_OBSERVED_M = 2.0        # ... and at least this much of its length observed
CORNER_REACH_M = 1.0        # a wall is "observed up to" a corner when its observed part ends this close to it
CORNER_CAP_CM = 200.0
COVER_M = 1.0               # a fused feature "covers" a wall when at least this much of the wall lies on it
MAX_SCORED_LENGTH_M = 1_000_000.0
"""Walls or segments longer than this in total (1,000 km: ten million samples of STEP_M, ~0.3 GB) are more
than one scoring holds in memory; evaluate refuses them with the file's name instead of running out of memory."""


@dataclass(frozen=True)
class GroundTruth:
    """Ground truth in the local metric frame of a run (metres).

    Attributes:
        walls: (W, 4) building walls ``x1, y1, x2, y2``.
        building: (W,) building id of each wall.
        labels: (W, 2) vertex labels at each wall's two ends ("" when unlabelled).
        observed: per wall, a list of (start, end) metres along the wall that the drive observed.
        n_returns: (W,) LiDAR returns on each wall (-1 when unknown, e.g. footprints from a map).
        other_segments: (S, 4) other structure (fences, car sides) for ``precision_any``.
        poles: (P, 3) ``x, y, radius`` of poles.
    """

    walls: np.ndarray
    building: np.ndarray
    labels: np.ndarray
    observed: list
    n_returns: np.ndarray
    other_segments: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    poles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    def observable(self) -> np.ndarray:
        """(W,) walls the drive actually saw: enough returns and at least 2 m observed."""
        observed_m = np.array([sum(b - a for a, b in iv) for iv in self.observed])
        enough = (self.n_returns < 0) | (self.n_returns >= MIN_RETURNS)
        return enough & (observed_m >= MIN_OBSERVED_M)


# --- geometry of "lies on" --------------------------------------------------------------------------

def sample_segments(segments: np.ndarray, step: float = STEP_M) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points every ``step`` along (K, 4) segments: (samples (S, 2), owner (S,), length weight (S,))."""
    lengths = np.hypot(segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1])
    counts = np.maximum(1, np.ceil(lengths / step).astype(np.int64))
    owner = np.repeat(np.arange(len(segments)), counts)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    t = (np.arange(counts.sum()) - np.repeat(start, counts) + 0.5) / np.repeat(counts, counts)
    p, q = segments[owner, :2], segments[owner, 2:]
    return p + t[:, None] * (q - p), owner, np.repeat(lengths / counts, counts)


def lies_on(points: np.ndarray, directions: np.ndarray, segment: np.ndarray,
            tol: float = TOL_M, ang_deg: float = ANG_DEG) -> tuple[np.ndarray, np.ndarray]:
    """Which (S, 2) points with unit ``directions`` (S, 2) lie on ``segment`` (4,); and their distances."""
    p, q = segment[:2], segment[2:]
    length = np.hypot(*(q - p))
    if length == 0:
        return np.zeros(len(points), bool), np.full(len(points), np.inf)
    u = (q - p) / length
    rel = points - p
    along = rel @ u
    perp = np.abs(rel[:, 0] * u[1] - rel[:, 1] * u[0])
    cos = np.abs(directions @ u)
    ok = (perp <= tol) & (along >= -tol) & (along <= length + tol) & (cos >= np.cos(np.deg2rad(ang_deg)))
    return ok, perp


def walls_near(walls: np.ndarray, points, reach_m: float) -> np.ndarray:
    """(W,) which of the walls (W, 4) have one of the points within about ``reach_m`` of them: at least
    every wall with a point closer than ``reach_m`` (a KD-tree query around each wall's centre).

    ``points``: (P, 2) finite points, or a ``scipy.spatial.cKDTree`` of them."""
    from scipy.spatial import cKDTree

    walls = np.asarray(walls, float).reshape(-1, 4)
    if not isinstance(points, cKDTree):
        points = np.asarray(points, float).reshape(-1, 2)
    tree = points if isinstance(points, cKDTree) else cKDTree(points[np.isfinite(points).all(axis=1)])
    if not len(walls) or not tree.n:
        return np.zeros(len(walls), bool)
    centres = (walls[:, :2] + walls[:, 2:]) / 2
    half = np.hypot(walls[:, 2] - walls[:, 0], walls[:, 3] - walls[:, 1]) / 2
    return tree.query_ball_point(centres, half + reach_m, return_length=True) > 0


def observed_samples(truth: GroundTruth, walls_mask: np.ndarray, step: float = STEP_M):
    """Samples along the observed parts of the selected walls: (points (S, 2), wall index (S,), weight (S,))."""
    pts, owner, weight = [], [], []
    for w in np.flatnonzero(walls_mask):
        p, q = truth.walls[w, :2], truth.walls[w, 2:]
        length = np.hypot(*(q - p))
        u = (q - p) / length
        for a, b in truth.observed[w]:
            a, b = max(0.0, a), min(length, b)
            if b <= a:
                continue
            n = max(1, int(np.ceil((b - a) / step)))
            t = a + (np.arange(n) + 0.5) * (b - a) / n
            pts.append(p + t[:, None] * u)
            owner.append(np.full(n, w))
            weight.append(np.full(n, (b - a) / n))
    if not pts:
        return np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros(0)
    return np.concatenate(pts), np.concatenate(owner), np.concatenate(weight)


def building_samples(segments: np.ndarray, truth: GroundTruth
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Samples every ``STEP_M`` along (K, 4) segments and the building wall each lies on (the nearest one).

    Returns:
        (samples (S, 2), owner (S,) segment index, length weight (S,), unit directions (S, 2),
        wall (S,) index into ``truth.walls`` or -1 where the sample lies on no building wall,
        distance (S,) to that wall in metres, inf where none), in the frame of ``truth``.
    """
    segments = np.asarray(segments, float).reshape(-1, 4)
    samples, owner, weight = sample_segments(segments) if len(segments) else (np.zeros((0, 2)), np.zeros(0, int), np.zeros(0))
    sdir = segment_directions(segments)[owner] if len(segments) else np.zeros((0, 2))
    best = np.full(len(samples), np.inf)
    best_wall = np.full(len(samples), -1)
    for w in np.flatnonzero(walls_near(truth.walls, samples, 2 * TOL_M)):    # (no other wall can hold a sample)
        ok, perp = lies_on(samples, sdir, truth.walls[w])
        better = ok & (perp < best)
        best[better] = perp[better]
        best_wall[better] = w
    return samples, owner, weight, sdir, best_wall, best


def truth_metrics(fused: np.ndarray, truth: GroundTruth) -> dict:
    """All metrics of EVALUATION.md for fused segments (M, 4) in the truth's local frame."""
    fused = np.asarray(fused, float).reshape(-1, 4)
    observable = truth.observable()
    n_obs = int(observable.sum())
    out: dict = {"count": int(len(fused)), "observable_walls": n_obs,
                 "count_ratio": float(len(fused) / n_obs) if n_obs else None}

    # precision / offset: fused samples on building walls (and on any structure)
    samples, owner, weight, sdir, best_wall, best = building_samples(fused, truth)
    on_building = best_wall >= 0
    on_any = on_building.copy()
    for seg in truth.other_segments:
        on_any |= lies_on(samples, sdir, seg)[0]
    for x, y, r in truth.poles:
        on_any |= np.hypot(samples[:, 0] - x, samples[:, 1] - y) <= r + TOL_M
    total = weight.sum()
    out["precision"] = float(weight[on_building].sum() / total) if total > 0 else None
    out["precision_any"] = float(weight[on_any].sum() / total) if total > 0 else None
    out["offset_cm"] = float(100 * np.average(best[on_building], weights=weight[on_building])) if on_building.any() else None

    # recall / redundancy: observed wall samples covered by fused features
    wpts, wown, wweight = observed_samples(truth, observable)
    wdir = segment_directions(truth.walls)[wown] if len(wown) else np.zeros((0, 2))
    covered = np.zeros(len(wpts), bool)
    cover_len: dict[tuple[int, int], float] = {}
    for f, seg in enumerate(fused):
        ok, _ = lies_on(wpts, wdir, seg)
        if not ok.any():
            continue
        covered |= ok
        for w, length in zip(*np.unique(wown[ok], return_counts=True)):
            cover_len[(int(w), f)] = cover_len.get((int(w), f), 0.0) + float(wweight[ok][wown[ok] == w].sum())
    out["recall"] = float(wweight[covered].sum() / wweight.sum()) if len(wweight) else None
    per_wall: dict[int, int] = {}
    for (w, f), length in cover_len.items():
        if length >= COVER_M:
            per_wall[w] = per_wall.get(w, 0) + 1
    covered_walls = [w for w in np.unique(wown[covered])]
    out["redundancy"] = float(np.mean([per_wall.get(int(w), 0) for w in covered_walls])) if covered_walls else None

    # corners and labelled vertices
    ends = fused.reshape(-1, 2)
    corners = _observed_corners(truth, observable)
    if len(corners) and len(ends):
        d = np.hypot(ends[None, :, 0] - corners[:, None, 0], ends[None, :, 1] - corners[:, None, 1]).min(axis=1)
        out["corner_err_cm"] = float(np.mean(np.minimum(100 * d, CORNER_CAP_CM)))
    else:
        out["corner_err_cm"] = None
    out["corners_evaluated"] = int(len(corners))
    out["vertex_error_sum_m"] = vertex_error_sums(fused, truth, best_wall, owner)
    return out


def _observed_corners(truth: GroundTruth, observable: np.ndarray) -> np.ndarray:
    """Building corners whose two walls are both observed up to the corner: (C, 2)."""
    reach: dict[tuple[float, float], list[bool]] = {}
    for w, wall in enumerate(truth.walls):
        length = np.hypot(wall[2] - wall[0], wall[3] - wall[1])
        iv = truth.observed[w]
        at_p = bool(observable[w] and iv and iv[0][0] <= CORNER_REACH_M)
        at_q = bool(observable[w] and iv and iv[-1][1] >= length - CORNER_REACH_M)
        for point, ok in ((wall[:2], at_p), (wall[2:], at_q)):
            reach.setdefault((round(point[0], 3), round(point[1], 3)), []).append(ok)
    return np.array([k for k, v in reach.items() if len(v) >= 2 and all(v)], float).reshape(-1, 2)


def vertex_error_sums(fused: np.ndarray, truth: GroundTruth, sample_wall: np.ndarray, sample_owner: np.ndarray) -> dict:
    """The paper's Table 2: per labelled vertex, the sum of the distances from the vertex to the nearest
    endpoint of the fused feature on each of its two walls (None when a wall has no fused feature).

    A fused feature belongs to the wall most of its on-wall samples lie on.
    """
    if not len(fused):
        assignment = np.zeros(0, np.int64)
    else:
        assignment = np.full(len(fused), -1)
        for f in range(len(fused)):
            walls = sample_wall[(sample_owner == f) & (sample_wall >= 0)]
            if len(walls):
                assignment[f] = np.bincount(walls).argmax()
    out = {}
    for w, (lab_p, lab_q) in enumerate(truth.labels):
        for label, point in ((str(lab_p), truth.walls[w, :2]), (str(lab_q), truth.walls[w, 2:])):
            if not label:
                continue
            members = np.flatnonzero(assignment == w)
            if len(members) == 0:
                dist = None
            else:
                ends = fused[members].reshape(-1, 2)
                dist = float(np.hypot(*(ends - point).T).min())
            prev = out.get(label, 0.0)
            out[label] = None if (dist is None or prev is None) else prev + dist
    return dict(sorted(out.items()))
