"""The vertical-structure extractor's array helpers give exactly what the numpy/scipy calls they stand for give."""

import tracemalloc

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from featmap.extraction.vertical_structure import (SEEN_OVER_M, VerticalStructureConfig, _group_order, _hidden_next_to,
                                                   _labels, connected_labels, validated_xyz)


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


def test_sparse_columns_measure_straight_and_coplanar_columns():
    """Three columns of returns one azimuth step apart, 4 m apart in range (a wall seen at grazing
    incidence ~100 m away), each 8 returns over 3 m of height along its ray: straight columns give a
    curve of ~0, columns bent like a crown's round a curve of centimetres; columns that share one
    offset give no offset spread, columns 5 cm apart do."""
    from featmap.extraction.vertical_structure import sparse_columns

    z = np.linspace(0.0, 3.0, 8)
    azimuth = np.deg2rad(np.repeat([1.0, 1.235, 1.47], 8))
    height = np.tile(z, 3)

    def columns(bend):
        rng = np.repeat([100.0, 104.0, 108.0], 8) + 0.1 * height + bend        # each column slants
        pts = np.column_stack([rng * np.cos(azimuth), rng * np.sin(azimuth), height])
        u = pts[-1, :2] - pts[0, :2]
        u /= np.linalg.norm(u)
        return pts, pts[:, :2] @ u

    piece = np.zeros(24, np.int64)
    mean = np.array([[104.0, 2.2]])
    flat = np.zeros(24)
    pts, along = columns(0.0)
    curve, spread, within = sparse_columns(pts, along, flat, piece, mean, 1, 1.0, np.deg2rad(0.1))
    assert curve[0] < 1e-6 and spread[0] < 1e-12 and within[0] < 1e-12
    round_ = 0.3 * (z - 1.5) ** 2
    pts, along = columns(np.tile(round_, 3))
    curve, _, _ = sparse_columns(pts, along, flat, piece, mean, 1, 1.0, np.deg2rad(0.1))
    residual = np.sort(np.abs(round_ - round_.mean()))      # symmetric about the middle: no slope to fit
    assert residual[3] - 1e-6 <= curve[0] <= residual[4] + 1e-6 and curve[0] > 0.07
    wide, _, _ = sparse_columns(pts, along, flat, piece, mean, 1, 1.0, 0.0)
    assert wide[0] == 0.0                                   # no stretch narrow enough to be a column
    stepped = np.repeat([0.0, 0.05, -0.05], 8) + np.tile([0.001, -0.001], 12)
    _, spread, within = sparse_columns(pts, along, stepped, piece, mean, 1, 1.0, np.deg2rad(0.1))
    assert spread[0] == pytest.approx(np.sqrt(2 / 3) * 0.05, rel=1e-6) and within[0] == pytest.approx(0.001)
    empty = sparse_columns(pts[:0], along[:0], flat[:0], piece[:0], mean, 1, 1.0, 0.01)
    assert [v.tolist() for v in empty] == [[0.0]] * 3


def _rays_to(line_x: float, azimuths_deg: np.ndarray, heights: np.ndarray, beyond: np.ndarray) -> np.ndarray:
    """(N, 3) returns of rays at ``azimuths_deg`` x ``heights`` (the height where each ray crosses the line
    x = ``line_x``, for ``line_x`` > 0; -x for < 0): on it, or 10 m farther along the ray where ``beyond``
    (N,) is True."""
    az, z = (g.ravel() for g in np.meshgrid(np.deg2rad(azimuths_deg), heights))
    cross = abs(line_x) / np.cos(az)                                      # range to the line along each ray
    rng = np.where(beyond, cross + 10.0, cross)
    sign = np.sign(line_x)
    return np.column_stack([sign * rng * np.cos(az), sign * rng * np.sin(az), z * rng / cross])


