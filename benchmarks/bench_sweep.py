"""Time a 100-combination sweep of the proposed method on the default drive's cached segments (target < 1 min).

    .venv/bin/python benchmarks/bench_sweep.py [--workers 2]

Uses ``configs/sweeps/proposed_grid.yaml`` (5 delta x 4 gamma x 5 eta) against the segments of the
default drive (extracted and cached on first use), writing into a temporary folder.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import yaml
from rich.console import Console
from rich.table import Table

from featmap.pipeline import local_executor
from featmap.sweep import run_sweep_file

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args()
    spec = yaml.safe_load((ROOT / "configs" / "sweeps" / "proposed_grid.yaml").read_text())
    spec.pop("input")
    spec["drive"] = "default"
    spec["base"] = str(ROOT / "configs" / "default.yaml")
    table = Table(title="100-combination sweep of the proposed method (default drive, cached segments)")
    for col in ("workers", "combinations", "seconds"):
        table.add_column(col, justify="right")
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "sweep.yaml"
        path.write_text(yaml.safe_dump(spec))
        run_sweep_file(path, Path(tmp) / "warmup")          # extraction cache, imports
        for workers in args.workers:
            start = time.perf_counter()
            with local_executor(workers) as executor:
                rows, _ = run_sweep_file(path, Path(tmp) / f"w{workers}", executor)
            table.add_row(str(workers), str(len(rows)), f"{time.perf_counter() - start:.1f}")
    Console().print(table)


if __name__ == "__main__":
    main()
