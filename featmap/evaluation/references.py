"""Ground truth for :mod:`featmap.evaluation.truth_metrics`, from the references a run can have.

- a simulated drive's ``truth/`` folder (walls with what the drive observed of them);
- building footprints in a GeoJSON file (e.g. OpenStreetMap). They carry no observation record: a run
  keeps the walls near its scans and observes them with its scans' structure points
  (:func:`observed_footprints`: the stretches of a footprint edge that the scans' points lie on), and
  writes those walls and that record beside its map (``footprint_walls.csv``), which
  :func:`footprints_truth` reads back. Without it every wall counts as observable over its whole length,
  and recall is a lower bound.

Both are expressed in the run's local metric frame.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from featmap.errors import ConfigError, InputFileError
from featmap.evaluation.truth_metrics import MIN_OBSERVED_M, TOL_M, GroundTruth, walls_near
from featmap.geo import GeoFrame, open_ring, reproject, reproject_segments
from featmap.io.geojson import features_of, wgs84_position
from featmap.io.jsonfile import read_json
from featmap.io.sim_truth import (COVERAGE_BIN_M, FOOTPRINT_WALLS_FILE, TruthWalls, coverage_of_frames, observed_intervals,
                                  read_objects_local, read_simulation_json, read_walls_csv)


def simulation_frame(truth_dir: str | Path) -> GeoFrame:
    """The local frame of a simulated drive, from its ``truth/simulation.json`` ``geo_origin``; a one-line
    InputFileError naming that file when it is missing, malformed or off the earth."""
    truth_dir = Path(truth_dir)
    sim = read_simulation_json(truth_dir)
    try:
        return GeoFrame(**sim["geo_origin"])
    except (KeyError, TypeError):
        raise InputFileError(truth_dir / "simulation.json", "missing or malformed 'geo_origin'") from None
    except ConfigError as exc:
        raise InputFileError(truth_dir / "simulation.json", f"malformed 'geo_origin' ({exc})") from None


def load_simulator_truth(truth_dir: str | Path, frame: GeoFrame | None = None,
                         frames: list[int] | None = None) -> GroundTruth:
    """A simulated drive's ground truth.

    Args:
        truth_dir: the drive's ``truth/`` folder.
        frame: express the truth in this run's local frame (default: the drive's own).
        frames: count only what these frames observed (default: the whole drive).
    """
    truth_dir = Path(truth_dir)
    src = simulation_frame(truth_dir)
    table = read_walls_csv(truth_dir / "walls.csv")
    frame = frame or src
    walls = reproject_segments(table.walls, src, frame)
    observed, n_returns = table.observed, table.n_returns
    if frames is not None and (truth_dir / "coverage.npz").exists():
        observed, n_returns = coverage_of_frames(truth_dir / "coverage.npz", walls, frames)
    other, poles = [], []
    for obj in read_objects_local(truth_dir):
        geom = obj.get("geometry") or {}
        if obj.get("kind") in ("fence", "hedge"):
            line = np.asarray(geom["coordinates"], float)
            other += [np.concatenate([a, b]) for a, b in zip(line[:-1], line[1:])]
        elif obj.get("kind") == "car":
            ring = np.asarray(geom["coordinates"][0], float)
            other += [np.concatenate([ring[k], ring[(k + 1) % len(ring)]]) for k in range(len(ring))]
        elif obj.get("kind") == "pole":
            poles.append([*geom["coordinates"], obj.get("radius", 0.15)])
    other = reproject_segments(np.asarray(other, float).reshape(-1, 4), src, frame)
    poles = np.asarray(poles, float).reshape(-1, 3)
    if len(poles):
        poles[:, :2] = reproject(poles[:, :2], src, frame)
    return GroundTruth(walls=walls, building=table.building, labels=table.labels, observed=observed,
                       n_returns=n_returns, other_segments=other, poles=poles)


def truth_from_footprints(path: str | Path, frame: GeoFrame) -> GroundTruth:
    """Building footprints from a GeoJSON FeatureCollection (WGS84 Polygons), every wall fully observable.

    Features of another ``kind`` than ``building`` and other geometries are skipped, and so are rings of fewer
    than three distinct vertices (a vertex repeated in a row counts once); a feature that is not an object, or
    whose ``geometry`` or ``properties`` is neither an object nor null, is a one-line error.
    """
    path = Path(path)
    rings, ring_building, ring_labels = [], [], []
    for n, feat in enumerate(features_of(path, read_json(path), "a GeoJSON FeatureCollection of building Polygons")):
        geom = feat.get("geometry") or {}
        props = feat.get("properties") or {}
        if props.get("kind", "building") != "building":
            continue
        polys = [geom.get("coordinates")] if geom.get("type") == "Polygon" else \
            geom.get("coordinates") if geom.get("type") == "MultiPolygon" else []
        if not (isinstance(polys, list) and all(isinstance(rings, list) and all(isinstance(ring, list) for ring in rings)
                                                for rings in polys)):
            raise InputFileError(path, f"feature {n}: a {geom['type']}'s coordinates must be nested lists of rings")
        vlabels = props.get("vertex_labels") or []
        vlabels = vlabels if isinstance(vlabels, list) else []
        for polygon in polys:
            for r_index, ring in enumerate(polygon):
                ring = open_ring(wgs84_position(v, path, n) for v in ring)
                if len(ring) < 3:       # no area: two vertices would make one wall twice, there and back
                    continue
                rings.append(ring)
                ring_building.append(str(props.get("id", n)))
                ring_labels.append(vlabels if (r_index == 0 and len(vlabels) == len(ring)) else None)
    if not rings:
        raise InputFileError(path, "no building Polygon in the FeatureCollection: nothing to score against")
    # every ring's vertices at once: wall k of a ring runs from its vertex k to vertex k + 1 (the last to the first)
    counts = np.array([len(r) for r in rings])
    lonlat = np.array([v for r in rings for v in r], float).reshape(-1, 2)
    x, y = frame.to_local(lonlat[:, 1], lonlat[:, 0])
    points = np.column_stack([x, y])
    first = np.repeat(np.cumsum(counts) - counts, counts)
    size = np.repeat(counts, counts)
    following = first + (np.arange(len(points)) - first + 1) % size
    walls = np.column_stack([points, points[following]])
    labels = np.full((len(walls), 2), "", dtype=object)
    for ring, start, count in zip(ring_labels, np.cumsum(counts) - counts, counts):
        if ring is not None:            # (a label is text: a number or a list in the file is written out)
            names = [str(label) for label in ring]
            labels[start:start + count] = [[names[k], names[(k + 1) % count]] for k in range(count)]
    lengths = np.hypot(walls[:, 2] - walls[:, 0], walls[:, 3] - walls[:, 1])
    return GroundTruth(walls=walls, building=np.repeat(np.asarray(ring_building), counts),
                       labels=labels.astype(str), observed=[[(0.0, float(L))] for L in lengths],
                       n_returns=np.full(len(walls), -1))


VIEW_POINTS_PER_BIN = 2
"""A scan observes a ``COVERAGE_BIN_M`` bin of a footprint wall when at least this many of its structure points
lie in it. Chosen on tuning worlds 11-22 against the simulator's per-scan truth (observations with >= 50 hits
and >= 2 m, no range cap): with 1 the footprints counted 2-62 % more walls than it and the proposed map's
recall fell 0.006-0.17 below the truth's; with 3 they counted up to 25 % fewer walls (recall up to 0.027
above); with 2 they counted 0-37 % more walls and recall stayed within 0.016 of the truth's on 11 of the 12
worlds (world 15: 0.052 below). ``benchmarks/bench_footprints.py`` reports the held-out worlds."""


def observe_walls(truth: GroundTruth, points: np.ndarray, scans: np.ndarray | None = None, tol_m: float = TOL_M,
                  bin_m: float = COVERAGE_BIN_M, min_points: int = VIEW_POINTS_PER_BIN,
                  min_view_m: float = MIN_OBSERVED_M, keep_reach_m: float | None = None) -> GroundTruth:
    """``truth`` with its observation record taken from scan points: what a drive saw of footprint walls.

    The simulator's per-scan rule, with structure points for rays: a point observes a wall when it lies
    within ``tol_m`` of it (perpendicular) and projects inside it; a scan observes a ``bin_m`` bin of the
    wall when at least ``min_points`` of its points observe the wall there; a scan's view of a wall counts
    when it observes at least ``min_view_m`` of it; the wall's observed intervals are the bins that a
    counting view observed. ``n_returns`` is -1 (points are not returns), so a wall is observable when
    its observed part is at least 2 m long.

    Args:
        truth: walls (W, 4) in the run's local frame (e.g. :func:`truth_from_footprints`).
        points: (P, 2) the scans' structure points in the same frame (every return of a 2D laser; the
            wall candidate cells of a 3D LiDAR).
        scans: (P,) the scan of each point; None: all from one scan.
        keep_reach_m: leave out the walls that no point comes this close to (:func:`walls_near`); None:
            keep every wall.
    """
    from scipy.spatial import cKDTree

    points = np.asarray(points, float).reshape(-1, 2)
    scans = np.zeros(len(points), np.int64) if scans is None else np.asarray(scans, np.int64).reshape(-1)
    if len(scans) != len(points):
        raise ValueError(f"{len(points)} points but {len(scans)} scan ids")
    finite = np.isfinite(points).all(axis=1)
    points, scans = points[finite], scans[finite]
    tree = cKDTree(points)
    if keep_reach_m is not None:
        truth = crop_walls(truth, walls_near(truth.walls, tree, keep_reach_m))
    near_any = walls_near(truth.walls, tree, tol_m)
    observed = []
    for wall, reached in zip(np.asarray(truth.walls, float), near_any):
        p, q = wall[:2], wall[2:]
        length = float(np.hypot(*(q - p)))
        if not reached or length == 0:
            observed.append([])
            continue
        u = (q - p) / length
        near = np.asarray(tree.query_ball_point((p + q) / 2, length / 2 + tol_m), np.int64)
        rel = points[near] - p
        along = rel @ u
        on = (np.abs(rel[:, 0] * u[1] - rel[:, 1] * u[0]) <= tol_m) & (along >= 0) & (along < length)
        n_bins = max(1, int(np.ceil(length / bin_m)))
        bins = np.minimum((along[on] / bin_m).astype(np.int64), n_bins - 1)
        scan_bins, count = np.unique(scans[near][on] * n_bins + bins, return_counts=True)
        scan_bins = scan_bins[count >= min_points]                  # (scan, bin) pairs the scan observed
        view, view_bins = np.unique(scan_bins // n_bins, return_counts=True)
        counting = np.isin(scan_bins // n_bins, view[view_bins * bin_m >= min_view_m - 1e-9])
        seen = np.bincount(scan_bins[counting] % n_bins, minlength=n_bins)
        observed.append(observed_intervals(seen, 1, bin_m, length))
    return GroundTruth(walls=truth.walls, building=truth.building, labels=truth.labels, observed=observed,
                       n_returns=np.full(len(truth.walls), -1, np.int64), other_segments=truth.other_segments,
                       poles=truth.poles)


FOOTPRINT_REACH_M = 10.0
"""Footprint walls that no scan point comes this close to are left out of a run's reference (the test,
:func:`walls_near`, errs towards keeping a wall): the drive saw none of them, and no map made from its
scans (whose features lie along the points they were fitted to) has a feature within the metric's 0.3 m
of them. A city-wide footprints file scores as fast as the drive's own area."""


