"""OnlineFusion: one scan at a time, the same map as the offline proposed method, bit for bit."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings

from featmap.fusion import FusionConfig, fuse
from featmap.fusion.online import OnlineFusion
from featmap.simulation.segments import city_walls, observe_revisits
from tests.fusion.test_properties import segment_sets

CONFIG = FusionConfig()
SMALL_SUPPORT = FusionConfig.model_validate({"proposed": {"min_support": 2}})


def by_scan(segments, scan, rms=None):
    """The rows of each scan in turn (scans renumbered 0..S-1 as they come, empty ones kept)."""
    for s in range(int(scan.max()) + 1 if len(scan) else 0):
        m = scan == s
        yield segments[m], None if rms is None else rms[m]


def online_map(segments, scan, config, rms=None, upto=None):
    online = OnlineFusion(config)
    for k, (seg, r) in enumerate(by_scan(segments, scan, rms)):
        if upto is not None and k == upto:
            break
        online.add_scan(seg, r)
    return online


def assert_same_map(online: OnlineFusion, config, rms_given=True):
    segments, scan, rms = online.segments()
    offline = fuse("proposed", segments, scan, config, rms=rms if rms_given else None)
    result = online.fused()
    assert np.array_equal(result.segments, offline.segments)
    assert np.array_equal(result.support, offline.support)
    assert np.array_equal(result.labels, offline.labels)
    assert result.clusters_dropped == offline.clusters_dropped
    return result


def revisited_street(passes=5, seed=3, far=(0.0, 0.0)):
    rng = np.random.default_rng(seed)
    walls = city_walls(40, rng)
    segments, scan = observe_revisits(walls, passes, 20, rng)
    order = np.argsort(scan, kind="stable")
    segments, scan = segments[order] + np.tile(far, 2), scan[order]
    rms = rng.uniform(0.01, 0.06, len(segments))
    return segments, scan, rms


def test_a_street_driven_five_times_gives_the_offline_map_after_every_pass():
    segments, scan, rms = revisited_street()
    per_pass = (int(scan.max()) + 1) // 5
    for upto in (1, per_pass, 3 * per_pass, None):          # prefixes: what an online mapper shows on the way
        online = online_map(segments, scan, CONFIG, rms, upto)
        result = assert_same_map(online, CONFIG)
    assert online.n_segments == len(segments) and online.n_scans == int(scan.max()) + 1
    assert 20 < len(result.segments) < 80                    # 40 walls (some pieces dropped or split)


def test_far_from_the_frames_origin_it_is_still_the_offline_map():
    """UTM-like coordinates (500 km east, 5,400 km north): the working origin of the first scan and of the
    whole map are the same kilometre here, so both fuse in the same frame."""
    segments, scan, rms = revisited_street(passes=2, far=(500_000.0, 5_400_000.0))
    online = online_map(segments, scan, CONFIG, rms)
    assert online.origin.tolist() == [500_000.0, 5_400_000.0]
    assert_same_map(online, CONFIG)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow], derandomize=True)
@given(data=segment_sets())
def test_any_input_scan_by_scan_gives_the_offline_map(data):
    """Duplicates, zero-length rows, one scan or thousands (most of them empty): the same map, rms or not."""
    segments, scan = data
    order = np.argsort(scan, kind="stable")
    segments, scan = segments[order], scan[order]
    rms = np.random.default_rng(len(segments)).uniform(0.0, 0.05, len(segments))
    assert_same_map(online_map(segments, scan, SMALL_SUPPORT, rms), SMALL_SUPPORT)
    assert_same_map(online_map(segments, scan, SMALL_SUPPORT), SMALL_SUPPORT, rms_given=False)


def test_empty_scans_and_a_scan_of_one_point_long_segments():
    online = OnlineFusion(CONFIG)
    assert len(online.fused().segments) == 0                # nothing seen yet
    online.add_scan(np.zeros((0, 4)))
    online.add_scan([[1.0, 1.0, 1.0, 1.0]])                 # zero length: kept in the input, never fused
    wall = np.array([[0.0, 5.0, 10.0, 5.0]])
    for k in range(5):
        online.add_scan(wall + [0, 0.01 * k, 0, 0.01 * k])
    result = assert_same_map(online, CONFIG, rms_given=False)
    assert len(result.segments) == 1 and result.labels[0] == -1 and result.support.tolist() == [5]
    np.testing.assert_allclose(np.sort(result.segments[0, [0, 2]]), [0.0, 10.0], atol=1e-9)
    np.testing.assert_allclose(result.segments[0, [1, 3]], 5.02, atol=1e-9)


def test_bad_input_is_refused_before_anything_is_kept():
    online = OnlineFusion(CONFIG)
    with pytest.raises(ValueError, match="NaN or inf"):
        online.add_scan([[0.0, 0.0, np.nan, 1.0]])
    with pytest.raises(ValueError, match="rms has 2 entries for 1 segments"):
        online.add_scan([[0.0, 0.0, 1.0, 1.0]], rms=[0.01, 0.02])
    with pytest.raises(ValueError, match="max_gap has 0 entries for 1 segments"):
        online.add_scan([[0.0, 0.0, 1.0, 1.0]], max_gap=[])
    assert online.n_scans == 0 and online.n_segments == 0


def test_the_split_at_unresolved_gaps_is_the_offline_one():
    from tests.fusion.test_refine import _buildings_in_line

    segments, scan, max_gap = _buildings_in_line()
    config = FusionConfig.model_validate({"refine": {"resolved_gap_m": 3.0}})
    online = OnlineFusion(config)
    for s in range(int(scan.max()) + 1):
        online.add_scan(segments[scan == s], max_gap=max_gap[scan == s])
    offline = fuse("proposed", *online.segments()[:2], config, max_gap=online.max_gap())
    result = online.fused()
    assert len(result.segments) == 2 and np.array_equal(result.segments, offline.segments)
    assert np.array_equal(result.labels, offline.labels)


def test_coarse_views_are_the_offline_ones():
    """With coarse_gap_m, the views whose returns lie far apart cover no length online as offline."""
    config = FusionConfig.model_validate({"proposed": {"coarse_gap_m": 2.0}})
    online = OnlineFusion(config)
    for s in range(3):
        online.add_scan([[0.0, 0.01 * s, 30.0, 0.0], [5.0, 10.0, 16.0, 10.0 + 0.01 * s]], max_gap=[0.1, 6.4])
    offline = fuse("proposed", *online.segments()[:2], config, max_gap=online.max_gap())
    result = online.fused()
    assert np.array_equal(result.segments, offline.segments) and np.array_equal(result.labels, offline.labels)
    assert result.labels.reshape(3, 2)[:, 1].tolist() == [-1] * 3       # the coarse piece is dropped


def test_a_pair_within_rounding_of_a_threshold_is_decided_as_offline():
    """Two views exactly eta = 0.5 m apart: left undecided by the compiled code and decided by numpy, as offline."""
    online = OnlineFusion(SMALL_SUPPORT)
    online.add_scan([[0.0, 0.0, 10.0, 0.0]])
    online.add_scan([[0.0, 0.5, 10.0, 0.5]])
    assert online._n_undecided == 1
    assert online.links()[0].tolist() == [0]
    assert_same_map(online, SMALL_SUPPORT, rms_given=False)


def test_a_partner_exactly_eta_away_on_a_cell_boundary_is_found():
    """Cell coordinates of the online grid are ~2^25 cells from its origin, where a coordinate is only good to
    ~1e-8 m: a partner whose centre lies exactly eta from the segment, on a cell boundary, was not searched."""
    config = FusionConfig.model_validate({"proposed": {"min_support": 2}, "refine": {"max_offset_m": 0}})
    length, y = 16.93282940904733, 215.89357494307922
    online = OnlineFusion(config)
    online.add_scan([[-length / 2, 0, length / 2, 0], [0, y, length, y]])
    online.add_scan([[0, y - 0.5, length, y - 0.5]])
    result = assert_same_map(online, config, rms_given=False)
    assert sorted(result.support.tolist()) == [1, 2]                # the two views fused, the lone wall kept


def test_a_small_eta_still_reaches_walls_far_from_the_first_scan():
    """eta = 1 mm and a first scan of 4 mm segments: the cell is at least 0.6 m, so the grid still reaches
    150 km (with 4 mm cells it reached 134 km, and the far wall was never found again)."""
    config = FusionConfig.model_validate({"proposed": {"eta_m": 0.001, "min_support": 3, "min_support_length_m": None,
                                                       "clean_rms_ratio": None}})
    online = OnlineFusion(config)
    online.add_scan([[0.0, 0.0, 0.004, 0.0], [0.0, 0.01, 0.004, 0.01], [0.0, 0.02, 0.004, 0.02]])
    for _ in range(3):
        online.add_scan([[0.0, 5.0, 10.0, 5.0], [0.0, 5.0, 10.0, 5.0], [0.0, 150_000.0, 10.0, 150_000.0]])
    result = assert_same_map(online, config, rms_given=False)
    assert sorted(result.support.tolist()) == [3, 6]
    with pytest.raises(ValueError, match="more than 2e\\+07 m from the first scan"):
        online.add_scan([[0.0, 3e7, 10.0, 3e7]])
    assert online.n_scans == 4                                    # the refused scan left nothing behind
