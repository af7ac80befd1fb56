"""Shared refinement: consistent clusters, merged duplicates, gap splitting, the support rule."""

import numpy as np
import pytest

from featmap.evaluation.map_metric import sample_segments, truth_free_metrics
from featmap.fusion import FusionConfig, fuse
from featmap.fusion.base import FusionResult, fit_clusters
from featmap.fusion.gaps import (interval_union, observed_length, split_at_gaps, split_at_unresolved_gaps,
                                 trim_coarse_ends)
from featmap.fusion.refine import RefineConfig, refine
from featmap.geometry import point_segment_distance, segment_lengths
from featmap.simulation.segments import observe_walls

REFINE = RefineConfig(max_offset_m=0.07, split_gap_m=0.3)


def _config(**proposed):
    return FusionConfig.model_validate({"refine": REFINE.model_dump(), "corners": {"mode": "none"},
                                        "proposed": {"eta_m": 0.2, **proposed}})


def _one_cluster(segs, scan):
    """A FusionResult that put every segment into one cluster (what an over-eager clustering does)."""
    labels = np.zeros(len(segs), np.int64)
    fused = fit_clusters(segs, labels, 1, segment_lengths(segs))
    return FusionResult(fused, np.array([len(segs)]), labels, fused)


def _offsets(fused, wall):
    p, q = wall[:2], wall[2:]
    n = np.array([-(q - p)[1], (q - p)[0]]) / np.hypot(*(q - p))
    return np.abs((fused.reshape(-1, 2) - p) @ n)


def test_two_parallel_surfaces_in_one_cluster_are_split():
    rng = np.random.default_rng(0)
    walls = np.array([[0, 0, 10, 0], [0, 0.15, 10, 0.15]], float)      # a wall and a cabinet 15 cm before it
    segs, scan = observe_walls(walls, 10, 0.01, rng, min_fraction=0.6, first_scan=np.array([0, 0]))
    out = refine(_one_cluster(segs, scan), segs, scan, REFINE)
    assert len(out.segments) == 2
    for wall in walls:
        near = [f for f in out.segments if _offsets(f, wall).max() < 0.02]
        assert len(near) == 1
    # every member belongs to the feature of its own surface
    for k, f in enumerate(out.segments):
        members = segs[out.labels == k]
        assert np.ptp(0.5 * (members[:, 1] + members[:, 3])) < 0.1


def test_one_noisy_wall_stays_one_feature():
    rng = np.random.default_rng(1)
    wall = np.array([0.0, 0.0, 12.0, 1.0])
    segs, scan = observe_walls(wall, 25, 0.02, rng, min_fraction=0.4)
    for name in ("proposed", "density", "meanshift"):
        result = fuse(name, segs, scan, _config(min_support=2))
        assert len(result.segments) == 1, name
        assert _offsets(result.segments[0], wall).max() < 0.03


def _arc_observations(rng, radius=5.0, n_scans=30):
    """Views of a curved wall (60 deg of a 5 m circle) as straight chords of about 1 m."""
    segs, scan = [], []
    for k in range(n_scans):
        start = rng.uniform(-0.55, 0.35)
        for a in np.arange(start, start + 0.4, 0.2):
            p = radius * np.array([np.cos(a), np.sin(a)])
            q = radius * np.array([np.cos(a + 0.2), np.sin(a + 0.2)])
            segs.append(np.r_[p, q] + rng.normal(0, 0.005, 4))
            scan.append(k)
    return np.array(segs), np.array(scan)


