"""Pose refinement of an extraction: the scans' segments in, corrected poses out, timed."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from featmap.pipeline.extract import Extraction
from featmap.refinement import RefinementConfig, RefinementInput, RefinementResult, refine


@dataclass(frozen=True)
class RefinementRun:
    """One refinement of a run's poses.

    Attributes:
        method: the registry name of the method (``none`` when refinement is off).
        frames: (F,) frame numbers of the poses.
        source_poses: (F, 4, 4) ``T_world_sensor`` as the source gave them.
        result: the method's result (refined poses, per-scan corrections).
        seconds: wall-clock time of the refinement.
        slam_poses: the source's poses were taken as a SLAM result (held near them by the method's
            ``slam_absolute_*`` prior where set).
    """

    method: str
    frames: list[int]
    source_poses: np.ndarray
    result: RefinementResult
    seconds: float
    slam_poses: bool = False

    @property
    def poses(self) -> np.ndarray:
        """(F, 4, 4) the poses the map is built from."""
        return self.result.poses


def refine_extraction(extraction: Extraction, config: RefinementConfig) -> RefinementRun:  # type: ignore[valid-type]
    """Refine the source poses of ``extraction`` from its segments with ``config.method``."""
    start = time.perf_counter()
    table = extraction.world_table()
    position = {frame: i for i, frame in enumerate(extraction.frames)}
    scan = np.fromiter((position[s] for s in table.scan), dtype=np.int64, count=len(table))
    stamps = extraction.timestamps if len(extraction.timestamps) == len(extraction.frames) else None
    inp = RefinementInput(table.segments, scan, extraction.poses, stamps, slam_poses=extraction.slam_poses)
    result = refine(inp, config)
    return RefinementRun(config.method, list(extraction.frames), extraction.poses, result, time.perf_counter() - start,
                         extraction.slam_poses)
