"""Properties every fusion method keeps on any finite input (hypothesis).

Any input (duplicates, zero-length rows, collinear walls, huge coordinates, one scan or thousands) gives
finite output without a crash; the fused map does not depend on the order of the rows, nor on a global
translation of the coordinates (translated by up to 1e6 m: the same map, translated, within 1 mm).
"""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from featmap.fusion import FUSION_METHODS, FusionConfig, fuse
from featmap.fusion.gaps import trim_coarse_ends
from featmap.geometry import point_segment_distance

CONFIG = FusionConfig.model_validate({"proposed": {"min_support": 2}})
SETTINGS = settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow], derandomize=True)
"""Derandomized: every run (CI included) tries the same examples, so a failure is reproducible, not luck."""


@st.composite
def segment_sets(draw, max_walls=6):
    """Noisy partial views of a few walls, plus duplicates, zero-length rows and stray segments."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    n_walls = draw(st.integers(1, max_walls))
    n_scans = draw(st.sampled_from([1, 3, 40, 3000]))
    starts = rng.uniform(-60, 60, (n_walls, 2))
    angles = rng.choice([0.0, np.pi / 2, rng.uniform(0, np.pi)], n_walls)
    lengths = rng.uniform(0.5, 40, n_walls)
    rows, scans = [], []
    for w in range(n_walls):
        d = np.array([np.cos(angles[w]), np.sin(angles[w])])
        for _ in range(int(rng.integers(1, 12))):
            a, b = np.sort(rng.uniform(0, 1, 2))
            p, q = starts[w] + a * lengths[w] * d, starts[w] + b * lengths[w] * d
            rows.append(np.concatenate([p, q]) + rng.normal(0, draw(st.sampled_from([0.0, 0.01, 0.05])), 4))
            scans.append(int(rng.integers(0, n_scans)))
    segments = np.asarray(rows)
    if draw(st.booleans()):                                   # exact duplicates
        segments = np.vstack([segments, segments[:3]])
        scans += scans[:3]
    if draw(st.booleans()):                                   # zero-length rows
        segments = np.vstack([segments, [[5.0, 5.0, 5.0, 5.0]]])
        scans.append(0)
    return segments, np.asarray(scans, np.int64)


def _canonical(segments: np.ndarray) -> np.ndarray:
    """Undirected segments in a canonical order (endpoints sorted, rows sorted), rounded to 0.1 mm."""
    ends = segments.reshape(-1, 2, 2)
    flip = (ends[:, 0, 0] > ends[:, 1, 0]) | ((ends[:, 0, 0] == ends[:, 1, 0]) & (ends[:, 0, 1] > ends[:, 1, 1]))
    ends[flip] = ends[flip][:, ::-1]
    rows = np.round(ends.reshape(-1, 4), 4)
    return rows[np.lexsort(rows.T[::-1])]


@pytest.mark.parametrize("name", list(FUSION_METHODS))
@SETTINGS
@given(data=segment_sets())
def test_finite_input_gives_finite_output(name, data):
    segments, scan = data
    result = fuse(name, segments, scan, CONFIG)
    assert np.isfinite(result.segments).all()
    assert result.segments.shape == (len(result.support), 4)
    assert result.support.sum() == (result.labels >= 0).sum()
    assert len(result.labels) == len(segments)


@pytest.mark.parametrize("name", list(FUSION_METHODS))
@SETTINGS
@given(data=segment_sets(), seed=st.integers(0, 1000))
def test_the_order_of_the_rows_does_not_matter(name, data, seed):
    segments, scan = data
    order = np.random.default_rng(seed).permutation(len(segments))
    a = fuse(name, segments, scan, CONFIG).segments
    b = fuse(name, segments[order], scan[order], CONFIG).segments
    assert len(a) == len(b)
    assert np.abs(_canonical(a.copy()) - _canonical(b.copy())).max(initial=0.0) < 1e-3


@pytest.mark.parametrize("name", list(FUSION_METHODS))
@SETTINGS
@given(data=segment_sets(), dx=st.floats(-1e6, 1e6), dy=st.floats(-1e6, 1e6))
def test_a_global_translation_moves_the_map_and_nothing_else(name, data, dx, dy):
    segments, scan = data
    shift = np.array([dx, dy, dx, dy])
    a = fuse(name, segments, scan, CONFIG).segments
    b = fuse(name, segments + shift, scan, CONFIG).segments
    assert len(a) == len(b)
    assert np.abs(_canonical(a.copy()) - _canonical(b - shift)).max(initial=0.0) < 1e-3


@SETTINGS
@given(data=segment_sets(), seed=st.integers(0, 1000))
def test_clean_views_keep_the_map_independent_of_row_order(data, seed):
    """With the extraction's rms (here random, some rows much thinner than the median), the proposed method's
    clean-view clause keeps the map independent of the order of the rows, and keeps at least as many
    segments in features as without it."""
    segments, scan = data
    rng = np.random.default_rng(seed)
    rms = rng.choice([0.002, 0.01, 0.02], len(segments))
    order = rng.permutation(len(segments))
    a = fuse("proposed", segments, scan, CONFIG, rms=rms)
    b = fuse("proposed", segments[order], scan[order], CONFIG, rms=rms[order])
    assert len(a) == len(b)
    assert np.abs(_canonical(a.segments.copy()) - _canonical(b.segments.copy())).max(initial=0.0) < 1e-3
    assert (a.labels >= 0).sum() >= (fuse("proposed", segments, scan, CONFIG).labels >= 0).sum()


@SETTINGS
@given(data=segment_sets(), seed=st.integers(0, 1000), dx=st.floats(-1e6, 1e6), dy=st.floats(-1e6, 1e6))
def test_the_visibility_clause_keeps_the_map_independent_of_row_order_and_translation(data, seed, dx, dy):
    """With sensor positions (one random place per scan) and visible_share, the proposed method's map does not
    depend on the order of the rows nor on a global translation of segments and positions together."""
    segments, scan = data
    rng = np.random.default_rng(seed)
    place = rng.uniform(-80, 80, (int(scan.max()) + 1, 2))
    xy = place[scan]
    visible = FusionConfig.model_validate({"proposed": {"min_support": 2, "visible_share": 0.5}})
    order = rng.permutation(len(segments))
    a = fuse("proposed", segments, scan, visible, sensor_xy=xy)
    b = fuse("proposed", segments[order], scan[order], visible, sensor_xy=xy[order])
    assert len(a) == len(b)
    assert np.abs(_canonical(a.segments.copy()) - _canonical(b.segments.copy())).max(initial=0.0) < 1e-3
    shift = np.array([dx, dy])
    c = fuse("proposed", segments + np.tile(shift, 2), scan, visible, sensor_xy=xy + shift)
    assert len(c) == len(a)
    assert np.abs(_canonical(a.segments.copy()) - _canonical(c.segments - np.tile(shift, 2))).max(initial=0.0) < 1e-3


def test_clean_views_keep_a_short_end_segment_found_by_hypothesis():
    """A counterexample hypothesis found (random search, 2026-12-02) to the last assertion of
    ``test_clean_views_keep_the_map_independent_of_row_order``: segment 6 (3.5 m, at the wall's end, 3.4 cm
    from the feature's line) was in the feature without rms and left out with it (the merge step measured
    the 19 m feature's far endpoints against the short segment's own line; see ``offset_from_heavier``)."""
    segments = np.array([[-21.39395524, -38.01957199, -23.29526213, -31.55037526],
                         [-17.99004136, -49.60138905, -18.58598214, -47.57370052],
                         [-21.73357836, -36.86400433, -23.30543277, -31.51576965],
                         [-20.90500785, -39.68321551, -22.51263533, -34.21326295],
                         [-19.51670751, -44.40690743, -19.96273472, -42.88929985],
                         [-18.590059, -47.41106946, -19.634441, -43.91631008],
                         [-23.35260655, -31.4553975, -24.28494152, -28.0685443],
                         [-18.85015734, -46.67484439, -24.17278798, -28.56459353]])
    scan = np.array([0, 0, 1, 1, 0, 2, 0, 2])
    rms = np.array([0.01, 0.01, 0.02, 0.02, 0.002, 0.002, 0.02, 0.02])
    assert (fuse("proposed", segments, scan, CONFIG, rms=rms).labels >= 0).sum() >= \
        (fuse("proposed", segments, scan, CONFIG).labels >= 0).sum()


TRIM = FusionConfig.model_validate({"proposed": {"min_support": 2}, "refine": {"coarse_end_factor": 2.0}})


@SETTINGS
@given(data=segment_sets(), seed=st.integers(0, 1000))
def test_with_the_end_trim_on_the_map_stays_finite_and_independent_of_row_order(data, seed):
    """With the extraction's max_gap (here random: coarse views with columns metres apart among fine ones)
    and the end trim on, every method's map is finite and does not depend on the order of the rows."""
    segments, scan = data
    rng = np.random.default_rng(seed)
    max_gap = rng.choice([0.1, 0.3, 2.5, 7.0], len(segments))
    order = rng.permutation(len(segments))
    for name in FUSION_METHODS:
        a = fuse(name, segments, scan, TRIM, max_gap=max_gap)
        b = fuse(name, segments[order], scan[order], TRIM, max_gap=max_gap[order])
        assert np.isfinite(a.segments).all() and len(a) == len(b)
        assert np.abs(_canonical(a.segments.copy()) - _canonical(b.segments.copy())).max(initial=0.0) < 1e-3


