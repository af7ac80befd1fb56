"""Pose-noise benchmark (issue 14): fused maps before and after pose refinement, on drifting poses.

    .venv/bin/python benchmarks/bench_pose_noise.py [--parts sim carmen raw timing] [--split tuning|heldout|heldout2|...]
        [--seeds S ...] [--levels 0.3,0.5 ...] [--noise-seeds 0 1 2] [--methods all] [--set k=v ...] [--json FILE]

Drift is OXTS-like: a first-order Gauss-Markov process per axis (x, y, yaw) with a 5 s correlation time
(:func:`featmap.simulation.simulate.oxts_drift`) at 0.1 m / 0.2 deg, 0.3 m / 0.5 deg and 1.0 m / 1.0 deg,
added to exact poses the way the simulator adds it to OXTS packets (the vehicle body turns about
itself, the sensor rides on it; :func:`~featmap.simulation.simulate.perturb_poses`). The scans are the
exact drive's (extracted once, through the pipeline's cache): only the poses differ, so "before" and
"after" see the same segments.

Parts (``--parts``, default all but timing):

- ``sim``: simulated drives with ground truth: the default ``residential`` drive (tuning split only) and
  the procedural worlds of the split (``TUNING_SEEDS`` or one of the held-out splits of
  ``featmap.simulation.splits.HELDOUT_SPLITS``; never tune on the held-out ones), spread over ``--workers``
  processes. For each world, level and noise seed: the EVALUATION.md metrics (count, precision, recall,
  offset, corner error) of every fusion method on the exact poses, the drifted poses ("before"), the
  refined poses ("after"), and two references that separate what refinement can fix from what it
  cannot: **floor** = the exact map moved by the rigid motion that best fits the drifted positions
  (what a perfect relative refinement anchored on the drifting GPS positions would give: the drift's
  mean over the drive cannot be removed by any refinement) and **aligned** = the refined map moved by
  the rigid motion that best lays it (the first method's map) on the true walls: the refined map's shape;
  trajectory error = mean position / heading error of the sensor poses.
- ``carmen``: the real CARMEN logs with such drift added to their SLAM-corrected poses (intel and aces
  in the tuning split, fhw in the first held-out split; the later held-out splits have no log of their own);
  reference = the corrected poses without refinement.
  Truth-free map metric (precision, recall, count, redundancy) and trajectory error before / after.
- ``raw``: the raw wheel-odometry logs (intel, aces): the truth-free metric of the maps from the raw,
  refined and (as a separate log) corrected poses, and for aces the relation error (Kuemmerle et al.
  2009: translation and rotation error of the relative poses in ``aces.relations``, mean over the
  relations; also split into relations < 2 s, 2-100 s and > 100 s apart).
- ``timing``: whole ``featmap run``s of the residential drive with 0.3 m / 0.5 deg drift, refinement on
  and off (median of ``--repeats``, segments cached) and one run without a cache: what refinement adds
  to a run's time.

Configurations: ``configs/default.yaml`` for simulated drives, the ``indoor_2d`` preset for CARMEN logs
(the defaults a user gets); ``--set`` overrides both (e.g. ``--set refinement.method=scan_to_map``).
Everything is deterministic; noise seed ``k`` of world ``w`` at level ``l`` draws from
``default_rng([w, l, k])``.
"""

from __future__ import annotations

import argparse
import platform
import json
import os
import statistics
import sys
import time
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from featmap.datasets import KittiRawDataset
from featmap.datasets.carmen import CarmenSource
from featmap.errors import FeatmapError
from featmap.evaluation import load_simulator_truth, truth_metrics
from featmap.evaluation.map_metric import truth_free_metrics
from featmap.fusion import fuse
from featmap.fusion.registry import resolve_methods
from featmap.geometry import move_segments_2d, rigid_motion_2d
from featmap.io.carmen import read_relations
from featmap.pipeline import SegmentStore, load_config
from featmap.pipeline.executor import local_executor
from featmap.pipeline.extract import Extraction, extract_source
from featmap.pipeline.refine import refine_extraction
from featmap.refinement import planar_difference
from featmap.simulation.splits import SPLITS, split_seeds
from featmap.simulation.simulate import oxts_drift, perturb_poses

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_generalization import DRIVE, ensure_drive  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
LEVELS = ((0.1, 0.2), (0.3, 0.5), (1.0, 1.0))
TAU_S = 5.0
SIM_KEYS = ("count", "precision", "recall", "offset_cm", "corner_err_cm")
MAP_KEYS = ("count", "precision", "recall", "redundancy")
CARMEN_LOGS = {"tuning": ("intel", "aces"), "heldout": ("fhw",)}
RAW_LOGS = ("aces", "intel")


