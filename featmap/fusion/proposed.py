"""The paper's fusion method (Section 3): three criteria, clustering, support filter, least squares.

Two segments extracted in *different* scans are linked when all three criteria hold:

1. included angle ``beta <= delta`` (eq. 5, from the line coefficients ``A, B``);
2. feature-circle overlap ``epsilon = S_overlap / S_min >= gamma`` (eqs. 7-11; a feature circle has the
   segment's midpoint as centre and its length as diameter);
3. relative distance ``d_max = max(d(O_i, seg_j), d(O_j, seg_i)) <= eta`` (eqs. 12-13).

Clusters are the connected groups of linked segments (what the paper's sequential labelling of
Section 3.2 produces); clusters with fewer than ``min_support`` members are dropped (unless, with
``min_support_length_m``, their members cover that much of one line, and a lone segment
``min_single_length_m``, or, with ``clean_rms_ratio``, one member is a clean view); each remaining
cluster becomes the total-least-squares line through its members' endpoints, cut at the extreme
projections of those endpoints.

Candidate pairs come from a KD-tree over circle centres; the criteria are evaluated vectorised over
candidate pairs in chunks, and clustering is scipy's sparse connected components, so the cost grows
about linearly with the number of segments for a map of bounded density.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Callable, Literal, Optional

import numpy as np
from pydantic import Field
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from featmap.config import Section
from featmap.fusion.base import (TINY_INPUT, FusionMethod, FusionResult, SupportRule, SupportViews, fit_clusters,
                                 relabel_by_first_appearance, validate_input)
from featmap.fusion.gaps import observed_length
from featmap.fusion.visibility import prepare as prepare_visibility
from featmap.geometry import (circle_overlap_area, included_angle, line_coefficients, point_segment_distance,
                              segment_lengths, segment_midpoints)

_QUERY_CHUNK = 20_000


class ProposedConfig(Section):
    """The paper's method (Section 3): three criteria, clustering, least squares."""

    delta_deg: float = Field(5.0, gt=0, le=90, description="criterion 1: max included angle beta")
    gamma: float = Field(0.3, ge=0, le=1, description="criterion 2: min feature-circle overlap S_overlap/S_min")
    eta_m: float = Field(0.5, ge=0, description="criterion 3: max relative distance d_max")
    min_support: int = Field(4, ge=1, description="drop clusters with fewer member segments")
    min_support_length_m: Optional[float] = Field(3.0, ge=0, description="also keep smaller clusters whose members cover at least this length of their line (null = the paper's count rule only) ...")
    min_single_length_m: Optional[float] = Field(5.0, ge=0, description="... a single segment only if it covers this much (one view is weaker evidence than two that agree; null = min_support_length_m)")
    clean_rms_ratio: Optional[float] = Field(0.5, gt=0, description="also keep smaller clusters with a clean view: a member whose fit rms is at most this times the median of all segments' (the extraction's rms column; null = off) ...")
    clean_min_length_m: float = Field(1.4, ge=0, description="... and that is at least this long")
    coarse_gap_m: Optional[float] = Field(2.0, gt=0, description="a member whose returns lie this far apart along it (the extraction's max_gap column) counts toward min_support but covers no length for min_support_length_m and min_single_length_m (null = off)")
    visible_share: Optional[float] = Field(0.5, gt=0, le=1, description="also keep smaller clusters that at least this share of the scans able to see their line saw (the sensor_x / sensor_y columns; a wall seen through a gap by the only scans that could see it, not a tree crown extracted by two of forty scans; null = off)")
    fit_weighting: Literal["length", "none"] = Field("length", description="weight of each member's endpoints in the TLS fit")


@dataclass(frozen=True)
class PairCriteria:
    """The three criteria evaluated for K pairs ``(i, j)`` (all arrays (K,))."""

    i: np.ndarray
    j: np.ndarray
    beta: np.ndarray          # included angle, radians in [0, pi/2]
    epsilon: np.ndarray       # feature-circle overlap ratio in [0, 1]
    d_max: np.ndarray         # relative distance, metres


