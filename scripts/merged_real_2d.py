"""A batch of two halves of each real 2D log, merged and scored without ground truth; docs/batch.md.

    FEATMAP_SHARED=../shared .venv/bin/python scripts/merged_real_2d.py [--logs intel aces fhw] [--out runs/merged_2d]

For each ``<log>-corrected.log.gz`` in ``$FEATMAP_SHARED/data/carmen_2d``, ``featmap batch`` runs its first
and second half as two drives (the ``indoor_2d`` preset, as ``featmap run --carmen`` picks) on a 2-worker
LocalCluster and merges them: with each half's poses refined on their own, merged as they are and after
aligning the halves (``refinement.drives``, the preset), and with the log's poses; the merged map is scored with the truth-free metric against both halves'
scan points (``featmap.batch.merged_reference``). Beside it: each half's own map against the same points,
and ``featmap run`` over the whole log (one drive: its poses refined together). Writes the table into the
``merged_real_2d`` block of docs/batch.md.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
VARIANTS = (("refined", "refined per half, halves not aligned", ["refinement.drives.enabled=false"]),
            ("aligned", "refined per half, halves aligned (indoor_2d)", []),
            ("logged", "as logged", ["refinement.method=none"]))
"""(folder, label, --set): each half's poses as ``featmap run`` refines them, merged as they are or after
the drives' rigid alignment (the preset), and the log's own (SLAM-corrected) poses."""


def main() -> None:
    from featmap.batch import local_cluster, plan_batch, run_batch
    from featmap.datasets.carmen import CarmenSource
    from featmap.io.markdown import markdown_table
    from featmap.pipeline import MappingPipeline, SegmentStore, load_config
    from featmap.reporting import NullReporter

    sys.path.insert(0, str(ROOT / "scripts"))
    from doc_blocks import replace_block

    shared = Path(os.environ.get("FEATMAP_SHARED", ROOT.parent / "shared"))
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", type=Path, default=shared / "data" / "carmen_2d")
    parser.add_argument("--logs", nargs="+", default=["intel", "aces", "fhw"])
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "merged_2d")
    parser.add_argument("--cache-dir", type=Path, default=ROOT / "data" / "cache")
    args = parser.parse_args()
    start = time.time()
    rows = []
    from distributed import Client

    cluster = local_cluster(2)
    with Client(cluster) as client:
        for name in args.logs:
            log = args.data_dir / f"{name}-corrected.log.gz"
            half = len(CarmenSource(log)) // 2
            for key, poses, extra in VARIANTS:
                folder = args.out / name / key
                folder.mkdir(parents=True, exist_ok=True)
                batch = folder / "batch.yaml"
                sets = ["output.plots=false", *extra]
                batch.write_text(f"cache_dir: {args.cache_dir}\nmethods: [proposed]\nset: {sets}\ndrives:\n"
                                 f"  - {{dataset: carmen, location: {log}, frames: '0:{half}', name: {name}_a}}\n"
                                 f"  - {{dataset: carmen, location: {log}, frames: '{half}:', name: {name}_b}}\n")
                merged = run_batch(plan_batch(batch, folder / "out"), client).merged
                whole = MappingPipeline(load_config("indoor_2d", sets), ["proposed"], SegmentStore(args.cache_dir),
                                        reporter=NullReporter()).run(CarmenSource(log), folder / "whole")
                m, w = merged.scores["proposed"], whole.metrics.primary_scores("proposed")
                halves = [merged.drive_scores["proposed"][d.name]["recall"] for d in merged.drives]
                rows.append([name, poses, merged.evaluator, f"{halves[0]:.3f} / {halves[1]:.3f}", m["count"],
                             m["precision"], m["recall"], m["redundancy"], m["compression"],
                             merged.multi_drive["proposed"], f"{merged.seconds:.1f}", w["count"], w["recall"],
                             w["redundancy"]])
    cluster.close()
    header = ["log", "poses", "scored by", "recall of each half's map", "merged features", "precision", "recall",
              "redundancy", "compression", "seen by both", "merge s", "whole-log run: features", "recall",
              "redundancy"]
    body = (f"`FEATMAP_SHARED=../shared .venv/bin/python scripts/merged_real_2d.py` ({platform.machine()}, "
            f"{time.strftime('%Y-%m-%d')}, {time.time() - start:.0f} s); proposed method, `indoor_2d`; every map "
            "scored against both halves' scan points (placed with the poses their runs used):\n\n" + markdown_table(header, rows))
    replace_block(ROOT / "docs" / "batch.md", "merged_real_2d", body)
    print(body)


if __name__ == "__main__":
    main()
