"""Simulated indoor 2D laser logs that no 2D default was tuned on: featmap's indoor preset against the truth.

    .venv/bin/python benchmarks/bench_indoor_2d.py [--seeds S ...] [--presets indoor_2d paper] [--methods all]
        [--sim-root data/sim/indoor] [--out runs/indoor_2d_sim] [--docs] [--prior-sweep]

The real 2D logs are three (intel and aces chose the ``indoor_2d`` preset, fhw was held out). This adds
floors the preset never saw: :mod:`featmap.simulation.indoor` draws office floors (a ring corridor lined
with rooms, doors, cabinets, on some a round hall) from :data:`~featmap.simulation.indoor.INDOOR_SEEDS`,
and a robot's log of two laps, written as a CARMEN log into ``--sim-root`` and run through the same
pipeline as ``featmap run --carmen LOG --config PRESET`` into ``--out/<floor>/<preset>``.

Per floor, preset and method it prints the run's truth-free metric (precision, recall and redundancy at
5 cm against the log's own scan points, count, compression: what the real logs report, with the same
targets) and **truth precision**: the share of the fused length within 5 cm of a true surface once the
map is laid on the floor by the rigid motion that best maps the run's poses onto the true ones (the
refined map is laid on it the same way). A second table compares, for the proposed method, the indoor
preset's refined poses (held near the log's, which it takes as a SLAM result) with the log's own poses
and with the refinement without that prior, on the whole log and on its first ``FIRST_SCANS`` scans.
``--docs`` writes both into ``docs/simulated_2d.md`` (blocks ``indoor_sim_1``, ``_2``).

``--prior-sweep`` instead runs the floors of :data:`~featmap.simulation.indoor.INDOOR_TUNING_SEEDS` (three
with their logged poses, three with :func:`~featmap.simulation.indoor.drifting_poses`) with each strength
of the SLAM prior in ``PRIOR_SWEEP`` and prints the truth precision of the proposed map (block
``indoor_prior_1``): how the preset's 0.3 m / 2 deg was chosen.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from featmap.datasets.carmen import CarmenSource
from featmap.evaluation.map_metric import SegmentIndex, sample_segments
from featmap.fusion.registry import resolve_methods
from featmap.geometry import move_segments_2d, rigid_motion_2d
from featmap.io.atomic import atomic_write_text
from featmap.io.carmen import flaser_log_text
from featmap.pipeline import MappingPipeline, SegmentStore, load_config
from featmap.reporting import NullReporter
from featmap.simulation.indoor import INDOOR_SEEDS, INDOOR_TUNING_SEEDS, drifting_poses, generate_indoor

ROOT = Path(__file__).resolve().parents[1]
TOLERANCE_M = 0.05


def truth_precision(fused: np.ndarray, surfaces: np.ndarray) -> float:
    """Share of the length of ``fused`` (M, 4) within ``TOLERANCE_M`` of a true surface (S, 4)."""
    points, _, weight = sample_segments(fused, 0.02)
    if not len(points):
        return float("nan")
    near = SegmentIndex(surfaces, TOLERANCE_M).near(points)
    return float(weight[near].sum() / weight.sum())


def write_log(sim_root: Path, seed: int, drift: bool = False):
    """Write floor ``seed``'s log (only when its text changed, so the segment cache stays valid); with
    ``drift`` its poses are :func:`~featmap.simulation.indoor.drifting_poses` instead of the logged ones."""
    drive = generate_indoor(seed)
    path = sim_root / f"floor_{seed}{'_drift' if drift else ''}.log"
    poses = drifting_poses(drive, seed) if drift else drive.logged
    text = flaser_log_text(drive.ranges, poses, drive.stamps,
                           comment=f"featmap simulated floor {seed}: {drive.description}")
    if not path.exists() or path.read_text() != text:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, text)
    return drive, path


FIRST_SCANS = 200
"""The refinement table's partial logs: the first scans of the first lap (no loop closed yet)."""

NO_SLAM_PRIOR = ["refinement.pose_graph.slam_absolute_sigma_m=null", "refinement.pose_graph.slam_absolute_sigma_deg=null"]
POSE_VARIANTS = (("refined (indoor_2d)", []), ("as logged", ["refinement.method=none"]),
                 ("refined, no SLAM prior", NO_SLAM_PRIOR))
"""The refinement table's poses: the preset's (held near the log's SLAM poses by its prior), the log's
own, and the preset's refinement without that prior (the first scan held, as for odometry)."""


