"""Small, shared, vectorised 2D geometry on segments.

A *segment array* has shape (N, 4): rows ``x1, y1, x2, y2`` in metres, all in one frame (the local
metric "world" frame unless stated otherwise). Nothing here reads files, prints or plots.
"""

from __future__ import annotations

import numpy as np

MAX_COORDINATE_M = 1e12
"""Coordinates are metres of a local or projected frame (UTM northings stay below 1e7; float64 keeps 0.1 mm
here). Readers refuse larger ones."""

MAX_MAP_SPAN_M = 2.0e7
"""No map of the Earth's surface spans more than this (metres; half the Earth's circumference). Readers refuse
a wider one: one position is wrong, and the fusion's grids and samples over that span would not fit in memory."""


def spread_and_outlier(points: np.ndarray) -> tuple[float, int]:
    """(span, k) of (N, D) points (N >= 1): their largest extent along an axis, and the index of the point
    farthest (largest coordinate difference) from their median: the one to blame when the span is too wide."""
    span = float((points.max(axis=0) - points.min(axis=0)).max())
    return span, int(np.argmax(np.abs(points - np.median(points, axis=0)).max(axis=1)))


def as_segments(segments) -> np.ndarray:
    """Return ``segments`` as a float64 (N, 4) array (an empty input gives shape (0, 4))."""
    arr = np.asarray(segments, dtype=float)
    if arr.size == 0:
        return np.zeros((0, 4))
    if arr.ndim != 2 or arr.shape[1] != 4:
        raise ValueError(f"segments must have shape (N, 4), got {arr.shape}")
    return arr


def segment_lengths(segments: np.ndarray) -> np.ndarray:
    """(N,) Euclidean length of each segment."""
    return np.hypot(segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1])


