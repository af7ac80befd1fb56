"""Shared clean-up after every fusion method: each feature is one straight, observed wall.

Any clustering can put segments of two surfaces into one cluster (a wall and a cabinet in front of
it, the two walls of a corridor under mean shift's 3 m bandwidth, the facets of a curved wall chained
by small angle steps), and can leave one wall in several clusters (views whose feature circles or
centres are too far apart to link). Both show on real maps as lines that leave their points or as
parallel duplicates. :func:`refine` repairs them from the member segments alone, in three steps:

1. **split**: a cluster whose member endpoints lie farther than ``max_offset_m`` from the cluster's
   fitted line is cut in two, recursively, where two lines explain its members best: across (the
   members sorted by their offset from the line: two parallel surfaces) or along (sorted by their
   position: a bend or a curve, which thus becomes several chords).
2. **merge**: two clusters whose lines are within ``merge_angle_deg``, that overlap or leave at most
   ``merge_gap_m`` between them along the line, and whose union still has every member endpoint
   within ``max_offset_m`` of one fitted line become one (closest pairs first). Segments dropped by a
   support filter join a feature when they lie on it (``absorb_dropped``): within ``max_offset_m`` of
   the line of the heavier side, as a short view's own direction is too poorly known to test a long
   feature against. Two kept features merge when each lies within ``max_offset_m`` of the other's
   line, or the lighter within ``kept_heavier_ratio * max_offset_m`` of the heavier's (a short
   duplicate beside a long wall, slightly askew).
3. **gaps**: every feature is cut where its members leave more than ``split_gap_m`` of its line
   unobserved (doorways, passages between walls in line), and, with the segments' ``max_gap`` column,
   where the members that resolve gaps of ``resolved_gap_m`` leave one that the others are too coarsely
   sampled to close; with ``coarse_end_factor`` a feature's end that only coarse views
   carry on past its finely sampled members towards the next facade in line is cut back; see
   :mod:`featmap.fusion.gaps`.

A cluster that changes is refitted as the length-weighted total-least-squares line through its
members' endpoints, cut at their extreme projections (the proposed method's fit); unchanged clusters
keep the line their method gave them.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from pydantic import Field

from featmap.config import Section
from featmap.fusion.base import (FusionResult, SupportRule, SupportViews, fit_clusters, relabel_by_first_appearance,
                                 validate_input)
from featmap.fusion.close_pairs import close_owner_pairs
from featmap.fusion.gaps import observed_length, split_at_gaps, split_at_unresolved_gaps, trim_coarse_ends
from featmap.geometry import segment_lengths


class RefineConfig(Section):
    """Shared clean-up after every method, before corners: split and merge clusters so that each feature is one straight wall, cut features at unobserved gaps (featmap.fusion.refine)."""

    max_offset_m: float = Field(0.15, ge=0, description="split clusters whose member endpoints lie farther than this from their line; merge clusters that one line explains within it (0 = off)")
    merge_angle_deg: float = Field(5.0, ge=0, le=90, description="merge only features within this angle of parallel")
    merge_gap_m: float = Field(1.0, ge=0, description="merge only features that overlap or leave at most this gap along their line")
    absorb_dropped: bool = Field(True, description="segments dropped by a support filter join a feature they lie on")
    kept_heavier_ratio: float = Field(0.5, ge=0, le=1, description="two kept features also merge when the lighter lies within this fraction of max_offset_m of the heavier's line (0 = only when each lies near the other's)")
    split_gap_m: float = Field(0.0, ge=0, description="cut features where no member covers this much of their line, e.g. doorways (0 = off)")
    resolved_gap_m: float = Field(3.0, ge=0, description="cut features where the members whose returns lie less than this apart (the segments' max_gap column) leave this much of their line between them and no member that spans it is sampled finely enough to show it (a far view at grazing incidence covers the passage between two buildings in line without seeing it; 0 = off)")
    coarse_end_factor: float = Field(2.0, ge=0, description="after the cut at unresolved gaps, cut a feature's end back to where a member at least twice as finely sampled (max_gap) starts, when the members reaching past it cover that stretch with fewer than this many of their longest gaps (median) and another feature begins just beyond, in line but on a line of its own (a facade set 0.1-0.5 m forward or back): the last column of a far view at grazing incidence may be the next building's in line, past the passage (0 = off; needs resolved_gap_m > 0; chosen on the tuning worlds, docs/results.md)")


def _moments(points: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(K, 6) per-point weighted moments ``w, wx, wy, wxx, wxy, wyy`` (for cumulative TLS costs)."""
    x, y = points[:, 0], points[:, 1]
    return np.stack([weights, weights * x, weights * y, weights * x * x, weights * x * y, weights * y * y], axis=1)


