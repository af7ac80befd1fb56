"""Known answers for the per-scan observation metrics of the generalization benchmark."""

import numpy as np
import pytest

from featmap.evaluation import GroundTruth, truth_metrics
from featmap.evaluation.observation_metrics import (fusion_losses, lies_on_matrix, match_observations, merge_intervals,
                                                   observation_samples, truth_from_observations, uncovered_stretches,
                                                   union_coverage)
from featmap.io.sim_truth import ScanObservations
from featmap.simulation.observations import concatenate, observe_scan

WALLS = np.array([[0.0, 0.0, 10.0, 0.0],       # wall 0: along x
                  [10.0, 0.0, 10.0, 8.0]])     # wall 1: along y, meets wall 0 at (10, 0)


def _obs(rows):
    """rows: (frame, wall, n_hits, [(start, end), ...])."""
    parts = []
    for frame, wall, hits, intervals in rows:
        starts = np.array([a for a, _ in intervals], float)
        ends = np.array([b for _, b in intervals], float)
        parts.append(ScanObservations(np.array([frame]), np.array([wall]), np.array([hits]), starts[:1], ends[-1:],
                                      np.array([float((ends - starts).sum())]), np.array([0, len(intervals)]),
                                      starts, ends))
    return concatenate(parts)


def test_observe_scan_splits_at_occlusions_and_counts_hits():
    s = np.concatenate([np.arange(0.0, 3.01, 0.1), np.arange(4.5, 6.01, 0.1), [2.0, 2.05]])
    wall = np.concatenate([np.zeros(len(s) - 2, int), [1, 1]])
    obs = observe_scan(7, wall, s, spacing=np.full(len(s), 0.1))        # gaps above max(0.5, 0.25) split
    assert obs.frame.tolist() == [7, 7] and obs.wall.tolist() == [0, 1]
    assert obs.n_hits.tolist() == [len(s) - 2, 2]
    assert obs.intervals(0) == [(0.0, pytest.approx(3.0)), (4.5, pytest.approx(6.0, abs=0.06))]
    assert obs.observed_m[0] == pytest.approx(3.0 + (obs.intervals(0)[1][1] - 4.5))
    assert obs.extent_m[0] == pytest.approx(obs.s_max[0])
    # sparse far hits: a 1.2 m spacing keeps 1.5 m gaps inside one stretch
    far = observe_scan(0, np.zeros(5, int), np.arange(5) * 1.5, spacing=np.full(5, 1.2))
    assert far.intervals(0) == [(0.0, 6.0)]


def test_subset_keeps_each_observations_intervals():
    obs = _obs([(0, 0, 100, [(0, 2), (3, 4)]), (1, 0, 60, [(5, 9)]), (1, 1, 10, [(0, 1)])])
    sub = obs.subset(obs.frame == 1)
    assert sub.wall.tolist() == [0, 1] and sub.intervals(0) == [(5.0, 9.0)] and sub.intervals(1) == [(0.0, 1.0)]
    assert obs.counting().tolist() == [True, True, False]


def test_observation_samples_cover_the_observed_length():
    obs = _obs([(0, 0, 100, [(0, 2), (3, 4)]), (0, 1, 80, [(1, 6)])])
    pts, owner, weight = observation_samples(WALLS, obs)
    assert weight[owner == 0].sum() == pytest.approx(3.0) and weight[owner == 1].sum() == pytest.approx(5.0)
    assert np.allclose(pts[owner == 0, 1], 0) and np.all(pts[owner == 1, 0] == 10)
    assert pts[owner == 1, 1].min() > 1.0 and pts[owner == 1, 1].max() < 6.0


def test_lies_on_uses_the_tolerances_of_evaluation():
    pts = np.array([[5.0, 0.29], [5.0, 0.31], [-0.29, 0.0], [-0.31, 0.0]])
    dirs = np.tile([1.0, 0.0], (4, 1))
    ok = lies_on_matrix(pts, dirs, np.array([[0.0, 0.0, 10.0, 0.0]]))[:, 0]
    assert ok.tolist() == [True, False, True, False]
    tilted = np.array([[np.cos(np.deg2rad(a)), np.sin(np.deg2rad(a))] for a in (9.0, 11.0)])
    assert lies_on_matrix(np.array([[5.0, 0.0]] * 2), tilted, np.array([[0.0, 0.0, 10.0, 0.0]]))[:, 0].tolist() == [True, False]


