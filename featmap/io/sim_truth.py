"""The simulator's ground-truth folder (``<drive>/truth/``): its files as read/write pairs.

- ``walls.csv``: one row per building wall (local frame of the simulation, metres), its vertex labels,
  LiDAR returns and observed intervals along it;
- ``coverage.npz``: which wall bins each frame saw (``frame``, ``bin``, ``count`` per row, plus
  ``bin_offset`` per wall, ``bin_m`` and ``min_bin_returns``), so a selection of frames is scored fairly;
- ``objects_local.json``: every object with its kind and geometry (local frame);
- ``simulation.json``: the simulation's parameters, seed and geo origin;
- ``observations.npz`` (drives simulated with per-scan truth): every (scan, wall) pair with at least one
  return: the rays that hit the wall (after dropout and the sensor's range limits, no other range cap) and
  the stretches of the wall they landed on (:class:`ScanObservations`). An observation *counts* with at
  least :data:`MIN_HITS` hits and :data:`MIN_OBSERVED_M` metres observed, the per-scan version of
  EVALUATION.md's observable wall; walls 50-100 m away count whenever they are sampled that densely.

Readers raise one-line :class:`InputFileError` naming the file (and line).
"""

from __future__ import annotations

import csv
import io
import math
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from featmap.errors import InputFileError
from featmap.io.atomic import atomic_path, atomic_write_text
from featmap.io.jsonfile import read_json

COVERAGE_BIN_M = 0.5
MIN_BIN_RETURNS = 3
FOOTPRINT_WALLS_FILE = "footprint_walls.csv"
"""A run's record of what its scans observed of the building footprints it was scored against (WALL_COLUMNS)."""
WALL_COLUMNS = ("building", "x1", "y1", "x2", "y2", "label_1", "label_2", "n_returns", "observed_intervals")


def is_truth_folder(path: str | Path) -> bool:
    """Whether ``path`` looks like a simulated drive's ``truth/`` folder."""
    path = Path(path)
    return (path / "walls.csv").is_file() and (path / "simulation.json").is_file()


def observed_intervals(counts: np.ndarray, min_returns: int = MIN_BIN_RETURNS, bin_m: float = COVERAGE_BIN_M,
                       length: float | None = None) -> list[tuple[float, float]]:
    """Merge coverage bins (B,) with at least ``min_returns`` hits into intervals (metres along the wall)."""
    seen = np.asarray(counts) >= min_returns
    out = []
    k = 0
    while k < len(seen):
        if seen[k]:
            j = k
            while j + 1 < len(seen) and seen[j + 1]:
                j += 1
            end = (j + 1) * bin_m if length is None else min((j + 1) * bin_m, length)
            out.append((k * bin_m, end))
            k = j + 1
        else:
            k += 1
    return out


@dataclass(frozen=True)
class TruthWalls:
    """``walls.csv``: walls (W, 4) local frame, building ids (W,), vertex labels (W, 2), returns (W,),
    observed intervals per wall (list of (start, end) metres along the wall); for a run's record of
    footprints (``footprint_walls.csv``), the SHA-256 of the footprints file it was made from (column
    ``source_sha256``; "" in the simulator's walls.csv)."""

    walls: np.ndarray
    building: np.ndarray
    labels: np.ndarray
    n_returns: np.ndarray
    observed: list
    source_sha256: str = ""


def read_walls_csv(path: str | Path) -> TruthWalls:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputFileError(path, "not found: not a simulated drive's truth/ folder") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(path, f"cannot read ({exc})") from None
    reader = csv.DictReader(io.StringIO(text))
    missing = [c for c in WALL_COLUMNS if c not in (reader.fieldnames or [])]
    if missing:
        raise InputFileError(path, f"missing column(s) {', '.join(missing)}", line=1)
    walls, building, labels, n_returns, observed = [], [], [], [], []
    rows = []                                   # (the line a row ends on, the row)
    try:
        for row in reader:
            rows.append((reader.line_num, row))
    except csv.Error as exc:
        raise InputFileError(path, f"not a readable CSV ({exc})", line=reader.reader.line_num) from None
    for n, row in rows:
        if None in row.values():
            raise InputFileError(path, f"malformed row: fewer cells than the header's {len(reader.fieldnames)}",
                                 line=n)
        try:
            coords = [float(row[c]) for c in ("x1", "y1", "x2", "y2")]
            returns = int(row["n_returns"])
            intervals = [tuple(float(v) for v in part.split("-")) for part in row["observed_intervals"].split(";") if part]
        except (TypeError, ValueError):
            raise InputFileError(path, "malformed row (numbers expected in x1,y1,x2,y2,n_returns,observed_intervals)",
                                 line=n) from None
        if not all(len(iv) == 2 and math.isfinite(iv[0]) and math.isfinite(iv[1]) and 0 <= iv[0] <= iv[1]
                   for iv in intervals):
            raise InputFileError(path, "observed_intervals must be START-END pairs of metres along the wall "
                                       "(0 <= START <= END) joined by ';'", line=n)
        if not all(math.isfinite(c) for c in coords):
            raise InputFileError(path, "wall coordinates must be finite numbers", line=n)
        walls.append(coords)
        building.append(row["building"])
        labels.append([row["label_1"], row["label_2"]])
        n_returns.append(returns)
        observed.append(intervals)
    digests = {row.get("source_sha256") or "" for _, row in rows}
    if len(digests) > 1:
        raise InputFileError(path, "its rows name different source files (source_sha256)")
    return TruthWalls(np.asarray(walls, float).reshape(-1, 4), np.asarray(building, dtype=str),
                      np.asarray(labels, dtype=str).reshape(-1, 2), np.asarray(n_returns, np.int64), observed,
                      digests.pop() if digests else "")


