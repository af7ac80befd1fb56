"""Rigid alignment of several drives' maps before they are fused into one (a batch's merged map).

Each drive's poses are refined on their own (:mod:`featmap.refinement.pose_graph`), so two drives of the
same streets can disagree as a whole: GPS/INS of different days, or stretches of one indoor log, each
refined from its own first scan. Where they overlap, a wall then comes out twice, once per drive.
:func:`align_drives` finds one planar correction ``(dx, dy, dyaw)`` per drive (turning about the centre
of its map, :mod:`featmap.refinement.base`) that makes the drives' maps agree: the same segment-to-segment
least squares as the scan alignment (matches of near-parallel overlapping segments, Cauchy-weighted
point-to-line residuals, gates shrinking from coarse to fine), with one unknown per drive instead of one
per scan. The first drive holds the merged frame (it stays put); every other drive has a prior of
``prior_sigma_m`` / ``prior_sigma_deg`` towards where it is, and moves only along the directions the
matches observe: a drive that overlaps the others only along one street moves only across it. The
corrections are kept only when the length of the drives' maps that agrees within the finest gate grows
``min_improvement`` times: at the coarse gates a corridor's two walls, or a wall and a cabinet, can
match, and a drive pulled onto the wrong one agrees less, not more, at the finest. Only the rigid part
of the disagreement is corrected: what differs inside a drive stays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydantic import Field
from scipy import sparse

from featmap.config import Section
from featmap.refinement.base import correct_points, correct_segments
from featmap.refinement.matching import MatchCandidates, segment_matches
from featmap.refinement.terms import (FIXED_SIGMA, LEVER_M, AlignmentConfig, Gates, correction_size,
                                     match_normal_equations, solve_normal_equations)

OBSERVED = 1e-4
"""A direction of the drives' corrections is observed when the matches' information along it is at least this
fraction of the best observed one's (translations in metres, rotations as metres at ``LEVER_M``)."""
ROBUST_GATE_FRACTION = 0.3
"""The Cauchy kernel's scale is at least this fraction of the round's gate: drives metres apart are pulled in."""


class DriveAlignmentConfig(Section):
    """Rigid alignment of the drives of a batch before their merged map is fused (world frame, metres)."""

    enabled: bool = Field(True, description="align each drive's map to the others before fusing them together")
    gates_m: Gates = Field([2.0, 1.0, 0.5, 0.25, 0.12], min_length=1, description="match distance gate of each round, coarse to fine")
    iterations_per_gate: int = Field(3, ge=1, description="Gauss-Newton iterations (each re-matching) per gate")
    angle_deg: float = Field(5.0, gt=0, lt=90, description="matched features are within this angle of parallel")
    min_overlap_m: float = Field(1.0, gt=0, description="shorter overlaps are not matched")
    prior_sigma_m: float = Field(2.0, gt=0, description="how far a drive's map may be off as a whole (the first drive stays put)")
    prior_sigma_deg: float = Field(2.0, gt=0, description="... and turned")
    min_improvement: float = Field(1.5, ge=1, description="keep the drives as they are unless this many times more of their maps then agree within the finest gate ...")
    min_correction_m: float = Field(0.03, ge=0, description="... and some drive moves by at least this (a point 10 m from its map's centre)")


@dataclass(frozen=True)
class DriveAlignment:
    """What :func:`align_drives` found.

    Attributes:
        corrections: (D, 3) ``dx, dy`` (metres) and ``dyaw`` (radians) per drive; zero when not applied.
        anchors: (D, 2) the points each drive turns about (the centre of its map's segments).
        applied: whether the corrections are to be applied.
        stats: numbers for the record (matches; metres of the maps agreeing within the finest gate before
            and after; the largest correction).
    """

    corrections: np.ndarray
    anchors: np.ndarray
    applied: bool
    stats: dict

    def segments(self, segments: np.ndarray, drive: np.ndarray) -> np.ndarray:
        """(N, 4) world segments of the drives ``drive`` (N,) moved by their drives' corrections (the
        segments of a drive that does not move are returned exactly as they are)."""
        segments = np.array(segments, float).reshape(-1, 4)
        drive = np.asarray(drive, np.int64)
        moving = self.corrections.any(axis=1)[drive]
        segments[moving] = correct_segments(segments[moving], drive[moving], self.anchors, self.corrections)
        return segments

    def points(self, points: np.ndarray, drive: int) -> np.ndarray:
        """(P, 2) world points of drive ``drive`` moved by its correction."""
        points = np.asarray(points, float).reshape(-1, 2)
        if not self.corrections[drive].any():
            return points
        return correct_points(points, np.full(len(points), drive), self.anchors, self.corrections)