def _prior(metres: float, degrees: float) -> list[str]:
    return [f"refinement.pose_graph.slam_absolute_sigma_m={metres}", f"refinement.pose_graph.slam_absolute_sigma_deg={degrees}"]


PRIOR_SWEEP = (("none", NO_SLAM_PRIOR), ("0.1 m / 0.5 deg", _prior(0.1, 0.5)), ("0.2 m / 1 deg", _prior(0.2, 1.0)),
               ("0.3 m / 2 deg", _prior(0.3, 2.0)), ("0.5 m / 3 deg", _prior(0.5, 3.0)), ("1 m / 5 deg", _prior(1.0, 5.0)))
"""``--prior-sweep``: strengths of the SLAM prior tried on the tuning floors (the preset has 0.3 m / 2 deg)."""
TUNING_FLOORS = tuple(zip(INDOOR_TUNING_SEEDS, (True, True, True, False, False, False)))
"""``--prior-sweep``'s logs: (seed of :data:`INDOOR_TUNING_SEEDS`, poses drifting or as logged)."""


def laid_on_floor(result, drive) -> tuple[np.ndarray, np.ndarray, float]:
    """(rot, shift) of the rigid motion that lays ``result``'s map on the floor (its poses onto the true
    ones), and the largest distance of a laid pose from its true position (metres)."""
    true = drive.poses[np.asarray(result.products.frames)][:, :2]
    rot, shift = rigid_motion_2d(result.products.poses[:, :2, 3], true)
    moved = result.products.poses[:, :2, 3] @ rot.T + shift
    return rot, shift, float(np.hypot(*(moved - true).T).max())


def write_docs(prefix: str, tables: list[Table], command: str, start: float) -> None:
    """The tables into ``docs/simulated_2d.md`` (blocks ``<prefix>_1``, ...), captioned with the command."""
    sys.path.insert(0, str(ROOT / "scripts"))
    from doc_blocks import write_tables

    write_tables(ROOT / "docs" / "simulated_2d.md", prefix, tables,
                 f"{command} ({time.strftime('%Y-%m-%d')}, {platform.machine()}, {time.perf_counter() - start:.0f} s):")
    Console().print("wrote the tables into docs/simulated_2d.md")


