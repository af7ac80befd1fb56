import numpy as np
import pytest

from featmap.fusion import FusionConfig, fuse
from featmap.fusion.base import SupportViews
from featmap.fusion.proposed import ProposedConfig, evaluate_pairs, fuse_proposed, support_rule
from featmap.geometry import point_segment_distance
from featmap.simulation.segments import observe_walls


def _max_dist_to_line(fused, wall):
    """Largest distance of the fused endpoints to the infinite line of ``wall``."""
    p, q = np.asarray(wall[:2]), np.asarray(wall[2:])
    n = np.array([-(q - p)[1], (q - p)[0]]) / np.hypot(*(q - p))
    return max(abs((fused[:2] - p) @ n), abs((fused[2:] - p) @ n))


def test_one_noisy_wall_fuses_to_one_segment_spanning_the_observations():
    rng = np.random.default_rng(7)
    wall = np.array([2.0, 5.0, 32.0, 9.0])
    segs, scan = observe_walls(wall, 20, 0.03, rng, min_fraction=0.4)
    result = fuse_proposed(segs, scan)
    assert len(result.segments) == 1
    fused = result.segments[0]
    assert _max_dist_to_line(fused, wall) < 0.03
    # spans the union of the observations (extreme projections), within noise
    d = (wall[2:] - wall[:2]) / np.hypot(*(wall[2:] - wall[:2]))
    t_obs = np.concatenate([(segs[:, :2] - wall[:2]) @ d, (segs[:, 2:] - wall[:2]) @ d])
    t_fused = np.sort((fused.reshape(2, 2) - wall[:2]) @ d)
    assert t_fused[0] == pytest.approx(t_obs.min(), abs=0.1)
    assert t_fused[1] == pytest.approx(t_obs.max(), abs=0.1)
    assert result.support.tolist() == [20]
    assert (result.labels == 0).all()


@pytest.mark.parametrize("gap", [15.0, 2.5])
def test_parallel_walls_stay_apart(gap):
    rng = np.random.default_rng(3)
    walls = np.array([[0, 0, 30, 0], [0, gap, 30, gap]], float)
    segs, scan = observe_walls(walls, 20, 0.03, rng, first_scan=np.array([0, 0]))
    result = fuse_proposed(segs, scan)
    assert len(result.segments) == 2
    ys = sorted(result.segments[:, [1, 3]].mean(axis=1))
    assert ys == pytest.approx([0.0, gap], abs=0.05)


def test_short_fence_in_two_scans_is_dropped_and_does_not_pull_the_wall():
    rng = np.random.default_rng(11)
    wall = np.array([0.0, 0.0, 40.0, 0.0])
    segs, scan = observe_walls(wall, 20, 0.03, rng)
    fence = np.array([[15.0, 1.5, 19.0, 1.5], [15.2, 1.55, 19.1, 1.52]])   # 1.5 m in front of the wall
    segs = np.vstack([segs, fence])
    scan = np.concatenate([scan, [3, 4]])
    result = fuse_proposed(segs, scan, ProposedConfig(min_support=4, eta_m=0.5, min_support_length_m=None))
    assert len(result.segments) == 1
    assert (result.labels[-2:] == -1).all()
    assert np.abs(result.segments[0, [1, 3]]).max() < 0.05
    # with the length rule, two views that agree over 4 m are a feature of their own; the wall stays put
    result = fuse_proposed(segs, scan, ProposedConfig(min_support=4, eta_m=0.5))
    assert len(result.segments) == 2
    assert np.abs(result.segments[result.labels[0], [1, 3]]).max() < 0.05


@pytest.mark.parametrize("scans,length,kept", [([0], 4.0, False), ([0], 6.0, True), ([0, 1], 4.0, True),
                                               ([0, 1], 2.5, False), ([0, 1, 2, 3], 1.0, True)])
def test_small_clusters_are_kept_by_length_a_single_view_only_when_long(scans, length, kept):
    """min_support 4; smaller clusters stay when their members cover min_support_length_m (3 m), a lone
    segment only when it covers min_single_length_m (5 m)."""
    segs = np.array([[0.0, 0.01 * k, length, 0.01 * k] for k in range(len(scans))])
    result = fuse_proposed(segs, np.array(scans), ProposedConfig())
    assert (len(result.segments) == 1) == kept


@pytest.mark.parametrize("rms,length,kept", [(0.004, 2.0, True), (0.012, 2.0, False), (0.004, 1.2, False),
                                             (np.nan, 2.0, False)])
