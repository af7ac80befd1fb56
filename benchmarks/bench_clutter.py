"""Segments on clutter in simulated worlds, by what they lie on: the simulated counterpart of the real scans'
segments on hedges, cars and trees.

    .venv/bin/python benchmarks/bench_clutter.py [--world configs/worlds/clutter_street.yaml ...]
        [--set KEY=VALUE ...] [--variant "KEY=VALUE ..." ...] [--workers 2] [--cache-dir data/cache] [--json FILE]

For each world (a world file or a built-in name; simulated on first use into ``data/sim/<stem>`` like
``featmap run --world``), extract every scan through the pipeline's loop and cache, fuse the segments with
the proposed method, and put every stretch of a per-scan segment or a fused feature that lies on no
building wall down to the object it lies on (:mod:`featmap.evaluation.clutter`: a hedge, fence, car, pole
or tree of the world, beside a wall, or nothing near). Printed per world and configuration: the per-scan
segments on each kind of clutter per 100 scans, and the proposed map's precision, recall and features on
clutter against the simulator's truth. With ``--variant`` (repeatable) the same worlds again with those
settings on top of ``--set``, for comparing an extraction rule against the configuration without it.

The default world, ``configs/worlds/clutter_street.yaml``, is a development world (not a tuning or a
held-out world): a street of the clutter the real KITTI scans keep as walls (hedges with tree crowns down
to their tops, tall porous bushes in front of facades, vans).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from rich.console import Console
from rich.table import Table

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from featmap.datasets import SourceSpec, open_source  # noqa: E402
from featmap.errors import FeatmapError  # noqa: E402
from featmap.evaluation import load_simulator_truth, truth_metrics  # noqa: E402
from featmap.evaluation.clutter import CLUTTER_KINDS, ClutterObjects, off_wall  # noqa: E402
from featmap.fusion import fuse  # noqa: E402
from featmap.fusion.registry import fuse_columns  # noqa: E402
from featmap.io.sim_truth import read_objects_local  # noqa: E402
from featmap.pipeline import SegmentStore, load_config  # noqa: E402
from featmap.pipeline.executor import ProcessExecutor, SerialExecutor  # noqa: E402
from featmap.pipeline.extract import extract_source  # noqa: E402

DEFAULT_WORLD = ROOT / "configs" / "worlds" / "clutter_street.yaml"
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
    objects = ClutterObjects.from_records(read_objects_local(truth_dir))
    result = fuse("proposed", table.segments, table.scan, config.fusion, **fuse_columns(table.extra, len(table)))
    metrics = truth_metrics(result.segments, truth)
    return {"world": Path(world).stem, "scans": len(extraction.frames), "segments": len(table),
            "per_scan_on": off_wall(table.segments, truth, objects).counts_on(), "features": len(result.segments),
            "features_on": off_wall(result.segments, truth, objects).counts_on(),
            "precision": metrics["precision"], "recall": metrics["recall"]}


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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--world", action="append", default=[], help="a world file or built-in name (repeatable)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--variant", action="append", default=[], metavar='"KEY=VALUE ..."',
                        help="the same worlds again with these settings on top (repeatable)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--cache-dir", type=Path, default=ROOT / "data" / "cache")
    parser.add_argument("--json", type=Path, help="also write the rows here")
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
    if args.json:
        from featmap.io.atomic import atomic_write_text

        atomic_write_text(args.json, json.dumps([{"configuration": label, **r} for label, r in rows], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
