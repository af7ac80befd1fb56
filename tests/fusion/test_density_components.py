"""The density method's linear-time neighbour components are scikit-learn DBSCAN's clusters (min_samples = 1)."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from featmap.fusion.density import DensityConfig
from featmap.fusion.base import cluster_orientations
from featmap.fusion.density import _dbscan_per_orientation, along_and_across, cluster_directions, neighbour_components
from featmap.geometry import segment_lengths, segment_orientations
from featmap.simulation.segments import city_walls, observe_revisits


def _same_partition(a, b):
    """True when two labelings group the items identically (ids may differ)."""
    _, a = np.unique(a, return_inverse=True)
    _, b = np.unique(b, return_inverse=True)
    pairs = np.unique(np.stack([a.ravel(), b.ravel()]), axis=1)
    return pairs.shape[1] == len(np.unique(a)) == len(np.unique(b))


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), passes=st.integers(1, 6), walls=st.integers(1, 6),
       eps=st.sampled_from([0.05, 0.5, 3.0]), gap=st.sampled_from([0.0, 1.0, 10.0]),
       noise=st.sampled_from([0.0, 0.03, 0.4]), offset=st.sampled_from([0.0, 2.0e5]))
def test_same_clusters_as_dbscan_on_the_precomputed_neighbourhood(seed, passes, walls, eps, gap, noise, offset):
    rng = np.random.default_rng(seed)
    segments, _ = observe_revisits(city_walls(walls, rng), passes, 8, rng, noise_m=noise, pose_noise_m=noise,
                                   clutter_fraction=0.2)
    segments = segments + offset
    config = DensityConfig(lateral_eps_m=eps, longitudinal_gap_m=gap)
    orient = rng.integers(0, 3, len(segments))          # any orientation clusters: they must never mix
    directions = {}
    umin, umax, v = np.empty(len(segments)), np.empty(len(segments)), np.empty(len(segments))
    for o in np.unique(orient):
        members = np.flatnonzero(orient == o)
        angle = rng.uniform(0, np.pi)
        directions[o] = (members, np.array([np.cos(angle), np.sin(angle)]))
        umin[members], umax[members], v[members] = along_and_across(segments[members], directions[o][1])
    fast = neighbour_components(umin, umax, v, orient, config)
    assert _same_partition(fast, _dbscan_per_orientation(segments, directions, config))
    assert all(len(np.unique(orient[fast == c])) == 1 for c in np.unique(fast))


def test_touching_intervals_and_lateral_eps_are_inclusive():
    # gap exactly longitudinal_gap_m and lateral offset exactly lateral_eps_m are neighbours; a hair more is not
    config = DensityConfig(lateral_eps_m=0.5, longitudinal_gap_m=1.0)
    umin = np.array([0.0, 11.0, 0.0, 0.0, 11.0 + 1e-9])
    umax = np.array([10.0, 20.0, 10.0, 10.0, 20.0])
    v = np.array([0.0, 0.0, 0.5, 0.5 + 1e-9 + 0.5, 3.0])
    groups = neighbour_components(umin, umax, v, np.zeros(5, np.int64), config)
    assert groups[0] == groups[1] == groups[2]
    assert groups[3] != groups[0] and groups[4] != groups[0]


def test_heavy_revisits_give_dbscans_clusters():
    rng = np.random.default_rng(5)
    segments, _ = observe_revisits(city_walls(10, rng), 20, 10, rng)
    config = DensityConfig()
    theta = segment_orientations(segments)
    orient = cluster_orientations(theta, np.deg2rad(config.orientation_bandwidth_deg))
    directions = cluster_directions(theta, orient, segment_lengths(segments))
    umin, umax, v = np.empty(len(segments)), np.empty(len(segments)), np.empty(len(segments))
    for members, direction in directions.values():
        umin[members], umax[members], v[members] = along_and_across(segments[members], direction)
    fast = neighbour_components(umin, umax, v, orient, config)
    assert _same_partition(fast, _dbscan_per_orientation(segments, directions, config))
    assert 10 <= len(np.unique(fast)) < 0.2 * len(segments)
