"""Causal pose refinement for online mapping (``featmap run --online N``): a fixed-lag smoother that
decides each scan's correction once ``lag_scans`` newer scans have come.

The offline methods see the whole drive; here scans come one at a time (:meth:`FixedLagRefiner.add_scan`).
Every ``solve_every`` scans the smoother solves the scans of its *problem* jointly, with the terms of
:mod:`featmap.refinement.terms` (segment matching, the absolute prior, the motion prior), and every scan
more than ``lag_scans`` behind the newest is *decided*: its current estimate becomes its final
correction, and its segments can go into the map. The problem keeps the newest ``lag_scans +
solve_every + context_scans`` scans after each solve; the older ones are *marginalised*: every term that
involves them (their priors, the motion prior to the next scan, their matches, the marginal they
carried) is folded into a Gaussian prior on the scans that stay (a Schur complement at the current
estimate). So what the old scans said about where the map lies in the world is kept, and a solve costs
the same on the first kilometre and the hundredth. (Holding the decided scans fixed instead keeps the
map self-consistent but lets it turn with the first scans' heading error.)

Only scans near in time are compared, so a revisit minutes later is not tied in (no loop closure online;
the offline ``pose_graph`` does that). A decision uses the information so far: a scan decided early in
a drive with a weak absolute prior may sit a few centimetres from where a later decision would put it.

As offline, a solve is kept only when it makes its scans agree ``min_improvement`` times better than the
input poses do and moves some scan by ``min_correction_m`` (the test of
:func:`featmap.refinement.terms.keep_if_better`); otherwise the scans decided until the next solve keep
their input poses, and the next solve starts from the poses as decided. So scans whose poses already
agree (exact poses) keep them exactly.

:func:`refine_fixed_lag` feeds a whole drive to the smoother in time order: the registry's
``refinement.method: fixed_lag`` gives offline exactly what the online mapper gets. Numpy in, numpy out;
world frame, metres and radians.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field, model_validator
from threadpoolctl import threadpool_limits

from featmap.refinement.base import (RefinementInput, RefinementMethod, RefinementResult, apply_corrections,
                                     correct_segments)
from featmap.refinement.matching import Matches, MatchCandidates, scan_pairs, segment_matches
from featmap.refinement.terms import (FIXED_SIGMA, AlignmentConfig, Gates, consistency, correction_size,
                                     normal_equations)

WINDOW_DAMPING = 1e-9
"""Added to the normal equations' diagonal (keeps a scan that nothing constrains where it is)."""
CANDIDATE_SLACK_M = 3.0
"""Reach added to the segment combinations one solve keeps testing (metres; the matches are the same, see
:class:`~featmap.refinement.matching.MatchCandidates`): a solve moves far segments by more than the
default 0.5 m allows (0.3 deg moves a wall 50 m away by 0.26 m), and each rebuild costs as much as a
matching. On the pose-noise drive of docs/online.md 3 m leaves one build per solve (0.5 m: three)."""
UNCONSTRAINED = 1e6
"""Standard deviation (metres, radians) standing for "no absolute prior" inside the smoother."""


class FixedLagConfig(AlignmentConfig):
    """Causal fixed-lag pose refinement for online mapping (world frame, metres; the terms of pose_graph)."""

    gates_m: Gates = Field([0.5, 0.12], min_length=1, description="match distance gate of each round, coarse to fine (each solve starts near its solution: the older scans are solved, and a new scan starts from the last one's correction)")
    iterations_per_gate: int = Field(1, ge=1, description="Gauss-Newton iterations (each re-matching) per gate")
    lag_scans: int = Field(40, ge=1, description="a scan's correction is decided once this many newer scans have come (the map lags this many scans behind)")
    solve_every: int = Field(10, ge=1, description="solve the problem after every this many new scans")
    context_scans: int = Field(20, ge=0, description="this many decided scans stay in the problem (matched to the newer ones) before they are marginalised")
    pair_radius_m: float = Field(40.0, gt=0, description="scans whose sensors were farther apart are not compared")

    @model_validator(mode="after")
    def _solved_before_decided(self):
        if self.lag_scans < self.solve_every:
            raise ValueError(f"lag_scans ({self.lag_scans}) must be at least solve_every ({self.solve_every}): "
                             "otherwise scans are decided before any solve has seen them")
        return self


