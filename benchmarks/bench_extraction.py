"""Extraction speed per scan, with the time per stage (target: >= 25 scans/s on 2 cores).

    .venv/bin/python benchmarks/bench_extraction.py [--frames 0:561:5] [--set extraction.key=value ...] [--real DIR]

Runs on the embedded simulated drive (HDL-64E, ~130k points per scan; simulated on first use).
Reports the median wall-clock and CPU time per stage in one process (reading the scan included as
"read"), then the throughput of the pipeline's extraction loop with 1 and 2 worker processes (no
cache): from starting the pool, and with the pool's processes already started (the steady rate of a
long run). ``--real DIR`` also times the real KITTI scans (*.bin) in DIR, e.g.
../shared/data/kitti_raw_2011_09_26_drive_0001_scans. ``--set extraction.method_3d=ransac_planes`` times
the RANSAC extractor. On a shared machine, CPU time is the steadier number.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from rich.console import Console
from rich.table import Table

from featmap.pipeline.config import load_config
from featmap.datasets import SourceSpec, open_source
from featmap.extraction import extractor_for
from featmap.io.kitti_raw import read_velo_bin
from featmap.pipeline import SegmentStore, local_executor
from featmap.pipeline.extract import extract_source


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", default="0:561:5")
    parser.add_argument("--set", action="append", default=[], dest="overrides")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--real", help="also time the *.bin scans in this folder")
    args = parser.parse_args()
    config = load_config(None, args.overrides)
    ds = open_source(SourceSpec("simulated", "residential", args.frames))
    extractor = extractor_for(3, config.extraction)
    section = getattr(config.extraction, extractor.name)

    def extract_segments(points, _config, timings=None):
        return extractor.extract(points, section, timings)

    console = Console()

    positions = list(range(len(ds)))
    extract_segments(ds[0].points, config.extraction)          # warm-up (imports, first allocation)
    for label, loader, keys in [("simulated drive", ds.__getitem__, positions)] + (
            [("real scans", lambda p: read_velo_bin(p), sorted(Path(args.real).glob("*.bin")))] if args.real else []):
        per_stage: dict[str, list[float]] = {}
        cpu_stage: dict[str, list[float]] = {}
        totals, cpu_totals, counts, points = [], [], [], []
        for key in keys:
            start, cpu = time.perf_counter(), time.process_time()
            item = loader(key)
            pts = item if isinstance(item, np.ndarray) else item.points
            timings: dict[str, float] = {"read": time.perf_counter() - start}
            cpu_read = time.process_time() - cpu
            result = extract_segments(pts, config.extraction, timings)
            totals.append(time.perf_counter() - start)
            cpu_totals.append(time.process_time() - cpu)
            counts.append(len(result))
            points.append(len(pts))
            for stage, sec in timings.items():
                per_stage.setdefault(stage, []).append(sec)
            cpu_stage.setdefault("read", []).append(cpu_read)
        table = Table(title=f"extraction stages, one process, {label} ({len(keys)} scans, median "
                            f"{statistics.median(points):,.0f} points, method {extractor.name})")
        table.add_column("stage")
        table.add_column("median ms (wall)", justify="right")
        for stage, secs in per_stage.items():
            table.add_row(stage, f"{1000 * statistics.median(secs):.1f}")
        table.add_row("total", f"{1000 * statistics.median(totals):.1f}")
        table.add_row("total CPU", f"{1000 * statistics.median(cpu_totals):.1f}")
        table.add_row("scans/s in one process (CPU)", f"{1 / statistics.median(cpu_totals):.1f}")
        table.add_row("segments per scan", f"{statistics.median(counts):.0f}")
        console.print(table)

    table = Table(title="pipeline extraction throughput (read + extract + cache)")
    for col in ("workers", "scans", "seconds", "scans/s", "scans/s, pool started"):
        table.add_column(col, justify="right")
    warm_up = open_source(SourceSpec("simulated", "residential", f"0:{2 * max(args.workers)}"))
    for workers in args.workers:
        with tempfile.TemporaryDirectory() as tmp:
            start = time.perf_counter()
            with local_executor(workers) as executor:
                extract_source(ds, config.extraction, SegmentStore(tmp), executor)
            sec = time.perf_counter() - start
        # The same with the pool's processes started and their modules imported (a run's steady rate:
        # starting 2 spawned processes takes about a second, a fifth of this short benchmark).
        with tempfile.TemporaryDirectory() as tmp, local_executor(workers) as executor:
            extract_source(warm_up, config.extraction, SegmentStore(None), executor)
            start = time.perf_counter()
            extract_source(ds, config.extraction, SegmentStore(tmp), executor)
            warm = time.perf_counter() - start
        table.add_row(str(workers), str(len(ds)), f"{sec:.1f}", f"{len(ds) / sec:.1f}", f"{len(ds) / warm:.1f}")
    console.print(table)


if __name__ == "__main__":
    main()
