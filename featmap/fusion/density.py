"""Competing algorithm 2 (the paper's Section 2.2, after Sarkar, Pal & Sarkar 2014): density clustering.

1. Mean shift on segment orientations (pi-periodic embedding, as in algorithm 1).
2. Within each orientation cluster, density-based spatial clustering (scikit-learn DBSCAN on a
   sparse precomputed neighbourhood): two segments are neighbours when their *lateral separation*
   (distance between their midpoints across the cluster's mean direction) is at most
   ``lateral_eps_m`` and their *longitudinal overlap* along that direction leaves a gap of at most
   ``longitudinal_gap_m``.
3. Each cluster is merged into a length-weighted segment: the line through the length-weighted mean
   midpoint at the length-weighted mean orientation, cut at the extreme projections of its members.

No support filter, as in the original.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from pydantic import Field
from scipy.sparse import coo_matrix
from scipy.spatial import cKDTree

from featmap.config import Section
from featmap.fusion.base import (TINY_INPUT, FusionMethod, FusionResult, cluster_orientations, finish_clusters,
                                 merge_onto_mean_line, validate_input)
from featmap.geometry import segment_lengths, segment_orientations


class DensityConfig(Section):
    """Competing algorithm 2 (after Sarkar et al. 2014): orientation mean shift, then density clustering."""

    orientation_bandwidth_deg: float = Field(3.0, gt=0, le=90, description="mean-shift bandwidth on orientation")
    lateral_eps_m: float = Field(0.5, gt=0, description="max lateral separation of neighbouring segments")
    longitudinal_gap_m: float = Field(1.0, ge=0, description="max gap along the line between neighbouring segments")
    min_samples: int = Field(1, ge=1, description="DBSCAN min_samples (1 = every segment is a core point)")


def along_and_across(segments: np.ndarray, direction: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(umin, umax, v), each (K,): the extent of (K, 4) segments along ``direction`` (2,) and their midpoints across it."""
    normal = np.array([-direction[1], direction[0]])
    u1, u2 = segments[:, :2] @ direction, segments[:, 2:] @ direction
    v = 0.5 * (segments[:, :2] + segments[:, 2:]) @ normal
    return np.minimum(u1, u2), np.maximum(u1, u2), v


def spatial_neighbours(segments: np.ndarray, direction: np.ndarray, config: DensityConfig) -> tuple[np.ndarray, np.ndarray]:
    """Pairs ``(i, j)`` of (K, 4) segments that are lateral and longitudinal neighbours along ``direction`` (2,).

    Every pair: the cost grows with the square of how often a wall is seen (see :func:`neighbour_components`).
    """
    umin, umax, v = along_and_across(segments, direction)
    length = umax - umin
    scale_u = length.max() + config.longitudinal_gap_m + 1e-9
    pts = np.stack([0.5 * (umin + umax) / scale_u, v / config.lateral_eps_m], axis=1)
    pairs = cKDTree(pts).query_pairs(1.0 + 1e-9, p=np.inf, output_type="ndarray")
    if len(pairs) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    i, j = pairs[:, 0], pairs[:, 1]
    gap = np.maximum(umin[i], umin[j]) - np.minimum(umax[i], umax[j])   # < 0 means they overlap
    ok = (np.abs(v[i] - v[j]) <= config.lateral_eps_m) & (gap <= config.longitudinal_gap_m)
    return i[ok], j[ok]