class FixedLagRefiner:
    """The smoother's state between scans; see the module docstring.

    The problem solved holds the newest scans (``lag_scans + solve_every + context_scans`` after each solve,
    ``solve_every`` more before the next); the scans that leave it are *marginalised*: every term that
    involves them (their priors, the motion prior to the next scan, their matches, the earlier marginal)
    is folded into a Gaussian prior on the scans that stay (a Schur complement), so what they told about
    the map's place in the world is kept while the cost of a solve stays bounded.

    Args:
        config: its settings (a ``FixedLagConfig``; the slam prior already applied if wanted).
    """

    def __init__(self, config: FixedLagConfig = FixedLagConfig()):
        self.config = config
        # Odometry (no absolute prior): only the drive's first scan is held, not the first of each problem.
        self._terms_config = config.model_copy(update={
            "absolute_sigma_m": config.absolute_sigma_m or UNCONSTRAINED,
            "absolute_sigma_deg": config.absolute_sigma_deg or np.rad2deg(UNCONSTRAINED)})
        self._hold_first = [k for k, sigma in enumerate((config.absolute_sigma_m, config.absolute_sigma_m,
                                                         config.absolute_sigma_deg)) if sigma is None]
        self._segments: list[np.ndarray] = []        # per scan: (K, 4) world segments under the input pose
        self._poses: list[np.ndarray] = []           # per scan: (4, 4) input T_world_sensor
        self._stamps: list[float] = []
        self._estimate = np.zeros((0, 3))            # (n, 3) the latest estimate of every scan's correction
        self._c = np.zeros((0, 3))                   # (n, 3) output corrections: final for the decided scans
        self._applied = False                        # whether the latest solve was kept
        self.first = 0                               # scans before this have left the problem (marginalised)
        self._prior: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None   # (H, g, at) on scans first..
        self.decided = 0                             # scans 0 .. decided-1 are final
        self.solves = 0                              # problems solved
        self.applied = 0                             # ... whose solution was kept
        self.matches = 0                             # segment pairs matched in the last solve
        self._agreements: list[tuple[float, float]] = []   # per solve: mean mismatch before, after (metres)
        self._solved_at = 0                          # how many scans there were at the last solve
        self._input_pairs: dict[tuple[int, int], tuple[float, int]] = {}   # scan pair -> (sum |residual|, count)

    def __len__(self) -> int:
        return len(self._poses)

    def stats(self) -> dict:
        """Numbers for the run's record: whether any solve was kept, how many were solved and kept, and the
        mean mismatch between matched segments with the input poses and after the solves (millimetres,
        averaged over the solves where both were measured)."""
        both = np.array([a for a in self._agreements if np.isfinite(a).all()]).reshape(-1, 2)
        before, after = (1000 * both.mean(axis=0)).round(3) if len(both) else (None, None)
        return {"applied": self.applied > 0, "solves": self.solves, "solves_applied": self.applied,
                "residual_before_mm": None if before is None else float(before),
                "residual_after_mm": None if after is None else float(after)}

    @property
    def corrections(self) -> np.ndarray:
        """(n, 3) corrections ``dx, dy, dyaw`` of every scan so far: final for the decided ones, the latest
        estimate (when kept) for the others."""
        out = self._c.copy()
        out[self.decided:] = self._estimate[self.decided:] if self._applied else 0.0
        return out

    def add_scan(self, segments: np.ndarray, pose: np.ndarray, timestamp: float | None = None) -> list[int]:
        """Take the next scan: its (K, 4) world-frame segments under its input pose (4, 4) and its time
        (seconds; None: 1 s after the previous scan). Returns the positions (0-based, in the order added)
        of the scans decided now (their corrections are final: :meth:`decided_segments`)."""
        segments = np.asarray(segments, float).reshape(-1, 4)
        pose = np.asarray(pose, float).reshape(4, 4)
        if timestamp is None:
            timestamp = self._stamps[-1] + 1.0 if self._stamps else 0.0
        self._segments.append(segments)
        self._poses.append(pose)
        self._stamps.append(float(timestamp))
        # a new scan starts from the estimate of the scan before it (the error of a GPS/INS drifts)
        start = self._estimate[-1:] if len(self._estimate) else np.zeros((1, 3))
        self._estimate = np.vstack([self._estimate, start])
        self._c = np.vstack([self._c, np.zeros((1, 3))])
        if len(self) % self.config.solve_every == 0:
            self._solve()
        return self._decide(len(self) - self.config.lag_scans)

    def finish(self) -> list[int]:
        """Decide every scan left (the end of the drive): solve once more, then fix them all."""
        if self.decided < len(self) and self._solved_at != len(self):
            self._solve()
        return self._decide(len(self))

    def decided_segments(self, position: int) -> np.ndarray:
        """(K, 4) world segments of the decided scan at ``position``, moved by its correction."""
        if position >= self.decided:
            raise ValueError(f"scan {position} is not decided yet ({self.decided} are)")
        seg = self._segments[position]
        anchor = self._poses[position][None, :2, 3]
        return correct_segments(seg, np.zeros(len(seg), np.int64), anchor, self._c[position:position + 1])

    def decided_pose(self, position: int) -> np.ndarray:
        """(4, 4) the refined ``T_world_sensor`` of the decided scan at ``position``."""
        if position >= self.decided:
            raise ValueError(f"scan {position} is not decided yet ({self.decided} are)")
        return apply_corrections(self._poses[position][None], self._c[position:position + 1])[0]

    def _decide(self, upto: int) -> list[int]:
        upto = min(upto, len(self))
        if upto <= self.decided:
            return []
        newly = list(range(self.decided, upto))
        self._c[newly] = self._estimate[newly] if self._applied else 0.0
        self.decided = upto
        return newly

    def _input(self, first: int) -> RefinementInput:
        n = len(self)
        return RefinementInput(np.concatenate(self._segments[first:]) if n > first else np.zeros((0, 4)),
                               np.repeat(np.arange(n - first), [len(s) for s in self._segments[first:]]),
                               np.array(self._poses[first:]), np.array(self._stamps[first:]))

    def _terms(self, inp: RefinementInput, c: np.ndarray, m: Matches, gate: float, first: int,
               prior: bool = True, time_steps: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Dense (H, g) of every term over the scans ``first..`` of ``inp`` at ``c`` (see terms.py), with
        the marginal prior (``prior``) and, for the drive's first scan without an absolute prior, its hold."""
        H, g = normal_equations(inp, c, m, gate, self._terms_config, time_steps)
        H = H.toarray()
        if self._hold_first and first == 0:
            held = self._hold_first
            H[held, held] += 1.0 / FIXED_SIGMA ** 2
            g[held] += c[0, held] / FIXED_SIGMA ** 2
        if prior and self._prior is not None:
            Hp, gp, at = self._prior
            k = 3 * len(at)
            H[:k, :k] += Hp
            g[:k] += gp + Hp @ (c[:len(at)] - at).ravel()
        return H, g

    def _input_agreement(self, inp: RefinementInput, pairs: np.ndarray, first: int) -> float:
        """:func:`~featmap.refinement.terms.consistency` of the input poses over ``pairs`` (local to ``inp``,
        whose scan 0 is ``first``): a pair's matches at the input poses never change, so each pair is
        matched once and remembered (until both its scans have left the problem)."""
        cfg = self.config
        keys = [(first + int(i), first + int(j)) for i, j in pairs]
        new = [k for k, key in enumerate(keys) if key not in self._input_pairs]
        if new:
            order = np.argsort(inp.scan, kind="stable")
            m = segment_matches(inp.segments[order], inp.scan[order], pairs[new], cfg.gates_m[0], cfg.angle_deg,
                                cfg.margin_m, cfg.min_overlap_m)
            n = inp.n_scans
            code, inverse = np.unique(np.minimum(m.source, m.target) * n + np.maximum(m.source, m.target),
                                      return_inverse=True)
            total = np.bincount(inverse, np.abs(m.residuals()), len(code))
            count = np.bincount(inverse, minlength=len(code))
            found = {(first + int(c // n), first + int(c % n)): (float(t), int(k)) for c, t, k in zip(code, total, count)}
            for k in new:
                self._input_pairs[keys[k]] = found.get(keys[k], (0.0, 0))
        total = sum(self._input_pairs[key][0] for key in keys)
        count = sum(self._input_pairs[key][1] for key in keys)
        for key in [key for key in self._input_pairs if key[1] < first]:   # both scans have left the problem
            del self._input_pairs[key]
        return total / count if count else float("nan")

    def _solve(self) -> None:
        """Solve the scans of the problem jointly, keep the solution if it helps, then marginalise the
        scans that leave the problem. On one BLAS thread: the systems are small (3 x the scans), and the
        results are then the same bits whatever the caller's thread settings (online and offline agree)."""
        with threadpool_limits(1, user_api="blas"):
            self._solve_problem()

    def _solve_problem(self) -> None:
        cfg = self.config
        first, n = self.first, len(self)
        inp = self._input(first)
        F = n - first
        c = self._estimate[first:].copy()
        order = np.argsort(inp.scan, kind="stable")
        seg0, scan = inp.segments[order], inp.scan[order]
        pairs = scan_pairs(inp.anchors + c[:, :2], cfg.pair_radius_m)
        m = Matches.empty()
        candidates = MatchCandidates(slack_m=CANDIDATE_SLACK_M)   # the combinations worth testing this solve
        for gate in cfg.gates_m:
            for _ in range(cfg.iterations_per_gate):
                current = correct_segments(seg0, scan, inp.anchors, c)
                m = segment_matches(current, scan, pairs, gate, cfg.angle_deg, cfg.margin_m, cfg.min_overlap_m,
                                    candidates=candidates)
                H, g = self._terms(inp, c, m, gate, first)
                c -= np.linalg.solve(H + np.eye(3 * F) * WINDOW_DAMPING, g).reshape(F, 3)
        self.matches = m.n_pairs
        # Keep the solution only when the scans agree better than with the input poses (exact poses stay).
        undecided = slice(self.decided - first, F)
        before = self._input_agreement(inp, pairs, first)
        after = consistency(inp, c, pairs, cfg, candidates)
        largest = float(correction_size(c[undecided]).max()) if F > self.decided - first else 0.0
        self._applied = bool(np.isfinite(after) and before >= cfg.min_improvement * after
                             and largest >= cfg.min_correction_m)
        if not self._applied:
            # The scans decided until the next solve keep their input poses; so does the estimate the next
            # solve starts from (the decided scans stay where they were decided): no jump when it is kept.
            c = self._c[first:].copy()
        self._estimate[first:] = c
        self._solved_at = n
        self.solves += 1
        self.applied += int(self._applied)
        self._agreements.append((before, after))
        # Marginalise the oldest scans so that at most lag + solve_every + context scans stay.
        keep = cfg.lag_scans + cfg.solve_every + cfg.context_scans
        leave = F - keep
        if leave > 0:
            current = correct_segments(seg0, scan, inp.anchors, c)
            m = segment_matches(current, scan, pairs, cfg.gates_m[-1], cfg.angle_deg, cfg.margin_m, cfg.min_overlap_m,
                                candidates=candidates)
            self._marginalise(inp, c, m, leave, first)

    def _marginalise(self, inp: RefinementInput, c: np.ndarray, m: Matches, leave: int, first: int) -> None:
        """Fold every term that involves the ``leave`` oldest scans of the problem into a prior on the rest."""
        gate = self.config.gates_m[-1]
        H_all, g_all = self._terms(inp, c, m, gate, first)
        stay = np.flatnonzero((m.source >= leave) & (m.target >= leave))
        rest = Matches(m.point[stay], m.source[stay] - leave, m.target[stay] - leave, m.base[stay], m.normal[stay],
                       m.weight[stay], len(stay) // 2)
        H_rest, g_rest = self._terms(inp.subset(np.arange(leave, inp.n_scans)), c[leave:], rest, gate,
                                     first + leave, prior=False, time_steps=inp.time_steps()[leave:])
        k = 3 * leave
        H = H_all.copy()
        H[k:, k:] -= H_rest
        g = g_all.copy()
        g[k:] -= g_rest
        H_ee = H[:k, :k] + np.eye(k) * WINDOW_DAMPING
        solve = np.linalg.solve(H_ee, np.column_stack([H[:k, k:], g[:k]]))
        H_prior = H[k:, k:] - H[k:, :k] @ solve[:, :-1]
        g_prior = g[k:] - H[k:, :k] @ solve[:, -1]
        # Only the scans tied to the ones that leave carry the prior (the rest of it is zero).
        weight = np.abs(H_prior).reshape(-1, 3, H_prior.shape[1]).sum(axis=(1, 2))
        tied = np.flatnonzero(weight > 1e-12 * max(float(weight.max(initial=0.0)), 1e-300))
        span = int(tied.max()) + 1 if len(tied) else 0
        H_prior, g_prior = H_prior[:3 * span, :3 * span], g_prior[:3 * span]
        H_prior = 0.5 * (H_prior + H_prior.T)
        self._prior = (H_prior, g_prior, c[leave:leave + span].copy()) if span else None
        self.first = first + leave


def refine_fixed_lag(inp: RefinementInput, config: FixedLagConfig = FixedLagConfig()) -> RefinementResult:
    """The corrections :class:`FixedLagRefiner` decides for the scans of ``inp`` fed in time order."""
    refiner = FixedLagRefiner(config)
    order = np.argsort(inp.scan, kind="stable")
    bounds = np.searchsorted(inp.scan[order], np.arange(inp.n_scans + 1))
    stamps = inp.timestamps if inp.timestamps is not None else np.arange(inp.n_scans, dtype=float)
    for k in range(inp.n_scans):
        refiner.add_scan(inp.segments[order[bounds[k]:bounds[k + 1]]], inp.poses[k], float(stamps[k]))
    refiner.finish()
    c = refiner.corrections
    return RefinementResult(corrections=c, poses=apply_corrections(inp.poses, c), iterations=refiner.solves,
                            matches=refiner.matches, stats=refiner.stats())


METHOD = RefinementMethod(name="fixed_lag", title="causal fixed-lag smoothing (online)", config_type=FixedLagConfig,
                          refine=refine_fixed_lag)
