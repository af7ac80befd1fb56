"""Per-scan observation recall of the extraction on featmap's own (tuning) worlds, at every range.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_extraction_recall.py [--worlds residential:hdl64 prescan_case2:vlp32]
        [--step 10] [--noise 0.02] [--set extraction.key=value ...]
    PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_extraction_recall.py --run RUN_DIR --truth DRIVE/truth

The second form scores a finished ``featmap run`` of a simulated drive instead: its segments.csv against
the drive's truth/coverage.npz (returns within the simulator's truth range, 50 m by default), frame by
frame, with the same observation rule.

For every ``step``-th pose of a world's route, the scan is ray-cast in memory with the simulator's scene
and sensor (the same geometry ``featmap simulate`` writes, fresh range noise), so the wall each return
hit is known at any range, not only within the 50 m of the drive's ``truth/``. An *observation* is a
(scan, building wall) pair with >= 50 returns and >= 2 m observed (0.5 m bins with >= 3 returns); it is
*found* when the scan's segments, moved to the world frame, lie on (0.30 m, 10 deg) at least
min(1 m, half) of its observed length. Precision is the share of segment length (0.1 m samples) lying
on some building wall. These worlds are the ones the defaults were tuned on: they are not a held-out
test (benchmarks/bench_generalization.py is).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from rich.console import Console
from rich.table import Table

from featmap.pipeline.config import load_config
from featmap.evaluation.truth_metrics import lies_on
from featmap.extraction import extract_scan, segments_to_world
from featmap.simulation.scene import build_scene, cast
from featmap.simulation.sensors import SENSORS
from featmap.simulation.simulate import rotation_xyz, synthetic_T_velo_imu
from featmap.simulation.trajectory import sample_poses
from featmap.simulation.worlds import building_edges, load_world

BIN_M, MIN_BIN_RETURNS, MIN_HITS, MIN_OBSERVED_M = 0.5, 3, 50, 2.0
RANGE_BANDS = [(0, 30), (30, 50), (50, 80), (80, 1e9)]
HIT_BANDS = [(50, 300), (300, 1000), (1000, 10**9)]


def labelled_scans(world_name: str, sensor_name: str, step: int, noise: float, seed: int = 0):
    """Yield (points (N, 4) velodyne frame, wall index per point (N,) or -1, range (N,), T_w_velo (4, 4),
    true world hit positions (N, 3)) for every ``step``-th frame of the world's route."""
    world = load_world(world_name)
    sensor = SENSORS[sensor_name]
    scene, index = build_scene(world)
    directions = sensor.ray_directions()
    xy, yaw = sample_poses(np.asarray(world.route.waypoints), world.route.speed_mps, world.route.turn_radius_m, sensor.rate_hz)
    T_imu_velo = np.linalg.inv(synthetic_T_velo_imu())
    imu_z = sensor.height_m - T_imu_velo[2, 3]
    rng = np.random.default_rng(seed)
    for k in range(0, len(xy), step):
        T = np.eye(4)
        T[:3, :3] = rotation_xyz(0.0, 0.0, yaw[k])
        T[:3, 3] = (xy[k, 0], xy[k, 1], imu_z)
        T = T @ T_imu_velo
        t, gid, prim = cast(scene, T[:3, 3], directions @ T[:3, :3].T)
        keep = np.isfinite(t) & (t <= sensor.max_range_m) & (t >= sensor.min_range_m)
        r = t[keep] + rng.normal(0.0, noise, int(keep.sum()))
        points = np.column_stack([directions[keep] * r[:, None], np.full(len(r), 0.3)]).astype(np.float32)
        wall = np.full(len(r), -1)
        on_wall = gid[keep] == index.wall_geometry_id
        wall[on_wall] = index.wall_edge_of_triangle[prim[keep][on_wall]]
        hits = T[:3, 3] + (directions[keep] @ T[:3, :3].T) * t[keep, None]
        yield points, wall, t[keep], T, hits


