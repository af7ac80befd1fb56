"""The visibility clause of the support filter: the share of the scans able to see a cluster's line that saw it."""

import numpy as np
import pytest

from featmap.fusion import FusionConfig, fuse
from featmap.fusion.base import SupportViews
from featmap.fusion.online import OnlineFusion
from featmap.fusion.visibility import seen_share, sensor_xy_column
from featmap.simulation.segments import observe_walls
from tests.repo_scripts import repo_script

STREET = np.column_stack([np.arange(41.0), np.zeros(41)])
"""41 scans taken 1 m apart along y = 0 (scan k at x = k)."""
FRONTS = np.array([[10.0, 5.0, 19.5, 5.0], [20.5, 5.0, 30.0, 5.0]])
"""Two house fronts along the street with a 1 m gap between them at x 19.5-20.5."""


def _members(scans):
    """labels, scan, sensor_xy of one cluster (0) seen by ``scans`` of STREET, one segment each, and one
    segment in no cluster from each scan of STREET (the scans are known from their segments)."""
    scan = np.r_[np.asarray(scans), np.arange(len(STREET))]
    labels = np.r_[np.zeros(len(scans), np.int64), np.full(len(STREET), -1)]
    return labels, scan, STREET[scan]


def test_a_piece_in_the_open_is_seen_by_the_scans_within_its_range_and_angle():
    """A 4 m piece 10 m off the street seen by scans 19-21: scans up to 1.2 x its farthest view (12.1 m,
    i.e. x 14-26) could see it, so 3 of 13 did."""
    labels, scan, xy = _members([19, 20, 21])
    share = seen_share(np.array([[18.0, 10.0, 22.0, 10.0]]), labels, scan, xy, np.array([True]), np.zeros((0, 4)))
    assert share[0] == pytest.approx(3 / 13)


def test_a_wall_seen_through_a_gap_was_seen_by_every_scan_that_could_see_it():
    """The same piece behind the two fronts: only scan 20 looks through the gap, and it saw the piece."""
    piece = np.array([[18.0, 10.0, 22.0, 10.0]])
    labels, scan, xy = _members([19, 20, 21])
    assert seen_share(piece, labels, scan, xy, np.array([True]), FRONTS)[0] == 1.0
    # seen only from scans the fronts hide it from: it lies behind a wall from where it was seen
    labels, scan, xy = _members([15, 25])
    assert seen_share(piece, labels, scan, xy, np.array([True]), FRONTS)[0] == 0.0


def test_only_candidates_are_measured():
    lines = np.array([[18.0, 10.0, 22.0, 10.0], [0.0, 10.0, 4.0, 10.0]])
    labels, scan = np.array([0, 1]), np.array([20, 2])
    share = seen_share(lines, labels, scan, STREET[scan], np.array([False, True]), np.zeros((0, 4)))
    assert np.isnan(share[0]) and share[1] > 0


def _gap_scene():
    """The fronts seen by every scan 5-35, a 2 m rear wall through the gap seen by scans 19-21, and a 2 m
    piece in the open (a tree crown) seen by 3 of the 13 scans that could see it: (segments, scan, sensor_xy)."""
    rng = np.random.default_rng(2)
    segs, scan = [], []
    for front in FRONTS:
        s, k = observe_walls(front, 31, 0.01, rng, min_fraction=0.8)
        segs.append(s)
        scan.append(k + 5)
    for piece, seen_by in (([19.0, 10.0, 21.0, 10.0], [19, 20, 21]), ([3.0, -10.0, 5.0, -10.0], [3, 4, 5])):
        segs.append(np.array([[piece[0], piece[1] + 0.01 * k, piece[2], piece[3] + 0.01 * k] for k in range(3)]))
        scan.append(np.array(seen_by))
    scan = np.concatenate(scan)
    return np.vstack(segs), scan, STREET[scan]


def test_the_clause_keeps_a_wall_seen_through_a_gap_and_drops_a_piece_most_scans_saw_nothing_on():
    segs, scan, xy = _gap_scene()
    plain = FusionConfig.model_validate({"proposed": {"visible_share": None}})
    visible = FusionConfig()
    assert visible.proposed.visible_share == 0.5                       # the default
    without = fuse("proposed", segs, scan, plain, sensor_xy=xy)
    assert len(without.segments) == 2                                   # the fronts only (3 views < min_support 4)
    result = fuse("proposed", segs, scan, visible, sensor_xy=xy)
    assert len(result.segments) == 3
    rear = result.labels[-6:-3]
    assert (rear >= 0).all() and len(set(rear.tolist())) == 1
    assert np.allclose(np.sort(result.segments[rear[0]][[0, 2]]), [19.0, 21.0], atol=0.05)
    assert (result.labels[-3:] < 0).all()                               # the piece in the open stays dropped
    # without sensor positions the clause keeps nothing
    assert len(fuse("proposed", segs, scan, visible).segments) == 2


