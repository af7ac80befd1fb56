import math

import numpy as np
import pytest

from featmap.geometry import point_segment_distance
from featmap.evaluation.map_metric import (SegmentIndex, TruthFreeConfig, greedy_cover, map_reference, sample_segments,
                                        score_map, truth_free_metrics)

SQUARE = np.array([[0, 0, 10, 0], [10, 0, 10, 10], [10, 10, 0, 10], [0, 10, 0, 0]], float)


def _wall_points(walls, spacing=0.01, noise=0.0, seed=0):
    samples, _, _ = sample_segments(walls, spacing)
    return samples + np.random.default_rng(seed).normal(0, noise, samples.shape)


def _raw_views(walls, n_views=5):
    """Each wall seen as n_views shorter pieces (the raw extracted segments)."""
    out = []
    for w in walls:
        a, b = w[:2], w[2:]
        for k in range(n_views):
            t0, t1 = k / n_views, (k + 1) / n_views
            out.append(np.r_[a + t0 * (b - a), a + t1 * (b - a)])
    return np.array(out)


def test_perfect_map_scores_one_with_no_redundancy():
    pts = _wall_points(SQUARE, noise=0.005)
    raw = _raw_views(SQUARE)
    m = truth_free_metrics(SQUARE, pts, raw)
    assert m.precision == pytest.approx(1.0) and m.recall == pytest.approx(1.0)
    assert m.redundancy == 0.0 and m.count == 4 and m.compression == pytest.approx(5.0)
    assert m.fused_length_m == pytest.approx(40.0) and m.wall_points == len(pts)


def test_a_line_off_the_points_lowers_precision_by_its_length():
    pts = _wall_points(SQUARE)
    stray = np.array([[2.0, 5.0, 6.0, 5.0]])                     # 4 m through the empty middle
    m = truth_free_metrics(np.concatenate([SQUARE, stray]), pts, _raw_views(SQUARE))
    assert m.precision == pytest.approx(40 / 44, abs=1e-3)
    assert m.recall == pytest.approx(1.0)


def test_a_missing_wall_lowers_recall_by_its_points():
    pts = _wall_points(SQUARE)
    m = truth_free_metrics(SQUARE[:3], pts, _raw_views(SQUARE))
    # 30 m of walls covered, plus the 5 cm at each end of the missing wall that touch its neighbours.
    assert m.recall == pytest.approx(30.1 / 40, abs=1e-3)
    assert m.precision == pytest.approx(1.0)


def test_points_away_from_any_raw_segment_are_not_wall_points():
    pts = np.concatenate([_wall_points(SQUARE), np.random.default_rng(1).uniform(3, 7, (500, 2))])
    m = truth_free_metrics(SQUARE, pts, _raw_views(SQUARE))
    assert m.wall_points == len(pts) - 500 and m.recall == pytest.approx(1.0)


def test_duplicate_and_parallel_copy_count_as_redundancy_but_a_perpendicular_neighbour_does_not():
    pts = _wall_points(SQUARE)
    raw = _raw_views(SQUARE)
    # Bottom wall twice (10 m + a 2 cm offset copy of 5 m of it): 5 m of each carries one other segment.
    copy = np.array([[0.0, 0.02, 5.0, 0.02]])
    m = truth_free_metrics(np.concatenate([SQUARE, copy]), pts, raw)
    assert m.redundancy == pytest.approx((5 + 5) / 45, abs=2e-3)
    # A copy turned by 10 deg is not parallel: no redundancy counted (it also lies mostly off the points).
    turned = np.array([[0.0, 0.0, 0.5 * np.cos(np.deg2rad(10)), 0.5 * np.sin(np.deg2rad(10))]])
    assert truth_free_metrics(np.concatenate([SQUARE, turned]), pts, raw).redundancy == 0.0


def test_tolerance_is_exact_at_the_boundary():
    wall = np.array([[0.0, 0.0, 10.0, 0.0]])
    x = np.random.default_rng(2).uniform(0, 10, 400)
    pts = np.c_[x, np.where(np.arange(400) % 2, 0.0499, 0.0501)]     # just inside, just outside
    near = SegmentIndex(wall, 0.05, candidate_step=0.5).near(pts)
    assert np.array_equal(near, pts[:, 1] < 0.05)


def test_segment_index_matches_brute_force():
    rng = np.random.default_rng(3)
    segs = np.c_[rng.uniform(0, 20, (60, 2)), rng.uniform(0, 20, (60, 2))]
    pts = rng.uniform(0, 20, (3000, 2))
    brute = np.zeros(len(pts), bool)
    for s in segs:
        brute |= point_segment_distance(pts, np.broadcast_to(s, (len(pts), 4))) <= 0.3
    assert np.array_equal(SegmentIndex(segs, 0.3, candidate_step=0.7).near(pts), brute)
    p, s = SegmentIndex(segs, 0.3, candidate_step=0.7).pairs(pts)
    d = point_segment_distance(pts[p], segs[s])
    assert np.all(d <= 0.3) and len(np.unique(p * 60 + s)) == len(p)


def test_empty_map_and_subsampling():
    pts = _wall_points(SQUARE)
    m = truth_free_metrics(np.zeros((0, 4)), pts, _raw_views(SQUARE))
    assert m.count == 0 and m.recall == 0.0 and math.isnan(m.precision) and math.isinf(m.compression)
    assert m.to_dict()["precision"] is None and m.to_dict()["compression"] is None
    sub = truth_free_metrics(SQUARE, pts, _raw_views(SQUARE), TruthFreeConfig(max_points=1000))
    assert sub.points == 1000 and sub.recall == pytest.approx(1.0)


def test_covered_points_are_the_points_near_a_segment_exactly():
    from scipy.spatial import cKDTree

    from featmap.evaluation.map_metric import SegmentIndex, covered_points

    rng = np.random.default_rng(3)
    segments = np.column_stack([rng.uniform(0, 20, (40, 2)), rng.uniform(0, 20, (40, 2))])
    segments[:5, 2:] = segments[:5, :2]                       # zero-length ones too
    base = segments[rng.integers(0, 40, 20000)]
    t = rng.uniform(0, 1, (20000, 1))
    points = base[:, :2] + t * (base[:, 2:] - base[:, :2]) + rng.normal(0, 0.05, (20000, 2))
    for tol, step in ((0.05, 0.1), (0.03, 0.5)):
        expected = SegmentIndex(segments, tol, step).near(points)
        assert 0.2 < expected.mean() < 0.9
        assert np.array_equal(covered_points(segments, cKDTree(points), tol, step), expected)


def test_greedy_cover_takes_whole_walls_before_their_pieces_and_longer_walls_first():
    walls = np.array([[0, 0, 10, 0], [10, 0, 10, 4], [0, 6, 3, 6]], float)       # 10, 4 and 3 m long
    pts = _wall_points(walls, noise=0.005)
    raw = _raw_views(walls)                                                      # 15 pieces of 0.6-2 m
    reference = map_reference(pts, raw)
    candidates = np.vstack([raw, walls])                                        # the whole walls come last
    one, three, all_ = greedy_cover(candidates, reference, [1, 3, 50])
    assert np.array_equal(one, [15]) and np.array_equal(three, [15, 16, 17])
    assert len(all_) == 3                              # nothing left to cover after the three walls
    assert score_map(candidates[three], reference).recall == pytest.approx(1.0)
    assert greedy_cover(candidates, reference, []) == []
