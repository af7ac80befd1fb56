"""Joint refinement of every scan's planar pose: segment-to-segment alignment in a sparse least-squares graph.

All corrections are solved at once (:mod:`featmap.refinement.terms` has the terms): Gauss-Newton with
iteratively re-weighted residuals on the sparse normal equations (``scipy.sparse.linalg.spsolve``).
Which scans are compared comes from :func:`featmap.refinement.matching.scan_pairs` (every time scale,
from the next scan to a revisit), recomputed at each gate; matches are found again before every
iteration, their distance gate shrinking over ``gates_m`` (coarse to fine), so large initial errors
are pulled in first and only close matches decide the final poses. Scans closer than
``keyframe_distance_m`` / ``keyframe_angle_deg`` to the previous keyframe are not solved but get
interpolated corrections. With ``loops.radius_m`` set (odometry poses), loop closures found by a wide
search after this first solve (:mod:`featmap.refinement.loops`) are closed on the priors alone and the
matching runs again from the gate that reaches them; that solution is kept only when the scans agree at
least as well as without the loops. Deterministic: no random draws.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from featmap.refinement.base import (RefinementInput, RefinementMethod, RefinementResult, apply_corrections,
                                     correct_segments, interpolate_corrections, keyframes)
from featmap.refinement.loops import LoopConfig, Loops, find_loops, loop_errors, loop_terms
from featmap.refinement.matching import Matches, MatchCandidates, scan_pairs, segment_matches
from featmap.refinement.terms import (KeyframeAlignmentConfig, consistency, keep_if_better, normal_equations,
                                     solve_normal_equations)


class PoseGraphConfig(KeyframeAlignmentConfig):
    """Joint segment-to-segment alignment of all scans with GPS/INS or odometry priors (world frame, metres)."""

    pair_radius_m: float = Field(40.0, gt=0, description="scans whose sensors were farther apart are not compared")
    tolerance_m: float = Field(1e-4, gt=0, description="stop when no scan moves more than this in an iteration at the finest gate")
    loops: LoopConfig = Field(default_factory=LoopConfig, description="loop closures by a wide search, then a second solve")


def refine_pose_graph(inp: RefinementInput, config: PoseGraphConfig = PoseGraphConfig()) -> RefinementResult:
    """Refined poses of every scan of ``inp`` (see the module doc): the keyframes are solved, the scans
    between them get interpolated corrections; nothing changes unless the scans then agree better."""
    if inp.n_scans == 0:
        return RefinementResult(np.zeros((0, 3)), inp.poses.copy(), stats={"applied": False})
    keys = keyframes(inp.poses, config.keyframe_distance_m, config.keyframe_angle_deg)
    sub = inp.subset(keys)
    candidates = MatchCandidates()           # the segment combinations worth testing, while the poses move little
    c, iterations, matches, converged, step = _solve(sub, config, np.zeros((sub.n_scans, 3)), Loops.empty(), candidates)
    loops = find_loops(sub, c, config.loops)
    found = len(loops)
    pairs = scan_pairs(sub.anchors, config.pair_radius_m)
    agreement = None                         # how well the scans agree with the chosen corrections, once measured
    if found:
        # close the loops on the priors alone first (matches made while they were open would hold them
        # open), then match again from the coarsest gate that reaches the most open of them; keep the
        # result only if the scans agree at least as well as without the loops (a wrong loop bends walls)
        widest = float(loop_errors(sub, c, loops).max())
        closed = _close_loops(sub, config, c, loops)
        gates = config.gates_m
        first = max([k for k, g in enumerate(gates) if g >= widest] or [0])
        closed, more, m_loops, conv_loops, step_loops = _solve(sub, config, closed, loops, candidates, gates[first:])
        with_loops = consistency(sub, closed, pairs, config, candidates)
        without = consistency(sub, c, pairs, config, candidates)
        if with_loops <= without:
            c, matches, converged, step = closed, m_loops, conv_loops, step_loops
            iterations += more
            agreement = with_loops
        else:
            loops = Loops.empty(loops.candidates)
            agreement = without
    applied, check = keep_if_better(sub, c, pairs, config, candidates, after=agreement)
    full = interpolate_corrections(inp.anchors, keys, c) if applied else np.zeros((inp.n_scans, 3))
    return RefinementResult(corrections=full, poses=apply_corrections(inp.poses, full), iterations=iterations,
                            matches=matches, converged=converged,
                            stats={"keyframes": int(len(keys)), **check, "last_step_m": step,
                                   "loops": int(len(loops)) if config.loops.radius_m is not None else None,
                                   "loops_found": found, "loop_candidates": loops.candidates})


def _close_loops(inp: RefinementInput, config: PoseGraphConfig, c: np.ndarray, loops: Loops,
                 iterations: int = 3) -> np.ndarray:
    """Corrections (F, 3) that close ``loops`` against the priors only (no segment matching), from ``c``."""
    for _ in range(iterations):
        H, g = normal_equations(inp, c, Matches.empty(), config.gates_m[0], config)
        H_loop, g_loop = loop_terms(inp, c, loops, config.loops)
        c = c + solve_normal_equations(H + H_loop, g + g_loop)
    return c


def _solve(inp: RefinementInput, config: PoseGraphConfig, c: np.ndarray, loops: Loops,
           candidates: MatchCandidates | None = None, gates=None):
    c = c.copy()
    order = np.argsort(inp.scan, kind="stable")
    seg0, scan = inp.segments[order], inp.scan[order]
    anchors0 = inp.anchors
    iterations, matches, converged, step = 0, 0, False, float("inf")
    gates = config.gates_m if gates is None else gates
    for round_, gate in enumerate(gates):
        pairs = scan_pairs(anchors0 + c[:, :2], config.pair_radius_m)
        for _ in range(config.iterations_per_gate):
            current = correct_segments(seg0, scan, anchors0, c)
            m = segment_matches(current, scan, pairs, gate, config.angle_deg, config.margin_m, config.min_overlap_m,
                                candidates=candidates)
            H, g = normal_equations(inp, c, m, gate, config)
            if len(loops):
                H_loop, g_loop = loop_terms(inp, c, loops, config.loops)
                H, g = H + H_loop, g + g_loop
            dc = solve_normal_equations(H, g)
            c = c + dc
            iterations += 1
            matches = m.n_pairs
            # how far any point within a quarter of the pair radius moved
            step = float(np.max(np.hypot(dc[:, 0], dc[:, 1]) + np.abs(dc[:, 2]) * config.pair_radius_m / 4))
            if round_ == len(gates) - 1 and step < config.tolerance_m:
                converged = True
                break
    return c, iterations, matches, converged, step


METHOD = RefinementMethod(name="pose_graph", title="joint segment alignment (pose graph)", config_type=PoseGraphConfig,
                          refine=refine_pose_graph)
