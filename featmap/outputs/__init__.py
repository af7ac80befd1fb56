"""Output plug-ins: each writes some files of a run and declares whether it needs a geo origin.

``OUTPUTS`` is the list the pipeline runs in order. A new output is one class (``name``, ``needs_geo``,
``enabled(config)``, ``write(products, folder) -> [file names]``) plus one entry here.
"""

from __future__ import annotations

from pathlib import Path

from featmap.outputs.base import Output, OutputConfig, RunProducts
from featmap.outputs.comparison import Comparison, write_comparison
from featmap.outputs.maps import (FusedGeojson, HtmlMap, Kml, LayersGeojson, OverviewPng, RefinedTrajectoryGeojson,
                                  tiles_of)
from featmap.outputs.tables import (FootprintWallsCsv, FusedCsv, PoseCorrectionsCsv, RefinedTrajectoryCsv, SegmentsCsv,
                                    TrajectoryCsv)

OUTPUTS: tuple[Output, ...] = (SegmentsCsv(), FusedCsv(), TrajectoryCsv(), RefinedTrajectoryCsv(), PoseCorrectionsCsv(),
                               FootprintWallsCsv(), FusedGeojson(), LayersGeojson(), RefinedTrajectoryGeojson(), Kml(),
                               HtmlMap(), OverviewPng(), Comparison())


def write_outputs(products: RunProducts, folder: str | Path, outputs: tuple[Output, ...] = OUTPUTS) -> list[str]:
    """Run every enabled output that the run can serve (geo origin) into ``folder``; the files written."""
    folder = Path(folder)
    written: list[str] = []
    for output in outputs:
        if not output.enabled(products.output) or (output.needs_geo and products.geo_frame is None):
            continue
        written += output.write(products, folder)
    return written


__all__ = ["OUTPUTS", "Output", "OutputConfig", "RunProducts", "tiles_of", "write_comparison", "write_outputs"]