def neighbour_components(umin: np.ndarray, umax: np.ndarray, v: np.ndarray, orient: np.ndarray,
                         config: DensityConfig) -> np.ndarray:
    """Connected components of the neighbour graph of :func:`spatial_neighbours`, in about linear time.

    Args:
        umin, umax, v: (K,) extents along and midpoints across each segment's orientation-cluster direction.
        orient: (K,) orientation cluster of each segment (segments of different clusters are never neighbours).
    Returns:
        (K,) component id per segment. With ``min_samples = 1`` every point is a DBSCAN core point, so
        these components are exactly DBSCAN's clusters; they are found with union-find over a grid
        (:func:`featmap.fusion.link_forest.band_components_kernel`) without listing every neighbour pair.
    """
    from featmap.fusion import link_forest as lf

    k = len(umin)
    if k == 0:
        return np.zeros(0, np.int64)
    eps, gap = float(config.lateral_eps_m), float(config.longitudinal_gap_m)
    slack = 1e-9 * (1.0 + float(max(np.abs(umin).max(), np.abs(umax).max(), np.abs(v).max())))
    # at most 2^24 cells per axis, so that (cluster, u cell, v cell) keys fit in an int64
    u_size = max(gap, float(np.median(umax - umin)), float(umax.max() - umin.min()) / 2**24, 1e-3)
    v_size = max(eps, float(v.max() - v.min()) / 2**24)
    u_origin, v_origin = float(umin.min()) - u_size, float(v.min()) - v_size
    nu = int(np.floor((umax.max() - u_origin) / u_size)) + 2
    nv = int(np.floor((v.max() - v_origin) / v_size)) + 2
    _, orient = np.unique(orient, return_inverse=True)
    orient = orient.reshape(-1).astype(np.int64)
    base = orient * (nu * nv)
    cu0 = np.floor((umin - u_origin) / u_size).astype(np.int64)
    cu1 = np.floor((umax - u_origin) / u_size).astype(np.int64)
    cv = np.floor((v - v_origin) / v_size).astype(np.int64)
    per = cu1 - cu0 + 1
    entry_start = np.concatenate([[0], np.cumsum(per)]).astype(np.int64)
    owner = np.repeat(np.arange(k), per)
    entry_keys = base[owner] + (cu0[owner] + np.arange(len(owner)) - entry_start[owner]) * nv + cv[owner]
    keys, entry_cells = np.unique(entry_keys, return_inverse=True)
    table_keys, table_cell, mask = lf._build_cell_table(keys)
    order = np.lexsort((umin, orient))
    parent, _ = lf.band_components_kernel(order, umin, umax, v, entry_start, entry_cells.reshape(-1).astype(np.int64),
                                          len(keys), eps, gap, slack, base, table_keys, table_cell, mask,
                                          u_origin, u_size, v_origin, v_size, nu, nv)
    return parent


def fuse_density(segments, scan, config: DensityConfig = DensityConfig(),
                 progress: Callable[[int, int], None] | None = None) -> FusionResult:
    """Fuse (N, 4) world-frame segments; ``scan`` (N,) is accepted for a common signature but unused.

    ``progress(done, total)`` is called after the orientation clustering and at the end (a fusion step each).
    """
    segments, scan, valid = validate_input(segments, scan)
    seg = segments[valid]
    groups = np.zeros(len(seg), dtype=np.int64)
    lengths = segment_lengths(segments)
    if len(seg):
        theta = segment_orientations(seg)
        orient = cluster_orientations(theta, np.deg2rad(config.orientation_bandwidth_deg))
        if progress is not None:
            progress(1, 2)
        directions = cluster_directions(theta, orient, lengths[valid])
        if config.min_samples == 1:
            umin, umax, v = np.empty(len(seg)), np.empty(len(seg)), np.empty(len(seg))
            for members, direction in directions.values():
                umin[members], umax[members], v[members] = along_and_across(seg[members], direction)
            groups = neighbour_components(umin, umax, v, orient, config)
        else:
            groups = _dbscan_per_orientation(seg, directions, config)
        if progress is not None:
            progress(2, 2)
    return finish_clusters(segments, scan, valid, groups, merge_onto_mean_line, weights=lengths)


def cluster_directions(theta: np.ndarray, orient: np.ndarray, weights: np.ndarray) -> dict:
    """Per orientation cluster: (member indices, unit direction (2,)) at the weighted doubled-angle mean of ``theta`` (K,)."""
    directions = {}
    for o in np.unique(orient):
        members = np.flatnonzero(orient == o)
        phi = 2 * theta[members]
        mean = 0.5 * np.arctan2((weights[members] * np.sin(phi)).sum(), (weights[members] * np.cos(phi)).sum())
        directions[o] = (members, np.array([np.cos(mean), np.sin(mean)]))
    return directions


def _dbscan_per_orientation(seg: np.ndarray, directions: dict, config: DensityConfig) -> np.ndarray:
    """scikit-learn DBSCAN on the sparse precomputed neighbourhood of each orientation cluster (any min_samples)."""
    from sklearn.cluster import DBSCAN

    groups = np.zeros(len(seg), dtype=np.int64)
    next_id = 0
    for members, direction in directions.values():
        i, j = spatial_neighbours(seg[members], direction, config)
        k = len(members)
        # Neighbours get distance 0.5 (< eps = 1); pairs not stored are "infinitely" far apart.
        dist = coo_matrix((np.full(2 * len(i), 0.5), (np.r_[i, j], np.r_[j, i])), shape=(k, k)).tocsr()
        sub = DBSCAN(eps=1.0, min_samples=config.min_samples, metric="precomputed").fit_predict(dist)
        noise = sub < 0                                  # possible only when min_samples > 1
        sub[noise] = sub.max() + 1 + np.arange(noise.sum())
        groups[members] = next_id + sub
        next_id += int(sub.max()) + 1
    return groups


METHOD = FusionMethod(name="density", title="Competing 2: density clustering (Sarkar et al. 2014)", color="#2ca02c",
                      linestyle=":", config_type=DensityConfig, fuse=fuse_density,
                      prepare=lambda: fuse_density(*TINY_INPUT))
