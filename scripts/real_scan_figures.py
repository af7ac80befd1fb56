"""Walls found in the eight real KITTI scans: one figure per scan and the table of docs/real_scans.md.

    PYTHONPATH=$PWD .venv/bin/python scripts/real_scan_figures.py [--data ../shared/data]
    PYTHONPATH=$PWD .venv/bin/python scripts/real_scan_figures.py --set extraction.key=value ... --out DIR

Reads the two full raw scans (kitti_raw_2011_09_26_drive_0001_scans/) and the six object-benchmark
crops (kitti_object_velodyne/) from the shared data (default ``$FEATMAP_SHARED/data`` or
``../shared/data``), runs the configured extraction, scores it against the eye-checked lists in
tests/extraction/real_scan_walls.yaml and writes docs/figures/real_scans/<scan>.png and the table
docs/real_scans.md (the same numbers it prints). docs/ holds the default configuration: a run with
``--set`` needs ``--out DIR`` and writes its figures and ``real_scans.md`` there instead.

In the figures: thick green = a listed wall that was found, thick red = missed, dashed grey =
optional structure, dotted orange boxes = cars, hedges and trees; thin lines = extracted segments
(blue on a listed wall, cyan on optional structure, red in a clutter box, purple on nothing listed).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from featmap.errors import FeatmapError
from featmap.extraction import extract_scan
from featmap.extraction.explain import explain_scan
from featmap.geometry import segment_lengths
from featmap.io.atomic import atomic_write_text
from featmap.io.kitti_raw import read_velo_bin
from featmap.evaluation.wall_lists import lying_on, read_wall_lists, score_wall_list
from featmap.pipeline.config import load_config

ROOT = Path(__file__).resolve().parents[1]
LISTS = ROOT / "tests" / "extraction" / "real_scan_walls.yaml"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    default_data = Path(os.environ.get("FEATMAP_SHARED", ROOT / ".." / "shared")) / "data"
    parser.add_argument("--data", type=Path, default=default_data)
    parser.add_argument("--set", action="append", default=[], dest="overrides", help="config overrides (needs --out)")
    parser.add_argument("--out", type=Path, help="write the figures and real_scans.md here instead of into docs/")
    args = parser.parse_args(argv)
    try:
        return _run(args)
    except FeatmapError as exc:
        print(f"error: {exc}")
        return 2


MIN_PIECE_M = 0.5
"""Pieces shorter than this are left out of why a wall was missed (a wall's edges leave many tiny ones)."""


def why_missed(explanation, line, tolerance_m: float, most: int = 3) -> str:
    """What the extractor's tests said about the pieces lying on a missed listed ``line`` (an
    :class:`~featmap.extraction.explain.ScanExplanation` of the scan): the ``most`` longest at least
    ``MIN_PIECE_M`` long that failed a test, each with its length and the tests it failed (at the height
    stage, or at the final stage after passing it)."""
    if not explanation.stages:
        return "no piece"
    found = []
    for stage, suffix in (("height", ""), ("final", " (final tests)")):
        tests, segments = explanation.stages[stage], explanation.segments(stage)
        length = segment_lengths(segments)
        for k in np.flatnonzero(lying_on(segments, line, tolerance_m) & (length >= MIN_PIECE_M) & ~tests.kept):
            found.append((float(length[k]), f"{length[k]:.1f} m: {', '.join(tests.failed(int(k)))}{suffix}"))
    found.sort(key=lambda item: -item[0])
    return "; ".join(text for _, text in found[:most]) or f"no dropped piece of {MIN_PIECE_M} m or more"


def _run(args) -> int:
    if args.overrides and args.out is None:
        raise FeatmapError("--set: docs/ holds the default configuration; write this variant elsewhere with --out DIR")
    figures = ROOT / "docs" / "figures" / "real_scans" if args.out is None else args.out
    page = ROOT / "docs" / "real_scans.md" if args.out is None else args.out / "real_scans.md"
    link = "figures/real_scans/" if args.out is None else ""
    config = load_config(None, args.overrides)
    lists = read_wall_lists(LISTS)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from featmap.plotting.scan_walls import plot_scan_walls

    clouds = {scan: read_velo_bin(args.data / scan) for scan in lists.scans}     # every scan read before anything is written
    figures.mkdir(parents=True, exist_ok=True)
    rows = []
    for scan, wall_list in lists.scans.items():
        points = clouds[scan]
        explanation = None                                    # warm-up (imports), not timed; why walls were missed
        if config.extraction.method_3d == "vertical_structure":
            explanation = explain_scan(points, config.extraction.vertical_structure)
        else:
            extract_scan(points, 3, config.extraction)
        times = []
        for _ in range(5):                                    # the median of 5: one run on a shared machine is noisy
            start = time.perf_counter()
            result = extract_scan(points, 3, config.extraction)
            times.append(time.perf_counter() - start)
        ms = 1000 * float(np.median(times))
        score = score_wall_list(result.segments, wall_list, lists.tolerance_m, lists.min_coverage)
        name = Path(scan).stem
        fig, ax = plt.subplots(figsize=(7.5, 5.0))
        plot_scan_walls(ax, points, result.segments, wall_list, score)
        ax.set_title(f"{scan}: {int(score.found.sum())}/{len(score.found)} walls found, "
                     f"{score.n_clutter} on clutter, {score.n_unlisted} unlisted", fontsize=8)
        fig.tight_layout()
        fig.savefig(figures / f"{name}.png", dpi=110)
        plt.close(fig)
        missed = [f"{w.name} ({c:.2f} covered{'; ' + why_missed(explanation, w, lists.tolerance_m) if explanation is not None else ''})"
                  for w, f, c in zip(wall_list.walls, score.found, score.coverage) if not f]
        rows.append((scan, len(points), len(result), int(score.found.sum()), len(score.found), score.n_clutter,
                     score.n_unlisted, ms, "; ".join(missed)))
    header = ("| scan | points | segments | walls found | on clutter | unlisted | ms | missed |\n"
              "|---|---|---|---|---|---|---|---|\n")
    body = "".join(f"| {r[0]} | {r[1]:,} | {r[2]} | {r[3]}/{r[4]} | {r[5]} | {r[6]} | {r[7]:.0f} | {r[8]} |\n" for r in rows)
    found, listed = sum(r[3] for r in rows), sum(r[4] for r in rows)
    total = (f"| **all eight** | | {sum(r[2] for r in rows)} | **{found}/{listed}** | {sum(r[5] for r in rows)} | "
             f"{sum(r[6] for r in rows)} | {np.median([r[7] for r in rows]):.0f} (median) | |\n")
    table = header + body + total
    print(table)
    text = ("# Walls in the real KITTI scans\n\n"
            "Made by `scripts/real_scan_figures.py` (extraction method "
            f"`{config.extraction.method_3d}`{'; ' + ' '.join(f'`--set {o}`' for o in args.overrides) if args.overrides else ''}); the eye-checked lists and how they were made are in "
            "`tests/extraction/real_scan_walls.yaml`. A wall is found when segments cover >= 90 % of it "
            "(endpoints within 0.5 m). Times are medians of 5 extractions in one process on a shared 2-core machine. "
            "After a missed wall: the longest pieces (at least 0.5 m) lying on it that the extractor dropped, with the "
            "tests each failed (`featmap explain` names them: the height tests, then the final tests).\n\n"
            + "<!-- table:real_scans -->\n" + table + "<!-- /table -->\n\n" + "".join(f"![{Path(r[0]).stem}]({link}{Path(r[0]).stem}.png)\n" for r in rows))
    atomic_write_text(page, text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
