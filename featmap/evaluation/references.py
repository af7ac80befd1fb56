"""Ground truth for :mod:`featmap.evaluation.truth_metrics`, from the references a run can have.

- a simulated drive's ``truth/`` folder (walls with what the drive observed of them);
- building footprints in a GeoJSON file (e.g. OpenStreetMap): no observation record, so every wall
  counts as observable over its whole length and recall is a lower bound.

Both are expressed in the run's local metric frame.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from featmap.errors import ConfigError, InputFileError
from featmap.evaluation.truth_metrics import GroundTruth
from featmap.geo import GeoFrame, reproject, reproject_segments
from featmap.io.geojson import features_of, wgs84_position
from featmap.io.jsonfile import read_json
from featmap.io.sim_truth import coverage_of_frames, read_objects_local, read_simulation_json, read_walls_csv


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

    Features of another ``kind`` than ``building`` and other geometries are skipped; a feature that is not an
    object, or whose ``geometry`` or ``properties`` is neither an object nor null, is a one-line error.
    """
    path = Path(path)
    walls, building, labels = [], [], []
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
        for rings in polys:
            for r_index, ring in enumerate(rings):
                ring = np.asarray([wgs84_position(v, path, n) for v in ring], float).reshape(-1, 2)
                if len(ring) > 1 and np.allclose(ring[0], ring[-1]):
                    ring = ring[:-1]
                if len(ring) < 2:
                    continue
                x, y = frame.to_local(ring[:, 1], ring[:, 0])
                pts = np.column_stack([x, y])
                for k in range(len(pts)):
                    walls.append(np.concatenate([pts[k], pts[(k + 1) % len(pts)]]))
                    building.append(str(props.get("id", n)))
                    lab = vlabels if (r_index == 0 and len(vlabels) == len(pts)) else [""] * len(pts)
                    labels.append([lab[k], lab[(k + 1) % len(pts)]])
    if not walls:
        raise InputFileError(path, "no building Polygon in the FeatureCollection: nothing to score against")
    walls = np.asarray(walls, float).reshape(-1, 4)
    lengths = np.hypot(walls[:, 2] - walls[:, 0], walls[:, 3] - walls[:, 1])
    return GroundTruth(walls=walls, building=np.asarray(building), labels=np.asarray(labels).reshape(-1, 2),
                       observed=[[(0.0, float(L))] for L in lengths], n_returns=np.full(len(walls), -1))


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