# --- poses -------------------------------------------------------------------------------------------

def drifted(extraction: Extraction, level: tuple[float, float], seed: list[int],
            T_sensor_body: np.ndarray | None) -> np.ndarray:
    """(F, 4, 4) the extraction's poses with Gauss-Markov drift at ``level`` (m, deg), 5 s correlation."""
    error = oxts_drift(np.random.default_rng(seed), extraction.timestamps, level, TAU_S)
    return perturb_poses(extraction.poses, error, T_sensor_body)


def rigid_fit(poses: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(4, 4) the planar rigid motion C minimising the distance of the positions of ``C @ poses`` to those of
    ``target`` (both (F, 4, 4))."""
    rot, shift = rigid_motion_2d(poses[:, :2, 3], target[:, :2, 3])
    C = np.eye(4)
    C[:2, :2], C[:2, 3] = rot, shift
    return C


def align_to_truth(segments: np.ndarray, walls: np.ndarray, iterations: int = 12) -> np.ndarray:
    """(4, 4) the planar rigid motion that best lays ``segments`` (M, 4) on ``walls`` (W, 4): robust
    point-to-line alignment (the refinement's own segment matching, a Cauchy kernel of 5 cm) with a gate
    shrinking from 1 m to 0.2 m."""
    from featmap.refinement.matching import segment_matches

    C = np.eye(4)
    if not len(segments) or not len(walls):
        return C
    scan = np.r_[np.zeros(len(segments), int), np.ones(len(walls), int)]
    for gate in np.geomspace(1.0, 0.2, iterations):
        cur = move_segments_2d(segments, C[:2, :2], C[:2, 3])
        centre = cur.reshape(-1, 2).mean(axis=0)
        m = segment_matches(np.concatenate([cur, walls]), scan, np.array([[0, 1]]), gate, 10.0, 0.3, 0.5)
        own = m.source == 0
        if own.sum() < 3:
            break
        r, n, arm = m.residuals()[own], m.normal[own], m.point[own] - centre
        jac = np.column_stack([n, n[:, 1] * arm[:, 0] - n[:, 0] * arm[:, 1]])
        w = m.weight[own] / (1 + (r / 0.05) ** 2)
        step = np.linalg.solve((jac * w[:, None]).T @ jac + 1e-9 * np.eye(3), -(jac * w[:, None]).T @ r)
        c, s = np.cos(step[2]), np.sin(step[2])
        D = np.eye(4)
        D[:2, :2] = [[c, -s], [s, c]]
        D[:2, 3] = centre + step[:2] - D[:2, :2] @ centre
        C = D @ C
    return C


def trajectory_error(poses: np.ndarray, reference: np.ndarray) -> tuple[float, float]:
    """Mean position error (m) and mean heading error (deg) of ``poses`` against ``reference``."""
    d = planar_difference(poses, reference)
    return float(np.hypot(d[:, 0], d[:, 1]).mean()), float(np.rad2deg(np.abs(d[:, 2])).mean())


def refined(extraction: Extraction, poses: np.ndarray, config):
    """(refined poses, RefinementRun) of the extraction's scans placed with ``poses`` (drifted or raw
    odometry poses here: never taken as a SLAM result, whatever log they came from)."""
    run = refine_extraction(replace(extraction, poses=poses, slam_poses=False), config.refinement)
    return run.poses, run


# --- scoring -----------------------------------------------------------------------------------------

def fused(extraction: Extraction, poses: np.ndarray, methods: list[str], config) -> dict:
    table = extraction.world_table(poses)
    out = {}
    for name in methods:
        start = time.perf_counter()
        out[name] = (fuse(name, table.segments, table.scan, config.fusion, rms=table.extra.get("rms"),
                           max_gap=table.extra.get("max_gap")),
                     time.perf_counter() - start)
    return out, table


def score_truth(extraction, poses, methods, config, truth) -> dict:
    results, _ = fused(extraction, poses, methods, config)
    out = {}
    for name, (r, s) in results.items():
        m = truth_metrics(r.segments, truth)
        out[name] = {**{k: m[k] for k in SIM_KEYS}, "fusion_s": s}
    return out


def score_map(extraction, poses, methods, config) -> dict:
    results, table = fused(extraction, poses, methods, config)
    points = extraction.world_points(poses)
    out = {}
    for name, (r, s) in results.items():
        m = truth_free_metrics(r.segments, points, table.segments, config.evaluation.map).to_dict()
        out[name] = {**{k: m[k] for k in MAP_KEYS}, "fusion_s": s}
    return out


# --- relation error (Kuemmerle et al. 2009) ----------------------------------------------------------

def relation_errors(poses: np.ndarray, stamps: np.ndarray, relations) -> dict:
    """Mean translation (m) and rotation (deg) error of the relative poses between the scans at the
    relations' timestamps (``stamps`` (F,) absolute, the relations' t1, t2 must be among them)."""
    x = np.column_stack([poses[:, 0, 3], poses[:, 1, 3], np.arctan2(poses[:, 1, 0], poses[:, 0, 0])])
    order = np.argsort(stamps, kind="stable")

    def index(t):
        k = order[np.clip(np.searchsorted(stamps[order], t - 1e-6), 0, len(order) - 1)]
        return k, np.abs(stamps[k] - t) < 1e-3

    i, ok_i = index(relations.t1)
    j, ok_j = index(relations.t2)
    ok = ok_i & ok_j
    i, j, ref = i[ok], j[ok], relations.delta[ok]
    d = x[j, :2] - x[i, :2]
    c, s = np.cos(x[i, 2]), np.sin(x[i, 2])
    est = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], x[j, 2] - x[i, 2]])
    c, s = np.cos(ref[:, 2]), np.sin(ref[:, 2])
    e = est[:, :2] - ref[:, :2]
    trans = np.hypot(c * e[:, 0] + s * e[:, 1], -s * e[:, 0] + c * e[:, 1])
    rot = np.rad2deg(np.abs(np.mod(est[:, 2] - ref[:, 2] + np.pi, 2 * np.pi) - np.pi))
    dt = (relations.t2 - relations.t1)[ok]
    out = {"n": int(ok.sum()), "of": int(len(ok)), "trans_m": float(trans.mean()), "rot_deg": float(rot.mean())}
    for name, lo, hi in (("short", 0, 2), ("mid", 2, 100), ("long", 100, np.inf)):
        m = (dt >= lo) & (dt < hi)
        out[name] = {"n": int(m.sum()), "trans_m": float(trans[m].mean()) if m.any() else None,
                     "rot_deg": float(rot[m].mean()) if m.any() else None}
    return out


# --- parts -------------------------------------------------------------------------------------------

@dataclass
class World:
    name: str
    extraction: Extraction
    T_sensor_body: np.ndarray | None
    truth: object | None = None


def simulated_worlds(args, config, executor, console) -> list[World]:
    from featmap.datasets.simulated import ensure_simulated_drive

    store = SegmentStore(args.cache_dir)
    roots = []
    if args.split == "tuning" and not args.seeds:
        data_dir, drive = ensure_simulated_drive("residential", args.sim_root)
        roots.append(("residential", data_dir, drive))
    for seed in args.seeds or split_seeds(args.split):
        roots.append((f"procedural_{seed}", ensure_drive(args.sim_root, args.split, seed), DRIVE))
    worlds = []
    for name, data_dir, drive in roots:
        ds = KittiRawDataset(data_dir, drive)
        extraction = extract_source(ds, config.extraction, store, executor)
        truth = load_simulator_truth(ds.location / "truth", ds.geo_origin, extraction.frames)
        console.print(f"  {name}: {len(extraction.frames)} scans ({extraction.extracted_now} extracted now)")
        worlds.append(World(name, extraction, ds.T_velo_imu, truth))
    return worlds


def run_sim(args, config, methods, executor, console) -> list[dict]:
    """Every world's rows (:func:`world_rows`), the worlds spread over the executor's processes (each world's
    rows are computed in one process, from seeds that name the world: the same numbers in any order)."""
    console.print(f"[b]simulated drives[/b] ({args.split} split)")
    worlds = simulated_worlds(args, config, executor, console)
    job = partial(world_rows, levels=args.levels, noise_seeds=args.noise_seeds, methods=methods, config=config)
    rows = []
    for per_world in executor.imap(job, worlds):
        for row in per_world:
            console.print(f"  {row['world']} {tuple(row['level'])} seed {row['noise_seed']}: traj "
                          f"{row['traj_before'][0]:.3f} -> {row['traj_after'][0]:.3f} m, refinement "
                          f"{row['refinement']['seconds']:.1f} s")
        rows += per_world
    return rows


def world_rows(world: World, levels, noise_seeds, methods: list[str], config) -> list[dict]:
    """One row per drift level and noise seed of ``world``: scores before / after refinement and the
    references (see the module doc)."""
    e = world.extraction
    exact = score_truth(e, e.poses, methods, config, world.truth)
    rows = []
    for li, level in enumerate(levels):
        for k in noise_seeds:
            seed_key = [zlib_id(world.name), li, k]
            before_poses = drifted(e, level, seed_key, world.T_sensor_body)
            after_poses, run = refined(e, before_poses, config)
            floor_poses = rigid_fit(e.poses, before_poses) @ e.poses
            table = e.world_table(after_poses)
            reference_map = fuse(methods[0], table.segments, table.scan, config.fusion,
                                 rms=table.extra.get("rms"), max_gap=table.extra.get("max_gap")).segments
            walls = world.truth.walls[world.truth.observable()]
            aligned_poses = align_to_truth(reference_map, walls) @ after_poses
            rows.append({"world": world.name, "level": list(level), "noise_seed": k, "scans": len(e.frames),
                         "exact": exact,
                         "before": score_truth(e, before_poses, methods, config, world.truth),
                         "after": score_truth(e, after_poses, methods, config, world.truth),
                         "floor": score_truth(e, floor_poses, methods, config, world.truth),
                         "aligned": score_truth(e, aligned_poses, methods, config, world.truth),
                         "traj_before": trajectory_error(before_poses, e.poses),
                         "traj_after": trajectory_error(after_poses, e.poses),
                         "traj_floor": trajectory_error(floor_poses, e.poses),
                         "refinement": {"applied": bool(run.result.stats.get("applied")), "seconds": run.seconds,
                                        "keyframes": run.result.stats.get("keyframes"),
                                        "residual_before_mm": run.result.stats.get("residual_before_mm"),
                                        "residual_after_mm": run.result.stats.get("residual_after_mm")}})
    return rows


def zlib_id(name: str) -> int:
    import zlib

    return zlib.crc32(name.encode())


def run_carmen(args, config2d, methods, executor, console) -> list[dict]:
    console.print(f"[b]CARMEN logs with drift added to the corrected poses[/b] ({args.split} split)")
    store = SegmentStore(args.cache_dir)
    rows = []
    if not CARMEN_LOGS.get(args.split):
        console.print(f"  no CARMEN log is held out in the {args.split} split: skipped")
    for name in CARMEN_LOGS.get(args.split, ()):
        path = args.data_dir / "carmen_2d" / f"{name}-corrected.log.gz"
        if not path.exists():
            console.print(f"  {path}: not found, skipped")
            continue
        e = extract_source(CarmenSource(path), config2d.extraction, store, executor)
        reference = score_map(e, e.poses, methods, config2d)
        for li, level in enumerate(args.levels):
            for k in args.noise_seeds:
                before_poses = drifted(e, level, [zlib_id(name), li, k], None)
                after_poses, run = refined(e, before_poses, config2d)
                rows.append({"log": name, "level": list(level), "noise_seed": k, "scans": len(e.frames),
                             "reference": reference, "before": score_map(e, before_poses, methods, config2d),
                             "after": score_map(e, after_poses, methods, config2d),
                             "traj_before": trajectory_error(before_poses, e.poses),
                             "traj_after": trajectory_error(after_poses, e.poses),
                             "traj_after_aligned": trajectory_error(rigid_fit(after_poses, e.poses) @ after_poses, e.poses),
                             "refinement": {"applied": bool(run.result.stats.get("applied")), "seconds": run.seconds}})
                console.print(f"  {name} {level} seed {k}: refinement {run.seconds:.1f} s")
    return rows


def run_raw(args, config2d, methods, executor, console) -> list[dict]:
    console.print("[b]raw wheel-odometry logs[/b]")
    store = SegmentStore(args.cache_dir)
    rows = []
    relations_path = args.data_dir / "carmen_2d_raw" / "aces.relations"
    for name in RAW_LOGS:
        path = args.data_dir / "carmen_2d_raw" / f"{name}.clf.bz2"
        corrected = args.data_dir / "carmen_2d" / f"{name}-corrected.log.gz"
        if not path.exists():
            console.print(f"  {path}: not found, skipped")
            continue
        source = CarmenSource(path)
        e = extract_source(source, config2d.extraction, store, executor)
        after_poses, run = refined(e, e.poses, config2d)
        row = {"log": name, "scans": len(e.frames), "raw": score_map(e, e.poses, methods, config2d),
               "refined": score_map(e, after_poses, methods, config2d),
               "refinement": {"applied": bool(run.result.stats.get("applied")), "seconds": run.seconds,
                              "keyframes": run.result.stats.get("keyframes")}}
        if corrected.exists():
            ec = extract_source(CarmenSource(corrected), config2d.extraction, store, executor)
            row["corrected"] = score_map(ec, ec.poses, methods, config2d)
            row["corrected_scans"] = len(ec.frames)
        if name == "aces" and relations_path.exists():
            relations = read_relations(relations_path)
            stamps = e.timestamps + float(source.log.timestamp[0])
            row["relations_raw"] = relation_errors(e.poses, stamps, relations)
            row["relations_refined"] = relation_errors(after_poses, stamps, relations)
        rows.append(row)
        console.print(f"  {name}: {len(e.frames)} scans, refinement {run.seconds:.1f} s")
    return rows


class DriftedSource:
    """A scan source whose poses are replaced (the timing runs): everything else is the wrapped source's."""

    slam_poses = False

    def __init__(self, source, poses: np.ndarray):
        self._source, self._poses = source, poses
        self._position = {f: i for i, f in enumerate(source.frames)}

    def __getattr__(self, name):
        return getattr(self._source, name)

    def __len__(self) -> int:
        return len(self._source)

    def __getitem__(self, i):
        scan = self._source[i]
        return replace(scan, T_world_sensor=self._poses[self._position[scan.index]])

    def poses(self) -> np.ndarray:
        return self._poses


