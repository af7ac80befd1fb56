"""The least-squares terms the alignment methods share, and the check that keeps a refinement only when it helps.

Unknowns: one correction ``c_i = (dx, dy, dyaw)`` per scan (:mod:`featmap.refinement.base`). Terms:

- **scan matching**: for every matched pair of segments of two scans (:mod:`featmap.refinement.matching`),
  the distance of one segment's overlapping part to the other's line, as two point-to-line residuals
  weighted by the overlap length over ``match_sigma_m**2`` and by a Cauchy kernel of scale
  ``robust_scale_m`` (at least ``robust_gate_fraction`` of the current gate): wrong matches, moving
  objects and clutter count little;
- **absolute prior** (GPS/INS): each correction itself, with standard deviations ``absolute_sigma_m`` and
  ``absolute_sigma_deg``: the map stays where the input poses put it on average. ``null`` turns it off
  (odometry: then the first scan is held fixed). When the input poses are a SLAM result
  (``RefinementInput.slam_poses``, e.g. a CARMEN ``*-corrected`` log), ``slam_absolute_sigma_m`` and
  ``slam_absolute_sigma_deg`` replace them where set (:func:`with_slam_prior`): such poses are already
  consistent to centimetres, so the map should stay where they put it;
- **motion prior**: the relative pose of consecutive scans stays what the input poses say. Its variance
  adds up along the way, like the error of the source of the poses: per second (GPS/INS drift,
  ``motion_sigma_m`` / ``motion_sigma_deg`` per sqrt(s)), per metre travelled and per degree turned
  (odometry, ``motion_sigma_*_per_sqrt_*``).

A refinement is kept only when the mean distance between matched segments of different scans shrinks by
at least ``min_improvement`` and some scan moves by at least ``min_correction_m`` (:func:`keep_if_better`):
scans that already agree (exact poses) are left exactly as they were.
"""

from __future__ import annotations

from typing import Annotated, Optional

import numpy as np
from pydantic import AfterValidator, Field
from scipy import sparse
from scipy.sparse.linalg import spsolve

from featmap.config import Section
from featmap.refinement.base import RefinementInput, correct_segments
from featmap.refinement.matching import Matches, MatchCandidates, segment_matches

FIXED_SIGMA = 1e-6
"""Standard deviation (metres, radians) that holds the first scan in place when there is no absolute prior."""


def _positive_gates(value: list[float]) -> list[float]:
    if any(not g > 0 for g in value):
        raise ValueError(f"every gate must be positive, got {value}")
    return value


Gates = Annotated[list[float], AfterValidator(_positive_gates)]
"""Match distance gates of the rounds of an alignment, coarse to fine (metres, each positive)."""


class AlignmentConfig(Section):
    """Settings shared by the alignment methods (world frame, metres)."""

    gates_m: Gates = Field([1.0, 0.5, 0.25, 0.12], min_length=1, description="match distance gate of each round, coarse to fine")
    iterations_per_gate: int = Field(2, ge=1, description="Gauss-Newton iterations (each re-matching) per gate")
    angle_deg: float = Field(5.0, gt=0, lt=90, description="matched segments are within this angle of parallel")
    margin_m: float = Field(0.5, ge=0, description="a segment may overlap another this far beyond its endpoints")
    min_overlap_m: float = Field(0.5, gt=0, description="shorter overlaps are not matched")
    match_sigma_m: float = Field(0.02, gt=0, description="point-to-line noise per metre of overlap")
    robust_scale_m: float = Field(0.05, gt=0, description="Cauchy kernel scale of the point-to-line residuals")
    robust_gate_fraction: float = Field(0.0, ge=0, description="... at least this fraction of the round's gate (wider kernels while the gates are wide)")
    absolute_sigma_m: Optional[float] = Field(0.5, gt=0, description="absolute (GPS/INS) position prior per scan; null = odometry poses, no absolute prior")
    absolute_sigma_deg: Optional[float] = Field(1.0, gt=0, description="absolute heading prior per scan; null = none")
    slam_absolute_sigma_m: Optional[float] = Field(None, gt=0, description="position prior instead of absolute_sigma_m when the source's poses are a SLAM result (a CARMEN *-corrected log); null = absolute_sigma_m")
    slam_absolute_sigma_deg: Optional[float] = Field(None, gt=0, description="heading prior instead of absolute_sigma_deg for such poses; null = absolute_sigma_deg")
    motion_sigma_m: float = Field(0.2, ge=0, description="relative motion prior between consecutive scans: metres per sqrt(second) (GPS/INS drift)")
    motion_sigma_deg: float = Field(0.3, ge=0, description="relative heading prior: degrees per sqrt(second)")
    motion_sigma_m_per_sqrt_m: float = Field(0.0, ge=0, description="relative motion prior: metres per sqrt(metre travelled) (odometry)")
    motion_sigma_deg_per_sqrt_m: float = Field(0.0, ge=0, description="relative heading prior: degrees per sqrt(metre travelled) (odometry)")
    motion_sigma_deg_per_sqrt_deg: float = Field(0.0, ge=0, description="relative heading prior: degrees per sqrt(degree turned) (odometry)")
    motion_floor_m: float = Field(0.001, gt=0, description="relative motion prior never tighter than this (metres)")
    motion_floor_deg: float = Field(0.01, gt=0, description="relative heading prior never tighter than this (degrees)")
    min_improvement: float = Field(1.5, ge=1, description="keep the input poses unless the mean distance between matched segments of different scans shrinks by at least this factor ...")
    min_correction_m: float = Field(0.03, ge=0, description="... and some scan moves by at least this (a point 10 m from its sensor)")