def test_curved_wall_becomes_joined_chords_on_the_arc():
    rng = np.random.default_rng(2)
    segs, scan = _arc_observations(rng)
    plain = fuse("proposed", segs, scan, FusionConfig.model_validate({"corners": {"mode": "none"},
                                                                      "proposed": {"eta_m": 0.2}}))
    refined = fuse("proposed", segs, scan, _config(min_support=2))
    assert len(plain.segments) < len(refined.segments)
    # every fused sample lies within 5 cm of the arc; the plain chord bows far off it
    for result, ok in ((refined, True), (plain, False)):
        samples, _, _ = sample_segments(result.segments, 0.05)
        assert (np.abs(np.hypot(*samples.T) - 5.0).max() < 0.05) == ok
    # consecutive chords meet instead of overlapping: no redundancy
    points, _, _ = sample_segments(np.array([[5 * np.cos(a), 5 * np.sin(a), 5 * np.cos(a + 0.01), 5 * np.sin(a + 0.01)]
                                             for a in np.arange(-0.55, 0.75, 0.01)]), 0.01)
    m = truth_free_metrics(refined.segments, points, segs)
    assert m.redundancy < 0.02 and m.precision > 0.99


def test_doorway_splits_the_fused_line():
    rng = np.random.default_rng(3)
    left, right = np.array([0.0, 0.0, 4.0, 0.0]), np.array([5.0, 0.0, 9.0, 0.0])    # 1 m door between
    segs, scan = observe_walls(np.array([left, right]), 12, 0.01, rng, min_fraction=0.7,
                               first_scan=np.array([0, 0]))
    segs = np.vstack([segs, [[0.2, 0.0, 8.8, 0.0]]])[:-1]                               # (no bridging view)
    labels = np.zeros(len(segs), np.int64)
    fused = fit_clusters(segs, labels, 1)
    pieces, new_labels, parent = split_at_gaps(fused, segs, labels, 0.3)
    assert len(pieces) == 2 and parent.tolist() == [0, 0]
    xs = np.sort(pieces[:, [0, 2]], axis=1)
    assert xs[0, 1] <= 4.05 and xs[1, 0] >= 4.95           # nothing drawn across the door
    assert set(new_labels[segs[:, 0] < 4.5]) == {0} and set(new_labels[segs[:, 0] > 4.5]) == {1}
    # through the registry, with every method
    for name in ("proposed", "density"):
        result = fuse(name, segs, np.arange(len(segs)) % 12, _config(min_support=2))
        assert len(result.segments) == 2, name


def _buildings_in_line(coarse_gap_m: float = 9.0):
    """Two facades in line on y = 0 ([0, 20] and [26, 50] m, a 6 m passage between) seen head-on in 10
    scans each (returns 0.2 m apart), and 6 far views at grazing incidence that span -4 .. 45 m with
    columns of returns ``coarse_gap_m`` apart: (segments (N, 4), scan (N,), max_gap (N,))."""
    rng = np.random.default_rng(5)
    walls = np.array([[0.0, 0.0, 20.0, 0.0], [26.0, 0.0, 50.0, 0.0]])
    near, near_scan = observe_walls(walls, 10, 0.01, rng, min_fraction=0.9, first_scan=np.array([0, 10]))
    far = np.column_stack([rng.uniform(-4.2, -3.8, 6), rng.normal(0, 0.02, 6), rng.uniform(44.8, 45.2, 6),
                           rng.normal(0, 0.02, 6)])
    segs = np.vstack([near, far])
    scan = np.r_[near_scan, 20 + np.arange(6)]
    max_gap = np.r_[np.full(len(near), 0.2), np.full(6, coarse_gap_m)]
    return segs, scan, max_gap


