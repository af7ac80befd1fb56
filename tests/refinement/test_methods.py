"""Every refinement method on scans of a known floor: known shifts come back, exact poses stay exactly."""

import numpy as np
import pytest

from featmap.datasets.carmen import pose_matrix
from featmap.refinement import REFINEMENT_METHODS, RefinementConfig, planar_difference, refine
from featmap.refinement.pose_graph import PoseGraphConfig, refine_pose_graph
from featmap.simulation.simulate import oxts_drift
from tests.refinement.conftest import refinement_input


def _true(poses):
    return np.stack([pose_matrix(p) for p in poses])


def _map_frame(refined, truth, others):
    """``refined`` (F, 4, 4) moved by the rigid motion that best puts the ``others`` scans on their true poses."""
    a, b = refined[others, :2, 3], truth[others, :2, 3]
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    rot = vt.T @ u.T
    C = np.eye(4)
    C[:2, :2], C[:2, 3] = rot, cb - rot @ ca
    return C @ refined


def test_a_scan_shifted_by_a_known_amount_is_moved_back(hall):
    """One scan of 24 placed 0.25 m / 0.15 m / 2 degrees off the map the others make: refinement puts it
    back within 1 cm and 0.05 degrees of its place in that map. (The map as a whole moves by about 1/24 of
    the shift: each scan's absolute prior pulls it, as GPS/INS would.)"""
    poses, scans = hall
    given = poses.copy()
    given[9] += [0.25, -0.15, np.deg2rad(2.0)]
    result = refine_pose_graph(refinement_input(scans, given))
    assert result.stats["applied"]
    others = np.delete(np.arange(len(poses)), 9)
    err = planar_difference(_map_frame(result.poses, _true(poses), others), _true(poses))
    assert np.hypot(*err[9, :2]) < 0.01 and np.rad2deg(abs(err[9, 2])) < 0.05
    assert np.hypot(err[others, 0], err[others, 1]).max() < 0.005
    moved = np.hypot(result.corrections[:, 0], result.corrections[:, 1])
    assert moved[9] > 0.25 and np.delete(moved, 9).max() < 0.025


@pytest.mark.parametrize("name", [n for n in REFINEMENT_METHODS if n != "none"])
def test_exact_poses_are_left_exactly_as_they_were(hall, name):
    poses, scans = hall
    inp = refinement_input(scans, poses)
    result = refine(inp, RefinementConfig(method=name))
    assert result.stats["applied"] is False
    assert np.array_equal(result.poses, inp.poses) and not result.corrections.any()
    assert result.stats["residual_before_mm"] < 5


def test_gauss_markov_drift_is_removed(hall):
    """0.3 m / 0.5 deg OXTS-like drift (5 s correlation) on every scan: the refined scans agree to a few mm
    and their poses relative to each other are within 2 cm / 0.1 deg of the truth."""
    poses, scans = hall
    drift = oxts_drift(np.random.default_rng(4), np.arange(len(poses)) * 0.5, (0.3, 0.5), 5.0)
    inp = refinement_input(scans, poses + drift)
    result = refine_pose_graph(inp)
    assert result.stats["applied"] and result.stats["residual_after_mm"] < 5 < result.stats["residual_before_mm"]
    err = planar_difference(result.poses, _true(poses))
    before = planar_difference(inp.poses, _true(poses))
    rel = err - err.mean(axis=0)                       # what is left once the common offset is removed
    assert np.hypot(rel[:, 0], rel[:, 1]).max() < 0.02 and np.rad2deg(np.abs(rel[:, 2])).max() < 0.1
    assert np.hypot(before[:, 0], before[:, 1]).mean() > 0.15


def test_odometry_mode_holds_the_first_scan_and_follows_the_scans(hall):
    poses, scans = hall
    given = poses.copy()
    given[12:] += [0.3, 0.2, np.deg2rad(1.5)]          # a jump in the odometry halfway
    config = PoseGraphConfig(absolute_sigma_m=None, absolute_sigma_deg=None, motion_sigma_m_per_sqrt_m=0.05,
                             motion_sigma_deg_per_sqrt_m=1.0)
    result = refine_pose_graph(refinement_input(scans, given), config)
    assert np.abs(result.corrections[0]).max() < 1e-5
    rel = planar_difference(result.poses, _true(poses))
    assert np.hypot(rel[:, 0], rel[:, 1]).max() < 0.02 and np.rad2deg(np.abs(rel[:, 2])).max() < 0.1


