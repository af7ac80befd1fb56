"""Fusion cost when the same walls are seen again and again (revisits), for every method.

    .venv/bin/python benchmarks/bench_fusion_revisits.py                      # the table of the README
    .venv/bin/python benchmarks/bench_fusion_revisits.py --revisits 50 --sizes 2000000 --methods proposed
    .venv/bin/python benchmarks/bench_fusion_revisits.py --exhaustive-max 100000   # also the old pairwise links
    .venv/bin/python benchmarks/bench_fusion_revisits.py --fuse-process       # whole `featmap fuse` processes

Cases:
- ``street kK``: a street grid (featmap.simulation.segments.city_walls) driven K times (observe_revisits): per pass
  every wall is seen in 20 consecutive scans, about 4 walls per scan, partial views (30-100 % of the
  wall), 3 cm endpoint noise, a per-pass localisation error (5 cm, 0.1 deg) and 5 % clutter. The number
  of walls is chosen so that the map has N segments, so each wall is seen 20 K times. Each scan's sensor
  position (revisited_street.py: on the street in front of the wall being passed) is given to the
  fusion, so the proposed method's visibility clause (`visible_share`) runs as in a real drive.
- ``freiburg-like``: a robot driving 8 laps of an office floor's corridor loop (indoor_loop_walls /
  observe_indoor_loop): about 4,800 scans, 6 segments per scan, 213 walls with door gaps, 29k segments,
  1.6 million linked pairs (the real freiburg-079 log: 4,791 scans, 22,710 segments, 2.53 million).

Every (case, method) runs in a fresh process: imports and the one-off compilation or cache load are done
on a tiny input first and reported once (``import s``), never charged to fusion. ``median s`` is the
median wall-clock of ``--repeats`` fusions (corner optimisation included); ``peak MiB`` is the process's
peak resident memory (ru_maxrss: Python, libraries, the input and the fusion).

``--fuse-process`` instead writes the freiburg-like case to a ``segments.csv`` and times whole
``featmap fuse SEGMENTS --method M --out DIR`` processes (start-up, imports, reading, fusion, writing),
median of ``--repeats``, for ``--method proposed`` and ``--method all`` (the command's default).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time

import numpy as np

SCANS_PER_PASS = 20
CLUTTER = 0.05


def make_case(case: str, n_segments: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(segments (N, 4), scan (N,), sensor_xy (N, 2) or None) of one case."""
    from featmap.simulation.segments import city_walls, indoor_loop_walls, observe_indoor_loop, observe_revisits
    from revisited_street import street_sensor_positions

    rng = np.random.default_rng(seed)
    if case == "freiburg-like":
        loop = (120.0, 80.0)
        walls = indoor_loop_walls(rng, loop_m=loop, piece_m=(1.0, 8.0))
        return (*observe_indoor_loop(walls, 8, rng, loop_m=loop, scan_spacing_m=0.67, range_m=5.0, min_view_m=1.0),
                None)
    passes = int(case.split("k")[-1])
    n_walls = max(1, round(n_segments * (1 - CLUTTER) / (SCANS_PER_PASS * passes)))
    walls = city_walls(n_walls, rng)
    segments, scan = observe_revisits(walls, passes, SCANS_PER_PASS, rng, clutter_fraction=CLUTTER)
    return segments, scan, street_sensor_positions(walls, scan, SCANS_PER_PASS)


