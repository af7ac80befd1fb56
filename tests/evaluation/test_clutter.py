"""What segments off every building wall lie on: known layouts of a wall, a hedge, a fence, a car, a pole and a tree."""

import numpy as np
import pytest

from featmap.evaluation.clutter import CLUTTER_KINDS, ClutterObjects, off_wall, walls_on
from featmap.evaluation.truth_metrics import GroundTruth

WALL = np.array([[0.0, 0.0, 20.0, 0.0]])                 # a building wall along y = 0
TRUTH = GroundTruth(walls=WALL, building=np.array(["A"]), labels=np.array([["a", "b"]]), observed=[[(0.0, 20.0)]],
                    n_returns=np.array([500]))
RECORDS = [
    {"kind": "building", "geometry": {"type": "Polygon", "coordinates": [[[0, 0], [20, 0], [20, 10], [0, 10]]]}},
    {"kind": "hedge", "geometry": {"type": "LineString", "coordinates": [[0, -10], [8, -10]]}, "height": 1.2},
    {"kind": "fence", "geometry": {"type": "LineString", "coordinates": [[30, -10], [40, -10]]}, "height": 1.0},
    {"kind": "car", "geometry": {"type": "Polygon", "coordinates": [[[50, -1], [54.5, -1], [54.5, 0.8], [50, 0.8]]]},
     "height": 1.5},
    {"kind": "pole", "geometry": {"type": "Point", "coordinates": [60, -5]}, "radius": 0.1},
    {"kind": "tree", "geometry": {"type": "Point", "coordinates": [70, -5]}, "radius": 0.2},
]
OBJECTS = ClutterObjects.from_records(RECORDS)


def kind(name: str) -> int:
    return CLUTTER_KINDS.index(name)


@pytest.mark.parametrize("segment,expected", [
    ([1.0, -10.1, 7.0, -9.9], "hedge"),            # along the hedge, 10 cm off its line
    ([32.0, -10.3, 38.0, -10.3], "fence"),         # 30 cm in front of the fence
    ([50.2, -1.05, 54.3, -1.05], "car"),           # the car's long side
    ([59.8, -5.5, 59.8, -4.5], "pole"),
    ([68.0, -7.0, 68.0, -3.0], "tree"),            # 2 m from the trunk: in its crown
    ([5.0, 0.6, 15.0, 0.6], "beside a wall"),      # parallel to the wall, 60 cm off it (beyond the 30 cm tolerance)
    ([5.0, -0.2, 5.0, -6.0], "nothing near"),      # square to the wall, 0.2-6 m from it: off by angle, mostly far
    ([100.0, 50.0, 104.0, 50.0], "nothing near"),
])
def test_a_segment_off_the_walls_is_put_down_to_what_it_lies_on(segment, expected):
    result = off_wall(np.array([segment]), TRUTH, OBJECTS)
    length = np.hypot(segment[2] - segment[0], segment[3] - segment[1])
    by_kind = result.metres_by_kind()
    assert by_kind.sum() == pytest.approx(length, rel=0.05)          # none of it lies on the wall
    assert by_kind[kind(expected)] >= 0.75 * length
    assert result.segments_on().tolist() == [kind(expected)]


def test_a_segment_on_the_wall_counts_nowhere_and_a_mixed_one_by_its_larger_part():
    segments = np.array([[2.0, 0.05, 18.0, 0.05],          # on the wall (5 cm off, within tolerance)
                         [1.0, -10.0, 7.0, -10.0],          # on the hedge
                         [10.0, 0.0, 26.0, 0.0]])            # 10 m on the wall, 6 m past its end (beside it)
    result = off_wall(segments, TRUTH, OBJECTS)
    on = result.segments_on()
    assert on[0] == -1 and on[1] == kind("hedge")
    assert on[2] == -1                                      # only ~5 of its 16 m lie off the wall
    assert result.metres_by_kind()[kind("beside a wall")] == pytest.approx(0.7, abs=0.2)   # 0.7 m past end + tolerance
    assert result.segments_on(min_share=0.25)[2] == kind("nothing near")  # 5.7 m off: "beside a wall" 1 m past the end
    assert result.segments_on(min_length_m=7.0)[1] == -1    # the hedge segment is 6 m long


def test_a_hedge_under_a_crown_counts_as_hedge_and_no_objects_means_nothing_near():
    records = RECORDS + [{"kind": "tree", "geometry": {"type": "Point", "coordinates": [4, -10.5]}, "radius": 0.2}]
    result = off_wall(np.array([[1.0, -10.0, 7.0, -10.0]]), TRUTH, ClutterObjects.from_records(records))
    assert result.segments_on().tolist() == [kind("hedge")]
    bare = off_wall(np.array([[1.0, -10.0, 7.0, -10.0]]), TRUTH, ClutterObjects.from_records([]))
    assert bare.segments_on().tolist() == [kind("nothing near")]
    empty = off_wall(np.zeros((0, 4)), TRUTH, OBJECTS)
    assert empty.segments_on().shape == (0,) and empty.metres_by_kind().sum() == 0


def test_each_segment_on_clutter_is_put_down_to_the_object_it_lies_on():
    records = RECORDS + [{"id": "h2", "kind": "hedge", "geometry": {"type": "LineString",
                                                                   "coordinates": [[10, -10], [18, -10]]}, "height": 2.0}]
    objects = ClutterObjects.from_records(records)
    assert objects.names[:2] == ("hedge 0", "fence 1") and objects.names[-1] == "h2"
    assert [CLUTTER_KINDS[k] for k in objects.object_kind] == ["hedge", "fence", "car", "pole", "tree", "hedge"]
    assert objects.heights[0] == 1.2 and np.isnan(objects.heights[objects.names.index("tree 4")])
    segments = np.array([[1.0, -10.0, 7.0, -10.0],           # the first hedge
                         [11.0, -10.1, 17.0, -10.1],         # the second
                         [7.0, -10.0, 12.0, -10.0],          # 2 m within reach of the first, 3 m of the second
                         [68.0, -7.0, 68.0, -3.0],           # the tree
                         [50.2, -1.05, 54.3, -1.05],         # the car
                         [2.0, 0.05, 18.0, 0.05],            # on the wall
                         [100.0, 50.0, 104.0, 50.0]])        # nothing near
    on = off_wall(segments, TRUTH, objects).objects_on(len(objects.names))
    assert [objects.names[i] if i >= 0 else None for i in on] == ["hedge 0", "h2", "h2", "tree 4", "car 2", None, None]


def test_walls_on_names_the_wall_holding_most_of_a_segment():
    segments = np.array([[2.0, 0.05, 18.0, 0.05],        # on the wall
                         [10.0, 0.0, 26.0, 0.0],         # 10 of 16 m on it
                         [14.0, 0.0, 30.0, 0.0],         # 6 of 16 m on it
                         [1.0, -10.0, 7.0, -10.0]])      # on the hedge
    assert walls_on(segments, TRUTH).tolist() == [0, 0, -1, -1]
    assert walls_on(segments, TRUTH, min_share=0.3).tolist() == [0, 0, 0, -1]
    assert walls_on(np.zeros((0, 4)), TRUTH).shape == (0,)
