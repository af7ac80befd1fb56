"""Line segments of one 2D laser scan (split-and-merge on the ordered beams).

Input: the scan's returns in the sensor frame, in beam order. Output: segments in the sensor frame.

1. Crop by range (``min_range_m``, ``max_range_m``).
2. Cut the beam sequence into runs at *breakpoints*: between two consecutive returns whose gap is
   larger than the adaptive threshold of Borges & Aldon (2004),
   ``r * sin(dphi) / sin(lambda - dphi) + 3 sigma`` (what a surface seen at ``lambda`` degrees
   from the beam would leave between two returns ``dphi`` apart), clamped to
   ``[jump_min_m, jump_max_m]``; missing beams make ``dphi`` larger, so a run also ends where returns
   are missing over more than ``lambda``.
3. Split each run recursively at its point farthest from the chord between its first and last
   point while that distance exceeds ``split_distance_m`` (iterative end-point fit).
4. Merge neighbouring pieces of a run when one total-least-squares line fits both within
   ``split_distance_m`` (undoes splits caused by noise).
5. Each piece: trim end points farther than ``split_distance_m`` from its TLS line (corner points
   shared with the neighbouring wall), refit, cut at the extreme projections of its points, and
   keep it if it has ``min_points`` points, ``min_length_m`` length and ``max_rms_m`` residual.

Everything is deterministic; nothing opens files, prints or plots.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydantic import Field

from featmap.config import Section
from featmap.extraction.base import Extractor, ScanSegments
from featmap.geometry import move_segments_2d


class Lines2DConfig(Section):
    """Per-scan line extraction of a 2D laser (sensor frame, metres)."""

    min_range_m: float = Field(0.05, ge=0, description="drop returns closer than this")
    max_range_m: float = Field(30.0, gt=0, description="drop returns farther than this (sparse, noisy)")
    breakpoint_lambda_deg: float = Field(10.0, gt=0, lt=90, description="adaptive breakpoints: the shallowest beam incidence on one surface")
    range_sigma_m: float = Field(0.01, ge=0, description="adaptive breakpoints: range noise (adds 3 sigma)")
    jump_min_m: float = Field(0.1, ge=0, description="a gap this small never breaks a run")
    jump_max_m: float = Field(0.3, gt=0, description="a gap this large always breaks a run (no segment bridges an opening or a sparse stretch)")
    split_distance_m: float = Field(0.05, gt=0, description="split a piece where a point lies this far from its chord; merge and trim with the same distance")
    min_points: int = Field(6, ge=2, description="drop segments with fewer points")
    min_length_m: float = Field(0.5, ge=0, description="drop shorter segments")
    max_rms_m: float = Field(0.03, gt=0, description="drop segments whose points lie farther than this (rms) from their line")


@dataclass(frozen=True)
class ScanLines:
    """Line segments of one scan, in the sensor frame.

    Attributes:
        segments: (K, 4) ``x1, y1, x2, y2`` in metres; endpoint 1 is at the lower beam index.
        n_points: (K,) returns on each segment.
        rms: (K,) root-mean-square distance of those returns to the segment's line (metres).
        first, last: (K,) index (into the points given to :func:`extract_lines`) of the first and last
            return of each segment; its returns are ``first..last`` minus those cropped by range.
    """

    segments: np.ndarray
    n_points: np.ndarray
    rms: np.ndarray
    first: np.ndarray
    last: np.ndarray

    def __len__(self) -> int:
        return len(self.segments)

    @staticmethod
    def empty() -> "ScanLines":
        i = np.zeros(0, np.int64)
        return ScanLines(np.zeros((0, 4)), i, np.zeros(0), i, i)


def breakpoints(points: np.ndarray, config: Lines2DConfig) -> np.ndarray:
    """(N - 1,) True where the run breaks between return ``i`` and ``i + 1`` of (N, 2) ordered points."""
    if len(points) < 2:
        return np.zeros(0, dtype=bool)
    r = np.hypot(points[:, 0], points[:, 1])
    phi = np.arctan2(points[:, 1], points[:, 0])
    dphi = np.abs(np.diff(phi))
    dphi = np.minimum(dphi, 2 * np.pi - dphi)
    gap = np.hypot(*np.diff(points, axis=0).T)
    lam = np.deg2rad(config.breakpoint_lambda_deg)
    with np.errstate(divide="ignore", invalid="ignore"):
        adaptive = np.minimum(r[:-1], r[1:]) * np.sin(dphi) / np.sin(lam - dphi) + 3 * config.range_sigma_m
    adaptive = np.where(dphi < lam, adaptive, 0.0)
    threshold = np.clip(adaptive, config.jump_min_m, config.jump_max_m)
    return gap > threshold


def _tls(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Total-least-squares line of (k, 2) points: (centroid (2,), unit direction (2,), distances (k,))."""
    centroid = points.mean(axis=0)
    centred = points - centroid
    sxx, syy, sxy = (centred[:, 0] ** 2).sum(), (centred[:, 1] ** 2).sum(), (centred[:, 0] * centred[:, 1]).sum()
    theta = 0.5 * np.arctan2(2 * sxy, sxx - syy)
    direction = np.array([np.cos(theta), np.sin(theta)])
    dist = np.abs(centred[:, 0] * direction[1] - centred[:, 1] * direction[0])
    return centroid, direction, dist