def test_match_observations_known_answers():
    # scan 0 saw all of wall 0 and 5 m of wall 1; scan 1 saw wall 0 only
    obs = _obs([(0, 0, 500, [(0, 10)]), (0, 1, 120, [(0, 5)]), (1, 0, 400, [(0, 10)])])
    segments = np.array([
        [1.0, 0.1, 6.0, 0.1],        # scan 0, on wall 0 (10 cm off): covers x in [0.7, 6.3] -> 5.6 m
        [10.0, 0.0, 10.5, 3.0],      # scan 0, 9.5 deg off wall 1 but up to 0.5 m away: 0.3 m tolerance -> partly
        [2.0, 0.5, 8.0, 0.5],        # scan 1, 0.5 m off wall 0: nothing
        [10.2, 2.0, 10.2, 2.3],      # scan 1, on wall 1: but scan 1 did not observe wall 1
    ])
    scan = np.array([0, 0, 1, 1])
    m = match_observations(WALLS, obs, segments, scan, sensor_xy={0: np.array([5.0, -10.0]), 1: np.array([5.0, -60.0])})
    assert m.covered_m[0] == pytest.approx(5.6) and m.best_m[0] == pytest.approx(5.6)
    assert m.found.tolist()[0] is True and m.found.tolist()[2] is False
    assert m.covered_m[2] == 0.0
    assert m.sampled_m.tolist() == pytest.approx([10.0, 5.0, 10.0])
    assert m.coverage[0] == pytest.approx(0.56)
    # the tilted segment: a sample at y lies on it while its offset y * tan(9.46 deg) <= 0.3 m (y <= 1.8 m)
    assert m.best_m[1] == pytest.approx(1.8, abs=0.11) and m.found[1]
    assert m.min_distance_m.tolist() == pytest.approx([10.0, np.hypot(5.0, 10.0), 60.0], abs=0.06)


def test_short_segment_needs_one_metre_on_the_wall():
    obs = _obs([(0, 0, 500, [(0, 10)])])
    for length, found in ((0.3, False), (0.5, True)):   # the 0.3 m end tolerances count: 0.3 + 0.6 < 1 <= 0.5 + 0.6
        m = match_observations(WALLS, obs, np.array([[4.0, 0.0, 4.0 + length, 0.0]]), np.array([0]))
        assert bool(m.found[0]) is found


def test_drive_truth_is_the_union_of_counting_observations():
    assert merge_intervals([(3, 4), (0, 2), (1.5, 2.5), (4, 5)]) == [(0, 2.5), (3, 5)]
    base = GroundTruth(walls=WALLS, building=np.array(["a", "a"]), labels=np.array([["", ""], ["", ""]]),
                       observed=[[], []], n_returns=np.zeros(2, int))
    obs = _obs([(0, 0, 100, [(0, 4)]), (1, 0, 100, [(3, 7)]), (1, 1, 20, [(0, 8)]), (2, 1, 70, [(0, 1.5)])])
    truth = truth_from_observations(base, obs)
    assert truth.observed == [[(0.0, 7.0)], []] and truth.n_returns.tolist() == [200, 0]
    assert truth.observable().tolist() == [True, False]
    # coverage of the union of segments = recall of those segments as a map
    segments = np.array([[0.0, 0.0, 2.0, 0.0], [5.0, 0.05, 6.0, 0.05]])
    expected = (2.0 + 0.3 + 1.6) / 7.0                  # [0, 2.3] and [4.7, 6.3] of [0, 7]
    assert union_coverage(segments, truth) == pytest.approx(expected, abs=0.015)
    assert union_coverage(segments, truth) == pytest.approx(truth_metrics(segments, truth)["recall"])
    assert union_coverage(np.zeros((0, 4)), truth) == 0.0