def run_timing(args, console) -> dict:
    import tempfile

    from featmap.datasets.simulated import ensure_simulated_drive
    from featmap.pipeline import MappingPipeline

    console.print("[b]timing[/b]: featmap run on the residential drive with 0.3 m / 0.5 deg drift")
    data_dir, drive = ensure_simulated_drive("residential", args.sim_root)
    ds = KittiRawDataset(data_dir, drive)
    level = (0.3, 0.5)
    error = oxts_drift(np.random.default_rng([zlib_id("residential"), 1, 0]),
                       0.1 * np.asarray(ds.frames, float), level, TAU_S)
    source = DriftedSource(ds, perturb_poses(ds.poses(), error, ds.T_velo_imu))
    out = {"warm": {}, "cold": {}}
    with tempfile.TemporaryDirectory() as tmp, local_executor(args.workers) as executor:
        for method in ("none", "pose_graph"):
            cfg = load_config(None, ["output.plots=false", f"refinement.method={method}", *args.overrides])
            totals, refine_s = [], []
            for r in range(args.repeats + 1):            # the first run fills the cache
                result = MappingPipeline(cfg, resolve_methods(args.methods), SegmentStore(args.cache_dir),
                                         executor).run(source, Path(tmp) / f"{method}{r}")
                if r:
                    totals.append(result.metrics.timings_s["total"])
                    refine_s.append(result.metrics.timings_s["refinement"])
            out["warm"][method] = {"total_s": statistics.median(totals), "refinement_s": statistics.median(refine_s)}
            console.print(f"  cached segments, refinement {method}: total {statistics.median(totals):.1f} s")
        cfg = load_config(None, ["output.plots=false", *args.overrides])
        result = MappingPipeline(cfg, resolve_methods(args.methods), SegmentStore(None), executor).run(
            source, Path(tmp) / "cold")
        t = result.metrics.timings_s
        out["cold"] = {"total_s": t["total"], "refinement_s": t["refinement"], "extraction_s": t["extraction"]}
        console.print(f"  no cache: total {t['total']:.1f} s, of which refinement {t['refinement']:.1f} s")
    return out


