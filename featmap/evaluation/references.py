"""Ground truth for :mod:`featmap.evaluation.truth_metrics`, from the references a run can have.

- a simulated drive's ``truth/`` folder (walls with what the drive observed of them);
- building footprints in a GeoJSON file (e.g. OpenStreetMap): no observation record, so every wall
  counts as observable over its whole length and recall is a lower bound.

Both are expressed in the run's local metric frame.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from featmap.errors import InputFileError
from featmap.evaluation.truth_metrics import GroundTruth
from featmap.geo import GeoFrame
from featmap.io.jsonfile import read_json
from featmap.io.sim_truth import coverage_of_frames, read_objects_local, read_simulation_json, read_walls_csv


def _transform(points: np.ndarray, src: GeoFrame | None, dst: GeoFrame | None) -> np.ndarray:
    """Move (K, 2) local points from the frame of ``src`` to the frame of ``dst`` (through WGS84)."""
    if src is None or dst is None or (src.lat0_deg == dst.lat0_deg and src.lon0_deg == dst.lon0_deg):
        return points
    lat, lon = src.to_wgs84(points[:, 0], points[:, 1])
    x, y = dst.to_local(lat, lon)
    return np.column_stack([x, y])


def _transform_segments(segments: np.ndarray, src: GeoFrame | None, dst: GeoFrame | None) -> np.ndarray:
    if not len(segments):
        return segments
    return np.column_stack([_transform(segments[:, :2], src, dst), _transform(segments[:, 2:], src, dst)])


def load_simulator_truth(truth_dir: str | Path, frame: GeoFrame | None = None,
                         frames: list[int] | None = None) -> GroundTruth:
    """A simulated drive's ground truth.

    Args:
        truth_dir: the drive's ``truth/`` folder.
        frame: express the truth in this run's local frame (default: the drive's own).
        frames: count only what these frames observed (default: the whole drive).
    """
    truth_dir = Path(truth_dir)
    sim = read_simulation_json(truth_dir)
    try:
        src = GeoFrame(**sim["geo_origin"])
    except (KeyError, TypeError):
        raise InputFileError(truth_dir / "simulation.json", "missing or malformed 'geo_origin'") from None
    table = read_walls_csv(truth_dir / "walls.csv")
    walls = _transform_segments(table.walls, src, frame)
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
    other = _transform_segments(np.asarray(other, float).reshape(-1, 4), src, frame)
    poles = np.asarray(poles, float).reshape(-1, 3)
    if len(poles):
        poles[:, :2] = _transform(poles[:, :2], src, frame)
    return GroundTruth(walls=walls, building=table.building, labels=table.labels, observed=observed,
                       n_returns=n_returns, other_segments=other, poles=poles)


def _position(value, path: Path, feature: int) -> tuple[float, float]:
    """A GeoJSON position ``[lon, lat, ...]`` as two finite floats; a one-line error otherwise."""
    try:
        lon, lat = float(value[0]), float(value[1])
        if isinstance(value[0], (str, bool)) or isinstance(value[1], (str, bool)):
            raise TypeError
    except (TypeError, ValueError, IndexError):
        raise InputFileError(path, f"feature {feature}: a position must be [lon, lat] numbers, got {value!r}") from None
    if not (math.isfinite(lon) and math.isfinite(lat)):
        raise InputFileError(path, f"feature {feature}: a position is not finite ({value!r})")
    if not (-180 <= lon <= 180 and -90 <= lat <= 90):
        raise InputFileError(path, f"feature {feature}: position {value!r} is not WGS84 [lon, lat]")
    return lon, lat


def truth_from_footprints(path: str | Path, frame: GeoFrame) -> GroundTruth:
    """Building footprints from a GeoJSON FeatureCollection (WGS84 Polygons), every wall fully observable."""
    path = Path(path)
    data = read_json(path)
    if not isinstance(data, dict) or data.get("type") != "FeatureCollection":
        raise InputFileError(path, "expected a GeoJSON FeatureCollection of building Polygons")
    walls, building, labels = [], [], []
    for n, feat in enumerate(data.get("features") or []):
        if not isinstance(feat, dict):
            raise InputFileError(path, f"feature {n}: expected a GeoJSON Feature object")
        geom = feat.get("geometry") or {}
        props = feat.get("properties") or {}
        if props.get("kind", "building") != "building":
            continue
        polys = [geom.get("coordinates")] if geom.get("type") == "Polygon" else \
            geom.get("coordinates") if geom.get("type") == "MultiPolygon" else []
        vlabels = props.get("vertex_labels") or []
        for rings in polys or []:
            for r_index, ring in enumerate(rings or []):
                ring = np.asarray([_position(v, path, n) for v in ring], float).reshape(-1, 2)
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
