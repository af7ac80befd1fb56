"""Extraction speed per scan, with the time per stage (target: >= 10 scans/s on 2 cores).

    .venv/bin/python benchmarks/bench_extraction.py [--frames 0:561:5] [--set extraction.key=value ...]

Runs on the embedded simulated drive (HDL-64E, ~130k points per scan; simulated on first use).
Reports the median time per stage in one process, then the throughput of the pipeline's
extraction loop with 1 and 2 worker processes (no cache).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time

from rich.console import Console
from rich.table import Table

from featmap.datasets import SourceSpec, open_source
from featmap.extraction.ransac_planes import extract_segments
from featmap.pipeline import SegmentStore, load_config, local_executor
from featmap.pipeline.extract import extract_source


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", default="0:561:5")
    parser.add_argument("--set", action="append", default=[], dest="overrides")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args()
    config = load_config(None, args.overrides)
    ds = open_source(SourceSpec("simulated", "residential", args.frames))
    section = config.extraction.ransac_planes
    console = Console()

    items = [ds[i] for i in range(len(ds))]
    extract_segments(items[0].points, section)          # warm-up (imports, first allocation)
    per_stage: dict[str, list[float]] = {}
    totals, counts, points = [], [], []
    for item in items:
        timings: dict[str, float] = {}
        start = time.perf_counter()
        result = extract_segments(item.points, section, timings)
        totals.append(time.perf_counter() - start)
        counts.append(len(result))
        points.append(len(item.points))
        for stage, sec in timings.items():
            per_stage.setdefault(stage, []).append(sec)
    table = Table(title=f"extraction stages, one process ({len(items)} scans, median {statistics.median(points):,.0f} points)")
    table.add_column("stage")
    table.add_column("median ms", justify="right")
    for stage, secs in per_stage.items():
        table.add_row(stage, f"{1000 * statistics.median(secs):.1f}")
    table.add_row("total", f"{1000 * statistics.median(totals):.1f}")
    table.add_row("segments per scan", f"{statistics.median(counts):.0f}")
    console.print(table)

    table = Table(title="pipeline extraction throughput (read + extract + cache)")
    for col in ("workers", "scans", "seconds", "scans/s"):
        table.add_column(col, justify="right")
    for workers in args.workers:
        with tempfile.TemporaryDirectory() as tmp, local_executor(workers) as executor:
            start = time.perf_counter()
            extract_source(ds, config.extraction, SegmentStore(tmp), executor)
            sec = time.perf_counter() - start
        table.add_row(str(workers), str(len(ds)), f"{sec:.1f}", f"{len(ds) / sec:.1f}")
    console.print(table)


if __name__ == "__main__":
    main()