# --- report ------------------------------------------------------------------------------------------

def _f(value, fmt: str) -> str:
    return "-" if value is None or (isinstance(value, float) and value != value) else format(value, fmt)


def _median(values):
    values = [v for v in values if v is not None and v == v]
    return statistics.median(values) if values else None


def print_sim(rows: list[dict], methods: list[str], console: Console) -> list:
    tables: list = []
    if not rows:
        return []
    worlds = sorted({r["world"] for r in rows})
    table = Table(title=f"simulated drives: medians over {len(worlds)} world(s) x {len({r['noise_seed'] for r in rows})} "
                        "noise seed(s); drift 5 s Gauss-Markov; floor = exact map on the drifting GPS mean, "
                        "aligned = refined map laid on the truth by one rigid motion")
    for col in ("drift", "method", "poses", "count", "precision", "recall", "offset cm", "corner cm", "traj m", "traj deg"):
        table.add_column(col, justify="left" if col in ("drift", "method", "poses") else "right")
    for level in sorted({tuple(r["level"]) for r in rows}):
        sel = [r for r in rows if tuple(r["level"]) == level]
        for name in methods:
            for state in ("exact", "before", "after", "floor", "aligned"):
                med = {k: _median([r[state][name][k] for r in sel]) for k in SIM_KEYS}
                traj = {"exact": (0.0, 0.0), "before": None, "after": None, "floor": None, "aligned": None}[state]
                if state in ("before", "after", "floor"):
                    key = {"before": "traj_before", "after": "traj_after", "floor": "traj_floor"}[state]
                    traj = (_median([r[key][0] for r in sel]), _median([r[key][1] for r in sel]))
                table.add_row(f"{level[0]} m / {level[1]} deg", name, state, _f(med["count"], ".0f"),
                              _f(med["precision"], ".3f"), _f(med["recall"], ".3f"), _f(med["offset_cm"], ".1f"),
                              _f(med["corner_err_cm"], ".1f"), _f(traj[0] if traj else None, ".3f"),
                              _f(traj[1] if traj else None, ".3f"))
        table.add_section()
    console.print(table)
    tables.append(table)
    table = Table(title="simulated drives, per world (proposed method; medians over noise seeds)")
    for col in ("world", "drift", "scans", "traj m before/after/floor", "precision exact/before/after/floor",
                "recall exact/before/after", "offset cm before/after/floor", "count exact/after", "applied", "refine s"):
        table.add_column(col, justify="left" if col in ("world", "drift") else "right")
    m = "proposed" if "proposed" in methods else methods[0]
    for world in worlds:
        for level in sorted({tuple(r["level"]) for r in rows}):
            sel = [r for r in rows if r["world"] == world and tuple(r["level"]) == level]
            g = lambda state, key: _median([r[state][m][key] for r in sel])  # noqa: E731
            t = lambda key: _median([r[key][0] for r in sel])  # noqa: E731
            table.add_row(world, f"{level[0]}/{level[1]}", str(sel[0]["scans"]),
                          f"{_f(t('traj_before'), '.2f')}/{_f(t('traj_after'), '.2f')}/{_f(t('traj_floor'), '.2f')}",
                          "/".join(_f(g(s, "precision"), ".2f") for s in ("exact", "before", "after", "floor")),
                          "/".join(_f(g(s, "recall"), ".2f") for s in ("exact", "before", "after")),
                          "/".join(_f(g(s, "offset_cm"), ".1f") for s in ("before", "after", "floor")),
                          f"{_f(g('exact', 'count'), '.0f')}/{_f(g('after', 'count'), '.0f')}",
                          f"{sum(r['refinement']['applied'] for r in sel)}/{len(sel)}",
                          _f(_median([r["refinement"]["seconds"] for r in sel]), ".1f"))
    console.print(table)
    tables.append(table)
    return tables