def dense_samples(segments: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Points along each (M, 4) segment, both endpoints included, at most ``step`` apart:
    (samples (S, 2), owner segment (S,))."""
    lengths = segment_lengths(segments)
    n = np.maximum(np.ceil(lengths / step).astype(np.int64), 1) + 1
    owner = np.repeat(np.arange(len(segments)), n)
    start = np.cumsum(n) - n
    t = (np.arange(n.sum()) - start[owner]) / (n[owner] - 1)
    a, b = segments[owner, :2], segments[owner, 2:]
    return a + t[:, None] * (b - a), owner


def segment_midpoints(segments: np.ndarray) -> np.ndarray:
    """(N, 2) midpoint of each segment (the centre of its feature circle)."""
    return 0.5 * (segments[:, :2] + segments[:, 2:])


def segment_directions(segments: np.ndarray) -> np.ndarray:
    """(N, 2) unit direction from endpoint 1 to endpoint 2 ((1, 0) for zero-length segments)."""
    d = segments[:, 2:] - segments[:, :2]
    n = np.hypot(d[:, 0], d[:, 1])
    out = np.tile([1.0, 0.0], (len(segments), 1))
    ok = n > 0
    out[ok] = d[ok] / n[ok, None]
    return out


def segment_orientations(segments: np.ndarray) -> np.ndarray:
    """(N,) undirected orientation in [0, pi): a wall at 179 deg and one at -1 deg both give ~pi."""
    d = segments[:, 2:] - segments[:, :2]
    return np.mod(np.arctan2(d[:, 1], d[:, 0]), np.pi)


def line_coefficients(segments: np.ndarray) -> np.ndarray:
    """(N, 3) coefficients ``A, B, C`` of the line ``A x + B y + C = 0`` through each segment (eqs. 3-4).

    ``A = y2 - y1``, ``B = x1 - x2``, ``C = x2 y1 - x1 y2``: no slope form, so vertical and
    horizontal lines need no special case.
    """
    x1, y1, x2, y2 = segments.T
    return np.stack([y2 - y1, x1 - x2, x2 * y1 - x1 * y2], axis=1)


def included_angle(coef_a: np.ndarray, coef_b: np.ndarray) -> np.ndarray:
    """Included angle beta in [0, pi/2] between lines given by (K, 3) coefficient rows (eq. 5)."""
    num = np.abs(coef_a[:, 0] * coef_b[:, 0] + coef_a[:, 1] * coef_b[:, 1])
    den = np.hypot(coef_a[:, 0], coef_a[:, 1]) * np.hypot(coef_b[:, 0], coef_b[:, 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = np.where(den > 0, num / np.where(den > 0, den, 1.0), 1.0)
    return np.arccos(np.clip(cos, 0.0, 1.0))


def circle_overlap_area(r1: np.ndarray, r2: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Exact area shared by circles of radii ``r1``, ``r2`` whose centres are ``d`` apart (eq. 10).

    Disjoint or tangent (``d >= r1 + r2``): 0. One inside the other (``d <= |r1 - r2|``):
    the smaller circle's area. Otherwise ``a1 r1^2 + a2 r2^2 - d r1 sin(a1)``, with ``a1`` the angle
    at centre 1 between the centre line and an intersection point (law of cosines).
    """
    r1, r2, d = np.broadcast_arrays(np.asarray(r1, float), np.asarray(r2, float), np.asarray(d, float))
    out = np.zeros(r1.shape)
    contained = d <= np.abs(r1 - r2)
    out[contained] = np.pi * np.minimum(r1, r2)[contained] ** 2
    partial = (d < r1 + r2) & ~contained
    if np.any(partial):
        a, b, c = r1[partial], r2[partial], d[partial]
        alpha1 = np.arccos(np.clip((c**2 + a**2 - b**2) / (2 * c * a), -1.0, 1.0))
        alpha2 = np.arccos(np.clip((c**2 + b**2 - a**2) / (2 * c * b), -1.0, 1.0))
        out[partial] = alpha1 * a**2 + alpha2 * b**2 - c * a * np.sin(alpha1)
    return out


def point_segment_distance(points: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """(K,) distance from each point (K, 2) to the matching segment (K, 4) (row-wise pairs)."""
    a = segments[:, :2]
    ab = segments[:, 2:] - a
    denom = np.einsum("ij,ij->i", ab, ab)
    t = np.einsum("ij,ij->i", points - a, ab)
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.where(denom > 0, t / np.where(denom > 0, denom, 1.0), 0.0)
    closest = a + np.clip(t, 0.0, 1.0)[:, None] * ab
    return np.hypot(*(points - closest).T)


def fit_line_tls(points: np.ndarray, weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Total-least-squares line through (K, 2) points: returns (centroid (2,), unit direction (2,)).

    Orientation-invariant (minimises perpendicular distances), so vertical lines fit as well as
    horizontal ones. ``weights`` (K,) are non-negative point weights.
    """
    w = np.ones(len(points)) if weights is None else np.asarray(weights, float)
    if w.sum() <= 0:
        w = np.ones(len(points))
    centroid = (w[:, None] * points).sum(0) / w.sum()
    centred = points - centroid
    cov = (w[:, None] * centred).T @ centred
    eigvals, eigvecs = np.linalg.eigh(cov)
    direction = eigvecs[:, np.argmax(eigvals)]
    # A canonical sign makes results independent of input order.
    if direction[0] < 0 or (direction[0] == 0 and direction[1] < 0):
        direction = -direction
    return centroid, direction


def line_intersection(p1: np.ndarray, d1: np.ndarray, p2: np.ndarray, d2: np.ndarray) -> np.ndarray | None:
    """Intersection of lines ``p1 + s d1`` and ``p2 + t d2`` (2,), or None when parallel."""
    cross = d1[0] * d2[1] - d1[1] * d2[0]
    if abs(cross) < 1e-12:
        return None
    diff = p2 - p1
    s = (diff[0] * d2[1] - diff[1] * d2[0]) / cross
    return p1 + s * d1


def rigid_motion_2d(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The planar rigid motion that best maps ``source`` (K, 2) onto ``target`` (K, 2) in least squares
    (Kabsch): ``(R (2, 2), t (2,))`` with ``target ~ source @ R.T + t``."""
    source, target = np.asarray(source, float), np.asarray(target, float)
    cs, ct = source.mean(axis=0), target.mean(axis=0)
    u, _, vt = np.linalg.svd((source - cs).T @ (target - ct))
    rot = vt.T @ np.diag([1.0, np.sign(np.linalg.det(vt.T @ u.T))]) @ u.T
    return rot, ct - rot @ cs


def move_segments_2d(segments: np.ndarray, rot: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """(M, 4) ``segments`` moved by the planar rigid motion ``x -> rot @ x + shift``."""
    segments = as_segments(segments)
    return np.column_stack([segments[:, :2] @ rot.T + shift, segments[:, 2:] @ rot.T + shift])
