import json
import xml.etree.ElementTree as ET

import numpy as np

from featmap.geo import GeoFrame
from featmap.io.geojson import read_segments_geojson, write_fused_geojson
from featmap.io.html_map import write_html_map
from featmap.io.kml import read_kml, write_kml

FRAME = GeoFrame(49.011, 8.424)
SEGS = np.array([[0.0, 0.0, 30.0, 0.0], [30.0, 0.0, 30.0, -20.0], [-5.5, 12.25, 3.0, 40.0]])


def test_geojson_is_rfc7946_and_round_trips(tmp_path):
    path = write_fused_geojson(tmp_path / "f.geojson", SEGS, np.array([5, 6, 7]), FRAME, "proposed")
    fc = json.loads(path.read_text())
    assert fc["type"] == "FeatureCollection" and len(fc["features"]) == 3
    for feat in fc["features"]:
        assert feat["type"] == "Feature" and feat["geometry"]["type"] == "LineString"
        for lon, lat in feat["geometry"]["coordinates"]:            # [lon, lat] order, WGS84
            assert 8.3 < lon < 8.6 and 48.9 < lat < 49.1
        assert feat["properties"]["method"] == "proposed"
    assert fc["features"][0]["properties"]["length_m"] == 30.0
    back, props = read_segments_geojson(path, FRAME)
    assert np.abs(back - SEGS).max() < 1e-3 and [p["support"] for p in props] == [5, 6, 7]


def test_kml_parses_and_round_trips(tmp_path):
    path = write_kml(tmp_path / "m.kml", {"proposed": (SEGS, np.array([1, 2, 3])), "density": (SEGS[:1], None)},
                     FRAME, trajectory=np.array([[0.0, -5.0], [10.0, -5.0], [20.0, -6.0]]))
    root = ET.parse(path).getroot()
    assert root.tag.endswith("kml")
    layers = read_kml(path, FRAME)
    assert set(layers) == {"proposed", "density", "trajectory"}
    assert np.abs(layers["proposed"] - SEGS).max() < 1e-3 and len(layers["density"]) == 1


def test_html_map_has_every_layer(tmp_path):
    path = write_html_map(tmp_path / "m.html", {"proposed": (SEGS, np.array([1, 2, 3])), "meanshift": (SEGS, np.array([1, 1, 1])),
                                                "density": (SEGS, np.array([4, 4, 4]))}, FRAME,
                          trajectory=np.array([[0.0, -5.0], [10.0, -5.0]]), truth_walls=SEGS)
    html = path.read_text()
    for layer in ("proposed", "meanshift", "density", "trajectory", "truth"):
        assert f'"{layer}"' in html or f"{layer}</span>" in html or layer in html
    assert html.count("L.polyline") >= 3 * 3 + 3 + 1
    assert "support 4 segments" in html and "length 30.00 m" in html
    assert "L.control.layers" in html
