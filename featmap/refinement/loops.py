"""Loop closures found by a wide search: where the trajectory comes back, align the two local maps.

The pose graph's segment matching pulls scans together only when their walls already lie within its
first gate (a metre). Wheel odometry comes back to a place metres off, and along a corridor the walls
say nothing about the error along it. :func:`find_loops` looks, after a first solve, at keyframes that
are close again after travelling at least ``min_travel_m``: the segments seen around each (the keyframes
within ``window_m`` of travel) are sampled as points, one side's points turned by each candidate angle
and correlated over every shift up to ``search_m`` with a blurred raster of the other side (FFT), and the
best shift is kept only when it explains enough of the points (``min_score``) and no shift a metre or
more away explains nearly as much (``max_ambiguity``: a corridor, a row of identical doors). Each kept
loop is a relative-pose measurement between the two keyframes (:func:`loop_terms`), which the pose graph
adds to its terms: it closes them on its priors alone, then matches again (:mod:`featmap.refinement.pose_graph`).
A keyframe whose local maps already agree (the best unturned shift within ``CLOSED_M``) is left to the
matching.

All positions in the world frame of the current poses; angles in radians.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
from pydantic import Field
from scipy import sparse
from scipy.ndimage import gaussian_filter

from featmap.config import Section
from featmap.geometry import dense_samples
from featmap.refinement.base import RefinementInput, correct_segments

CELL_M = 0.2
"""Raster cell of the correlation (metres)."""
BLUR_CELLS = 1.0
"""Standard deviation of the blur of the target raster (cells): a point scores by how close it is to a wall."""
SAMPLE_M = 0.1
"""Segments are sampled as points this far apart (metres)."""
CROP_M = 12.0
"""A keyframe's local map keeps the walls this close to it (metres)."""
CLOSED_M = 0.4
"""A candidate whose local maps already agree within this shift (unturned) is left to the matching (metres)."""
SEPARATION_M = 1.0
"""A second peak at least this far from the best is another explanation (metres)."""


class LoopConfig(Section):
    """Loop closures found by a wide search after a first solve (world frame, metres)."""

    radius_m: Optional[float] = Field(None, gt=0, description="look for loops between keyframes this close after a first solve; null = off")
    min_travel_m: float = Field(20.0, gt=0, description="... reached again after travelling at least this far")
    every: int = Field(5, ge=1, description="... trying every this many keyframes")
    window_m: float = Field(3.0, gt=0, description="the local map of a keyframe: segments of the keyframes within this much travel")
    search_m: float = Field(4.0, gt=0, description="search shifts up to this far ...")
    max_angle_deg: float = Field(6.0, ge=0, description="... and turns up to this much (1 deg steps)")
    min_score: float = Field(0.35, ge=0, le=1, description="keep a loop when the alignment explains at least this share of the points ...")
    max_ambiguity: float = Field(0.65, ge=0, le=1, description="... and no shift a metre away explains more than this fraction of that (corridors)")
    sigma_m: float = Field(0.05, gt=0, description="standard deviation of a loop's relative position")
    sigma_deg: float = Field(0.5, gt=0, description="standard deviation of a loop's relative heading")
    robust_m: float = Field(4.0, gt=0, description="Cauchy kernel scale of a loop's position error: a loop this far off counts half (loops metres open must pull; the checks above keep wrong ones out)")


@dataclass(frozen=True)
class Loops:
    """Relative-pose measurements between keyframes.

    Attributes:
        i, j: (L,) keyframe positions (``i < j``).
        delta: (L, 3) pose of ``j`` in the frame of ``i`` (x, y metres; yaw radians), as measured.
        score: (L,) share of ``i``'s points the alignment explains; ambiguity: (L,) second-best / best.
        candidates: how many pairs were tried.
    """

    i: np.ndarray
    j: np.ndarray
    delta: np.ndarray
    score: np.ndarray
    ambiguity: np.ndarray
    candidates: int = 0

    def __len__(self) -> int:
        return len(self.i)

    @staticmethod
    def empty(candidates: int = 0) -> "Loops":
        z = np.zeros(0)
        return Loops(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), z, z, candidates)


def candidate_pairs(positions: np.ndarray, radius_m: float, min_travel_m: float, every: int) -> np.ndarray:
    """(C, 2) keyframe pairs ``i < j``: for every ``every``-th keyframe ``i``, the nearest later keyframe
    within ``radius_m`` reached after travelling at least ``min_travel_m`` (positions (F, 2), time order)."""
    positions = np.asarray(positions, float).reshape(-1, 2)
    if len(positions) < 2:
        return np.zeros((0, 2), np.int64)
    travel = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(positions, axis=0).T))])
    out = []
    for i in range(0, len(positions), max(1, every)):
        later = np.flatnonzero(travel - travel[i] >= min_travel_m)
        if not len(later):
            break
        d = np.hypot(*(positions[later] - positions[i]).T)
        k = int(np.argmin(d))
        if d[k] <= radius_m:
            out.append((i, int(later[k])))
    return np.asarray(out, np.int64).reshape(-1, 2)