def test_refinement_is_deterministic_and_none_changes_nothing(hall):
    poses, scans = hall
    inp = refinement_input(scans, poses + [0.1, 0.0, 0.01])
    a, b = refine_pose_graph(inp), refine_pose_graph(inp)
    assert np.array_equal(a.poses, b.poses)
    none = refine(inp, RefinementConfig(method="none"))
    assert np.array_equal(none.poses, inp.poses) and none.stats["applied"] is False


def test_empty_and_segment_free_inputs():
    from featmap.refinement import RefinementInput

    empty = refine(RefinementInput(np.zeros((0, 4)), np.zeros(0, int), np.zeros((0, 4, 4))))
    assert empty.poses.shape == (0, 4, 4)
    poses = np.tile(np.eye(4), (3, 1, 1))
    bare = refine(RefinementInput(np.zeros((0, 4)), np.zeros(0, int), poses, np.arange(3.0)))
    assert np.array_equal(bare.poses, poses) and bare.stats["applied"] is False


@pytest.mark.parametrize("name", sorted(REFINEMENT_METHODS))
def test_scans_without_segments_at_the_end_are_refined_with_the_rest(hall, name):
    """The last scans of a drive may see no wall (open country): they are paired like any other and keep
    their pose's correction from their neighbours, instead of failing (they used to index past the end)."""
    poses, scans = hall
    from featmap.extraction.base import ScanSegments

    scans = list(scans[:-3]) + [ScanSegments.empty()] * 3
    given = poses + [0.15, -0.1, 0.01] * (np.arange(len(poses)) >= 12)[:, None]
    inp = refinement_input(scans, given)
    assert inp.scan.max() < inp.n_scans - 3
    result = refine(inp, RefinementConfig(method=name))
    assert result.poses.shape == inp.poses.shape and np.isfinite(result.poses).all()


def test_slam_poses_hold_the_map_where_the_input_put_it(hall):
    """The first of 24 scans is 0.25 m / 2 deg off, the rest are exact. In odometry mode (no absolute
    prior) the first scan is held and the whole map follows it; when the input says its poses are a SLAM
    result, the ``slam_absolute_*`` prior holds the map where the 23 good scans put it (within 2.5 cm: it
    moves by about 1/24 of the error, as every scan's prior pulls it) and the first scan comes back within
    2 cm. Without ``slam_poses`` that prior does nothing."""
    from dataclasses import replace

    poses, scans = hall
    given = poses.copy()
    given[0] += [0.25, -0.15, np.deg2rad(2.0)]
    section = PoseGraphConfig(absolute_sigma_m=None, absolute_sigma_deg=None, slam_absolute_sigma_m=0.1,
                              slam_absolute_sigma_deg=0.5, motion_sigma_m_per_sqrt_m=0.05,
                              motion_sigma_deg_per_sqrt_m=1.0)
    config = RefinementConfig(method="pose_graph", pose_graph=section)
    inp = refinement_input(scans, given)
    odometry = refine(inp, config)
    slam = refine(replace(inp, slam_poses=True), config)
    assert np.abs(odometry.corrections[0]).max() < 1e-5                 # the first scan held, the map moved
    moved = planar_difference(odometry.poses, _true(poses))
    assert np.hypot(moved[1:, 0], moved[1:, 1]).min() > 0.1
    err = planar_difference(slam.poses, _true(poses))
    assert slam.stats["applied"] and np.hypot(*err[0, :2]) < 0.02
    assert np.hypot(err[1:, 0], err[1:, 1]).max() < 0.025


def test_the_slam_prior_replaces_only_what_it_sets():
    from featmap.refinement.terms import with_slam_prior

    base = PoseGraphConfig(absolute_sigma_m=None, absolute_sigma_deg=None, slam_absolute_sigma_m=0.1)
    assert with_slam_prior(base, False) is base
    held = with_slam_prior(base, True)
    assert (held.absolute_sigma_m, held.absolute_sigma_deg) == (0.1, None)
    unset = PoseGraphConfig()
    assert with_slam_prior(unset, True) is unset