def _split(points: np.ndarray, start: int, stop: int, threshold: float, min_points: int, out: list) -> None:
    """Iterative end-point fit of ``points[start:stop]``: append (start, stop) pieces to ``out``."""
    stack = [(start, stop)]
    pieces = []
    while stack:
        a, b = stack.pop()
        if b - a <= 2:
            pieces.append((a, b))
            continue
        p, q = points[a], points[b - 1]
        d = q - p
        norm = np.hypot(d[0], d[1])
        seg = points[a:b]
        if norm < 1e-9:
            dist = np.hypot(seg[:, 0] - p[0], seg[:, 1] - p[1])
        else:
            dist = np.abs((seg[:, 0] - p[0]) * d[1] - (seg[:, 1] - p[1]) * d[0]) / norm
        k = int(np.argmax(dist))
        if dist[k] <= threshold or k == 0 or k == b - a - 1:
            pieces.append((a, b))
            continue
        # The farthest point is the corner: it belongs to both sides; trimming later drops it
        # from the side it does not fit.
        stack.append((a + k, b))
        stack.append((a, a + k + 1))
    pieces.sort()
    out.extend(pieces)


def _merge(points: np.ndarray, pieces: list[tuple[int, int]], threshold: float) -> list[tuple[int, int]]:
    """Join neighbouring pieces of one run when a single TLS line fits all their points within ``threshold``."""
    merged: list[tuple[int, int]] = []
    for a, b in pieces:
        if merged:
            pa, pb = merged[-1]
            if b - pa >= 3:
                _, _, dist = _tls(points[pa:b])
                if dist.max() <= threshold:
                    merged[-1] = (pa, b)
                    continue
        merged.append((a, b))
    return merged


def _fit_piece(points: np.ndarray, a: int, b: int, threshold: float):
    """TLS fit of ``points[a:b]`` after trimming end points off the line; None if too few remain."""
    for _ in range(4):
        if b - a < 2:
            return None
        centroid, direction, dist = _tls(points[a:b])
        trimmed = False
        if b - a > 2 and dist[0] > threshold:
            a += 1
            trimmed = True
        if b - a > 2 and dist[-1] > threshold:
            b -= 1
            trimmed = True
        if not trimmed:
            break
    else:
        centroid, direction, dist = _tls(points[a:b])
    return a, b, centroid, direction, dist


def extract_lines(points, config: Lines2DConfig = Lines2DConfig()) -> ScanLines:
    """Line segments of one 2D scan.

    Args:
        points: (N, 2) returns in the sensor frame (metres), in beam order (no-returns removed).
        config: thresholds.
    Returns:
        ScanLines with (K, 4) segments in the sensor frame.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    r = np.hypot(pts[:, 0], pts[:, 1])
    keep = np.flatnonzero(np.isfinite(r) & (r >= config.min_range_m) & (r <= config.max_range_m))
    if len(keep) < config.min_points:
        return ScanLines.empty()
    kept = pts[keep]
    cuts = np.flatnonzero(breakpoints(kept, config)) + 1
    bounds = np.concatenate([[0], cuts, [len(kept)]])
    threshold = config.split_distance_m
    segments, n_points, rms, first, last = [], [], [], [], []
    for start, stop in zip(bounds[:-1], bounds[1:]):
        if stop - start < config.min_points:
            continue
        pieces: list[tuple[int, int]] = []
        _split(kept, int(start), int(stop), threshold, config.min_points, pieces)
        for a, b in _merge(kept, pieces, threshold):
            if b - a < config.min_points:
                continue
            fit = _fit_piece(kept, a, b, threshold)
            if fit is None:
                continue
            a, b, centroid, direction, dist = fit
            n = b - a
            piece_rms = float(np.sqrt(np.mean(dist ** 2)))
            t = (kept[a:b] - centroid) @ direction
            lo, hi = t.min(), t.max()
            if n < config.min_points or hi - lo < config.min_length_m or piece_rms > config.max_rms_m:
                continue
            if t[-1] < t[0]:                       # endpoint 1 at the lower beam index
                lo, hi = hi, lo
            segments.append(np.concatenate([centroid + lo * direction, centroid + hi * direction]))
            n_points.append(n)
            rms.append(piece_rms)
            first.append(keep[a])
            last.append(keep[b - 1])
    if not segments:
        return ScanLines.empty()
    return ScanLines(np.array(segments), np.array(n_points, dtype=np.int64), np.array(rms),
                     np.array(first, dtype=np.int64), np.array(last, dtype=np.int64))


def lines_to_world(segments: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Move (K, 4) sensor-frame segments to the world frame with the sensor pose ``x, y, theta`` (3,)."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return move_segments_2d(segments, np.array([[c, -s], [s, c]]), pose[:2])


def extract_lines_2d(points, config: Lines2DConfig = Lines2DConfig()) -> ScanSegments:
    """The registry's 2D extractor: :func:`extract_lines` as :class:`ScanSegments` (sensor frame), with
    every finite return of the scan as its support points (what the truth-free map metric scores against).

    Args:
        points: (N, 2) returns in the sensor frame, in beam order (no-returns removed).
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    lines = extract_lines(pts, config)
    return ScanSegments(segments=lines.segments, n_points=lines.n_points, rms=lines.rms,
                        support_points=pts[np.isfinite(pts).all(axis=1)])


EXTRACTOR = Extractor(name="lines_2d", dimension=2, config_type=Lines2DConfig, extract=extract_lines_2d, version=1)
