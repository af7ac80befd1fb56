"""Fusion cost against map size, for every registered method (the paper's Table 3, at scale).

    .venv/bin/python benchmarks/bench_fusion.py [--sizes 1000 10000 100000 1000000] [--methods proposed ...]

Synthetic maps: building walls of 5-50 m along a street grid (parallel walls 15 m apart on both
sides of each street), each wall seen in 20 scans with 3 cm endpoint noise and random partial
extents. Prints a table of median wall-clock seconds (of --repeats runs) and peak traced memory
(tracemalloc, a separate run), including corner optimisation.
"""

from __future__ import annotations

import argparse
import statistics
import time
import tracemalloc

import numpy as np
from rich.console import Console
from rich.table import Table

from featmap.fusion import FUSION_METHODS, FusionConfig, fuse
from featmap.simulation.segments import city_walls, observe_walls


def make_map(n_segments: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    n_walls = max(1, n_segments // 20)
    walls = city_walls(n_walls, rng)
    return observe_walls(walls, 20, 0.03, rng)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[1_000, 10_000, 100_000, 1_000_000])
    parser.add_argument("--methods", nargs="+", default=list(FUSION_METHODS))
    parser.add_argument("--repeats", type=int, default=3, help="timed runs per size (median is reported); 1 for N >= 1M")
    parser.add_argument("--meanshift-max", type=int, default=100_000,
                        help="skip meanshift above this N (it needs ~8 min per run at 1M on 2 cores)")
    args = parser.parse_args()
    config = FusionConfig()
    table = Table(title="featmap fusion benchmark (median seconds, peak traced MiB)")
    for col in ("method", "N segments", "features out", "median s", "s per 100k", "peak MiB"):
        table.add_column(col, justify="right")
    console = Console()
    for n in args.sizes:
        segs, scan = make_map(n)
        for name in args.methods:
            if name == "meanshift" and n > args.meanshift_max:
                table.add_row(name, f"{len(segs):,}", "skipped", "-", "-", "-")
                continue
            repeats = 1 if n >= 1_000_000 else args.repeats
            times = []
            for _ in range(repeats):
                start = time.perf_counter()
                result = fuse(name, segs, scan, config)
                times.append(time.perf_counter() - start)
            tracemalloc.start()
            fuse(name, segs, scan, config)
            peak = tracemalloc.get_traced_memory()[1] / 2**20
            tracemalloc.stop()
            med = statistics.median(times)
            table.add_row(name, f"{len(segs):,}", f"{len(result):,}", f"{med:.3f}", f"{med / len(segs) * 1e5:.3f}", f"{peak:.0f}")
            console.print(f"  {name:9s} N={len(segs):>9,}  {med:8.3f} s  {peak:7.0f} MiB")
    console.print(table)


if __name__ == "__main__":
    main()
