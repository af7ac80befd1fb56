"""Simulator speed in frames per second (target: >= 10 frames/s for hdl64 on 2 cores).

    .venv/bin/python benchmarks/bench_simulator.py [--frames 100] [--world residential]

Times ``simulate_drive`` end to end (scene build, ray casting, noise, writing .bin/OXTS/truth) for each
sensor preset, and the ray cast alone, in a temporary folder.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time

import numpy as np
from rich.console import Console
from rich.table import Table

from featmap.simulation.scene import build_scene, cast
from featmap.simulation.sensors import SENSORS
from featmap.simulation.simulate import simulate_drive
from featmap.simulation.worlds import load_world


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--world", default="residential")
    args = parser.parse_args()
    world = load_world(args.world)
    table = Table(title=f"simulator speed ({args.world}, {args.frames} frames)")
    for col in ("sensor", "rays/scan", "cast ms (median)", "end-to-end frames/s"):
        table.add_column(col, justify="right")
    scene, _ = build_scene(world)
    for name, sensor in SENSORS.items():
        dirs = sensor.ray_directions()
        origin = np.array([world.route.waypoints[0][0], world.route.waypoints[0][1], sensor.height_m])
        times = []
        for _ in range(20):
            start = time.perf_counter()
            cast(scene, origin, dirs)
            times.append(time.perf_counter() - start)
        with tempfile.TemporaryDirectory() as tmp:
            start = time.perf_counter()
            drive = simulate_drive(world, tmp, sensor, n_frames=args.frames)
            fps = drive.n_frames / (time.perf_counter() - start)
        table.add_row(name, f"{len(dirs):,}", f"{1000 * statistics.median(times):.1f}", f"{fps:.1f}")
    Console().print(table)


if __name__ == "__main__":
    main()