def _samples(segments: np.ndarray, step: float = 0.1):
    pts, dirs = [], []
    for s in segments:
        length = np.hypot(s[2] - s[0], s[3] - s[1])
        n = max(2, int(np.ceil(length / step)) + 1)
        pts.append(s[:2] + np.linspace(0, 1, n)[:, None] * (s[2:] - s[:2]))
        dirs.append(np.tile((s[2:] - s[:2]) / max(length, 1e-9), (n, 1)))
    return (np.concatenate(pts), np.concatenate(dirs)) if pts else (np.zeros((0, 2)), np.zeros((0, 2)))


def score_scan(walls: np.ndarray, segments_world: np.ndarray, wall: np.ndarray, hit_range: np.ndarray, hits: np.ndarray):
    """Observations of one scan as (hits, range, observed m, found) rows, and (samples on walls, samples)."""
    pts, dirs = _samples(segments_world)
    on_any = np.zeros(len(pts), bool)
    rows = []
    for w in np.unique(wall[wall >= 0]):
        p, q = walls[w, :2], walls[w, 2:]
        length = np.hypot(*(q - p))
        n_bins = max(1, int(np.ceil(length / BIN_M)))
        mine = wall == w
        along = (hits[mine, :2] - p) @ ((q - p) / length)
        seen = np.bincount(np.clip((along / BIN_M).astype(int), 0, n_bins - 1), minlength=n_bins) >= MIN_BIN_RETURNS
        covered = np.zeros(n_bins, bool)
        if len(pts):
            ok, _ = lies_on(pts, dirs, walls[w])
            on_any |= ok
            t = (pts[ok] - p) @ ((q - p) / length)
            covered[np.clip((t / BIN_M).astype(int), 0, n_bins - 1)] = True
        observed = seen.sum() * BIN_M
        if mine.sum() >= MIN_HITS and observed >= MIN_OBSERVED_M:
            rows.append((int(mine.sum()), float(np.median(hit_range[mine])), observed,
                         (covered & seen).sum() * BIN_M >= min(1.0, 0.5 * observed)))
    return rows, int(on_any.sum()), len(pts)


def run(world_name: str, sensor_name: str, step: int, noise: float, extraction_config):
    world = load_world(world_name)
    walls = np.array([np.concatenate([e["p"], e["q"]]) for e in building_edges(world)]).reshape(-1, 4)
    rows, on_wall, samples, seconds, counts = [], 0, 0, [], []
    for points, wall, hit_range, T, hits in labelled_scans(world_name, sensor_name, step, noise):
        start = time.perf_counter()
        result = extract_scan(points, 3, extraction_config)
        seconds.append(time.perf_counter() - start)
        counts.append(len(result))
        scan_rows, on, n = score_scan(walls, segments_to_world(result, T), wall, hit_range, hits)
        rows += scan_rows
        on_wall += on
        samples += n
    return np.array(rows, float).reshape(-1, 4), on_wall / max(samples, 1), seconds, counts


