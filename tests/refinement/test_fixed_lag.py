"""Causal fixed-lag refinement: drift removed one scan at a time, decided corrections never change, the
problem stays bounded, exact poses stay exact."""

import numpy as np
import pytest

from featmap.datasets.carmen import pose_matrix
from featmap.extraction.base import segments_to_world
from featmap.refinement import RefinementConfig, planar_difference, refine
from featmap.refinement.fixed_lag import FixedLagConfig, FixedLagRefiner, refine_fixed_lag
from featmap.simulation.simulate import oxts_drift
from tests.refinement.conftest import path, refinement_input, scan_segments

# Small windows, so that a 48-scan drive marginalises many times.
SMALL = FixedLagConfig(lag_scans=6, solve_every=3, context_scans=4)


@pytest.fixture(scope="module")
def long_hall():
    """Two laps of the hall (48 scans, 0.5 s apart): (true poses (48, 3), their scans' segments)."""
    poses = np.vstack([path(), path()])
    return poses, scan_segments(poses, np.random.default_rng(1))


def _feed(refiner, scans, given, dt=0.5):
    decided = []
    for k, (s, p) in enumerate(zip(scans, given)):
        T = pose_matrix(p)
        decided += refiner.add_scan(segments_to_world(s, T), T, k * dt)
    return decided


def test_gauss_markov_drift_shrinks_one_scan_at_a_time(long_hall):
    """0.2 m / 0.4 deg OXTS-like drift (5 s correlation) on two laps of a small hall: the decided poses
    jump from scan to scan at most a third as much as the drifting ones (a map's walls stay together),
    and lie closer to the truth on average, with at most 6 + 2 x 3 + 4 scans in any problem solved. A
    causal estimate cannot do what the offline pose graph does: each decision has only the absolute
    prior of the scans so far, so on a drive this short successive decisions still differ by up to
    6 cm (the offline pose graph: 2 cm, tests/refinement/test_methods.py)."""
    poses, scans = long_hall
    drift = oxts_drift(np.random.default_rng(7), np.arange(len(poses)) * 0.5, (0.2, 0.4), 5.0)
    refiner = FixedLagRefiner(SMALL)
    largest = 0
    for k, (s, p) in enumerate(zip(scans, poses + drift)):
        T = pose_matrix(p)
        refiner.add_scan(segments_to_world(s, T), T, k * 0.5)
        largest = max(largest, len(refiner) - refiner.first)
    assert refiner.decided == len(poses) - SMALL.lag_scans
    refiner.finish()
    assert refiner.decided == len(poses) and refiner.applied > 0 and refiner.first > 20
    assert largest <= SMALL.lag_scans + 2 * SMALL.solve_every + SMALL.context_scans
    truth = np.stack([pose_matrix(p) for p in poses])
    refined = planar_difference(np.stack([refiner.decided_pose(k) for k in range(len(poses))]), truth)
    given = planar_difference(np.stack([pose_matrix(p) for p in poses + drift]), truth)

    def largest_step(err):
        step = np.diff(err, axis=0)
        return np.hypot(step[:, 0], step[:, 1]).max(), np.abs(step[:, 2]).max()

    (step_m, step_rad), (given_m, given_rad) = largest_step(refined), largest_step(given)
    assert step_m < given_m / 3 and step_rad < given_rad / 3
    assert np.hypot(refined[:, 0], refined[:, 1]).mean() < 0.85 * np.hypot(given[:, 0], given[:, 1]).mean()
    # the decided segments are the scans' segments on their refined poses
    k = 17
    T = refiner.decided_pose(k)
    assert np.allclose(refiner.decided_segments(k), segments_to_world(scans[k], T)[:, :4], atol=1e-9)


def test_a_decided_correction_never_changes_and_needs_no_later_scan(long_hall):
    """Causality: what is decided after scan k depends on scans 0..k only, and stays as decided."""
    poses, scans = long_hall
    given = poses + oxts_drift(np.random.default_rng(3), np.arange(len(poses)) * 0.5, (0.2, 0.4), 5.0)
    whole = FixedLagRefiner(SMALL)
    decided_at = {}
    for k, (s, p) in enumerate(zip(scans, given)):
        T = pose_matrix(p)
        for j in whole.add_scan(segments_to_world(s, T), T, k * 0.5):
            decided_at[j] = whole.corrections[j].copy()
    whole.finish()
    for j, c in decided_at.items():
        assert np.array_equal(whole.corrections[j], c)
    prefix = FixedLagRefiner(SMALL)                      # the same drive cut after 30 scans
    _feed(prefix, scans[:30], given[:30])
    upto = prefix.decided
    assert upto == 30 - SMALL.lag_scans
    assert np.array_equal(prefix.corrections[:upto], whole.corrections[:upto])


def test_the_registry_method_is_the_smoother_fed_in_order(long_hall):
    poses, scans = long_hall
    given = poses + oxts_drift(np.random.default_rng(5), np.arange(len(poses)) * 0.5, (0.2, 0.4), 5.0)
    inp = refinement_input(scans, given)
    result = refine(inp, RefinementConfig(method="fixed_lag", fixed_lag=SMALL))
    refiner = FixedLagRefiner(SMALL)
    _feed(refiner, scans, given)
    refiner.finish()
    assert np.array_equal(result.corrections, refiner.corrections)
    assert result.stats["applied"] and result.stats["residual_after_mm"] < 5 < result.stats["residual_before_mm"]
    assert np.array_equal(refine_fixed_lag(inp, SMALL).poses, result.poses)


