"""Extraction of every scan of a source, through the segment store and an executor.

The main process reads each scan (so a bad scan is reported at once, with its file), looks its content
key up in the store, and sends only the scans that are not cached to the executor. Results are kept in
the sensor frame; :meth:`Extraction.world_table` moves them to the world frame with the poses given
(the source's own, or refined ones).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Iterator

import numpy as np

from featmap.datasets.base import ScanSource
from featmap.errors import DatasetError
from featmap.extraction import ExtractionConfig, ScanSegments, extractor_for, segments_to_world, world_fields
from featmap.extraction.base import Extractor
from featmap.fusion.visibility import sensor_columns
from featmap.geometry import MAX_MAP_SPAN_M, spread_and_outlier
from featmap.io.segments_csv import SegmentTable
from featmap.pipeline.executor import Executor, SerialExecutor
from featmap.pipeline.segment_store import SegmentStore, scan_key
from featmap.reporting import NullReporter, Reporter


@dataclass
class Extraction:
    """Per-scan segments of a source (sensor frame) and how they were obtained.

    Attributes:
        frames: frame numbers whose scans were processed, in order.
        scans: sensor-frame segments of each of those frames.
        poses: (F, 4, 4) ``T_world_sensor`` of those frames (the source's poses).
        dimension: 2 or 3.
        timestamps: (F,) seconds of those frames (the scans' timestamps).
        extracted_now, from_cache: how many scans were extracted in this call or came from the store.
        skipped: frame -> reason, for unreadable scans left out (``skip_bad_scans``).
        seconds: wall-clock time of the whole extraction; scan_seconds: per extracted scan.
        discarded: cache entries found corrupt and re-made.
        slam_poses: the source's poses are a SLAM result (:attr:`featmap.datasets.base.ScanSource.slam_poses`).
    """

    frames: list[int]
    scans: list[ScanSegments]
    poses: np.ndarray
    dimension: int
    extracted_now: int = 0
    from_cache: int = 0
    skipped: dict[int, str] = field(default_factory=dict)
    seconds: float = 0.0
    scan_seconds: list[float] = field(default_factory=list)
    discarded: list[str] = field(default_factory=list)
    timestamps: np.ndarray = field(default_factory=lambda: np.zeros(0))
    slam_poses: bool = False

    def world_table(self, poses: np.ndarray | None = None) -> SegmentTable:
        """Every segment in the world frame with its scan (frame number) and per-segment columns (the
        extractor's :func:`~featmap.extraction.world_fields`, and ``sensor_x``, ``sensor_y``: where the sensor
        stood, :func:`~featmap.fusion.visibility.sensor_columns`).

        Args:
            poses: (F, 4, 4) ``T_world_sensor`` to use instead of the source's (e.g. refined poses).
        """
        poses = self.poses if poses is None else poses
        segs, scans, extras = [], [], []
        for frame, scan_segments, T in zip(self.frames, self.scans, poses):
            segs.append(segments_to_world(scan_segments, T))
            scans.append(np.full(len(scan_segments), frame, np.int64))
            extras.append({**world_fields(scan_segments, T), **sensor_columns(T, len(scan_segments))})
        if not segs:
            return SegmentTable(scan=np.zeros(0, np.int64), segments=np.zeros((0, 4)))
        # A scan without segments may lack a column its extractor measures on non-empty scans (max_gap).
        names = list(next((e for e, s in zip(extras, segs) if len(s)), extras[0]))
        empty = np.zeros(0)
        return SegmentTable(scan=np.concatenate(scans), segments=np.concatenate(segs),
                            extra={k: np.concatenate([e.get(k, empty) if len(s) == 0 else e[k]
                                                      for e, s in zip(extras, segs)]).astype(float) for k in names})


    def world_points(self, poses: np.ndarray | None = None) -> np.ndarray | None:
        """(P, 2) the scans' support points (structure points from the extractor) in the world frame, or
        None when the extractor gives none."""
        poses = self.poses if poses is None else poses
        parts = [s.support_points_world(T) for s, T in zip(self.scans, poses)]
        parts = [p for p in parts if p is not None]
        return np.concatenate(parts) if parts else None

    def world_point_scans(self) -> np.ndarray | None:
        """(P,) the frame number of each of :meth:`world_points`' points, or None when there are none."""
        parts = [np.full(len(s.support_points), frame, np.int64)
                 for frame, s in zip(self.frames, self.scans) if s.support_points is not None]
        return np.concatenate(parts) if parts else None


def _extract_one(task: tuple[int, str, np.ndarray, Extractor, object]) -> tuple[int, str, ScanSegments, float]:
    """Executor task: (frame, key, points, extractor, config section) -> (frame, key, segments, seconds)."""
    frame, key, points, extractor, section = task
    start = time.perf_counter()
    result = extractor.extract(points, section)
    return frame, key, result, time.perf_counter() - start


def extract_source(source: ScanSource, config: ExtractionConfig, store: SegmentStore,  # type: ignore[valid-type]
                   executor: Executor = SerialExecutor(), reporter: Reporter = NullReporter(),
                   skip_bad_scans: bool = False) -> Extraction:
    """Segments of every selected scan of ``source``, from ``store`` where possible.

    Raises:
        DatasetError: an unreadable scan (unless ``skip_bad_scans``: then it is left out and listed).
    """
    extractor = extractor_for(source.dimension, config)
    section = getattr(config, extractor.name)
    results: dict[int, ScanSegments] = {}
    stamps: dict[int, float] = {}
    out = empty_extraction(source)
    start = time.perf_counter()
    with reporter.progress(f"extracting {source.name}", len(source)) as advance:
        def uncached():
            for _, frame, scan in readable_scans(source, skip_bad_scans, out.skipped, advance):
                stamps[frame] = float(scan.timestamp)
                key = scan_key(scan.points, extractor, section)
                cached = store.get(key)
                if cached is not None:
                    results[frame] = cached
                    out.from_cache += 1
                    advance(1)
                    continue
                yield frame, key, scan.points, extractor, section

        for frame, key, segments, seconds in executor.imap(_extract_one, uncached()):
            store.put(key, segments)
            results[frame] = segments
            out.extracted_now += 1
            out.scan_seconds.append(seconds)
            advance(1)
    out.seconds = time.perf_counter() - start
    out.discarded = list(store.discarded)
    out.frames = [f for f in source.frames if f in results]
    out.scans = [results[f] for f in out.frames]
    out.timestamps = np.array([stamps[f] for f in out.frames], dtype=float)
    poses = source.poses()
    position = {f: i for i, f in enumerate(source.frames)}
    out.poses = poses[[position[f] for f in out.frames]] if out.frames else np.zeros((0, 4, 4))
    check_poses(source, out.frames, out.poses)
    return out


def empty_extraction(source: ScanSource) -> Extraction:
    """An Extraction of no scan yet, of ``source``'s dimension and kind of poses."""
    return Extraction(frames=[], scans=[], poses=np.zeros((0, 4, 4)), dimension=source.dimension,
                      slam_poses=bool(getattr(source, "slam_poses", False)))      # (a source that does not say: no)


def readable_scans(source: ScanSource, skip_bad_scans: bool, skipped: dict[int, str],
                   advance: Callable[[int], None]) -> Iterator[tuple[int, int, object]]:
    """``(position, frame, scan)`` of every selected scan of ``source`` that can be read, in order.

    Raises:
        DatasetError: an unreadable scan, naming it, unless ``skip_bad_scans``: then it is left out, its
            reason recorded in ``skipped`` (frame -> message) and counted by ``advance(1)``.
    """
    for position, frame in enumerate(source.frames):
        try:
            scan = source[position]
        except DatasetError as exc:
            if not skip_bad_scans:
                raise DatasetError(f"{exc} (use --skip-bad-scans to leave it out)") from None
            skipped[frame] = str(exc)
            advance(1)
            continue
        yield position, frame, scan


def check_poses(source: ScanSource, frames: list[int], poses: np.ndarray) -> None:
    """A one-line DatasetError for poses (F, 4, 4) that are not finite or span more than any map of the Earth."""
    if not len(frames):
        return
    xyz = poses[:, :3, 3]
    finite = np.all(np.isfinite(poses), axis=(1, 2))
    if not finite.all():
        k = int(np.argmin(finite))
        raise DatasetError(f"{source.location}: frame {frames[k]}: its pose has NaN or inf values")
    span, k = spread_and_outlier(xyz)
    if span > MAX_MAP_SPAN_M:
        raise DatasetError(f"{source.location}: frame {frames[k]}: pose at {xyz[k].tolist()} m: the poses span "
                           f"{span:.3g} m, more than any map of the Earth ({MAX_MAP_SPAN_M:g} m)")
