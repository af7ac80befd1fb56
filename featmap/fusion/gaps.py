"""Where the members of a fused feature actually cover its line, and splitting it at unobserved gaps.

A fused feature is drawn between the extreme projections of its members. When a wall has a doorway,
or two walls lie in line with a passage between them, no member covers the opening, yet the fused
line spans it. :func:`split_at_gaps` cuts every fused feature where the union of its members'
projections leaves a gap longer than ``min_gap_m``; each piece keeps the feature's line.
:func:`split_at_unresolved_gaps` also cuts where only coarsely sampled views cover the opening, and
:func:`trim_coarse_ends` cuts back an end that only such views carry on towards the next facade in line.

Used by every method (see :func:`featmap.fusion.registry.fuse`). All arrays in the world frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from featmap.geometry import segment_directions, segment_lengths

END_EPS_M = 0.05
"""A feature's end less than this beyond a finer member's is that member's (metres)."""

IN_LINE_M = 0.5
STEP_M = 0.1
IN_LINE_DEG = 5.0
"""Another feature lies in line with a feature, on a line of its own (the next facade, set forward or back),
when both its ends are within IN_LINE_M of that feature's line, its near end at least STEP_M off it, and
it is within IN_LINE_DEG of parallel (:func:`trim_coarse_ends`)."""


