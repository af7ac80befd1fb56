"""Known answers for every metric of EVALUATION.md on a 20 m x 10 m building."""

import numpy as np
import pytest

from featmap.evaluation.truth_metrics import GroundTruth, lies_on, sample_segments, truth_metrics, walls_near

WALLS = np.array([[0, 0, 20, 0], [20, 0, 20, 10], [20, 10, 0, 10], [0, 10, 0, 0]], float)
LABELS = np.array([["a", "b"], ["b", "c"], ["c", "d"], ["d", "a"]])


def _truth(observed=None, n_returns=None, other=np.zeros((0, 4)), poles=np.zeros((0, 3))):
    lengths = np.hypot(WALLS[:, 2] - WALLS[:, 0], WALLS[:, 3] - WALLS[:, 1])
    return GroundTruth(walls=WALLS, building=np.array(["A"] * 4), labels=LABELS,
                       observed=observed if observed is not None else [[(0.0, float(L))] for L in lengths],
                       n_returns=np.asarray(n_returns if n_returns is not None else [1000] * 4),
                       other_segments=np.asarray(other, float).reshape(-1, 4), poles=np.asarray(poles, float).reshape(-1, 3))


def test_the_walls_themselves_score_perfectly():
    m = truth_metrics(WALLS, _truth())
    assert m["count"] == 4 and m["observable_walls"] == 4 and m["count_ratio"] == 1.0
    assert m["precision"] == pytest.approx(1.0) and m["precision_any"] == pytest.approx(1.0)
    assert m["recall"] == pytest.approx(1.0) and m["redundancy"] == 1.0
    assert m["offset_cm"] == pytest.approx(0.0, abs=1e-9) and m["corner_err_cm"] == pytest.approx(0.0, abs=1e-9)
    assert m["corners_evaluated"] == 4
    assert m["vertex_error_sum_m"] == {lab: pytest.approx(0.0, abs=1e-9) for lab in "abcd"}


def test_one_wall_10cm_off():
    fused = np.array([[0, 0.1, 20, 0.1]])
    m = truth_metrics(fused, _truth())
    assert m["precision"] == pytest.approx(1.0)                 # within TOL = 0.30 m
    assert m["recall"] == pytest.approx(20 / 60)                # one wall of 60 m
    assert m["offset_cm"] == pytest.approx(10.0)
    assert m["count_ratio"] == 0.25 and m["redundancy"] == 1.0
    # corners a and b: 10 cm to the nearest fused endpoint; c and d: capped at 200 cm
    assert m["corner_err_cm"] == pytest.approx((10 + 10 + 200 + 200) / 4)
    # vertex a: the feature of wall a-b ends 0.1 m from it; wall d-a has no feature
    assert m["vertex_error_sum_m"]["a"] is None and m["vertex_error_sum_m"]["b"] is None


def test_far_tilted_and_fence_segments_are_not_on_the_building():
    beyond_tol = np.array([[0, 0.4, 20, 0.4]])
    assert truth_metrics(beyond_tol, _truth())["precision"] == 0.0
    tilted = np.array([[0, 0, 10, 10 * np.tan(np.deg2rad(15))]])    # 15 deg > ANG = 10 deg
    m = truth_metrics(tilted, _truth())
    assert m["precision"] < 0.2 and m["recall"] == 0.0
    fence = np.array([[2, -3, 12, -3]])
    m = truth_metrics(fence, _truth(other=[[0, -3, 15, -3]]))
    assert m["precision"] == 0.0 and m["precision_any"] == pytest.approx(1.0)
    pole = np.array([[30, 5, 30.2, 5]])
    assert truth_metrics(pole, _truth(poles=[[30.1, 5, 0.15]]))["precision_any"] == pytest.approx(1.0)


