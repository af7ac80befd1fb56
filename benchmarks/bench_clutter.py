"""Segments on clutter in simulated worlds, by what they lie on: the simulated counterpart of the real scans'
segments on hedges, cars and trees.

    .venv/bin/python benchmarks/bench_clutter.py [--world configs/worlds/clutter_street.yaml ...]
        [--set KEY=VALUE ...] [--variant "KEY=VALUE ..." ...] [--workers 2] [--cache-dir data/cache] [--json FILE]
        [--by-object]

For each world (a world file or a built-in name; simulated on first use into ``data/sim/<stem>`` like
``featmap run --world``), extract every scan through the pipeline's loop and cache, fuse the segments with
the proposed method, and put every stretch of a per-scan segment or a fused feature that lies on no
building wall down to the object it lies on (:mod:`featmap.evaluation.clutter`: a hedge, fence, car, pole
or tree of the world, beside a wall, or nothing near). Printed per world and configuration: the per-scan
segments on each kind of clutter per 100 scans, and the proposed map's precision, recall and features on
clutter against the simulator's truth. With ``--variant`` (repeatable) the same worlds again with those
settings on top of ``--set``, for comparing an extraction rule against the configuration without it.
With ``--by-object``, also per world and configuration: each object (by its id in the world file) that
per-scan segments or fused features lie on, and every building lower than ``LOW_WALL_M`` (a garden or
boundary wall) with the segments on its walls, so that a hedge can be set beside a garden wall of its height.

The default world, ``configs/worlds/clutter_street.yaml``, is a development world (not a tuning or a
held-out world): a street of the clutter the real KITTI scans keep as walls (hedges with tree crowns down
to their tops, tall porous bushes in front of facades, vans).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from featmap.datasets import SourceSpec, open_source  # noqa: E402
from featmap.errors import FeatmapError  # noqa: E402
from featmap.evaluation import load_simulator_truth, truth_metrics  # noqa: E402
from featmap.evaluation.clutter import CLUTTER_KINDS, ClutterObjects, OffWall, off_wall, walls_on  # noqa: E402
from featmap.fusion import fuse  # noqa: E402
from featmap.fusion.registry import fuse_columns  # noqa: E402
from featmap.io.sim_truth import read_objects_local  # noqa: E402
from featmap.pipeline import SegmentStore, load_config  # noqa: E402
from featmap.pipeline.executor import ProcessExecutor, SerialExecutor  # noqa: E402
from featmap.pipeline.extract import extract_source  # noqa: E402

DEFAULT_WORLD = ROOT / "configs" / "worlds" / "clutter_street.yaml"
LOW_WALL_M = 3.0
"""``--by-object`` also lists every building lower than this (metres): garden and boundary walls."""
CLUTTER = CLUTTER_KINDS[:5]
"""The kinds that are clutter (not "beside a wall" nor "nothing near")."""


def score(world: str, config, store: SegmentStore, workers: int) -> dict:
    """Extract, fuse (proposed) and sort out the off-wall segments of one world's drive."""
    source = open_source(SourceSpec("simulated", world, None))
    with (ProcessExecutor(workers) if workers > 1 else SerialExecutor()) as executor:
        extraction = extract_source(source, config.extraction, store, executor)
    table = extraction.world_table()
    truth_dir = Path(source.location) / "truth"
    truth = load_simulator_truth(truth_dir)
    records = read_objects_local(truth_dir)
    objects = ClutterObjects.from_records(records)
    result = fuse("proposed", table.segments, table.scan, config.fusion, **fuse_columns(table.extra, len(table)))
    metrics = truth_metrics(result.segments, truth)
    per_scan, fused = off_wall(table.segments, truth, objects), off_wall(result.segments, truth, objects)
    return {"world": Path(world).stem, "scans": len(extraction.frames), "segments": len(table),
            "per_scan_on": per_scan.counts_on(), "features": len(result.segments), "features_on": fused.counts_on(),
            "precision": metrics["precision"], "recall": metrics["recall"],
            "by_object": [*_by_clutter_object(objects, per_scan, fused, table.scan),
                          *_by_low_wall(records, truth, table.segments, result.segments, table.scan)]}


def _by_clutter_object(objects: ClutterObjects, per_scan: OffWall, fused: OffWall, scan: np.ndarray) -> list[dict]:
    """One row per clutter object that a per-scan segment or a fused feature lies on."""
    n = len(objects.names)
    on, fused_on = per_scan.objects_on(n), fused.objects_on(n)
    rows = [{"id": name, "kind": CLUTTER_KINDS[objects.object_kind[i]], "height": _height(objects.heights[i]),
             "segments": int(np.sum(on == i)), "scans": len(np.unique(scan[on == i])),
             "features": int(np.sum(fused_on == i))} for i, name in enumerate(objects.names)]
    return [row for row in rows if row["segments"] or row["features"]]