def print_carmen(rows: list[dict], methods: list[str], console: Console) -> list:
    tables: list = []
    if not rows:
        return []
    table = Table(title="CARMEN logs, drift added to the corrected poses (truth-free metric; medians over noise seeds; "
                        "reference = corrected poses, no refinement)")
    for col in ("log", "drift", "method", "poses", "count", "precision", "recall", "redundancy", "traj m", "traj deg",
                "traj m aligned"):
        table.add_column(col, justify="left" if col in ("log", "drift", "method", "poses") else "right")
    for log in sorted({r["log"] for r in rows}):
        for level in sorted({tuple(r["level"]) for r in rows}):
            sel = [r for r in rows if r["log"] == log and tuple(r["level"]) == level]
            for name in methods:
                for state in ("reference", "before", "after"):
                    med = {k: _median([r[state][name][k] for r in sel]) for k in MAP_KEYS}
                    traj = (None, None) if state == "reference" else \
                        tuple(_median([r[f"traj_{state}"][i] for r in sel]) for i in (0, 1))
                    aligned = _median([r["traj_after_aligned"][0] for r in sel]) if state == "after" else None
                    table.add_row(log, f"{level[0]}/{level[1]}", name, state, _f(med["count"], ".0f"),
                                  _f(med["precision"], ".3f"), _f(med["recall"], ".3f"), _f(med["redundancy"], ".3f"),
                                  _f(traj[0], ".3f"), _f(traj[1], ".3f"), _f(aligned, ".3f"))
            table.add_section()
    console.print(table)
    tables.append(table)
    return tables


