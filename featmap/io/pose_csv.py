"""``trajectory.csv`` (and ``trajectory_refined.csv``) and ``pose_corrections.csv`` of a run folder.

``trajectory.csv``: header ``frame,x,y,z,yaw``, the sensor's pose per frame (local frame, metres, radians).
``pose_corrections.csv``: header ``frame,dx_m,dy_m,dyaw_deg``, the planar correction pose refinement applied
to each frame's pose (world frame: the scan is turned by ``dyaw`` about its own sensor position, then moved
by ``dx, dy``; see :func:`featmap.refinement.base.apply_corrections`).
Readers raise a one-line :class:`InputFileError` naming the file.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from featmap.errors import InputFileError
from featmap.geometry import MAX_COORDINATE_M


def trajectory_csv_text(frames: list[int], poses: np.ndarray) -> str:
    """``frame,x,y,z,yaw`` of the sensor per frame, from (F, 4, 4) ``T_world_sensor``."""
    lines = ["frame,x,y,z,yaw"]
    for frame, T in zip(frames, poses):
        yaw = np.arctan2(T[1, 0], T[0, 0])
        lines.append(f"{frame},{T[0, 3]:.4f},{T[1, 3]:.4f},{T[2, 3]:.4f},{yaw:.6f}")
    return "\n".join(lines) + "\n"


def corrections_csv_text(frames: list[int], corrections: np.ndarray) -> str:
    """``frame,dx_m,dy_m,dyaw_deg`` per frame from (F, 3) corrections ``dx, dy`` (metres), ``dyaw`` (radians)."""
    lines = ["frame,dx_m,dy_m,dyaw_deg"]
    for frame, (dx, dy, dyaw) in zip(frames, corrections):
        lines.append(f"{frame},{dx:.4f},{dy:.4f},{np.rad2deg(dyaw):.5f}")
    return "\n".join(lines) + "\n"


def _read_table(path: Path, kind: str, header: str) -> np.ndarray:
    """(R, C) the finite numbers of a CSV table (a ``kind`` table) whose first line is ``header``; errors
    name the file and line."""
    what = f"not a {kind} table {header}"
    columns = header.count(",") + 1
    rows = []
    try:
        with open(path, encoding="utf-8") as f:
            first = f.readline().strip()
            if first != header:
                raise InputFileError(path, f"{what} (its header is {first[:60]!r})", 1)
            for line_number, line in enumerate(f, start=2):     # the rows after the header
                if not line.strip():
                    continue
                cells = line.split(",")
                if len(cells) != columns:
                    raise InputFileError(path, f"{what} (expected {columns} values, found {len(cells)})", line_number)
                values = []
                for cell in cells:
                    try:
                        values.append(float(cell))
                    except ValueError:
                        raise InputFileError(path, f"{what} (not a number: {cell.strip()[:40]!r})", line_number) from None
                if not all(math.isfinite(v) for v in values):
                    raise InputFileError(path, f"{what} (a value that is not a finite number)", line_number)
                if any(abs(v) > MAX_COORDINATE_M for v in values[1:]):      # (the frame column: see its reader)
                    raise InputFileError(path, f"{what} (a value beyond {MAX_COORDINATE_M:g}: no pose lies that far)",
                                         line_number)
                rows.append(values)
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(path, f"{what} ({exc})") from None
    return np.array(rows, dtype=float).reshape(-1, columns)


def read_trajectory_xy(path: str | Path) -> np.ndarray:
    """(F, 2) x, y of a run's ``trajectory.csv``."""
    return _read_table(Path(path), "trajectory", "frame,x,y,z,yaw")[:, 1:3]


def read_corrections_csv(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """A run's ``pose_corrections.csv``: frames (F,) and corrections (F, 3) ``dx, dy`` (metres), ``dyaw`` (radians)."""
    table = _read_table(Path(path), "pose-corrections", "frame,dx_m,dy_m,dyaw_deg")
    frames = table[:, 0]
    if not np.array_equal(frames, np.round(frames)) or (np.abs(frames) >= 2.0**62).any():
        raise InputFileError(path, "frame numbers that are not whole numbers of a sensible size")
    return frames.astype(np.int64), np.column_stack([table[:, 1:3], np.deg2rad(table[:, 3])])