def _by_low_wall(records: list[dict], truth, segments: np.ndarray, features: np.ndarray, scan: np.ndarray) -> list[dict]:
    """One row per building lower than ``LOW_WALL_M`` (a garden or boundary wall): the per-scan segments
    and fused features on its walls, for comparing with the clutter beside it."""
    def building_on(segs: np.ndarray) -> np.ndarray:
        wall = walls_on(segs, truth)
        return np.where(wall >= 0, truth.building[np.maximum(wall, 0)].astype(object), None)

    on, fused_on = building_on(segments), building_on(features)
    rows = []
    for r in records:
        if r.get("kind") != "building" or not r.get("height", np.inf) < LOW_WALL_M:
            continue
        mine = on == r.get("id")
        rows.append({"id": str(r.get("id")), "kind": "low wall", "height": _height(float(r["height"])),
                     "segments": int(mine.sum()), "scans": len(np.unique(scan[mine])),
                     "features": int(np.sum(fused_on == r.get("id")))})
    return rows


def _height(value: float) -> float | None:
    return None if np.isnan(value) else round(float(value), 2)


def report(rows: list[tuple[str, dict]], console: Console) -> None:
    table = Table(title="per-scan segments on clutter per 100 scans, by kind, and the proposed map")
    for col in ("world", "configuration", "scans", *CLUTTER, "on clutter", "beside a wall", "proposed precision",
                "recall", "features on clutter"):
        table.add_column(col, justify="left" if col in ("world", "configuration") else "right")
    for label, r in rows:
        per100 = [100 * n / r["scans"] for n in r["per_scan_on"]]
        table.add_row(r["world"], label, str(r["scans"]), *(f"{v:.1f}" for v in per100[:5]),
                      f"[b]{sum(per100[:5]):.1f}[/b]", f"{per100[5]:.1f}", f"{r['precision']:.3f}",
                      f"{r['recall']:.3f}", f"{sum(r['features_on'][:5])} of {r['features']}")
    console.print(table)


def report_objects(rows: list[tuple[str, dict]], console: Console) -> None:
    """Per world and configuration, the objects that per-scan segments or fused features lie on."""
    for label, r in rows:
        table = Table(title=f"{r['world']} ({label}): the objects segments lie on, and the walls lower than "
                            f"{LOW_WALL_M:g} m")
        table.add_column("object", no_wrap=True, min_width=max((len(o["id"]) for o in r["by_object"]), default=6))
        table.add_column("kind", no_wrap=True, min_width=8)
        for col in ("height m", "per-scan segments", "in scans", "per 100 scans", "fused features"):
            table.add_column(col, justify="right")
        for o in sorted(r["by_object"], key=lambda o: (-o["segments"], o["id"])):
            table.add_row(o["id"], o["kind"], "-" if o["height"] is None else f"{o['height']:.2f}", str(o["segments"]),
                          str(o["scans"]), f"{100 * o['segments'] / r['scans']:.1f}", str(o["features"]))
        console.print(table)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--world", action="append", default=[], help="a world file or built-in name (repeatable)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--variant", action="append", default=[], metavar='"KEY=VALUE ..."',
                        help="the same worlds again with these settings on top (repeatable)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--cache-dir", type=Path, default=ROOT / "data" / "cache")
    parser.add_argument("--json", type=Path, help="also write the rows here")
    parser.add_argument("--by-object", action="store_true",
                        help="also list, per world, each object that segments lie on (its id, kind and height)")
    args = parser.parse_args(argv)
    console = Console()
    try:
        if args.workers < 1:
            raise FeatmapError(f"--workers {args.workers}: give 1 or more")
        worlds = args.world or [str(DEFAULT_WORLD)]
        configs = [("as configured", load_config(None, args.overrides))]
        for text in args.variant:
            settings = text.split()
            if not settings:
                raise FeatmapError("--variant '': give one or more KEY=VALUE settings")
            configs.append((text, load_config(None, [*args.overrides, *settings])))
        store = SegmentStore(args.cache_dir)
        rows = [(label, score(world, config, store, args.workers)) for world in worlds for label, config in configs]
    except FeatmapError as exc:
        print(f"bench_clutter: error: {exc}", file=sys.stderr)
        return 2
    report(rows, console)
    if args.by_object:
        report_objects(rows, console)
    if args.json:
        from featmap.io.atomic import atomic_write_text

        atomic_write_text(args.json, json.dumps([{"configuration": label, **r} for label, r in rows], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