def print_raw(rows: list[dict], methods: list[str], console: Console) -> list:
    tables: list = []
    if not rows:
        return []
    table = Table(title="raw wheel-odometry logs: truth-free metric of the maps from raw, refined and corrected poses "
                        "(the corrected log is a separate, sparser recording of the same run)")
    for col in ("log", "method", "poses", "scans", "count", "precision", "recall", "redundancy"):
        table.add_column(col, justify="left" if col in ("log", "method", "poses") else "right")
    for row in rows:
        for name in methods:
            for state in ("raw", "refined", "corrected"):
                if state not in row:
                    continue
                m = row[state][name]
                scans = row["corrected_scans"] if state == "corrected" else row["scans"]
                table.add_row(row["log"], name, state, str(scans), _f(m["count"], ".0f"), _f(m["precision"], ".3f"),
                              _f(m["recall"], ".3f"), _f(m["redundancy"], ".3f"))
        table.add_section()
    console.print(table)
    tables.append(table)
    for row in rows:
        if "relations_raw" not in row:
            continue
        table = Table(title=f"{row['log']}: relation error (mean over {row['relations_raw']['n']} of "
                            f"{row['relations_raw']['of']} relations), refinement {row['refinement']['seconds']:.1f} s "
                            f"on {row['refinement']['keyframes']} keyframes")
        for col in ("poses", "translation m", "rotation deg", "< 2 s apart", "2-100 s", "> 100 s (revisits)"):
            table.add_column(col, justify="left" if col == "poses" else "right")
        for state in ("raw", "refined"):
            r = row[f"relations_{state}"]
            parts = [f"{_f(r[k]['trans_m'], '.3f')} m {_f(r[k]['rot_deg'], '.2f')} deg (n={r[k]['n']})"
                     for k in ("short", "mid", "long")]
            table.add_row(state, _f(r["trans_m"], ".3f"), _f(r["rot_deg"], ".2f"), *parts)
        raw, ref = row["relations_raw"], row["relations_refined"]
        table.add_row("raw / refined", _f(raw["trans_m"] / ref["trans_m"], ".1f") + "x",
                      _f(raw["rot_deg"] / ref["rot_deg"], ".1f") + "x", "", "", "")
        console.print(table)
        tables.append(table)
    return tables


