"""What a run hands its writers, and what a writer (an output plug-in) is."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from pydantic import Field, field_validator

from featmap.config import Section
from featmap.fusion import FusionResult
from featmap.geo import GeoFrame
from featmap.io.run_metrics import RunMetrics
from featmap.io.segments_csv import SegmentTable
from featmap.io.sim_truth import TruthWalls
from featmap.plotting.basemap import tile_provider


class OutputConfig(Section):
    """What a run writes besides the CSV files of the output contract."""

    geojson: bool = Field(True, description="write fused_<method>.geojson (WGS84)")
    kml: bool = Field(True, description="write map.kml for Google Earth")
    html: bool = Field(True, description="write map.html (interactive Leaflet map)")
    plots: bool = Field(True, description="write overview PNG plots")
    tile_source: str = Field("OpenStreetMap.Mapnik", description="basemap: an xyzservices name or a {z}/{x}/{y} URL template")
    tile_cache_dir: str = Field("~/.cache/featmap/tiles", description="on-disk cache of fetched map tiles")
    tile_timeout_s: float = Field(5.0, gt=0, description="give up on the basemap after this many seconds")

    @field_validator("tile_source")
    @classmethod
    def _known_tile_source(cls, value: str) -> str:
        """An unknown provider name is a mistake to report at once (an unreachable server is not: it falls back)."""
        tile_provider(value)
        return value


@dataclass(frozen=True)
class RunProducts:
    """Everything one run made, in its local metric frame.

    Attributes:
        table: the extracted segments (world frame) with their scans.
        results: method name -> its fusion result.
        frames: (F,) frame numbers of ``poses``.
        poses: (F, 4, 4) ``T_world_sensor`` of the scans processed: the poses the map was built from
            (refined when pose refinement ran).
        geo_frame: WGS84 origin of the local frame, or None (then no WGS84 output is written).
        truth: the ground truth the run was scored against (walls (W, 4), labels, ...), or None.
        config_yaml: the resolved configuration, as saved in ``config.yaml``.
        metrics: the run's record (``metrics.json``).
        output: the ``output:`` config section.
        source_poses: (F, 4, 4) the poses as the source gave them (None: the same as ``poses``).
        corrections: (F, 3) per-scan pose corrections ``dx, dy`` (m) and ``dyaw`` (rad) of the refinement
            (:mod:`featmap.refinement.base`), or None when no refinement ran.
        footprints: the building footprint walls the run was scored against (those near its scans) with
            what its scans observed of them, as ``footprint_walls.csv`` holds them
            (:class:`featmap.io.sim_truth.TruthWalls`), or None.
    """

    table: SegmentTable
    results: dict[str, FusionResult]
    frames: list[int]
    poses: np.ndarray
    geo_frame: GeoFrame | None
    truth: Any
    config_yaml: str
    metrics: RunMetrics
    output: OutputConfig
    source_poses: np.ndarray | None = None
    corrections: np.ndarray | None = None
    footprints: TruthWalls | None = None

    @property
    def trajectory(self) -> np.ndarray:
        """(F, 2) sensor positions (of the poses the map was built from)."""
        return self.poses[:, :2, 3]

    @property
    def input_poses(self) -> np.ndarray:
        """(F, 4, 4) the poses as the source gave them."""
        return self.poses if self.source_poses is None else self.source_poses


class Output(Protocol):
    """A writer: the files it makes, whether it needs a geo origin, whether the config turns it on."""

    name: str
    needs_geo: bool

    def enabled(self, config: OutputConfig) -> bool: ...

    def write(self, products: RunProducts, folder: Path) -> list[str]:
        """Write into ``folder``; return the names of the files written."""
        ...