def test_a_lone_view_much_thinner_than_the_typical_wall_is_kept(rms, length, kept):
    """A wall seen 20 times (rms 1 cm per view) and a lone 2 m piece elsewhere: the piece is kept when its rms
    is at most half the median (clean_rms_ratio 0.5) and it is at least 1.4 m long, whatever its scan."""
    rng = np.random.default_rng(4)
    segs, scan = observe_walls(np.array([0.0, 0.0, 30.0, 0.0]), 20, 0.02, rng)
    segs = np.vstack([segs, [[5.0, 10.0, 5.0 + length, 10.0]]])
    scan = np.concatenate([scan, [7]])
    rms_all = np.r_[np.full(20, 0.01), rms]
    result = fuse("proposed", segs, scan, FusionConfig(), rms=rms_all)
    assert len(result.segments) == (2 if kept else 1)
    assert (result.labels[-1] >= 0) == kept
    if kept:
        assert result.segments[result.labels[-1]] == pytest.approx([5.0, 10.0, 5.0 + length, 10.0], abs=1e-9)
    # without the extraction's rms, or with the paper's count rule, no view is clean
    assert len(fuse("proposed", segs, scan, FusionConfig()).segments) == 1
    paper = FusionConfig.model_validate({"proposed": {"clean_rms_ratio": None}})
    assert len(fuse("proposed", segs, scan, paper, rms=rms_all).segments) == 1


@pytest.mark.parametrize("views,max_gap,kept_plain,kept_coarse", [
    (1, 6.4, True, False),      # one 11 m view whose returns lie 6.4 m apart: two columns, no wall between
    (2, 3.0, True, False),      # two such views that agree
    (2, 0.3, True, True),       # two finely sampled views: they cover their length
    (4, 6.4, True, True)])      # min_support views are kept by their count alone
def test_coarse_views_count_as_members_but_cover_no_length(views, max_gap, kept_plain, kept_coarse):
    """A lone 11 m piece (or a few that agree) beside a wall seen 20 times: with coarse_gap_m = 2 m, a
    view whose returns lie at least that far apart along it no longer earns its cluster a place by
    length (min_support_length_m 3 m, min_single_length_m 5 m); the wall is kept either way."""
    rng = np.random.default_rng(4)
    segs, scan = observe_walls(np.array([0.0, 0.0, 30.0, 0.0]), 20, 0.02, rng)
    piece = np.array([[5.0, 10.0 + 0.01 * k, 16.0, 10.0 + 0.01 * k] for k in range(views)])
    segs, scan = np.vstack([segs, piece]), np.concatenate([scan, np.arange(views)])
    gaps = np.r_[np.full(20, 0.1), np.full(views, max_gap)]
    coarse, plain = FusionConfig(), FusionConfig.model_validate({"proposed": {"coarse_gap_m": None}})
    assert coarse.proposed.coarse_gap_m == 2.0                      # the default
    for config, kept in ((plain, kept_plain), (coarse, kept_coarse)):
        result = fuse("proposed", segs, scan, config, max_gap=gaps)
        assert len(result.segments) == (2 if kept else 1)
        assert (result.labels[20:] >= 0).all() == kept
        assert result.labels[:20].tolist() == [result.labels[0]] * 20
    # without the extraction's max_gap no view is coarse
    assert len(fuse("proposed", segs, scan, coarse).segments) == 2


def test_coarse_views_need_one_max_gap_per_segment():
    segs = np.array([[0.0, 0.0, 2.0, 0.0]] * 3)
    coarse = FusionConfig.model_validate({"proposed": {"coarse_gap_m": 2.0}})
    with pytest.raises(ValueError, match="max_gap has 2 entries for 3 segments"):
        fuse("proposed", segs, np.arange(3), coarse, max_gap=np.array([0.1, 0.1]))


def test_support_views_count_clean_members_and_leave_coarse_ones_out_of_the_length():
    views = SupportViews(clean=np.array([True, False, True, True]), coarse=np.array([False, True, False, True]))
    labels = np.array([0, 0, -1, 1])            # segment 2 is in no cluster; cluster 2 has no member
    assert views.clean_members(labels, 3).tolist() == [1, 1, 0]
    assert views.covering(labels).tolist() == [0, -1, -1, -1]
    part = views.subset(np.array([1, 3]))
    assert part.clean.tolist() == [False, True] and part.coarse.tolist() == [True, True]
    assert SupportViews().clean_members(labels, 3) is None
    assert SupportViews().covering(labels).tolist() == labels.tolist()


@pytest.mark.parametrize("rms, clean", [([0.0, 0.0, 0.0, 0.0], [False] * 4),       # no scale: nothing is clean
                                        ([0.0, 0.01, 0.01, 0.01], [True, False, False, False]),
                                        ([-0.01, 0.004, 0.01, 0.01], [False, True, False, False]),
                                        ([np.nan, 0.004, 0.01, 0.01], [False, True, False, False])])
def test_clean_views_are_half_as_loose_as_the_median_and_unknown_values_never_clean(rms, clean):
    segs = np.array([[0.0, 0.0, 2.0, 0.0]] * 4)
    assert support_rule(ProposedConfig()).clean_views(segs, np.array(rms)).tolist() == clean


def test_clean_views_need_one_rms_per_segment():
    segs = np.array([[0.0, 0.0, 2.0, 0.0]] * 3)
    with pytest.raises(ValueError, match="rms has 2 entries for 3 segments"):
        fuse("proposed", segs, np.arange(3), FusionConfig(), rms=np.array([0.01, 0.01]))