def print_timing(timing: dict, console: Console) -> list:
    tables: list = []
    if not timing:
        return []
    w, c = timing["warm"], timing["cold"]
    table = Table(title="what refinement adds to a featmap run (residential, 0.3 m / 0.5 deg drift, all methods; "
                        "cached: medians of --repeats runs)")
    for col in ("run", "total s", "refinement s", "run time vs refinement none", "refinement / rest of the run"):
        table.add_column(col, justify="left" if col == "run" else "right")
    off = w["none"]["total_s"]
    for label, rec in (("segments cached, refinement none", w["none"]), ("segments cached, pose_graph", w["pose_graph"]),
                       ("no cache, pose_graph", c)):
        rest = rec["total_s"] - rec["refinement_s"]
        added = f"{100 * (rec['total_s'] - off) / off:+.0f}%" if rec is w["pose_graph"] else "-"
        table.add_row(label, f"{rec['total_s']:.1f}", f"{rec['refinement_s']:.2f}", added,
                      f"{100 * rec['refinement_s'] / rest:.0f}%" if rest > 0 else "-")
    console.print(table)
    tables.append(table)
    return tables


# --- main --------------------------------------------------------------------------------------------


def argv_text(args) -> list[str]:
    """The options of this run as a user would type them (for the docs)."""
    out = ["--parts", *args.parts]
    if args.split != "tuning":
        out += ["--split", args.split]
    if args.methods != "all":
        out += ["--methods", args.methods]
    return out


