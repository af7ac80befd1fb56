"""Reading segments back from GeoJSON: polylines become their consecutive segments; bad files fail in one line."""

import json

import numpy as np
import pytest

from featmap.errors import InputFileError
from featmap.geo import GeoFrame
from featmap.io.geojson import first_position, read_segments_geojson

FRAME = GeoFrame(49.011, 8.424)


def _positions(points):
    lat, lon = FRAME.to_wgs84(np.array([p[0] for p in points], float), np.array([p[1] for p in points], float))
    return [[float(a), float(b)] for a, b in zip(lon, lat)]


def _write(tmp_path, features):
    path = tmp_path / "m.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": features}))
    return path


def test_a_polyline_becomes_its_consecutive_segments(tmp_path):
    path = _write(tmp_path, [
        {"type": "Feature", "properties": {"id": "L"},
         "geometry": {"type": "LineString", "coordinates": _positions([(0, 0), (20, 0), (20, 15)])}},
        {"type": "Feature", "properties": {"id": "M"},
         "geometry": {"type": "MultiLineString", "coordinates": [_positions([(0, 5), (0, 9)]),
                                                                 _positions([(5, 5), (9, 5), (9, 9)])]}},
    ])
    segments, props = read_segments_geojson(path, FRAME)
    expected = [[0, 0, 20, 0], [20, 0, 20, 15], [0, 5, 0, 9], [5, 5, 9, 5], [9, 5, 9, 9]]
    assert segments.shape == (5, 4) and np.abs(segments - expected).max() < 1e-3
    assert [p["id"] for p in props] == ["L", "L", "M", "M", "M"]


@pytest.mark.parametrize("collection,match", [
    ({"type": "FeatureCollection", "features": [None]}, r"m.geojson: feature 0: expected a GeoJSON Feature object"),
    ({"type": "FeatureCollection", "features": {"type": "Feature"}}, r"m.geojson: 'features' must be a list"),
    ({"type": "FeatureCollection", "features": [
        {"type": "Feature", "geometry": {"type": "LineString", "coordinates": [[8.424, 49.011], [8.425, 49.011]]}},
        {"type": "Feature", "geometry": {"type": "LineString", "coordinates": [[8.424, 49.011], [8.425]]}}]},
     r"m.geojson: feature 1: a position must be \[lon, lat\] numbers, got \[8.425\]"),
    ({"type": "FeatureCollection", "features": [{"type": "Feature", "geometry": "LineString"}]},
     r"m.geojson: feature 0: 'geometry' must be an object or null, got str"),
    ({"type": "FeatureCollection", "features": [{"type": "Feature", "geometry": [[8.424, 49.011], [8.425, 49.011]]}]},
     r"m.geojson: feature 0: 'geometry' must be an object or null, got list"),
    ({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": [1], "geometry": {"type": "LineString", "coordinates": [[8.4, 49.0], [8.5, 49.0]]}}]},
     r"m.geojson: feature 0: 'properties' must be an object or null, got list"),
    ({"type": "FeatureCollection", "features": [{"type": "Feature", "geometry": {"type": "Point", "coordinates": [8.4, 49.0]}}]},
     r"m.geojson: feature 0: expected a LineString or MultiLineString geometry, got 'Point'"),
    ({"type": "FeatureCollection", "features": [{"type": "Feature", "geometry": {"type": "LineString", "coordinates": [[8.4, 49.0]]}}]},
     r"m.geojson: feature 0: every line of a LineString needs a list of at least two positions"),
    ({"type": "FeatureCollection", "features": [{"type": "Feature", "geometry": {"type": "MultiLineString", "coordinates": 5}}]},
     r"m.geojson: feature 0: every line of a MultiLineString needs a list of at least two positions"),
    ({"type": "FeatureCollection", "features": [{"type": "Feature", "geometry": {"type": "LineString", "coordinates": [[8.4, 49.0], "x"]}}]},
     r"m.geojson: feature 0: a position must be \[lon, lat\] numbers, got 'x'"),
    ({"type": "FeatureCollection", "features": [{"type": "Feature", "geometry": {"type": "LineString", "coordinates": [[49.0, 8.4], [491.0, 8.4]]}}]},
     r"m.geojson: feature 0: position \[491.0, 8.4\] is not WGS84 \[lon, lat\]"),
    ([1, 2], r"m.geojson: expected a GeoJSON FeatureCollection"),
])
def test_malformed_collections_fail_in_one_line(tmp_path, collection, match):
    path = tmp_path / "m.geojson"
    path.write_text(json.dumps(collection))
    with pytest.raises(InputFileError, match=match):
        read_segments_geojson(path, FRAME)


def test_first_position_skips_features_without_coordinates_and_checks_the_rest(tmp_path):
    ring = _positions([(3, 4), (13, 4), (13, 14), (3, 4)])
    path = _write(tmp_path, [{"type": "Feature", "geometry": None},
                             {"type": "Feature", "geometry": {"type": "Polygon", "coordinates": [ring]}}])
    frame = first_position(path)
    assert abs(frame.lon0_deg - ring[0][0]) < 1e-12 and abs(frame.lat0_deg - ring[0][1]) < 1e-12
    with pytest.raises(InputFileError, match=r"m.geojson: feature 0: expected a GeoJSON Feature object"):
        first_position(_write(tmp_path, [None]))
    with pytest.raises(InputFileError, match=r"m.geojson: feature 0: 'geometry' must be an object or null"):
        first_position(_write(tmp_path, [{"type": "Feature", "geometry": "Polygon"}]))
    with pytest.raises(InputFileError, match=r"m.geojson: feature 0: a position must be \[lon, lat\] numbers"):
        first_position(_write(tmp_path, [{"type": "Feature", "geometry": {"type": "Point", "coordinates": ["8.4", 49.0]}}]))
    with pytest.raises(InputFileError, match=r"m.geojson: feature 0: geo origin latitude 90 is outside"):
        first_position(_write(tmp_path, [{"type": "Feature", "geometry": {"type": "Point", "coordinates": [8.4, 90.0]}}]))
