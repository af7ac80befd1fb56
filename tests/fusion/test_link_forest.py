"""The linear-time link forest gives exactly the exhaustive pairwise clusters (property tests)."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from featmap.fusion.proposed import ProposedConfig
from featmap.fusion.proposed import (_meets_criteria, cluster_segments, evaluate_pairs, fuse_proposed, linked_pairs,
                                     linked_pairs_exhaustive)
from featmap.simulation.segments import city_walls, observe_revisits

SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _assert_same_clusters(segments, scan, config):
    """Same labels (canonical order included) from the sparse links as from all links; sparse links are real."""
    fast_i, fast_j = linked_pairs(segments, scan, config)
    all_i, all_j = linked_pairs_exhaustive(segments, scan, config)
    if len(fast_i):
        assert _meets_criteria(evaluate_pairs(segments, fast_i, fast_j), config).all()
        assert (scan[fast_i] != scan[fast_j]).all()
    got = cluster_segments(len(segments), fast_i, fast_j, scan, segments)
    want = cluster_segments(len(segments), all_i, all_j, scan, segments)
    assert np.array_equal(got[0], want[0])
    assert np.array_equal(got[1], want[1])
    return len(fast_i), len(all_i)


@st.composite
def scenes(draw):
    """Walls (collinear pieces, parallel neighbours near eta), seen in many passes with duplicates."""
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    config = ProposedConfig(
        delta_deg=draw(st.sampled_from([1e-6, 1.0, 5.0, 30.0, 90.0])),
        gamma=draw(st.sampled_from([0.0, 0.3, 0.7, 1.0])),
        eta_m=draw(st.sampled_from([0.0, 0.05, 0.5, 2.0])))
    n_walls = draw(st.integers(1, 4))
    angle = draw(st.sampled_from([0.0, np.pi / 2, np.pi / 4, float(rng.uniform(0, np.pi))]))
    u = np.array([np.cos(angle), np.sin(angle)])
    n = np.array([-u[1], u[0]])
    walls = []
    for _ in range(n_walls):
        kind = draw(st.sampled_from(["collinear", "parallel_near_eta", "random"]))
        length = float(rng.uniform(0.5, 20.0))
        if kind == "collinear":
            start = float(rng.uniform(-20, 20))
            p = start * u
        elif kind == "parallel_near_eta":
            p = float(rng.uniform(-5, 5)) * u + config.eta_m * float(rng.choice([0.5, 1.0, 1.0 + 1e-12, 2.0])) * n
        else:
            p = rng.uniform(-15, 15, 2)
            v = rng.normal(size=2)
            walls.append([*p, *(p + length * v / np.hypot(*v))])
            continue
        walls.append([*p, *(p + length * u)])
    walls = np.asarray(walls)
    passes = draw(st.integers(1, 8))
    views = draw(st.integers(1, 6))
    noise = draw(st.sampled_from([0.0, 1e-6, 0.02, 0.3]))
    segments, scan = observe_revisits(walls, passes, views, rng, noise_m=noise, pose_noise_m=noise,
                                      pose_noise_deg=draw(st.sampled_from([0.0, 0.5, 5.0])),
                                      min_fraction=draw(st.sampled_from([0.05, 0.5, 1.0])),
                                      walls_per_scan=draw(st.sampled_from([0.5, 2.0, 10.0])),
                                      clutter_fraction=draw(st.sampled_from([0.0, 0.3])))
    # exact duplicates, in the same scan and in other scans
    dup = rng.integers(0, len(segments), draw(st.integers(0, 10)))
    same_scan = rng.random(len(dup)) < 0.5
    segments = np.vstack([segments, segments[dup]])
    scan = np.concatenate([scan, np.where(same_scan, scan[dup], rng.integers(0, scan.max() + 2, len(dup)))])
    # reversed directions, arbitrary scan numbers, far-away coordinates
    flip = rng.random(len(segments)) < 0.3
    segments[flip] = segments[flip][:, [2, 3, 0, 1]]
    scan = draw(st.sampled_from([1, -1, 7])) * scan + draw(st.sampled_from([0, 1000]))
    segments = segments + draw(st.sampled_from([0.0, 1e3, 4.5e5]))
    keep = np.hypot(segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1]) > 1e-6
    order = rng.permutation(int(keep.sum()))
    return segments[keep][order], scan[keep][order], config


@SETTINGS
@given(scenes())
def test_same_clusters_as_every_pair_on_random_revisited_scenes(scene):
    segments, scan, config = scene
    _assert_same_clusters(segments, scan, config)


@st.composite
def threshold_pairs(draw):
    """Two segments whose criteria sit on, or one rounding step either side of, a threshold."""
    eta = draw(st.sampled_from([0.5, 0.25, 0.1]))
    length = draw(st.sampled_from([4.0, 10.0, 1.0]))
    step = draw(st.sampled_from([-1, 0, 1]))
    which = draw(st.sampled_from(["offset", "angle", "overlap_tangent", "overlap_contained", "shift"]))
    a = np.array([0.0, 0.0, length, 0.0])
    config = ProposedConfig(eta_m=eta, gamma=0.3, delta_deg=5.0)
    if which == "offset":                   # parallel at exactly eta (d_max == eta)
        b = np.array([0.0, eta, length, eta])
        b[[1, 3]] = np.nextafter(b[[1, 3]], np.inf * step) if step else b[[1, 3]]
    elif which == "angle":                  # the included angle is delta up to rounding
        theta = np.deg2rad(5.0) + step * 1e-15
        b = np.array([0.0, 0.0, length * np.cos(theta), length * np.sin(theta)])
        config = ProposedConfig(eta_m=10.0, gamma=0.0, delta_deg=5.0)
    elif which == "overlap_tangent":        # collinear, circles touching: overlap 0 (gamma = 0 links)
        b = np.array([length, 0.0, 2 * length, 0.0]) + np.array([1, 0, 1, 0]) * step * 1e-12
        config = ProposedConfig(eta_m=100.0, gamma=0.0, delta_deg=5.0)
    elif which == "overlap_contained":      # the small circle touches the big one from inside: overlap 1
        b = np.array([length / 2, 0.0, length, 0.0]) + np.array([1, 0, 1, 0]) * step * 1e-12
        config = ProposedConfig(eta_m=100.0, gamma=1.0, delta_deg=5.0)
    else:                                   # sliding along: centre at distance eta beyond the end
        b = a + np.array([length + eta, 0.0, length + eta, 0.0]) * (1 + step * 1e-15)
        config = ProposedConfig(eta_m=eta, gamma=0.0, delta_deg=5.0)
    offset = draw(st.sampled_from([0.0, 3.0e5]))
    return np.vstack([a, b]) + offset, np.array([0, 1]), config


@settings(max_examples=200, deadline=None)
@given(threshold_pairs())
def test_pairs_on_a_threshold_are_decided_as_the_exhaustive_version_decides(pair):
    segments, scan, config = pair
    fast = linked_pairs(segments, scan, config)
    every = linked_pairs_exhaustive(segments, scan, config)
    assert [list(x) for x in fast] == [list(x) for x in every]


@pytest.mark.parametrize("passes", [1, 5, 20])
def test_revisited_street_same_map_and_far_fewer_links(passes):
    rng = np.random.default_rng(passes)
    segments, scan = observe_revisits(city_walls(12, rng), passes, 15, rng)
    n_fast, n_all = _assert_same_clusters(segments, scan, ProposedConfig())
    assert n_fast < len(segments)                  # a forest: fewer links than segments
    if passes >= 5:
        assert n_all > 10 * n_fast                 # where the exhaustive version pays quadratically


def test_progress_is_reported_in_scans_up_to_the_total():
    rng = np.random.default_rng(0)
    segments, scan = observe_revisits(city_walls(8, rng), 3, 10, rng)
    calls = []
    result = fuse_proposed(segments, scan, progress=lambda done, total: calls.append((done, total)))
    total = len(np.unique(scan))
    assert calls[-1] == (total, total)
    assert all(t == total for _, t in calls) and [d for d, _ in calls] == sorted(d for d, _ in calls)
    assert np.array_equal(result.labels, fuse_proposed(segments, scan).labels)


SCENE_LINKS = """
import numpy as np
from featmap.fusion.proposed import ProposedConfig, linked_pairs
from featmap.simulation.segments import city_walls, observe_revisits
rng = np.random.default_rng(3)
segments, scan = observe_revisits(city_walls(12, rng), passes=3, scans_per_wall=4, rng=rng)
i, j = linked_pairs(segments, scan, ProposedConfig())
print(len(segments), len(i), int(i.sum() + j.sum()))
"""


def test_the_link_forest_works_where_numba_has_nowhere_to_cache_it():
    # a read-only install whose user has no writable cache folder: numba finds no cache locator (forced here
    # with the one locator that never applies outside IPython); featmap compiles without the disk cache
    import os
    import subprocess
    import sys

    def links(**env):
        done = subprocess.run([sys.executable, "-c", SCENE_LINKS], capture_output=True, text=True, timeout=300,
                              env={**os.environ, **env})
        assert done.returncode == 0, done.stderr
        return done.stdout

    assert links(NUMBA_CACHE_LOCATOR_CLASSES="IPythonCacheLocator") == links()