def evaluate_pairs(segments: np.ndarray, i: np.ndarray, j: np.ndarray) -> PairCriteria:
    """Evaluate the three criteria for the segment pairs ``(i[k], j[k])``.

    Args:
        segments: (N, 4) world-frame segments with non-zero length.
        i, j: (K,) integer indices into ``segments``.
    """
    seg_i, seg_j = segments[i], segments[j]
    beta = included_angle(line_coefficients(seg_i), line_coefficients(seg_j))
    c_i, c_j = segment_midpoints(seg_i), segment_midpoints(seg_j)
    r_i, r_j = 0.5 * segment_lengths(seg_i), 0.5 * segment_lengths(seg_j)
    d = np.hypot(*(c_i - c_j).T)
    s_min = np.pi * np.minimum(r_i, r_j) ** 2
    epsilon = np.clip(circle_overlap_area(r_i, r_j, d) / s_min, 0.0, 1.0)
    d_max = np.maximum(point_segment_distance(c_i, seg_j), point_segment_distance(c_j, seg_i))
    return PairCriteria(i=i, j=j, beta=beta, epsilon=epsilon, d_max=d_max)


def linked_pairs_exhaustive(segments: np.ndarray, scan: np.ndarray, config: ProposedConfig) -> tuple[np.ndarray, np.ndarray]:
    """All pairs ``(i, j)``, ``i < j``, from different scans that meet the three criteria (the reference).

    Its cost grows with the square of how often a wall is seen; :func:`linked_pairs` gives the same
    clusters in linear time. Kept as the definition the fast version is tested against.

    Any linked pair has ``|O_i - O_j| <= min(R_i, R_j) + eta`` (criterion 3: the centre of each lies within
    eta of the other segment) and, when ``gamma > 0``, ``|O_i - O_j| < R_i + R_j`` (criterion 2), so a ball
    query of radius ``R_i + min(eta, R_max)`` around each centre finds every candidate.
    """
    n = len(segments)
    if n < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    centres = segment_midpoints(segments)
    radii = 0.5 * segment_lengths(segments)
    reach = min(config.eta_m, radii.max()) if config.gamma > 0 else config.eta_m
    tree = cKDTree(centres)
    out_i, out_j = [], []
    for start in range(0, n, _QUERY_CHUNK):
        stop = min(start + _QUERY_CHUNK, n)
        neighbours = tree.query_ball_point(centres[start:stop], radii[start:stop] + reach + 1e-9,
                                           workers=-1, return_sorted=False)
        counts = np.fromiter((len(x) for x in neighbours), dtype=np.int64, count=stop - start)
        if counts.sum() == 0:
            continue
        i = np.repeat(np.arange(start, stop), counts)
        j = np.concatenate([np.asarray(x, dtype=np.int64) for x in neighbours if len(x)])
        keep = (j > i) & (scan[i] != scan[j])       # only features of different scans (k vs k - i)
        i, j = i[keep], j[keep]
        if len(i) == 0:
            continue
        ok = _meets_criteria(evaluate_pairs(segments, i, j), config)
        out_i.append(i[ok])
        out_j.append(j[ok])
    if not out_i:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(out_i), np.concatenate(out_j)