def test_a_passage_that_only_coarse_views_cover_is_cut_there_and_nowhere_else():
    segs, scan, max_gap = _buildings_in_line()
    labels = np.zeros(len(segs), np.int64)
    fused = fit_clusters(segs, labels, 1)
    pieces, new_labels, parent = split_at_unresolved_gaps(fused, segs, labels, max_gap, 3.0)
    assert len(pieces) == 2 and parent.tolist() == [0, 0]
    xs = np.sort(np.sort(pieces[:, [0, 2]], axis=1), axis=0)
    near_ends = np.sort(segs[:20, [0, 2]], axis=1)
    assert xs[0, 1] == pytest.approx(near_ends[:10, 1].max(), abs=1e-6)     # cut where the facades' views end ...
    assert xs[1, 0] == pytest.approx(near_ends[10:, 0].min(), abs=1e-6)     # ... and start again
    assert xs[0, 0] < -3.7 and xs[1, 1] > 49.5                             # the ends stay as the views drew them
    assert set(new_labels) == {0, 1}
    assert np.array_equal(pieces[0, :2], fused[0, :2]) and np.array_equal(pieces[-1, 2:], fused[0, 2:])   # ends kept exactly
    # The views that resolve 3 m gaps leave none: nothing to cut, the feature stays exactly as it was.
    assert np.array_equal(split_at_unresolved_gaps(fused, segs, labels, max_gap, 7.0)[0], fused)
    # One view spanning the passage with returns 4 m apart (closer than the passage is long) shows wall in it.
    shown = max_gap.copy()
    shown[-1] = 4.0
    assert len(split_at_unresolved_gaps(fused, segs, labels, shown, 3.0)[0]) == 1
    # Every member resolving, or none: nothing to weigh, nothing cut.
    assert len(split_at_unresolved_gaps(fused, segs, labels, np.full(len(segs), 0.2), 3.0)[0]) == 1
    assert len(split_at_unresolved_gaps(fused, segs, labels, np.full(len(segs), 9.0), 3.0)[0]) == 1


def test_resolved_gap_split_through_the_registry_needs_the_max_gap_column():
    segs, scan, max_gap = _buildings_in_line()
    on = FusionConfig.model_validate({"refine": {"resolved_gap_m": 3.0}, "corners": {"mode": "none"}})
    off = FusionConfig.model_validate({"refine": {"resolved_gap_m": 0.0}, "corners": {"mode": "none"}})
    bridged = fuse("proposed", segs, scan, off, max_gap=max_gap)
    assert len(bridged.segments) == 1                                       # the far views join the facades
    cut = fuse("proposed", segs, scan, on, max_gap=max_gap)
    assert len(cut.segments) == 2 and cut.extras["refine"]["unresolved_gap_pieces"] == 1
    ends = np.sort(np.sort(cut.segments[:, [0, 2]], axis=1), axis=0)
    assert 19.5 < ends[0, 1] < 20.5 and 25.5 < ends[1, 0] < 26.5
    assert np.array_equal(fuse("proposed", segs, scan, on).segments, bridged.segments)     # no column: off


def _wall_with_a_coarse_end(coarse_to_m: float = 22.5, coarse_gap_m: float = 3.0):
    """A facade on y = 0 from 0 to 20 m seen head-on in 10 scans (returns 0.2 m apart) and in 6 far views at
    grazing incidence (columns ``coarse_gap_m`` apart) that run on to ``coarse_to_m``: (segments (16, 4),
    max_gap (16,))."""
    rng = np.random.default_rng(8)
    fine = np.column_stack([rng.uniform(0.0, 0.05, 10), rng.normal(0, 0.01, 10), rng.uniform(19.95, 20.0, 10),
                            rng.normal(0, 0.01, 10)])
    fine[0, 2] = 20.0
    coarse = np.column_stack([rng.uniform(0.0, 0.05, 6), rng.normal(0, 0.01, 6),
                              rng.uniform(coarse_to_m - 0.05, coarse_to_m, 6), rng.normal(0, 0.01, 6)])
    coarse[0, 2] = coarse_to_m
    return np.vstack([fine, coarse]), np.r_[np.full(10, 0.2), np.full(6, coarse_gap_m)]


