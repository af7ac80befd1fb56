"""Corner optimisation: the paper's midpoint rule and featmap's intersection rule."""

import numpy as np
import pytest

from featmap.fusion.corners import CornerConfig
from featmap.fusion.corners import optimise_corners
from featmap.geometry import included_angle, line_coefficients

INTERSECTION = CornerConfig(mode="intersection", snap_distance_m=1.0, max_extension_m=0.3)


def _direction(seg):
    d = seg[2:] - seg[:2]
    return d / np.hypot(*d)


def test_l_corner_meets_on_both_lines_without_turning_them():
    walls = np.array([[0.0, 0.0, 4.9, 0.02], [5.0, 0.1, 5.02, 4.0]])     # 10 cm short of the corner
    out = optimise_corners(walls, INTERSECTION)
    assert np.allclose(out[0, 2:], out[1, :2])
    for before, after in zip(walls, out):
        assert abs(abs(_direction(before) @ _direction(after)) - 1) < 1e-12     # same line, not tilted
        shift, d = after[:2] - before[:2], _direction(before)
        assert abs(shift[0] * d[1] - shift[1] * d[0]) < 1e-9                      # start still on it


def test_free_standing_wall_is_not_joined_to_the_wall_behind_it():
    outer = np.array([0.0, 0.0, 10.0, 0.0])
    inner = np.array([10.6, 0.7, 10.6, 5.0])          # ends 0.7 m before the outer wall's corner region
    out = optimise_corners(np.array([outer, inner]), INTERSECTION)
    assert np.array_equal(out, np.array([outer, inner]))


def test_wall_continuing_after_a_doorway_is_left_alone_but_midpoint_joins_it():
    left, right = [0.0, 0.0, 4.0, 0.0], [4.9, 0.03, 9.0, 0.03]
    segs = np.array([left, right])
    assert np.array_equal(optimise_corners(segs, INTERSECTION), segs)
    paper = optimise_corners(segs, CornerConfig(mode="midpoint", snap_distance_m=1.0))
    assert np.allclose(paper[0, 2:], [4.45, 0.015]) and np.allclose(paper[1, :2], [4.45, 0.015])


def test_corner_beyond_the_extension_limit_is_not_joined():
    walls = np.array([[0.0, 0.0, 4.5, 0.0], [5.0, 0.5, 5.0, 4.0]])      # corner 0.5 m from both ends
    assert np.array_equal(optimise_corners(walls, INTERSECTION), walls)
    joined = optimise_corners(walls, CornerConfig(mode="intersection", snap_distance_m=1.0, max_extension_m=0.6))
    assert np.allclose(joined[0, 2:], [5.0, 0.0]) and np.allclose(joined[1, :2], [5.0, 0.0])


def test_no_feature_is_shortened_past_its_other_end():
    short = np.array([0.0, 0.0, 0.2, 0.0])
    cross = np.array([-0.1, -0.5, -0.1, 0.5])           # the corner lies behind the short wall's start
    out = optimise_corners(np.array([short, cross]), CornerConfig(mode="intersection", snap_distance_m=1.0,
                                                                  max_extension_m=1.0))
    assert np.hypot(*(out[0, 2:] - out[0, :2])) > 0
    assert (out[0, 2] - out[0, 0]) > 0                  # still pointing the same way


def test_midpoint_rule_never_writes_duplicate_features():
    a = np.array([0.0, 0.0, 1.0, 0.0])
    b = np.array([0.05, 0.02, 1.02, 0.01])              # almost the same short feature
    out = optimise_corners(np.array([a, b]), CornerConfig(mode="midpoint", snap_distance_m=0.5))
    assert not np.allclose(out[0], out[1])


@pytest.mark.parametrize("mode", ["midpoint", "intersection", "none"])
def test_far_apart_features_are_untouched(mode):
    segs = np.array([[0.0, 0.0, 1.0, 0.0], [5.0, 5.0, 5.0, 6.0]])
    assert np.array_equal(optimise_corners(segs, CornerConfig(mode=mode)), segs)
    coef = line_coefficients(segs)
    assert included_angle(coef[:1], coef[1:])[0] == pytest.approx(np.pi / 2)
