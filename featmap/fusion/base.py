"""What every fusion method returns, and the cluster fit they share.

All arrays are in the local metric world frame (metres).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Optional

import numpy as np
from scipy.spatial import cKDTree

from featmap.config import Section
from featmap.fusion.visibility import seen_share
from featmap.geometry import as_segments, segment_lengths

MIN_SEGMENT_LENGTH_M = 1e-6
"""Segments shorter than this have no direction nor feature circle; every method skips them."""


@dataclass(frozen=True)
class FusionResult:
    """Output of one fusion method.

    Attributes:
        segments: (M, 4) fused features ``x1, y1, x2, y2`` after corner optimisation.
        support: (M,) number of input segments merged into each fused feature.
        labels: (N,) index of the fused feature each input segment went into, -1 if dropped.
        segments_before_corners: (M, 4) the same features before corner optimisation.
        clusters_dropped: clusters (groups of linked segments, singletons included) removed
            because they had fewer than ``min_support`` members (0 for methods without that rule).
        skipped_zero_length: input segments skipped because they had no length.
    """

    segments: np.ndarray
    support: np.ndarray
    labels: np.ndarray
    segments_before_corners: np.ndarray
    clusters_dropped: int = 0
    skipped_zero_length: int = 0
    extras: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.segments)


@dataclass(frozen=True)
class FusionMethod:
    """A fusion method as the registry knows it (:mod:`featmap.fusion.registry`).

    Attributes:
        name: registry key, also the config section ``fusion.<name>`` and the file suffix ``fused_<name>``.
        title: human-readable name for tables and figure legends.
        color, linestyle: how figures and maps draw it.
        config_type: the method's config section (a :class:`featmap.config.Section`).
        fuse: ``fuse(segments (N, 4) world frame, scan (N,), config, progress=None) -> FusionResult`` (before
            corner optimisation); ``progress(done, total)`` is called now and then by long fusions.
        support_rule: ``config -> SupportRule`` for a method that drops small clusters (refinement
            applies the same rule to the features it makes); None: every cluster is kept. Such a method's
            ``fuse`` also takes ``views=``, a :class:`SupportViews` (the rule's clean and coarse views).
        prepare: imports the method's heavy libraries and loads its compiled code, so that callers can keep
            that one-off cost out of fusion timings.
    """

    name: str
    title: str
    color: str
    linestyle: str
    config_type: type[Section]
    fuse: Callable[[np.ndarray, np.ndarray, Any], "FusionResult"]
    support_rule: Callable[[Any], "SupportRule"] | None = None
    prepare: Callable[[], None] = lambda: None


def segment_column(name: str, values, n_segments: int) -> np.ndarray | None:
    """One per-segment column (``rms``, ``max_gap``, ...) as a float array (N,), or None when ``values`` is
    None; a ValueError naming the column when it does not hold one entry per segment."""
    if values is None:
        return None
    column = np.asarray(values, dtype=float).reshape(-1)
    if len(column) != n_segments:
        raise ValueError(f"{name} has {len(column)} entries for {n_segments} segments")
    return column


@dataclass(frozen=True)
class SupportViews:
    """What a support rule reads per input segment beyond its geometry (:meth:`SupportRule.views`).

    Attributes:
        clean: (N,) bool, the clean views (:meth:`SupportRule.clean_views`: one keeps its cluster), or None.
        coarse: (N,) bool, the coarse views (:meth:`SupportRule.coarse_views`: members that cover no
            length), or None.
        sensor_xy: (N, 2) where the sensor stood when each segment's scan was taken (world frame, metres),
            for the visibility clause (:func:`featmap.fusion.visibility.seen_share`), or None.
    """

    clean: np.ndarray | None = None
    coarse: np.ndarray | None = None
    sensor_xy: np.ndarray | None = None

    def subset(self, idx: np.ndarray) -> "SupportViews":
        """The views of the segments ``idx`` (K,) (indices into the N)."""
        return SupportViews(*(None if part is None else part[idx]
                              for part in (self.clean, self.coarse, self.sensor_xy)))

    def moved(self, origin: np.ndarray) -> "SupportViews":
        """The same views with the sensor positions in a frame whose origin is ``origin`` (2,) (the working
        frame the methods fuse in, :func:`featmap.fusion.registry.working_origin`)."""
        if self.sensor_xy is None:
            return self
        return SupportViews(self.clean, self.coarse, self.sensor_xy - np.asarray(origin, dtype=float))

    def seen(self, lines: Callable[[], np.ndarray], labels: np.ndarray, scan: np.ndarray
             ) -> Callable[[np.ndarray, float | None], np.ndarray] | None:
        """For :meth:`SupportRule.keep`: given the (C,) clusters kept so far and the share that keeps one
        (or None), the share of the scans that could see each other cluster's line that saw it
        (:func:`~featmap.fusion.visibility.seen_share`, the kept lines hiding what lies behind them; a share
        below the one that keeps is only known to be below it). ``lines()`` gives the (C, 4) fitted lines,
        ``labels`` (N,) each segment's cluster, ``scan`` (N,) its scan. None without sensor positions."""
        if self.sensor_xy is None:
            return None

        def share(kept: np.ndarray, at_least: float | None = None) -> np.ndarray:
            fitted = lines()
            return seen_share(fitted, labels, scan, self.sensor_xy, ~kept, fitted[kept], at_least)
        return share

    def clean_members(self, labels: np.ndarray, n_clusters: int) -> np.ndarray | None:
        """(C,) how many clean views each of ``n_clusters`` clusters has, from the (N,) cluster label of
        each segment (-1: in none); None without clean views."""
        if self.clean is None:
            return None
        member = labels >= 0
        return np.bincount(labels[member], weights=self.clean[member], minlength=n_clusters)

    def covering(self, labels: np.ndarray) -> np.ndarray:
        """(N,) ``labels`` with the coarse views' set to -1: the members whose length counts."""
        return labels if self.coarse is None else np.where(self.coarse, -1, labels)


@dataclass(frozen=True)
class SupportRule:
    """Which clusters a support filter keeps: those with at least ``min_support`` members, and, when
    ``min_length_m`` is set, smaller ones whose members cover at least that length of their line
    (a single member only when it covers ``min_single_length_m``, if set: one view is weaker
    evidence than two that agree), and, when ``clean_rms_ratio`` is set, smaller ones with a clean
    view among their members (:meth:`clean_views`: a segment much thinner than the input's typical
    wall is a plane seen well, not clutter). With ``coarse_gap_m`` set, a coarse view (:meth:`coarse_views`:
    returns that far apart along it) counts as a member but covers no length: a line drawn between a
    few columns metres apart is no evidence that a wall spans them. With ``visible_share`` set, a smaller
    cluster is also kept when at least that share of the scans that could see its line saw it
    (:mod:`featmap.fusion.visibility`: a wall seen through a gap by the only scans that could see it, not a
    crown extracted by two of forty scans)."""

    min_support: int = 1
    min_length_m: Optional[float] = None
    min_single_length_m: Optional[float] = None
    clean_rms_ratio: Optional[float] = None
    clean_min_length_m: float = 0.0
    coarse_gap_m: Optional[float] = None
    visible_share: Optional[float] = None

    def clean_views(self, segments: np.ndarray, rms: np.ndarray | None) -> np.ndarray | None:
        """(N,) True for the segments that are evidence of a wall on their own: at least
        ``clean_min_length_m`` long with a fit rms at most ``clean_rms_ratio`` times the median rms of all
        N (the input's typical wall). None when the rule has no such clause or ``rms`` is None; no segment
        is clean when the median is 0 (no scale to compare with).

        Args:
            segments: (N, 4) world-frame segments (metres); rms: (N,) each one's fit rms from the
                extraction (metres; a non-finite or negative value is unknown, never clean).
        """
        if self.clean_rms_ratio is None or rms is None:
            return None
        rms = segment_column("rms", rms, len(segments))
        with np.errstate(invalid="ignore"):
            known = np.isfinite(rms) & (rms >= 0)
        typical = float(np.median(rms[known])) if known.any() else 0.0
        if typical <= 0:
            return np.zeros(len(rms), dtype=bool)
        with np.errstate(invalid="ignore"):
            return known & (rms <= self.clean_rms_ratio * typical) & (segment_lengths(segments) >= self.clean_min_length_m)

    def coarse_views(self, segments: np.ndarray, max_gap: np.ndarray | None) -> np.ndarray | None:
        """(N,) True for the segments whose longest stretch between consecutive returns is at least
        ``coarse_gap_m``: they cover no length for the length rule. None when the rule has no such clause
        or ``max_gap`` is None.

        Args:
            segments: (N, 4) world-frame segments (metres); max_gap: (N,) each one's longest stretch
                between consecutive returns along it (metres, >= 0; the extraction's column).
        """
        if self.coarse_gap_m is None or max_gap is None:
            return None
        return segment_column("max_gap", max_gap, len(segments)) >= self.coarse_gap_m

    @property
    def coarse_clause_acts(self) -> bool:
        """Whether ``coarse_gap_m`` can change which clusters are kept: a coarse view only loses its length,
        so the clause acts through the length rule (``min_length_m``) or not at all."""
        return self.coarse_gap_m is not None and self.min_length_m is not None

    def views(self, segments: np.ndarray, rms: np.ndarray | None, max_gap: np.ndarray | None,
              sensor_xy: np.ndarray | None = None) -> SupportViews:
        """The rule's clean and coarse views of (N, 4) world-frame ``segments`` from the extraction's (N,)
        ``rms`` and ``max_gap`` columns (metres, each None when absent), and the (N, 2) ``sensor_xy``
        (where each segment's scan was taken) when the rule has a visibility clause."""
        if self.visible_share is None or sensor_xy is None:
            sensor_xy = None
        else:
            sensor_xy = np.asarray(sensor_xy, dtype=float).reshape(-1, 2)
            if len(sensor_xy) != len(segments):
                raise ValueError(f"sensor_xy has {len(sensor_xy)} entries for {len(segments)} segments")
            if not np.isfinite(sensor_xy).all():
                raise ValueError("sensor_xy has a NaN or infinite position")
        return SupportViews(self.clean_views(segments, rms), self.coarse_views(segments, max_gap), sensor_xy)

    def keep(self, members: np.ndarray, covered: Callable[[], np.ndarray],
             clean_members: np.ndarray | None = None,
             seen: Callable[[np.ndarray, float | None], np.ndarray] | None = None) -> np.ndarray:
        """(C,) kept clusters from their (C,) member counts; ``covered()`` gives each one's covered
        length (C,) (called only when the length rule is needed); ``clean_members`` (C,): how many of each
        cluster's members are clean views (:meth:`clean_views`); one keeps the cluster; ``seen(kept, visible_share)``
        (:meth:`SupportViews.seen`) gives the share of the scans able to see each cluster not kept by the
        other clauses that saw it (called only when the visibility clause is set and needed)."""
        kept = members >= self.min_support
        if self.min_length_m is not None and not kept.all():
            length = covered()
            single = self.min_length_m if self.min_single_length_m is None else self.min_single_length_m
            kept |= (length >= self.min_length_m) & ((members >= 2) | (length >= single))
        if clean_members is not None:
            kept |= clean_members > 0
        if self.visible_share is not None and seen is not None and not kept.all():
            with np.errstate(invalid="ignore"):
                kept |= seen(kept, self.visible_share) >= self.visible_share
        return kept


def validate_input(segments, scan) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Check shapes and values; return (segments (N, 4), scan (N,), valid mask (N,))."""
    segments = as_segments(segments)
    scan = np.asarray(scan).reshape(-1)
    if len(scan) != len(segments):
        raise ValueError(f"scan has {len(scan)} entries for {len(segments)} segments")
    if not np.all(np.isfinite(segments)):
        raise ValueError("segments contain NaN or inf")
    scan = scan.astype(np.int64)
    valid = segment_lengths(segments) > MIN_SEGMENT_LENGTH_M
    return segments, scan, valid


def cut_at_extreme_projections(points: np.ndarray, labels: np.ndarray, n_clusters: int, mx: np.ndarray,
                               my: np.ndarray, ux: np.ndarray, uy: np.ndarray) -> np.ndarray:
    """Per cluster, the segment between the extreme projections of its points onto its line.

    Args:
        points: (K, 2) member endpoints; labels: (K,) their cluster in ``[0, n_clusters)``.
        mx, my, ux, uy: (M,) a point on each cluster's line and the line's unit direction.
    Returns:
        (M, 4) fused segments (a cluster without points collapses onto its line point).
    """
    t = (points[:, 0] - mx[labels]) * ux[labels] + (points[:, 1] - my[labels]) * uy[labels]
    tmin = np.full(n_clusters, np.inf)
    tmax = np.full(n_clusters, -np.inf)
    np.minimum.at(tmin, labels, t)
    np.maximum.at(tmax, labels, t)
    empty = ~np.isfinite(tmin)
    tmin[empty] = tmax[empty] = 0.0
    return np.stack([mx + tmin * ux, my + tmin * uy, mx + tmax * ux, my + tmax * uy], axis=1)


def fit_clusters(segments: np.ndarray, labels: np.ndarray, n_clusters: int,
                 weights: np.ndarray | None = None) -> np.ndarray:
    """Fuse each cluster into one segment, vectorised over clusters.

    For cluster ``c`` (members ``labels == c``), a total-least-squares line is fitted through all
    member endpoints (each endpoint weighted by its segment's weight), every member endpoint is
    projected onto that line, and the two extreme projections become the fused endpoints
    (the paper's Section 3.2 and Figure 6).

    Args:
        segments: (N, 4) input segments.
        labels: (N,) cluster index in ``[0, n_clusters)`` or -1 (ignored).
        n_clusters: number of clusters M.
        weights: (N,) non-negative weight per segment, or None for equal weights.
    Returns:
        (M, 4) fused segments.
    """
    if n_clusters == 0:
        return np.zeros((0, 4))
    keep = labels >= 0
    seg = segments[keep]
    lab = labels[keep]
    w = np.ones(len(seg)) if weights is None else np.asarray(weights, float)[keep]
    pts = np.concatenate([seg[:, :2], seg[:, 2:]])  # (2K, 2): first endpoints, then second
    lab2 = np.concatenate([lab, lab])
    w2 = np.concatenate([w, w])
    wsum = np.bincount(lab2, w2, n_clusters)
    wsum = np.where(wsum > 0, wsum, 1.0)
    mx = np.bincount(lab2, w2 * pts[:, 0], n_clusters) / wsum
    my = np.bincount(lab2, w2 * pts[:, 1], n_clusters) / wsum
    dx = pts[:, 0] - mx[lab2]
    dy = pts[:, 1] - my[lab2]
    sxx = np.bincount(lab2, w2 * dx * dx, n_clusters)
    syy = np.bincount(lab2, w2 * dy * dy, n_clusters)
    sxy = np.bincount(lab2, w2 * dx * dy, n_clusters)
    # Principal axis of the 2x2 scatter matrix in closed form; theta in (-pi/2, pi/2] gives cos >= 0,
    # a canonical sign that makes the result independent of the input order.
    theta = 0.5 * np.arctan2(2 * sxy, sxx - syy)
    ux, uy = np.cos(theta), np.sin(theta)
    return cut_at_extreme_projections(pts, lab2, n_clusters, mx, my, ux, uy)


def relabel_by_first_appearance(groups: np.ndarray, scan: np.ndarray, segments: np.ndarray,
                                order_key: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Renumber group ids 0..G-1 in a canonical order that does not depend on the input order.

    Groups are ordered by ``order_key`` (per group, e.g. the scan at which the group was first
    linked; default: the group's first scan), then by its first scan, then by its mean midpoint.
    Returns (new group id per segment (N,), group sizes (G,)).
    """
    n_groups = int(groups.max()) + 1 if len(groups) else 0
    first_scan = np.full(n_groups, np.iinfo(np.int64).max)
    np.minimum.at(first_scan, groups, scan)
    sizes = np.bincount(groups, minlength=n_groups)
    mid = 0.5 * (segments[:, :2] + segments[:, 2:])
    cx = np.bincount(groups, mid[:, 0], n_groups) / np.maximum(sizes, 1)
    cy = np.bincount(groups, mid[:, 1], n_groups) / np.maximum(sizes, 1)
    key = first_scan if order_key is None else order_key
    order = np.lexsort((np.round(cy, 6), np.round(cx, 6), first_scan, key))
    rank = np.empty(n_groups, dtype=np.int64)
    rank[order] = np.arange(n_groups)
    return rank[groups], sizes[order]


def orientation_embedding(theta: np.ndarray) -> np.ndarray:
    """Embed undirected orientations (radians, pi-periodic) as (K, 2) points on a circle of radius 1/2.

    Doubling the angle makes 0 and pi the same point (a wall at 179 deg is a wall at -1 deg), and the
    radius 1/2 makes the chord between two embedded points approximately the angle difference in
    radians, so a Euclidean bandwidth in this space is an angular bandwidth.
    """
    return 0.5 * np.stack([np.cos(2 * theta), np.sin(2 * theta)], axis=1)


def cluster_orientations(theta: np.ndarray, bandwidth_rad: float) -> np.ndarray:
    """Mean-shift clusters of undirected orientations (K,) -> (K,) cluster ids (scikit-learn MeanShift)."""
    return mean_shift(orientation_embedding(theta), bandwidth_rad)


def mean_shift(points: np.ndarray, bandwidth: float) -> np.ndarray:
    """(K,) cluster ids of (K, D) points: scikit-learn's flat-kernel MeanShift, all seeds at once.

    The result is ``MeanShift(bandwidth=bandwidth, bin_seeding=True, cluster_all=True)
    .fit_predict(points)`` (same seeds, neighbourhoods, means, stopping rule, duplicate removal and
    nearest-centre labels; a test checks it on points in general position), but every seed climbs in the
    same iteration with one batched radius query per iteration, instead of one Python-level query per
    seed and iteration (which made scikit-learn's loop 20-50x slower on large maps). The queries are
    scipy KD-trees (closed balls, as scikit-learn's; importing scikit-learn would cost most of a second):
    each neighbourhood is averaged in index order, where scikit-learn sums in its tree's order, so when a
    neighbour lies at exactly the bandwidth or a point exactly between two centres, float rounding may
    decide differently (points on a grid; never seen on real fusion inputs).
    """
    points = np.asarray(points, dtype=np.float64)
    if len(points) < 2:
        return np.zeros(len(points), np.int64)
    # Bin seeding snaps points to a grid anchored at 0: anchor it at the data instead, so that a translated
    # input gives the same clusters.
    points = points - points.min(axis=0)
    seeds = _bin_seeds(points, bandwidth)
    stop_thresh = 1e-3 * bandwidth
    max_iter = 300                                      # MeanShift's default
    tree = cKDTree(points)
    current = seeds.astype(np.float64)                  # float32 bin seeds, as scikit-learn makes them
    final = np.zeros_like(current)
    count = np.zeros(len(seeds), dtype=np.int64)
    iterations = np.zeros(len(seeds), dtype=np.int64)
    active = np.arange(len(seeds))
    while len(active):
        found = tree.query_ball_point(current[active], bandwidth, return_sorted=True)
        still = []
        for seed, idx in zip(active, found):
            if len(idx) == 0:
                continue
            new = np.mean(points[idx], axis=0)
            if np.linalg.norm(new - current[seed]) <= stop_thresh or iterations[seed] == max_iter:
                final[seed], count[seed] = new, len(idx)
            else:
                iterations[seed] += 1
                current[seed] = new
                still.append(seed)
        active = np.asarray(still, dtype=np.int64)
    intensity = {tuple(final[s]): int(count[s]) for s in range(len(seeds)) if count[s]}
    by_intensity = sorted(intensity.items(), key=lambda item: (item[1], item[0]), reverse=True)
    centres = np.array([centre for centre, _ in by_intensity])
    near = cKDTree(centres).query_ball_point(centres, bandwidth)
    unique = np.ones(len(centres), dtype=bool)
    for k in range(len(centres)):
        if unique[k]:
            unique[near[k]] = False
            unique[k] = True
    kept = centres[unique]
    k = min(3, len(kept))
    dist, idx = cKDTree(kept).query(points, k=[1, 2, 3][:k])
    # scikit-learn breaks exact ties towards the lower centre index (the stronger cluster).
    idx = np.where(dist == dist[:, :1], idx, len(kept))
    return idx.min(axis=1).astype(np.int64)


def _bin_seeds(points: np.ndarray, bin_size: float) -> np.ndarray:
    """scikit-learn's ``get_bin_seeds(points, bin_size, min_bin_freq=1)``, vectorised.

    One seed per occupied bin (``round(p / bin_size)``, in order of first occurrence), as float32 times
    ``bin_size``; the points themselves when every point has a bin of its own.
    """
    binned = np.round(points / bin_size)
    cells = binned.astype(np.int64)
    low, span = cells.min(axis=0), cells.max(axis=0) - cells.min(axis=0) + 1
    if np.all(np.isfinite(binned)) and float(np.prod(span.astype(float))) < 2.0**62:
        _, first = np.unique(np.ravel_multi_index((cells - low).T, tuple(span)), return_index=True)
    else:
        _, first = np.unique(binned, axis=0, return_index=True)
    if len(first) == len(points):
        return points
    return binned[np.sort(first)].astype(np.float32) * bin_size


def merge_onto_mean_line(segments: np.ndarray, labels: np.ndarray, n_clusters: int,
                         weights: np.ndarray | None = None) -> np.ndarray:
    """Merge each cluster onto the line through its (weighted) mean midpoint at its mean orientation.

    The merging rule of both competing algorithms: the representative line passes through the middle
    of the cluster with the clusters' average direction (doubled-angle circular mean); member endpoints
    are projected onto it and the extreme projections become the fused endpoints.
    Returns (M, 4).
    """
    if n_clusters == 0:
        return np.zeros((0, 4))
    keep = labels >= 0
    seg, lab = segments[keep], labels[keep]
    w = np.ones(len(seg)) if weights is None else np.asarray(weights, float)[keep]
    wsum = np.maximum(np.bincount(lab, w, n_clusters), 1e-12)
    mid = 0.5 * (seg[:, :2] + seg[:, 2:])
    mx = np.bincount(lab, w * mid[:, 0], n_clusters) / wsum
    my = np.bincount(lab, w * mid[:, 1], n_clusters) / wsum
    d = seg[:, 2:] - seg[:, :2]
    phi = 2 * np.arctan2(d[:, 1], d[:, 0])
    theta = 0.5 * np.arctan2(np.bincount(lab, w * np.sin(phi), n_clusters),
                             np.bincount(lab, w * np.cos(phi), n_clusters))
    ux, uy = np.cos(theta), np.sin(theta)
    pts = np.concatenate([seg[:, :2], seg[:, 2:]])
    return cut_at_extreme_projections(pts, np.concatenate([lab, lab]), n_clusters, mx, my, ux, uy)


def finish_clusters(segments: np.ndarray, scan: np.ndarray, valid: np.ndarray, groups: np.ndarray,
                    merge, weights: np.ndarray | None = None, extras: dict | None = None) -> FusionResult:
    """Common tail of the methods without a support filter: canonical labels, merge, FusionResult.

    ``groups`` (K,) are cluster ids of the valid segments; ``merge`` is a merge function such as
    :func:`merge_onto_mean_line`.
    """
    labels = np.full(len(segments), -1, dtype=np.int64)
    idx = np.flatnonzero(valid)
    if len(idx) == 0:
        empty = np.zeros((0, 4))
        return FusionResult(empty, np.zeros(0, np.int64), labels, empty, 0, int((~valid).sum()), extras or {})
    seg, sc = segments[idx], scan[idx]
    _, groups = np.unique(groups, return_inverse=True)
    sub, sizes = relabel_by_first_appearance(groups.reshape(-1), sc, seg)
    fused = merge(seg, sub, len(sizes), None if weights is None else weights[idx])
    labels[idx] = sub
    return FusionResult(fused, sizes.astype(np.int64), labels, fused, 0, int((~valid).sum()), extras or {})


TINY_INPUT = (np.array([[0.0, 0.0, 10.0, 0.0], [0.0, 0.05, 10.0, 0.05], [0.0, 10.0, 0.0, 20.0]]), np.array([0, 1, 2]))
"""Three segments a method's ``prepare`` can fuse to import its libraries and compile its kernels."""
