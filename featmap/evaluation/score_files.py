"""``featmap evaluate``: score any fused map file against any ground truth, in one local frame."""

from __future__ import annotations

from dataclasses import dataclass
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


@dataclass(frozen=True)
class _MapOrigin:
    """What the folder a fused map lies in says about it: its run's (``metrics.json``) or batch merge's
    (``merged.json``) local frame, the references it was scored against (name -> absolute path) and, for a
    run, the frames it processed."""

    folder: Path
    frame: GeoFrame | None
    references: dict[str, Path]
    frames: list[int] | None = None


def _map_origin(fused: Path, strict: bool) -> _MapOrigin | None:
    """The run or batch merge ``fused`` was written by, or None when its folder holds neither record (or,
    unless ``strict``, an unreadable one: a map file can be scored without it)."""
    from featmap.io.batch_records import read_merged_record
    from featmap.io.run_metrics import read_run_metrics

    folder = fused.parent
    try:
        if (folder / "metrics.json").exists():
            meta = read_run_metrics(folder / "metrics.json")
            references = {name: meta.reference_path(name, folder) for name in meta.references}
            return _MapOrigin(folder, meta.geo_frame.frame() if meta.geo_frame is not None else None,
                              {k: v.resolve() for k, v in references.items() if v is not None},
                              meta.source.frames_processed)
        if (folder / "merged.json").exists():
            merged = read_merged_record(folder / "merged.json")
            single = merged.evaluator is not None and merged.reference is not None and ";" not in merged.reference
            return _MapOrigin(folder, merged.geo_frame.frame() if merged.geo_frame is not None else None,
                              {merged.evaluator: Path(merged.reference).resolve()} if single else {})
    except FeatmapError:
        if strict:
            raise
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
    geojson = fused.suffix.lower() in (".geojson", ".json")
    run = _map_origin(fused, strict=not geojson and origin is None)
    if geojson:                                  # WGS84: scored in its run's frame where it has one
        frame = (run.frame if run is not None and run.frame is not None else parse_origin(origin) if origin
                 else first_position(truth) if truth.is_file() else simulation_frame(truth))
        segments, _ = read_segments_geojson(fused, frame)
    else:
        frame = parse_origin(origin) if origin is not None else run.frame if run is not None else None
        segments, _ = read_fused_csv(fused)
        if frame is None and truth.is_file():
            raise FeatmapError(f"{fused}: a CSV is in a local frame; give --origin LAT,LON or keep it next to its "
                               "metrics.json (or merged.json)")
    _check_scored_length(fused, segments, "segments", "is it one drive's map?")
    own = run is not None and truth.resolve() in run.references.values()
    if truth.is_dir():              # a run of selected frames is scored on what those frames observed
        gt = load_simulator_truth(truth, frame, run.frames if own else None)
    else:
        gt = footprints_truth(truth, frame, run.folder if own else None, run.frame if own else None)
    _check_scored_length(truth, gt.walls, "walls", "crop it to the drive's area, or score the run with it "
                         "(--set evaluation.footprints=FILE): a run keeps only the walls near its scans")
    return truth_metrics(segments, gt)


def _check_scored_length(path: Path, segments: np.ndarray, what: str, advice: str) -> None:
    """A one-line InputFileError when (K, 4) ``segments`` are longer in total than one scoring holds in memory."""
    total = float(np.hypot(segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1]).sum())
    if total > MAX_SCORED_LENGTH_M:
        raise InputFileError(path, f"its {what} are {total / 1e3:,.0f} km long in total, more than one scoring holds "
                                   f"({MAX_SCORED_LENGTH_M / 1e3:,.0f} km at {100 * STEP_M:.0f} cm samples): {advice}")