@pytest.mark.parametrize("line_x", [10.0, -10.0])          # -10: the line straddles azimuth +-180 deg
def test_seen_through_is_the_share_of_crossing_rays_that_return_beyond_the_line(line_x):
    from featmap.extraction.vertical_structure import seen_through

    azimuths = np.arange(-20.0, 20.01, 0.5)                   # the line spans -26.6 .. 26.6 deg
    heights = np.linspace(0.5, 2.5, 5)
    n = len(azimuths) * len(heights)
    a, b = np.array([[line_x, -5.0]]), np.array([[line_x, 5.0]])
    z_lo, z_hi = np.array([0.0]), np.array([3.0])
    step = np.deg2rad(0.5)
    wall = _rays_to(line_x, azimuths, heights, np.zeros(n, bool))
    assert seen_through(wall, a, b, z_lo, z_hi, step) == pytest.approx([0.0])
    one_side = np.tile(azimuths < 0, len(heights))           # through on one side of the line's middle
    trees = _rays_to(line_x, azimuths, heights, one_side)
    assert seen_through(trees, a, b, z_lo, z_hi, step) == pytest.approx([one_side.mean()])
    over_the_top = _rays_to(line_x, azimuths, np.array([3.5, 5.0]), np.ones(2 * len(azimuths), bool))
    assert seen_through(np.concatenate([wall, over_the_top]), a, b, z_lo, z_hi, step) == pytest.approx([0.0])
    outside = _rays_to(line_x, np.array([30.0, 40.0]), heights, np.ones(10, bool))   # beside the line's azimuths
    assert seen_through(np.concatenate([wall, outside]), a, b, z_lo, z_hi, step) == pytest.approx([0.0])
    assert seen_through(wall[:0], a, b, z_lo, z_hi, step) == pytest.approx([0.0])            # no ray: 0


def test_continuous_tops_stop_at_the_first_gap_in_height():
    from featmap.extraction.vertical_structure import continuous_tops

    cell = np.array([0, 0, 0, 0, 1, 1, 2, 0])
    height = np.array([0.6, 0.3, 2.5, 0.9, 0.5, 1.0, 3.0, 3.1])
    gap = np.full(8, 0.5)
    # cell 0: 0.3 0.6 0.9 | 2.5 3.1 (a 1.6 m gap); cell 1: a 0.5 m step is no gap; cell 3 has no point
    assert continuous_tops(cell, height, 4, gap).tolist() == [0.9, 1.0, 3.0, -np.inf]
    # the gap allowed is the upper point's: 2.5 may follow 0.9 when its own allowance is 2 m (and 3.1,
    # 0.6 m above it, still may not)
    gap[2] = 2.0
    assert continuous_tops(cell, height, 4, gap).tolist() == [2.5, 1.0, 3.0, -np.inf]
    assert continuous_tops(np.zeros(0, int), np.zeros(0), 2, np.zeros(0)).tolist() == [-np.inf, -np.inf]


def test_a_crown_over_a_fence_lifts_its_cell_only_without_the_column_gap_rule():
    from featmap.extraction.vertical_structure import VerticalStructureConfig, structure_cells

    # one 15 cm cell 12 m ahead: a 1.3 m fence (returns every 0.1 m) and a crown from 3 to 5 m above it
    heights = np.concatenate([np.arange(0.3, 1.31, 0.1), np.arange(3.0, 5.01, 0.25)])
    xyz = np.column_stack([np.full(len(heights), 12.05), np.full(len(heights), 0.05), heights - 1.73])
    for gap, top in ((0.0, 5.0), (0.8, 1.3)):
        config = VerticalStructureConfig(max_column_gap_m=gap, elevation_step_deg=0.4)
        cells = structure_cells(xyz, heights, np.tan(np.deg2rad(2.0)), config, lines_only=True)
        assert cells.top.tolist() == pytest.approx([top]), gap


def _wall_cells(centroids: np.ndarray, along_x: np.ndarray):
    """Cells (C,) at ``centroids`` (C, 2) of 10 returns each, spread evenly over 15 cm along x or along y
    (``along_x`` (C,) bool) and with a 2 cm standard deviation across; only what
    ``rejoin_corner_cells`` and ``stray_cells`` read is filled in."""
    from featmap.extraction.vertical_structure import Cells

    n = len(centroids)
    along, across = 10 * 0.15 ** 2 / 12, 10 * 0.02 ** 2
    scatter = np.where(along_x[:, None], [along, 0.0, across], [across, 0.0, along])
    empty = np.zeros(0)
    return Cells(point_cell=np.zeros(0, np.int64), count=np.full(n, 10.0), centroid=centroids, scatter=scatter,
                 top=np.full(n, 3.0), bottom=np.full(n, 0.3), reaches_top=np.ones(n, bool),
                 hidden_above=np.zeros(n, bool), grid_keys=empty, grid_counts=empty, grid_origin=(0.0, 0.0))


FRONT, SIDE = 3, 7
"""The labels of the two faces in ``_corner`` (labels with gaps, as ``kept_cells`` leaves them)."""


