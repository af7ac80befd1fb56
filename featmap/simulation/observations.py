"""Per-scan ground truth of what each scan saw of each building wall (``truth/observations.npz``).

An *observation* is one (scan, wall) pair with at least one return on the wall. For each the
simulator records the number of rays that hit the wall (after dropout and the sensor's range
limits, with no other range cap) and where along the wall they landed:

- ``s_min``, ``s_max``: the extreme hit positions along the wall (metres from its first vertex,
  in the direction of ``walls.csv``'s ``x1,y1 -> x2,y2``), so ``extent_m = s_max - s_min``;
- ``intervals``: the stretches actually seen. Hits sorted along the wall are joined while the gap
  between neighbours is at most ``max(MIN_GAP_M, GAP_FACTOR x`` the spacing the sensor's azimuth
  step gives at that range and incidence``)``; a longer gap is something in front of the wall
  (a tree, a pole, a car, another building). ``observed_m`` is their total length.

An observation *counts* (:meth:`ScanObservations.counting`) with at least :data:`MIN_HITS` hits and
:data:`MIN_OBSERVED_M` metres observed, the per-scan version of EVALUATION.md's observable wall.
Walls 50-100 m away count whenever they are sampled that densely: there is no fixed range cap.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from featmap.errors import InputFileError

MIN_HITS = 50
MIN_OBSERVED_M = 2.0
GAP_FACTOR = 2.5
MIN_GAP_M = 0.5
OBSERVATIONS_FILE = "observations.npz"


@dataclass(frozen=True)
class ScanObservations:
    """Observations of walls by scans (O observations, I intervals in total).

    Attributes:
        frame: (O,) frame (scan) index in the drive.
        wall: (O,) wall index (row of ``truth/walls.csv``, the order of ``building_edges``).
        n_hits: (O,) rays that hit the wall in that scan.
        s_min, s_max: (O,) extreme hit positions along the wall (metres).
        observed_m: (O,) total length of the observed intervals (metres).
        interval_offset: (O + 1,) observation o owns intervals ``interval_offset[o]:interval_offset[o + 1]``.
        interval_start, interval_end: (I,) observed stretches along the wall (metres).
    """

    frame: np.ndarray
    wall: np.ndarray
    n_hits: np.ndarray
    s_min: np.ndarray
    s_max: np.ndarray
    observed_m: np.ndarray
    interval_offset: np.ndarray
    interval_start: np.ndarray
    interval_end: np.ndarray

    def __len__(self) -> int:
        return len(self.frame)

    @property
    def extent_m(self) -> np.ndarray:
        """(O,) span between the extreme hits along the wall (metres), gaps included."""
        return self.s_max - self.s_min

    def intervals(self, o: int) -> list[tuple[float, float]]:
        """Observed (start, end) stretches of observation ``o`` along its wall (metres)."""
        a, b = self.interval_offset[o], self.interval_offset[o + 1]
        return [(float(s), float(e)) for s, e in zip(self.interval_start[a:b], self.interval_end[a:b])]

    def counting(self, min_hits: int = MIN_HITS, min_observed_m: float = MIN_OBSERVED_M) -> np.ndarray:
        """(O,) True for observations with at least ``min_hits`` hits and ``min_observed_m`` observed."""
        return (self.n_hits >= min_hits) & (self.observed_m >= min_observed_m)

    def subset(self, mask: np.ndarray) -> "ScanObservations":
        """The observations where ``mask`` (O,) is True (e.g. ``np.isin(obs.frame, frames)``)."""
        idx = np.flatnonzero(np.asarray(mask, bool))
        counts = np.diff(self.interval_offset)[idx]
        starts = self.interval_offset[idx]
        take = (np.repeat(starts - np.concatenate([[0], np.cumsum(counts)[:-1]]), counts)
                + np.arange(counts.sum())).astype(np.int64)
        return ScanObservations(self.frame[idx], self.wall[idx], self.n_hits[idx], self.s_min[idx], self.s_max[idx],
                                self.observed_m[idx], np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
                                self.interval_start[take], self.interval_end[take])

    @staticmethod
    def empty() -> "ScanObservations":
        i, f = np.zeros(0, np.int64), np.zeros(0)
        return ScanObservations(i, i, i, f, f, f, np.zeros(1, np.int64), f, f)


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


def write_observations(path: str | Path, obs: ScanObservations, n_walls: int) -> None:
    """Write ``obs`` as a compressed ``.npz`` (with the thresholds used, for the reader)."""
    from featmap.io.atomic import atomic_path

    with atomic_path(Path(path)) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, frame=obs.frame.astype(np.int32), wall=obs.wall.astype(np.int32),
                                n_hits=obs.n_hits.astype(np.int32), s_min=obs.s_min, s_max=obs.s_max,
                                observed_m=obs.observed_m, interval_offset=obs.interval_offset,
                                interval_start=obs.interval_start, interval_end=obs.interval_end,
                                n_walls=np.int64(n_walls), gap_factor=np.float64(GAP_FACTOR),
                                min_gap_m=np.float64(MIN_GAP_M))


def read_observations(truth_dir: str | Path, frames: list[int] | np.ndarray | None = None) -> ScanObservations:
    """Read ``truth_dir/observations.npz``; with ``frames``, only those scans' observations."""
    path = Path(truth_dir) / OBSERVATIONS_FILE
    if not path.exists():
        raise InputFileError(path, "not found: simulate the drive with per-scan truth "
                                   "(simulate_drive(..., scan_observations=True))")
    try:
        with np.load(path) as data:
            obs = ScanObservations(data["frame"].astype(np.int64), data["wall"].astype(np.int64),
                                   data["n_hits"].astype(np.int64), data["s_min"], data["s_max"], data["observed_m"],
                                   data["interval_offset"].astype(np.int64), data["interval_start"],
                                   data["interval_end"])
    except (OSError, ValueError, KeyError) as exc:
        raise InputFileError(path, f"not a per-scan observation file ({type(exc).__name__}: {exc})") from None
    if frames is not None:
        obs = obs.subset(np.isin(obs.frame, np.asarray(frames)))
    return obs
