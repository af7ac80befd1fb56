"""The vertical-structure extractor's array helpers give exactly what the numpy/scipy calls they stand for give."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from featmap.extraction.vertical_structure import _group_order, _labels, connected_labels


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
