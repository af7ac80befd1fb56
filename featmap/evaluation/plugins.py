"""Evaluation plug-ins: each scores fused maps against one kind of reference, when the run has it.

The pipeline asks every plug-in in ``EVALUATORS`` to ``prepare`` a reference from what the run knows
(where the scans came from, the frames processed, the geo frame, the config, the scans' points and the
extracted segments); a plug-in that finds nothing returns None and is skipped. ``score`` then maps fused segments to a dict of metrics. The
first plug-in that prepared a reference is the run's *primary* score (summary table, sweeps).

A new metric is one plug-in class here (or in its own module) plus one entry in ``EVALUATORS``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional, Protocol

import numpy as np
from pydantic import Field

from featmap.config import Section
from featmap.errors import ConfigError
from featmap.evaluation.map_metric import TruthFreeConfig, map_reference, score_map
from featmap.evaluation.references import load_simulator_truth, observed_footprints, truth_from_footprints
from featmap.evaluation.truth_metrics import truth_metrics
from featmap.geo import GeoFrame
from featmap.io.sim_truth import is_truth_folder


class EvaluationConfig(Section):
    """References to score fused maps against (besides a simulated drive's own ground truth)."""

    footprints: Optional[str] = Field(None, description="building footprints (.geojson, WGS84) to score against, e.g. from OpenStreetMap")
    map: TruthFreeConfig = TruthFreeConfig()


@dataclass(frozen=True)
class EvaluationContext:
    """What a run knows that a reference may be found from.

    Attributes:
        location: where the scans came from (a KITTI drive folder, a log file), or None.
        frames: frame numbers of the scans processed (None: all of the source's).
        geo_frame: WGS84 origin of the run's local frame, or None.
        config: the ``evaluation:`` section.
        points: (P, 2) the scans' structure points in the world frame (from the extractor), or None.
        point_scans: (P,) the scan each of ``points`` came from, or None (then they count as one scan).
        raw_segments: (N, 4) the extracted segments in the world frame, or None.
        workers: threads a reference may use (the run's worker count).
    """

    location: Path | None
    frames: list[int] | None
    geo_frame: GeoFrame | None
    config: EvaluationConfig
    points: np.ndarray | None = None
    raw_segments: np.ndarray | None = None
    workers: int = 1
    point_scans: np.ndarray | None = None


@dataclass(frozen=True)
class Reference:
    """A prepared reference: the object a plug-in scores against, and the file it came from (absolute)."""

    data: Any
    path: str


class Evaluator(Protocol):
    name: str

    def prepare(self, context: EvaluationContext) -> Reference | None: ...

    def score(self, reference: Reference, fused: np.ndarray) -> dict: ...


class SimulatorTruth:
    """The simulator's ground truth of a simulated drive (``<drive>/truth/``), restricted to the frames run.

    ``location`` is the drive folder (its ``truth/`` is used) or a ``truth/`` folder itself.
    """

    name = "truth"

    def prepare(self, context: EvaluationContext) -> Reference | None:
        if context.location is None:
            return None
        for folder in (Path(context.location) / "truth", Path(context.location)):
            if is_truth_folder(folder):
                truth_dir = folder.resolve()
                return Reference(load_simulator_truth(truth_dir, context.geo_frame, context.frames), str(truth_dir))
        return None

    def score(self, reference: Reference, fused: np.ndarray) -> dict:
        return truth_metrics(fused, reference.data)


class Footprints:
    """Building footprints given in ``evaluation.footprints``: the walls near the run's scan points, with
    what the scans observed of them (:func:`featmap.evaluation.references.observed_footprints`); without
    points every wall, observable whole."""

    name = "footprints"

    def prepare(self, context: EvaluationContext) -> Reference | None:
        if context.config.footprints is None:
            return None
        if context.geo_frame is None:
            raise ConfigError(f"evaluation.footprints={context.config.footprints}: footprints are WGS84 but this run "
                              "has no geo origin to place them in its local frame")
        path = Path(context.config.footprints).expanduser().resolve()
        truth = truth_from_footprints(path, context.geo_frame)
        if context.points is not None:
            truth = observed_footprints(truth, context.points, context.point_scans)
        return Reference(truth, str(path))

    def score(self, reference: Reference, fused: np.ndarray) -> dict:
        return truth_metrics(fused, reference.data)


class MapQuality:
    """The truth-free map metric against the scans' own points (any run whose extractor gives them)."""

    name = "map"

    def prepare(self, context: EvaluationContext) -> Reference | None:
        if context.points is None or context.raw_segments is None or not len(context.points):
            return None
        return Reference(map_reference(context.points, context.raw_segments, context.config.map, context.workers),
                         "scan points")

    def score(self, reference: Reference, fused: np.ndarray) -> dict:
        return score_map(fused, reference.data).to_dict()


EVALUATORS: tuple[Evaluator, ...] = (SimulatorTruth(), Footprints(), MapQuality())
