"""Four default-size drives as a Dask batch with 1 and 2 workers vs one after another; the task graph's
critical path; the merged map of two drives over the same streets.

    .venv/bin/python benchmarks/bench_batch.py [--repeats 1] [--frames 0:561] [--workers 1 2]

The drives are the residential world's four routes (``residential``, ``residential_cross``,
``residential_reverse``, ``residential_north``; about 540 HDL-64E scans each), simulated into
``data/sim`` on first use (not timed). Every timed run starts from an empty segment cache, runs every
fusion method and writes every output but the PNG overview (which would fetch map tiles):

- ``sequential, featmap run -j 2``: the four drives one after another, each as ``featmap run`` does it
  by default (extraction on a pool of 2 local processes);
- ``sequential, -j 1``: the same in one process;
- ``batch, N workers``: ``featmap batch`` on a LocalCluster of N single-threaded workers (cluster start
  included), one task per drive.

``CPU s`` is the CPU time of the whole case (this process and its worker processes, which are waited
for); ``drive CPU s`` the drive tasks' CPU time. On a machine shared with other jobs the wall-clock
times say how much of the cores we got; the CPU times say whether the batch adds work.

Targets (issue 16): the 2-worker batch within 1.1x of the sequential time on this 2-core machine, near
linear scaling from 1 to 2 workers, and the critical path (longest simulation -> drive -> merge chain)
far below the total work, so more workers would keep scaling until the longest drive. The merged map
of ``residential`` and ``residential_reverse`` (the same streets driven both ways) should have
redundancy <= 1.05 and the recall of the better single drive (scored against both drives' truths,
united, in the first drive's frame).
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import tempfile
import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

WORLDS = ("residential", "residential_cross", "residential_reverse", "residential_north")
SETTINGS = ["output.plots=false"]


def batch_file(folder: Path, cache: Path, frames: str | None) -> Path:
    lines = [f"set: {SETTINGS}", f"cache_dir: {cache}", "sim_root: data/sim", "drives:"]
    for world in WORLDS:
        lines.append(f"  - world: {world}")
        if frames:
            lines.append(f"    frames: '{frames}'")
    path = folder / "bench.yaml"
    path.write_text("\n".join(lines) + "\n")
    return path


def _cpu_seconds() -> float:
    """CPU time of this process and its finished children (the process pools' and the LocalCluster's workers)."""
    import resource

    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def sequential(folder: Path, frames: str | None, workers: int) -> float:
    from featmap.datasets import SourceSpec, open_source
    from featmap.fusion import resolve_methods
    from featmap.pipeline import MappingPipeline, SegmentStore, load_config, local_executor

    cache = folder / "cache"
    start = time.perf_counter()
    for world in WORLDS:     # what `featmap run --world W -j N` does, one drive after the other
        config = load_config(None, SETTINGS)
        source = open_source(SourceSpec("simulated", world, frames))
        with local_executor(workers) as executor:
            MappingPipeline(config, resolve_methods("all"), SegmentStore(cache), executor).run(source, folder / world)
    return time.perf_counter() - start


def batch(folder: Path, frames: str | None, workers: int):
    from distributed import Client

    from featmap.batch import local_cluster, plan_batch, run_batch

    start = time.perf_counter()
    plan = plan_batch(batch_file(folder, folder / "cache", frames), folder / "out")
    cluster = local_cluster(workers)
    client = Client(cluster)
    try:
        result = run_batch(plan, client)
    finally:
        client.close()
        cluster.close()
    return time.perf_counter() - start, result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--frames", default=None, help="a frame selection of every drive (default: all)")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--docs", action="store_true", help="write the tables into docs/batch.md (blocks batch_bench_<k>)")
    args = parser.parse_args()

    from featmap.batch import merge_task
    from featmap.datasets.simulated import ensure_simulated_drive
    from featmap.pipeline import load_config

    for world in WORLDS:
        ensure_simulated_drive(world)                              # not timed
    times: dict[str, list[float]] = {}
    cpu: dict[str, list[float]] = {}
    last = {}
    Path("data").mkdir(exist_ok=True)
    with tempfile.TemporaryDirectory(dir="data", prefix="bench_batch_") as tmp:      # ignored by git if a run is killed
        tmp = Path(tmp)
        for r in range(args.repeats):
            cases = [("sequential, featmap run -j 2", lambda f: sequential(f, args.frames, 2)),
                     ("sequential, -j 1", lambda f: sequential(f, args.frames, 1))]
            cases += [(f"batch, {w} worker{'s' if w > 1 else ''}", (lambda w: lambda f: batch(f, args.frames, w))(w))
                      for w in args.workers]
            for name, run in cases:
                folder = tmp / f"{r}-{''.join(c if c.isalnum() else '_' for c in name)}"
                folder.mkdir()
                cpu0 = _cpu_seconds()
                out = run(folder)
                cpu.setdefault(name, []).append(_cpu_seconds() - cpu0)
                seconds, result = (out, None) if isinstance(out, float) else out
                times.setdefault(name, []).append(seconds)
                if result is not None:
                    last[name] = result
                if r < args.repeats - 1 or result is None:
                    shutil.rmtree(folder, ignore_errors=True)
        console = Console(width=220)
        base = statistics.median(times["sequential, featmap run -j 2"])
        table = Table(title=f"4 drives ({', '.join(WORLDS)}), frames {args.frames or 'all'}; medians of {args.repeats}")
        for col in ("how", "seconds", "vs sequential -j 2", "CPU s", "work s", "drive CPU s", "critical path s",
                    "work / critical path"):
            table.add_column(col, justify="right" if col != "how" else "left")
        for name, values in times.items():
            res = last.get(name)
            s = res.summary if res is not None else None
            table.add_row(name, f"{statistics.median(values):.1f}", f"{statistics.median(values) / base:.2f}x",
                          f"{statistics.median(cpu[name]):.1f}",
                          f"{s.work_seconds:.1f}" if s else "", f"{s.work_cpu_seconds:.1f}" if s else "",
                          f"{s.critical_path_seconds:.1f}" if s else "",
                          f"{s.work_seconds / s.critical_path_seconds:.2f}" if s else "")
        console.print(table)
        tables = [table]
        one = [n for n in times if n.startswith("batch, 1 ")]
        two = [n for n in times if n.startswith("batch, 2 ")]
        scaling = ""
        if one and two:
            scaling = f"scaling 1 -> 2 workers: {statistics.median(times[one[0]]) / statistics.median(times[two[0]]):.2f}x"
            console.print(scaling)
        if two:
            res = last[two[0]]
            drives = Table(title="per drive (2-worker batch)")
            for col in ("drive", "scans", "segments", "proposed", "seconds", "simulation s", "worker"):
                drives.add_column(col)
            for d in res.summary.drives:
                drives.add_row(d.name, str(d.scans), str(d.segments), str(d.counts.get("proposed")), f"{d.seconds:.1f}",
                               f"{d.simulation_seconds:.1f}", d.worker or "")
            console.print(drives)
            tables.append(drives)
            out = Path(res.summary.drives[0].run_dir).parent
            pair = [(d.name, d.run_dir) for d in res.summary.drives if d.name in ("residential", "residential_reverse")]
            config = load_config(None, SETTINGS).model_dump(mode="json")
            merged = {"2 drives, same streets both ways": merge_task(pair, str(out / "merged_pair"),
                                                                     ("proposed", "meanshift", "density"), config),
                      "4 drives": res.merged}
            mt = Table(title="merged maps (scored against the drives' truths united, first drive's frame)")
            for col in ("map", "method", "features", "2+ drives", "count_ratio", "precision", "recall", "redundancy",
                        "recall of each drive alone"):
                mt.add_column(col)
            for label, m in merged.items():
                for method, count in m.counts.items():
                    sc = m.scores.get(method, {})
                    alone = ", ".join(f"{k} {v['recall']:.3f}" for k, v in m.drive_scores.get(method, {}).items())
                    mt.add_row(label, method, str(count), str(m.multi_drive[method]), f"{sc.get('count_ratio', 0):.2f}",
                               f"{sc.get('precision', 0):.3f}", f"{sc.get('recall', 0):.3f}",
                               f"{sc.get('redundancy', 0):.2f}", alone)
            console.print(mt)
            tables.append(mt)
        if args.docs:
            import platform
            import sys

            sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
            from doc_blocks import write_tables

            load = os.getloadavg()[0]
            write_tables(Path(__file__).resolve().parents[1] / "docs" / "batch.md", "batch_bench", tables,
                         f"`.venv/bin/python benchmarks/bench_batch.py {' '.join(sys.argv[1:])}` ({time.strftime('%Y-%m-%d')}, "
                         f"{platform.machine()}, {os.cpu_count()} cores, load {load:.1f} at the end); {scaling}")
            console.print("wrote the tables into docs/batch.md")


if __name__ == "__main__":
    main()
