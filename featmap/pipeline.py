"""The mapping pipeline: the one place that loops, times, caches, writes and reports.

``fuse_and_write`` is the fusion-only path (``featmap fuse``); :class:`MappingPipeline` runs a whole
drive (``featmap run``): extraction per scan (cached, resumable, parallel), then every fusion method,
then the writers and the metrics, into one run folder.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from featmap.config import FeatmapConfig, save_config
from featmap.fusion import FusionResult, fuse
from featmap.io.segments_csv import SegmentTable, write_fused_csv

console = Console(highlight=False)


@dataclass(frozen=True)
class MethodRun:
    """One method's result on one input, with its wall-clock time in seconds."""

    name: str
    result: FusionResult
    seconds: float


def run_methods(table: SegmentTable, methods: list[str], config: FeatmapConfig) -> list[MethodRun]:
    """Fuse ``table`` with every method in ``methods`` (corner optimisation included), timing each."""
    runs = []
    for name in methods:
        start = time.perf_counter()
        result = fuse(name, table.segments, table.scan, config)
        runs.append(MethodRun(name, result, time.perf_counter() - start))
    return runs


def summary_table(table: SegmentTable, runs: list[MethodRun], title: str = "featmap fuse") -> Table:
    out = Table(title=title)
    for col in ("method", "segments in", "features out", "clusters dropped", "zero-length skipped", "seconds"):
        out.add_column(col, justify="left" if col == "method" else "right")
    for run in runs:
        r = run.result
        out.add_row(run.name, str(len(table)), str(len(r)), str(r.clusters_dropped),
                    str(r.skipped_zero_length + table.skipped_zero_length), f"{run.seconds:.3f}")
    return out


def fuse_and_write(table: SegmentTable, methods: list[str], config: FeatmapConfig, out: str | Path) -> list[MethodRun]:
    """Fuse a segment table and write ``fused_<method>.csv`` + ``config.yaml`` into ``out``.

    Everything is computed before the first file is written, so a failure leaves nothing behind.
    """
    runs = run_methods(table, methods, config)
    out = Path(out)
    for run in runs:
        write_fused_csv(out / f"fused_{run.name}.csv", run.result.segments, run.result.support)
    save_config(config, out / "config.yaml")
    console.print(summary_table(table, runs))
    if table.skipped_zero_length:
        console.print(f"skipped {table.skipped_zero_length} zero-length row(s) of the input (no direction, no feature circle)")
    console.print(f"wrote {', '.join(f'fused_{r.name}.csv' for r in runs)} and config.yaml to {out}")
    return runs