def _window_points(segments: np.ndarray, scan: np.ndarray, travel: np.ndarray, centre: int, window_m: float,
                   anchor: np.ndarray) -> np.ndarray:
    """(P, 2) points sampled along the segments of the keyframes within ``window_m`` of travel of ``centre``,
    at most ``CROP_M`` from ``anchor`` (2,)."""
    near = np.flatnonzero(np.abs(travel - travel[centre]) <= window_m)
    points, _ = dense_samples(segments[np.isin(scan, near)], SAMPLE_M)
    return points[np.hypot(*(points - anchor).T) <= CROP_M]


def align_points(source: np.ndarray, target: np.ndarray, pivot: np.ndarray, angles: np.ndarray,
                 search_m: float) -> tuple[float, np.ndarray, float, float]:
    """Best planar motion (turn by an angle of ``angles`` about ``pivot``, then shift by at most
    ``search_m``) that lays the (P, 2) ``source`` points on the (Q, 2) ``target`` points.

    Returns (angle, shift (2,), score = share of source points explained, ambiguity = best score at
    least ``SEPARATION_M`` away from the best shift over the best score).
    """
    pad = int(np.ceil(search_m / CELL_M)) + 2
    lo = target.min(axis=0) - pad * CELL_M
    shape = tuple((np.ceil((target.max(axis=0) + pad * CELL_M - lo) / CELL_M)).astype(int) + 1)
    idx = np.floor((target - lo) / CELL_M).astype(int)
    raster = np.bincount(idx[:, 0] * shape[1] + idx[:, 1], minlength=shape[0] * shape[1]).reshape(shape)
    field = gaussian_filter(np.minimum(raster, 1.0).astype(float), BLUR_CELLS)
    field /= max(float(field.max()), 1e-12)
    spectrum = np.conj(np.fft.rfft2(field))
    reach = int(np.floor(search_m / CELL_M))
    offsets = np.arange(-reach, reach + 1)
    gx, gy = np.meshgrid(offsets, offsets, indexing="ij")
    inside = np.hypot(gx, gy) <= reach
    best = (-1.0, 0.0, np.zeros(2), None)
    for angle in angles:
        c, s = np.cos(angle), np.sin(angle)
        rel = source - pivot
        moved = pivot + np.column_stack([c * rel[:, 0] - s * rel[:, 1], s * rel[:, 0] + c * rel[:, 1]])
        cell = np.floor((moved - lo) / CELL_M).astype(int)
        ok = (cell[:, 0] >= 0) & (cell[:, 0] < shape[0]) & (cell[:, 1] >= 0) & (cell[:, 1] < shape[1])
        hist = np.bincount(cell[ok, 0] * shape[1] + cell[ok, 1], minlength=shape[0] * shape[1]).reshape(shape)
        # corr[k] = sum_x hist[x + k] field[x] (circular; the padding keeps shifts within reach apart), so
        # the score of shifting the source by s, sum_x hist[x] field[x + s], is corr[-s]
        corr = np.fft.irfft2(np.fft.rfft2(hist) * spectrum, s=shape)
        window = corr[np.mod(-gx, shape[0]), np.mod(-gy, shape[1])]
        window = np.where(inside, window, -np.inf)
        k = np.unravel_index(int(np.argmax(window)), window.shape)
        if window[k] > best[0]:
            best = (float(window[k]), float(angle), np.array([gx[k], gy[k]]) * CELL_M, window)
    score, angle, shift, window = best
    if window is None or score <= 0:
        return 0.0, np.zeros(2), 0.0, 1.0
    far = np.hypot(gx * CELL_M - shift[0], gy * CELL_M - shift[1]) >= SEPARATION_M
    second = float(np.max(np.where(far, window, -np.inf))) if far.any() else 0.0
    return angle, shift, score / len(source), max(second, 0.0) / score