def _corner(stray_xy, with_side_wall=True, side_x=0.0):
    """A wall along y = 0 with cells from x = 0.45 to 5.85 (label FRONT) and, optionally, its corner's
    other face along x = ``side_x`` with cells from y = 0.1 to 4.9 (label SIDE), 15 cm cells; plus
    stray cells at ``stray_xy`` (K, 2), label -1."""
    front_x = np.arange(0.45, 5.9, 0.15)
    side_y = np.arange(0.1, 4.95, 0.15) if with_side_wall else np.zeros(0)
    front = np.column_stack([front_x, np.zeros(len(front_x))])
    side = np.column_stack([np.full(len(side_y), side_x), side_y])
    stray_xy = np.asarray(stray_xy, float).reshape(-1, 2)
    centroids = np.concatenate([front, side, stray_xy])
    label = np.concatenate([np.full(len(front), FRONT), np.full(len(side), SIDE), np.full(len(stray_xy), -1)])
    along_x = np.concatenate([np.ones(len(front), bool), np.zeros(len(side), bool), np.ones(len(stray_xy), bool)])
    return _wall_cells(centroids, along_x), label


def test_cells_beside_a_corner_join_the_wall_they_continue():
    from featmap.extraction.vertical_structure import VerticalStructureConfig, rejoin_corner_cells

    config = VerticalStructureConfig()                    # link_radius_m 0.45, line_tolerance_m 0.08
    strays = [[0.15, 0.01], [0.3, -0.02]]                 # the wall's last two cells, left out of its piece
    cells, label = _corner(strays)
    out = rejoin_corner_cells(cells, label, label < 0, config)
    assert out[-2:].tolist() == [FRONT, FRONT]            # the wall now reaches its corner
    assert np.array_equal(out[:-2], label[:-2])           # nothing else changes
    # not beside a corner (no other face): they stay out, as a stray piece of hedge beyond a wall's end would
    cells, label = _corner(strays, with_side_wall=False)
    assert rejoin_corner_cells(cells, label, label < 0, config)[-2:].tolist() == [-1, -1]
    # off the wall's line (0.15 m > line_tolerance_m), or only cells the caller did not call stray
    cells, label = _corner([[0.3, 0.15]])
    assert rejoin_corner_cells(cells, label, label < 0, config)[-1] == -1
    cells, label = _corner(strays)
    assert rejoin_corner_cells(cells, label, np.zeros(len(label), bool), config)[-2:].tolist() == [-1, -1]


def test_a_stray_cell_joins_only_the_piece_whose_end_it_continues():
    from featmap.extraction.vertical_structure import VerticalStructureConfig, rejoin_corner_cells

    config = VerticalStructureConfig()
    # within the wall's extent (a gap in it, 7 cm from its end at x = 0.45) beside a face at x = 0.1: not
    # beyond the end, so it stays out
    cells, label = _corner([[0.52, 0.03]], side_x=0.1)
    assert rejoin_corner_cells(cells, label, label < 0, config)[-1] == -1
    # farther than link_radius_m from every end
    cells, label = _corner([[-0.05, -0.6]])
    assert rejoin_corner_cells(cells, label, label < 0, config)[-1] == -1
    # on both lines, beyond both ends: it goes to the nearer end (the side face's, 0.13 m; the front's 0.40 m)
    cells, label = _corner([[0.05, -0.02]])
    assert rejoin_corner_cells(cells, label, label < 0, config)[-1] == SIDE


def test_short_pieces_and_cells_in_no_piece_are_stray():
    from featmap.extraction.vertical_structure import VerticalStructureConfig, stray_cells

    cells, label = _corner([[0.15, 0.0], [0.3, 0.0]])
    label[-2:] = 2                                        # a two-cell piece, 0.15 m long
    label[0] = -1
    stray = stray_cells(cells, label, VerticalStructureConfig())
    assert stray[-2:].all() and stray[0] and not stray[1:-2].any()
    assert stray_cells(cells, label, VerticalStructureConfig(min_length_m=0.1))[-2:].tolist() == [False, False]


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), m=st.integers(1, 400), n_cells=st.integers(1, 30),
       step_deg=st.sampled_from([0.1, 0.5, 2.0]), above=st.booleans())
