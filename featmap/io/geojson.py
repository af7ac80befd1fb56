"""GeoJSON (RFC 7946: WGS84, ``[lon, lat]``) of segments, fused features and trajectories."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from featmap.errors import ConfigError, InputFileError
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


def wgs84_position(value, path: Path, feature: int) -> tuple[float, float]:
    """A GeoJSON position ``[lon, lat, ...]`` as two finite WGS84 floats; a one-line error naming the file
    and the feature otherwise."""
    try:
        if not isinstance(value, list) or any(isinstance(v, (str, bool)) for v in value[:2]):
            raise TypeError
        lon, lat = float(value[0]), float(value[1])
    except (TypeError, ValueError, IndexError):
        raise InputFileError(path, f"feature {feature}: a position must be [lon, lat] numbers, got {value!r}") from None
    if not (math.isfinite(lon) and math.isfinite(lat)):
        raise InputFileError(path, f"feature {feature}: a position is not finite ({value!r})")
    if not (-180 <= lon <= 180 and -90 <= lat <= 90):
        raise InputFileError(path, f"feature {feature}: position {value!r} is not WGS84 [lon, lat]")
    return lon, lat


def features_of(path: Path, data, expected: str = "a GeoJSON FeatureCollection") -> list[dict]:
    """The Feature objects of a parsed GeoJSON FeatureCollection (none when ``features`` is absent).

    A one-line error naming the file when ``data`` is not a FeatureCollection (``expected <expected>``), its
    ``features`` is not a list, or a feature is not an object whose ``geometry`` and ``properties`` are
    objects or null.
    """
    if not isinstance(data, dict) or data.get("type") != "FeatureCollection":
        raise InputFileError(path, f"expected {expected}")
    features = data.get("features")
    if features is None:
        return []
    if not isinstance(features, list):
        raise InputFileError(path, f"'features' must be a list of GeoJSON Features, got {type(features).__name__}")
    for n, feat in enumerate(features):
        if not isinstance(feat, dict):
            raise InputFileError(path, f"feature {n}: expected a GeoJSON Feature object, got {json.dumps(feat)[:40]}")
        for key in ("geometry", "properties"):
            if feat.get(key) is not None and not isinstance(feat[key], dict):
                raise InputFileError(path, f"feature {n}: '{key}' must be an object or null, "
                                           f"got {type(feat[key]).__name__}")
    return features


def _lines(path: Path, n: int, geom: dict) -> list[list]:
    """The position lists of a LineString or MultiLineString geometry, each of at least two positions."""
    kind, coords = geom.get("type"), geom.get("coordinates")
    lines = [coords] if kind == "LineString" else coords if kind == "MultiLineString" else None
    if lines is None:
        raise InputFileError(path, f"feature {n}: expected a LineString or MultiLineString geometry, got {kind!r}")
    if not isinstance(lines, list) or not all(isinstance(line, list) and len(line) >= 2 for line in lines):
        raise InputFileError(path, f"feature {n}: every line of a {kind} needs a list of at least two positions")
    return lines


def read_segments_geojson(path: str | Path, frame: GeoFrame) -> tuple[np.ndarray, list[dict]]:
    """Read LineString and MultiLineString features back into local-frame segments (M, 4) and their properties.

    A line of more than two positions gives one segment per pair of consecutive positions, each with the
    feature's properties.
    """
    path = Path(path)
    segs, props = [], []
    for n, feat in enumerate(features_of(path, read_json(path))):
        for line in _lines(path, n, feat.get("geometry") or {}):
            lonlat = np.array([wgs84_position(v, path, n) for v in line], float)
            x, y = frame.to_local(lonlat[:, 1], lonlat[:, 0])
            segs += [[x[k], y[k], x[k + 1], y[k + 1]] for k in range(len(line) - 1)]
            props += [dict(feat.get("properties") or {}) for _ in range(len(line) - 1)]
    return np.asarray(segs, float).reshape(-1, 4), props


def first_position(path: str | Path) -> GeoFrame:
    """A local frame at the first position of a GeoJSON FeatureCollection (for scoring WGS84 files directly)."""
    path = Path(path)
    for n, feat in enumerate(features_of(path, read_json(path))):
        coords = (feat.get("geometry") or {}).get("coordinates")
        while isinstance(coords, list) and coords and isinstance(coords[0], list):
            coords = coords[0]
        if isinstance(coords, list) and coords:
            lon, lat = wgs84_position(coords, path, n)
            try:
                return GeoFrame(lat, lon)
            except ConfigError as exc:       # a pole: the local projection has none
                raise InputFileError(path, f"feature {n}: {exc}") from None
    raise InputFileError(path, "no coordinates")