def test_a_coarse_end_running_on_to_the_next_building_in_line_is_cut_back_to_the_fine_views():
    segs, max_gap = _wall_with_a_coarse_end()
    labels = np.zeros(len(segs), np.int64)
    wall = fit_clusters(segs, labels, 1)
    assert wall[0, [0, 2]].max() == pytest.approx(22.5, abs=0.02)           # drawn to the coarse views' end
    next_building = np.array([[23.0, 0.3, 40.0, 0.3]])                       # in line, 0.3 m offset, 3 m on
    fused = np.vstack([wall, next_building])
    out, cut = trim_coarse_ends(fused, segs, labels, max_gap, 1.5)
    assert cut == 1
    assert out[0, [0, 2]].max() == pytest.approx(20.0, abs=0.01)            # where the fine views end
    assert np.array_equal(out[1], fused[1])                                  # the other feature as it was
    start = np.argmin(wall[0, [0, 2]])
    assert np.array_equal(out[0, 2 * start:2 * start + 2], wall[0, 2 * start:2 * start + 2])   # other end exact
    # Nothing in line beyond (a wall's far part only far views see): kept exactly.
    alone, cut = trim_coarse_ends(wall, segs, labels, max_gap, 1.5)
    assert cut == 0 and np.array_equal(alone, wall)
    # The next feature on this one's own line may be the same wall beyond a stretch nothing saw well: kept.
    same_line = np.vstack([wall, next_building - [0, 0.3, 0, 0.3]])
    assert trim_coarse_ends(same_line, segs, labels, max_gap, 1.5)[1] == 0
    # A building beside the line, not in it (2 m off): kept.
    beside = np.vstack([wall, next_building + [0, 1.7, 0, 1.7]])
    assert trim_coarse_ends(beside, segs, labels, max_gap, 1.5)[1] == 0
    # A stretch of several coarse columns (5 m past the fine views, 1.5 x 3 m = 4.5 m): evidence of wall, kept.
    segs5, gap5 = _wall_with_a_coarse_end(coarse_to_m=25.0)
    wall5 = fit_clusters(segs5, labels, 1)
    far_next = np.array([[26.0, 0.3, 40.0, 0.3]])
    assert trim_coarse_ends(np.vstack([wall5, far_next]), segs5, labels, gap5, 1.5)[1] == 0
    # Every member as fine as the others: nothing to weigh, nothing cut.
    assert trim_coarse_ends(fused, segs, labels, np.full(len(segs), 0.2), 1.5)[1] == 0


def test_coarse_end_trim_through_the_registry_is_on_by_default_and_off_at_zero():
    segs, max_gap = _wall_with_a_coarse_end()
    rng = np.random.default_rng(9)
    next_segs, _ = observe_walls(np.array([23.0, 0.3, 40.0, 0.3]), 10, 0.01, rng, min_fraction=0.9)
    segs = np.vstack([segs, next_segs])
    max_gap = np.r_[max_gap, np.full(len(next_segs), 0.2)]
    scan = np.r_[np.arange(10), 20 + np.arange(6), np.arange(len(next_segs))]
    base = {"proposed": {"min_support": 2}, "corners": {"mode": "none"}}
    off = fuse("proposed", segs, scan, FusionConfig.model_validate({**base, "refine": {"coarse_end_factor": 0.0}}),
               max_gap=max_gap)
    on = fuse("proposed", segs, scan, FusionConfig.model_validate(base), max_gap=max_gap)
    assert len(off.segments) == len(on.segments) == 2
    assert off.segments[:, [0, 2]].max(axis=1).min() == pytest.approx(22.5, abs=0.05)   # runs into the passage
    assert on.segments[:, [0, 2]].max(axis=1).min() == pytest.approx(20.0, abs=0.05)    # ends with the facade
    assert on.extras["refine"]["coarse_ends_cut"] == 1 and "coarse_ends_cut" not in off.extras["refine"]


