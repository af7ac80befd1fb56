"""The vertical-structure extractor's array helpers give exactly what the numpy/scipy calls they stand for give."""

import tracemalloc

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from featmap.extraction.vertical_structure import _group_order, _labels, connected_labels, validated_xyz


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 300), density=st.sampled_from([0.0, 0.002, 0.01, 0.05]),
       chain=st.booleans())
def test_connected_labels_are_scipys_components(seed, n, density, chain):
    rng = np.random.default_rng(seed)
    m = int(density * n * n)
    i, j = rng.integers(0, n, m), rng.integers(0, n, m)
    if chain:                                           # long paths in shuffled node order
        perm = rng.permutation(n)
        i, j = np.concatenate([i, perm[:-1]]), np.concatenate([j, perm[1:]])
    _, expected = connected_components(coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n)), directed=False)
    assert np.array_equal(connected_labels(n, i, j), expected)


def test_connected_labels_without_nodes_or_edges():
    assert connected_labels(0, np.zeros(0, np.int64), np.zeros(0, np.int64)).shape == (0,)
    assert np.array_equal(connected_labels(3, np.zeros(0, np.int64), np.zeros(0, np.int64)), [0, 1, 2])


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(0, 500), span=st.sampled_from([1, 5, 1000, 10**7]),
       per_value=st.sampled_from([None, 20, 40]))
def test_labels_are_numpys_unique_inverse(seed, k, span, per_value):
    # (per_value: a span of that many labels per value plus the table's margin, either side of the
    # ratio at which the table gives way to sorting)
    span = span if per_value is None else per_value * k + 65536
    values = np.random.default_rng(seed).integers(0, span, k)
    distinct, inverse = _labels(values)
    expected_distinct, expected_inverse = np.unique(values, return_inverse=True)
    assert np.array_equal(distinct, expected_distinct)
    assert np.array_equal(inverse, expected_inverse)


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(0, 400), groups=st.integers(1, 20), ties=st.booleans(),
       offset=st.sampled_from([0, 2**16 - 21, 2**16]))
def test_group_order_sorts_by_group_then_value(seed, k, groups, ties, offset):
    rng = np.random.default_rng(seed)
    group = rng.integers(0, groups, k) + offset          # (labels from 2**16 up are ordered by another path)
    value = rng.integers(0, 5, k).astype(float) if ties else rng.normal(size=k)
    order = _group_order(group, value)
    assert np.array_equal(np.sort(order), np.arange(k))
    expected = np.lexsort((value, group))
    assert np.array_equal(group[order], group[expected])
    assert np.array_equal(value[order], value[expected])


def test_labels_of_a_wide_range_do_not_take_a_table_of_that_range():
    # 2**20 labels spread over 2**25 values: within 32 times their number, but a table of 2**25 entries
    # would take 300 MB; past LABEL_TABLE_MAX they are sorted instead.
    values = np.random.default_rng(0).integers(0, 2**25, 2**20)
    tracemalloc.start()
    try:
        distinct, inverse = _labels(values)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    expected_distinct, expected_inverse = np.unique(values, return_inverse=True)
    assert np.array_equal(distinct, expected_distinct) and np.array_equal(inverse, expected_inverse)
    assert peak < 120e6


def test_validated_points_are_a_column_major_copy_whatever_the_input_layout():
    points = np.random.default_rng(1).normal(size=(50, 4))
    for given_points in (points, np.asfortranarray(points[:, :3]), points.astype(np.float32), points[::-1]):
        xyz = validated_xyz(given_points)
        assert xyz.flags.f_contiguous and xyz.dtype == np.float64 and not np.shares_memory(xyz, given_points)
        assert np.array_equal(xyz, np.asarray(given_points[:, :3], dtype=np.float64))