def worker(case: str, method: str, n_segments: int, repeats: int) -> dict:
    """Runs in its own process: warm up, time ``repeats`` fusions, report peak memory."""
    segments, scan, sensor_xy = make_case(case, n_segments)
    start = time.perf_counter()
    from featmap.fusion.registry import FusionConfig, fuse, prepare_method

    config = FusionConfig()
    if method == "proposed-exhaustive":
        from featmap.fusion import proposed

        proposed.linked_pairs = lambda s, c, cfg, progress=None: proposed.linked_pairs_exhaustive(s, c, cfg)
        name = "proposed"
    else:
        name = method
    prepare_method(name)
    import_s = time.perf_counter() - start
    times, result = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = fuse(name, segments, scan, config, sensor_xy=sensor_xy)
        times.append(time.perf_counter() - t0)
    return {"n": len(segments), "scans": int(len(np.unique(scan))), "features": len(result),
            "links": int(result.extras.get("links_kept", -1)), "median_s": statistics.median(times),
            "min_s": min(times), "max_s": max(times), "import_s": import_s,
            "peak_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--revisits", type=int, nargs="+", default=[1, 5, 20, 50])
    parser.add_argument("--sizes", type=int, nargs="+", default=[100_000, 1_000_000])
    parser.add_argument("--methods", nargs="+", default=["proposed", "density", "meanshift"])
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per case (3 at N >= 1M)")
    parser.add_argument("--meanshift-max", type=int, default=100_000, help="skip meanshift above this N")
    parser.add_argument("--exhaustive-max", type=int, default=0,
                        help="also time the exhaustive pairwise links (the old proposed method) up to this N")
    parser.add_argument("--no-freiburg", action="store_true", help="skip the freiburg-like case")
    parser.add_argument("--fuse-process", action="store_true",
                        help="time whole `featmap fuse` processes on the freiburg-like case instead")
    parser.add_argument("--worker", nargs=4, metavar=("CASE", "METHOD", "N", "REPEATS"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        case, method, n, repeats = args.worker
        print(json.dumps(worker(case, method, int(n), int(repeats))))
        return
    if args.fuse_process:
        fuse_processes(args.repeats)
        return

    cases = [] if args.no_freiburg else [("freiburg-like", 0)]
    cases += [(f"street k{k}", n) for n in args.sizes for k in args.revisits]
    methods = list(args.methods)
    if args.exhaustive_max:
        methods.append("proposed-exhaustive")
    header = f"{'case':15s} {'method':20s} {'N':>10s} {'scans':>8s} {'features':>9s} {'links kept':>11s} " \
             f"{'median s':>9s} {'min-max s':>13s} {'peak MiB':>9s} {'import s':>9s}"
    print(f"load before: {os.getloadavg()[0]:.2f} (1-min load average; 2 cores shared)")
    print(header)
    print("-" * len(header))
    for case, n in cases:
        for method in methods:
            size = 29_200 if case == "freiburg-like" else n
            if (method == "meanshift" and size > args.meanshift_max) or \
                    (method == "proposed-exhaustive" and size > args.exhaustive_max):
                continue
            repeats = args.repeats if size < 1_000_000 else min(args.repeats, 3)
            proc = subprocess.run([sys.executable, __file__, "--worker", case.replace("street ", ""), method,
                                   str(n), str(repeats)], capture_output=True, text=True, check=True)
            r = json.loads(proc.stdout.strip().splitlines()[-1])
            links = f"{r['links']:,}" if r["links"] >= 0 else "-"
            print(f"{case:15s} {method:20s} {r['n']:>10,} {r['scans']:>8,} {r['features']:>9,} {links:>11s} "
                  f"{r['median_s']:>9.3f} {r['min_s']:>6.2f}-{r['max_s']:<6.2f} {r['peak_mib']:>9.0f} "
                  f"{r['import_s']:>9.2f}", flush=True)
    print(f"load after: {os.getloadavg()[0]:.2f}")


def fuse_processes(repeats: int) -> None:
    """Median wall-clock of whole ``featmap fuse`` processes on the freiburg-like segments."""
    import tempfile
    from pathlib import Path

    segments, scan, _ = make_case("freiburg-like", 0)
    featmap = Path(sys.executable).with_name("featmap")
    with tempfile.TemporaryDirectory() as tmp:
        csv = Path(tmp) / "segments.csv"
        rows = np.column_stack([scan, segments])
        np.savetxt(csv, rows, delimiter=",", header="scan,x1,y1,x2,y2", comments="", fmt=["%d"] + ["%.6f"] * 4)
        print(f"load before: {os.getloadavg()[0]:.2f}; featmap fuse on {len(segments):,} segments "
              f"({len(np.unique(scan)):,} scans), median of {repeats}")
        for method in ("proposed", "all"):
            times = []
            for k in range(repeats):
                t0 = time.perf_counter()
                subprocess.run([str(featmap), "fuse", str(csv), "--method", method, "--out", f"{tmp}/out{k}"],
                               check=True, capture_output=True)
                times.append(time.perf_counter() - t0)
            print(f"  --method {method:9s} {statistics.median(times):6.2f} s  (min {min(times):.2f}, max {max(times):.2f})")
        print(f"load after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