class KeyframeAlignmentConfig(AlignmentConfig):
    """The shared settings, for the methods that solve keyframes and interpolate the scans between them."""

    keyframe_distance_m: float = Field(0.3, ge=0, description="refine a scan once the sensor moved this far since the last refined one (others are interpolated)")
    keyframe_angle_deg: float = Field(10.0, ge=0, description="... or turned this much")


def with_slam_prior(config: AlignmentConfig, slam_poses: bool) -> AlignmentConfig:
    """``config`` with the ``slam_absolute_*`` priors as its absolute priors when the input poses are a
    SLAM result (``slam_poses``) and those are set; otherwise ``config`` itself."""
    if not slam_poses:
        return config
    update = {name: value for name, value in (("absolute_sigma_m", config.slam_absolute_sigma_m),
                                               ("absolute_sigma_deg", config.slam_absolute_sigma_deg))
              if value is not None}
    return config.model_copy(update=update) if update else config


def _perp(v: np.ndarray) -> np.ndarray:
    return np.column_stack([-v[:, 1], v[:, 0]])


def _match_rows(m: Matches, anchors: np.ndarray, config: AlignmentConfig, scale: float):
    """Residuals, weights and the (R, 6) Jacobian blocks (source dx, dy, dyaw, target dx, dy, dyaw)."""
    r = m.residuals()
    n = m.normal
    rel_src = m.point - anchors[m.source]
    rel_tgt = m.base - anchors[m.target]
    jac = np.empty((len(m), 6))
    jac[:, 0:2] = n
    jac[:, 2] = np.einsum("ij,ij->i", n, _perp(rel_src))
    jac[:, 3:5] = -n
    jac[:, 5] = np.einsum("ij,ij->i", _perp(n), m.point - m.base) - np.einsum("ij,ij->i", n, _perp(rel_tgt))
    kernel = 1.0 / (1.0 + (r / scale) ** 2)
    weight = m.weight / config.match_sigma_m ** 2 * kernel
    return r, weight, jac