def run_folder_recall(run_dir, truth_dir):
    """(observations (O, 4) rows as in ``score_scan`` (range unknown: nan), precision) of a run's
    segments.csv against a simulated drive's truth/coverage.npz."""
    import csv
    from pathlib import Path

    from featmap.evaluation import load_simulator_truth

    truth = load_simulator_truth(truth_dir)
    cov = np.load(Path(truth_dir) / "coverage.npz")
    offset, bin_m, min_ret = cov["bin_offset"], float(cov["bin_m"]), int(cov["min_bin_returns"])
    wall_of_bin = np.repeat(np.arange(len(offset) - 1), np.diff(offset))
    with open(Path(run_dir) / "segments.csv", newline="") as fh:
        table = [(int(r["scan"]), [float(r[c]) for c in ("x1", "y1", "x2", "y2")]) for r in csv.DictReader(fh)]
    scans = np.array([t[0] for t in table])
    segs = np.array([t[1] for t in table]).reshape(-1, 4)
    rows, on_wall, samples = [], 0, 0
    for frame in np.unique(cov["frame"]):
        sel = cov["frame"] == frame
        bins, counts = cov["bin"][sel], cov["count"][sel]
        pts, dirs = _samples(segs[scans == frame])
        on_any = np.zeros(len(pts), bool)
        for w in range(len(truth.walls)):
            if len(pts):
                ok, _ = lies_on(pts, dirs, truth.walls[w])
                on_any |= ok
            mine = wall_of_bin[bins] == w
            if not mine.any():
                continue
            seen = np.zeros(offset[w + 1] - offset[w], bool)
            seen[bins[mine][counts[mine] >= min_ret] - offset[w]] = True
            p, q = truth.walls[w, :2], truth.walls[w, 2:]
            covered = np.zeros(len(seen), bool)
            if len(pts):
                t = (pts[ok] - p) @ ((q - p) / np.hypot(*(q - p)))
                covered[np.clip((t / bin_m).astype(int), 0, len(seen) - 1)] = True
            observed = seen.sum() * bin_m
            if counts[mine].sum() >= MIN_HITS and observed >= MIN_OBSERVED_M:
                rows.append((int(counts[mine].sum()), np.nan, observed, (covered & seen).sum() * bin_m >= min(1.0, 0.5 * observed)))
        on_wall += int(on_any.sum())
        samples += len(pts)
    return np.array(rows, float).reshape(-1, 4), on_wall / max(samples, 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--worlds", nargs="+", default=["residential:hdl64", "prescan_case1:vlp32", "prescan_case2:vlp32"])
    parser.add_argument("--step", type=int, default=10, help="every step-th frame of the route")
    parser.add_argument("--noise", type=float, default=0.02)
    parser.add_argument("--set", action="append", default=[], dest="overrides")
    parser.add_argument("--run", help="score this featmap run folder's segments.csv instead (with --truth)")
    parser.add_argument("--truth", help="the simulated drive's truth/ folder")
    args = parser.parse_args()
    if args.run:
        obs, precision = run_folder_recall(args.run, args.truth)
        found = obs[:, 3].astype(bool)
        bands = " ".join(f"{a}-{b}: {found[m].mean():.3f} ({int(m.sum())})" for a, b in HIT_BANDS
                         for m in [(obs[:, 0] >= a) & (obs[:, 0] < b)] if m.any())
        print(f"{args.run}: {len(obs)} observations within the truth range, per-scan recall {found.mean():.3f} "
              f"(by returns {bands}); segment length on building walls {precision:.3f}")
        return
    config = load_config(None, args.overrides)
    table = Table(title=f"per-scan observation recall, tuning worlds (extraction.method_3d = {config.extraction.method_3d})")
    for col in ["world:sensor", "scans", "observations", "recall", *(f"{a}-{b} hits" if b < 10**9 else f">={a} hits" for a, b in HIT_BANDS),
                *(f"{a:.0f}-{b:.0f} m" if b < 1e9 else f">={a:.0f} m" for a, b in RANGE_BANDS), "precision", "segments/scan", "ms/scan"]:
        table.add_column(col, justify="right")
    for spec in args.worlds:
        world_name, sensor_name = spec.split(":")
        obs, precision, seconds, counts = run(world_name, sensor_name, args.step, args.noise, config.extraction)
        found = obs[:, 3].astype(bool)

        def band(mask):
            return f"{found[mask].mean():.3f} ({int(mask.sum())})" if mask.any() else "-"

        table.add_row(spec, str(len(seconds)), str(len(obs)), f"{found.mean():.3f}",
                      *(band((obs[:, 0] >= a) & (obs[:, 0] < b)) for a, b in HIT_BANDS),
                      *(band((obs[:, 1] >= a) & (obs[:, 1] < b)) for a, b in RANGE_BANDS),
                      f"{precision:.3f}", f"{statistics.median(counts):.0f}", f"{1000 * statistics.median(seconds):.0f}")
    Console(width=240).print(table)


if __name__ == "__main__":
    main()
