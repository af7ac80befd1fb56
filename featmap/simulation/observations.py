"""Per-scan observations from a scan's wall hits (the simulator writes them to ``truth/observations.npz``;
the format and its reader are in :mod:`featmap.io.sim_truth`).

Hits sorted along a wall are joined while the gap between neighbours is at most ``max(MIN_GAP_M,
GAP_FACTOR x`` the spacing the sensor's azimuth step gives at that range and incidence``)``; a longer gap is
something in front of the wall (a tree, a pole, a car, another building).
"""

from __future__ import annotations

import numpy as np

from featmap.io.sim_truth import GAP_FACTOR, MIN_GAP_M, ScanObservations


def observe_scan(frame: int, wall: np.ndarray, s: np.ndarray, spacing: np.ndarray,
                 gap_factor: float = GAP_FACTOR, min_gap_m: float = MIN_GAP_M) -> ScanObservations:
    """The observations of one scan from its wall hits.

    Args:
        frame: the scan's frame index.
        wall: (H,) wall index of each hit.
        s: (H,) position of each hit along its wall (metres).
        spacing: (H,) expected distance along the wall to the next firing of the same beam
            (range x azimuth step / cos(incidence)), which sets the largest gap that is not an occlusion.
    """
    wall = np.asarray(wall, np.int64)
    s = np.asarray(s, float)
    spacing = np.asarray(spacing, float)
    if len(wall) == 0:
        return ScanObservations.empty()
    order = np.lexsort((s, wall))
    wall, s, spacing = wall[order], s[order], spacing[order]
    new_wall = np.concatenate([[True], wall[1:] != wall[:-1]])
    allowed = np.maximum(min_gap_m, gap_factor * np.maximum(spacing[1:], spacing[:-1]))
    breaks = np.concatenate([[True], (np.diff(s) > allowed) | new_wall[1:]])
    run_start = np.flatnonzero(breaks)
    run_end = np.concatenate([run_start[1:], [len(s)]]) - 1
    wall_start = np.flatnonzero(new_wall)
    wall_end = np.concatenate([wall_start[1:], [len(s)]])
    runs_per_wall = np.add.reduceat(breaks.astype(np.int64), wall_start)
    iv_start, iv_end = s[run_start], s[run_end]
    observed = np.add.reduceat(iv_end - iv_start, np.concatenate([[0], np.cumsum(runs_per_wall)[:-1]]))
    return ScanObservations(
        frame=np.full(len(wall_start), frame, np.int64), wall=wall[wall_start],
        n_hits=(wall_end - wall_start).astype(np.int64), s_min=s[wall_start], s_max=s[wall_end - 1],
        observed_m=observed, interval_offset=np.concatenate([[0], np.cumsum(runs_per_wall)]).astype(np.int64),
        interval_start=iv_start, interval_end=iv_end)


def concatenate(parts: list[ScanObservations]) -> ScanObservations:
    """One :class:`ScanObservations` from several (e.g. one per scan), in the given order."""
    parts = [p for p in parts if len(p)]
    if not parts:
        return ScanObservations.empty()
    offsets, base = [np.zeros(1, np.int64)], 0
    for p in parts:
        offsets.append(p.interval_offset[1:] + base)
        base += int(p.interval_offset[-1])
    cat = lambda name: np.concatenate([getattr(p, name) for p in parts])  # noqa: E731
    return ScanObservations(cat("frame"), cat("wall"), cat("n_hits"), cat("s_min"), cat("s_max"), cat("observed_m"),
                            np.concatenate(offsets), cat("interval_start"), cat("interval_end"))