def normal_equations(inp: RefinementInput, c: np.ndarray, m: Matches, gate: float,
                     config: AlignmentConfig, time_steps: np.ndarray | None = None) -> tuple[sparse.csc_matrix, np.ndarray]:
    """(H (3F, 3F), g (3F,)) of the problem linearised at corrections ``c`` (F, 3), with the matches ``m``
    found within ``gate``: the update ``dc`` solves ``H dc = -g`` (:func:`solve_normal_equations`).
    ``time_steps``: (F - 1,) seconds between the scans for the motion prior (default
    ``inp.time_steps()``; a part of a larger problem passes the larger problem's, whose floor for
    repeated timestamps may differ)."""
    F = inp.n_scans
    anchors = inp.anchors + c[:, :2]
    scale = max(config.robust_scale_m, config.robust_gate_fraction * gate)
    rows, cols, vals, res, wts = [], [], [], [], []
    n_rows = 0
    # Absolute prior, or the first scan held fixed.
    if config.absolute_sigma_m is not None or config.absolute_sigma_deg is not None:
        sig = np.array([config.absolute_sigma_m or np.inf, config.absolute_sigma_m or np.inf,
                        np.deg2rad(config.absolute_sigma_deg) if config.absolute_sigma_deg else np.inf])
        rows.append(n_rows + np.arange(3 * F))
        cols.append(np.arange(3 * F))
        vals.append(np.ones(3 * F))
        res.append(c.ravel())
        wts.append(np.tile(1.0 / sig ** 2, F))
        n_rows += 3 * F
    if config.absolute_sigma_m is None or config.absolute_sigma_deg is None:
        free = [k for k, s in enumerate((config.absolute_sigma_m, config.absolute_sigma_m, config.absolute_sigma_deg))
                if s is None]
        rows.append(n_rows + np.arange(len(free)))
        cols.append(np.array(free))
        vals.append(np.ones(len(free)))
        res.append(c[0, free])
        wts.append(np.full(len(free), 1.0 / FIXED_SIGMA ** 2))
        n_rows += len(free)
    # Motion prior between consecutive scans: C_k and C_k+1 should be the same planar motion.
    if F > 1:
        o = inp.anchors
        step = o[1:] - o[:-1]
        th = c[:-1, 2]
        cos, sin = np.cos(th), np.sin(th)
        turned = np.column_stack([cos * step[:, 0] - sin * step[:, 1], sin * step[:, 0] + cos * step[:, 1]])
        r_t = c[1:, :2] - c[:-1, :2] - (turned - step)
        r_th = c[1:, 2] - c[:-1, 2]
        dt2 = inp.time_steps() if time_steps is None else np.asarray(time_steps, float)
        k = np.arange(F - 1)
        base = n_rows + 3 * k
        d_turn = _perp(turned)                              # d(turned)/d(theta_k)
        for axis in range(2):
            # r_t[axis] = c[k+1, axis] - c[k, axis] - (turned - step)[axis]
            rows += [base + axis] * 3
            cols += [3 * (k + 1) + axis, 3 * k + axis, 3 * k + 2]
            vals += [np.ones(F - 1), -np.ones(F - 1), -d_turn[:, axis]]
        rows += [base + 2, base + 2]
        cols += [3 * (k + 1) + 2, 3 * k + 2]
        vals += [np.ones(F - 1), -np.ones(F - 1)]
        res.append(np.column_stack([r_t, r_th]).ravel())
        dist = np.hypot(step[:, 0], step[:, 1])
        turn = np.abs(np.mod(inp.yaw[1:] - inp.yaw[:-1] + np.pi, 2 * np.pi) - np.pi)
        # Variances add up along the way: each term grows with time, distance or turn (random walks).
        sig_t = np.sqrt(config.motion_sigma_m ** 2 * dt2 + config.motion_sigma_m_per_sqrt_m ** 2 * dist
                        + config.motion_floor_m ** 2)
        sig_th = np.deg2rad(np.sqrt(config.motion_sigma_deg ** 2 * dt2 + config.motion_sigma_deg_per_sqrt_m ** 2 * dist
                                    + config.motion_sigma_deg_per_sqrt_deg ** 2 * np.rad2deg(turn)
                                    + config.motion_floor_deg ** 2))
        sig = np.column_stack([sig_t, sig_t, sig_th])
        wts.append((1.0 / sig ** 2).ravel())
        n_rows += 3 * (F - 1)
    J = sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n_rows, 3 * F))
    r = np.concatenate(res)
    w = np.concatenate(wts)
    JtW = J.T.multiply(w).tocsr()
    H, g = JtW @ J, JtW @ r
    if len(m):                                              # scan matching
        H_match, g_match = match_normal_equations(m, anchors, config, scale, F)
        H, g = H + H_match, g + g_match
    return H.tocsc(), g


