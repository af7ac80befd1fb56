import json
import xml.etree.ElementTree as ET

import numpy as np

from featmap.geo import GeoFrame
from featmap.io.geojson import read_segments_geojson, write_fused_geojson
from featmap.io.html_map import write_html_map
from featmap.io.kml import kml_color, read_kml, write_kml
from featmap.io.layers import MapLayer

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
    layers = [MapLayer("proposed", SEGS, np.array([1, 2, 3]), "#d62728"), MapLayer("density", SEGS[:1], None, "#2ca02c")]
    path = write_kml(tmp_path / "m.kml", layers, FRAME, trajectory=np.array([[0.0, -5.0], [10.0, -5.0], [20.0, -6.0]]))
    root = ET.parse(path).getroot()
    assert root.tag.endswith("kml")
    back = read_kml(path, FRAME)
    assert set(back) == {"proposed", "density", "trajectory"}
    assert np.abs(back["proposed"] - SEGS).max() < 1e-3 and len(back["density"]) == 1
    text = path.read_text()
    assert kml_color("#d62728") == "ff2827d6" and "ff2827d6" in text and "ff2ca02c" in text


def test_kml_of_a_missing_or_broken_file_is_one_line(tmp_path):
    import pytest

    from featmap.errors import InputFileError

    bad = tmp_path / "bad.kml"
    bad.write_text("<kml><Folder>")
    for path in (bad, tmp_path / "missing.kml"):
        with pytest.raises(InputFileError, match="not a readable KML file"):
            read_kml(path, FRAME)


def test_html_map_has_every_layer(tmp_path):
    layers = [MapLayer("truth", SEGS, None, "#595959"), MapLayer("proposed", SEGS, np.array([1, 2, 3]), "#d62728"),
              MapLayer("meanshift", SEGS, np.array([1, 1, 1]), "#1f77b4"), MapLayer("density", SEGS, np.array([4, 4, 4]), "#2ca02c")]
    path = write_html_map(tmp_path / "m.html", layers, FRAME, trajectory=np.array([[0.0, -5.0], [10.0, -5.0]]))
    html = path.read_text()
    for layer in ("proposed", "meanshift", "density", "trajectory", "truth"):   # one named overlay each
        assert f'"{layer}" : feature_group_' in html or f'"{layer}": feature_group_' in html, layer
    assert html.count("L.polyline") == 3 * 3 + 1            # fused features and the trajectory: a polyline each
    for color in ("#d62728", "#1f77b4", "#2ca02c"):
        assert html.count(f'"color": "{color}"') == 3, color
    # the truth (no support) is one GeoJSON MultiLineString of its three walls, in its colour
    assert html.count("MultiLineString") == 1 and '"color": "#595959"' in html
    assert "support 4 segments" in html and "length 30.00 m" in html
    assert "L.control.layers" in html


def test_kml_is_the_same_however_many_maps_the_process_wrote_before(tmp_path):
    """simplekml numbers elements with a class-wide counter: a batch worker writing many maps must still
    write the bytes a fresh ``featmap run`` writes."""
    layers = [MapLayer("proposed", SEGS, np.array([1, 2, 3]), "#d62728")]
    first = write_kml(tmp_path / "a.kml", layers, FRAME).read_bytes()
    write_kml(tmp_path / "b.kml", layers * 3, FRAME)
    assert write_kml(tmp_path / "c.kml", layers, FRAME).read_bytes() == first
