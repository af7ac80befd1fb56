"""Ground truth from building footprints and from a simulated drive's truth folder; bad files in one line."""

import json

import numpy as np
import pytest

from featmap.errors import InputFileError
from featmap.evaluation import EvaluationConfig, EvaluationContext
from featmap.evaluation.plugins import Footprints, SimulatorTruth
from featmap.evaluation.references import (footprints_truth, load_simulator_truth, observation_record, observe_walls,
                                          observed_footprints, truth_from_footprints)
from featmap.evaluation.truth_metrics import truth_metrics
from featmap.io.sim_truth import FOOTPRINT_WALLS_FILE, write_walls_csv
from featmap.geo import GeoFrame

FRAME = GeoFrame(49.011, 8.424)


def _square(frame, x0=0.0, y0=0.0, size=10.0):
    xs = np.array([x0, x0 + size, x0 + size, x0, x0])
    ys = np.array([y0, y0, y0 + size, y0 + size, y0])
    lat, lon = frame.to_wgs84(xs, ys)
    return [[float(a), float(b)] for a, b in zip(lon, lat)]


def _write(tmp_path, features):
    path = tmp_path / "fp.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": features}))
    return path


def test_footprints_become_walls_in_the_local_frame(tmp_path):
    ring = _square(FRAME, 5, -3)
    path = _write(tmp_path, [{"type": "Feature", "properties": {"id": "B1", "vertex_labels": list("abcd")},
                              "geometry": {"type": "Polygon", "coordinates": [ring]}}])
    truth = truth_from_footprints(path, FRAME)
    assert truth.walls.shape == (4, 4) and np.abs(truth.walls[0] - [5, -3, 15, -3]).max() < 1e-6
    assert truth.labels[0].tolist() == ["a", "b"] and truth.observable().all()


@pytest.mark.parametrize("geometry,match", [
    ({"type": "Polygon", "coordinates": [[["8.42", "49.01"], [8.43, 49.01], [8.43, 49.02]]]}, r"feature 0: a position must be \[lon, lat\] numbers"),
    ({"type": "Polygon", "coordinates": [[[8.42, 49.01], [float("nan"), 49.01], [8.43, 49.02]]]}, r"not valid JSON \(NaN is not a finite number\)"),
    ({"type": "Polygon", "coordinates": [[[49.01, 8.42], [491.0, 8.43], [49.02, 8.43]]]}, r"is not WGS84 \[lon, lat\]"),
])
def test_bad_positions_fail_in_one_line(tmp_path, geometry, match):
    path = _write(tmp_path, [{"type": "Feature", "properties": {}, "geometry": geometry}])
    with pytest.raises(InputFileError, match=match):
        truth_from_footprints(path, FRAME)


def test_rings_without_area_are_skipped_and_repeated_vertices_count_once(tmp_path):
    square = _square(FRAME, 5, -3)
    repeated = [square[0], *square[:3], square[2], *square[3:]]            # vertices 0 and 2 given twice in a row
    two = [square[0], square[1], square[0]]                                 # a line: one wall there and back
    one = [square[0], square[0], square[0], square[0]]
    path = _write(tmp_path, [{"type": "Feature", "properties": {"id": f"B{k}"},
                              "geometry": {"type": "Polygon", "coordinates": [ring]}}
                             for k, ring in enumerate((repeated, two, one))])
    truth = truth_from_footprints(path, FRAME)
    assert truth.walls.shape == (4, 4) and set(truth.building) == {"B0"}
    lengths = np.hypot(truth.walls[:, 2] - truth.walls[:, 0], truth.walls[:, 3] - truth.walls[:, 1])
    assert np.allclose(lengths, 10.0, atol=1e-6)                            # no zero-length wall
    with pytest.raises(InputFileError, match="no building Polygon"):
        truth_from_footprints(_write(tmp_path, [{"type": "Feature", "properties": {},
                                                 "geometry": {"type": "Polygon", "coordinates": [two]}}]), FRAME)


def test_empty_or_wrong_collections_fail(tmp_path):
    with pytest.raises(InputFileError, match="no building Polygon"):
        truth_from_footprints(_write(tmp_path, []), FRAME)
    (tmp_path / "x.geojson").write_text("[1, 2]")
    with pytest.raises(InputFileError, match="expected a GeoJSON FeatureCollection"):
        truth_from_footprints(tmp_path / "x.geojson", FRAME)