def test_views_of_one_wall_left_in_two_clusters_are_merged():
    rng = np.random.default_rng(4)
    wall = np.array([0.0, 0.0, 20.0, 0.0])
    segs, scan = observe_walls(wall, 16, 0.01, rng, min_fraction=0.3)
    mid = 0.5 * (segs[:, 0] + segs[:, 2])
    labels = (mid > 10).astype(np.int64)
    fused = fit_clusters(segs, labels, 2)
    result = FusionResult(fused, np.bincount(labels), labels, fused)
    out = refine(result, segs, scan, REFINE)
    assert len(out.segments) == 1 and out.support.tolist() == [len(segs)]
    # two parallel walls 30 cm apart are never merged
    segs2, scan2 = observe_walls(np.array([[0, 0, 10, 0], [0, 0.3, 10, 0.3]], float), 8, 0.01, rng,
                                 first_scan=np.array([0, 0]))
    labels2 = (segs2[:, 1] > 0.15).astype(np.int64)
    fused2 = fit_clusters(segs2, labels2, 2)
    out2 = refine(FusionResult(fused2, np.bincount(labels2), labels2, fused2), segs2, scan2, REFINE)
    assert len(out2.segments) == 2


def test_dropped_segments_on_a_kept_wall_join_it_and_others_stay_dropped():
    rng = np.random.default_rng(5)
    wall = np.array([0.0, 0.0, 10.0, 0.0])
    segs, scan = observe_walls(wall, 10, 0.01, rng)
    stray = np.array([[3.0, 2.0, 4.0, 2.5]])
    segs = np.vstack([segs, [[2.0, 0.01, 3.0, 0.01]], stray])
    scan = np.r_[scan, 50, 51]
    labels = np.r_[np.zeros(10, np.int64), -1, -1]
    fused = fit_clusters(segs, labels, 1)
    out = refine(FusionResult(fused, np.array([10]), labels, fused), segs, scan, REFINE)
    assert out.labels[10] == 0 and out.labels[11] == -1 and out.support.tolist() == [11]


def test_a_short_view_slightly_askew_at_a_long_walls_end_joins_it_and_a_parallel_surface_does_not():
    """A 3.5 m view starting 3 cm off a 20 m wall, 2 deg askew, lies on the wall (its endpoints 3 and 15 cm
    from the wall's line, 9 cm on average), though the wall's far end is 0.56 m from the view's own line; a
    view 0.3 m in front of the wall is another surface."""
    rng = np.random.default_rng(3)
    wall = np.array([0.0, 0.0, 20.0, 0.0])
    segs, scan = observe_walls(wall, 6, 0.005, rng)
    a = np.deg2rad(2.0)
    askew = np.array([[17.0, 0.03, 17.0 + 3.5 * np.cos(a), 0.03 + 3.5 * np.sin(a)]])
    parallel = np.array([[5.0, 0.3, 8.5, 0.3]])
    segs = np.vstack([segs, askew, parallel])
    scan = np.r_[scan, 50, 51]
    labels = np.r_[np.zeros(6, np.int64), -1, -1]
    fused = fit_clusters(segs, labels, 1)
    config = RefineConfig(max_offset_m=0.15)
    out = refine(FusionResult(fused, np.array([6]), labels, fused), segs, scan, config)
    assert out.labels[6] == 0 and out.labels[7] == -1
    assert np.abs(out.segments[0, [1, 3]]).max() < 0.05


