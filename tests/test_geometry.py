import numpy as np
import pytest

from featmap.geometry import (circle_overlap_area, fit_line_tls, included_angle, line_coefficients, move_segments_2d,
                              point_segment_distance, rigid_motion_2d, segment_orientations)


def test_equal_circles_at_distance_r():
    r = 2.0
    expected = (2 * np.pi / 3 - np.sqrt(3) / 2) * r**2
    assert circle_overlap_area(r, r, r) == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize("r1,r2,d,expected", [
    (1.0, 3.0, 0.5, np.pi * 1.0),        # contained
    (1.0, 3.0, 2.0, np.pi * 1.0),        # internally tangent: still contained
    (1.0, 1.0, 0.0, np.pi),              # identical
    (1.0, 2.0, 3.0, 0.0),                # externally tangent
    (1.0, 2.0, 10.0, 0.0),               # disjoint
])
def test_overlap_special_cases(r1, r2, d, expected):
    assert circle_overlap_area(r1, r2, d) == pytest.approx(expected, abs=1e-12)


def test_overlap_symmetric_and_matches_numeric_integration():
    rng = np.random.default_rng(1)
    r1, r2 = rng.uniform(0.5, 3, 20), rng.uniform(0.5, 3, 20)
    d = rng.uniform(0, 6, 20)
    a = circle_overlap_area(r1, r2, d)
    assert np.allclose(a, circle_overlap_area(r2, r1, d))
    # Monte-Carlo-free check: integrate the lens on a fine grid for one partial case.
    R1, R2, D = 2.0, 1.5, 2.5
    xs = np.linspace(-2, 4.5, 1301)
    X, Y = np.meshgrid(xs, np.linspace(-2, 2, 801))
    inside = (X**2 + Y**2 <= R1**2) & ((X - D) ** 2 + Y**2 <= R2**2)
    numeric = inside.sum() * (xs[1] - xs[0]) * (4 / 800)
    assert circle_overlap_area(R1, R2, D) == pytest.approx(numeric, rel=5e-3)


def _beta(s1, s2):
    return float(included_angle(line_coefficients(np.array([s1], float)), line_coefficients(np.array([s2], float)))[0])


def test_included_angle_cases():
    assert _beta([0, 0, 1, 0], [5, 3, -2, 3]) == pytest.approx(0.0, abs=1e-12)          # parallel, opposite directions
    assert _beta([0, 0, 1, 0], [0, 0, 0, 1]) == pytest.approx(np.pi / 2)                 # perpendicular
    assert _beta([2, 0, 2, 5], [7, -1, 7, 9]) == pytest.approx(0.0, abs=1e-12)           # both exactly vertical
    assert _beta([0, 0, 0, 1], [0, 0, 1e-4, 1]) == pytest.approx(1e-4, rel=1e-6)         # nearly vertical
    assert _beta([0, 0, 1, 1], [0, 0, -1, 1]) == pytest.approx(np.pi / 2)
    assert 0 <= _beta([0, 0, 1, 0.2], [0, 0, -1, 0.3]) <= np.pi / 2


def test_point_segment_distance_hand_made():
    seg = np.array([[0, 0, 10, 0]] * 3, float)
    pts = np.array([[5, 2], [-3, 4], [13, 0]], float)
    assert np.allclose(point_segment_distance(pts, seg), [2.0, 5.0, 3.0])
    # zero-length segment: distance to its point
    assert point_segment_distance(np.array([[3.0, 4.0]]), np.zeros((1, 4)))[0] == pytest.approx(5.0)


def test_orientation_is_pi_periodic():
    seg = np.array([[0, 0, np.cos(np.deg2rad(179)), np.sin(np.deg2rad(179))],
                    [0, 0, np.cos(np.deg2rad(-1)), np.sin(np.deg2rad(-1))]])
    o = segment_orientations(seg)
    assert o[0] == pytest.approx(o[1])


def test_tls_fits_vertical_line():
    pts = np.array([[3.0, y] for y in np.linspace(-5, 5, 11)])
    c, d = fit_line_tls(pts)
    assert c[0] == pytest.approx(3.0)
    assert abs(d[0]) < 1e-12 and abs(abs(d[1]) - 1) < 1e-12


def test_rigid_motion_2d_recovers_a_known_motion_and_moves_segments_with_it():
    rng = np.random.default_rng(2)
    source = rng.uniform(-50, 50, (30, 2))
    angle, shift = np.deg2rad(17.0), np.array([3.0, -4.5])
    rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    got_rot, got_shift = rigid_motion_2d(source, source @ rot.T + shift)
    assert np.allclose(got_rot, rot) and np.allclose(got_shift, shift)
    segments = np.column_stack([source[:15], source[15:]])
    assert np.allclose(move_segments_2d(segments, rot, shift),
                       np.column_stack([source[:15] @ rot.T + shift, source[15:] @ rot.T + shift]))
