"""Real 2D laser logs (CARMEN) through the whole chain, scored with the truth-free metric.

    .venv/bin/python scripts/real_data_2d.py [--data-dir ../shared/data/carmen_2d] [--logs intel aces fhw]
                                             [--figures docs/figures/real_2d] [--markdown table.md]

For each ``<log>-corrected.log.gz``: read it (featmap.io.carmen), extract lines per scan
(featmap.extraction.lines_2d), move them to the world frame with the corrected poses, fuse them with
the three methods under three presets, ``configs/indoor_2d.yaml`` (featmap's defaults for 2D logs),
``configs/default.yaml`` (the defaults, chosen for KITTI-like drives) and ``configs/paper.yaml`` (the
paper's method as published; the competing methods without refinement, with the paper's midpoint
corners), and score every map against the log's own scan points
(featmap.evaluation.map_metric: precision, recall, redundancy at 5 cm, count, compression). Prints one table
and, with ``--figures``, writes ``<log>.png``: the proposed method's map under the 2D and paper
presets over the scan points.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from featmap.pipeline.config import load_config
from featmap.extraction.lines_2d import Lines2DConfig, extract_lines, lines_to_world
from featmap.fusion import FUSION_METHODS, fuse
from featmap.io.carmen import read_carmen
from featmap.evaluation.map_metric import TruthFreeConfig, truth_free_metrics

ROOT = Path(__file__).resolve().parents[1]
PRESETS = {"featmap 2D": ROOT / "configs" / "indoor_2d.yaml", "default": ROOT / "configs" / "default.yaml",
           "paper": ROOT / "configs" / "paper.yaml"}


def default_data_dir() -> Path:
    shared = Path(os.environ.get("FEATMAP_SHARED", ROOT / ".." / "shared"))
    return shared / "data" / "carmen_2d"


def extract_log(path: Path, config: Lines2DConfig):
    """Read one log and extract its lines: (log, world segments (N, 4), scan (N,), points (P, 2), seconds)."""
    start = time.perf_counter()
    log = read_carmen(path)
    segments, scans = [], []
    for k in range(len(log)):
        found = extract_lines(log.points(k), config)
        segments.append(lines_to_world(found.segments, log.pose[k]))
        scans.append(np.full(len(found), k, dtype=np.int64))
    seconds = time.perf_counter() - start
    points, _ = log.world_points()
    return log, np.concatenate(segments), np.concatenate(scans), points, seconds


def failure_modes(fused: np.ndarray, labels: np.ndarray, segments: np.ndarray, points: np.ndarray,
                  tolerance: float = 0.05) -> dict:
    """The failure modes of issue 10, counted on one fused map (world frame, metres).

    - ``door_spans``: stretches of 0.6-1.6 m inside a fused line with no scan point within the
      tolerance (a line drawn across a doorway);
    - ``max_off_m``: the largest distance from a fused line to the nearest scan point (a chord
      bowing away from a curved wall, a line between two walls);
    - ``two_walls``: features whose member segments lie on both sides of the fused line, 0.5 m or
      more away (two walls of a corridor merged into one line down the middle);
    - ``duplicates``: fused rows identical to another row;
    - ``lost_wall_points``: share of wall points (within the tolerance of a raw segment) whose raw
      segments were all dropped and that no fused line covers.
    """
    from scipy.spatial import cKDTree

    from featmap.evaluation.map_metric import SegmentIndex, sample_segments

    samples, owner, weight = sample_segments(fused, 0.02)
    dist, _ = cKDTree(points).query(samples)
    off = dist > tolerance
    spans = 0
    if len(samples):
        change = np.flatnonzero(np.diff(np.r_[0, off.astype(np.int8), 0]))
        for start, stop in zip(change[::2], change[1::2]):
            f = owner[start]
            interior = start > 0 and owner[start - 1] == f and stop < len(owner) and owner[stop] == f
            if interior and 0.6 <= weight[start:stop].sum() <= 1.6 and np.all(owner[start:stop] == f):
                spans += 1
    two_walls = 0
    for k in range(len(fused)):
        members = segments[labels == k]
        if len(members) < 2:
            continue
        d = fused[k, 2:] - fused[k, :2]
        n = np.array([-d[1], d[0]]) / max(np.hypot(*d), 1e-12)
        side = (0.5 * (members[:, :2] + members[:, 2:]) - fused[k, :2]) @ n
        two_walls += int(side.max() >= 0.5 and side.min() <= -0.5)
    rounded = np.round(np.where((fused[:, [0]] > fused[:, [2]]), fused[:, [2, 3, 0, 1]], fused), 9)
    duplicates = len(rounded) - len(np.unique(rounded, axis=0)) if len(rounded) else 0
    wall = SegmentIndex(segments, tolerance).near(points)
    dropped_only = SegmentIndex(segments[labels < 0], tolerance).near(points[wall]) if (labels < 0).any() else \
        np.zeros(int(wall.sum()), bool)
    if dropped_only.any():
        kept = SegmentIndex(segments[labels >= 0], tolerance).near(points[wall][dropped_only])
        covered = SegmentIndex(fused, tolerance).near(points[wall][dropped_only])
        lost = float(np.count_nonzero(~kept & ~covered) / max(wall.sum(), 1))
    else:
        lost = 0.0
    return {"door_spans": spans, "max_off_m": float(dist.max()) if len(dist) else 0.0,
            "two_walls": two_walls, "duplicates": int(duplicates), "lost_wall_points": lost}


def plot_log(path: Path, name: str, points: np.ndarray, maps: dict[str, np.ndarray], scores: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    span = np.ptp(points, axis=0)
    panel_w = float(np.clip(7.0 * span[0] / max(span[1], 1e-9), 3.2, 9.0))   # 7 in high, as wide as the map
    fig, axes = plt.subplots(1, len(maps), figsize=(panel_w * len(maps) + 0.6, 7.6), sharex=True, sharey=True)
    for ax, (title, fused) in zip(np.atleast_1d(axes), maps.items()):
        ax.plot(points[:, 0], points[:, 1], ",", color="0.65", rasterized=True)
        ax.plot(fused[:, [0, 2]].T, fused[:, [1, 3]].T, "-", color="C3", lw=0.9)
        m = scores[title]
        ax.set_title(f"{name}, {title}\n{m.count} lines, P {m.precision:.3f}, R {m.recall:.3f}", fontsize=10)
        ax.set_aspect("equal")
        ax.set_xlabel("x (m, log frame)")
    np.atleast_1d(axes)[0].set_ylabel("y (m)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data-dir", type=Path, default=default_data_dir())
    parser.add_argument("--logs", nargs="+", default=["intel", "aces", "fhw"])
    parser.add_argument("--figures", type=Path, default=None, help="write <log>.png here")
    parser.add_argument("--markdown", type=Path, default=None, help="also write the table as Markdown")
    parser.add_argument("--failure-modes", action="store_true", help="also count the failure modes of issue 10")
    args = parser.parse_args()

    extraction = Lines2DConfig()
    metric = TruthFreeConfig()
    presets = {name: load_config(path) for name, path in PRESETS.items()}
    table = Table(title=f"CARMEN logs, truth-free metric ({metric.tolerance_m * 100:.0f} cm)")
    columns = ("log", "scans", "read+extract s", "preset", "method", "raw", "features", "precision", "recall",
               "redundancy", "compression", "fusion s")
    for col in columns:
        table.add_column(col, justify="right")
    rows, failures = [], []
    for name in args.logs:
        path = args.data_dir / f"{name}-corrected.log.gz"
        log, segments, scan, points, seconds = extract_log(path, extraction)
        figure_maps, figure_scores = {}, {}
        for preset, config in presets.items():
            for method in FUSION_METHODS:
                start = time.perf_counter()
                result = fuse(method, segments, scan, config.fusion)
                fusion_s = time.perf_counter() - start
                m = truth_free_metrics(result.segments, points, segments, metric)
                row = (name, str(len(log)), f"{seconds:.2f}", preset, method, str(len(segments)), str(m.count),
                       f"{m.precision:.3f}", f"{m.recall:.3f}", f"{m.redundancy:.3f}", f"{m.compression:.1f}",
                       f"{fusion_s:.2f}")
                rows.append(row)
                table.add_row(*row)
                if args.failure_modes:
                    failures.append((name, preset, method, failure_modes(result.segments, result.labels,
                                                                        segments, points)))
                if method == "proposed" and preset != "default":
                    figure_maps[preset], figure_scores[preset] = result.segments, m
        table.add_section()
        if args.figures is not None:
            plot_log(args.figures / f"{name}.png", name, points, figure_maps, figure_scores)
    console = Console(width=160)
    console.print(table)
    if failures:
        ftable = Table(title="failure modes (issue 10): doorway spans 0.6-1.6 m, farthest line sample from any "
                             "point, lines across two walls >= 1 m apart, duplicate rows, wall points lost "
                             "with dropped clusters")
        for col in ("log", "preset", "method", "door spans", "max off m", "two walls", "duplicates", "lost wall pts"):
            ftable.add_column(col, justify="right")
        for name, preset, method, f in failures:
            ftable.add_row(name, preset, method, str(f["door_spans"]), f"{f['max_off_m']:.2f}", str(f["two_walls"]),
                           str(f["duplicates"]), f"{f['lost_wall_points']:.3f}")
        console.print(ftable)
    if args.markdown is not None:
        lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
        lines += ["| " + " | ".join(r) + " |" for r in rows]
        args.markdown.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