def prior_sweep(args, store, console) -> Table:
    """Truth precision of the proposed map on the tuning floors for each strength of the SLAM prior."""
    table = Table(title="tuning floors: truth precision of the proposed map (indoor_2d) for each strength of the "
                        "SLAM prior (logs with poses as logged, 1.5 cm / 0.2 deg per scan, or drifting, 5 cm / 0.5 deg "
                        f"slowly varying; whole log and first {FIRST_SCANS} scans)")
    for column in ("floor", "poses", "scans") + tuple(label for label, _ in PRIOR_SWEEP):
        table.add_column(column, justify="left" if column in ("floor", "poses") else "right")
    values: dict[str, list[float]] = {label: [] for label, _ in PRIOR_SWEEP}
    for seed, drift in TUNING_FLOORS:
        drive, path = write_log(args.sim_root, seed, drift)
        for frames in (None, f"0:{FIRST_SCANS}"):
            part = CarmenSource(path, frames)
            row = []
            for label, overrides in PRIOR_SWEEP:
                result = MappingPipeline(load_config("indoor_2d", overrides), ["proposed"], store,
                                         reporter=NullReporter()).run(part, args.out / "prior" / path.stem / label)
                rot, shift, _ = laid_on_floor(result, drive)
                laid = move_segments_2d(result.products.results["proposed"].segments, rot, shift)
                values[label].append(truth_precision(laid, drive.surfaces))
                row.append(f"{values[label][-1]:.3f}")
            table.add_row(str(seed) if frames is None else "", ("drifting" if drift else "as logged") if frames is None else "",
                          str(len(part)), *row)
            console.print(f"  floor {seed} {'drifting' if drift else 'as logged'} {len(part)} scans: {' '.join(row)}")
    table.add_row("worst", "", "", *(f"{min(v):.3f}" for v in values.values()))
    table.add_row("mean", "", "", *(f"{np.mean(v):.3f}" for v in values.values()))
    return table


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=list(INDOOR_SEEDS))
    parser.add_argument("--presets", nargs="+", default=["indoor_2d", "paper"])
    parser.add_argument("--methods", default="all")
    parser.add_argument("--sim-root", type=Path, default=ROOT / "data" / "sim" / "indoor")
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "indoor_2d_sim")
    parser.add_argument("--cache-dir", type=Path, default=ROOT / "data" / "cache")
    parser.add_argument("--docs", action="store_true", help="write the tables into docs/simulated_2d.md")
    parser.add_argument("--prior-sweep", action="store_true",
                        help="instead: the SLAM prior's strengths on the tuning floors (INDOOR_TUNING_SEEDS)")
    args = parser.parse_args(argv)
    if any(seed < 0 for seed in args.seeds):
        parser.error("--seeds: a floor's seed is a non-negative integer")
    console = Console()
    methods = resolve_methods(args.methods)
    store = SegmentStore(args.cache_dir)
    start = time.perf_counter()
    if args.prior_sweep:
        sweep = prior_sweep(args, store, console)
        console.print(sweep)
        console.print(f"took {time.perf_counter() - start:.0f} s")
        if args.docs:
            write_docs("indoor_prior", [sweep], "`.venv/bin/python benchmarks/bench_indoor_2d.py --prior-sweep`", start)
        return 0
    table = Table(title="simulated indoor floors (held out): truth-free metric at 5 cm against the log's scan "
                        "points, and truth precision (fused length within 5 cm of a true surface, map laid on the "
                        "floor by its poses)")
    for column in ("floor", "scans", "preset", "method", "raw segments", "features", "precision", "recall",
                   "redundancy", "compression", "truth precision"):
        table.add_column(column, justify="left" if column in ("floor", "preset", "method") else "right")
    poses_table = Table(title="the indoor preset's pose refinement against the log's own poses (proposed method; "
                              f"two laps, and the first {FIRST_SCANS} scans: no loop closed)")
    for column in ("floor", "scans", "poses", "precision", "recall", "features", "truth precision",
                   "largest pose error after laying on the floor (m)"):
        poses_table.add_column(column, justify="left" if column in ("floor", "poses") else "right")
    for seed in args.seeds:
        drive, path = write_log(args.sim_root, seed)
        source = CarmenSource(path)
        console.print(f"floor {seed}: {drive.description}")
        for preset in args.presets:
            result = MappingPipeline(load_config(preset), methods, store, reporter=NullReporter()).run(
                source, args.out / f"floor_{seed}" / preset)
            rot, shift, _ = laid_on_floor(result, drive)
            for k, method in enumerate(methods):
                m = result.metrics.primary_scores(method)
                laid = move_segments_2d(result.products.results[method].segments, rot, shift)
                table.add_row(f"{seed}" if (preset, k) == (args.presets[0], 0) else "",
                              str(len(source)) if (preset, k) == (args.presets[0], 0) else "",
                              preset if k == 0 else "", method, str(m["raw_count"]), str(m["count"]),
                              f"{m['precision']:.3f}", f"{m['recall']:.3f}", f"{m['redundancy']:.3f}",
                              f"{m['compression']:.1f}", f"{truth_precision(laid, drive.surfaces):.3f}")
        for frames in (None, f"0:{FIRST_SCANS}"):
            part = CarmenSource(path, frames)
            for label, overrides in POSE_VARIANTS:
                result = MappingPipeline(load_config("indoor_2d", overrides), ["proposed"], store,
                                         reporter=NullReporter()).run(part, args.out / f"floor_{seed}" / "poses")
                rot, shift, worst = laid_on_floor(result, drive)
                m = result.metrics.primary_scores("proposed")
                laid = move_segments_2d(result.products.results["proposed"].segments, rot, shift)
                poses_table.add_row(f"{seed}" if (frames, label) == (None, "refined (indoor_2d)") else "",
                                    str(len(part)) if label == POSE_VARIANTS[0][0] else "", label,
                                    f"{m['precision']:.3f}", f"{m['recall']:.3f}", str(m["count"]),
                                    f"{truth_precision(laid, drive.surfaces):.3f}", f"{worst:.3f}")
    console.print(table)
    console.print(poses_table)
    console.print(f"took {time.perf_counter() - start:.0f} s")
    if args.docs:
        command = "`.venv/bin/python benchmarks/bench_indoor_2d.py" + (
            f" --seeds {' '.join(map(str, args.seeds))}`" if list(args.seeds) != list(INDOOR_SEEDS) else "`")
        write_docs("indoor_sim", [table, poses_table], command, start)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
