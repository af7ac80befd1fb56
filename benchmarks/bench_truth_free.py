"""Cost of the truth-free map metric (featmap.evaluation.map_metric) at KITTI-like sizes.

    .venv/bin/python benchmarks/bench_truth_free.py [--points 100000 1000000 3000000] [--repeats 3]

Synthetic map: city walls (featmap.simulation.segments.city_walls), each seen in 20 scans with 3 cm endpoint
noise (the raw segments); the fused map is the walls themselves; the scan points are spread along
the walls with 2 cm noise, plus 20% clutter off the walls. Prints median wall-clock seconds.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from rich.console import Console
from rich.table import Table

from featmap.simulation.segments import city_walls, observe_walls
from featmap.evaluation.map_metric import sample_segments, truth_free_metrics


def make_case(n_points: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    n_walls = max(4, n_points // 4000)                      # ~4000 points per wall, as a few scans give
    walls = city_walls(n_walls, rng)
    raw, _ = observe_walls(walls, 20, 0.03, rng)
    length = np.hypot(walls[:, 2] - walls[:, 0], walls[:, 3] - walls[:, 1]).sum()
    on_wall, _, _ = sample_segments(walls, length / (0.8 * n_points))
    on_wall = on_wall[: int(0.8 * n_points)] + rng.normal(0, 0.02, (min(len(on_wall), int(0.8 * n_points)), 2))
    lo, hi = walls.reshape(-1, 2).min(0), walls.reshape(-1, 2).max(0)
    clutter = rng.uniform(lo, hi, (n_points - len(on_wall), 2))
    return walls, np.concatenate([on_wall, clutter]), raw


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--points", type=int, nargs="+", default=[100_000, 1_000_000, 3_000_000])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    table = Table(title="truth-free metric (median seconds)")
    for col in ("points", "raw segments", "fused", "median s", "precision", "recall"):
        table.add_column(col, justify="right")
    for n in args.points:
        fused, pts, raw = make_case(n)
        times = []
        for _ in range(args.repeats):
            start = time.perf_counter()
            m = truth_free_metrics(fused, pts, raw)
            times.append(time.perf_counter() - start)
        table.add_row(f"{len(pts):,}", f"{len(raw):,}", f"{len(fused):,}", f"{statistics.median(times):.2f}",
                      f"{m.precision:.3f}", f"{m.recall:.3f}")
    Console().print(table)


if __name__ == "__main__":
    main()
