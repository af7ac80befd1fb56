"""Reading and line extraction of CARMEN logs (target: intel, 910 scans, read + extract < 3 s).

    .venv/bin/python benchmarks/bench_carmen.py [--data-dir ../shared/data] [--repeats 5]

Times featmap.io.carmen.read_carmen and featmap.extraction.lines_2d.extract_lines over every scan of
the corrected Radish logs (and reading alone for the raw .clf logs, 7-14k scans), single process.
Prints medians of --repeats runs.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

from featmap.extraction.lines_2d import extract_lines
from featmap.io.carmen import read_carmen

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data-dir", type=Path,
                        default=Path(os.environ.get("FEATMAP_SHARED", ROOT / ".." / "shared")) / "data")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    table = Table(title="CARMEN read + 2D line extraction (median seconds, one process)")
    for col in ("log", "scans", "read s", "extract s", "read + extract s", "segments"):
        table.add_column(col, justify="right")
    logs = sorted((args.data_dir / "carmen_2d").glob("*-corrected.log.gz")) + \
        sorted((args.data_dir / "carmen_2d_raw").glob("*.clf.bz2"))
    for path in logs:
        extract = path.name.endswith(".log.gz")
        reads, extracts, n_segments = [], [], 0
        for _ in range(args.repeats):
            start = time.perf_counter()
            log = read_carmen(path)
            reads.append(time.perf_counter() - start)
            if extract:
                start = time.perf_counter()
                n_segments = sum(len(extract_lines(log.points(k))) for k in range(len(log)))
                extracts.append(time.perf_counter() - start)
        r = statistics.median(reads)
        e = statistics.median(extracts) if extracts else None
        table.add_row(path.name, f"{len(log):,}", f"{r:.2f}", "-" if e is None else f"{e:.2f}",
                      "-" if e is None else f"{r + e:.2f}", str(n_segments) if extract else "-")
    Console(width=120).print(table)


if __name__ == "__main__":
    main()
