"""The scan-source contract every dataset implements, and how a source is named on the command line.

A scan source is a sequence of :class:`Scan` (``len(source)``, ``source[i]``) that also declares its
dimension (a 2D laser or a 3D LiDAR), where its data lives, the frames it selected, the poses of those
frames (without reading any scan) and, when it has one, the WGS84 origin of its local frame. Nothing
downstream asks which format it was.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Protocol, Sequence, runtime_checkable

import numpy as np

from featmap.errors import DatasetError
from featmap.geo import GeoFrame


@dataclass(frozen=True)
class Scan:
    """One scan.

    Attributes:
        index: frame number within the source (the file or record number, not the position in a selection).
        points: sensor-frame points: (N, 3|4) ``x, y, z[, reflectance]`` for a 3D LiDAR (x forward, y left,
            z up), (N, 2) ``x, y`` in beam order for a 2D laser (x forward, y left).
        T_world_sensor: (4, 4) sensor-to-world transform; world = the source's local metric frame.
        timestamp: seconds since the source's first scan.
        extras: optional raw fields of the format (e.g. a 2D laser's ranges).
    """

    index: int
    points: np.ndarray
    T_world_sensor: np.ndarray
    timestamp: float
    extras: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class SourceNotes:
    """What opening a source found besides its scans.

    Attributes:
        skipped: frame -> reason, for frames left out because they are unreadable (``--skip-bad-scans``).
        flags: name -> frames, e.g. ``{"poor_gps": [...]}`` (reported, not acted on).
    """

    skipped: dict[int, str] = field(default_factory=dict)
    flags: dict[str, list[int]] = field(default_factory=dict)


TIME_GOES_BACK = "time_goes_back"
"""The flag of the frames whose timestamp is not after the one before (:func:`frames_back_in_time`)."""


def frames_back_in_time(timestamps: np.ndarray, frames: Sequence[int]) -> list[int]:
    """The ``frames`` (indices into ``timestamps`` (F,), seconds) whose timestamp is not after the previous
    selected frame's: a log or drive whose clock stepped back or stood still."""
    frames = list(frames)
    if len(frames) < 2:
        return []
    stamps = np.asarray(timestamps, dtype=float)[frames]
    return [frames[k + 1] for k in np.flatnonzero(np.diff(stamps) <= 0)]


@runtime_checkable
class ScanSource(Protocol):
    """A dataset: a sequence of :class:`Scan` plus what the pipeline needs to know about it.

    Attributes:
        kind: the registry name of its format (``kitti_raw``, ``carmen``, ...).
        name: a short name of this source (the drive or log name; the default run folder name).
        dimension: 3 for a 3D LiDAR, 2 for a 2D laser.
        location: absolute path of its data (a KITTI drive folder, a log file).
        geo_origin: WGS84 of the local frame's origin, or None (indoor logs).
        frames: frame numbers of the selected scans, in order.
        notes: skipped frames and flags found while opening it.
        slam_poses: its poses are a SLAM result, consistent to centimetres (a CARMEN ``*-corrected`` log),
            not odometry or GPS/INS: pose refinement then holds the map near them.
    """

    kind: str
    name: str
    dimension: int
    location: Path
    geo_origin: GeoFrame | None
    frames: list[int]
    notes: SourceNotes
    slam_poses: bool

    def __len__(self) -> int: ...

    def __getitem__(self, i: int) -> Scan: ...

    def poses(self) -> np.ndarray:
        """(F, 4, 4) ``T_world_sensor`` of the selected frames, without reading any scan."""
        ...


class FrameSource:
    """A base for scan sources: ``frames`` selects the scans; a subclass implements ``scan(frame)`` and
    ``pose(frame)`` for one frame number, and gets the sequence and ``poses()`` from here."""

    frames: list[int]
    slam_poses: bool = False

    def scan(self, frame: int) -> Scan:
        raise NotImplementedError

    def pose(self, frame: int) -> np.ndarray:
        """(4, 4) ``T_world_sensor`` of ``frame`` (without reading its scan)."""
        raise NotImplementedError

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, i: int) -> Scan:
        if not -len(self) <= i < len(self):
            raise IndexError(i)
        return self.scan(self.frames[i])

    def poses(self) -> np.ndarray:
        """(F, 4, 4) ``T_world_sensor`` of the selected frames, without reading any scan."""
        return np.stack([self.pose(f) for f in self.frames]) if self.frames else np.zeros((0, 4, 4))


@dataclass(frozen=True)
class SourceSpec:
    """How to open a source again (e.g. in a batch task): its format, location and options.

    ``options`` are keyword arguments of the format's opener beyond the common ones, as (name, value)
    pairs, e.g. ``(("sim_root", "/data/sim"),)`` for a simulated drive (where it is simulated).
    """

    kind: str
    location: str
    frames: str | None = None
    skip_bad_scans: bool = False
    options: tuple[tuple[str, str], ...] = ()


def parse_frames(text: str | None, given_by: str = "--frames") -> slice | None:
    """``"start:stop:step"`` (each part optional) -> slice; None for all frames. Errors name ``given_by``
    (the flag, or the key of the file the text came from)."""
    if text is None or text.strip() in ("", ":"):
        return None
    parts = text.split(":")
    if len(parts) > 3:
        raise DatasetError(f"{given_by} {text!r}: expected start:stop:step")
    try:
        values = [int(p) if p.strip() else None for p in parts]
    except ValueError:
        raise DatasetError(f"{given_by} {text!r}: expected integers, e.g. 0:200:2") from None
    if len(values) == 1:
        return slice(values[0], values[0] + 1)
    if len(values) == 3 and values[2] is not None and values[2] <= 0:
        raise DatasetError(f"{given_by} {text!r}: step must be positive")
    return slice(*values)


def format_frames(selection: slice) -> str:
    """A slice as the ``start:stop:step`` text of ``--frames``."""
    parts = ["" if v is None else str(v) for v in (selection.start, selection.stop, selection.step)]
    return ":".join(parts).rstrip(":") or ":"


def select_frames(n_frames: int, selection: slice | str | None, what: str) -> list[int]:
    """Frame numbers ``range(n_frames)[selection]``; a selection that reaches past the end is an error.

    Args:
        selection: a slice, its ``--frames`` text, or None for all frames.
        what: the source's name (for the message).
    """
    text = selection if isinstance(selection, str) else None
    selection = parse_frames(selection) if isinstance(selection, str) else selection
    if selection is None:
        return list(range(n_frames))
    text = text or format_frames(selection)
    for bound in (selection.start, selection.stop):
        if bound is not None and not -n_frames <= bound <= n_frames:
            raise DatasetError(f"--frames {text}: {what} has {n_frames} frames (0..{n_frames - 1})")
    frames = list(range(n_frames)[selection])
    if not frames:
        raise DatasetError(f"--frames {text} selects no frame of {what} ({n_frames} frames)")
    return frames
