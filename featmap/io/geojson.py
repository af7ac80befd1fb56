"""GeoJSON (RFC 7946: WGS84, ``[lon, lat]``) of segments, fused features and trajectories."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from featmap.errors import InputFileError
from featmap.geo import GeoFrame
from featmap.io.atomic import atomic_write_text
from featmap.io.jsonfile import read_json


def segments_feature_collection(segments: np.ndarray, frame: GeoFrame, properties: list[dict] | None = None,
                                common: dict | None = None) -> dict:
    """A FeatureCollection of LineStrings from local-frame segments (M, 4).

    Every feature gets ``length_m`` plus its entry of ``properties`` and the ``common`` properties.
    """
    segments = np.asarray(segments, float).reshape(-1, 4)
    lat1, lon1 = frame.to_wgs84(segments[:, 0], segments[:, 1])
    lat2, lon2 = frame.to_wgs84(segments[:, 2], segments[:, 3])
    lengths = np.hypot(segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1])
    features = []
    for k in range(len(segments)):
        props = dict(common or {})
        props.update(properties[k] if properties else {})
        props["length_m"] = round(float(lengths[k]), 3)
        features.append({"type": "Feature", "properties": props,
                         "geometry": {"type": "LineString",
                                      "coordinates": [[round(float(lon1[k]), 9), round(float(lat1[k]), 9)],
                                                      [round(float(lon2[k]), 9), round(float(lat2[k]), 9)]]}})
    return {"type": "FeatureCollection", "features": features}


def write_segments_geojson(path: str | Path, segments: np.ndarray, frame: GeoFrame,
                           properties: list[dict] | None = None, common: dict | None = None) -> Path:
    """Write local-frame segments (M, 4) as a WGS84 GeoJSON FeatureCollection of LineStrings (atomically)."""
    fc = segments_feature_collection(segments, frame, properties, common)
    return atomic_write_text(path, json.dumps(fc, indent=None))


def write_fused_geojson(path: str | Path, segments: np.ndarray, support: np.ndarray, frame: GeoFrame,
                        method: str, scans: np.ndarray | None = None) -> Path:
    """``fused_<method>.geojson``: properties ``method``, ``support``, ``length_m`` (and ``scans``: distinct
    scans among the members, when given)."""
    props = [{"support": int(s)} for s in np.asarray(support)]
    if scans is not None:
        for p, n in zip(props, np.asarray(scans)):
            p["scans"] = int(n)
    return write_segments_geojson(path, segments, frame, props, {"method": method})


def read_segments_geojson(path: str | Path, frame: GeoFrame) -> tuple[np.ndarray, list[dict]]:
    """Read LineString features back into local-frame segments (M, 4) and their properties."""
    path = Path(path)
    data = read_json(path)
    if not isinstance(data, dict) or data.get("type") != "FeatureCollection":
        raise InputFileError(path, "expected a GeoJSON FeatureCollection")
    segs, props = [], []
    for n, feat in enumerate(data.get("features", [])):
        geom = feat.get("geometry") or {}
        if geom.get("type") != "LineString" or len(geom.get("coordinates", [])) < 2:
            raise InputFileError(path, f"feature {n}: expected a LineString with two positions")
        (lon1, lat1), (lon2, lat2) = [c[:2] for c in (geom["coordinates"][0], geom["coordinates"][-1])]
        x, y = frame.to_local(np.array([lat1, lat2]), np.array([lon1, lon2]))
        segs.append([x[0], y[0], x[1], y[1]])
        props.append(feat.get("properties") or {})
    return np.asarray(segs, float).reshape(-1, 4), props


def first_position(path: str | Path) -> GeoFrame:
    """A local frame at the first position of a GeoJSON file (for scoring WGS84 files directly)."""
    data = read_json(path)
    for feat in data.get("features", []) if isinstance(data, dict) else []:
        coords = np.asarray((feat.get("geometry") or {}).get("coordinates", []), dtype=object)
        while coords.ndim and len(coords) and not np.isscalar(coords[0]):
            coords = np.asarray(coords[0], dtype=object)
        if len(coords) >= 2:
            return GeoFrame(float(coords[1]), float(coords[0]))
    raise InputFileError(path, "no coordinates")
