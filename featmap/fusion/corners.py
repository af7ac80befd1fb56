"""Corner optimisation: join the nearly touching endpoints of different fused features.

``midpoint`` (the paper's rule, Section 3.2 and Figure 7): two endpoints of different features closer
than ``snap_distance_m`` are both replaced by their midpoint.

``intersection`` (featmap's improvement): two endpoints closer than ``snap_distance_m`` are joined
only where their walls really meet: the two features cross at a clear angle (at least
``min_angle_deg``) and the intersection of their fitted lines lies within ``max_extension_m`` of
*both* endpoints. Both endpoints then move to that intersection, each along its own line, so no wall
turns or shifts off its points; the corner lands on both walls instead of being cut off as the
midpoint does. Nearly collinear endpoints (a wall continuing after a doorway) and a wall ending
in front of another one (a free-standing wall before the outer wall) are left alone, and no feature
is shortened past its other endpoint.

Pairs are joined greedily, closest first; each endpoint moves at most once. Both modes leave a
feature unchanged where a join would collapse it or make it a copy of another feature.
"""

from __future__ import annotations

from typing import Literal, Optional

import numpy as np
from pydantic import Field
from scipy.spatial import cKDTree

from featmap.config import Section
from featmap.geometry import as_segments, included_angle, line_coefficients, line_intersection, segment_directions


class CornerConfig(Section):
    """Corner optimisation, run identically after every method (as in the paper's Table 2)."""

    mode: Literal["midpoint", "intersection", "none"] = Field(
        "intersection", description="midpoint = the paper's rule; intersection = ours; none = off")
    snap_distance_m: float = Field(1.0, ge=0, description="endpoints of different features closer than this are joined")
    min_angle_deg: float = Field(30.0, ge=0, le=90, description="intersection mode: lines must meet at least this steeply")
    max_extension_m: Optional[float] = Field(0.5, ge=0, description="intersection mode: join only if each endpoint moves at most this far along its own line to the corner (null = snap_distance_m)")


def optimise_corners(segments, config: CornerConfig = CornerConfig()) -> np.ndarray:
    """Return a copy of ``segments`` (M, 4) with nearby endpoints of different features joined."""
    segments = as_segments(segments).copy()
    if config.mode == "none" or len(segments) < 2 or config.snap_distance_m <= 0:
        return segments
    endpoints = segments.reshape(-1, 2).copy()          # row 2m = first endpoint of m, 2m+1 = second
    owner = np.arange(len(endpoints)) // 2
    pairs = cKDTree(endpoints).query_pairs(config.snap_distance_m, output_type="ndarray")
    if len(pairs) == 0:
        return segments
    pairs = pairs[owner[pairs[:, 0]] != owner[pairs[:, 1]]]
    dist = np.hypot(*(endpoints[pairs[:, 0]] - endpoints[pairs[:, 1]]).T)
    order = np.lexsort((pairs[:, 1], pairs[:, 0], dist))
    coef = line_coefficients(segments)
    directions = segment_directions(segments)
    min_angle = np.deg2rad(config.min_angle_deg)
    used = np.zeros(len(endpoints), dtype=bool)
    new = endpoints.copy()
    max_ext = config.snap_distance_m if config.max_extension_m is None else config.max_extension_m
    for a, b in pairs[order]:
        if used[a] or used[b]:
            continue
        fa, fb = owner[a], owner[b]
        if config.mode == "midpoint":
            target = 0.5 * (endpoints[a] + endpoints[b])
        else:
            target = _corner(endpoints, a, b, coef[fa:fa + 1], coef[fb:fb + 1], directions[fa], directions[fb],
                             min_angle, max_ext)
            if target is None:
                continue
        new[a] = new[b] = target
        used[a] = used[b] = True
    out = new.reshape(-1, 4)
    # Never let a feature collapse or turn into a copy of another one: keep the original instead.
    collapsed = np.hypot(out[:, 2] - out[:, 0], out[:, 3] - out[:, 1]) < 1e-6
    out[collapsed] = segments[collapsed]
    copies = _copies(out)
    out[copies] = segments[copies]
    return out


def _corner(endpoints: np.ndarray, a: int, b: int, coef_a: np.ndarray, coef_b: np.ndarray, dir_a: np.ndarray,
            dir_b: np.ndarray, min_angle: float, max_ext: float) -> np.ndarray | None:
    """The corner where endpoint ``a`` and endpoint ``b`` of two features really meet, or None."""
    if included_angle(coef_a, coef_b)[0] < min_angle:
        return None
    x = line_intersection(endpoints[a], dir_a, endpoints[b], dir_b)
    if x is None or max(np.hypot(*(x - endpoints[a])), np.hypot(*(x - endpoints[b]))) > max_ext:
        return None
    # Moving an endpoint to x must keep it on the same side of the feature's other endpoint.
    for end, direction in ((a, dir_a), (b, dir_b)):
        other = endpoints[end ^ 1]
        if np.dot(endpoints[end] - other, direction) * np.dot(x - other, direction) <= 0:
            return None
    return x


def _copies(segments: np.ndarray) -> np.ndarray:
    """(M,) True for features identical (either direction, to 1 nm) to an earlier feature."""
    key = np.round(segments, 9)
    swap = (key[:, 0] > key[:, 2]) | ((key[:, 0] == key[:, 2]) & (key[:, 1] > key[:, 3]))
    canonical = np.where(swap[:, None], key[:, [2, 3, 0, 1]], key)
    _, first = np.unique(canonical, axis=0, return_index=True)
    dup = np.ones(len(segments), dtype=bool)
    dup[first] = False
    return dup