def crop_walls(truth: GroundTruth, keep: np.ndarray) -> GroundTruth:
    """The walls of ``truth`` where the (W,) mask ``keep`` is set, with their records."""
    keep = np.asarray(keep, bool)
    return GroundTruth(walls=truth.walls[keep], building=truth.building[keep], labels=truth.labels[keep],
                       observed=[iv for iv, k in zip(truth.observed, keep) if k],
                       n_returns=np.asarray(truth.n_returns)[keep], other_segments=truth.other_segments,
                       poles=truth.poles)


def file_sha256(path: str | Path) -> str:
    """The SHA-256 of a file's bytes (hex)."""
    import hashlib

    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def observation_record(truth: GroundTruth, footprints: str | Path | None = None) -> TruthWalls:
    """The walls and observation record of ``truth`` as ``walls.csv`` holds them; with the SHA-256 of the
    ``footprints`` file they were made from, when given (:func:`footprints_truth` checks it)."""
    return TruthWalls(truth.walls, truth.building, truth.labels, np.asarray(truth.n_returns, np.int64), truth.observed,
                      file_sha256(footprints) if footprints is not None else "")


def observed_footprints(truth: GroundTruth, points: np.ndarray, scans: np.ndarray | None = None) -> GroundTruth:
    """Footprint walls as a run scores them: those within ``FOOTPRINT_REACH_M`` of its scan points, with
    what the scans observed of them (:func:`observe_walls`; ``points`` (P, 2), ``scans`` (P,) as there)."""
    return observe_walls(truth, points, scans, keep_reach_m=FOOTPRINT_REACH_M)


