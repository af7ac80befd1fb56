"""Online mapping: what one more scan costs, and whether it grows as the map grows or its walls are seen again.

    .venv/bin/python benchmarks/bench_online.py                 # all four tables (about 7 minutes)
    .venv/bin/python benchmarks/bench_online.py --docs          # and write them into docs/online.md
    .venv/bin/python benchmarks/bench_online.py --parts revisits --revisits 1 5 20 50 100
    .venv/bin/python benchmarks/bench_online.py --parts heldout --docs   # not in "all": 18 minutes for the 60 held-out worlds with the generalization runs' extraction cache, more from an empty one

Parts:
- ``revisits``: a street grid of 100 walls (featmap.simulation.segments.city_walls) driven K times
  (observe_revisits: per pass every wall is seen in 20 consecutive scans, about 4 walls per scan, 3 cm
  endpoint noise, a per-pass localisation error of 5 cm / 0.1 deg, 5 % clutter; each scan with its sensor
  position, benchmarks/revisited_street.py, for the visibility clause), fed to
  :class:`featmap.fusion.online.OnlineFusion` one scan at a time. Per-scan linking time over the scans
  of the last pass (median and 99th percentile, milliseconds); the time to make the map of everything
  seen (``fused()``) at the end; and, for comparison, fusing the same segments offline from scratch
  (``fuse("proposed")``), what re-making the map after a scan would cost without the online state.
  Each figure is the median of ``--repeats`` feeds (fresh state each time, compiled code loaded first).
- ``corridor``: a long drive in which every scan reaches new grid cells (a 30 km corridor, 1 m per scan, six
  8 m walls per scan): per-scan linking time over the first, middle and last thousand scans (does it grow
  with the map's area?).
- ``noise``: the default drive simulated with 0.10 m / 0.2 deg pose noise (``scripts/reproduce_paper.py``'s
  ``residential_pose_noise``), mapped online with the causal pose correction (``fixed_lag``, the default of
  ``--online``) and without, and offline without refinement and with the pose graph: what mapping online
  costs in accuracy, and the pose correction's time per scan.
- ``heldout``: the causal pose correction against the offline pose graph on drives it was never tuned on:
  ``benchmarks/bench_pose_noise.py --split S --parts sim carmen --methods proposed`` for every held-out
  split S (``featmap.simulation.splits.HELDOUT_SPLITS``: their procedural worlds, and the held-out CARMEN
  log fhw of the first, 0.1 m / 0.2 deg and 0.3 m / 0.5 deg drift, three noise seeds each) once with
  ``--set refinement.method=fixed_lag`` and once with the default pose graph:
  medians over worlds and seeds, the worst world's median, and the trajectory error; for fhw the
  truth-free map metric against its corrected poses. (The fixed-lag settings were chosen on the
  ``noise`` drive above, for speed: accuracy barely moved with them.)
- ``drive``: ``featmap run --online 25`` on the default simulated drive (plots off), with the causal pose
  correction (the default) and with ``--set refinement.method=none``, ``--repeats`` whole processes each,
  interleaved: per-scan extraction and linking (medians over the scans, from metrics.json; then the
  median over the processes), the pose correction's mean time per scan, the map's time, end-to-end scans
  per second, and whether the map is byte for byte the offline one with the same refinement (``featmap
  run --method proposed --set refinement.method=...``; the poses are exact there, so fixed_lag keeps them).

A shared 2-core machine: times are noisy; the medians are what to quote.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from datetime import date
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
N_WALLS = 100
SCANS_PER_WALL = 20


def feed(passes: int, seed: int = 0) -> dict:
    """One street driven ``passes`` times, fed scan by scan; times in seconds."""
    from featmap.fusion.online import OnlineFusion
    from featmap.fusion.registry import FusionConfig, fuse
    from featmap.simulation.segments import city_walls, observe_revisits
    from revisited_street import street_sensor_positions

    rng = np.random.default_rng(seed)
    walls = city_walls(N_WALLS, rng)
    segments, scan = observe_revisits(walls, passes, SCANS_PER_WALL, rng, clutter_fraction=0.05)
    order = np.argsort(scan, kind="stable")
    segments, scan = segments[order], scan[order]
    n_scans = int(scan.max()) + 1
    bounds = np.searchsorted(scan, np.arange(n_scans + 1))
    scan_xy = street_sensor_positions(walls, np.arange(n_scans), SCANS_PER_WALL)    # (S, 2), one per scan
    online = OnlineFusion(FusionConfig())
    link = np.empty(n_scans)
    for s in range(n_scans):
        t0 = time.perf_counter()
        online.add_scan(segments[bounds[s]:bounds[s + 1]], sensor_xy=scan_xy[s])
        link[s] = time.perf_counter() - t0
    t0 = time.perf_counter()
    result = online.fused()
    map_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    offline = fuse("proposed", segments, scan, FusionConfig(), sensor_xy=scan_xy[scan])
    offline_s = time.perf_counter() - t0
    last = link[-(n_scans // passes):]
    return {"segments": len(segments), "scans": n_scans, "features": len(result),
            "same": bool(np.array_equal(result.segments, offline.segments)),
            "link_median_ms": 1e3 * float(np.median(last)), "link_p99_ms": 1e3 * float(np.quantile(last, 0.99)),
            "map_s": map_s, "offline_s": offline_s}


def corridor(n_scans: int, seed: int = 0) -> np.ndarray:
    """Per-scan linking seconds (n_scans,) of a long drive that reaches new grid cells with every scan: 1 m
    per scan along a corridor, six 8 m walls per scan 6 m either side (half of them up to 40 m farther out)."""
    from featmap.fusion.online import OnlineFusion

    rng = np.random.default_rng(seed)
    online = OnlineFusion()
    link = np.empty(n_scans)
    for s in range(n_scans):
        xs = s + rng.uniform(-20, 20, 6)
        ys = rng.choice([-6.0, 6.0], 6) + rng.normal(0, 0.02, 6) + rng.uniform(-40, 40, 6) * (rng.random(6) < 0.5)
        t0 = time.perf_counter()
        online.add_scan(np.stack([xs - 4, ys, xs + 4, ys], 1))
        link[s] = time.perf_counter() - t0
    return link


def part_corridor(n_scans: int, repeats: int) -> tuple[list[str], list[list[str]]]:
    from featmap.fusion.registry import prepare_method

    prepare_method("proposed")
    runs = [corridor(n_scans) for _ in range(repeats)]
    header = ["scans", "link ms per scan (median)", "99th percentile ms"]
    rows = []
    for a in sorted({0, n_scans // 3, 2 * n_scans // 3, n_scans - 1000}):
        block = [r[a:a + 1000] for r in runs]
        rows.append([f"{a + 1:,}-{a + 1000:,}", f"{statistics.median(1e3 * float(np.median(b)) for b in block):.3f}",
                     f"{statistics.median(1e3 * float(np.quantile(b, 0.99)) for b in block):.3f}"])
        print(" | ".join(rows[-1]), flush=True)
    return header, rows


def part_revisits(revisits: list[int], repeats: int) -> tuple[list[str], list[list[str]]]:
    from featmap.fusion.registry import prepare_method

    prepare_method("proposed")
    feed(1, seed=99)                                    # compiled code loaded, caches warm
    header = ["passes", "segments", "scans", "features", "link ms per scan (median / p99, last pass)",
              "map of all s", "offline from scratch s", "same map"]
    rows = []
    for k in revisits:
        runs = [feed(k) for _ in range(repeats)]
        med = {key: statistics.median(r[key] for r in runs) for key in ("link_median_ms", "link_p99_ms", "map_s", "offline_s")}
        r0 = runs[0]
        rows.append([str(k), f"{r0['segments']:,}", f"{r0['scans']:,}", str(r0["features"]),
                     f"{med['link_median_ms']:.2f} / {med['link_p99_ms']:.2f}", f"{med['map_s']:.2f}",
                     f"{med['offline_s']:.2f}", "yes" if all(r["same"] for r in runs) else "NO"])
        print(" | ".join(rows[-1]), flush=True)
    return header, rows


def part_drive(repeats: int) -> tuple[list[str], list[list[str]]]:
    """``featmap run --online 25`` on the default drive with the causal pose correction (the default) and
    without, ``repeats`` processes each, interleaved; each map compared with the offline run's of the same
    refinement."""
    featmap = [sys.executable, "-m", "featmap.cli"]
    quiet = ["--set", "output.plots=false", "--set", "output.html=false", "--set", "output.kml=false"]
    variants = {"residential (default: fixed_lag)": "fixed_lag", "residential, refinement none": "none"}
    stats: dict[str, list[dict]] = {name: [] for name in variants}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for method in variants.values():
            subprocess.run(featmap + ["run", "--method", "proposed", "--set", f"refinement.method={method}", *quiet,
                                      "--out", str(tmp / f"offline_{method}")], check=True, cwd=ROOT, capture_output=True)
        for k in range(repeats):
            for name, method in variants.items():
                out = tmp / f"online_{method}{k}"
                extra = [] if method == "fixed_lag" else ["--set", f"refinement.method={method}"]
                t0 = time.perf_counter()
                subprocess.run(featmap + ["run", "--online", "25", *extra, *quiet, "--out", str(out)], check=True,
                               cwd=ROOT, capture_output=True)
                wall = time.perf_counter() - t0
                metrics = json.loads((out / "metrics.json").read_text())
                t = metrics["timings_s"]
                offline = tmp / f"offline_{method}" / "fused_proposed.csv"
                stats[name].append({"scans": metrics["scans"]["processed"], "extract": t["online_extraction_per_scan_median"],
                                    "refine": t["refinement"], "link": t["online_link_per_scan_median"],
                                    "link_max": t["online_link_per_scan_max"], "map": t["online_map_median"],
                                    "map_max": t["online_map_max"], "total": t["total"], "wall": wall,
                                    "same": (out / "fused_proposed.csv").read_bytes() == offline.read_bytes(),
                                    "features": metrics["methods"]["proposed"]["count"]})
                print(name, stats[name][-1], flush=True)
    header = ["drive", "scans", "extraction ms per scan", "pose correction ms per scan (mean)",
              "linking ms per scan (median / max)", "map every 25 scans ms (median / max)", "scans/s (run total; process)",
              "features", "same map as offline"]
    rows = []
    for name, runs in stats.items():
        med = {key: statistics.median(s[key] for s in runs) for key in runs[0] if key not in ("same",)}
        rows.append([name, str(int(med["scans"])), f"{1e3 * med['extract']:.1f}", f"{1e3 * med['refine'] / med['scans']:.1f}",
                     f"{1e3 * med['link']:.2f} / {1e3 * med['link_max']:.1f}",
                     f"{1e3 * med['map']:.0f} / {1e3 * med['map_max']:.0f}",
                     f"{med['scans'] / med['total']:.1f}; {med['scans'] / med['wall']:.1f}", str(int(med["features"])),
                     "yes" if all(s["same"] for s in runs) else "NO"])
    return header, rows


def part_noise() -> tuple[list[str], list[list[str]]]:
    """What mapping online costs when the poses are noisy: the drive of ``scripts/reproduce_paper.py`` with
    0.10 m / 0.2 deg pose noise, online (no pose refinement) against offline without and with refinement."""
    sys.path.insert(0, str(ROOT / "scripts"))
    from reproduce_paper import DRIVE, drive_for

    root = drive_for("residential_pose_noise")
    featmap = [sys.executable, "-m", "featmap.cli", "run", "--drive", DRIVE, "--data-dir", str(root)]
    quiet = ["--set", "output.plots=false", "--set", "output.html=false", "--set", "output.kml=false"]
    runs = {"online (--online 25: fixed_lag)": ["--online", "25"],
            "online, refinement none": ["--online", "25", "--set", "refinement.method=none"],
            "offline, refinement none": ["--method", "proposed", "--set", "refinement.method=none"],
            "offline, default (pose_graph)": ["--method", "proposed"]}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for k, (name, extra) in enumerate(runs.items()):
            out = Path(tmp) / f"r{k}"
            subprocess.run(featmap + [*extra, *quiet, "--out", str(out)], check=True, cwd=ROOT, capture_output=True)
            truth = json.loads((out / "metrics.json").read_text())["methods"]["proposed"]
            score = truth["scores"]["truth"]
            metrics = json.loads((out / "metrics.json").read_text())
            refine_ms = metrics["timings_s"].get("online_refinement_per_scan_median")
            refine_ms = f"{1e3 * refine_ms:.1f}" if refine_ms is not None else "-"
            rows.append([name, str(truth["count"]), f"{score['precision']:.3f}", f"{score['recall']:.3f}",
                         f"{score['redundancy']:.2f}", f"{score['offset_cm']:.1f}", f"{score['corner_err_cm']:.1f}",
                         refine_ms, f"{metrics['timings_s']['refinement']:.1f}"])
            print(" | ".join(rows[-1]), flush=True)
    header = ["residential_pose_noise (0.10 m / 0.2 deg)", "features", "precision", "recall", "redundancy",
              "offset cm", "corner cm", "refinement ms per scan (median)", "refinement s (total)"]
    return header, rows


def part_heldout() -> tuple[list[str], list[list[str]], list[str], list[list[str]], int]:
    """The held-out pose-noise drives with ``fixed_lag`` and with ``pose_graph`` (see the module doc)."""
    from featmap.simulation.splits import HELDOUT_SPLITS

    levels = ["0.1,0.2", "0.3,0.5"]
    results = {name: {"sim": [], "carmen": []} for name in ("fixed_lag", "pose_graph")}
    with tempfile.TemporaryDirectory() as tmp:
        for split in HELDOUT_SPLITS:
            for name in results:
                out = Path(tmp) / f"{split}_{name}.json"
                subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_pose_noise.py"), "--split", split,
                                "--parts", "sim", "carmen", "--methods", "proposed", "--levels", *levels,
                                "--set", f"refinement.method={name}", "--json", str(out)], check=True, cwd=ROOT)
                found = json.loads(out.read_text())
                for part in ("sim", "carmen"):
                    results[name][part] += found.get(part, [])

    def med(values):
        values = [v for v in values if v is not None and v == v]
        return statistics.median(values) if values else float("nan")

    header = ["drift", "poses", "precision (median / worst world)", "recall (median / worst world)",
              "offset cm", "corner cm", "trajectory error m", "refinement s per drive"]
    rows = []
    for level in ([0.1, 0.2], [0.3, 0.5]):
        first = True
        for name, label in (("fixed_lag", "before (drifting)"), ("fixed_lag", "fixed_lag (online)"),
                            ("pose_graph", "pose_graph (offline)")):
            sel = [r for r in results[name]["sim"] if r["level"] == level]
            state = "before" if label.startswith("before") else "after"
            if state == "before" and not first:
                continue
            first = False
            worlds = sorted({r["world"] for r in sel})
            per_world = {key: [med([r[state]["proposed"][key] for r in sel if r["world"] == w]) for w in worlds]
                         for key in ("precision", "recall")}
            score = {key: med([r[state]["proposed"][key] for r in sel]) for key in ("precision", "recall", "offset_cm",
                                                                                      "corner_err_cm")}
            traj = med([r["traj_before" if state == "before" else "traj_after"][0] for r in sel])
            seconds = "-" if state == "before" else f"{med([r['refinement']['seconds'] for r in sel]):.1f}"
            rows.append([f"{level[0]} m / {level[1]} deg", label,
                         f"{score['precision']:.3f} / {min(per_world['precision']):.3f}",
                         f"{score['recall']:.3f} / {min(per_world['recall']):.3f}", f"{score['offset_cm']:.1f}",
                         f"{score['corner_err_cm']:.1f}", f"{traj:.3f}", seconds])
            print(" | ".join(rows[-1]), flush=True)
    carmen_header = ["fhw (drift on its corrected poses)", "poses", "precision", "recall", "redundancy",
                     "trajectory error m"]
    carmen_rows = []
    for level in ([0.1, 0.2], [0.3, 0.5]):
        for name, label, state in (("fixed_lag", "before (drifting)", "before"), ("fixed_lag", "fixed_lag (online)", "after"),
                                   ("pose_graph", "pose_graph (offline)", "after")):
            sel = [r for r in results[name].get("carmen", []) if r["level"] == level]
            if not sel:
                continue
            m = {key: med([r[state]["proposed"][key] for r in sel]) for key in ("precision", "recall", "redundancy")}
            traj = med([r["traj_before" if state == "before" else "traj_after"][0] for r in sel])
            carmen_rows.append([f"{level[0]} m / {level[1]} deg", label, f"{m['precision']:.3f}", f"{m['recall']:.3f}",
                                f"{m['redundancy']:.3f}", f"{traj:.3f}"])
    n_worlds = len({r["world"] for r in results["pose_graph"]["sim"]})
    return header, rows, carmen_header, carmen_rows, n_worlds


def markdown(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in rows])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--parts", nargs="+", default=["revisits", "corridor", "drive", "noise"],
                        choices=["revisits", "corridor", "drive", "noise", "heldout"])
    parser.add_argument("--corridor-scans", type=int, default=30_000)
    parser.add_argument("--revisits", type=int, nargs="+", default=[1, 5, 20, 50])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--docs", action="store_true", help="write the tables into docs/online.md")
    args = parser.parse_args()
    stamp = f"{platform.machine()}, {date.today().isoformat()}, load {os.getloadavg()[0]:.1f} at the start"
    command = "`.venv/bin/python benchmarks/bench_online.py" + (" " + " ".join(sys.argv[1:]) if sys.argv[1:] else "") + "`"
    tables = {}
    if "revisits" in args.parts:
        header, rows = part_revisits(args.revisits, args.repeats)
        tables["online_revisits"] = (f"{command} ({stamp}); a street of {N_WALLS} walls driven K times, medians of "
                                     f"{args.repeats} feeds:\n\n" + markdown(header, rows))
    if "corridor" in args.parts:
        header, rows = part_corridor(args.corridor_scans, args.repeats)
        tables["online_corridor"] = (f"{command} ({stamp}); a {args.corridor_scans / 1e3:g} km corridor, 1 m and six walls "
                                     f"per scan, every scan reaching new grid cells; medians of {args.repeats} feeds:\n\n"
                                     + markdown(header, rows))
    if "drive" in args.parts:
        header, rows = part_drive(args.repeats)
        tables["online_drive"] = (f"{command} ({stamp}); `featmap run --online 25`, medians of {args.repeats} "
                                  "processes each:\n\n" + markdown(header, rows))
    if "noise" in args.parts:
        header, rows = part_noise()
        tables["online_noise"] = (f"{command} ({stamp}); one run each, scored against the simulator's truth:\n\n"
                                  + markdown(header, rows))
    for body in tables.values():
        print("\n" + body)
    if "heldout" in args.parts:
        header, rows, carmen_header, carmen_rows, n_worlds = part_heldout()
        body = (f"{command} ({stamp}); `bench_pose_noise.py --split S --parts sim carmen --methods proposed` for "
                f"every held-out split S, with each refinement, medians over {n_worlds} held-out worlds x 3 noise "
                "seeds (worst world: its median over the seeds), scored against the simulator's truth:\n\n" + markdown(header, rows))
        if carmen_rows:
            body += ("\n\nThe held-out CARMEN log fhw, drift added to its corrected poses, truth-free metric "
                     "(medians over 3 noise seeds):\n\n" + markdown(carmen_header, carmen_rows))
        tables["online_heldout"] = body
    if args.docs:
        sys.path.insert(0, str(ROOT / "scripts"))
        from doc_blocks import replace_block

        for name, body in tables.items():
            replace_block(ROOT / "docs" / "online.md", name, body)
        print("wrote", ", ".join(tables), "into docs/online.md")


if __name__ == "__main__":
    main()
