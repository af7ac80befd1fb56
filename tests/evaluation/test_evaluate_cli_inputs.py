"""``featmap fuse`` and ``featmap evaluate`` on malformed or polyline inputs: one error line, exit 2, or a fair score."""

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from featmap.cli import app
from featmap.geo import GeoFrame

FRAME = GeoFrame(49.011, 8.424)
RUNNER = CliRunner()


def _cli(*args):
    return RUNNER.invoke(app, [str(a) for a in args])


def _error_line(result) -> str:
    """The single ``featmap: error:`` line of a run that exited with status 2."""
    errors = [line for line in result.output.splitlines() if line.startswith("featmap: error:")]
    assert result.exit_code == 2 and len(errors) == 1 and "Traceback" not in result.output, result.output
    return errors[0]


def _positions(points):
    lat, lon = FRAME.to_wgs84(np.array([p[0] for p in points], float), np.array([p[1] for p in points], float))
    return [[float(a), float(b)] for a, b in zip(lon, lat)]


def _collection(path, features):
    path.write_text(json.dumps({"type": "FeatureCollection", "features": features}))
    return path


@pytest.fixture
def footprints(tmp_path):
    ring = _positions([(0, 0), (30, 0), (30, 20), (0, 20), (0, 0)])
    return _collection(tmp_path / "fp.geojson", [{"type": "Feature", "properties": {"id": "B"},
                                                  "geometry": {"type": "Polygon", "coordinates": [ring]}}])


@pytest.mark.parametrize("text,needle", [
    ("scan,x1,y1,x2,y2,x1\n0,0,0,1,0,5\n", "s.csv:1: column 'x1' appears more than once in the header"),
    ("scan,x1,y1,x2,y2\n0,0,0,1,0\n1e30,0,0,2,0\n", "s.csv:3: column 'scan': 1e30 is outside the 64-bit integer range"),
])
def test_fuse_rejects_a_malformed_segments_csv(tmp_path, text, needle):
    (tmp_path / "s.csv").write_text(text)
    assert needle in _error_line(_cli("fuse", tmp_path / "s.csv", "--out", tmp_path / "out"))


def test_evaluate_scores_every_leg_of_a_polyline(tmp_path, footprints):
    two_walls = _collection(tmp_path / "map.geojson", [
        {"type": "Feature", "properties": {},
         "geometry": {"type": "LineString", "coordinates": _positions([(0, 20), (0, 0), (30, 0)])}}])
    result = _cli("evaluate", two_walls, "--truth", footprints, "--out", tmp_path / "m.json")
    assert result.exit_code == 0, result.output
    metrics = json.loads((tmp_path / "m.json").read_text())
    assert metrics["count"] == 2 and metrics["precision"] == pytest.approx(1.0), metrics
    assert metrics["recall"] == pytest.approx(0.5, abs=1e-6), metrics


@pytest.mark.parametrize("features,needle", [
    ([None], "map.geojson: feature 0: expected a GeoJSON Feature object"),
    ([{"type": "Feature", "geometry": {"type": "LineString", "coordinates": [[8.424, 49.011], [8.425]]}}],
     "map.geojson: feature 0: a position must be [lon, lat] numbers"),
])
def test_evaluate_rejects_a_malformed_map(tmp_path, footprints, features, needle):
    bad = _collection(tmp_path / "map.geojson", features)
    assert needle in _error_line(_cli("evaluate", bad, "--truth", footprints))


def test_evaluate_rejects_footprints_with_list_properties(tmp_path, footprints):
    fp = json.loads(footprints.read_text())
    fp["features"][0]["properties"] = ["kind", "building"]
    footprints.write_text(json.dumps(fp))
    one_wall = _collection(tmp_path / "map.geojson", [
        {"type": "Feature", "properties": {}, "geometry": {"type": "LineString", "coordinates": _positions([(0, 0), (30, 0)])}}])
    line = _error_line(_cli("evaluate", one_wall, "--truth", footprints))
    assert "fp.geojson: feature 0: 'properties' must be an object or null" in line


def test_evaluate_refuses_more_walls_or_segments_than_one_scoring_holds(tmp_path, footprints):
    """A footprint the size of a continent (or a map line 1,733 km long) is a one-line error naming the file;
    it was killed for lack of memory (every wall is sampled every 10 cm)."""
    continent = [[-10.0, 35.0], [30.0, 35.0], [30.0, 60.0], [-10.0, 60.0], [-10.0, 35.0]]
    huge = _collection(tmp_path / "huge.geojson", [{"type": "Feature", "properties": {},
                                                    "geometry": {"type": "Polygon", "coordinates": [continent]}}])
    one_wall = _collection(tmp_path / "map.geojson", [
        {"type": "Feature", "properties": {}, "geometry": {"type": "LineString", "coordinates": _positions([(0, 0), (30, 0)])}}])
    line = _error_line(_cli("evaluate", one_wall, "--truth", huge))
    assert "huge.geojson: its walls are" in line and "crop it to the drive's area" in line
    long_map = _collection(tmp_path / "long.geojson", [
        {"type": "Feature", "properties": {}, "geometry": {"type": "LineString", "coordinates": [[8.0, 49.0], [8.0, 31.0]]}}])
    line = _error_line(_cli("evaluate", long_map, "--truth", footprints))
    assert "long.geojson: its segments are 1,733 km long in total" in line and "one drive's map?" in line
