"""The paper's fusion method (Section 3): three criteria, clustering, support filter, least squares.

Two segments extracted in *different* scans are linked when all three criteria hold:

1. included angle ``beta <= delta`` (eq. 5, from the line coefficients ``A, B``);
2. feature-circle overlap ``epsilon = S_overlap / S_min >= gamma`` (eqs. 7-11; a feature circle has the
   segment's midpoint as centre and its length as diameter);
3. relative distance ``d_max = max(d(O_i, seg_j), d(O_j, seg_i)) <= eta`` (eqs. 12-13).

Clusters are the connected groups of linked segments (what the paper's sequential labelling of
Section 3.2 produces); clusters with fewer than ``min_support`` members are dropped (unless, with
``min_support_length_m``, their members cover that much of one line); each remaining
cluster becomes the total-least-squares line through its members' endpoints, cut at the extreme
projections of those endpoints.

Candidate pairs come from a KD-tree over circle centres; the criteria are evaluated vectorised over
candidate pairs in chunks, and clustering is scipy's sparse connected components, so the cost grows
about linearly with the number of segments for a map of bounded density.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Optional

import numpy as np
from pydantic import Field
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from featmap.config import Section
from featmap.fusion.base import (FusionMethod, FusionResult, fit_clusters, relabel_by_first_appearance,
                                 validate_input)
from featmap.fusion.gaps import observed_length
from featmap.geometry import (circle_overlap_area, included_angle, line_coefficients, point_segment_distance,
                              segment_lengths, segment_midpoints)

_QUERY_CHUNK = 20_000


class ProposedConfig(Section):
    """The paper's method (Section 3): three criteria, clustering, least squares."""

    delta_deg: float = Field(5.0, gt=0, le=90, description="criterion 1: max included angle beta")
    gamma: float = Field(0.3, ge=0, le=1, description="criterion 2: min feature-circle overlap S_overlap/S_min")
    eta_m: float = Field(0.5, ge=0, description="criterion 3: max relative distance d_max")
    min_support: int = Field(4, ge=1, description="drop clusters with fewer member segments")
    min_support_length_m: Optional[float] = Field(5.0, ge=0, description="also keep smaller clusters whose members cover at least this length of their line (null = the paper's count rule only)")
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


def linked_pairs(segments: np.ndarray, scan: np.ndarray, config: ProposedConfig) -> tuple[np.ndarray, np.ndarray]:
    """All pairs ``(i, j)``, ``i < j``, from different scans that meet the three criteria.

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
    delta = np.deg2rad(config.delta_deg)
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
        crit = evaluate_pairs(segments, i, j)
        ok = (crit.beta <= delta) & (crit.epsilon >= config.gamma) & (crit.d_max <= config.eta_m)
        out_i.append(i[ok])
        out_j.append(j[ok])
    if not out_i:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(out_i), np.concatenate(out_j)


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


def fuse_proposed(segments, scan, config: ProposedConfig = ProposedConfig()) -> FusionResult:
    """Fuse world-frame segments with the paper's method.

    Args:
        segments: (N, 4) ``x1, y1, x2, y2`` in the world frame, metres.
        scan: (N,) index of the scan each segment was extracted from.
        config: thresholds delta, gamma, eta, the support filter and fit weighting.
    Returns:
        FusionResult with (M, 4) fused segments (before corner optimisation; the registry applies it).
    """
    segments, scan, valid = validate_input(segments, scan)
    labels = np.full(len(segments), -1, dtype=np.int64)
    idx = np.flatnonzero(valid)
    seg, sc = segments[idx], scan[idx]
    if len(seg) == 0:
        empty = np.zeros((0, 4))
        return FusionResult(empty, np.zeros(0, np.int64), labels, empty, 0, int((~valid).sum()))
    i, j = linked_pairs(seg, sc, config)
    groups, sizes = cluster_segments(len(seg), i, j, sc, seg)
    kept = sizes >= config.min_support
    if config.min_support_length_m is not None and not kept.all():
        # Few views of a wall still make it a wall when they cover enough of one line.
        small = ~kept[groups]
        lines = fit_clusters(seg, groups, len(sizes), segment_lengths(seg))
        covered = observed_length(lines, seg, np.where(small, groups, -1))
        kept |= covered >= config.min_support_length_m
    new_id = np.full(len(sizes), -1, dtype=np.int64)
    new_id[kept] = np.arange(kept.sum())
    sub_labels = new_id[groups]
    weights = segment_lengths(seg) if config.fit_weighting == "length" else None
    fused = fit_clusters(seg, sub_labels, int(kept.sum()), weights)
    labels[idx] = sub_labels
    support = sizes[kept].astype(np.int64)
    return FusionResult(segments=fused, support=support, labels=labels, segments_before_corners=fused,
                        clusters_dropped=int((~kept).sum()), skipped_zero_length=int((~valid).sum()),
                        extras={"linked_pairs": int(len(i))})


METHOD = FusionMethod(name="proposed", title="Proposed (three criteria)", color="#d62728", linestyle="-",
                      config_type=ProposedConfig, fuse=fuse_proposed,
                      support_rule=lambda config: (config.min_support, config.min_support_length_m))
