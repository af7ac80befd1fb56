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

import numpy as np
from scipy.sparse import coo_matrix
from scipy.spatial import cKDTree

from featmap.config import DensityConfig
from featmap.fusion.base import (FusionResult, cluster_orientations, finish_clusters, merge_onto_mean_line,
                                 validate_input)
from featmap.geometry import segment_lengths, segment_orientations


def spatial_neighbours(segments: np.ndarray, direction: np.ndarray, config: DensityConfig) -> tuple[np.ndarray, np.ndarray]:
    """Pairs ``(i, j)`` of (K, 4) segments that are lateral and longitudinal neighbours along ``direction`` (2,)."""
    normal = np.array([-direction[1], direction[0]])
    u1, u2 = segments[:, :2] @ direction, segments[:, 2:] @ direction
    umin, umax = np.minimum(u1, u2), np.maximum(u1, u2)
    v = 0.5 * (segments[:, :2] + segments[:, 2:]) @ normal
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


def fuse_density(segments, scan, config: DensityConfig = DensityConfig(), progress=None) -> FusionResult:
    """Fuse (N, 4) world-frame segments; ``scan`` (N,) is accepted for a common signature but unused."""
    from sklearn.cluster import DBSCAN

    segments, scan, valid = validate_input(segments, scan)
    seg = segments[valid]
    groups = np.zeros(len(seg), dtype=np.int64)
    lengths = segment_lengths(segments)
    if len(seg):
        theta = segment_orientations(seg)
        orient = cluster_orientations(theta, np.deg2rad(config.orientation_bandwidth_deg))
        w = lengths[valid]
        next_id = 0
        for o in np.unique(orient):
            members = np.flatnonzero(orient == o)
            phi = 2 * theta[members]
            mean = 0.5 * np.arctan2((w[members] * np.sin(phi)).sum(), (w[members] * np.cos(phi)).sum())
            i, j = spatial_neighbours(seg[members], np.array([np.cos(mean), np.sin(mean)]), config)
            k = len(members)
            # Neighbours get distance 0.5 (< eps = 1); pairs not stored are "infinitely" far apart.
            dist = coo_matrix((np.full(2 * len(i), 0.5), (np.r_[i, j], np.r_[j, i])), shape=(k, k)).tocsr()
            sub = DBSCAN(eps=1.0, min_samples=config.min_samples, metric="precomputed").fit_predict(dist)
            noise = sub < 0                                  # possible only when min_samples > 1
            sub[noise] = sub.max() + 1 + np.arange(noise.sum())
            groups[members] = next_id + sub
            next_id += int(sub.max()) + 1
    return finish_clusters(segments, scan, valid, groups, merge_onto_mean_line, weights=lengths)