def align_drives(maps: list[np.ndarray], config: DriveAlignmentConfig = DriveAlignmentConfig()) -> DriveAlignment:
    """One rigid planar correction per drive that makes the drives' maps agree (see the module doc).

    Args:
        maps: per drive, its (K_d, 4) map segments in the common world frame (e.g. its fused features).
    """
    segments = np.concatenate([np.asarray(m, float).reshape(-1, 4) for m in maps]) if maps else np.zeros((0, 4))
    drive = np.repeat(np.arange(len(maps)), [len(np.asarray(m).reshape(-1, 4)) for m in maps])
    anchors = np.zeros((len(maps), 2))
    for d in range(len(maps)):
        own = segments[drive == d]
        if len(own):
            anchors[d] = 0.5 * (own[:, :2] + own[:, 2:]).mean(axis=0)
    zero = DriveAlignment(np.zeros((len(maps), 3)), anchors, False, {"applied": False, "matches": 0})
    if len(maps) < 2 or not len(segments):
        return zero
    match = AlignmentConfig(gates_m=config.gates_m, angle_deg=config.angle_deg, min_overlap_m=config.min_overlap_m,
                            robust_gate_fraction=ROBUST_GATE_FRACTION, min_improvement=config.min_improvement,
                            min_correction_m=config.min_correction_m)
    pairs = np.array([(i, j) for i in range(len(maps)) for j in range(i + 1, len(maps))], np.int64)
    prior = np.tile([1 / config.prior_sigma_m ** 2, 1 / config.prior_sigma_m ** 2,
                     1 / np.deg2rad(config.prior_sigma_deg) ** 2], len(maps))
    prior[:3] = 1 / FIXED_SIGMA ** 2                       # the first drive holds the merged frame
    candidates = MatchCandidates()
    c = np.zeros((len(maps), 3))
    matches = 0
    for gate in config.gates_m:
        for _ in range(config.iterations_per_gate):
            current = correct_segments(segments, drive, anchors, c)
            m = segment_matches(current, drive, pairs, gate, match.angle_deg, match.margin_m, match.min_overlap_m,
                                candidates=candidates)
            matches = m.n_pairs
            if not len(m):
                continue
            scale = max(match.robust_scale_m, match.robust_gate_fraction * gate)
            H_match, g_match = match_normal_equations(m, anchors + c[:, :2], match, scale, len(maps))
            step = solve_normal_equations(H_match + sparse.diags(prior), g_match + prior * c.ravel())
            c = c + _observed(step, H_match)
            c[0] = 0.0
    fine = config.gates_m[-1]
    before = _agreeing_length(segments, drive, anchors, np.zeros_like(c), pairs, fine, match)
    after = _agreeing_length(segments, drive, anchors, c, pairs, fine, match)
    largest = float(correction_size(c).max())
    applied = bool(after >= config.min_improvement * max(before, 1e-9) and largest >= config.min_correction_m)
    stats = {"applied": applied, "matches": int(matches), "agreeing_before_m": round(before, 2),
             "agreeing_after_m": round(after, 2), "largest_correction_m": round(largest, 4)}
    return DriveAlignment(c if applied else np.zeros_like(c), anchors, applied, stats)


def _observed(step: np.ndarray, H_match: sparse.spmatrix) -> np.ndarray:
    """``step`` (D, 3) without its part along directions the matches do not observe (the first drive,
    which holds the frame, left out): walls all along one street say nothing of a slide along it, and
    noise on them must not decide it. Rotations count as the motion ``LEVER_M`` from the map's centre."""
    scale = np.tile([1.0, 1.0, 1.0 / LEVER_M], len(step))[3:]
    H = H_match.toarray()[3:, 3:] * np.outer(scale, scale)
    w, V = np.linalg.eigh(H)
    seen = V[:, w > OBSERVED * max(float(w.max()), 1e-300)]
    z = step.ravel()[3:] / scale
    out = step.copy()
    out[1:] = (seen @ (seen.T @ z) * scale).reshape(-1, 3)
    out[0] = 0.0
    return out


def _agreeing_length(segments: np.ndarray, drive: np.ndarray, anchors: np.ndarray, c: np.ndarray, pairs: np.ndarray,
                     gate: float, match: AlignmentConfig) -> float:
    """Metres of the drives' maps that lie on another drive's map within ``gate`` after corrections ``c``
    (overlaps counted from both sides): how much of them agrees, at the finest gate."""
    current = correct_segments(segments, drive, anchors, c)
    m = segment_matches(current, drive, pairs, gate, match.angle_deg, match.margin_m, match.min_overlap_m)
    return float(m.weight.sum())