def test_a_kept_short_duplicate_slightly_askew_on_a_long_wall_merges_and_a_parallel_surface_does_not():
    """Two kept features: a 20 m wall and a 3 m duplicate at its end, 2 deg askew (its endpoints 0 and
    10 cm from the wall's line, within half of max_offset_m on average; the wall's far end 0.59 m from
    the duplicate's own line). They merge only with ``kept_heavier_ratio``; a kept 3 m feature 0.3 m in
    front of the wall never does."""
    rng = np.random.default_rng(5)
    wall = np.array([0.0, 0.0, 20.0, 0.0])
    segs, scan = observe_walls(wall, 6, 0.005, rng)
    a = np.deg2rad(2.0)
    askew = np.array([17.0, 0.0, 17.0 + 3.0 * np.cos(a), 3.0 * np.sin(a)])
    front = np.array([5.0, 0.3, 8.0, 0.3])
    segs = np.vstack([segs, np.tile(askew, (3, 1)), np.tile(front, (3, 1))])
    segs[6:] += rng.normal(0.0, 0.002, (6, 4))
    scan = np.r_[scan, 50, 51, 52, 60, 61, 62]
    labels = np.r_[np.zeros(6, np.int64), 1, 1, 1, 2, 2, 2]
    fused = fit_clusters(segs, labels, 3)
    result = FusionResult(fused, np.bincount(labels), labels, fused)
    merged = refine(result, segs, scan, RefineConfig(max_offset_m=0.15, kept_heavier_ratio=0.5))
    assert len(merged.segments) == 2
    assert merged.labels[6] == merged.labels[0] != merged.labels[9]
    assert np.abs(merged.segments[merged.labels[0], [1, 3]]).max() < 0.05
    apart = refine(result, segs, scan, RefineConfig(max_offset_m=0.15, kept_heavier_ratio=0.0))
    assert len(apart.segments) == 3


def test_support_length_rule_keeps_a_long_wall_seen_twice():
    rng = np.random.default_rng(6)
    walls = np.array([[0, 0, 6, 0], [0, 5, 0.6, 5]], float)          # a 6 m wall and a 0.6 m object
    segs, scan = observe_walls(walls, 2, 0.005, rng, min_fraction=0.9)
    paper = fuse("proposed", segs, scan, _config(min_support=4, min_support_length_m=None))
    ours = fuse("proposed", segs, scan, _config(min_support=4, min_support_length_m=2.0))
    assert len(paper.segments) == 0
    assert len(ours.segments) == 1 and _offsets(ours.segments[0], walls[0]).max() < 0.02


def test_members_lie_on_their_feature_and_refine_is_order_independent():
    rng = np.random.default_rng(7)
    walls = np.array([[0, 0, 10, 0], [10, 0, 10, 8], [0, 0.15, 6, 0.15], [3, 5, 7, 5], [8, 5, 9.5, 5]], float)
    segs, scan = observe_walls(walls, 8, 0.01, rng, min_fraction=0.5)
    a = fuse("density", segs, scan, _config())
    perm = rng.permutation(len(segs))
    b = fuse("density", segs[perm], scan[perm], _config())
    assert np.allclose(a.segments, b.segments) and np.array_equal(a.labels[perm], b.labels)
    kept = a.labels >= 0
    mids = 0.5 * (segs[kept, :2] + segs[kept, 2:])
    assert point_segment_distance(mids, a.segments[a.labels[kept]]).max() < 0.07


def test_interval_union_and_observed_length():
    group = np.array([0, 0, 0, 1, 1])
    lo = np.array([0.0, 1.0, 3.0, 0.0, 0.5])
    hi = np.array([1.2, 2.0, 4.0, 1.0, 0.8])
    g, plo, phi, piece = interval_union(group, lo, hi, 2, min_gap=0.5)
    assert g.tolist() == [0, 0, 1] and plo.tolist() == [0.0, 3.0, 0.0] and phi.tolist() == [2.0, 4.0, 1.0]
    assert piece.tolist() == [0, 0, 1, 2, 2]
    fused = np.array([[0, 0, 4, 0], [0, 1, 1, 1]], float)
    segs = np.c_[lo, np.where(group == 0, 0.0, 1.0), hi, np.where(group == 0, 0.0, 1.0)]
    assert observed_length(fused, segs, group) == pytest.approx([3.0, 1.0])


def test_refine_off_changes_nothing():
    rng = np.random.default_rng(8)
    segs, scan = observe_walls(np.array([0.0, 0.0, 10.0, 0.0]), 10, 0.02, rng)
    result = fuse("proposed", segs, scan)
    assert refine(result, segs, scan, RefineConfig(max_offset_m=0.0, split_gap_m=0.0)) is result
