"""Why the wall extraction kept or dropped the pieces of one scan: the tests each piece fails.

    .venv/bin/python scripts/explain_extraction.py SCAN.bin [--at=X,Y] [--radius 2] [--set KEY=VALUE ...]
    .venv/bin/python scripts/explain_extraction.py --seed 16 --frame 165 [--at=X,Y] ...

A tool for looking into the extractor (``vertical_structure``), not a figure of the README. It extracts
one scan with the configured settings (``--set extraction.vertical_structure.KEY=VALUE``, as ``featmap
run`` takes them), with :func:`featmap.extraction.vertical_structure.extract_vertical_structure`'s
``trace``, and prints, stage by stage, the tests each piece fails: the height tests on the pieces of
cells (:func:`~featmap.extraction.vertical_structure.height_tests`), then the final tests on the returns
of those that passed (:func:`~featmap.extraction.vertical_structure.final_tests`). A piece that fails
none at both stages is a wall (its ends may still move, see ``extend_hidden_m``).

The scan is a KITTI velodyne ``.bin`` file (e.g. ``../shared/data/kitti_raw_2011_09_26_drive_0001_scans/
0000000065.bin``), or ``--seed S --frame I``: frame I of a tuning or probe world simulated by
``benchmarks/bench_generalization.py`` into ``data/sim/tuning/procedural_S`` (held-out seeds are
refused: they are not looked into). With ``--at=X,Y`` (velodyne frame, metres; the ``=`` lets X be
negative) it lists the pieces within ``--radius`` of that point, nearest first; without it, how many
pieces each test drops.

Ends are given in the velodyne frame, turned back from the extractor's levelled frame at height 0
(within a few centimetres of the velodyne frame's own ends where the sensor leans by a degree or two).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

ROOT = Path(__file__).resolve().parents[1]
DRIVE = "2000_01_01_drive_0001"


def _point(text: str) -> np.ndarray:
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected X,Y in metres (e.g. 9.5,20.2), got {text!r}") from None
    if not np.isfinite([x, y]).all():
        raise argparse.ArgumentTypeError(f"expected finite X,Y, got {text!r}")
    return np.array([x, y])


def _distances(point: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(K,) distance of ``point`` (2,) from each segment a-b ((K, 2) each)."""
    d = b - a
    t = np.clip(((point - a) * d).sum(1) / np.maximum((d * d).sum(1), 1e-12), 0.0, 1.0)
    return np.hypot(*(a + t[:, None] * d - point).T)


def stage_rows(tests, rotation: np.ndarray, at: np.ndarray | None, radius: float) -> list[tuple]:
    """(distance, a, b, failed test names) of the pieces of one stage's ``tests`` (a
    :class:`~featmap.extraction.vertical_structure.PieceTests`) within ``radius`` of ``at`` (velodyne frame),
    nearest first; every piece when ``at`` is None."""
    segments = tests.velodyne_segments(rotation)
    a, b = segments[:, :2], segments[:, 2:]
    dist = np.zeros(len(a)) if at is None else _distances(at, a, b)
    order = np.argsort(dist, kind="stable")
    return [(float(dist[k]), a[k], b[k], tests.failed(int(k))) for k in order if dist[k] <= radius]


def failure_counts(tests) -> dict[str, int]:
    """How many pieces fail each of ``tests``' tests (a piece counts under each test it fails), in order."""
    return {name: int((~passed).sum()) for name, passed in tests.passed.items()}


def load_scan(args) -> tuple[np.ndarray, str]:
    """The scan's (N, 4) points and a name for it, from the arguments; raises FeatmapError or ValueError."""
    from featmap.io.kitti_raw import read_velo_bin

    if args.scan is not None:
        return read_velo_bin(args.scan), str(args.scan)
    from featmap.datasets import KittiRawDataset
    from featmap.simulation.splits import held_out_seeds

    if args.seed in held_out_seeds():
        raise ValueError(f"--seed {args.seed} is held out; use a tuning or probe world")
    root = args.sim_root / "tuning" / f"procedural_{args.seed}"
    if not root.exists():
        raise ValueError(f"{root} is missing; simulate it with benchmarks/bench_generalization.py --seeds {args.seed}")
    dataset = KittiRawDataset(root, DRIVE)
    if not 0 <= args.frame < len(dataset):
        raise ValueError(f"--frame {args.frame} is out of range: procedural_{args.seed} has {len(dataset)} frames")
    return dataset[args.frame].points, f"procedural_{args.seed} frame {args.frame}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scan", type=Path, nargs="?", help="a KITTI velodyne .bin scan")
    parser.add_argument("--seed", type=int, help="a tuning or probe world simulated into data/sim/tuning (with --frame)")
    parser.add_argument("--frame", type=int, help="the frame of --seed's drive")
    parser.add_argument("--sim-root", type=Path, default=ROOT / "data" / "sim")
    parser.add_argument("--at", type=_point, help="list the pieces near this point (velodyne frame, metres): X,Y")
    parser.add_argument("--radius", type=float, default=2.0, help="... within this distance (metres; default 2)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args(argv)
    if (args.scan is None) == (args.seed is None) or (args.seed is None) != (args.frame is None):
        parser.error("give either a SCAN.bin file or --seed S --frame I")
    if not args.radius >= 0:
        parser.error(f"--radius must be at least 0, got {args.radius}")
    from featmap.errors import FeatmapError
    from featmap.extraction.vertical_structure import extract_vertical_structure
    from featmap.pipeline.config import load_config

    try:
        config = load_config(None, overrides=args.overrides).extraction.vertical_structure
        points, name = load_scan(args)
        trace: dict = {}
        result = extract_vertical_structure(points, config, trace=trace)
    except (FeatmapError, ValueError) as exc:
        print(f"explain_extraction: {exc}", file=sys.stderr)
        return 2
    console = Console()
    console.print(f"{name}: {len(points):,} points, {len(result)} wall segment(s)")
    if not trace:
        console.print("too few returns above the ground for any piece")
        return 0
    for stage, title in (("height", "height tests, on the pieces of cells"),
                         ("final", "final tests, on the returns of the pieces that passed the height tests")):
        tests = trace[stage]
        if args.at is None:
            table = Table(title=f"{title}: {len(tests.a)} piece(s), {int(tests.kept.sum())} kept")
            table.add_column("test")
            table.add_column("pieces failing it", justify="right")
            for test, count in failure_counts(tests).items():
                table.add_row(test, str(count))
        else:
            rows = stage_rows(tests, trace["rotation"], args.at, args.radius)
            table = Table(title=f"{title}: {len(rows)} within {args.radius:g} m of {args.at[0]:g},{args.at[1]:g}")
            for column in ("distance m", "from", "to", "length m", "fails"):
                table.add_column(column, justify="left" if column == "fails" else "right")
            for dist, a, b, failed in rows:
                table.add_row(f"{dist:.2f}", f"{a[0]:.2f}, {a[1]:.2f}", f"{b[0]:.2f}, {b[1]:.2f}",
                              f"{np.hypot(*(b - a)):.2f}", ", ".join(failed) or "nothing (kept)")
        console.print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
