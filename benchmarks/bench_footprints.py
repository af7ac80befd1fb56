"""Scoring against building footprints: does a run's own observation record agree with the simulator's?

    .venv/bin/python benchmarks/bench_footprints.py [--seeds S ...] [--no-heldout] [--docs]

Building footprints (e.g. OpenStreetMap's) say where the walls are but not what a drive saw of them. A run
given ``evaluation.footprints`` takes that record from its own scans: the stretches of each footprint edge
that the scans' structure points lie on (:func:`featmap.evaluation.references.observe_walls`). This
benchmark checks that record where the answer is known: on simulated drives, whose footprints are
exported by the simulator beside its ground truth (``truth/footprints.geojson``), it runs ``featmap run
--method proposed --set evaluation.footprints=...`` and compares the proposed map's scores against

- the simulator's truth (``scores.truth``: walls with >= 50 returns within 50 m and >= 2 m observed);
- the simulator's per-scan truth, where the drive has one (the procedural worlds): walls seen by a scan
  with >= 50 hits over >= 2 m, no range cap (``bench_generalization.py``'s truth; the rule that the
  footprints' observation follows, with structure points for hits);
- the footprints observed by the run's scans (``scores.footprints``);
- the footprints with every wall counted whole (what the footprints alone give: ``featmap evaluate`` on a
  copy of the file, which no run observed).

Drives: the default ``residential`` drive and the held-out procedural worlds of
``bench_generalization.py`` (simulated on first use; their segments come from the segment cache when
the generalization benchmark ran). About 30 s per drive with a warm cache.

A town: the default drive's footprints inside a 20 km x 20 km grid of 250,000 more houses (1M walls,
none within 600 m of the drive's first building): the run keeps the walls near its scans, so its scores
must equal the drive's own footprints' and its evaluation must take seconds, not the hours one pass over
every wall per map would. Printed below the table: the whole run's time and its evaluation stage's.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from datetime import date
from pathlib import Path

from rich.console import Console
from rich.table import Table

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(ROOT / "scripts"))
from bench_generalization import DRIVE, ensure_drive  # noqa: E402

import numpy as np  # noqa: E402

from featmap.evaluation import load_simulator_truth, truth_metrics  # noqa: E402
from featmap.evaluation.observation_metrics import truth_from_observations  # noqa: E402
from featmap.io.run_metrics import read_run_metrics  # noqa: E402
from featmap.io.segments_csv import read_fused_csv  # noqa: E402
from featmap.io.sim_truth import OBSERVATIONS_FILE, read_observations  # noqa: E402
from featmap.simulation.splits import split_seeds  # noqa: E402

QUIET = ["--set", "output.plots=false", "--set", "output.html=false", "--set", "output.kml=false"]
KEYS = ("observable_walls", "recall", "precision", "corner_err_cm")


def score_drive(root: Path, tmp: Path) -> dict:
    """The proposed map of the drive under ``root`` scored three ways (see the module doc)."""
    footprints = root / DRIVE[:10] / f"{DRIVE}_sync" / "truth" / "footprints.geojson"
    out = tmp / root.name
    subprocess.run([sys.executable, "-m", "featmap.cli", "run", "--drive", DRIVE, "--data-dir", str(root),
                    "--method", "proposed", "--set", f"evaluation.footprints={footprints}", *QUIET, "--out", str(out)],
                   check=True, cwd=ROOT, capture_output=True)
    scores = json.loads((out / "metrics.json").read_text())["methods"]["proposed"]["scores"]
    copy = tmp / f"{root.name}_footprints.geojson"                       # not the run's: counted whole
    shutil.copyfile(footprints, copy)
    subprocess.run([sys.executable, "-m", "featmap.cli", "evaluate", str(out / "fused_proposed.csv"), "--truth",
                    str(copy), "--out", str(tmp / "whole.json")], check=True, cwd=ROOT, capture_output=True)
    whole = json.loads((tmp / "whole.json").read_text())
    per_scan = None
    if (footprints.parent / OBSERVATIONS_FILE).exists():
        frame = read_run_metrics(out / "metrics.json").geo_frame.frame()
        base = load_simulator_truth(footprints.parent, frame)
        obs = read_observations(footprints.parent)
        obs = obs.subset(obs.counting())
        per_scan = truth_metrics(read_fused_csv(out / "fused_proposed.csv")[0],
                                 truth_from_observations(base, obs, np.ones(len(obs), bool)))
    return {"truth": scores["truth"], "per_scan": per_scan, "observed": scores["footprints"], "whole": whole}


def write_town(footprints: Path, out: Path, half_cells: int = 250, spacing_m: float = 40.0, clear_m: float = 600.0) -> int:
    """``footprints`` plus 12 m square houses every ``spacing_m`` on a grid around its first vertex, none
    within ``clear_m`` of it; returns the number of houses added."""
    town = json.loads(footprints.read_text())
    lon0, lat0 = town["features"][0]["geometry"]["coordinates"][0][0]
    m_lat, m_lon = 1 / 111_320.0, 1 / (111_320.0 * np.cos(np.deg2rad(lat0)))
    added = 0
    for i in range(-half_cells, half_cells):
        for j in range(-half_cells, half_cells):
            x, y = i * spacing_m, j * spacing_m
            if abs(x) < clear_m and abs(y) < clear_m:
                continue
            ring = [[lon0 + (x + dx) * m_lon, lat0 + (y + dy) * m_lat]
                    for dx, dy in ((0, 0), (12, 0), (12, 12), (0, 12), (0, 0))]
            town["features"].append({"type": "Feature", "properties": {"id": f"town{added}"},
                                     "geometry": {"type": "Polygon", "coordinates": [ring]}})
            added += 1
    out.write_text(json.dumps(town))
    return added


def score_town(root: Path, tmp: Path) -> dict:
    """The default drive scored against its footprints inside a town (see the module doc)."""
    footprints = root / DRIVE[:10] / f"{DRIVE}_sync" / "truth" / "footprints.geojson"
    houses = write_town(footprints, tmp / "town.geojson")
    out = tmp / "town_run"
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "featmap.cli", "run", "--drive", DRIVE, "--data-dir", str(root),
                    "--method", "proposed", "--set", f"evaluation.footprints={tmp / 'town.geojson'}", *QUIET,
                    "--out", str(out)], check=True, cwd=ROOT, capture_output=True)
    seconds = time.perf_counter() - start
    metrics = json.loads((out / "metrics.json").read_text())
    return {"houses": houses, "seconds": seconds, "evaluation_s": metrics["timings_s"]["evaluation"],
            "scores": metrics["methods"]["proposed"]["scores"]["footprints"]}


def _f(value, fmt: str) -> str:
    return "-" if value is None else format(value, fmt)


def table_rows(results: dict[str, dict]) -> tuple[list[str], list[list[str]]]:
    header = ["drive", "observable walls: truth / per-scan truth / observed / whole",
              "recall: truth / per-scan truth / observed / whole", "precision: truth / observed",
              "corner cm: truth / observed"]
    rows = []
    for name, r in results.items():
        t, p, o, w = r["truth"], r["per_scan"] or {}, r["observed"], r["whole"]
        rows.append([name, f"{t['observable_walls']} / {p.get('observable_walls', '-')} / {o['observable_walls']} / "
                           f"{w['observable_walls']}",
                     f"{t['recall']:.3f} / {_f(p.get('recall'), '.3f')} / {o['recall']:.3f} / {w['recall']:.3f}",
                     f"{t['precision']:.3f} / {o['precision']:.3f}",
                     f"{_f(t['corner_err_cm'], '.1f')} / {_f(o['corner_err_cm'], '.1f')}"])
    for against in ("truth", "per_scan"):
        gaps = [r["observed"]["recall"] - r[against]["recall"] for r in results.values() if r[against] is not None]
        if gaps:
            rows.append([f"observed - {against.replace('_', '-')} recall: median / range, {len(gaps)} drives", "",
                         f"{statistics.median(gaps):+.3f} / {min(gaps):+.3f} to {max(gaps):+.3f}", "", ""])
    return header, rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="*", help="held-out seeds (default: all)")
    parser.add_argument("--no-heldout", action="store_true", help="only the default drive")
    parser.add_argument("--docs", action="store_true", help="write the table into docs/results.md")
    args = parser.parse_args(argv)
    console = Console()
    from reproduce_paper import drive_for

    drives = {"residential (default)": drive_for("residential")}
    if not args.no_heldout:
        for seed in args.seeds or split_seeds("heldout"):
            drives[f"procedural_{seed} (held-out)"] = ensure_drive(ROOT / "data" / "sim", "heldout", seed)
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, root in drives.items():
            results[name] = score_drive(root, Path(tmp))
            r = results[name]
            console.print(f"{name}: recall truth {r['truth']['recall']:.3f}, observed footprints "
                          f"{r['observed']['recall']:.3f}, whole footprints {r['whole']['recall']:.3f}")
        town = score_town(drives["residential (default)"], Path(tmp))
    own = results["residential (default)"]["observed"]
    same = all(town["scores"][k] == own[k] for k in own)
    town_line = (f"The default drive's footprints inside a town of {town['houses']:,} more houses: "
                 f"{'the same scores' if same else 'DIFFERENT scores'} (recall {town['scores']['recall']:.3f}, "
                 f"{town['scores']['observable_walls']} observable walls); the whole run {town['seconds']:.0f} s, "
                 f"its evaluation {town['evaluation_s']:.0f} s.")
    header, rows = table_rows(results)
    table = Table(title="the proposed map scored against the simulator's truth and against footprints")
    for h in header:
        table.add_column(h)
    for row in rows:
        table.add_row(*row)
    console.print(table)
    console.print(town_line)
    if args.docs:
        from doc_blocks import replace_block

        from featmap.io.markdown import markdown_table

        command = "`.venv/bin/python benchmarks/bench_footprints.py --docs`"
        replace_block(ROOT / "docs" / "results.md", "footprints",
                      f"{command}: the proposed map of each drive (default configuration) scored three ways "
                      f"({date.today().isoformat()}).\n\n" + markdown_table(header, rows) + "\n" + town_line)
        console.print("wrote the table into docs/results.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