def match_normal_equations(m: Matches, anchors: np.ndarray, config: AlignmentConfig, scale: float,
                            F: int) -> tuple[sparse.csr_matrix, np.ndarray]:
    """The matches' share of (H (3F, 3F), g (3F,)): each residual's 6 x 6 outer product summed per (source,
    target) scan pair first (a few per scan instead of hundreds of thousands of rows)."""
    r, w, jac = _match_rows(m, anchors, config, scale)
    pair, inv = np.unique(m.source * F + m.target, return_inverse=True)
    n = len(pair)
    blocks = np.empty((n, 6, 6))
    for p in range(6):
        wj = w * jac[:, p]
        for q in range(p, 6):
            blocks[:, p, q] = blocks[:, q, p] = np.bincount(inv, wj * jac[:, q], n)
    grad = np.column_stack([np.bincount(inv, w * jac[:, p] * r, n) for p in range(6)])
    src, tgt = pair // F, pair % F
    idx = np.column_stack([3 * src + k for k in range(3)] + [3 * tgt + k for k in range(3)])   # (n, 6)
    H = sparse.csr_matrix((blocks.ravel(), (np.repeat(idx, 6, axis=1).ravel(), np.tile(idx, (1, 6)).ravel())),
                          shape=(3 * F, 3 * F))
    return H, np.bincount(idx.ravel(), grad.ravel(), 3 * F)


def consistency(inp: RefinementInput, corrections: np.ndarray, pairs: np.ndarray, config: AlignmentConfig,
                candidates: MatchCandidates | None = None) -> float:
    """Mean distance (metres) between matched segments of the scan ``pairs`` after ``corrections``
    (matches within the first gate; NaN when nothing matches): how well the scans agree with each other.
    ``candidates``: see :func:`featmap.refinement.matching.segment_matches`."""
    order = np.argsort(inp.scan, kind="stable")
    scan = inp.scan[order]
    current = correct_segments(inp.segments[order], scan, inp.anchors, corrections)
    m = segment_matches(current, scan, pairs, config.gates_m[0], config.angle_deg, config.margin_m, config.min_overlap_m,
                        candidates=candidates)
    return float(np.mean(np.abs(m.residuals()))) if len(m) else float("nan")


LEVER_M = 10.0
"""A correction's size is how far it moves a point this far from the sensor: ``|(dx, dy)| + LEVER_M * |dyaw|``."""


def correction_size(corrections: np.ndarray) -> np.ndarray:
    """(F,) how far each correction (F, 3) moves a point ``LEVER_M`` from its sensor, at most (metres)."""
    return np.hypot(corrections[:, 0], corrections[:, 1]) + LEVER_M * np.abs(corrections[:, 2])


def keep_if_better(inp: RefinementInput, corrections: np.ndarray, pairs: np.ndarray,
                   config: AlignmentConfig, candidates: MatchCandidates | None = None,
                   after: float | None = None) -> tuple[bool, dict]:
    """Whether to apply ``corrections``: only when they make the scans agree at least ``min_improvement``
    times better than the input poses, and move some scan by at least ``min_correction_m``. Otherwise the
    input poses are kept: exact poses stay exact, instead of absorbing extraction noise (scans that see a
    single wall can be made to agree perfectly by moving them a few mm) or extraction bias (the agreement
    barely improves while the poses wander). ``after``: the :func:`consistency` of ``corrections`` when the
    caller measured it already. Returns (apply, numbers for the record)."""
    before = consistency(inp, np.zeros_like(corrections), pairs, config, candidates)
    if after is None:                                   # (unless the caller measured it already)
        after = consistency(inp, corrections, pairs, config, candidates)
    largest = float(correction_size(corrections).max()) if len(corrections) else 0.0
    applied = bool(before >= config.min_improvement * after and largest >= config.min_correction_m)
    return applied, {"applied": applied, "residual_before_mm": round(1000 * before, 3),
                     "residual_after_mm": round(1000 * after, 3), "largest_correction_m": round(largest, 4)}


def solve_normal_equations(H: sparse.spmatrix, g: np.ndarray) -> np.ndarray:
    """``dc`` (F, 3) solving ``H dc = -g`` (a tiny diagonal keeps unobserved scans at zero)."""
    F = len(g) // 3
    H = H + sparse.identity(3 * F, format="csc") * 1e-9
    return spsolve(H.tocsc(), -g).reshape(F, 3)