def _points_along(segments: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(K, 2) the points at arc length ``t`` (K,) from the first endpoint of each of the (K, 4) ``segments``
    along it (the first endpoint itself where a segment has no length and ``t`` is 0)."""
    return segments[:, :2] + np.asarray(t, dtype=float)[:, None] * segment_directions(segments)


def member_intervals(fused: np.ndarray, segments: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Projections of member segments onto their feature's line.

    Args:
        fused: (M, 4) fused features; segments: (N, 4) input segments; labels: (N,) feature of each
            segment or -1.
    Returns:
        (member index (K,) into ``segments``, lo (K,), hi (K,)): the interval each member covers, as
        arc length from the feature's first endpoint (clipped to ``[0, length]``).
    """
    idx = np.flatnonzero(labels >= 0)
    f = fused[labels[idx]]
    length = segment_lengths(f)
    u = segment_directions(f)
    t1 = np.einsum("ij,ij->i", segments[idx, :2] - f[:, :2], u)
    t2 = np.einsum("ij,ij->i", segments[idx, 2:] - f[:, :2], u)
    lo = np.clip(np.minimum(t1, t2), 0.0, length)
    hi = np.clip(np.maximum(t1, t2), 0.0, length)
    return idx, lo, hi


@dataclass(frozen=True)
class _Members:
    """The members of M fused features with their sampling, grouped by feature: ``idx`` (K,) index into the
    segments, ``lo``/``hi`` (K,) the interval each covers on its feature's line (:func:`member_intervals`),
    ``feature`` (K,) and ``gap`` (K,) its feature and ``max_gap``; ``order``/``starts`` group them."""

    idx: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    feature: np.ndarray
    gap: np.ndarray
    order: np.ndarray
    starts: np.ndarray

    def of(self, k: int) -> np.ndarray:
        """Positions (into the (K,) arrays) of feature ``k``'s members."""
        return self.order[self.starts[k]:self.starts[k + 1]]


def _members(fused: np.ndarray, segments: np.ndarray, labels: np.ndarray, max_gap: np.ndarray) -> _Members:
    """The members of the (M, 4) ``fused`` features (``labels`` (N,) of the (N, 4) ``segments``, -1 for
    none) with their ``max_gap`` (N,), grouped by feature."""
    idx, lo, hi = member_intervals(fused, segments, labels)
    feature = labels[idx]
    order = np.argsort(feature, kind="stable")
    starts = np.searchsorted(feature[order], np.arange(len(fused) + 1))
    return _Members(idx, lo, hi, feature, np.asarray(max_gap, dtype=float)[idx], order, starts)


def interval_union(group: np.ndarray, lo: np.ndarray, hi: np.ndarray, n_groups: int,
                   min_gap: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Union of 1D intervals per group, joining pieces separated by at most ``min_gap``.

    Args:
        group: (K,) group of each interval in ``[0, n_groups)``; lo, hi: (K,) interval ends.
    Returns:
        (piece group (P,), piece lo (P,), piece hi (P,), piece of each input interval (K,)); pieces
        are sorted by group, then position.
    """
    if len(group) == 0:
        z = np.zeros(0)
        return np.zeros(0, np.int64), z, z, np.zeros(0, np.int64)
    order = np.lexsort((lo, group))
    g, a, b = group[order], lo[order], hi[order]
    span = max(np.abs(a).max(), np.abs(b).max()) * 2 + min_gap + 1.0
    shifted = b + g * span                                  # cumulative max restarts per group
    reach = np.maximum.accumulate(shifted) - g * span       # max hi so far within the group
    new_piece = np.ones(len(g), dtype=bool)
    new_piece[1:] = (g[1:] != g[:-1]) | (a[1:] > reach[:-1] + min_gap)
    piece_sorted = np.cumsum(new_piece) - 1
    n_pieces = int(piece_sorted[-1]) + 1
    p_lo = np.full(n_pieces, np.inf)
    p_hi = np.full(n_pieces, -np.inf)
    np.minimum.at(p_lo, piece_sorted, a)
    np.maximum.at(p_hi, piece_sorted, b)
    p_group = g[new_piece]
    piece = np.empty(len(g), dtype=np.int64)
    piece[order] = piece_sorted
    return p_group.astype(np.int64), p_lo, p_hi, piece


def observed_length(fused: np.ndarray, segments: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """(M,) length of each feature's line covered by at least one member (overlaps counted once)."""
    idx, lo, hi = member_intervals(fused, segments, labels)
    group, p_lo, p_hi, _ = interval_union(labels[idx], lo, hi, len(fused))
    return np.bincount(group, p_hi - p_lo, minlength=len(fused))


def split_at_gaps(fused: np.ndarray, segments: np.ndarray, labels: np.ndarray,
                  min_gap_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cut fused features where their members leave more than ``min_gap_m`` of the line uncovered.

    Each piece is the part of the feature's line between the extreme projections of the members in
    it (a member belongs to the piece that contains its projection); the line itself is unchanged.

    Args:
        fused: (M, 4) fused features; segments: (N, 4) input segments; labels: (N,) their feature or -1.
    Returns:
        (pieces (P, 4), new labels (N,) into the pieces, parent feature of each piece (P,)).
        Features without members are kept whole.
    """
    fused = np.asarray(fused, dtype=float).reshape(-1, 4)
    labels = np.asarray(labels, dtype=np.int64)
    idx, lo, hi = member_intervals(fused, segments, labels)
    group, p_lo, p_hi, piece = interval_union(labels[idx], lo, hi, len(fused), min_gap_m)
    orphans = np.setdiff1d(np.arange(len(fused)), group)
    length = segment_lengths(fused)
    if len(orphans):                         # keep features that have no members as they are
        group = np.concatenate([group, orphans])
        p_lo = np.concatenate([p_lo, np.zeros(len(orphans))])
        p_hi = np.concatenate([p_hi, length[orphans]])
    order = np.lexsort((p_lo, group))
    rank = np.empty(len(order), dtype=np.int64)
    rank[order] = np.arange(len(order))
    group, p_lo, p_hi = group[order], p_lo[order], p_hi[order]
    pieces = np.concatenate([_points_along(fused[group], p_lo), _points_along(fused[group], p_hi)], axis=1)
    new_labels = np.full(len(labels), -1, dtype=np.int64)
    new_labels[idx] = rank[piece]
    return pieces, new_labels, group


def split_at_unresolved_gaps(fused: np.ndarray, segments: np.ndarray, labels: np.ndarray, max_gap: np.ndarray,
                             gap_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cut fused features across gaps that the views able to see them show and the others cannot hide.

    A member whose returns lie less than ``gap_m`` apart along it (``max_gap``, the extraction's column)
    *resolves* gaps of ``gap_m``: where such members cover a feature's line on both sides of a stretch
    longer than ``gap_m`` and none of them covers the stretch, the wall has a gap there, unless a member
    that spans the whole stretch samples it finely enough to show wall in it (its ``max_gap`` is shorter
    than the stretch). A far wall seen at grazing incidence is sampled in columns of returns metres apart:
    such a view covers the passage between two buildings in line without seeing it, and is no evidence
    of wall there. The feature's ends are left as they are (nothing resolving shows where a wall ends
    beyond the views that resolve it).

    Args:
        fused: (M, 4) fused features; segments: (N, 4) input segments; labels: (N,) their feature or -1;
        max_gap: (N,) each segment's longest stretch between consecutive returns (metres, >= 0).
        gap_m: the gap length resolved (> 0).
    Returns:
        (pieces (P, 4), new labels (N,) into the pieces, parent feature of each piece (P,)), pieces in the
        order of their features, then along them; a member goes to the piece nearest its middle.
    """
    fused = np.asarray(fused, dtype=float).reshape(-1, 4)
    labels = np.asarray(labels, dtype=np.int64)
    members = _members(fused, segments, labels, max_gap)
    idx, lo, hi, feature, gap = members.idx, members.lo, members.hi, members.feature, members.gap
    n = len(fused)
    resolving = gap < gap_m
    mixed = (np.bincount(feature, resolving, n) > 0) & (np.bincount(feature, ~resolving, n) > 0)
    cuts_of = {}                              # only features with both kinds of member can be cut
    for k in np.flatnonzero(mixed):
        mine = members.of(k)
        cuts = _unresolved_gaps(lo[mine], hi[mine], gap[mine], gap_m)
        if len(cuts):
            cuts_of[int(k)] = (mine, cuts)
    count = np.ones(n, dtype=np.int64)
    for k, (_, cuts) in cuts_of.items():
        count[k] += len(cuts)
    first = np.concatenate([[0], np.cumsum(count)[:-1]]).astype(np.int64)
    parent = np.repeat(np.arange(n, dtype=np.int64), count)
    pieces = fused[parent].copy()
    new_labels = np.full(len(labels), -1, dtype=np.int64)
    new_labels[idx] = first[feature]
    length = segment_lengths(fused)
    for k, (mine, cuts) in cuts_of.items():
        bounds = np.concatenate([[0.0], cuts.ravel(), [length[k]]]).reshape(-1, 2)
        middle = 0.5 * (lo[mine] + hi[mine])
        inside = np.clip(middle[:, None], bounds[:, 0], bounds[:, 1])
        new_labels[idx[mine]] = first[k] + np.argmin(np.abs(inside - middle[:, None]), axis=1)
        ends = np.vstack([fused[k, :2], _points_along(fused[[k] * cuts.size], cuts.ravel()), fused[k, 2:]])
        pieces[first[k]:first[k] + count[k]] = np.column_stack([ends[0::2], ends[1::2]])   # own ends kept exactly
    return pieces, new_labels, parent


def _unresolved_gaps(lo: np.ndarray, hi: np.ndarray, max_gap: np.ndarray, gap_m: float) -> np.ndarray:
    """(G, 2) the stretches ``[start, end]`` of one feature's line to cut (see :func:`split_at_unresolved_gaps`);
    ``lo``, ``hi``, ``max_gap`` (K,) are its members' intervals and sampling."""
    resolving = max_gap < gap_m
    if not resolving.any() or resolving.all():
        return np.zeros((0, 2))
    a, b = lo[resolving], hi[resolving]
    o = np.argsort(a, kind="stable")
    a, b = a[o], np.maximum.accumulate(b[o])
    opens = np.flatnonzero(a[1:] > b[:-1] + gap_m)          # covered up to b[i], again from a[i + 1]
    start, end = b[opens], a[opens + 1]
    others_lo, others_hi, others_gap = lo[~resolving], hi[~resolving], max_gap[~resolving]
    shown = ((others_lo[None, :] <= start[:, None]) & (others_hi[None, :] >= end[:, None])
             & (others_gap[None, :] < (end - start)[:, None])).any(axis=1)
    return np.column_stack([start[~shown], end[~shown]])


def trim_coarse_ends(fused: np.ndarray, segments: np.ndarray, labels: np.ndarray, max_gap: np.ndarray,
                     factor: float) -> tuple[np.ndarray, int]:
    """Cut features' ends back to where a finer view starts, when the coarser views beyond it cover the
    stretch with less than ``factor`` of their longest gaps.

    A far view at grazing incidence samples a wall in columns metres apart; its last column may be the
    first of the next building in line, past the passage between them, and the fused feature, drawn
    between its members' extreme projections, then runs into the passage. At each end the cut point is
    the nearest member end (more than ``END_EPS_M`` in) whose member is at least twice as finely sampled
    (``max_gap``) as the median of the members reaching past it, and it is taken when the stretch is shorter
    than ``factor`` times that median (those views cover it with about one column, no evidence of wall)
    and another feature begins within that median past the cut point, in line but on a line of its own
    (:func:`_facades_in_line`: the next building, set forward or back, whose first column the coarse views
    joined to this wall). A longer stretch (several columns: the far part of a wall only far views see),
    one with nothing in line beyond, or one followed by a feature on this feature's own line (perhaps the
    same wall beyond a stretch nothing saw well), is kept.

    Args:
        fused: (M, 4) fused features; segments: (N, 4) input segments; labels: (N,) their feature or -1;
        max_gap: (N,) each segment's longest stretch between consecutive returns (metres, >= 0);
        factor: the bound on a cut stretch, in longest gaps (> 0).
    Returns:
        ((M, 4) the features on their own lines, ends moved inwards or kept exactly, the number of ends cut).
    """
    fused = np.array(fused, dtype=float).reshape(-1, 4)
    labels = np.asarray(labels, dtype=np.int64)
    members = _members(fused, segments, labels, max_gap)
    length = segment_lengths(fused)
    cut_at = np.zeros((len(fused), 2))                       # metres cut at the first and at the second end
    for k, side, beyond in _ends_before_a_facade_in_line(fused, length, members.feature, members.gap, factor):
        mine = members.of(k)
        g = members.gap[mine]
        if len(mine) < 2 or g.min() > 0.5 * g.max():          # no member twice as fine as others: nothing to weigh
            continue
        inward = members.lo[mine] if side == 0 else length[k] - members.hi[mine]    # each one's distance from the end
        by_depth = np.argsort(inward, kind="stable")
        x, g = inward[by_depth], g[by_depth]
        past = np.searchsorted(x, x - 1e-9, side="left")      # members reaching past each one (a prefix)
        widest = np.maximum.accumulate(g)[np.maximum(past - 1, 0)]
        # Only where the median of the members reaching past could reach both bounds: the widest of them
        # bounds it, and half of them must be twice as coarse (each member in turn, nearest the end first,
        # until one is weighed).
        maybe = np.flatnonzero((x > END_EPS_M) & (past > 0) & (2 * g <= widest) & (x < factor * widest))
        for i in maybe[_half_twice_as_coarse(g, past, maybe)]:
            coarse = float(np.median(g[:past[i]]))
            if 2 * g[i] <= coarse and x[i] < factor * coarse:
                if np.any((beyond > -x[i]) & (beyond <= coarse)):    # it begins past the cut point, within a column
                    cut_at[k, side] = x[i]
                break
    moved = cut_at.any(axis=1)                               # (the others keep their ends exactly)
    if moved.any():
        kept = fused[moved]
        fused[moved] = np.column_stack([_points_along(kept, cut_at[moved, 0]),
                                        _points_along(kept, length[moved] - cut_at[moved, 1])])
    return fused, int(np.count_nonzero(cut_at))


def _half_twice_as_coarse(g: np.ndarray, past: np.ndarray, which: np.ndarray, chunk: int = 256) -> np.ndarray:
    """(len(which),) for members ``which`` (indices into ``g`` (K,), the gaps in order of depth): whether at
    least half of the ``past[i]`` members before member ``i`` have a gap at least twice its own (the median
    of theirs can then be; a bound, not the median). Chunked: at most ``chunk`` x K cells at a time."""
    out = np.zeros(len(which), dtype=bool)
    rank = np.arange(len(g))
    for s in range(0, len(which), chunk):
        w = which[s:s + chunk]
        coarser = ((g[None, :] >= 2 * g[w, None]) & (rank[None, :] < past[w, None])).sum(axis=1)
        out[s:s + chunk] = 2 * coarser >= past[w]
    return out


def _ends_before_a_facade_in_line(fused: np.ndarray, length: np.ndarray, feature: np.ndarray, gap: np.ndarray,
                                  factor: float) -> list[tuple[int, int, np.ndarray]]:
    """The ends :func:`trim_coarse_ends` may cut: (feature, side (0: first end, 1: second), the distances
    outwards from that end at which the facades in line beyond it begin (:func:`_facades_in_line`)), for
    the ends of the (M, 4) ``fused`` features where such a facade begins within ``factor`` times the widest
    ``gap`` (K,) of the members of ``feature`` (K,) (no cut reaches farther)."""
    n = len(fused)
    if n < 2 or not len(feature):
        return []
    widest = np.zeros(n)
    np.maximum.at(widest, feature, gap)
    ends = fused.reshape(-1, 2)
    window = np.repeat(max(factor, 1.0) * widest, 2)
    near = cKDTree(ends).query_ball_point(ends, window + IN_LINE_M)
    out = []
    for e in np.flatnonzero(window > 0):
        k, side = divmod(int(e), 2)
        others = np.unique(np.asarray(near[e], dtype=np.int64) // 2)
        others = others[others != k]
        if len(others) == 0 or length[k] <= 0:
            continue
        beyond = _facades_in_line(fused, length, k, side, others)
        beyond = beyond[(beyond > -window[e]) & (beyond <= window[e])]
        if len(beyond):
            out.append((k, side, beyond))
    return out


def _facades_in_line(fused: np.ndarray, length: np.ndarray, k: int, side: int, others: np.ndarray) -> np.ndarray:
    """Where the ``others`` of the (M, 4) ``fused`` features that lie in line with feature ``k`` but on a line of
    their own begin: the distance of each one's near end outwards from ``k``'s ``side`` end (0: first, 1:
    second), for those within ``IN_LINE_DEG`` of parallel with both ends within ``IN_LINE_M`` of ``k``'s line and
    the near end at least ``STEP_M`` off it (the next facade, set forward or back: a feature on ``k``'s own
    line may be the same wall beyond a stretch nothing saw well). (J,) metres, J <= len(others)."""
    a, b = fused[k, :2], fused[k, 2:]
    u = (b - a) / length[k]
    origin, out = (a, -u) if side == 0 else (b, u)
    normal = np.array([-u[1], u[0]])
    p, q = fused[others, :2], fused[others, 2:]
    d = q - p
    norm = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)
    parallel = np.abs(d @ u) / norm >= np.cos(np.deg2rad(IN_LINE_DEG))
    off_p, off_q = np.abs((p - origin) @ normal), np.abs((q - origin) @ normal)
    along_p, along_q = (p - origin) @ out, (q - origin) @ out
    near_off = np.where(along_p <= along_q, off_p, off_q)
    in_line = parallel & (np.maximum(off_p, off_q) <= IN_LINE_M) & (near_off >= STEP_M)
    return np.minimum(along_p, along_q)[in_line]