def test_redundancy_counts_features_covering_a_metre_or_more():
    halves = np.array([[0, 0, 12, 0], [8, 0.05, 20, 0.05], [19.5, 0, 20, 0]])   # the last covers only 0.5 m
    m = truth_metrics(halves, _truth())
    assert m["redundancy"] == 2.0
    assert m["offset_cm"] == pytest.approx(100 * 0.05 * 12 / 24.5, abs=0.05)


def test_only_the_observed_part_of_an_observable_wall_counts():
    observed = [[(0.0, 10.0)], [(0.0, 1.5)], [], [(0.0, 10.0)]]     # wall 2: 1.5 m < 2 m, wall 3: unseen
    truth = _truth(observed=observed, n_returns=[1000, 1000, 0, 30])  # wall 4: 30 returns < 50
    assert truth.observable().tolist() == [True, False, False, False]
    m = truth_metrics(np.array([[0, 0, 10, 0]]), truth)
    assert m["observable_walls"] == 1 and m["recall"] == pytest.approx(1.0)
    assert m["corners_evaluated"] == 0 and m["corner_err_cm"] is None


def test_vertex_error_sums_use_the_features_of_the_vertex_walls():
    fused = WALLS.copy()
    fused[0] = [0.3, 0.0, 20, 0.0]          # wall a-b starts 0.3 m from a
    fused[3] = [0.0, 10.0, 0.0, 0.2]        # wall d-a ends 0.2 m from a
    m = truth_metrics(fused, _truth())
    assert m["vertex_error_sum_m"]["a"] == pytest.approx(0.5)
    assert m["vertex_error_sum_m"]["b"] == pytest.approx(0.0, abs=1e-9)


def test_no_features():
    m = truth_metrics(np.zeros((0, 4)), _truth())
    assert m["count"] == 0 and m["precision"] is None and m["recall"] == 0.0 and m["corner_err_cm"] is None


def test_sampling_and_lies_on():
    pts, owner, weight = sample_segments(np.array([[0, 0, 1, 0], [0, 0, 0, 0.25]]), step=0.1)
    assert len(pts) == 10 + 3 and weight[:10].sum() == pytest.approx(1.0) and weight[10:].sum() == pytest.approx(0.25)
    ok, perp = lies_on(np.array([[5, 0.2], [5, 0.35], [-0.25, 0], [-0.4, 0]]), np.tile([1.0, 0.0], (4, 1)),
                       np.array([0, 0, 20, 0.0]))
    assert ok.tolist() == [True, False, True, False] and perp[0] == pytest.approx(0.2)


def test_walls_far_from_every_feature_change_no_score():
    """Precision only looks at the walls a feature comes near (``walls_near``): the same building among
    2,000 unobserved walls 50 m-2 km away, or a wall just within the tolerance, gives the same scores."""
    rng = np.random.default_rng(0)
    start = rng.uniform(50, 2000, (2000, 2)) * rng.choice([-1, 1], (2000, 2))
    far = np.column_stack([start, start + rng.uniform(-20, 20, (2000, 2))])
    base = _truth()
    crowded = GroundTruth(walls=np.concatenate([WALLS, far]), building=np.array(["A"] * 4 + ["B"] * 2000),
                          labels=np.concatenate([LABELS, np.full((2000, 2), "")]),
                          observed=base.observed + [[]] * 2000, n_returns=np.concatenate([base.n_returns, [0] * 2000]))
    fused = np.array([[0, 0.1, 20, 0.1], [20.2, 0, 20.2, 10], [5, 10.29, 15, 10.29], [-3, 3, -3, 8]])
    assert truth_metrics(fused, crowded) == truth_metrics(fused, base)
    # (a circle around each wall's centre: the wall's half length plus the reach)
    assert walls_near(WALLS, np.array([[10.0, -10.31]]), 0.3).tolist() == [False, False, False, False]
    assert walls_near(WALLS, np.array([[20.29, 5.0]]), 0.3).tolist() == [False, True, False, False]
    assert walls_near(WALLS, np.zeros((0, 2)), 0.3).tolist() == [False] * 4
