"""Re-run, in order and resumably, every script that writes a figure or table into docs/ (and so the README).

    .venv/bin/python scripts/refresh_figures.py --changed extraction_3d [--dry-run]
    .venv/bin/python scripts/refresh_figures.py --changed all --skip online_heldout
    .venv/bin/python scripts/refresh_figures.py --only real_scans footprints
    .venv/bin/python scripts/refresh_figures.py --only footprints --force     # again, on unchanged code

A change to what the figures measure (``--changed``: extraction_3d, extraction_2d, fusion, refinement,
evaluation, simulation, speed, or all) selects the steps that measure it. Each step is one command, the
one that made the blocks it names (their headers in docs/ quote it); it runs from the repository's root
with the tests' network guard first on ``PYTHONPATH`` (nothing leaves this machine: map tiles fall back
with a warning) and, when ``../shared`` (or ``$FEATMAP_SHARED``) holds the shared data, ``FEATMAP_SHARED``
set. Its output goes to ``data/refresh_figures/<step>.log``.

A step that finished is recorded in ``data/refresh_figures/state.json`` with a digest of the code the
figures come from (every file under featmap/, configs/, benchmarks/ and scripts/): run again after an interruption, the script
skips the steps already done for that code and starts the others; any edit there starts them all again.
``--force`` runs the selected steps even when they were done for this code (to time a step again on an
idle machine, say); the others stay recorded.
A step whose data is missing (the shared real scans and logs) is reported as not run, never counted as
done. A failing step stops the script (exit 1) with the name of its log. At the end,
``scripts/doc_blocks.py`` copies the blocks into the README, and the benchmarks whose figures are written
into the README's speed table by hand are listed.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from featmap.simulation.splits import HELDOUT_SPLITS

ROOT = Path(__file__).resolve().parents[1]
STATE_DIR = ROOT / "data" / "refresh_figures"
AREAS = ("extraction_3d", "extraction_2d", "fusion", "refinement", "evaluation", "simulation", "speed")
MAPPING = frozenset({"fusion", "refinement", "evaluation"})
"""What every step that fuses and scores a map measures."""


@dataclass(frozen=True)
class Step:
    """One command that writes figures or tables into docs/.

    Attributes:
        name: what --only / --skip call it.
        args: the command after the repository's python (a script and its options).
        areas: the kinds of change that alter its figures.
        blocks: the docs blocks it writes (``<!-- table:NAME -->``).
        shared: it reads the shared data (real KITTI scans, CARMEN logs).
        figures: the figures it draws, if any.
    """

    name: str
    args: tuple[str, ...]
    areas: frozenset
    blocks: tuple[str, ...]
    shared: bool = False
    figures: str = ""


def _step(name, args, areas, blocks, shared=False, figures="") -> Step:
    return Step(name, tuple(args.split()), frozenset(areas), tuple(blocks.split()), shared, figures)


HELDOUT_SPLIT_NAMES = tuple(HELDOUT_SPLITS)
"""Every held-out split has a generalization step and (but the first, whose step also runs its CARMEN log)
a pose step."""

DRAWN_FOLIAGE_SPLITS = ("heldout5", "heldout6", "heldout7", "heldout8")
"""The held-out splits also run with drawn porous foliage (``--foliage drawn``): every split since the fifth."""

STEPS = (
    _step("real_scans", "scripts/real_scan_figures.py", {"extraction_3d", "speed"}, "real_scans",
          shared=True, figures="docs/figures/real_scans/"),
    _step("reproduce_paper", "scripts/reproduce_paper.py", {"extraction_3d", "simulation", "speed", *MAPPING},
          "paper_all_drives paper_corners paper_default_drive paper_preset paper_table1 paper_table2 paper_table3",
          figures="docs/figures/"),
    _step("generalization_tuning", "benchmarks/bench_generalization.py --split tuning --losses 10 --docs",
          {"extraction_3d", "simulation", *MAPPING}, "generalization_tuning generalization_losses"),
    *(_step(f"generalization_{split}", f"benchmarks/bench_generalization.py --split {split} --docs",
            {"extraction_3d", "simulation", *MAPPING}, f"generalization_{split}") for split in HELDOUT_SPLIT_NAMES),
    # (its drives, 7.5 GB that no other step reads, are deleted once scored: the machine's disk is short)
    _step("generalization_tuning_foliage",
          "benchmarks/bench_generalization.py --foliage 0.3,0.3,0.15,0.2 --drop-drives --docs",
          {"extraction_3d", "simulation", *MAPPING}, "generalization_tuning_foliage"),
    _step("generalization_tuning_foliage_drawn", "benchmarks/bench_generalization.py --foliage drawn --docs",
          {"extraction_3d", "simulation", *MAPPING}, "generalization_tuning_foliage_drawn"),
    *(_step(f"generalization_{split}_foliage_drawn",
            f"benchmarks/bench_generalization.py --split {split} --foliage drawn --docs",
            {"extraction_3d", "simulation", *MAPPING}, f"generalization_{split}_foliage_drawn")
      for split in DRAWN_FOLIAGE_SPLITS),
    _step("footprints", "benchmarks/bench_footprints.py --docs", {"extraction_3d", "simulation", *MAPPING},
          "footprints"),
    _step("pose_tuning_sim", "benchmarks/bench_pose_noise.py --parts sim --docs",
          {"extraction_3d", "simulation", *MAPPING}, "pose_tuning_sim_1 pose_tuning_sim_2"),
    _step("pose_tuning_carmen_raw", "benchmarks/bench_pose_noise.py --parts carmen raw --docs",
          {"extraction_2d", *MAPPING}, "pose_tuning_carmen_1 pose_tuning_raw_1 pose_tuning_raw_2", shared=True),
    _step("pose_heldout", "benchmarks/bench_pose_noise.py --parts sim carmen --split heldout --docs",
          {"extraction_3d", "extraction_2d", "simulation", *MAPPING},
          "pose_heldout_sim_1 pose_heldout_sim_2 pose_heldout_carmen_1", shared=True),
    *(_step(f"pose_{split}", f"benchmarks/bench_pose_noise.py --parts sim --split {split} --methods proposed --docs",
            {"extraction_3d", "simulation", *MAPPING}, f"pose_{split}_sim_1 pose_{split}_sim_2")
      for split in HELDOUT_SPLIT_NAMES[1:]),
    _step("pose_timing", "benchmarks/bench_pose_noise.py --parts timing --docs", {"extraction_3d", "speed", *MAPPING},
          "pose_tuning_timing_1"),
    _step("online", "benchmarks/bench_online.py --docs", {"extraction_3d", "simulation", "speed", *MAPPING},
          "online_revisits online_corridor online_drive online_noise"),
    _step("online_heldout", "benchmarks/bench_online.py --parts heldout --docs",
          {"extraction_3d", "extraction_2d", "simulation", *MAPPING}, "online_heldout", shared=True),
    _step("batch", "benchmarks/bench_batch.py --repeats 3 --docs", {"extraction_3d", "simulation", "speed", *MAPPING},
          "batch_bench_1 batch_bench_2 batch_bench_3"),
    _step("drive_alignment", "benchmarks/bench_drive_alignment.py --pose-noise 1.0,1.0 --docs",
          {"extraction_3d", "simulation", *MAPPING}, "drive_alignment"),
    _step("indoor_2d", "benchmarks/bench_indoor_2d.py --docs", {"extraction_2d", "simulation", *MAPPING},
          "indoor_sim_1 indoor_sim_2"),
    _step("indoor_prior", "benchmarks/bench_indoor_2d.py --prior-sweep --docs", {"extraction_2d", "simulation", *MAPPING},
          "indoor_prior_1"),
    _step("real_2d", "scripts/real_data_2d.py --failure-modes --frontier", {"extraction_2d", *MAPPING},
          "real_2d real_2d_presets real_2d_frontier", shared=True, figures="docs/figures/real_2d/"),
    _step("merged_real_2d", "scripts/merged_real_2d.py", {"extraction_2d", *MAPPING}, "merged_real_2d", shared=True),
)

BY_HAND = {
    "extraction_3d": ["benchmarks/bench_extraction.py --real ../shared/data/kitti_raw_2011_09_26_drive_0001_scans",
                      "the README's first command, timed from outside (`featmap run`, empty cache)"],
    "extraction_2d": ["benchmarks/bench_carmen.py"],
    "fusion": ["benchmarks/bench_fusion.py", "benchmarks/bench_fusion_revisits.py", "benchmarks/bench_sweep.py"],
    "evaluation": ["benchmarks/bench_truth_free.py"],
    "simulation": ["benchmarks/bench_simulator.py"],
}
"""Benchmarks whose figures go into the README's speed table by hand (after each, with the date)."""