def test_the_clause_is_the_same_far_from_the_frame_origin():
    """The methods fuse in a working frame; the sensor positions move with the segments."""
    segs, scan, xy = _gap_scene()
    visible = FusionConfig.model_validate({"proposed": {"visible_share": 0.5}})
    far = np.array([4.5e5, 5.5e6])
    near = fuse("proposed", segs, scan, visible, sensor_xy=xy)
    moved = fuse("proposed", segs + np.tile(far, 2), scan, visible, sensor_xy=xy + far)
    assert np.array_equal(near.labels, moved.labels)
    assert np.allclose(moved.segments - np.tile(far, 2), near.segments, atol=1e-6)


def test_online_fusion_with_sensor_positions_is_the_offline_map():
    segs, scan, xy = _gap_scene()
    visible = FusionConfig.model_validate({"proposed": {"visible_share": 0.5}})
    online = OnlineFusion(visible)
    for s in range(41):
        online.add_scan(segs[scan == s], sensor_xy=STREET[s])
    order = np.argsort(scan, kind="stable")
    offline = fuse("proposed", segs[order], scan[order], visible, sensor_xy=xy[order])
    result = online.fused()
    assert len(result.segments) == 3
    assert np.array_equal(result.segments, offline.segments) and np.array_equal(result.labels, offline.labels)


def test_sensor_positions_need_one_row_per_segment_and_both_columns():
    segs = np.array([[0.0, 0.0, 2.0, 0.0]] * 3)
    visible = FusionConfig.model_validate({"proposed": {"visible_share": 0.5}})
    with pytest.raises(ValueError, match="sensor_xy has 2 entries for 3 segments"):
        fuse("proposed", segs, np.arange(3), visible, sensor_xy=np.zeros((2, 2)))
    with pytest.raises(ValueError, match="sensor_xy has a NaN or infinite position"):
        fuse("proposed", segs, np.arange(3), visible, sensor_xy=np.array([[0.0, 0.0], [np.nan, 1.0], [0.0, 0.0]]))
    assert sensor_xy_column({"sensor_x": np.zeros(3)}, 3) is None
    assert sensor_xy_column({"sensor_x": np.arange(3.0), "sensor_y": np.ones(3)}, 3).tolist() == [[0, 1], [1, 1], [2, 1]]
    with pytest.raises(ValueError, match="sensor_x / sensor_y have 3 entries for 2 segments"):
        sensor_xy_column({"sensor_x": np.zeros(3), "sensor_y": np.zeros(3)}, 2)


def test_support_views_carry_sensor_positions_through_subset_and_move():
    views = SupportViews(sensor_xy=np.array([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]]))
    assert views.subset(np.array([2, 0])).sensor_xy.tolist() == [[5, 6], [1, 2]]
    assert views.moved(np.array([1.0, 1.0])).sensor_xy.tolist() == [[0, 1], [2, 3], [4, 5]]
    assert SupportViews().seen(lambda: np.zeros((0, 4)), np.zeros(0, np.int64), np.zeros(0, np.int64)) is None


def test_stopping_early_decides_as_the_full_count():
    """With ``at_least`` the count stops once a share cannot reach it: every share at or above it is exact
    and every other one stays below it (and above the true share), on a street driven five times."""
    from featmap.simulation.segments import city_walls, observe_revisits

    with repo_script("benchmarks/revisited_street.py") as street:
        street_sensor_positions = street.street_sensor_positions
    rng = np.random.default_rng(4)
    walls = city_walls(24, rng)
    segs, scan = observe_revisits(walls, 5, 20, rng, clutter_fraction=0.1)
    xy = street_sensor_positions(walls, scan, 20)
    fused = fuse("proposed", segs, scan, FusionConfig(), sensor_xy=xy)
    lines, labels = fused.segments, fused.labels
    candidates = np.ones(len(lines), dtype=bool)
    for at_least in (0.5, 0.3, 0.8):
        exact = seen_share(lines, labels, scan, xy, candidates, lines)
        quick = seen_share(lines, labels, scan, xy, candidates, lines, at_least=at_least)
        reached = exact >= at_least
        assert 0 < reached.sum() < len(lines)                  # both kinds occur
        assert np.array_equal(quick[reached], exact[reached])
        assert (quick[~reached] < at_least).all() and (quick[~reached] >= exact[~reached] - 1e-12).all()