def test_exact_poses_stay_exact_in_every_window(long_hall):
    poses, scans = long_hall
    refiner = FixedLagRefiner(SMALL)
    _feed(refiner, scans, poses)
    refiner.finish()
    assert refiner.solves > 10 and refiner.applied == 0 and not refiner.corrections.any()


def test_odometry_without_an_absolute_prior_holds_the_first_scan_and_follows_a_jump(long_hall):
    """No absolute prior (wheel odometry): the drive's first scan stays put, not the first of each problem,
    and a jump in the odometry halfway is taken out."""
    poses, scans = long_hall
    given = poses.copy()
    given[20:] += [0.3, 0.2, np.deg2rad(1.5)]
    config = SMALL.model_copy(update=dict(absolute_sigma_m=None, absolute_sigma_deg=None, motion_sigma_m=0.01,
                                          motion_sigma_deg=0.05, motion_sigma_m_per_sqrt_m=0.05,
                                          motion_sigma_deg_per_sqrt_m=1.0))
    refiner = FixedLagRefiner(config)
    _feed(refiner, scans, given)
    refiner.finish()
    assert np.abs(refiner.corrections[0]).max() < 1e-5
    refined = np.stack([refiner.decided_pose(k) for k in range(len(poses))])
    err = planar_difference(refined, np.stack([pose_matrix(p) for p in poses]))
    assert np.hypot(err[:, 0], err[:, 1]).max() < 0.03 and np.rad2deg(np.abs(err[:, 2])).max() < 0.15


def test_scans_without_segments_and_asking_for_an_undecided_scan():
    refiner = FixedLagRefiner(SMALL)
    for k in range(10):
        refiner.add_scan(np.zeros((0, 4)), pose_matrix(np.array([k * 0.5, 0.0, 0.0])), None)
    assert refiner.decided == 10 - SMALL.lag_scans and not refiner.corrections.any()
    with pytest.raises(ValueError, match="scan 9 is not decided yet"):
        refiner.decided_pose(9)
    assert refiner.finish() == list(range(4, 10)) and refiner.finish() == []


def test_the_online_loop_of_docs_online_md_maps_every_scan_once(long_hall):
    """The Python example of docs/online.md: every scan reaches the map once, on its decided pose, and the
    map is the offline proposed map of the decided segments."""
    from featmap.extraction.base import world_fields
    from featmap.fusion import fuse
    from featmap.fusion.online import OnlineFusion

    poses, scans = long_hall
    given = poses + oxts_drift(np.random.default_rng(9), np.arange(len(poses)) * 0.5, (0.2, 0.4), 5.0)
    online, refiner = OnlineFusion(), FixedLagRefiner(SMALL)
    rms_of, linked = {}, []
    for k, (s, p) in enumerate(zip(scans, given)):
        T = pose_matrix(p)
        rms_of[len(refiner)] = world_fields(s, T)["rms"]
        for j in refiner.add_scan(segments_to_world(s, T), T, k * 0.5):
            online.add_scan(refiner.decided_segments(j), rms_of.pop(j))
            linked.append(j)
    for j in refiner.finish():
        online.add_scan(refiner.decided_segments(j), rms_of.pop(j))
        linked.append(j)
    assert linked == list(range(len(poses))) and not rms_of
    segments = [refiner.decided_segments(j) for j in linked]
    offline = fuse("proposed", np.concatenate(segments), np.repeat(np.arange(len(segments)), [len(x) for x in segments]),
                   rms=np.concatenate([world_fields(s, pose_matrix(p))["rms"] for s, p in zip(scans, given)]))
    assert np.array_equal(online.fused().segments, offline.segments)


def test_lag_shorter_than_the_solve_interval_is_refused_in_one_line():
    from pydantic import ValidationError

    with pytest.raises(ValidationError, match=r"lag_scans \(2\) must be at least solve_every \(30\)"):
        FixedLagConfig(lag_scans=2, solve_every=30)


def test_the_end_of_the_drive_does_not_solve_the_same_scans_twice(long_hall):
    poses, scans = long_hall
    refiner = FixedLagRefiner(FixedLagConfig(lag_scans=6, solve_every=6, context_scans=4))
    _feed(refiner, scans[:24], poses[:24])
    assert refiner.solves == 4
    refiner.finish()
    assert refiner.solves == 4 and refiner.decided == 24


def test_the_marginal_prior_stays_a_gaussian_with_repeated_and_uneven_timestamps(long_hall):
    """A repeated timestamp (floored to a tenth of the median step) and uneven steps: the motion terms the
    prior takes are those of the scans that left, so it stays symmetric positive semi-definite."""
    poses, scans = long_hall
    stamps = np.cumsum(np.where(np.arange(len(poses)) < 20, 0.1, 0.5))
    stamps[25] = stamps[24]                                        # a repeated timestamp
    given = poses + oxts_drift(np.random.default_rng(2), stamps, (0.2, 0.4), 5.0)
    refiner = FixedLagRefiner(SMALL)
    for k, (s, p) in enumerate(zip(scans, given)):
        T = pose_matrix(p)
        refiner.add_scan(segments_to_world(s, T), T, float(stamps[k]))
        if refiner._prior is not None:
            H = refiner._prior[0]
            assert np.allclose(H, H.T)
            assert np.linalg.eigvalsh(H).min() >= -1e-9 * np.abs(H).max()
    assert refiner.first > 20