def footprints_truth(path: str | Path, frame: GeoFrame, run_dir: str | Path | None = None,
                     run_frame: GeoFrame | None = None, whole: GroundTruth | None = None) -> GroundTruth:
    """Building footprints as a run scored them, in ``frame``: the walls and observation record that the run
    (or batch merge) in ``run_dir`` wrote (``footprint_walls.csv``, :func:`observed_footprints`; in its
    local frame ``run_frame``, default ``frame``), else every wall of the footprints, observable whole (a
    run made before runs kept a record, or none given). ``whole``: the footprints already read in ``frame``
    (:func:`truth_from_footprints`), so that several runs' records are checked against one reading.

    Raises:
        InputFileError: the footprints or the record are unreadable, or the record holds walls that are not
            walls of these footprints (they changed since the run: its record is not theirs).
    """
    from scipy.spatial import cKDTree

    record_path = None if run_dir is None else Path(run_dir) / FOOTPRINT_WALLS_FILE
    if record_path is None or not record_path.is_file():
        return whole if whole is not None else truth_from_footprints(path, frame)
    run_frame = run_frame or frame
    record = read_walls_csv(record_path)
    if record.source_sha256 and record.source_sha256 != file_sha256(path):
        raise InputFileError(record_path, f"was made from another version of {path} (changed since the run): "
                                          "run again to score against it, or delete this file to count every wall")
    walls = record.walls if run_frame == frame else reproject_segments(record.walls, run_frame, frame)
    if len(walls):
        whole = whole if whole is not None else truth_from_footprints(path, frame)
        distance, _ = cKDTree(whole.walls).query(walls)
        if not (distance <= 1e-3).all():
            raise InputFileError(record_path, f"holds walls that {path} does not have (changed since the run?): "
                                              "run again to score against it, or delete this file to count every wall")
    return GroundTruth(walls=walls, building=record.building, labels=record.labels, observed=record.observed,
                       n_returns=record.n_returns)


