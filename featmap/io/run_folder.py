"""Read a run folder back (for figures, comparisons and sweeps)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from featmap.config import FeatmapConfig, load_config
from featmap.geo import GeoFrame
from featmap.io.jsonfile import read_json
from featmap.io.segments_csv import SegmentTable, read_fused_csv, read_segments_csv


@dataclass(frozen=True)
class RunData:
    """What ``featmap run`` wrote, in the run's local metric frame.

    Attributes:
        fused: method -> (segments (M, 4), support (M,)).
        trajectory: (F, 2) vehicle (velodyne) positions.
        truth: ground truth (simulated drives), restricted to the frames of the run, or None.
    """

    path: Path
    metrics: dict
    config: FeatmapConfig
    segments: SegmentTable
    fused: dict
    trajectory: np.ndarray
    frame: GeoFrame
    truth: object | None


def load_run(run_dir: str | Path) -> RunData:
    from featmap.evaluation import load_truth

    run_dir = Path(run_dir)
    metrics = read_json(run_dir / "metrics.json", "not found: is this a featmap run folder? (featmap run writes it)")
    config = load_config(run_dir / "config.yaml")
    segments = read_segments_csv(run_dir / "segments.csv")
    fused = {name: read_fused_csv(run_dir / f"fused_{name}.csv") for name in metrics["methods"]}
    traj_path = run_dir / "trajectory.csv"
    trajectory = np.loadtxt(traj_path, delimiter=",", skiprows=1, ndmin=2)[:, 1:3] if traj_path.exists() else np.zeros((0, 2))
    frame = GeoFrame(**metrics["geo_frame"])
    truth = None
    if metrics.get("ground_truth") and Path(metrics["ground_truth"]).exists():
        truth = load_truth(metrics["ground_truth"], frame, metrics.get("frames_processed"))
    return RunData(run_dir, metrics, config, segments, fused, trajectory, frame, truth)