def select(steps, changed: set[str], only: list[str] | None, skip: list[str]) -> list[Step]:
    """The steps that measure one of the ``changed`` areas ("all": every step), or the ``only`` ones, minus ``skip``."""
    names = {s.name for s in steps}
    unknown = sorted((set(only or []) | set(skip)) - names)
    if unknown:
        raise ValueError(f"unknown step(s) {', '.join(unknown)}; the steps: {', '.join(s.name for s in steps)}")
    if only:
        chosen = [s for s in steps if s.name in only]
    else:
        chosen = [s for s in steps if "all" in changed or s.areas & changed]
    return [s for s in chosen if s.name not in skip]


def hand_written(changed: set[str]) -> list[str]:
    """The benchmarks of the README's speed table that ``changed`` areas call for (every one of them for a
    change to speed: that table is all speed)."""
    areas = AREAS if changed & {"all", "speed"} else changed
    return sorted({bench for area in areas for bench in BY_HAND.get(area, [])})


def code_digest(root: Path = ROOT) -> str:
    """16 hex digits over every file under featmap/, configs/, benchmarks/ and scripts/ (paths and bytes)."""
    h = hashlib.sha256()
    for folder in ("featmap", "configs", "benchmarks", "scripts"):
        for path in sorted((root / folder).rglob("*")):
            if path.is_file() and "__pycache__" not in path.parts:
                h.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes() + b"\0")
    return h.hexdigest()[:16]