@pytest.mark.parametrize("features,match", [
    ([{"type": "Feature", "properties": ["kind", "fence"],
       "geometry": {"type": "Polygon", "coordinates": [[[8.42, 49.01], [8.43, 49.01], [8.43, 49.02]]]}}],
     r"fp.geojson: feature 0: 'properties' must be an object or null, got list"),
    ([{"type": "Feature", "properties": {}, "geometry": "Polygon"}],
     r"fp.geojson: feature 0: 'geometry' must be an object or null, got str"),
    ([None], r"fp.geojson: feature 0: expected a GeoJSON Feature object, got null"),
    ({"type": "Feature"}, r"fp.geojson: 'features' must be a list of GeoJSON Features, got dict"),
    ([{"type": "Feature", "properties": {}, "geometry": {"type": "Polygon", "coordinates": 5}}],
     r"fp.geojson: feature 0: a Polygon's coordinates must be nested lists of rings"),
    ([{"type": "Feature", "properties": {}, "geometry": {"type": "Polygon", "coordinates": [[[8.42]]]}}],
     r"fp.geojson: feature 0: a position must be \[lon, lat\] numbers, got \[8.42\]"),
])
def test_malformed_features_fail_in_one_line(tmp_path, features, match):
    with pytest.raises(InputFileError, match=match):
        truth_from_footprints(_write(tmp_path, features), FRAME)


def test_vertex_labels_that_are_not_text_are_written_out(tmp_path):
    path = _write(tmp_path, [{"type": "Feature", "properties": {"vertex_labels": [[1, 2], "b", None, 4]},
                              "geometry": {"type": "Polygon", "coordinates": [_square(FRAME)]}}])
    assert truth_from_footprints(path, FRAME).labels.tolist() == [["[1, 2]", "b"], ["b", "None"], ["None", "4"],
                                                                  ["4", "[1, 2]"]]


def test_null_properties_and_odd_vertex_labels_are_read_as_empty(tmp_path):
    ring = _square(FRAME)
    path = _write(tmp_path, [{"type": "Feature", "properties": None, "geometry": {"type": "Polygon", "coordinates": [ring]}},
                             {"type": "Feature", "properties": {"vertex_labels": 5},
                              "geometry": {"type": "Polygon", "coordinates": [_square(FRAME, 20)]}}])
    truth = truth_from_footprints(path, FRAME)
    assert truth.walls.shape == (8, 4) and truth.building.tolist() == ["0"] * 4 + ["1"] * 4
    assert (truth.labels == "").all()

def test_simulator_truth_of_a_drive_and_its_plugin(case1_drive):
    truth = load_simulator_truth(case1_drive.drive_dir / "truth")
    assert len(truth.walls) == 4 and sorted(truth.labels.reshape(-1).tolist()) == sorted("aabbccdd")
    few = load_simulator_truth(case1_drive.drive_dir / "truth", frames=[0, 1])
    assert few.n_returns.sum() < truth.n_returns.sum()
    ctx = EvaluationContext(case1_drive.drive_dir, list(range(40)), None, EvaluationConfig())
    ref = SimulatorTruth().prepare(ctx)
    assert ref is not None and ref.path.endswith("truth")
    assert SimulatorTruth().prepare(EvaluationContext(case1_drive.root, None, None, EvaluationConfig())) is None
    assert Footprints().prepare(ctx) is None                       # no footprints configured


def test_a_damaged_truth_folder_fails_in_one_line(drive_copy):
    root, drive = drive_copy
    walls = root / drive[:10] / f"{drive}_sync" / "truth" / "walls.csv"
    lines = walls.read_text().splitlines()
    walls.write_text("\n".join(lines[:2] + [lines[2].replace(lines[2].split(",")[3], "nan", 1)]) + "\n")
    with pytest.raises(InputFileError, match=r"walls.csv:3: wall coordinates must be finite"):
        load_simulator_truth(walls.parent)


def test_merged_truth_unites_what_each_drive_observed_of_the_same_walls():
    from featmap.evaluation.references import merge_truths
    from featmap.evaluation.truth_metrics import GroundTruth

    walls = np.array([[0.0, 0.0, 10.0, 0.0], [10.0, 0.0, 10.0, 8.0]])
    one = GroundTruth(walls=walls, building=np.array(["A", "A"]), labels=np.full((2, 2), ""),
                      observed=[[(0.0, 4.0)], []], n_returns=np.array([100, 0]))
    # the second drive saw the first wall from 3 to 9 m (its endpoints in the other order), the second wall
    # 0-8 m, and a third wall the first never saw
    two = GroundTruth(walls=np.array([[10.0, 0.0, 0.0, 0.0005], [10.0, 0.0, 10.0, 8.0], [20.0, 0.0, 30.0, 0.0]]),
                      building=np.array(["A", "A", "B"]), labels=np.full((3, 2), ""),
                      observed=[[(1.0, 7.0)], [(0.0, 8.0)], [(0.0, 10.0)]], n_returns=np.array([60, 80, 90]))
    merged = merge_truths([one, two])
    assert len(merged.walls) == 3
    assert np.allclose(merged.observed[0], [(0.0, 9.0)]) and merged.observed[1] == [(0.0, 8.0)]
    assert merged.n_returns.tolist() == [160, 80, 90]
    assert merged.observable().tolist() == [True, True, True]
    assert merge_truths([one]).observed == one.observed