def test_hidden_below_and_cut_above_are_their_definitions(seed, m, n_cells, step_deg, above):
    """A cell's bottom is hidden when, in its azimuth bin, the nearest return with an elevation slope in
    [lowest - band, lowest) (band: 2 beam spacings as tan) lies SEEN_OVER_M nearer than the cell; its top is
    cut (``above``) when the nearest return with a slope in (highest, highest + band] does."""
    rng = np.random.default_rng(seed)
    config = VerticalStructureConfig(elevation_step_deg=step_deg)
    width = np.deg2rad(2.0)

    def az_bin(xy):
        return ((np.arctan2(xy[:, 1], xy[:, 0]) + np.pi) / width).astype(np.int64)

    azimuth = rng.uniform(-0.3, 0.3, m)                       # a few bins only, so windows hold returns
    ranges = rng.uniform(3.0, 60.0, m)
    slope = rng.uniform(-0.1, 0.1, m)
    xyz = np.column_stack([ranges * np.cos(azimuth), ranges * np.sin(azimuth), slope * ranges])
    point_cell = np.where(rng.random(m) < 0.5, rng.integers(0, n_cells, m), -1)
    used = np.unique(point_cell[point_cell >= 0])
    point_cell = np.where(point_cell >= 0, np.searchsorted(used, np.maximum(point_cell, 0)), -1)
    n = len(used)
    inside = np.flatnonzero(point_cell >= 0)
    cell_range = np.array([ranges[point_cell == c].mean() for c in range(n)])
    cell_xy = np.array([xyz[point_cell == c, :2].mean(axis=0) for c in range(n)]).reshape(-1, 2)
    cell_bin = az_bin(cell_xy) if n else np.zeros(0, np.int64)
    got = _hidden_next_to(xyz, ranges, xyz[:, 2] / ranges, point_cell, inside, n, cell_range, cell_bin, az_bin,
                          config, above=above)
    band = 2.0 * np.tan(np.deg2rad(step_deg))
    point_bin = az_bin(xyz[:, :2])
    for c in range(n):
        if above:
            highest = slope[point_cell == c].max()
            window = (point_bin == cell_bin[c]) & (slope > highest) & (slope <= highest + band)
        else:
            lowest = slope[point_cell == c].min()
            window = (point_bin == cell_bin[c]) & (slope >= lowest - band) & (slope < lowest)
        expected = window.any() and ranges[window].min() < cell_range[c] - SEEN_OVER_M
        assert got[c] == expected, c


@pytest.mark.parametrize("above, other_range, other_slope, hidden", [
    (False, 29.4, 0.045, True),    # 0.6 m nearer, one beam spacing below: hides the cell's bottom
    (False, 29.7, 0.045, False),   # 0.3 m nearer only (SEEN_OVER_M is 0.5 m): the wall's own lower return
    (False, 29.4, 0.030, False),   # nearer, but 2.3 beam spacings below: not what hides its bottom
    (False, 29.4, 0.050, False),   # at the cell's lowest slope: not below it
    (False, 45.0, 0.045, False),   # farther: the ray passed under the cell (a crown)
    (True, 29.4, 0.085, True),     # 0.6 m nearer, just above its highest return: a crown in front cuts its top
    (True, 29.7, 0.085, False),    # 0.3 m nearer only: the wall's own upper return
    (True, 29.4, 0.100, False),    # nearer, but more than 2 beam spacings above
    (True, 29.4, 0.080, False),    # at the cell's highest slope: not above it
    (True, 45.0, 0.085, False),    # farther: the ray passed over the cell (its top is seen)
])
def test_a_hidden_edge_needs_a_return_just_beyond_it_and_half_a_metre_nearer(above, other_range, other_slope, hidden):
    config = VerticalStructureConfig(elevation_step_deg=0.5)   # band: 2 x tan(0.5 deg) = 0.0175 in slope
    ranges = np.array([30.0, 30.0, other_range])
    slope = np.array([0.05, 0.08, other_slope])
    xyz = np.column_stack([ranges, np.zeros(3), slope * ranges])
    point_cell = np.array([0, 0, -1])

    def one_bin(xy):
        return np.zeros(len(xy), np.int64)

    got = _hidden_next_to(xyz, ranges, xyz[:, 2] / ranges, point_cell, np.array([0, 1]), 1, np.array([30.0]),
                          np.zeros(1, np.int64), one_bin, config, above=above)
    assert got.tolist() == [hidden]
    if above and hidden:      # ... and at most max_ratio of the cell's range away (29.4 m is 0.98 of 30 m)
        assert not _hidden_next_to(xyz, ranges, xyz[:, 2] / ranges, point_cell, np.array([0, 1]), 1,
                                   np.array([30.0]), np.zeros(1, np.int64), one_bin, config, above=True,
                                   max_ratio=0.8).any()
