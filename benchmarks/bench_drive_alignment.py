"""Merging two drives whose GPS/INS is off as a whole, with and without aligning the drives first.

    .venv/bin/python benchmarks/bench_drive_alignment.py [--pose-noise 1.0,1.0] [--workers 2] [--docs]

Simulates the built-in ``residential`` and ``residential_cross`` drives (two routes over shared streets)
with an OXTS error of ``--pose-noise`` (metres, degrees) that drifts so slowly (correlation time 1000 s)
that each drive is off as a whole, by a different amount: GPS/INS of two different days. Runs them as one
``featmap batch`` (each drive refined on its own, as always) twice: with ``refinement.drives.enabled``
false and true, and prints the merged maps' tables: features, features made of both drives' segments,
the scores against the drives' truths united (they see the true walls, so a drive's whole offset costs
precision and recall as well), and the correction the alignment found. ``--docs`` writes the table into
docs/batch.md (block ``drive_alignment``). About 3 minutes on 2 cores (the simulation is 2 x 50 s).
"""

from __future__ import annotations

import argparse
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DRIVES = (("residential", 1), ("residential_cross", 2))
"""The two drives (built-in worlds) and the seeds of their OXTS errors."""


def main() -> None:
    from featmap.batch import local_cluster, plan_batch, run_batch
    from featmap.io.markdown import markdown_table

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pose-noise", default="1.0,1.0", help="OXTS error: metres, degrees")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--docs", action="store_true", help="write the table into docs/batch.md")
    args = parser.parse_args()
    start = time.time()
    from distributed import Client

    with tempfile.TemporaryDirectory(prefix="featmap_align_") as tmp:
        tmp = Path(tmp)
        sims = [subprocess.Popen([sys.executable, "-m", "featmap.cli", "simulate", "--world", world, "--out",
                                  str(tmp / world), "--pose-noise", args.pose_noise, "--pose-noise-tau", "1000",
                                  "--seed", str(seed)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
                for world, seed in DRIVES]
        for p in sims:
            if p.wait() != 0:
                raise SystemExit(f"simulation failed: {p.stderr.read()}")
        rows = []
        cluster = local_cluster(args.workers)
        with Client(cluster) as client:
            for enabled in (False, True):
                batch = tmp / f"batch_{enabled}.yaml"
                drives = "".join(f"  - {{dataset: kitti_raw, location: {tmp / world / '2000_01_01' / '2000_01_01_drive_0001_sync'}, "
                                 f"name: {world}}}\n" for world, _ in DRIVES)
                batch.write_text(f"methods: [proposed]\ncache_dir: {tmp / 'cache'}\nset: [output.plots=false, "
                                 f"refinement.drives.enabled={str(enabled).lower()}]\ndrives:\n{drives}")
                merged = run_batch(plan_batch(batch, tmp / f"out_{enabled}"), client).merged
                s = merged.scores["proposed"]
                dx, dy, dyaw = merged.drives[1].correction or (0.0, 0.0, 0.0)
                alone = [merged.drive_scores["proposed"][d.name] for d in merged.drives]
                rows.append(["aligned" if enabled else "not aligned", merged.counts["proposed"],
                             merged.multi_drive["proposed"], s["count_ratio"], s["precision"], s["recall"],
                             s["redundancy"], f"{alone[0]['precision']:.3f} / {alone[1]['precision']:.3f}",
                             f"{dx:+.2f}, {dy:+.2f} m, {dyaw:+.2f} deg" if merged.drives[1].correction else "-",
                             f"{merged.seconds:.1f}"])
        cluster.close()
    header = ["drives", "features", "of both drives", "count_ratio", "precision", "recall", "redundancy",
              "precision of each drive alone", f"{DRIVES[1][0]} moved by", "merge s"]
    body = (f"`.venv/bin/python benchmarks/bench_drive_alignment.py --pose-noise {args.pose_noise}` "
            f"({platform.machine()}, {time.strftime('%Y-%m-%d')}, {time.time() - start:.0f} s); proposed method, "
            "scored against the drives' truths united:\n\n" + markdown_table(header, rows, 3))
    print(body)
    if args.docs:
        sys.path.insert(0, str(ROOT / "scripts"))
        from doc_blocks import replace_block

        replace_block(ROOT / "docs" / "batch.md", "drive_alignment", body)


if __name__ == "__main__":
    main()