def _wall_points(rng, x0, x1, y, n, noise=0.03):
    """(n, 2) points along the wall y = const between x0 and x1, with Gaussian noise across it."""
    return np.column_stack([rng.uniform(x0, x1, n), y + rng.normal(0, noise, n)])


def test_scan_points_observe_the_stretches_of_footprint_walls_they_lie_on(tmp_path):
    """A 10 m square: its south wall seen from x = 2 to 7, its north wall seen from 1 m away (a hedge in front,
    not the wall), the east wall with 3 points, the west wall not at all: only the south wall is observable,
    over 2-7 m, and a map of that stretch has recall 1 against it (0.14 against the footprints counted whole:
    5.6 m, with the 0.3 m tolerance at both ends, of 40 m)."""
    rng = np.random.default_rng(0)
    truth = truth_from_footprints(_write(tmp_path, [{"type": "Feature", "properties": {"id": "A"},
                                                     "geometry": {"type": "Polygon", "coordinates": [_square(FRAME)]}}]),
                                  FRAME)
    south = int(np.argmin(truth.walls[:, 1] + truth.walls[:, 3]))
    points = np.concatenate([_wall_points(rng, 2.0, 7.0, 0.0, 400), _wall_points(rng, 0.0, 10.0, 11.0, 400),
                             np.array([[10.0, 4.0], [10.1, 5.0], [9.9, 6.0]])])
    observed = observe_walls(truth, points)
    assert observed.observable().tolist() == [w == south for w in range(4)]
    (a, b), = observed.observed[south]
    length = np.hypot(*(truth.walls[south, 2:] - truth.walls[south, :2]))
    start = 2.0 if truth.walls[south, 0] < truth.walls[south, 2] else length - 7.0
    assert a == pytest.approx(start, abs=0.5) and b - a == pytest.approx(5.0, abs=0.5)
    assert (observed.n_returns == -1).all()                      # points are not returns
    seen = np.array([[2.0, 0.0, 7.0, 0.0]])
    assert truth_metrics(seen, observed)["recall"] == pytest.approx(1.0, abs=0.02)
    assert truth_metrics(seen, truth)["recall"] == pytest.approx(5.6 / 40, abs=0.005)
    assert not observe_walls(truth, np.zeros((0, 2))).observable().any()
    assert observe_walls(truth, np.array([[np.nan, np.nan], *points])).observed == observed.observed


def test_a_footprint_wall_is_observed_by_scans_that_each_see_two_metres_of_it(tmp_path):
    """As in the simulator's per-scan truth, a wall counts where one scan saw at least 2 m of it: twenty
    scans that each see 1 m of the south wall (together 11 m of it) observe nothing; one more scan that
    sees 3 m of it observes those 3 m; a scan with one point per 0.5 m bin (a sparse view) observes nothing."""
    rng = np.random.default_rng(2)
    truth = truth_from_footprints(_write(tmp_path, [{"type": "Feature", "properties": {"id": "A"},
                                                     "geometry": {"type": "Polygon", "coordinates": [_square(FRAME)]}}]),
                                  FRAME)
    south = int(np.argmin(truth.walls[:, 1] + truth.walls[:, 3]))
    glimpses = [_wall_points(rng, 0.5 * k, 0.5 * k + 1.0, 0.0, 40) for k in range(20)]
    points = np.concatenate(glimpses)
    scans = np.repeat(np.arange(20), 40)
    assert not observe_walls(truth, points, scans).observable().any()
    assert observe_walls(truth, points).observable()[south]                  # as one scan: 11 m
    view = _wall_points(rng, 6.0, 9.0, 0.0, 60)
    seen = observe_walls(truth, np.concatenate([points, view]), np.concatenate([scans, np.full(60, 20)]))
    assert seen.observable().tolist() == [w == south for w in range(4)]
    (a, b), = seen.observed[south]
    assert b - a == pytest.approx(3.0, abs=0.5)
    sparse = np.column_stack([np.arange(0.25, 10, 0.5), np.zeros(20)])       # one point per bin
    assert not observe_walls(truth, sparse).observable().any()
    with pytest.raises(ValueError, match="20 points but 3 scan ids"):
        observe_walls(truth, sparse, np.zeros(3))


