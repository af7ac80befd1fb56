"""Registry of per-scan extractors, chosen by the scan's dimension (3D LiDAR or 2D laser).

``ExtractionConfig`` (the ``extraction:`` section of a run's config) is derived from ``EXTRACTORS``:
which extractor each dimension uses, plus one section per extractor. A new extractor is one module
(its function, config section and an ``EXTRACTOR`` entry) plus one line in ``EXTRACTORS``.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field, create_model

from featmap.config import Section
from featmap.errors import ConfigError
from featmap.extraction import lines_2d, ransac_planes, vertical_structure
from featmap.extraction.base import Extractor, ScanSegments

EXTRACTORS: tuple[Extractor, ...] = (vertical_structure.EXTRACTOR, ransac_planes.EXTRACTOR, lines_2d.EXTRACTOR)
EXTRACTOR_BY_NAME: dict[str, Extractor] = {e.name: e for e in EXTRACTORS}
DEFAULT_BY_DIMENSION = {3: "vertical_structure", 2: "lines_2d"}


def _names(dimension: int) -> tuple[str, ...]:
    return tuple(e.name for e in EXTRACTORS if e.dimension == dimension)


_method_fields = {
    f"method_{d}d": (Literal[_names(d)], Field(DEFAULT_BY_DIMENSION[d], description=f"extractor for {d}D scans"))
    for d in sorted(DEFAULT_BY_DIMENSION)
}
ExtractionConfig = create_model(
    "ExtractionConfig", __base__=Section, __doc__="Per-scan extraction: the extractor per scan dimension and their settings.",
    **_method_fields, **{e.name: (e.config_type, e.config_type()) for e in EXTRACTORS})


def extractor_for(dimension: int, config: ExtractionConfig) -> Extractor:  # type: ignore[valid-type]
    """The extractor ``config`` selects for scans of ``dimension`` (2 or 3)."""
    key = f"method_{dimension}d"
    if not hasattr(config, key):
        raise ConfigError(f"no extractor for {dimension}D scans; available: "
                          + ", ".join(f"{e.name} ({e.dimension}D)" for e in EXTRACTORS))
    return EXTRACTOR_BY_NAME[getattr(config, key)]


def extract_scan(points: np.ndarray, dimension: int, config: ExtractionConfig) -> ScanSegments:  # type: ignore[valid-type]
    """Segments of one scan (sensor frame) with the extractor ``config`` selects for ``dimension``.

    Args:
        points: (N, 3|4) velodyne-frame points for a 3D LiDAR, (N, 2) in beam order for a 2D laser.
    """
    extractor = extractor_for(dimension, config)
    return extractor.extract(points, getattr(config, extractor.name))