def test_uncovered_stretches_and_how_they_were_seen():
    base = GroundTruth(walls=WALLS, building=np.array(["a", "a"]), labels=np.array([["", ""], ["", ""]]),
                       observed=[[], []], n_returns=np.zeros(2, int))
    obs = _obs([(0, 0, 500, [(0, 10)]), (1, 0, 400, [(0, 10)]), (3, 0, 300, [(0, 10)]),
                (4, 0, 60, [(0, 2)]),            # sees only the first 2 m of wall 0
                (2, 1, 80, [(0, 8)])])           # wall 1, from almost straight along it
    truth = truth_from_observations(base, obs)
    sensors = {0: np.array([5.0, -10.0]), 1: np.array([5.0, -90.0]), 3: np.array([5.0, -20.0]),
               4: np.array([1.0, -5.0]), 2: np.array([10.5, -40.0])}
    segments = np.array([[1.0, 0.0, 4.0, 0.0]])          # covers x in [0.7, 4.3] of wall 0 (0.3 m tolerance)
    lost = uncovered_stretches(segments, truth, obs, sensors)
    # longest first: all of wall 1, then wall 0 beyond the segment, then before it
    assert lost.wall.tolist() == [1, 0, 0]
    assert lost.start == pytest.approx([0.0, 4.3, 0.0], abs=0.06)
    assert lost.end == pytest.approx([8.0, 10.0, 0.7], abs=0.06)
    assert lost.observed_m == pytest.approx(18.0)
    assert lost.length.sum() == pytest.approx((1 - union_coverage(segments, truth)) * 18.0, abs=1e-9)
    assert lost.n_views.tolist() == [1, 3, 4]              # scan 4 saw only [0, 2]
    assert lost.max_hits.tolist() == [80, 500, 500]
    # wall 1 from (10.5, -40): 44 m away, 89.3 deg from head-on; wall 0's far stretch nearest from scan 0
    assert lost.nearest_m[0] == pytest.approx(np.hypot(0.5, 44.0), abs=1e-6)
    assert lost.best_incidence_deg[0] == pytest.approx(np.degrees(np.arccos(0.5 / np.hypot(0.5, 44.0))), abs=1e-6)
    assert lost.nearest_m[1] == pytest.approx(np.hypot(7.15 - 5.0, 10.0), abs=0.05)
    assert lost.nearest_incidence_deg[1] == pytest.approx(np.degrees(np.arctan(2.15 / 10.0)), abs=0.3)
    assert lost.kind().tolist() == ["grazing", "other", "other"]
    # the same stretches seen from fewer places: only from 90 m away, or by two scans
    far = uncovered_stretches(segments, truth, obs, {1: sensors[1]})
    assert far.kind().tolist() == ["few views", "far", "far"] and far.n_views.tolist() == [0, 1, 1]   # wall 1: no view known
    few = uncovered_stretches(segments, truth, obs, {0: sensors[0], 3: sensors[3], 2: sensors[2]})
    assert few.kind().tolist() == ["grazing", "few views", "few views"]
    # nothing lost when everything is covered; every view unknown when no sensor position is
    assert len(uncovered_stretches(np.array([[0.0, 0.0, 10.0, 0.0], [10.0, 0.0, 10.0, 8.0]]), truth, obs, sensors)) == 0
    unknown = uncovered_stretches(segments, truth, obs, {})
    assert unknown.n_views.tolist() == [0, 0, 0] and np.isnan(unknown.nearest_m).all()


def test_fusion_losses_split_what_the_map_does_not_keep():
    truth = GroundTruth(walls=WALLS, building=np.array(["a", "a"]), labels=np.array([["", ""], ["", ""]]),
                        observed=[[(0.0, 10.0)], [(0.0, 8.0)]], n_returns=np.full(2, -1))
    segments = np.array([[1.0, 0.0, 4.0, 0.0],     # kept: covers [0.7, 4.3] of wall 0 (0.3 m tolerance)
                         [6.0, 0.0, 8.0, 0.0],     # dropped, and nothing kept covers [5.7, 8.3]
                         [2.0, 0.0, 3.0, 0.0],     # dropped, but inside the kept one
                         [0.0, 5.0, 2.0, 5.0]])    # dropped clutter, 5 m off every wall
    dropped = np.array([False, True, True, True])
    fused = np.array([[1.5, 0.0, 4.0, 0.0],        # the fit lost [0.7, 1.2] of the kept segment's coverage
                      [10.0, 6.5, 10.0, 7.5]])     # covers [6.2, 7.8] of wall 1, where no segment lies
    loss = fusion_losses(segments, dropped, fused, truth)
    assert loss.observed_m == pytest.approx(18.0)
    assert loss.segments_m == pytest.approx(3.6 + 2.6, abs=0.1)
    assert loss.fused_m == pytest.approx(3.1 + 1.6, abs=0.1)
    assert loss.filtered_m == pytest.approx(2.6, abs=0.1)
    assert loss.fit_m == pytest.approx(0.5, abs=0.1)
    assert loss.gained_m == pytest.approx(1.6, abs=0.1)
    assert loss.segments_m - loss.fused_m == pytest.approx(loss.filtered_m + loss.fit_m - loss.gained_m, abs=1e-9)
    assert loss.dropped_wall_m == pytest.approx(3.0) and loss.dropped_other_m == pytest.approx(2.0)
    # the same map as the metrics see it: its recall and the segments' coverage
    assert loss.fused_m / loss.observed_m == pytest.approx(truth_metrics(fused, truth)["recall"], abs=1e-9)
    assert loss.segments_m / loss.observed_m == pytest.approx(union_coverage(segments, truth), abs=1e-9)
    # nothing dropped: nothing filtered, and no dropped length
    kept_all = fusion_losses(segments[:1], np.zeros(1, bool), segments[:1], truth)
    assert (kept_all.filtered_m, kept_all.fit_m, kept_all.gained_m, kept_all.dropped_wall_m) == (0.0, 0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="dropped has 3 entries for 4 segments"):
        fusion_losses(segments, dropped[:3], fused, truth)