def _union(intervals: list) -> list:
    """Sorted, merged (start, end) intervals."""
    out: list = []
    for a, b in sorted(intervals):
        if out and a <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], b))
        else:
            out.append((a, b))
    return out


def merge_truths(truths: list[GroundTruth], tol_m: float = 0.05) -> GroundTruth:
    """One ground truth for several drives whose truths are already in one local frame.

    A wall of a later truth whose two endpoints lie within ``tol_m`` of a wall of the merged truth (in
    either order) is that wall (simulated drives of one world agree to about a centimetre after
    reprojection, as the simulator anchors every drive's geo origin with the world's Mercator scale): its observed intervals are united and its returns added. Other walls,
    fences, cars and poles are appended (fences, cars and poles seen twice only count twice for
    ``precision_any``'s "lies on", which a duplicate does not change).
    """
    from scipy.spatial import cKDTree

    if not truths:
        raise ValueError("merge_truths needs at least one ground truth")
    first = truths[0]
    walls = [np.asarray(w, float) for w in first.walls]
    building, labels = list(first.building), [list(lab) for lab in first.labels]
    observed = [list(iv) for iv in first.observed]
    n_returns = list(first.n_returns)
    other, poles = [first.other_segments], [first.poles]
    for truth in truths[1:]:
        tree = cKDTree(np.asarray(walls).reshape(-1, 4)) if walls else None
        for k, wall in enumerate(np.asarray(truth.walls, float).reshape(-1, 4)):
            length = float(np.hypot(wall[2] - wall[0], wall[3] - wall[1]))
            match, flipped = None, False
            if tree is not None:
                for candidate, flip in ((wall, False), (np.r_[wall[2:], wall[:2]], True)):
                    dist, index = tree.query(candidate)
                    if dist <= tol_m:
                        match, flipped = int(index), flip
                        break
            iv = [(length - b, length - a) for a, b in truth.observed[k]] if flipped else list(truth.observed[k])
            if match is None:
                walls.append(wall)
                building.append(truth.building[k])
                labels.append(list(truth.labels[k]))
                observed.append(_union(iv))
                n_returns.append(int(truth.n_returns[k]))
            else:
                observed[match] = _union(observed[match] + iv)
                a, b = n_returns[match], int(truth.n_returns[k])
                n_returns[match] = -1 if a < 0 or b < 0 else a + b
        other.append(truth.other_segments)
        poles.append(truth.poles)
    return GroundTruth(walls=np.asarray(walls, float).reshape(-1, 4), building=np.asarray(building),
                       labels=np.asarray(labels, dtype=str).reshape(-1, 2), observed=observed,
                       n_returns=np.asarray(n_returns, np.int64),
                       other_segments=np.concatenate([np.asarray(o, float).reshape(-1, 4) for o in other]),
                       poles=np.concatenate([np.asarray(p, float).reshape(-1, 3) for p in poles]))
