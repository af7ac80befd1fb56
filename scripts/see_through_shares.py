"""How much of what lies behind its line each extracted segment lets through, on walls and off them.

    PYTHONPATH=$PWD .venv/bin/python scripts/see_through_shares.py [--seeds 11 12 ...] [--every 4]
        [--data ../shared/data] [--set extraction.vertical_structure.key=value ...]

An investigation of ``sparse_max_through`` (docs/results.md, "Looked up and narrowed"), not a figure of
the README. For every ``--every``-th scan of the given tuning worlds (simulated drives in
``data/sim/tuning``, made by ``benchmarks/bench_generalization.py``; held-out seeds are refused) and for
the eight real KITTI scans, it extracts the segments with the configured ``vertical_structure`` settings
and measures each one's see-through share with
:func:`featmap.extraction.vertical_structure.seen_through`: of the returns (above the local ground) whose
rays cross the segment's line within its azimuth and height, the share that lies more than 0.5 m beyond
it, measured as the extractor measures its pieces, for every segment (not only the sparse ones the
setting asks). A simulated segment is *on a wall* when at least half of it lies on a truth wall
(EVALUATION.md's 0.3 m / 10 deg), a real one when the eye-checked list (tests/extraction/
real_scan_walls.yaml) says it lies on a listed wall or optional structure.

Prints, per threshold, how many segments on walls and off them have a larger share.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.progress import track
from rich.table import Table

from featmap.datasets import KittiRawDataset
from featmap.evaluation import load_simulator_truth
from featmap.evaluation.observation_metrics import lies_on_matrix
from featmap.evaluation.truth_metrics import sample_segments
from featmap.evaluation.wall_lists import read_wall_lists, score_wall_list
from featmap.extraction.base import segments_to_world
from featmap.extraction import vertical_structure as vs
from featmap.io.kitti_raw import read_velo_bin
from featmap.pipeline.config import load_config
from featmap.simulation.splits import held_out_seeds

ROOT = Path(__file__).resolve().parents[1]
DRIVE = "2000_01_01_drive_0001"
THRESHOLDS = (0.05, 0.1, 0.2, 0.3, 0.4, 0.5)


def extract_with_shares(points: np.ndarray, config) -> tuple:
    """The scan's walls as the final tests passed them (sensor frame; before ``extend_hidden_m`` moves
    their ends and joins some, so one share per piece the tests judged), (K,) the see-through share of
    each, measured as the extractor measures its pieces (levelled frame, each piece's height range, the
    scan's azimuth step, from the extraction's ``trace``); and (K,) True for the sparse ones (gaps longer
    than ``max_gap_m``, spanning at least ``min_azimuth_steps``: those ``sparse_max_through`` asks)."""
    trace: dict = {}
    vs.extract_vertical_structure(points, config, trace=trace)
    step = vs._configured_step_deg(trace["config"]) if trace else None
    index = vs.kept_pieces(trace["measures"], trace["final"]) if trace and trace["measures"] is not None else []
    if len(index) == 0 or step is None:
        return vs.ScanSegments.empty(), np.zeros(0), np.zeros(0, bool)
    m = trace["measures"]
    pieces = vs.unlevel_segments(vs.kept_segments(m, trace["final"]), trace["rotation"])
    a, b = m.a[index], m.b[index]
    sparse = vs.sparse_pieces(a, b, m.max_gap[index], step, trace["config"])
    return pieces, vs.seen_through(trace["xyz"], a, b, m.z_min[index], m.z_max[index], np.deg2rad(step)), sparse


def on_walls(world_segments: np.ndarray, walls: np.ndarray) -> np.ndarray:
    """(K,) True where at least half of each (K, 4) segment's length lies on one of the (W, 4) ``walls``."""
    samples, owner, weight = sample_segments(world_segments)
    d = world_segments[:, 2:] - world_segments[:, :2]
    d = d / np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)[:, None]
    on = lies_on_matrix(samples, d[owner], walls).any(1)
    total = np.bincount(owner, weight, len(world_segments))
    return np.bincount(owner, weight * on, len(world_segments)) >= 0.5 * total


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="*", default=[11, 12, 13, 14, 15, 16, 17, 18, 22, 54, 82, 138])
    parser.add_argument("--every", type=int, default=4, help="every n-th scan of each world")
    parser.add_argument("--sim-root", type=Path, default=ROOT / "data" / "sim")
    parser.add_argument("--data", type=Path, default=Path(os.environ.get("FEATMAP_SHARED", ROOT.parent / "shared")) / "data")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    console = Console()
    if args.every < 1:
        print(f"see_through_shares: --every must be at least 1, got {args.every}", file=sys.stderr)
        return 2
    held = sorted(set(args.seeds) & held_out_seeds())
    if held:
        print(f"see_through_shares: --seeds {held} are held out; use tuning or probe worlds", file=sys.stderr)
        return 2
    config = load_config(None, overrides=args.overrides).extraction.vertical_structure
    groups: dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = {"simulated": [], "real": []}
    for seed in args.seeds:
        root = args.sim_root / "tuning" / f"procedural_{seed}"
        if not root.exists():
            print(f"see_through_shares: {root} is missing; simulate it with "
                  f"benchmarks/bench_generalization.py --seeds {seed}", file=sys.stderr)
            return 2
        ds = KittiRawDataset(root, DRIVE)
        walls = load_simulator_truth(ds.location / "truth").walls
        for i in track(range(0, len(ds), args.every), description=f"procedural_{seed}", console=console):
            scan = ds[i]
            found, shares, sparse = extract_with_shares(scan.points, config)
            groups["simulated"].append((shares, on_walls(segments_to_world(found, scan.T_world_sensor), walls), sparse))
    lists = read_wall_lists(ROOT / "tests" / "extraction" / "real_scan_walls.yaml")
    for key, wall_list in lists.scans.items():
        path = args.data / key
        if not path.exists():
            continue
        points = read_velo_bin(path)
        found, shares, sparse = extract_with_shares(points, config)
        status = score_wall_list(found.segments, wall_list).status
        groups["real"].append((shares, np.isin(status, ["wall", "optional"]), sparse))
    if not groups["real"]:
        console.print(f"see_through_shares: no real scan under {args.data}; the real row is left out")
    table = Table(title="segments whose see-through share is above each threshold (on walls / off walls)")
    table.add_column("scans")
    table.add_column("segments on walls / off", justify="right")
    for q in THRESHOLDS:
        table.add_column(f"> {q}", justify="right")
    for name, rows in groups.items():
        if not rows:
            continue
        share, wall, sparse = (np.concatenate([r[i] for r in rows]) for i in range(3))
        for which, sel in (("sparse", sparse), ("all", np.ones(len(share), bool))):
            on, off = wall & sel, ~wall & sel
            table.add_row(f"{name}, {which}", f"{int(on.sum())} / {int(off.sum())}",
                          *[f"{int((on & (share > q)).sum())} / {int((off & (share > q)).sum())}" for q in THRESHOLDS])
        if wall.any():
            console.print(f"{name}: largest share of a segment on a wall {share[wall].max():.2f}"
                          + (f" (sparse: {share[wall & sparse].max():.2f})" if (wall & sparse).any() else ""))
    console.print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