def _tls_cost(m: np.ndarray) -> np.ndarray:
    """Weighted sum of squared perpendicular distances to the best line, from (..., 6) moments."""
    w = np.maximum(m[..., 0], 1e-300)
    mx, my = m[..., 1] / w, m[..., 2] / w
    sxx = m[..., 3] - w * mx * mx
    sxy = m[..., 4] - w * mx * my
    syy = m[..., 5] - w * my * my
    half_trace = 0.5 * (sxx + syy)
    root = np.sqrt(np.maximum(0.25 * (sxx - syy) ** 2 + sxy ** 2, 0.0))
    return np.maximum(half_trace - root, 0.0)


def _fit_line(ends: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted TLS line through (K, 2) points: (centroid (2,), unit direction (2,))."""
    w = weights / weights.sum()
    c = w @ ends
    d = ends - c
    sxx, syy, sxy = (w * d[:, 0] ** 2).sum(), (w * d[:, 1] ** 2).sum(), (w * d[:, 0] * d[:, 1]).sum()
    theta = 0.5 * np.arctan2(2 * sxy, sxx - syy)
    return c, np.array([np.cos(theta), np.sin(theta)])


def _max_offset(seg: np.ndarray, weights: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Largest endpoint distance of (K, 4) members to their weighted TLS line, and that line."""
    ends = np.concatenate([seg[:, :2], seg[:, 2:]])
    c, u = _fit_line(ends, np.concatenate([weights, weights]))
    off = np.abs((ends - c) @ np.array([-u[1], u[0]]))
    return float(off.max()), c, u


def _best_split(seg: np.ndarray, weights: np.ndarray, c: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, bool]:
    """Boolean mask of one side of the best two-line split of (K >= 2, 4) members, and whether the
    cut runs along the line (a bend: True) or across it (two parallel surfaces: False).

    Candidates: every cut of the members sorted by their midpoint's position along the line and by
    its offset across it; the cut with the smallest summed TLS cost of the two sides wins.
    """
    k = len(seg)
    mid = 0.5 * (seg[:, :2] + seg[:, 2:])
    normal = np.array([-u[1], u[0]])
    member_m = _moments(seg[:, :2], weights) + _moments(seg[:, 2:], weights)
    total = member_m.sum(axis=0)
    best_cost, best_mask, along = np.inf, None, True
    for is_along, key in ((True, (mid - c) @ u), (False, (mid - c) @ normal)):
        order = np.argsort(key, kind="stable")
        prefix = np.cumsum(member_m[order], axis=0)[:-1]          # first j+1 members, j = 0..k-2
        cost = _tls_cost(prefix) + _tls_cost(total - prefix)
        j = int(np.argmin(cost))
        if best_mask is None or cost[j] < best_cost:
            best_cost, along = cost[j], is_along
            best_mask = np.zeros(k, dtype=bool)
            best_mask[order[: j + 1]] = True
    return best_mask, along


def _angle_between(seg_a: np.ndarray, w_a: np.ndarray, seg_b: np.ndarray, w_b: np.ndarray) -> float:
    """Angle (radians, in [0, pi/2]) between the TLS lines of two member sets."""
    _, u = _fit_line(np.concatenate([seg_a[:, :2], seg_a[:, 2:]]), np.concatenate([w_a, w_a]))
    _, v = _fit_line(np.concatenate([seg_b[:, :2], seg_b[:, 2:]]), np.concatenate([w_b, w_b]))
    return float(np.arccos(np.clip(abs(u @ v), 0.0, 1.0)))


def _mean_offset(seg_a: np.ndarray, w_a: np.ndarray, seg_b: np.ndarray, w_b: np.ndarray) -> float:
    """Weighted mean distance (metres) of the endpoints of members ``seg_b`` (K, 4) to the weighted TLS
    line of members ``seg_a`` (J, 4)."""
    c, u = _fit_line(np.concatenate([seg_a[:, :2], seg_a[:, 2:]]), np.concatenate([w_a, w_a]))
    ends = np.concatenate([seg_b[:, :2], seg_b[:, 2:]])
    w = np.concatenate([w_b, w_b])
    return float(w @ np.abs((ends - c) @ np.array([-u[1], u[0]])) / w.sum())


def separation(seg_a: np.ndarray, w_a: np.ndarray, seg_b: np.ndarray, w_b: np.ndarray) -> float:
    """How far apart two member sets lie, in metres: the larger of the weighted mean distances of
    one set's endpoints to the other set's TLS line (two views of one wall: about the noise; two
    surfaces or the two arms of a bend: more)."""
    return max(_mean_offset(seg_a, w_a, seg_b, w_b), _mean_offset(seg_b, w_b, seg_a, w_a))


def offset_from_heavier(seg_a: np.ndarray, w_a: np.ndarray, seg_b: np.ndarray, w_b: np.ndarray) -> float:
    """How far the lighter of two member sets (smaller summed weight) lies from the heavier one's TLS
    line, in metres: the weighted mean distance of its endpoints to that line (:func:`separation` for
    equal weights).

    This is the test for joining a short piece to a long feature: the short piece's own line is poorly
    determined, and extended along a long feature a small error in its direction reaches the far
    members (a 3.5 m view 3 cm from a 19 m wall: 3.4 cm from the wall's line, but the wall's far
    endpoints 0.16 m from the view's line), so only the better-determined line is trusted.
    """
    heavy_a, heavy_b = float(w_a.sum()), float(w_b.sum())
    if heavy_a > heavy_b:
        return _mean_offset(seg_a, w_a, seg_b, w_b)
    if heavy_b > heavy_a:
        return _mean_offset(seg_b, w_b, seg_a, w_a)
    return separation(seg_a, w_a, seg_b, w_b)


def split_inconsistent(segments: np.ndarray, labels: np.ndarray, weights: np.ndarray, max_offset: float,
                       max_angle_deg: float = 5.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Split clusters until each one's member endpoints lie within ``max_offset`` of its TLS line.

    A cut is made only where the two sides are two lines: they lie farther apart than
    ``max_offset`` (:func:`separation`), or, for a cut along the line, their directions differ by more
    than ``max_angle_deg`` (a bend). Otherwise the spread is noise and the cluster stays whole.

    Args:
        segments: (N, 4); labels: (N,) cluster or -1; weights: (N,) member weights (lengths).
    Returns:
        (new labels (N,), parent (C,) old cluster of each new cluster, changed (C,) True if it came
        out of a split, bends (B, 2): for every cut along a line, the member on each side that lies
        closest to the cut, so the two pieces can be joined where they meet).
    """
    bends: list[tuple[int, int]] = []
    max_angle = np.deg2rad(max_angle_deg)
    new = np.full(len(labels), -1, dtype=np.int64)
    changed: list[bool] = []
    parent: list[int] = []
    order = np.argsort(labels, kind="stable")
    sorted_labels = labels[order]
    starts = np.flatnonzero(np.r_[True, sorted_labels[1:] != sorted_labels[:-1]])
    bounds = np.r_[starts, len(order)]
    for a, b in zip(bounds[:-1], bounds[1:]):
        if sorted_labels[a] < 0:
            continue
        stack = [order[a:b]]
        parts = []
        while stack:
            members = stack.pop()
            if len(members) == 1:
                parts.append(members)
                continue
            offset, c, u = _max_offset(segments[members], weights[members])
            if offset <= max_offset:
                parts.append(members)
                continue
            mask, along = _best_split(segments[members], weights[members], c, u)
            a_, b_ = members[mask], members[~mask]
            bend = along and _angle_between(segments[a_], weights[a_], segments[b_], weights[b_]) > max_angle
            if not bend and separation(segments[a_], weights[a_], segments[b_], weights[b_]) <= max_offset:
                parts.append(members)             # the spread is noise, not two lines
                continue
            if along:
                t_a = 0.5 * (segments[a_, :2] + segments[a_, 2:]) @ u
                t_b = 0.5 * (segments[b_, :2] + segments[b_, 2:]) @ u
                # the mask takes the first members in the sorted order, so a_ lies before b_ along u
                bends.append((int(a_[np.argmax(t_a)]), int(b_[np.argmin(t_b)])))
            stack.append(b_)
            stack.append(a_)
        for part in parts:
            new[part] = len(changed)
            changed.append(len(parts) > 1)
            parent.append(int(sorted_labels[a]))
    return (new, np.array(parent, dtype=np.int64), np.array(changed, dtype=bool),
            np.array(bends, dtype=np.int64).reshape(-1, 2))


class _Clusters:
    """Union-find over clusters with their member lists (for greedy merging)."""

    def __init__(self, labels: np.ndarray, n: int):
        self.parent = np.arange(n)
        order = np.argsort(labels, kind="stable")
        bounds = np.searchsorted(labels[order], np.arange(n + 1))
        self.members = [order[bounds[c]:bounds[c + 1]].tolist() for c in range(n)]

    def find(self, a: int) -> int:
        while self.parent[a] != a:
            self.parent[a] = self.parent[self.parent[a]]
            a = self.parent[a]
        return a


def _explained_together(seg_a: np.ndarray, w_a: np.ndarray, seg_b: np.ndarray, w_b: np.ndarray,
                        both_kept: bool, config: RefineConfig) -> bool:
    """Whether two member sets (K, 4) and (J, 4) lie on one line closely enough to merge (see
    :func:`merge_consistent`)."""
    if not both_kept:
        return offset_from_heavier(seg_a, w_a, seg_b, w_b) <= config.max_offset_m
    if separation(seg_a, w_a, seg_b, w_b) <= config.max_offset_m:
        return True
    return (config.kept_heavier_ratio > 0
            and offset_from_heavier(seg_a, w_a, seg_b, w_b) <= config.kept_heavier_ratio * config.max_offset_m)


def merge_consistent(segments: np.ndarray, labels: np.ndarray, fused: np.ndarray, weights: np.ndarray,
                     kept: np.ndarray, config: RefineConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Greedily merge clusters that one line explains within ``max_offset_m``: two kept clusters when
    each lies within it of the other's line (:func:`separation`) or the lighter lies within
    ``kept_heavier_ratio * max_offset_m`` of the heavier's line, a dropped cluster and a kept one when
    the lighter lies within ``max_offset_m`` of the heavier's line (:func:`offset_from_heavier`).

    Args:
        segments: (N, 4); labels: (N,) cluster in ``[0, C)`` (every segment has one); fused: (C, 4)
        each cluster's current line; weights: (N,); kept: (C,) False for clusters a support filter
        dropped (they may join a kept cluster, and stay dropped otherwise).
    Returns:
        (merged cluster of each cluster (C,) in ``[0, C')``, kept (C',), merged (C',): True where
        clusters were joined).
    """
    n = len(fused)
    unchanged = (np.arange(n), kept.copy(), np.zeros(n, dtype=bool))
    if n < 2:
        return unchanged
    lengths = segment_lengths(fused)
    step = 0.25
    counts = np.maximum(np.ceil(lengths / step).astype(np.int64), 1) + 1
    owner = np.repeat(np.arange(n), counts)
    start = np.cumsum(counts) - counts
    t = (np.arange(counts.sum()) - start[owner]) / (counts[owner] - 1)
    samples = fused[owner, :2] + t[:, None] * (fused[owner, 2:] - fused[owner, :2])
    reach = max(config.merge_gap_m, config.max_offset_m) + 0.5 * step
    ab = np.stack(np.divmod(close_owner_pairs(samples, owner, reach, n), n), axis=1)     # (lower, higher), sorted
    if len(ab) == 0:
        return unchanged
    d = fused[:, 2:] - fused[:, :2]
    theta = np.arctan2(d[:, 1], d[:, 0])
    diff = np.abs(np.mod(theta[ab[:, 0]] - theta[ab[:, 1]] + np.pi / 2, np.pi) - np.pi / 2)
    ab = ab[diff <= np.deg2rad(config.merge_angle_deg)]
    ab = ab[kept[ab[:, 0]] | kept[ab[:, 1]]]
    # Closest pairs first: the larger endpoint distance of the shorter feature to the longer's line.
    short = np.where(lengths[ab[:, 0]] <= lengths[ab[:, 1]], ab[:, 0], ab[:, 1])
    long_ = np.where(short == ab[:, 0], ab[:, 1], ab[:, 0])
    u = d[long_] / np.maximum(lengths[long_], 1e-12)[:, None]
    normal = np.stack([-u[:, 1], u[:, 0]], axis=1)
    lateral = np.maximum(np.abs(np.einsum("ij,ij->i", fused[short, :2] - fused[long_, :2], normal)),
                         np.abs(np.einsum("ij,ij->i", fused[short, 2:] - fused[long_, :2], normal)))
    ab = ab[np.lexsort((ab[:, 1], ab[:, 0], lateral))]

    clusters = _Clusters(labels, n)
    kept_root = kept.copy()
    merged = np.zeros(n, dtype=bool)
    for i, j in ab:
        ri, rj = clusters.find(i), clusters.find(j)
        if ri == rj or not (kept_root[ri] or kept_root[rj]):
            continue
        mi, mj = np.array(clusters.members[ri]), np.array(clusters.members[rj])
        if not _explained_together(segments[mi], weights[mi], segments[mj], weights[mj],
                                   both_kept=bool(kept_root[ri] and kept_root[rj]), config=config):
            continue
        members = np.concatenate([mi, mj])
        c, u = _fit_line(np.concatenate([segments[members, :2], segments[members, 2:]]),
                         np.concatenate([weights[members], weights[members]]))
        # Along the merged line the two clusters must overlap or leave at most merge_gap_m between them.
        gap = _gap_along(segments[mi], segments[mj], c, u)
        if gap > config.merge_gap_m:
            continue
        clusters.parent[rj] = ri
        clusters.members[ri] = members.tolist()
        clusters.members[rj] = []
        kept_root[ri] = kept_root[ri] or kept_root[rj]
        merged[ri] = True
    roots = np.array([clusters.find(c) for c in range(n)])
    uniq, inverse = np.unique(roots, return_inverse=True)
    return inverse, kept_root[uniq], merged[uniq]


def _gap_along(seg_a: np.ndarray, seg_b: np.ndarray, c: np.ndarray, u: np.ndarray) -> float:
    """Gap (> 0) or overlap (<= 0) between two member sets projected on the line ``c + t u``."""
    ta = np.concatenate([(seg_a[:, :2] - c) @ u, (seg_a[:, 2:] - c) @ u])
    tb = np.concatenate([(seg_b[:, :2] - c) @ u, (seg_b[:, 2:] - c) @ u])
    return float(max(ta.min(), tb.min()) - min(ta.max(), tb.max()))


def join_bends(fused: np.ndarray, first: np.ndarray, second: np.ndarray) -> tuple[np.ndarray, int]:
    """Join the pieces of a bend (or curve) where their lines cross.

    For each pair (``first[k]``, ``second[k]``) of features cut from one cluster along its line, the
    end of each that faces the other moves to the intersection of the two lines, if that moves it
    by at most half of the shorter piece (no overlapping chords on a curved wall, no gap at a bend).
    Returns (features (M, 4), number of bends joined).
    """
    out = fused.copy()
    moved = np.zeros(2 * len(fused), dtype=bool)
    joined = 0
    for fa, fb in zip(first, second):
        if fa < 0 or fb < 0 or fa == fb:
            continue
        a, b = out[fa].reshape(2, 2), out[fb].reshape(2, 2)
        da, db = a[1] - a[0], b[1] - b[0]
        cross = da[0] * db[1] - da[1] * db[0]
        if abs(cross) < 1e-12:
            continue
        w = b[0] - a[0]
        x = a[0] + (w[0] * db[1] - w[1] * db[0]) / cross * da
        mid_a, mid_b = a.mean(axis=0), b.mean(axis=0)
        ea = int(np.argmin(np.hypot(*(a - mid_b).T)))      # the end of a facing b
        eb = int(np.argmin(np.hypot(*(b - mid_a).T)))
        limit = 0.5 * min(np.hypot(*da), np.hypot(*db))
        if moved[2 * fa + ea] or moved[2 * fb + eb] or max(np.hypot(*(x - a[ea])), np.hypot(*(x - b[eb]))) > limit:
            continue
        out[fa, 2 * ea:2 * ea + 2] = x
        out[fb, 2 * eb:2 * eb + 2] = x
        moved[2 * fa + ea] = moved[2 * fb + eb] = True
        joined += 1
    return out, joined


def refine(result: FusionResult, segments, scan, config: RefineConfig,
           rule: SupportRule = SupportRule(), views: SupportViews = SupportViews(),
           max_gap: np.ndarray | None = None) -> FusionResult:
    """Apply the enabled refinement steps to one method's result (see the module docstring).

    Args:
        result: the method's FusionResult (its labels tie input segments to features).
        segments: (N, 4) the method's world-frame input; scan: (N,) scan of each segment.
        config: ``max_offset_m = 0`` turns split and merge off; ``split_gap_m = 0`` the gap split;
            ``resolved_gap_m = 0`` (or ``max_gap`` None) the split at unresolved gaps.
        rule: the method's support rule, applied again to the refined features (a piece split off a
            cluster must earn its place like any cluster); views: that rule's clean and coarse views of
            the N (``SupportRule.views``; coarse views cover no length).
        max_gap: (N,) each segment's longest stretch between consecutive returns (metres; the
            extraction's ``max_gap`` column), or None.
    Returns:
        A FusionResult whose segments, support, labels and segments_before_corners describe the
        refined features (corner optimisation still to come); ``extras["refine"]`` counts the changes.
    """
    unresolved = config.resolved_gap_m > 0 and max_gap is not None
    if config.max_offset_m <= 0 and config.split_gap_m <= 0 and not unresolved:
        return result
    segments, scan, valid = validate_input(segments, scan)
    weights = segment_lengths(segments)
    labels = result.labels.copy()
    fused = result.segments_before_corners
    stats = {"split": 0, "merged": 0, "absorbed": 0, "gap_pieces": 0, "unresolved_gap_pieces": 0, "bends_joined": 0}
    bends = np.zeros((0, 2), np.int64)

    if config.max_offset_m > 0 and len(fused):
        before = len(fused)
        labels, parent, changed, bends = split_inconsistent(segments, labels, weights, config.max_offset_m,
                                                            config.merge_angle_deg)
        stats["split"] = int(len(parent) - before)
        fitted = fit_clusters(segments, labels, len(parent), weights)
        fused = np.where(changed[:, None], fitted, fused[parent]) if len(parent) else np.zeros((0, 4))
        # Merge; segments without a feature (support filter) take part as dropped singletons.
        dropped = np.flatnonzero(valid & (labels < 0)) if config.absorb_dropped else np.zeros(0, np.int64)
        labels[dropped] = len(fused) + np.arange(len(dropped))
        candidates = np.concatenate([fused, segments[dropped]])
        kept = np.r_[np.ones(len(fused), dtype=bool), np.zeros(len(dropped), dtype=bool)]
        use = np.flatnonzero(labels >= 0)
        cluster_map, kept, merged = merge_consistent(segments[use], labels[use], candidates, weights[use],
                                                     kept, config)
        remap = np.full(len(kept), -1, dtype=np.int64)
        remap[kept] = np.arange(kept.sum())
        labels[use] = remap[cluster_map[labels[use]]]
        source = np.zeros(len(kept), dtype=np.int64)
        source[cluster_map] = np.arange(len(cluster_map))      # the only source of an unmerged cluster
        stats["absorbed"] = int(np.count_nonzero(labels[dropped] >= 0))
        stats["merged"] = int(len(fused) - kept.sum())
        n_kept = int(kept.sum())
        fitted = fit_clusters(segments, labels, n_kept, weights)
        fused = np.where(merged[kept][:, None], fitted, candidates[source[kept]]) if n_kept else np.zeros((0, 4))

    if config.split_gap_m > 0 and len(fused):
        before = len(fused)
        fused, labels, _ = split_at_gaps(fused, segments, labels, config.split_gap_m)
        stats["gap_pieces"] = int(len(fused) - before)

    if unresolved and len(fused):
        before = len(fused)
        fused, labels, _ = split_at_unresolved_gaps(fused, segments, labels, max_gap, config.resolved_gap_m)
        stats["unresolved_gap_pieces"] = int(len(fused) - before)
        if config.coarse_end_factor > 0:
            fused, stats["coarse_ends_cut"] = trim_coarse_ends(fused, segments, labels, max_gap,
                                                               config.coarse_end_factor)

    if len(bends) and len(fused):
        fused, stats["bends_joined"] = join_bends(fused, labels[bends[:, 0]], labels[bends[:, 1]])

    if rule.min_support > 1 and len(fused):
        members = np.bincount(labels[labels >= 0], minlength=len(fused))
        covering = views.covering(labels)
        keep = rule.keep(members, lambda: observed_length(fused, segments, covering),
                         views.clean_members(labels, len(fused)), views.seen(lambda: fused, labels, scan))
        stats["dropped"] = int((~keep).sum())
        remap = np.full(len(fused), -1, dtype=np.int64)
        remap[keep] = np.arange(keep.sum())
        labels = np.where(labels >= 0, remap[np.maximum(labels, 0)], -1)
        fused = fused[keep]

    # Canonical order and support of the refined features.
    idx = np.flatnonzero(labels >= 0)
    final = np.full(len(labels), -1, dtype=np.int64)
    if len(idx):
        _, groups = np.unique(labels[idx], return_inverse=True)
        present = np.unique(labels[idx])
        order_labels, sizes = relabel_by_first_appearance(groups, scan[idx], segments[idx])
        final[idx] = order_labels
        out = np.zeros((len(sizes), 4))
        out[order_labels] = fused[present[groups]]
        fused = out
        support = sizes.astype(np.int64)
    else:
        fused = np.zeros((0, 4))
        support = np.zeros(0, np.int64)
    extras = dict(result.extras)
    extras["refine"] = stats
    return replace(result, segments=fused, segments_before_corners=fused, support=support, labels=final,
                   extras=extras)
