"""Pairs of owners with points within a distance: the same pairs as a KD-tree's close pairs of points."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from featmap.fusion.close_pairs import close_owner_pairs


def _kd_tree_pairs(points, owner, reach, n_owners):
    pairs = cKDTree(points).query_pairs(reach, output_type="ndarray")
    a, b = owner[pairs[:, 0]], owner[pairs[:, 1]]
    other = a != b
    return np.unique(np.minimum(a[other], b[other]) * n_owners + np.maximum(a[other], b[other]))


def test_two_lines_a_reach_apart_pair_and_a_third_farther_does_not():
    along = np.arange(0.0, 5.01, 0.25)
    points = np.concatenate([np.column_stack([along, np.zeros_like(along)]),          # owner 0 at y = 0
                             np.column_stack([along, np.full_like(along, 0.5)]),      # owner 1 at y = 0.5
                             np.column_stack([along, np.full_like(along, 1.51)])])    # owner 2 at y = 1.51
    owner = np.repeat([0, 1, 2], len(along))
    keys = close_owner_pairs(points, owner, 0.5, 3)
    assert keys.tolist() == [0 * 3 + 1]                   # exactly 0.5 apart counts; 1.01 does not
    assert np.divmod(keys, 3)[1].tolist() == [1]
    assert close_owner_pairs(points, owner, 0.49, 3).size == 0
    assert close_owner_pairs(points[:1], owner[:1], 1.0, 3).size == 0      # one point: no pair


@pytest.mark.parametrize("origin", [0.0, -3.7e5, 4.2e6])
def test_far_from_the_frame_origin_the_same_pairs(origin):
    rng = np.random.default_rng(1)
    points = rng.uniform(0, 20, (600, 2)) + origin
    owner = rng.integers(0, 40, 600)
    assert np.array_equal(close_owner_pairs(points, owner, 0.6, 40), _kd_tree_pairs(points, owner, 0.6, 40))


@settings(max_examples=150, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(2, 300), st.integers(1, 25),
       st.sampled_from([0.1, 0.25, 0.3, 0.375, 0.5, 0.625]), st.booleans())
def test_the_same_pairs_as_a_kd_tree(seed, n_points, n_owners, reach, on_a_grid):
    rng = np.random.default_rng(seed)
    if on_a_grid:              # points 0.125 m apart: many pairs exactly a reach apart
        points = rng.integers(-16, 16, (n_points, 2)) * 0.125
    else:
        points = rng.uniform(-4, 4, (n_points, 2))
    owner = rng.integers(0, n_owners, n_points)
    assert np.array_equal(close_owner_pairs(points, owner, reach, n_owners),
                          _kd_tree_pairs(points, owner, reach, n_owners))


def test_many_close_pairs_grow_the_buffer_and_stay_the_same():
    rng = np.random.default_rng(3)
    points = rng.uniform(0, 3, (3000, 2))              # about 127k pairs within 0.3 m: far past the first buffer
    owner = np.arange(3000)
    keys = close_owner_pairs(points, owner, 0.3, 3000)
    assert len(keys) > 100_000 and np.array_equal(keys, _kd_tree_pairs(points, owner, 0.3, 3000))
