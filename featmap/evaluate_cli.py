"""``featmap evaluate``: read any fused map and any ground truth, in one local frame, and score it."""

from __future__ import annotations

from pathlib import Path

from featmap.errors import FeatmapError, InputFileError
from featmap.evaluation import compute_metrics, load_truth, truth_from_footprints
from featmap.geo import GeoFrame
from featmap.io.jsonfile import read_json


def _frame_for_csv(fused: Path, origin: str | None) -> GeoFrame | None:
    if origin is not None:
        try:
            lat, lon = (float(v) for v in origin.split(","))
        except ValueError:
            raise FeatmapError(f"--origin {origin!r}: expected LAT,LON, e.g. 49.011,8.424") from None
        return GeoFrame(lat, lon)
    metrics = fused.parent / "metrics.json"
    if metrics.exists():
        return GeoFrame(**read_json(metrics)["geo_frame"])
    return None


def evaluate_file(fused: Path, truth: Path, origin: str | None = None) -> dict:
    """Metrics of ``fused`` (.csv or .geojson) against ``truth`` (footprints .geojson or a truth/ folder)."""
    from featmap.io.geojson import first_position, read_segments_geojson
    from featmap.io.segments_csv import read_fused_csv

    fused, truth = Path(fused), Path(truth)
    if not truth.exists():
        raise InputFileError(truth, "ground truth not found")
    if fused.suffix.lower() in (".geojson", ".json"):
        frame = first_position(truth) if truth.is_file() else GeoFrame(**read_json(truth / "simulation.json")["geo_origin"])
        segments, _ = read_segments_geojson(fused, frame)
    else:
        frame = _frame_for_csv(fused, origin)
        segments, _ = read_fused_csv(fused)
        if frame is None and truth.is_file():
            raise FeatmapError(f"{fused}: a CSV is in a local frame; give --origin LAT,LON or keep it next to its metrics.json")
    if truth.is_dir():
        gt = load_truth(truth, frame)
    else:
        gt = truth_from_footprints(truth, frame)
    return compute_metrics(segments, gt)