def linked_pairs(segments: np.ndarray, scan: np.ndarray, config: ProposedConfig,
                 progress: Callable[[int, int], None] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A sparse set of linked pairs ``(i, j)``, ``i < j``, with the clusters of :func:`linked_pairs_exhaustive`.

    Every returned pair meets the three criteria; the connected components of the returned pairs are
    those of all linked pairs, and so is, per component, the smallest ``max(scan_i, scan_j)`` over its
    links (the key :func:`cluster_segments` orders clusters by). At most ``N - 1`` pairs plus the few
    whose criteria lie within rounding of a threshold. Cost about linear in N whatever the revisit count
    (see :mod:`featmap.fusion.link_forest` for the algorithm and the proof).

    Args:
        segments: (N, 4) world-frame segments with non-zero length, metres.
        scan: (N,) scan index of each segment.
        progress: called as ``progress(done, total)`` with a number of scans, a few dozen times.
    Returns:
        (i (K,), j (K,)) int64.
    """
    from featmap.fusion import link_forest as lf

    n = len(segments)
    if n < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    segments = np.ascontiguousarray(segments, dtype=np.float64)
    eta = float(config.eta_m)
    dist_band = 1e-9 + lf.DISTANCE_BAND_REL * float(np.abs(segments).max())
    centres = segment_midpoints(segments)
    origin = centres.min(axis=0)
    span = float((centres.max(axis=0) - origin).max())
    cell_size = lf.grid_cell_size(eta, float(np.median(segment_lengths(segments))), span)
    cell_xy = np.floor((centres - origin) / cell_size).astype(np.int64)
    ny = int(cell_xy[:, 1].max()) + 1
    keys, cell_of = np.unique(cell_xy[:, 0] * ny + cell_xy[:, 1], return_inverse=True)
    table_keys, table_cell, mask = lf._build_cell_table(keys)
    order = np.argsort(scan, kind="stable")
    _, scan_counts = np.unique(scan[order], return_counts=True)
    scan_start = np.concatenate([[0], np.cumsum(scan_counts)]).astype(np.int64)
    n_scans = len(scan_counts)
    state = dict(
        parent=np.arange(n, dtype=np.int64), comp_size=np.ones(n, np.int64),
        cell_head=np.full(len(keys), -1, np.int64), group_next=np.full(n, -1, np.int64),
        group_root=np.full(n, -1, np.int64), group_head=np.full(n, -1, np.int64),
        group_tail=np.full(n, -1, np.int64), group_box=np.zeros((n, 8)), seg_next=np.full(n, -1, np.int64))
    links_i, links_j = np.empty(n, np.int64), np.empty(n, np.int64)
    undecided_i, undecided_j = np.empty(1024, np.int64), np.empty(1024, np.int64)
    stats = np.zeros(4, np.int64)
    n_groups = n_links = n_undecided = 0
    cos_delta = float(np.cos(np.deg2rad(config.delta_deg)))
    steps = 1 if progress is None else min(n_scans, 50)
    bounds = np.linspace(0, n_scans, steps + 1).round().astype(int)
    for a, b in zip(bounds[:-1], bounds[1:]):
        n_groups, n_links, n_undecided, undecided_i, undecided_j = lf.link_forest_kernel(
            segments, order, scan_start, a, b, cell_of.reshape(-1),
            table_keys, table_cell, mask, ny, float(origin[0]), float(origin[1]), cell_size,
            cos_delta, float(config.gamma), eta, dist_band, config.delta_deg < 90.0, config.gamma > 0.0,
            state["parent"], state["comp_size"], state["cell_head"], state["group_next"], state["group_root"],
            state["group_head"], state["group_tail"], state["group_box"], state["seg_next"],
            n_groups, links_i, links_j, n_links, undecided_i, undecided_j, n_undecided, stats)
        if progress is not None:
            progress(int(b), n_scans)
    return decided_links(segments, links_i[:n_links], links_j[:n_links], undecided_i[:n_undecided],
                         undecided_j[:n_undecided], config)


def decided_links(segments: np.ndarray, i: np.ndarray, j: np.ndarray, undecided_i: np.ndarray,
                  undecided_j: np.ndarray, config: ProposedConfig) -> tuple[np.ndarray, np.ndarray]:
    """The link forest's links ``(i, j)`` (K,) and those of its undecided pairs (U,) that meet the criteria as
    numpy computes them (pairs within rounding of a threshold), as ``(min, max)`` index pairs of ``segments``."""
    if len(undecided_i):
        ok = _meets_criteria(evaluate_pairs(segments, undecided_i, undecided_j), config)
        i, j = np.concatenate([i, undecided_i[ok]]), np.concatenate([j, undecided_j[ok]])
    return np.minimum(i, j).astype(np.int64), np.maximum(i, j).astype(np.int64)


def _meets_criteria(crit: PairCriteria, config: ProposedConfig) -> np.ndarray:
    """(K,) bool: the three criteria hold (the paper's link test)."""
    delta = np.deg2rad(config.delta_deg)
    return (crit.beta <= delta) & (crit.epsilon >= config.gamma) & (crit.d_max <= config.eta_m)


def cluster_segments(n: int, i: np.ndarray, j: np.ndarray, scan: np.ndarray,
                     segments: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Connected groups of the link graph, labelled in the order the paper's sequential pass finds them.

    A group's label order is the scan ``k`` at which its first link appears when every scan ``k`` is
    compared with the scans before it (``max(scan_i, scan_j)`` minimised over its links); ties and
    singletons are ordered by first scan and position, so the labels do not depend on input order.
    Returns (group id per segment (N,), group sizes (G,)).
    """
    graph = coo_matrix((np.ones(len(i), dtype=np.int8), (i, j)), shape=(n, n))
    _, groups = connected_components(graph, directed=False)
    n_groups = int(groups.max()) + 1 if n else 0
    first_link = np.full(n_groups, np.iinfo(np.int64).max)
    if len(i):
        np.minimum.at(first_link, groups[i], np.maximum(scan[i], scan[j]))
    return relabel_by_first_appearance(groups, scan, segments, order_key=first_link)


def fuse_proposed(segments, scan, config: ProposedConfig = ProposedConfig(),
                  progress: Callable[[int, int], None] | None = None,
                  views: SupportViews = SupportViews()) -> FusionResult:
    """Fuse world-frame segments with the paper's method.

    Args:
        segments: (N, 4) ``x1, y1, x2, y2`` in the world frame, metres.
        scan: (N,) index of the scan each segment was extracted from.
        config: thresholds delta, gamma, eta, the support filter and fit weighting.
        progress: optional ``progress(done, total)`` callback (scans linked so far, all scans).
        views: the support rule's clean and coarse views of the N (``SupportRule.views``).
    Returns:
        FusionResult with (M, 4) fused segments (before corner optimisation; the registry applies it).
    """
    segments, scan, valid = validate_input(segments, scan)
    idx = np.flatnonzero(valid)
    if len(idx) == 0:
        return fuse_links(segments, scan, valid, np.zeros(0, np.int64), np.zeros(0, np.int64), config, views)
    i, j = linked_pairs(segments[idx], scan[idx], config, progress)
    return fuse_links(segments, scan, valid, i, j, config, views)


def fuse_links(segments: np.ndarray, scan: np.ndarray, valid: np.ndarray, i: np.ndarray, j: np.ndarray,
               config: ProposedConfig = ProposedConfig(), views: SupportViews = SupportViews()) -> FusionResult:
    """The method's clusters, support filter and fit, from linked pairs found already.

    Args:
        segments: (N, 4) world-frame segments, metres; scan: (N,) their scans; valid: (N,) bool, the
            segments long enough to fuse (``validate_input``).
        i, j: (K,) linked pairs as indices into the valid segments (``segments[valid]``), with the connected
            components and first-link scans of all linked pairs (``linked_pairs``, or an
            :class:`featmap.fusion.online.OnlineFusion`).
        views: the support rule's clean and coarse views of the N (``SupportRule.views``; coarse views
            cover no length).
    """
    labels = np.full(len(segments), -1, dtype=np.int64)
    idx = np.flatnonzero(valid)
    seg, sc = segments[idx], scan[idx]
    if len(seg) == 0:
        empty = np.zeros((0, 4))
        return FusionResult(empty, np.zeros(0, np.int64), labels, empty, 0, int((~valid).sum()))
    groups, sizes = cluster_segments(len(seg), i, j, sc, seg)
    views = views.subset(idx)

    @functools.cache
    def lines() -> np.ndarray:
        return fit_clusters(seg, groups, len(sizes), segment_lengths(seg))

    def covered() -> np.ndarray:
        # Few views of a wall still make it a wall when they cover enough of one line.
        small = sizes[groups] < config.min_support
        return observed_length(lines(), seg, views.covering(np.where(small, groups, -1)))

    kept = support_rule(config).keep(sizes, covered, views.clean_members(groups, len(sizes)),
                                     views.seen(lines, groups, sc))
    new_id = np.full(len(sizes), -1, dtype=np.int64)
    new_id[kept] = np.arange(kept.sum())
    sub_labels = new_id[groups]
    weights = segment_lengths(seg) if config.fit_weighting == "length" else None
    fused = fit_clusters(seg, sub_labels, int(kept.sum()), weights)
    labels[idx] = sub_labels
    support = sizes[kept].astype(np.int64)
    return FusionResult(segments=fused, support=support, labels=labels, segments_before_corners=fused,
                        clusters_dropped=int((~kept).sum()), skipped_zero_length=int((~valid).sum()),
                        extras={"links_kept": int(len(i))})


def support_rule(config: ProposedConfig) -> SupportRule:
    """The support filter of the proposed method's config."""
    return SupportRule(config.min_support, config.min_support_length_m, config.min_single_length_m,
                       config.clean_rms_ratio, config.clean_min_length_m, config.coarse_gap_m,
                       config.visible_share)


def _prepare() -> None:
    """Load the compiled code: the links' and the visibility clause's (on tiny inputs)."""
    fuse_proposed(*TINY_INPUT)
    prepare_visibility()


METHOD = FusionMethod(name="proposed", title="Proposed (three criteria)", color="#d62728", linestyle="-",
                      config_type=ProposedConfig, fuse=fuse_proposed,
                      support_rule=support_rule,
                      prepare=_prepare)
