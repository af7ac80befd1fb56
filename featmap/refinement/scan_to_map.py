"""Sliding-window scan-to-map alignment: each scan aligned on its own to the map of its neighbours.

The simpler alternative to :mod:`featmap.refinement.pose_graph`, with the same terms
(:mod:`featmap.refinement.terms`): every iteration moves each scan to fit the segments of the
``window_scans`` scans before and after it (their current poses held fixed) and its own priors, all
scans at once (block Jacobi, damped by ``damping`` so that neighbours moving towards each other do not
overshoot). It never solves the trajectory jointly, so errors that only the whole drive can resolve (a
slow drift along a straight street, a revisit minutes later) stay, and it needs more iterations.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from featmap.refinement.base import (RefinementInput, RefinementMethod, RefinementResult, apply_corrections,
                                     correct_segments, interpolate_corrections, keyframes)
from featmap.refinement.matching import segment_matches
from featmap.refinement.terms import KeyframeAlignmentConfig, keep_if_better, normal_equations


class ScanToMapConfig(KeyframeAlignmentConfig):
    """Sliding-window scan-to-map alignment, one scan at a time (world frame, metres)."""

    window_scans: int = Field(10, ge=1, description="each scan is aligned to this many scans before and after it")
    damping: float = Field(0.5, gt=0, le=1, description="fraction of each scan's own solution applied per iteration")
    iterations_per_gate: int = Field(6, ge=1, description="iterations (each re-matching) per gate")


def window_pairs(n: int, window: int) -> np.ndarray:
    """(P, 2) pairs ``i < j`` of ``n`` scans with ``j - i <= window``."""
    offsets = range(1, min(window, n - 1) + 1) if n > 1 else range(0)
    pairs = [np.column_stack([np.arange(n - o), np.arange(o, n)]) for o in offsets]
    return np.concatenate(pairs).astype(np.int64) if pairs else np.zeros((0, 2), np.int64)


def refine_scan_to_map(inp: RefinementInput, config: ScanToMapConfig = ScanToMapConfig()) -> RefinementResult:
    """Refined poses of every scan of ``inp`` (see the module doc)."""
    if inp.n_scans == 0:
        return RefinementResult(np.zeros((0, 3)), inp.poses.copy(), stats={"applied": False})
    keys = keyframes(inp.poses, config.keyframe_distance_m, config.keyframe_angle_deg)
    sub = inp.subset(keys)
    F = sub.n_scans
    c = np.zeros((F, 3))
    order = np.argsort(sub.scan, kind="stable")
    seg0, scan = sub.segments[order], sub.scan[order]
    pairs = window_pairs(F, config.window_scans)
    block = np.arange(3 * F) // 3
    iterations = matches = 0
    for gate in config.gates_m:
        for _ in range(config.iterations_per_gate):
            current = correct_segments(seg0, scan, sub.anchors, c)
            m = segment_matches(current, scan, pairs, gate, config.angle_deg, config.margin_m, config.min_overlap_m)
            H, g = normal_equations(sub, c, m, gate, config)
            H = H.tocoo()
            own = block[H.row] == block[H.col]             # each scan's own 3 x 3 block: neighbours held fixed
            blocks = np.zeros((F, 3, 3))
            np.add.at(blocks, (block[H.row[own]], H.row[own] % 3, H.col[own] % 3), H.data[own])
            blocks += np.eye(3) * 1e-9
            c = c - config.damping * np.linalg.solve(blocks, g.reshape(F, 3, 1))[:, :, 0]
            iterations += 1
            matches = m.n_pairs
    applied, check = keep_if_better(sub, c, pairs, config)
    full = interpolate_corrections(inp.anchors, keys, c) if applied else np.zeros((inp.n_scans, 3))
    return RefinementResult(corrections=full, poses=apply_corrections(inp.poses, full), iterations=iterations,
                            matches=matches, converged=True, stats={"keyframes": int(len(keys)), **check})


METHOD = RefinementMethod(name="scan_to_map", title="sliding-window scan-to-map alignment", config_type=ScanToMapConfig,
                          refine=refine_scan_to_map)