@pytest.mark.parametrize("wall", [[7.0, -10.0, 7.0, 20.0], [-10.0, 4.0, 25.0, 4.0]])
def test_axis_aligned_walls(wall):
    rng = np.random.default_rng(5)
    wall = np.array(wall)
    segs, scan = observe_walls(wall, 15, 0.02, rng)
    result = fuse_proposed(segs, scan)
    assert len(result.segments) == 1
    assert _max_dist_to_line(result.segments[0], wall) < 0.03


def test_building_corner_after_corner_optimisation():
    rng = np.random.default_rng(2)
    corner = np.array([10.0, 10.0])
    walls = np.array([[0.0, 10.0, 10.0, 10.0], [10.0, 10.0, 10.0, -5.0]])
    segs, scan = observe_walls(walls, 20, 0.03, rng, min_fraction=0.9, first_scan=np.array([0, 0]))
    for mode in ("midpoint", "intersection"):
        cfg = FusionConfig.model_validate({"corners": {"mode": mode}})
        result = fuse("proposed", segs, scan, cfg)
        assert len(result.segments) == 2
        ends = result.segments.reshape(-1, 2)
        err = np.sort(np.hypot(*(ends - corner).T))[:2]
        assert err.max() < 0.05, (mode, err)
        if mode == "intersection":          # both endpoints moved to the same point
            assert err[0] == pytest.approx(err[1], abs=1e-9)


def test_shuffled_input_gives_the_same_map():
    rng = np.random.default_rng(9)
    walls = np.array([[0, 0, 30, 0], [0, 15, 30, 15], [35, 0, 35, 20], [-5, 40, 20, 60]], float)
    segs, scan = observe_walls(walls, 12, 0.03, rng, first_scan=np.array([0, 0, 10, 20]))
    a = fuse("proposed", segs, scan)
    perm = rng.permutation(len(segs))
    b = fuse("proposed", segs[perm], scan[perm])
    assert np.allclose(a.segments, b.segments)
    assert np.array_equal(a.support, b.support)
    assert np.array_equal(a.labels[perm], b.labels)


def test_empty_and_zero_length_inputs():
    empty = fuse("proposed", np.zeros((0, 4)), np.zeros(0, int))
    assert empty.segments.shape == (0, 4) and len(empty.labels) == 0
    rng = np.random.default_rng(4)
    segs, scan = observe_walls(np.array([0.0, 0.0, 20.0, 0.0]), 10, 0.02, rng)
    segs = np.vstack([segs, [[3.0, 3.0, 3.0, 3.0]]])
    scan = np.concatenate([scan, [2]])
    result = fuse("proposed", segs, scan)
    assert len(result.segments) == 1
    assert result.skipped_zero_length == 1
    assert result.labels[-1] == -1


def test_same_scan_features_are_never_linked():
    # Two identical segments from one scan: criteria hold, but the paper only compares k with k - i.
    segs = np.array([[0, 0, 10, 0], [0, 0.01, 10, 0.01]], float)
    result = fuse_proposed(segs, np.array([0, 0]), ProposedConfig(min_support=2, min_support_length_m=None))
    assert len(result.segments) == 0
    result = fuse_proposed(segs, np.array([0, 1]), ProposedConfig(min_support=2, min_support_length_m=None))
    assert len(result.segments) == 1


def test_criteria_values_for_hand_made_pair():
    segs = np.array([[0, 0, 10, 0], [2, 1, 8, 1]], float)
    crit = evaluate_pairs(segs, np.array([0]), np.array([1]))
    assert crit.beta[0] == pytest.approx(0.0)
    assert crit.epsilon[0] == pytest.approx(1.0)          # the small circle (r=3) lies inside the big one (r=5)
    # d(O_i=(5,0), seg_j) = 1 and d(O_j=(5,1), seg_i) = 1
    assert crit.d_max[0] == pytest.approx(1.0)
    segs = np.array([[0, 0, 10, 0], [12, 0, 20, 0]], float)   # collinear, disjoint circles
    crit = evaluate_pairs(segs, np.array([0]), np.array([1]))
    assert crit.epsilon[0] == pytest.approx(0.0)
    assert crit.d_max[0] == pytest.approx(max(point_segment_distance(np.array([[5.0, 0]]), segs[1:])[0], 7.0))


def test_each_criterion_can_veto_a_link():
    base = np.array([[0, 0, 10, 0], [0, 0.1, 10, 0.1]], float)
    scan = np.array([0, 1])
    ok = ProposedConfig(min_support=2, min_support_length_m=None)   # the paper's count rule only
    assert len(fuse_proposed(base, scan, ok).segments) == 1
    rotated = np.array([[0, 0, 10, 0], [0, -0.5, 10, 0.5]], float)       # beta ~ 5.7 deg
    assert len(fuse_proposed(rotated, scan, ok.model_copy(update={"delta_deg": 5.0})).segments) == 0
    shifted = np.array([[0, 0, 10, 0], [8, 0.1, 18, 0.1]], float)        # small circle overlap
    assert len(fuse_proposed(shifted, scan, ok.model_copy(update={"gamma": 0.5, "eta_m": 10})).segments) == 0
    apart = np.array([[0, 0, 10, 0], [0, 1.0, 10, 1.0]], float)          # 1 m apart, eta 0.5
    assert len(fuse_proposed(apart, scan, ok).segments) == 0