def find_loops(inp: RefinementInput, corrections: np.ndarray, config: LoopConfig) -> Loops:
    """Loop closures among the scans of ``inp`` placed with ``corrections`` (F, 3) (see the module doc)."""
    if config.radius_m is None:
        return Loops.empty()
    anchors = inp.anchors + corrections[:, :2]
    pairs = candidate_pairs(anchors, config.radius_m, config.min_travel_m, config.every)
    if not len(pairs):
        return Loops.empty()
    order = np.argsort(inp.scan, kind="stable")
    scan = inp.scan[order]
    segments = correct_segments(inp.segments[order], scan, inp.anchors, corrections)
    travel = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(anchors, axis=0).T))])
    yaw = inp.yaw + corrections[:, 2]
    step = np.deg2rad(1.0)
    angles = np.arange(-np.deg2rad(config.max_angle_deg), np.deg2rad(config.max_angle_deg) + step / 2, step)
    found = []
    for i, j in pairs:
        src = _window_points(segments, scan, travel, i, config.window_m, anchors[i])
        tgt = _window_points(segments, scan, travel, j, config.window_m, anchors[j])
        if len(src) < 50 or len(tgt) < 50:
            continue
        # a loop the first solve already closed (its best unturned shift is within CLOSED_M) needs no
        # search: the segment matching holds it
        _, shift, score, _ = align_points(src, tgt, anchors[i], np.zeros(1), config.search_m)
        if score >= config.min_score and np.hypot(*shift) <= CLOSED_M:
            continue
        angle, shift, score, ambiguity = align_points(src, tgt, anchors[i], angles, config.search_m)
        if score < config.min_score or ambiguity > config.max_ambiguity:
            continue
        # i's pose moved by the alignment: turned by angle about its own position, then shifted
        pi = anchors[i] + shift
        ti = yaw[i] + angle
        d = anchors[j] - pi
        c, s = np.cos(ti), np.sin(ti)
        delta = np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1], np.mod(yaw[j] - ti + np.pi, 2 * np.pi) - np.pi])
        found.append((i, j, delta, score, ambiguity))
    if not found:
        return Loops.empty(len(pairs))
    i, j, delta, score, ambiguity = zip(*found)
    return Loops(np.array(i, np.int64), np.array(j, np.int64), np.array(delta), np.array(score), np.array(ambiguity),
                 len(pairs))


def _loop_residuals(inp: RefinementInput, corrections: np.ndarray, loops: Loops):
    """Translation (L, 2) and heading (L,) residuals of the loops, the keyframes' offsets (L, 2) and cos, sin
    of the first keyframe's heading (L,) at ``corrections`` (F, 3)."""
    i, j = loops.i, loops.j
    p = inp.anchors + corrections[:, :2]
    th = inp.yaw + corrections[:, 2]
    v = p[j] - p[i]
    c, s = np.cos(th[i]), np.sin(th[i])
    rel = np.column_stack([c * v[:, 0] + s * v[:, 1], -s * v[:, 0] + c * v[:, 1]])
    r_th = np.mod(th[j] - th[i] - loops.delta[:, 2] + np.pi, 2 * np.pi) - np.pi
    return rel - loops.delta[:, :2], r_th, v, c, s


def loop_errors(inp: RefinementInput, corrections: np.ndarray, loops: Loops) -> np.ndarray:
    """(L,) how far (metres) each loop is from closed at ``corrections`` (F, 3)."""
    if not len(loops):
        return np.zeros(0)
    r_xy = _loop_residuals(inp, corrections, loops)[0]
    return np.hypot(r_xy[:, 0], r_xy[:, 1])


def loop_terms(inp: RefinementInput, corrections: np.ndarray, loops: Loops,
               config: LoopConfig) -> tuple[sparse.csc_matrix, np.ndarray]:
    """(H (3F, 3F), g (3F,)) of the loops' relative-pose residuals at ``corrections`` (F, 3), to add to
    the pose graph's normal equations (Cauchy kernel of scale ``robust_m`` on the translation error)."""
    sigma_m, sigma_deg, robust_m = config.sigma_m, config.sigma_deg, config.robust_m
    F = inp.n_scans
    if not len(loops):
        return sparse.csc_matrix((3 * F, 3 * F)), np.zeros(3 * F)
    i, j = loops.i, loops.j
    r_xy, r_th, v, c, s = _loop_residuals(inp, corrections, loops)
    L = len(i)
    rows, cols, vals = [], [], []
    for axis, (ax, ay) in enumerate(((c, s), (-s, c))):        # row axis of R(-theta_i)
        r = 3 * np.arange(L) + axis
        d_th = np.where(axis == 0, -s * v[:, 0] + c * v[:, 1], -c * v[:, 0] - s * v[:, 1])
        rows += [r] * 5
        cols += [3 * j, 3 * j + 1, 3 * i, 3 * i + 1, 3 * i + 2]
        vals += [ax, ay, -ax, -ay, d_th]
    r = 3 * np.arange(L) + 2
    rows += [r, r]
    cols += [3 * j + 2, 3 * i + 2]
    vals += [np.ones(L), -np.ones(L)]
    J = sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * L, 3 * F))
    res = np.column_stack([r_xy, r_th]).ravel()
    kernel = 1.0 / (1.0 + (np.hypot(r_xy[:, 0], r_xy[:, 1]) / robust_m) ** 2)
    w = (np.column_stack([np.full(L, sigma_m), np.full(L, sigma_m), np.full(L, np.deg2rad(sigma_deg))]) ** -2.0
         * kernel[:, None]).ravel()
    JtW = J.T.multiply(w).tocsr()
    return (JtW @ J).tocsc(), JtW @ res
