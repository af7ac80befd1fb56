"""``segments.csv`` and ``fused_<method>.csv``: the CSV files of the output contract.

``segments.csv``: header ``scan,x1,y1,x2,y2`` (+ optional ``n_points,z_min,z_max,rms,max_gap``), world frame,
metres.
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
from featmap.geometry import MAX_COORDINATE_M, MAX_MAP_SPAN_M, spread_and_outlier
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
        extra: optional per-segment columns, each (N,) (e.g. ``n_points``, ``z_min``, ``z_max``, ``rms``,
            ``max_gap``).
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


INT64_MIN, INT64_MAX = -(2 ** 63), 2 ** 63 - 1


def _integer(cell: str) -> int | None:
    """The integer a cell holds (``12``, ``12.0``, ``1.2e3``), exactly; None if it is not a whole number."""
    text = cell.strip()
    try:
        return int(text)
    except ValueError:
        pass
    try:
        value = float(text)
    except ValueError:
        return None
    return int(value) if value.is_integer() else None


@dataclass(frozen=True)
class _Columns:
    """A numeric CSV as read: the numeric columns' names, their values as floats (rows, columns) and the
    integer columns' exact values as int64."""

    header: list[str]
    data: np.ndarray
    integers: dict[str, np.ndarray]


def _read_numeric_csv(path: Path, required: tuple[str, ...], text_columns: tuple[str, ...] = (),
                      integer_columns: tuple[str, ...] = (), non_negative: tuple[str, ...] = ()) -> _Columns:
    """Read a CSV of numbers (``text_columns`` are skipped; ``integer_columns`` must hold whole numbers that
    fit an int64; ``non_negative`` columns, when present, no value below 0); a one-line error naming the file
    and line for every malformed header or cell.

    Blank lines (empty or only whitespace) are ignored wherever they are.
    """
    try:
        text = path.read_text(encoding="utf-8-sig")      # a BOM (spreadsheets write one) is not part of the header
    except FileNotFoundError:
        raise InputFileError(path, "file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(path, f"cannot read ({exc})") from None
    reader = csv.reader(io.StringIO(text))
    try:
        rows = [(reader.line_num, row) for row in reader if any(cell.strip() for cell in row)]
    except csv.Error as exc:                                # a cell over the csv module's field size limit
        raise InputFileError(path, f"not a readable CSV ({exc})", line=reader.line_num) from None
    if not rows:
        raise InputFileError(path, f"empty file; expected a header {','.join(required)}", line=1)
    header_line, header = rows[0][0], [h.strip() for h in rows[0][1]]
    repeated = [h for k, h in enumerate(header) if h in header[:k]]
    if repeated:
        raise InputFileError(path, f"column '{repeated[0]}' appears more than once in the header "
                                   f"({','.join(header)})", line=header_line)
    missing = [c for c in required if c not in header]
    if missing:
        raise InputFileError(path, f"missing column(s) {', '.join(missing)}; the header must contain "
                                   f"{','.join(required)} (found {','.join(header)})", line=header_line)
    numeric = [c for c, h in enumerate(header) if h not in text_columns]
    whole = [c for c, h in enumerate(header) if h in integer_columns]
    data = np.empty((len(rows) - 1, len(numeric)))
    integers = np.empty((len(rows) - 1, len(whole)), np.int64)
    for r, (n, row) in enumerate(rows[1:]):
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
            if value < 0 and header[c] in non_negative:
                raise InputFileError(path, f"column '{header[c]}': {cell.strip()} is negative", line=n)
            data[r, k] = value
        for k, c in enumerate(whole):
            cell = row[c]
            value = _integer(cell)
            if value is None:
                raise InputFileError(path, f"column '{header[c]}': not an integer: {cell.strip()}", line=n)
            if not INT64_MIN <= value <= INT64_MAX:
                raise InputFileError(path, f"column '{header[c]}': {cell.strip()} is outside the 64-bit "
                                           f"integer range", line=n)
            integers[r, k] = value
    return _Columns(header=[header[c] for c in numeric], data=data,
                    integers={header[c]: integers[:, k] for k, c in enumerate(whole)})


def _first_occurrences(scan: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """(N,) bool: True for the first row of every distinct (scan, x1, y1, x2, y2), compared exactly."""
    order = np.lexsort((segments[:, 3], segments[:, 2], segments[:, 1], segments[:, 0], scan))
    same = np.zeros(len(order), bool)
    if len(order):
        same[1:] = (scan[order][1:] == scan[order][:-1]) & (segments[order][1:] == segments[order][:-1]).all(axis=1)
    first = np.zeros(len(order), bool)
    first[order[~same]] = True
    return first


def _check_extent(path: Path, segments: np.ndarray) -> None:
    """A one-line error for a coordinate beyond ``MAX_COORDINATE_M`` (the geometry would overflow), or for
    segments spanning more than ``MAX_MAP_SPAN_M`` (no map of the Earth is that large: one row is wrong)."""
    if not len(segments):
        return
    far = np.flatnonzero(np.abs(segments).max(axis=1) > MAX_COORDINATE_M)
    if len(far):
        raise InputFileError(path, f"a coordinate beyond {MAX_COORDINATE_M:g} m ({np.abs(segments[far[0]]).max():g}); "
                                   "coordinates are metres of a local or projected frame")
    span, k = spread_and_outlier(segments.reshape(-1, 2))
    if span > MAX_MAP_SPAN_M:
        raise InputFileError(path, f"the segments span {span:.3g} m, more than any map of the Earth "
                                   f"({MAX_MAP_SPAN_M:g} m); the farthest from the others is data row {k // 2 + 1} "
                                   f"({', '.join(f'{v:g}' for v in segments[k // 2])})")


def read_segments_csv(path: str | Path) -> SegmentTable:
    """Read a ``segments.csv``; zero-length rows are skipped and counted (``skipped_zero_length``), and so
    are rows repeating an earlier row's scan and endpoints (``skipped_duplicates``)."""
    path = Path(path)
    table = _read_numeric_csv(path, SEGMENT_COLUMNS, integer_columns=("scan",), non_negative=("n_points", "rms", "max_gap"))
    col = {h: table.data[:, k] for k, h in enumerate(table.header)}
    scan = table.integers["scan"]
    segments = np.stack([col[c] for c in ("x1", "y1", "x2", "y2")], axis=1)
    _check_extent(path, segments)
    nonzero = (segments[:, 0] != segments[:, 2]) | (segments[:, 1] != segments[:, 3])
    unique = _first_occurrences(scan, segments)
    keep = nonzero & unique
    extra = {h: col[h][keep] for h in table.header if h not in SEGMENT_COLUMNS}
    return SegmentTable(scan=scan[keep], segments=segments[keep], extra=extra,
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
    """Read a ``fused_<method>.csv``: returns (segments (M, 4), support (M,); 1 each without a ``support``)."""
    path = Path(path)
    table = _read_numeric_csv(path, ("x1", "y1", "x2", "y2"), TEXT_COLUMNS, integer_columns=("support",))
    col = {h: table.data[:, k] for k, h in enumerate(table.header)}
    segments = np.stack([col[c] for c in ("x1", "y1", "x2", "y2")], axis=1)
    _check_extent(path, segments)
    support = table.integers.get("support", np.ones(len(segments), np.int64))
    if (support < 1).any():
        row = int(np.argmax(support < 1))
        raise InputFileError(path, f"column 'support': {int(support[row])} (a feature is supported by at least one "
                                   "segment)", row + 2)
    return segments, support
