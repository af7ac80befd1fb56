"""``featmap evaluate``: score any fused map file against any ground truth, in one local frame."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from featmap.errors import FeatmapError, InputFileError
from featmap.evaluation.references import footprints_truth, load_simulator_truth, simulation_frame
from featmap.evaluation.truth_metrics import MAX_SCORED_LENGTH_M, STEP_M, truth_metrics
from featmap.geo import GeoFrame
from featmap.io.sim_truth import is_truth_folder


def parse_origin(origin: str) -> GeoFrame:
    try:
        lat, lon = (float(v) for v in origin.split(","))
    except ValueError:
        raise FeatmapError(f"--origin {origin!r}: expected LAT,LON, e.g. 49.011,8.424") from None
    try:
        return GeoFrame(lat, lon)
    except FeatmapError as exc:          # not finite, or off the earth (the projection has no poles)
        raise FeatmapError(f"--origin {origin!r}: {exc}") from None


def _local_frame(fused: Path, origin: str | None) -> GeoFrame | None:
    """The local frame to score ``fused`` in: ``--origin``, else its run's (metrics.json beside it), else None."""
    from featmap.io.run_metrics import read_run_metrics

    if origin is not None:
        return parse_origin(origin)
    metrics = fused.parent / "metrics.json"
    if metrics.exists():
        geo = read_run_metrics(metrics).geo_frame
        return geo.frame() if geo is not None else None
    return None


def evaluate_file(fused: str | Path, truth: str | Path, origin: str | None = None) -> dict:
    """Metrics of ``fused`` (.csv or .geojson) against ``truth`` (footprints .geojson or a truth/ folder).

    A map in a run folder scored against that run's own truth/ folder is scored on the walls of the frames
    the run processed (as the run itself was), not on the whole drive's."""
    from featmap.io.geojson import first_position, read_segments_geojson
    from featmap.io.segments_csv import read_fused_csv

    fused, truth = Path(fused), Path(truth)
    if not truth.exists():
        raise InputFileError(truth, "ground truth not found")
    if truth.is_dir() and not is_truth_folder(truth):
        raise InputFileError(truth, "not a simulated drive's truth/ folder (walls.csv and simulation.json expected)")
    if fused.suffix.lower() in (".geojson", ".json"):        # WGS84: scored in its run's frame where it has one
        frame = _local_frame(fused, origin) or (first_position(truth) if truth.is_file() else simulation_frame(truth))
        segments, _ = read_segments_geojson(fused, frame)
    else:
        frame = _local_frame(fused, origin)
        segments, _ = read_fused_csv(fused)
        if frame is None and truth.is_file():
            raise FeatmapError(f"{fused}: a CSV is in a local frame; give --origin LAT,LON or keep it next to its metrics.json")
    _check_scored_length(fused, segments, "segments", "is it one drive's map?")
    gt = (load_simulator_truth(truth, frame, _frames_of_run(fused, truth)) if truth.is_dir()
          else footprints_truth(truth, frame, _run_scored_against(fused, truth, "footprints")))
    _check_scored_length(truth, gt.walls, "walls", "crop it to the drive's area")
    return truth_metrics(segments, gt)


def _check_scored_length(path: Path, segments: np.ndarray, what: str, advice: str) -> None:
    """A one-line InputFileError when (K, 4) ``segments`` are longer in total than one scoring holds in memory."""
    total = float(np.hypot(segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1]).sum())
    if total > MAX_SCORED_LENGTH_M:
        raise InputFileError(path, f"its {what} are {total / 1e3:,.0f} km long in total, more than one scoring holds "
                                   f"({MAX_SCORED_LENGTH_M / 1e3:,.0f} km at {100 * STEP_M:.0f} cm samples): {advice}")


def _run_scored_against(fused: Path, truth: Path, reference: str) -> Path | None:
    """The run folder ``fused`` lies in, when that run was scored against ``truth`` as its ``reference``
    (``truth`` or ``footprints``); else None."""
    from featmap.io.run_metrics import read_run_metrics

    metrics = fused.parent / "metrics.json"
    if not metrics.exists():
        return None
    own = read_run_metrics(metrics).reference_path(reference, fused.parent)
    return fused.parent if own is not None and own.resolve() == truth.resolve() else None


def _frames_of_run(fused: Path, truth: Path) -> list[int] | None:
    """The frames the run beside ``fused`` was made from, when it was scored against this ``truth`` folder
    (a run of selected frames observed only part of the drive's walls); None: every frame."""
    from featmap.io.run_metrics import read_run_metrics

    run_dir = _run_scored_against(fused, truth, "truth")
    return None if run_dir is None else read_run_metrics(run_dir / "metrics.json").source.frames_processed