def write_walls_csv(path: str | Path, walls: TruthWalls) -> None:
    """``walls.csv`` (the columns :func:`read_walls_csv` reads: ``WALL_COLUMNS``, and ``source_sha256`` when
    the walls name their source file), written atomically."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    source = [walls.source_sha256] if walls.source_sha256 else []
    writer.writerow([*WALL_COLUMNS, *(["source_sha256"] if source else [])])
    for w in range(len(walls.walls)):
        x1, y1, x2, y2 = walls.walls[w]
        writer.writerow([walls.building[w], f"{x1:.6f}", f"{y1:.6f}", f"{x2:.6f}", f"{y2:.6f}", *walls.labels[w],
                         int(walls.n_returns[w]), ";".join(f"{a:.6f}-{b:.6f}" for a, b in walls.observed[w]), *source])
    atomic_write_text(path, buf.getvalue())


def write_coverage(path: Path, per_frame: list[tuple[np.ndarray, np.ndarray, np.ndarray]], bin_offset: np.ndarray) -> None:
    """``coverage.npz`` from per-frame (frame, bin, count) triples and the bin offset (W + 1,) of each wall."""
    cat = (lambda i: np.concatenate([p[i] for p in per_frame]) if per_frame else np.zeros(0, np.int32))
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, frame=cat(0), bin=cat(1), count=cat(2), bin_offset=bin_offset.astype(np.int64),
                                bin_m=np.float64(COVERAGE_BIN_M), min_bin_returns=np.int64(MIN_BIN_RETURNS))


def coverage_of_frames(path: str | Path, walls: np.ndarray, frames: list[int]) -> tuple[list, np.ndarray]:
    """Observed intervals and return counts per wall (W walls (W, 4)), counting only ``frames``."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            frame, bins, count, offset = data["frame"], data["bin"], data["count"], data["bin_offset"]
            bin_m, min_returns = float(data["bin_m"]), int(data["min_bin_returns"])
    except (OSError, ValueError, KeyError, EOFError, TypeError, zipfile.BadZipFile) as exc:
        raise InputFileError(path, f"unreadable coverage file ({type(exc).__name__}: {exc})") from None
    whole = all(a.dtype.kind in "iu" and a.ndim == 1 for a in (frame, bins, count, offset))
    if whole and len(offset) != len(walls) + 1:
        raise InputFileError(path, f"covers {len(offset) - 1} walls, walls.csv has {len(walls)}")
    if not (whole and len(offset) and len(frame) == len(bins) == len(count) and offset[0] == 0 and (np.diff(offset) >= 0).all()
            and (count >= 0).all() and ((bins >= 0) & (bins < offset[-1])).all()
            and math.isfinite(bin_m) and bin_m > 0):
        raise InputFileError(path, "malformed coverage file: frame, bin and count must be integer columns of one "
                                   "length, counts >= 0, bins within bin_offset (0, non-decreasing), bin_m > 0")
    keep = np.isin(frame, np.asarray(frames))
    counts = np.bincount(bins[keep], weights=count[keep], minlength=int(offset[-1])).astype(np.int64)
    lengths = np.hypot(walls[:, 2] - walls[:, 0], walls[:, 3] - walls[:, 1])
    observed, n_returns = [], []
    for w in range(len(walls)):
        c = counts[offset[w]:offset[w + 1]]
        observed.append(observed_intervals(c, min_returns, bin_m, float(lengths[w])))
        n_returns.append(int(c.sum()))
    return observed, np.asarray(n_returns)


def read_simulation_json(truth_dir: str | Path) -> dict:
    return read_json(Path(truth_dir) / "simulation.json", "not found: not a simulated drive's truth/ folder")


def read_objects_local(truth_dir: str | Path) -> list[dict]:
    path = Path(truth_dir) / "objects_local.json"
    data = read_json(path)
    if not isinstance(data, dict) or not isinstance(data.get("objects"), list):
        raise InputFileError(path, "expected {'objects': [...]}")
    return data["objects"]


# --- per-scan observations ------------------------------------------------------------------------

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


def write_observations(path: str | Path, obs: ScanObservations, n_walls: int) -> None:
    """Write ``obs`` as a compressed ``.npz`` (with the thresholds used, for the reader)."""
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
        with np.load(path, allow_pickle=False) as data:
            obs = ScanObservations(data["frame"].astype(np.int64), data["wall"].astype(np.int64),
                                   data["n_hits"].astype(np.int64), data["s_min"], data["s_max"], data["observed_m"],
                                   data["interval_offset"].astype(np.int64), data["interval_start"],
                                   data["interval_end"])
    except (OSError, ValueError, KeyError, EOFError, TypeError, zipfile.BadZipFile) as exc:
        raise InputFileError(path, f"not a per-scan observation file ({type(exc).__name__}: {exc})") from None
    columns = (obs.frame, obs.wall, obs.n_hits, obs.s_min, obs.s_max, obs.observed_m)
    offsets, starts, ends = obs.interval_offset, obs.interval_start, obs.interval_end
    if not (all(c.ndim == 1 and len(c) == len(obs.frame) for c in columns) and offsets.ndim == 1
            and len(offsets) == len(obs.frame) + 1 and starts.ndim == ends.ndim == 1 and len(starts) == len(ends)
            and offsets[0] == 0 and (np.diff(offsets) >= 0).all() and offsets[-1] == len(starts)):
        raise InputFileError(path, "not a per-scan observation file: its columns are not one row per observation "
                                   "with interval offsets into the intervals")
    if frames is not None:
        obs = obs.subset(np.isin(obs.frame, np.asarray(frames)))
    return obs