def load_state(path: Path, digest: str) -> dict:
    """``{step name: {"seconds": s, "finished": iso}}`` of the steps done for the code ``digest`` (else empty)."""
    try:
        state = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return state.get("done", {}) if isinstance(state, dict) and state.get("code") == digest else {}


def save_state(path: Path, digest: str, done: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps({"code": digest, "done": done}, indent=1) + "\n")
    os.replace(tmp, path)


def step_env(shared: Path | None) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT / "tests" / "loopback_only"), str(ROOT),
                                                    env.get("PYTHONPATH", "")) if p)
    if shared is not None:
        env["FEATMAP_SHARED"] = str(shared)
    return env


def shared_root() -> Path | None:
    """The shared data's root (``$FEATMAP_SHARED`` or ../shared) when it holds the real scans and logs."""
    root = Path(os.environ.get("FEATMAP_SHARED", ROOT / ".." / "shared")).resolve()
    return root if (root / "data" / "carmen_2d").is_dir() and (root / "data" / "kitti_object_velodyne").is_dir() else None


def run_steps(steps: list[Step], python: str, state_dir: Path, digest: str, shared: Path | None,
              print_line=print, force: bool = False) -> list[tuple[str, str, float]]:
    """Run the steps not yet done for ``digest`` (with ``force``, every one of ``steps``); returns (name,
    outcome, seconds) per step. Stops at a failure."""
    state_path = state_dir / "state.json"
    done = load_state(state_path, digest)
    if force:                       # forgotten until they finish again (an interrupted forced run resumes)
        done = {name: v for name, v in done.items() if name not in {s.name for s in steps}}
        save_state(state_path, digest, done)
    outcomes = []
    for k, step in enumerate(steps, start=1):
        if step.name in done:
            outcomes.append((step.name, "done before", done[step.name]["seconds"]))
            continue
        if step.shared and shared is None:
            outcomes.append((step.name, "not run: no shared data", 0.0))
            continue
        log = state_dir / f"{step.name}.log"
        log.parent.mkdir(parents=True, exist_ok=True)
        shown = log.relative_to(ROOT) if log.is_relative_to(ROOT) else log
        print_line(f"[{k}/{len(steps)}] {step.name}: {' '.join(step.args)} (log: {shown})")
        start = time.perf_counter()
        with open(log, "w") as out:
            rc = subprocess.run([python, *step.args], cwd=ROOT, env=step_env(shared), stdout=out,
                                stderr=subprocess.STDOUT).returncode
        seconds = time.perf_counter() - start
        if rc != 0:
            outcomes.append((step.name, f"FAILED (exit {rc}): see {log}", seconds))
            break
        done[step.name] = {"seconds": round(seconds, 1), "finished": time.strftime("%Y-%m-%dT%H:%M:%S")}
        save_state(state_path, digest, done)
        outcomes.append((step.name, "ran", seconds))
    return outcomes


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--changed", nargs="+", choices=(*AREAS, "all"), default=[],
                        help="what the change touched: the steps that measure it run")
    parser.add_argument("--only", nargs="+", help="run these steps (by name) instead")
    parser.add_argument("--skip", nargs="+", default=[], help="leave these steps out")
    parser.add_argument("--force", action="store_true",
                        help="run the selected steps even if they were done for this code")
    parser.add_argument("--dry-run", action="store_true", help="print the plan and stop")
    args = parser.parse_args(argv)
    if not args.changed and not args.only:
        parser.error("say what changed (--changed AREA ...) or which steps to run (--only NAME ...)")
    try:
        steps = select(STEPS, set(args.changed), args.only, args.skip)
    except ValueError as exc:
        parser.error(str(exc))
    digest, shared = code_digest(), shared_root()
    done = load_state(STATE_DIR / "state.json", digest)
    for step in steps:
        status = ("done for this code" if step.name in done and not args.force else
                  "no shared data: will not run" if step.shared and shared is None else "to run")
        print(f"{step.name:24s} {status:28s} {' '.join(step.args)}  ->  {', '.join(step.blocks)} {step.figures}")
    if args.dry_run:
        return 0
    outcomes = run_steps(steps, sys.executable, STATE_DIR, digest, shared, force=args.force)
    failed = any(o.startswith("FAILED") for _, o, _ in outcomes)
    if not failed:
        subprocess.run([sys.executable, "scripts/doc_blocks.py"], cwd=ROOT, check=True)
    print("\nstep                     outcome                         minutes")
    for name, outcome, seconds in outcomes:
        print(f"{name:24s} {outcome:31s} {seconds / 60:7.1f}")
    by_hand = hand_written(set(args.changed))
    if by_hand and not failed:
        print("\nthe README's speed table is written by hand: re-run and copy (with the date) " + "; ".join(by_hand))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
