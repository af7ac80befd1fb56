"""Map-quality metrics of ``shared/EVALUATION.md`` against ground-truth building footprints.

Tolerances: ``TOL = 0.30 m``, ``ANG = 10 deg``, sampling step 0.10 m. A point *lies on* a segment
when its perpendicular distance is at most TOL, its projection falls inside the segment extended by
TOL at both ends, and the two directions differ by at most ANG.

Ground truth comes from a simulated drive's ``truth/`` folder (walls with what the drive observed of
them) or from building footprints in a GeoJSON file (e.g. OpenStreetMap); footprints carry no
observation record, so there every wall counts as observable over its whole length.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from featmap.errors import InputFileError
from featmap.geo import GeoFrame

TOL_M = 0.30
ANG_DEG = 10.0
STEP_M = 0.10
MIN_RETURNS = 50            # an observable wall has at least this many LiDAR returns ...
MIN_OBSERVED_M = 2.0        # ... and at least this much of its length observed
CORNER_REACH_M = 1.0        # a wall is "observed up to" a corner when its observed part ends this close to it
CORNER_CAP_CM = 200.0
COVER_M = 1.0               # a fused feature "covers" a wall when at least this much of the wall lies on it


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


def _transform(points: np.ndarray, src: GeoFrame | None, dst: GeoFrame | None) -> np.ndarray:
    """Move (K, 2) local points from the frame of ``src`` to the frame of ``dst`` (through WGS84)."""
    if src is None or dst is None or (src.lat0_deg == dst.lat0_deg and src.lon0_deg == dst.lon0_deg):
        return points
    lat, lon = src.to_wgs84(points[:, 0], points[:, 1])
    x, y = dst.to_local(lat, lon)
    return np.column_stack([x, y])


def load_truth(truth_dir: str | Path, frame: GeoFrame | None = None, frames: list[int] | None = None) -> GroundTruth:
    """Read a simulated drive's ``truth/`` folder.

    Args:
        truth_dir: the drive's ``truth/`` folder.
        frame: express the truth in this run's local frame (default: the drive's own).
        frames: count only what these frames observed (default: the whole drive).
    """
    truth_dir = Path(truth_dir)
    from featmap.io.jsonfile import read_json

    sim = read_json(truth_dir / "simulation.json", "not found: not a simulated drive's truth/ folder")
    src = GeoFrame(**sim["geo_origin"])
    rows = list(csv.DictReader(open(truth_dir / "walls.csv", newline="")))
    walls = np.array([[float(r[c]) for c in ("x1", "y1", "x2", "y2")] for r in rows]).reshape(-1, 4)
    walls = np.column_stack([_transform(walls[:, :2], src, frame), _transform(walls[:, 2:], src, frame)])
    observed = []
    for r in rows:
        iv = [tuple(float(v) for v in part.split("-")) for part in r["observed_intervals"].split(";") if part]
        observed.append(iv)
    n_returns = np.array([int(r["n_returns"]) for r in rows])
    if frames is not None and (truth_dir / "coverage.npz").exists():
        observed, n_returns = _coverage_of_frames(truth_dir / "coverage.npz", walls, frames)
    objects = read_json(truth_dir / "objects_local.json")["objects"]
    other, poles = [], []
    for obj in objects:
        geom = obj["geometry"]
        if obj["kind"] in ("fence", "hedge"):
            line = np.asarray(geom["coordinates"], float)
            other += [np.concatenate([a, b]) for a, b in zip(line[:-1], line[1:])]
        elif obj["kind"] == "car":
            ring = np.asarray(geom["coordinates"][0], float)
            other += [np.concatenate([ring[k], ring[(k + 1) % len(ring)]]) for k in range(len(ring))]
        elif obj["kind"] == "pole":
            poles.append([*geom["coordinates"], obj.get("radius", 0.15)])
    other = np.asarray(other, float).reshape(-1, 4)
    if len(other):
        other = np.column_stack([_transform(other[:, :2], src, frame), _transform(other[:, 2:], src, frame)])
    poles = np.asarray(poles, float).reshape(-1, 3)
    if len(poles):
        poles[:, :2] = _transform(poles[:, :2], src, frame)
    return GroundTruth(walls=walls, building=np.array([r["building"] for r in rows]),
                       labels=np.array([[r["label_1"], r["label_2"]] for r in rows]).reshape(-1, 2),
                       observed=observed, n_returns=n_returns,
                       other_segments=other, poles=poles)


def _coverage_of_frames(path: Path, walls: np.ndarray, frames: list[int]) -> tuple[list, np.ndarray]:
    """Observed intervals and return counts per wall, counting only ``frames``."""
    from featmap.simulation.simulate import observed_intervals

    data = np.load(path)
    keep = np.isin(data["frame"], np.asarray(frames))
    offset = data["bin_offset"]
    counts = np.bincount(data["bin"][keep], weights=data["count"][keep], minlength=int(offset[-1])).astype(np.int64)
    lengths = np.hypot(walls[:, 2] - walls[:, 0], walls[:, 3] - walls[:, 1])
    observed, n_returns = [], []
    for w in range(len(walls)):
        c = counts[offset[w]:offset[w + 1]]
        observed.append(observed_intervals(c, int(data["min_bin_returns"]), float(data["bin_m"]), float(lengths[w])))
        n_returns.append(int(c.sum()))
    return observed, np.asarray(n_returns)


def truth_from_footprints(path: str | Path, frame: GeoFrame) -> GroundTruth:
    """Building footprints from a GeoJSON FeatureCollection (WGS84 Polygons), every wall fully observable."""
    from featmap.io.jsonfile import read_json

    path = Path(path)
    data = read_json(path)
    if not isinstance(data, dict) or data.get("type") != "FeatureCollection":
        raise InputFileError(path, "expected a GeoJSON FeatureCollection of building Polygons")
    walls, building, labels = [], [], []
    for n, feat in enumerate(data.get("features", [])):
        geom = feat.get("geometry") or {}
        props = feat.get("properties") or {}
        if props.get("kind", "building") != "building":
            continue
        polys = [geom.get("coordinates")] if geom.get("type") == "Polygon" else \
            geom.get("coordinates") if geom.get("type") == "MultiPolygon" else []
        vlabels = props.get("vertex_labels") or []
        for rings in polys:
            for r_index, ring in enumerate(rings):
                ring = np.asarray(ring, float)
                if len(ring) > 1 and np.allclose(ring[0], ring[-1]):
                    ring = ring[:-1]
                x, y = frame.to_local(ring[:, 1], ring[:, 0])
                pts = np.column_stack([x, y])
                for k in range(len(pts)):
                    walls.append(np.concatenate([pts[k], pts[(k + 1) % len(pts)]]))
                    building.append(str(props.get("id", n)))
                    lab = vlabels if (r_index == 0 and len(vlabels) == len(pts)) else [""] * len(pts)
                    labels.append([lab[k], lab[(k + 1) % len(pts)]])
    walls = np.asarray(walls, float).reshape(-1, 4)
    lengths = np.hypot(walls[:, 2] - walls[:, 0], walls[:, 3] - walls[:, 1])
    return GroundTruth(walls=walls, building=np.asarray(building), labels=np.asarray(labels).reshape(-1, 2),
                       observed=[[(0.0, float(L))] for L in lengths], n_returns=np.full(len(walls), -1))


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


def _directions(segments: np.ndarray) -> np.ndarray:
    d = segments[:, 2:] - segments[:, :2]
    n = np.hypot(d[:, 0], d[:, 1])
    return d / np.where(n > 0, n, 1.0)[:, None]


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


def compute_metrics(fused: np.ndarray, truth: GroundTruth) -> dict:
    """All metrics of EVALUATION.md for fused segments (M, 4) in the truth's local frame."""
    fused = np.asarray(fused, float).reshape(-1, 4)
    observable = truth.observable()
    n_obs = int(observable.sum())
    out: dict = {"count": int(len(fused)), "observable_walls": n_obs,
                 "count_ratio": float(len(fused) / n_obs) if n_obs else None}

    # precision / offset: fused samples on building walls (and on any structure)
    samples, owner, weight = sample_segments(fused) if len(fused) else (np.zeros((0, 2)), np.zeros(0, int), np.zeros(0))
    sdir = _directions(fused)[owner] if len(fused) else np.zeros((0, 2))
    best = np.full(len(samples), np.inf)
    best_wall = np.full(len(samples), -1)
    for w, wall in enumerate(truth.walls):
        ok, perp = lies_on(samples, sdir, wall)
        better = ok & (perp < best)
        best[better] = perp[better]
        best_wall[better] = w
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
    wdir = _directions(truth.walls)[wown] if len(wown) else np.zeros((0, 2))
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
        for label, point in ((lab_p, truth.walls[w, :2]), (lab_q, truth.walls[w, 2:])):
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