def test_a_runs_footprint_record_is_read_back_for_its_footprints_and_refused_for_others(tmp_path):
    """The record a run writes (the walls near its scans and what they observed) is what evaluate scores
    the run's maps on, in any local frame; footprints that no longer hold its walls are a one-line error;
    a damaged interval too."""
    rng = np.random.default_rng(1)
    path = _write(tmp_path, [{"type": "Feature", "properties": {"id": "A"},
                              "geometry": {"type": "Polygon", "coordinates": [_square(FRAME)]}},
                             {"type": "Feature", "properties": {"id": "far"},
                              "geometry": {"type": "Polygon", "coordinates": [_square(FRAME, 500, 500)]}}])
    observed = observed_footprints(truth_from_footprints(path, FRAME), _wall_points(rng, 2.0, 7.0, 0.0, 400))
    assert observed.building.tolist() == ["A"] * 4                            # the far building is left out
    run = tmp_path / "run"
    write_walls_csv(run / FOOTPRINT_WALLS_FILE, observation_record(observed, path))
    back = footprints_truth(path, FRAME, run)
    assert back.observable().tolist() == observed.observable().tolist() and back.building.tolist() == ["A"] * 4
    assert np.allclose(back.walls, observed.walls, atol=1e-6)
    assert back.observed == [[(pytest.approx(a, abs=1e-6), pytest.approx(b, abs=1e-6)) for a, b in iv]
                             for iv in observed.observed]
    other = GeoFrame(49.012, 8.425)                                          # scored in another local frame
    moved_frame = footprints_truth(path, other, run, FRAME)
    assert np.allclose(moved_frame.walls, truth_from_footprints(path, other).walls[:4], atol=1e-3)
    assert footprints_truth(path, FRAME).observable().all() and len(footprints_truth(path, FRAME).walls) == 8
    grown = json.loads(path.read_text())                      # a building added near the drive since the run
    grown["features"].append({"type": "Feature", "properties": {"id": "B"},
                              "geometry": {"type": "Polygon", "coordinates": [_square(FRAME, 0, -15)]}})
    path.write_text(json.dumps(grown))
    with pytest.raises(InputFileError, match=r"footprint_walls.csv: was made from another version of .*fp.geojson"):
        footprints_truth(path, FRAME, run)
    write_walls_csv(run / FOOTPRINT_WALLS_FILE, observation_record(observed))     # a record naming no file
    moved = _write(tmp_path, [{"type": "Feature", "properties": {"id": "A"},
                               "geometry": {"type": "Polygon", "coordinates": [_square(FRAME, 0.5)]}}])
    with pytest.raises(InputFileError, match=r"footprint_walls.csv: holds walls that .*fp.geojson does not have"):
        footprints_truth(moved, FRAME, run)
    text = (run / FOOTPRINT_WALLS_FILE).read_text().splitlines()
    for bad in ("5.0", "1-2-3", "nan-inf", "3-2"):
        row = text[1].split(",")
        row[-1] = bad
        (run / FOOTPRINT_WALLS_FILE).write_text("\n".join([text[0], ",".join(row), *text[2:]]) + "\n")
        with pytest.raises(InputFileError, match=r"footprint_walls.csv:2: observed_intervals must be START-END"):
            footprints_truth(path, FRAME, run)


def test_a_ring_is_closed_only_by_repeating_its_first_position(tmp_path):
    """An open ring whose last vertex lies 2 m from its first keeps that vertex: five walls, not four."""
    ring = _square(FRAME)[:4]
    lat, lon = FRAME.to_wgs84(np.array([2.0]), np.array([0.0]))
    open_ring = ring + [[float(lon[0]), float(lat[0])]]
    closed = truth_from_footprints(_write(tmp_path, [{"type": "Feature", "properties": {},
                                                      "geometry": {"type": "Polygon", "coordinates": [_square(FRAME)]}}]),
                                   FRAME)
    opened = truth_from_footprints(_write(tmp_path, [{"type": "Feature", "properties": {},
                                                      "geometry": {"type": "Polygon", "coordinates": [open_ring]}}]),
                                   FRAME)
    assert len(closed.walls) == 4 and len(opened.walls) == 5
    assert np.allclose(opened.walls[-1], [2.0, 0.0, 0.0, 0.0], atol=1e-3)
