"""``segments.csv`` and ``fused_<method>.csv``: the CSV files of the output contract.

``segments.csv``: header ``scan,x1,y1,x2,y2`` (+ optional ``n_points,z_min,z_max,rms``), world frame, metres.
``fused_<method>.csv``: header ``x1,y1,x2,y2,support`` (+ ``length_m``; a batch's merged map adds ``n_drives``
and ``drives``, the names of the drives that saw each feature joined by ``;``), world frame, metres.
Readers check every line and raise a one-line :class:`InputFileError` naming the file and line.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from featmap.errors import InputFileError
from featmap.io.atomic import atomic_write_text

SEGMENT_COLUMNS = ("scan", "x1", "y1", "x2", "y2")
FUSED_COLUMNS = ("x1", "y1", "x2", "y2", "support")
TEXT_COLUMNS = ("drives",)
"""Columns of a fused CSV that hold text (skipped by the numeric reader)."""


@dataclass(frozen=True)
class SegmentTable:
    """Extracted segments of a drive, world frame.

    Attributes:
        scan: (N,) scan index of each segment.
        segments: (N, 4) ``x1, y1, x2, y2`` in metres.
        extra: optional per-segment columns, each (N,) (e.g. ``n_points``, ``z_min``, ``z_max``, ``rms``).
        skipped_zero_length: rows skipped on reading because both endpoints coincide.
        skipped_duplicates: rows skipped on reading because they repeat an earlier row's scan and endpoints
            (they would count twice in a feature's support).
    """

    scan: np.ndarray
    segments: np.ndarray
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    skipped_zero_length: int = 0
    skipped_duplicates: int = 0

    def __len__(self) -> int:
        return len(self.segments)


def write_segments_csv(path: str | Path, table: SegmentTable) -> Path:
    """Write ``segments.csv`` atomically (full float precision, so reading gives the same numbers)."""
    columns = list(SEGMENT_COLUMNS) + list(table.extra)
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(columns)
    extras = [np.asarray(table.extra[k]) for k in table.extra]
    for r in range(len(table)):
        row = [str(int(table.scan[r]))] + [repr(float(v)) for v in table.segments[r]]
        row += [repr(float(e[r])) for e in extras]
        writer.writerow(row)
    return atomic_write_text(path, buf.getvalue())


def _read_numeric_csv(path: Path, required: tuple[str, ...], text_columns: tuple[str, ...] = ()) -> tuple[list[str], np.ndarray]:
    """(header without the ``text_columns``, their values (rows, columns)); a one-line error per bad cell."""
    try:
        text = path.read_text(encoding="utf-8-sig")      # a BOM (spreadsheets write one) is not part of the header
    except FileNotFoundError:
        raise InputFileError(path, "file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(path, f"cannot read ({exc})") from None
    rows = list(csv.reader(io.StringIO(text)))
    if not rows:
        raise InputFileError(path, f"empty file; expected a header {','.join(required)}", line=1)
    header = [h.strip() for h in rows[0]]
    missing = [c for c in required if c not in header]
    if missing:
        raise InputFileError(path, f"missing column(s) {', '.join(missing)}; the header must contain "
                                   f"{','.join(required)} (found {','.join(header)})", line=1)
    numeric = [c for c, h in enumerate(header) if h not in text_columns]
    data = np.empty((len(rows) - 1, len(numeric)))
    for n, row in enumerate(rows[1:], start=2):
        if len(row) != len(header):
            raise InputFileError(path, f"expected {len(header)} values, found {len(row)}", line=n)
        for k, c in enumerate(numeric):
            cell = row[c]
            try:
                value = float(cell)
            except ValueError:
                raise InputFileError(path, f"column '{header[c]}': not a number: {cell!r}", line=n) from None
            if not math.isfinite(value):
                raise InputFileError(path, f"column '{header[c]}': {cell.strip()} is not a finite number", line=n)
            data[n - 2, k] = value
    return [header[c] for c in numeric], data


def read_segments_csv(path: str | Path) -> SegmentTable:
    """Read a ``segments.csv``; zero-length rows are skipped and counted (``skipped_zero_length``)."""
    path = Path(path)
    header, data = _read_numeric_csv(path, SEGMENT_COLUMNS)
    col = {h: data[:, k] for k, h in enumerate(header)}
    scan = col["scan"]
    bad = np.flatnonzero(scan != np.round(scan))
    if len(bad):
        raise InputFileError(path, f"column 'scan': not an integer: {scan[bad[0]]}", line=int(bad[0]) + 2)
    segments = np.stack([col[c] for c in ("x1", "y1", "x2", "y2")], axis=1) if len(data) else np.zeros((0, 4))
    nonzero = (segments[:, 0] != segments[:, 2]) | (segments[:, 1] != segments[:, 3])
    keys = np.column_stack([scan, segments])
    _, first = np.unique(keys, axis=0, return_index=True)
    unique = np.zeros(len(keys), bool)
    unique[first] = True
    keep = nonzero & unique
    extra = {h: col[h][keep] for h in header if h not in SEGMENT_COLUMNS}
    return SegmentTable(scan=scan[keep].astype(np.int64), segments=segments[keep], extra=extra,
                        skipped_zero_length=int((~nonzero).sum()), skipped_duplicates=int((nonzero & ~unique).sum()))


def write_fused_csv(path: str | Path, segments: np.ndarray, support: np.ndarray,
                    columns: dict[str, list] | None = None) -> Path:
    """Write ``fused_<method>.csv`` atomically: ``x1,y1,x2,y2,support,length_m`` (+ ``columns``: name -> one
    value per feature, written with ``str``; text columns must be named in :data:`TEXT_COLUMNS`)."""
    columns = columns or {}
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(list(FUSED_COLUMNS) + ["length_m"] + list(columns))
    for r, (seg, sup) in enumerate(zip(np.asarray(segments).reshape(-1, 4), np.asarray(support))):
        length = math.hypot(seg[2] - seg[0], seg[3] - seg[1])
        writer.writerow([repr(float(v)) for v in seg] + [str(int(sup)), f"{length:.3f}"]
                        + [str(values[r]) for values in columns.values()])
    return atomic_write_text(path, buf.getvalue())


def read_fused_csv(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a ``fused_<method>.csv``: returns (segments (M, 4), support (M,))."""
    path = Path(path)
    header, data = _read_numeric_csv(path, ("x1", "y1", "x2", "y2"), TEXT_COLUMNS)
    col = {h: data[:, k] for k, h in enumerate(header)}
    segments = np.stack([col[c] for c in ("x1", "y1", "x2", "y2")], axis=1) if len(data) else np.zeros((0, 4))
    support = col["support"].astype(np.int64) if "support" in col else np.ones(len(segments), np.int64)
    return segments, support
