"""Why the ``vertical_structure`` extractor kept or dropped each piece of one scan (``featmap explain``).

The extractor judges its pieces in two stages, each a list of named tests (:class:`PieceTests`): the height
tests on the pieces of cells (:func:`~featmap.extraction.vertical_structure.height_tests`), then the final
tests on the returns of the pieces that passed them (:func:`~featmap.extraction.vertical_structure.final_tests`).
A piece that passes every test of both is a wall (its ends may still move, see ``extend_hidden_m``).
:func:`explain_scan` extracts a scan once and keeps both stages; numpy in, frozen dataclasses out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from featmap.extraction.base import ScanSegments
from featmap.extraction.vertical_structure import PieceTests, VerticalStructureConfig, extract_vertical_structure
from featmap.geometry import point_segment_distance

STAGES = ("height", "final")
"""The extractor's stages of tests, in order."""


@dataclass(frozen=True)
class PieceVerdict:
    """One piece of one stage: ``segment`` (4,) its ends in the velodyne frame (metres, see
    :meth:`PieceTests.velodyne_segments`), ``failed`` the tests it fails (empty: it passed that stage),
    ``distance_m`` from the point it was looked up by, ``measured`` some of what the tests looked at
    (:attr:`PieceTests.measured`)."""

    stage: str
    segment: np.ndarray
    failed: tuple[str, ...]
    distance_m: float
    measured: dict[str, float]

    def measured_text(self) -> str:
        """``measured`` for a reader, e.g. ``returns 184, top 3.28 m, bottom 0.77 m``."""
        return ", ".join(f"{name[:-2]} {value:.2f} m" if name.endswith("_m") else
                         f"{name} {value:.0f}" if name == "returns" else f"{name} {value:.2f}"
                         for name, value in self.measured.items())

    @property
    def length_m(self) -> float:
        return float(np.hypot(*(self.segment[2:] - self.segment[:2])))


@dataclass(frozen=True)
class ScanExplanation:
    """A scan's walls (``result``, velodyne frame) and, per stage (:data:`STAGES`), the tests of its pieces;
    ``stages`` is empty when the scan had too few returns above the ground for any piece. ``rotation`` (3, 3):
    the extractor's levelling (``x_levelled = rotation @ x_velodyne``)."""

    result: ScanSegments
    stages: dict[str, PieceTests]
    rotation: np.ndarray

    def segments(self, stage: str) -> np.ndarray:
        """(n, 4) the pieces of ``stage`` in the velodyne frame."""
        return self.stages[stage].velodyne_segments(self.rotation)

    def near(self, point, radius_m: float) -> list[PieceVerdict]:
        """The pieces of every stage within ``radius_m`` of ``point`` (2,) (velodyne frame), stage by stage,
        nearest first."""
        point = np.asarray(point, dtype=float)
        out = []
        for stage, tests in self.stages.items():
            segments = self.segments(stage)
            distance = point_segment_distance(np.broadcast_to(point, (len(segments), 2)), segments)
            for k in np.argsort(distance, kind="stable"):
                if distance[k] <= radius_m:
                    out.append(PieceVerdict(stage, segments[k], tuple(tests.failed(int(k))), float(distance[k]),
                                            {name: float(value[k]) for name, value in tests.measured.items()}))
        return out

    def failure_counts(self, stage: str) -> dict[str, int]:
        """How many pieces of ``stage`` fail each of its tests (a piece counts under each it fails), in order."""
        return {name: int((~passed).sum()) for name, passed in self.stages[stage].passed.items()}


def explain_scan(points, config: VerticalStructureConfig = VerticalStructureConfig()) -> ScanExplanation:
    """Extract one scan ((N, 3) or (N, 4) velodyne-frame points) with ``config`` and keep why each piece was
    kept or dropped. The walls are those :func:`extract_vertical_structure` returns for the same input."""
    trace: dict = {}
    result = extract_vertical_structure(points, config, trace=trace)
    stages = {stage: trace[stage] for stage in STAGES} if trace else {}
    return ScanExplanation(result=result, stages=stages, rotation=trace.get("rotation", np.eye(3)))