@settings(max_examples=300, deadline=None, derandomize=True)                     # (pure numpy, 1 s in all)
@given(angle=st.floats(0, 2 * np.pi), x0=st.floats(-500, 500), y0=st.floats(-500, 500),
       length=st.floats(5, 40), beyond=st.floats(0.3, 6), column=st.floats(1, 8), start=st.floats(0.3, 8),
       offset=st.floats(-0.6, 0.6))
def test_the_end_trim_cuts_back_to_the_fine_views_only_before_a_facade_set_forward_or_back(
        angle, x0, y0, length, beyond, column, start, offset):
    """A facade seen finely over [0, length] and by coarse views (columns ``column`` apart) on to
    ``length + beyond``, the next facade starting ``start`` past it, ``offset`` off its line: the trim keeps
    the next facade as it is, never cuts into the fine views, cuts only to their end and only when the next
    facade is on a line of its own (0.1-0.5 m off), within one column of the coarse views' end, and the
    stretch is shorter than two columns; clearly inside those bounds it always cuts."""
    u = np.array([np.cos(angle), np.sin(angle)])
    n = np.array([-u[1], u[0]])
    o = np.array([x0, y0])
    at = lambda t, off=0.0: o + t * u + off * n                                # noqa: E731
    fine = np.array([[*at(0), *at(length)]] * 5)
    coarse = np.array([[*at(0), *at(length + beyond)]] * 3)
    segments = np.vstack([fine, coarse])
    max_gap = np.r_[np.full(5, 0.2), np.full(3, column)]
    labels = np.zeros(8, np.int64)
    wall = np.array([[*at(0), *at(length + beyond)]])
    nxt = np.array([[*at(length + start, offset), *at(length + start + 10, offset)]])
    out, cut = trim_coarse_ends(np.vstack([wall, nxt]), segments, labels, max_gap, 2.0)
    assert np.array_equal(out[1], nxt[0])
    assert point_segment_distance(out[0, :2][None], wall)[0] < 1e-6 and point_segment_distance(out[0, 2:][None], wall)[0] < 1e-6
    assert np.hypot(*(out[0, :2] - at(0))) < 1e-6                                # the start is never cut
    if cut:
        assert np.hypot(*(out[0, 2:] - at(length))) < 1e-6                        # cut to where the fine views end
        assert 0.1 <= abs(offset) <= 0.5 and start <= beyond + column + 1e-6 and beyond < 2 * column
    else:
        assert np.array_equal(out[0], wall[0])
    if 0.15 < abs(offset) < 0.45 and start < beyond + column - 0.1 and beyond < 2 * column - 0.1:
        assert cut == 1
