"""The simulator's ground-truth folder (``<drive>/truth/``): its files as read/write pairs.

- ``walls.csv``: one row per building wall (local frame of the simulation, metres), its vertex labels,
  LiDAR returns and observed intervals along it;
- ``coverage.npz``: which wall bins each frame saw (``frame``, ``bin``, ``count`` per row, plus
  ``bin_offset`` per wall, ``bin_m`` and ``min_bin_returns``), so a selection of frames is scored fairly;
- ``objects_local.json``: every object with its kind and geometry (local frame);
- ``simulation.json``: the simulation's parameters, seed and geo origin.

Readers raise one-line :class:`InputFileError` naming the file (and line).
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from featmap.errors import InputFileError
from featmap.io.jsonfile import read_json

COVERAGE_BIN_M = 0.5
MIN_BIN_RETURNS = 3
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
    observed intervals per wall (list of (start, end) metres along the wall)."""

    walls: np.ndarray
    building: np.ndarray
    labels: np.ndarray
    n_returns: np.ndarray
    observed: list


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
    for n, row in enumerate(reader, start=2):
        try:
            coords = [float(row[c]) for c in ("x1", "y1", "x2", "y2")]
            returns = int(row["n_returns"])
            intervals = [tuple(float(v) for v in part.split("-")) for part in row["observed_intervals"].split(";") if part]
        except (TypeError, ValueError):
            raise InputFileError(path, "malformed row (numbers expected in x1,y1,x2,y2,n_returns,observed_intervals)",
                                 line=n) from None
        if not all(math.isfinite(c) for c in coords):
            raise InputFileError(path, "wall coordinates must be finite numbers", line=n)
        walls.append(coords)
        building.append(row["building"])
        labels.append([row["label_1"], row["label_2"]])
        n_returns.append(returns)
        observed.append(intervals)
    return TruthWalls(np.asarray(walls, float).reshape(-1, 4), np.asarray(building, dtype=str),
                      np.asarray(labels, dtype=str).reshape(-1, 2), np.asarray(n_returns, np.int64), observed)


def write_coverage(path: Path, per_frame: list[tuple[np.ndarray, np.ndarray, np.ndarray]], bin_offset: np.ndarray) -> None:
    """``coverage.npz`` from per-frame (frame, bin, count) triples and the bin offset (W + 1,) of each wall."""
    from featmap.io.atomic import atomic_path

    cat = (lambda i: np.concatenate([p[i] for p in per_frame]) if per_frame else np.zeros(0, np.int32))
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, frame=cat(0), bin=cat(1), count=cat(2), bin_offset=bin_offset.astype(np.int64),
                                bin_m=np.float64(COVERAGE_BIN_M), min_bin_returns=np.int64(MIN_BIN_RETURNS))


def coverage_of_frames(path: str | Path, walls: np.ndarray, frames: list[int]) -> tuple[list, np.ndarray]:
    """Observed intervals and return counts per wall (W walls (W, 4)), counting only ``frames``."""
    path = Path(path)
    try:
        data = np.load(path)
        frame, bins, count, offset = data["frame"], data["bin"], data["count"], data["bin_offset"]
        bin_m, min_returns = float(data["bin_m"]), int(data["min_bin_returns"])
    except (OSError, ValueError, KeyError, EOFError) as exc:
        raise InputFileError(path, f"unreadable coverage file ({exc})") from None
    if len(offset) != len(walls) + 1:
        raise InputFileError(path, f"covers {len(offset) - 1} walls, walls.csv has {len(walls)}")
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