def _level(text: str) -> tuple[float, float]:
    try:
        m, deg = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected METRES,DEGREES, e.g. 0.3,0.5") from None
    return m, deg


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--parts", nargs="+", choices=("sim", "carmen", "raw", "timing"), default=["sim", "carmen", "raw"])
    parser.add_argument("--split", choices=tuple(SPLITS), default="tuning")
    parser.add_argument("--seeds", type=int, nargs="+", help="a subset of the split's procedural seeds (no residential)")
    parser.add_argument("--levels", type=_level, nargs="+", default=list(LEVELS), help="drift levels METRES,DEGREES")
    parser.add_argument("--noise-seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--methods", default="all", help="fusion methods (all, or a comma-separated list)")
    parser.add_argument("--set", action="append", default=[], dest="overrides", help="config overrides (all parts)")
    parser.add_argument("--data-dir", type=Path,
                        default=Path(os.environ.get("FEATMAP_SHARED", ROOT / ".." / "shared")) / "data")
    parser.add_argument("--sim-root", type=Path, default=Path("data/sim"), help="where simulated drives are cached")
    parser.add_argument("--cache-dir", type=Path, default=Path("data/cache"), help="content-keyed extraction cache")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=3, help="timing: runs per setting (median)")
    parser.add_argument("--json", type=Path, help="also write every number to this JSON file")
    parser.add_argument("--docs", action="store_true",
                        help="write the tables into docs/pose_refinement.md (blocks pose_<split>_<part>_<k>)")
    args = parser.parse_args(argv)
    console = Console(highlight=False, width=None if os.isatty(1) else 220)
    try:
        return _run(args, console)
    except FeatmapError as exc:
        console.print(f"error: {exc}")
        return 2


def _run(args, console: Console) -> int:
    if args.seeds:
        stray = [s for s in args.seeds if s not in split_seeds(args.split)]
        if stray:
            raise FeatmapError(f"--seeds {stray}: not in the {args.split} split")
    methods = resolve_methods(args.methods)
    config = load_config(None, args.overrides)
    config2d = load_config("indoor_2d", args.overrides)
    out: dict = {"split": args.split, "levels": [list(level) for level in args.levels], "tau_s": TAU_S,
                 "noise_seeds": args.noise_seeds, "overrides": args.overrides}
    start = time.perf_counter()
    with local_executor(max(1, min(2, args.workers))) as executor:
        if "sim" in args.parts:
            out["sim"] = run_sim(args, config, methods, executor, console)
        if "carmen" in args.parts:
            out["carmen"] = run_carmen(args, config2d, methods, executor, console)
        if "raw" in args.parts and args.split == "tuning":
            out["raw"] = run_raw(args, config2d, methods, executor, console)
    if "timing" in args.parts:
        out["timing"] = run_timing(args, console)
    tables = {"sim": print_sim(out.get("sim", []), methods, console),
              "carmen": print_carmen(out.get("carmen", []), methods, console),
              "raw": print_raw(out.get("raw", []), methods, console),
              "timing": print_timing(out.get("timing", {}), console)}
    console.print(f"benchmark took {time.perf_counter() - start:.0f} s")
    if args.docs:
        sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
        from doc_blocks import write_tables

        page = Path(__file__).resolve().parents[1] / "docs" / "pose_refinement.md"
        command = f"`.venv/bin/python benchmarks/bench_pose_noise.py {' '.join(argv_text(args))}`"
        for part, part_tables in tables.items():
            if part_tables:
                write_tables(page, f"pose_{args.split}_{part}", part_tables,
                             f"{command} ({time.strftime('%Y-%m-%d')}, {platform.machine()}):")
        console.print("wrote the tables into docs/pose_refinement.md")
    if args.json:
        from featmap.io.atomic import atomic_write_text

        atomic_write_text(args.json, json.dumps(out, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
