"""The CSV files of the output contract: ``segments.csv``, ``fused_<method>.csv``, ``trajectory.csv``; when
pose refinement ran, ``trajectory_refined.csv`` and ``pose_corrections.csv``; when the run was scored against
building footprints, ``footprint_walls.csv`` (what its scans observed of them)."""

from __future__ import annotations

from pathlib import Path

from featmap.io.atomic import atomic_write_text
from featmap.io.pose_csv import corrections_csv_text, trajectory_csv_text
from featmap.io.segments_csv import write_fused_csv, write_segments_csv
from featmap.io.sim_truth import FOOTPRINT_WALLS_FILE, write_walls_csv
from featmap.outputs.base import OutputConfig, RunProducts


class SegmentsCsv:
    name = "segments.csv"
    needs_geo = False

    def enabled(self, config: OutputConfig) -> bool:
        return True

    def write(self, products: RunProducts, folder: Path) -> list[str]:
        write_segments_csv(folder / "segments.csv", products.table)
        return ["segments.csv"]


class FusedCsv:
    name = "fused_<method>.csv"
    needs_geo = False

    def enabled(self, config: OutputConfig) -> bool:
        return True

    def write(self, products: RunProducts, folder: Path) -> list[str]:
        names = []
        for method, result in products.results.items():
            write_fused_csv(folder / f"fused_{method}.csv", result.segments, result.support)
            names.append(f"fused_{method}.csv")
        return names


class TrajectoryCsv:
    name = "trajectory.csv"
    needs_geo = False

    def enabled(self, config: OutputConfig) -> bool:
        return True

    def write(self, products: RunProducts, folder: Path) -> list[str]:
        atomic_write_text(folder / "trajectory.csv", trajectory_csv_text(products.frames, products.input_poses))
        return ["trajectory.csv"]


class RefinedTrajectoryCsv:
    """The refined poses the map was built from, in ``trajectory.csv``'s columns (when refinement ran)."""

    name = "trajectory_refined.csv"
    needs_geo = False

    def enabled(self, config: OutputConfig) -> bool:
        return True

    def write(self, products: RunProducts, folder: Path) -> list[str]:
        if products.corrections is None:
            return []
        atomic_write_text(folder / "trajectory_refined.csv", trajectory_csv_text(products.frames, products.poses))
        return ["trajectory_refined.csv"]


class PoseCorrectionsCsv:
    """Per-scan pose corrections of the refinement (when it ran; all zero when they were not applied)."""

    name = "pose_corrections.csv"
    needs_geo = False

    def enabled(self, config: OutputConfig) -> bool:
        return True

    def write(self, products: RunProducts, folder: Path) -> list[str]:
        if products.corrections is None:
            return []
        atomic_write_text(folder / "pose_corrections.csv", corrections_csv_text(products.frames, products.corrections))
        return ["pose_corrections.csv"]


class FootprintWallsCsv:
    """The footprint walls a run was scored against with what its scans observed of them (local frame), so
    that ``featmap evaluate``, ``featmap figures`` and sweeps score its maps as the run did."""

    name = "footprint_walls.csv"
    needs_geo = False

    def enabled(self, config: OutputConfig) -> bool:
        return True

    def write(self, products: RunProducts, folder: Path) -> list[str]:
        if products.footprints is None:
            return []
        write_walls_csv(folder / FOOTPRINT_WALLS_FILE, products.footprints)
        return [FOOTPRINT_WALLS_FILE]
