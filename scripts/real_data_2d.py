"""Real 2D laser logs (CARMEN) through the whole chain, scored with the truth-free metric.

    .venv/bin/python scripts/real_data_2d.py [--data-dir ../shared/data/carmen_2d] [--logs intel aces fhw]
                                             [--figures docs/figures/real_2d] [--markdown table.md]

For each ``<log>-corrected.log.gz``: read it (featmap.io.carmen), extract lines per scan
(featmap.extraction.lines_2d), move them to the world frame with the corrected poses, fuse them with
the three methods under three presets, ``configs/indoor_2d.yaml`` (featmap's defaults for 2D logs),
``configs/default.yaml`` (the defaults, chosen for KITTI-like drives) and ``configs/paper.yaml`` (the
paper's method as published; the competing methods without refinement, with the paper's midpoint
corners), and score every map against the log's own scan points
(featmap.truth_free: precision, recall, redundancy at 5 cm, count, compression). Prints one table
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

from featmap.config import load_config
from featmap.extraction.lines_2d import Lines2DConfig, extract_lines, lines_to_world
from featmap.fusion import FUSION_METHODS, fuse
from featmap.io.carmen import read_carmen
from featmap.truth_free import TruthFreeConfig, truth_free_metrics

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


def plot_log(path: Path, name: str, points: np.ndarray, maps: dict[str, np.ndarray], scores: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(maps), figsize=(7 * len(maps), 7.2), sharex=True, sharey=True)
    for ax, (title, fused) in zip(np.atleast_1d(axes), maps.items()):
        ax.plot(points[:, 0], points[:, 1], ",", color="0.65", rasterized=True)
        ax.plot(fused[:, [0, 2]].T, fused[:, [1, 3]].T, "-", color="C3", lw=0.9)
        m = scores[title]
        ax.set_title(f"{name}, {title}: {m.count} lines, P {m.precision:.3f}, R {m.recall:.3f}", fontsize=10)
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
    args = parser.parse_args()

    extraction = Lines2DConfig()
    metric = TruthFreeConfig()
    presets = {name: load_config(path) for name, path in PRESETS.items()}
    table = Table(title=f"CARMEN logs, truth-free metric ({metric.tolerance_m * 100:.0f} cm)")
    columns = ("log", "scans", "read+extract s", "preset", "method", "raw", "features", "precision", "recall",
               "redundancy", "compression", "fusion s")
    for col in columns:
        table.add_column(col, justify="right")
    rows = []
    for name in args.logs:
        path = args.data_dir / f"{name}-corrected.log.gz"
        log, segments, scan, points, seconds = extract_log(path, extraction)
        figure_maps, figure_scores = {}, {}
        for preset, config in presets.items():
            for method in FUSION_METHODS:
                start = time.perf_counter()
                result = fuse(method, segments, scan, config)
                fusion_s = time.perf_counter() - start
                m = truth_free_metrics(result.segments, points, segments, metric)
                row = (name, str(len(log)), f"{seconds:.2f}", preset, method, str(len(segments)), str(m.count),
                       f"{m.precision:.3f}", f"{m.recall:.3f}", f"{m.redundancy:.3f}", f"{m.compression:.1f}",
                       f"{fusion_s:.2f}")
                rows.append(row)
                table.add_row(*row)
                if method == "proposed" and preset != "default":
                    figure_maps[preset], figure_scores[preset] = result.segments, m
        table.add_section()
        if args.figures is not None:
            plot_log(args.figures / f"{name}.png", name, points, figure_maps, figure_scores)
    Console(width=160).print(table)
    if args.markdown is not None:
        lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
        lines += ["| " + " | ".join(r) + " |" for r in rows]
        args.markdown.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
