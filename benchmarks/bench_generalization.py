"""Generalization benchmark: per-scan extraction and fused maps on procedurally generated worlds.

    .venv/bin/python benchmarks/bench_generalization.py [--split tuning|heldout|heldout2|...|heldout8] [--seeds S ...]
        [--frames a:b:c] [--workers 2] [--set key=value ...] [--cache-dir DIR] [--no-cache] [--json FILE] [--docs]
        [--losses K] [--variant "key=value [key=value ...]" ...] [--foliage CP,CD,HP,HD|drawn] [--drop-drives]

Worlds come from :mod:`featmap.simulation.procedural` (house rows, apartment blocks, courtyards,
side streets, far walls 50-100 m away, cars, fences, hedges, poles, trees, sloped streets with
curbs; hdl64, vlp32, vls128 or vlp16 with 0.1-0.4 deg azimuth steps, 1-3 cm range noise and
dropout). ``--split tuning`` (default) uses ``TUNING_SEEDS``, the worlds to develop and tune on;
``--split heldout`` uses ``HELDOUT_SEEDS``, ``--split heldout2`` ``SECOND_HELDOUT_SEEDS``, ``--split heldout3``
``THIRD_HELDOUT_SEEDS``, ``--split heldout4`` ``FOURTH_HELDOUT_SEEDS``, ``--split heldout5``
``FIFTH_HELDOUT_SEEDS``, ``--split heldout6`` ``SIXTH_HELDOUT_SEEDS``, ``--split heldout7``
``SEVENTH_HELDOUT_SEEDS`` and ``--split heldout8`` ``EIGHTH_HELDOUT_SEEDS``
(:mod:`featmap.simulation.splits`), which must never be used while tuning: run them only to report how
final defaults generalise. ``--split tuning --seeds`` also takes any other seed that is not
held out (a probe world, e.g. one chosen by the settings of a held-out world that misses). Each drive is simulated on first use into
``data/sim/<split>/procedural_<seed>`` with per-scan ground truth (``truth/observations.npz``).

The default covers every frame of every world of the split (31 tuning or eight times 10 held-out worlds of
115-260 scans at 10 Hz: 6147, 2198, 2063, 2110, 2155, 2139 and 2150 scans for the first six; the later sets' counts are in their tables). First use simulates them (10-100 s and 0.1-0.5 GB per
world), and so does any change to the generator or to the simulator's code. With an empty cache nearly
all of the run is extraction (the speed is printed); a re-run that changes only fusion settings takes
about a minute for the tuning split (61 s on 2026-12-03, all three methods).
``--drop-drives`` is for a disk short of space: the worlds go ``--workers`` at a time, each deleted once
scored (so the next run simulates them again; their scans still come from the extraction cache).
``--frames ::2`` halves the scans (fused maps then see each wall from half as many places).
``--foliage 0.3,0.3,0.15,0.2`` runs the same worlds with every tree crown and hedge porous
(:func:`featmap.simulation.worlds.with_porous_foliage`: the share of rays passing a crown, the mean depth
inside it at which the others return, the same for hedges), simulated into
``data/sim/<split>_foliage_<values>/`` (the generator's worlds have solid foliage); ``--foliage drawn``
gives each crown and hedge its own porosity and depth, drawn from the world's seed
(:func:`featmap.simulation.worlds.with_drawn_foliage`), into ``data/sim/<split>_foliage_drawn/``.

Per world and overall it prints:

- per-scan **observation recall**: the share of (scan, wall) observations with >= 50 hits and
  >= 2 m observed (no range cap) for which one segment of that scan has >= 1 m of the observed
  part lying on it (EVALUATION.md's 0.3 m / 10 deg "lies on"), overall, for observations of
  50-300 hits and for observations more than 50 m away (their nearest observed point);
- **per-scan coverage**: observed length lying on the union of the scan's segments, over all counting
  observations;
- **segment coverage**: the share of the drive's observed wall length (per wall the union of its
  counting observations over the selected scans) lying on any per-scan segment: the ceiling for fusion;
- for each fusion method (default configuration, ``featmap.fusion.fuse``): the metrics of
  EVALUATION.md against that same truth (precision, recall, redundancy, offset, corner error);
- extraction speed: scans/s of the whole extraction stage with ``--workers`` processes (reading
  included), and the median milliseconds of the extraction call per scan;
- with ``--losses K`` (tuning and probe worlds only: held-out worlds are not looked into): where the
  segment coverage is lost, i.e. the observed wall length no segment covers, by how the drive saw it at
  best (every view >= 84 deg from head-on, every view > 80 m away, at most 2 scans, other), and the K
  longest uncovered stretches with their views (``featmap.evaluation.observation_metrics.uncovered_stretches``);
  and per method where its fused map loses that coverage (``fusion_losses``): the observed length only
  segments it dropped covered (its support filter), the length a kept segment covered and its fused
  feature does not (the fit), and the dropped segments' own length on building walls and elsewhere;
  and what the per-scan segments and the fused features lie on where they lie on no building wall
  (``featmap.evaluation.clutter``: a hedge, fence, car, pole or tree of the world, beside a wall, or
  nothing near), the simulated counterpart of the real scans' segments on clutter.
- with ``--variant "KEY=VALUE ..."`` (repeatable; tuning and probe worlds only): the same worlds again
  with each variant's settings on top of ``--set``, and a table comparing every variant with the
  configuration without them (observation recall, segment coverage and each method's precision and
  recall, mean and worst world), then the worlds where a variant moved precision, recall or segment
  coverage by at least ``CHANGED`` (``--json`` holds every variant's numbers). Only the variants
  whose extraction settings differ extract again; the cache keeps each.

Extraction goes through the pipeline's own loop (:func:`featmap.pipeline.extract.extract_source`) with
the configured extractor (``--set extraction.method_3d=NAME`` picks another registered one) and its
content-keyed cache (``--cache-dir``, default ``data/cache``): a re-run that changes only fusion
settings does not extract again. ``--no-cache`` extracts every scan (for timing).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from featmap.datasets import KittiRawDataset
from featmap.errors import FeatmapError
from featmap.evaluation import load_simulator_truth, truth_metrics
from featmap.evaluation.clutter import CLUTTER_KINDS, ClutterObjects, OffWall, off_wall
from featmap.evaluation.observation_metrics import (FAR_VIEW_M, FEW_VIEWS, GRAZING_VIEW_DEG, LOSS_KINDS,
                                                   UncoveredStretches, fusion_losses, match_observations,
                                                   truth_from_observations, uncovered_stretches, union_coverage)
from featmap.fusion import fuse
from featmap.fusion.registry import fuse_columns
from featmap.io.segments_csv import SegmentTable
from featmap.io.sim_truth import read_objects_local, read_observations
from featmap.pipeline import SegmentStore, load_config
from featmap.pipeline.executor import ProcessExecutor, SerialExecutor
from featmap.pipeline.extract import extract_source
from featmap.simulation.procedural import generate
from featmap.simulation.splits import HELDOUT_SPLITS, SPLITS, held_out_seeds, split_seeds
from featmap.simulation.simulate import SIM_DATE, simulate_drive, simulation_fingerprint
from featmap.simulation.worlds import with_drawn_foliage, with_porous_foliage

DRIVE = f"{SIM_DATE}_drive_0001"
MAX_WORKERS = 2
FAR_M = 50.0
FEW_HITS = (50, 300)
CHANGED = 0.002
"""A variant's per-world change listed in the comparison (precision, recall or segment coverage)."""


# --- drives ------------------------------------------------------------------------------------------

Foliage = tuple[float, ...] | str | None
"""``--foliage``: None (the generator's solid foliage), four values (crown porosity, crown depth m, hedge
porosity, hedge depth m) for every crown and hedge, or ``"drawn"`` (each its own, from the world's seed)."""


def _generated(seed: int, foliage: Foliage = None):
    """``seed``'s world and settings, with its tree crowns and hedges made porous as ``foliage`` says."""
    g = generate(seed)
    if foliage is None:
        return g
    if foliage == "drawn":
        return replace(g, world=with_drawn_foliage(g.world, seed))
    return replace(g, world=with_porous_foliage(g.world, *foliage))


def foliage_tag(foliage: Foliage, sep: str = ",") -> str:
    """How ``foliage`` (not None) is named in folders (``sep="_"``), commands and labels."""
    return foliage if isinstance(foliage, str) else sep.join(f"{v:g}" for v in foliage)


def _fingerprint(seed: int, foliage: Foliage = None) -> str:
    """What a cached drive was made from: the world, its settings and the simulator's source."""
    g = _generated(seed, foliage)
    return simulation_fingerprint({"world": g.world.model_dump(mode="json"), "sensor": g.settings.sensor.__dict__,
                                   "noise_m": g.settings.noise_m, "dropout": g.settings.dropout,
                                   "seed": g.settings.seed})


def drive_root(sim_root: Path, split: str, seed: int, foliage: Foliage = None) -> Path:
    """Where ``seed``'s drive is cached (worlds with porous foliage apart from the generator's own)."""
    folder = split if foliage is None else f"{split}_foliage_{foliage_tag(foliage, '_')}"
    return sim_root / folder / f"procedural_{seed}"


def is_current(sim_root: Path, split: str, seed: int, foliage: Foliage = None) -> bool:
    """True when ``seed``'s drive is cached and was simulated from the world the generator makes now."""
    root = drive_root(sim_root, split, seed, foliage)
    stamp = root / "generator.json"
    done = (root / SIM_DATE / f"{DRIVE}_sync" / "truth" / "observations.npz").exists()
    return done and stamp.exists() and json.loads(stamp.read_text()).get("fingerprint") == _fingerprint(seed, foliage)


def ensure_drive(sim_root: Path, split: str, seed: int, foliage: Foliage = None) -> Path:
    """The KITTI raw root of ``seed``'s drive, simulated (with per-scan truth) if missing or stale."""
    root = drive_root(sim_root, split, seed, foliage)
    if is_current(sim_root, split, seed, foliage):
        return root
    if root.exists():
        shutil.rmtree(root)
    g = _generated(seed, foliage)
    s = g.settings
    simulate_drive(g.world, root, s.sensor, noise_m=s.noise_m, dropout=s.dropout, seed=s.seed, scan_observations=True)
    (root / "generator.json").write_text(json.dumps({"seed": seed, "fingerprint": _fingerprint(seed, foliage)}))
    return root


def _simulate_task(args) -> tuple[int, float]:
    sim_root, split, seed, foliage = args
    start = time.perf_counter()
    ensure_drive(Path(sim_root), split, seed, foliage)
    return seed, time.perf_counter() - start


# --- scoring -----------------------------------------------------------------------------------------

@dataclass
class WorldResult:
    seed: int
    label: str
    scans: int
    n_obs: int
    found: int
    few: tuple[int, int]
    far: tuple[int, int]
    covered_m: float
    observed_m: float
    segment_coverage: float | None
    segments: int
    extract_ms: list
    points: list
    methods: dict
    losses: UncoveredStretches | None = None
    clutter: dict | None = None


def score_world(root: Path, frames: list[int], table: SegmentTable, config, methods: list[str],
                losses: bool = False) -> dict:
    """Observation recall, coverage and every method's fused metrics for one world's extracted segments
    (``table``: world frame, with the extraction's per-segment columns); with ``losses`` also the observed
    wall stretches no segment covers (``"losses"``, :func:`uncovered_stretches`) and what the per-scan
    segments and each method's features lie on where they lie on no building wall (``"clutter"``,
    :func:`_clutter`)."""
    segments, scan = table.segments, table.scan
    ds = KittiRawDataset(root, DRIVE)
    truth_dir = ds.location / "truth"
    obs = read_observations(truth_dir, frames)
    base = load_simulator_truth(truth_dir)
    wanted = set(frames)
    poses = {f: T[:2, 3] for f, T in zip(ds.frames, ds.poses()) if f in wanted}
    counting = obs.counting()
    obs_c = obs.subset(counting)
    match = match_observations(base.walls, obs_c, segments, scan, poses)
    truth = truth_from_observations(base, obs_c, np.ones(len(obs_c), bool))
    few = (obs_c.n_hits >= FEW_HITS[0]) & (obs_c.n_hits <= FEW_HITS[1])
    far = match.min_distance_m > FAR_M
    out = {"n_obs": int(len(obs_c)), "found": int(match.found.sum()),
           "few": (int(match.found[few].sum()), int(few.sum())), "far": (int(match.found[far].sum()), int(far.sum())),
           "covered_m": float(match.covered_m.sum()), "observed_m": float(match.sampled_m.sum()),
           "segment_coverage": union_coverage(segments, truth), "methods": {}}
    if losses:
        out["losses"] = uncovered_stretches(segments, truth, obs_c, poses)
        objects = ClutterObjects.from_records(read_objects_local(truth_dir))
        out["clutter"] = _clutter(off_wall(segments, truth, objects))
    for name in methods:
        start = time.perf_counter()
        result = fuse(name, segments, scan, config.fusion, **fuse_columns(table.extra, len(table)))
        seconds = time.perf_counter() - start
        metrics = truth_metrics(result.segments, truth)
        metrics["fusion_seconds"] = seconds
        if losses:
            metrics["fusion_loss"] = asdict(fusion_losses(segments, result.labels < 0, result.segments, truth))
            metrics["clutter"] = _clutter(off_wall(result.segments, truth, objects))
        out["methods"][name] = metrics
    return out


def _clutter(off: OffWall) -> dict:
    """Per kind of ``CLUTTER_KINDS``: how many of the segments lie on it (most of their length off every
    building wall, most of that on it: :meth:`OffWall.segments_on`) and the metres off every wall on it."""
    return {"segments_on": off.counts_on(), "metres": off.metres_by_kind().tolist()}


# --- report ------------------------------------------------------------------------------------------

def _share(a: int, b: int) -> str:
    return f"{a / b:.3f}" if b else "-"


def _num(value, fmt: str) -> str:
    return "-" if value is None else format(value, fmt)


def print_report(results: list[WorldResult], methods: list[str], split: str, wall_seconds: float, workers: int,
                 console: Console, extracted_now: int) -> None:
    table = Table(title=f"per-scan extraction against observations ({split} worlds)")
    for col in ("seed", "sensor, step, noise, dropout", "scans", "obs", "obs recall", "50-300 hits (n)",
                f">{FAR_M:.0f} m (n)", "per-scan cov.", "segment cov.", "segs/scan", "ms/scan", "points/scan"):
        table.add_column(col, justify="left" if col in ("seed", "sensor, step, noise, dropout") else "right")
    for r in results:
        table.add_row(str(r.seed), r.label, str(r.scans), str(r.n_obs), _share(r.found, r.n_obs),
                      f"{_share(*r.few)} ({r.few[1]})", f"{_share(*r.far)} ({r.far[1]})",
                      _num(r.covered_m / r.observed_m if r.observed_m else None, ".3f"),
                      _num(r.segment_coverage, ".3f"), f"{r.segments / max(r.scans, 1):.1f}",
                      f"{statistics.median(r.extract_ms):.0f}" if r.extract_ms else "-", f"{statistics.median(r.points) / 1000:.0f}k")
    tot = lambda f: sum(f(r) for r in results)  # noqa: E731
    few = (tot(lambda r: r.few[0]), tot(lambda r: r.few[1]))
    far = (tot(lambda r: r.far[0]), tot(lambda r: r.far[1]))
    cov = [r.segment_coverage for r in results if r.segment_coverage is not None]
    all_ms = [m for r in results for m in r.extract_ms]
    table.add_row("[b]all[/b]", "pooled (segment cov.: mean / min)", str(tot(lambda r: r.scans)),
                  str(tot(lambda r: r.n_obs)), f"[b]{_share(tot(lambda r: r.found), tot(lambda r: r.n_obs))}[/b]",
                  f"{_share(*few)} ({few[1]})", f"{_share(*far)} ({far[1]})",
                  _num(tot(lambda r: r.covered_m) / tot(lambda r: r.observed_m) if tot(lambda r: r.observed_m) else None, ".3f"),
                  f"{np.mean(cov):.3f} / {np.min(cov):.3f}" if cov else "-",
                  f"{tot(lambda r: r.segments) / max(tot(lambda r: r.scans), 1):.1f}",
                  f"{statistics.median(all_ms):.0f}" if all_ms else "-", "")
    console.print(table)
    if extracted_now:
        console.print(f"extraction stage: {extracted_now} scans extracted in {wall_seconds:.1f} s with {workers} "
                      f"worker(s) = [b]{extracted_now / wall_seconds:.1f} scans/s[/b] (reading included)")

    table = Table(title=f"fused maps, default configuration ({split} worlds; truth = union of counting observations)")
    for col in ("seed", "method", "features", "walls", "precision", "recall", "coverage - recall", "redundancy",
                "offset cm", "corner cm", "fusion s"):
        table.add_column(col, justify="left" if col in ("seed", "method") else "right")
    for r in results:
        for name in methods:
            m = r.methods[name]
            gap = None if (m["recall"] is None or r.segment_coverage is None) else r.segment_coverage - m["recall"]
            table.add_row(str(r.seed), name, str(m["count"]), str(m["observable_walls"]),
                          _num(m["precision"], ".3f"), _num(m["recall"], ".3f"), _num(gap, "+.3f"),
                          _num(m["redundancy"], ".2f"), _num(m["offset_cm"], ".2f"), _num(m["corner_err_cm"], ".1f"),
                          f"{m['fusion_seconds']:.2f}")
    for name in methods:
        vals = {k: [r.methods[name][k] for r in results if r.methods[name][k] is not None]
                for k in ("precision", "recall", "redundancy", "offset_cm", "corner_err_cm")}
        gaps = [r.segment_coverage - r.methods[name]["recall"] for r in results
                if r.segment_coverage is not None and r.methods[name]["recall"] is not None]
        mean = lambda k: np.mean(vals[k]) if vals[k] else None  # noqa: E731
        table.add_row("[b]mean[/b]", name, "", "", _num(mean("precision"), ".3f"), _num(mean("recall"), ".3f"),
                      _num(np.mean(gaps) if gaps else None, "+.3f"), _num(mean("redundancy"), ".2f"),
                      _num(mean("offset_cm"), ".2f"), _num(mean("corner_err_cm"), ".1f"), "")
        worst = lambda k, f: f(vals[k]) if vals[k] else None  # noqa: E731
        table.add_row("[b]worst world[/b]", name, "", "", _num(worst("precision", min), ".3f"),
                      _num(worst("recall", min), ".3f"), _num(max(gaps) if gaps else None, "+.3f"),
                      _num(worst("redundancy", max), ".2f"), _num(worst("offset_cm", max), ".2f"),
                      _num(worst("corner_err_cm", max), ".1f"), "")
    console.print(table)


def _loss_rows(results: list[WorldResult]):
    """(seed, label, UncoveredStretches, kinds) of the worlds that were looked into."""
    return [(r.seed, r.label, r.losses, r.losses.kind()) for r in results if r.losses is not None]


def loss_tables(results: list[WorldResult], longest: int) -> list[Table]:
    """Where the segment coverage is lost: uncovered observed length by how the drive saw it, and the
    ``longest`` uncovered stretches (two tables)."""
    rows = _loss_rows(results)
    observed = sum(lost.observed_m for _, _, lost, _ in rows)
    lost_m = sum(float(lost.length.sum()) for _, _, lost, _ in rows)
    table = Table(title=f"observed wall length no segment covers, by its best view ({len(rows)} worlds; "
                        f"grazing >= {GRAZING_VIEW_DEG:.0f} deg, far > {FAR_VIEW_M:.0f} m, few views <= {FEW_VIEWS} scans)")
    for col in ("kind", "stretches", "metres", "share of the loss", "share of observed", "worlds (most metres)"):
        table.add_column(col, justify="left" if col in ("kind", "worlds (most metres)") else "right")
    for kind in LOSS_KINDS:
        per_world = sorted(((float(lost.length[kinds == kind].sum()), seed) for seed, _, lost, kinds in rows), reverse=True)
        metres = sum(m for m, _ in per_world)
        table.add_row(kind, str(sum(int((kinds == kind).sum()) for _, _, _, kinds in rows)), f"{metres:.1f}",
                      _num(metres / lost_m if lost_m else None, ".2f"), _num(metres / observed if observed else None, ".4f"),
                      ", ".join(f"{seed} ({m:.1f})" for m, seed in per_world[:4] if m > 0))
    table.add_row("[b]all[/b]", str(sum(len(lost) for _, _, lost, _ in rows)), f"{lost_m:.1f}", "1.00",
                  _num(lost_m / observed if observed else None, ".4f"), f"of {observed:.0f} m observed")
    by_kind = table
    table = Table(title=f"the {longest} longest uncovered stretches")
    for col in ("seed", "sensor, step, noise, dropout", "wall", "along m", "length m", "views", "nearest m",
                "its angle deg", "best angle deg", "max hits", "kind"):
        table.add_column(col, justify="left" if col in ("seed", "sensor, step, noise, dropout", "kind") else "right")
    flat = [(float(lost.length[i]), seed, label, lost, kinds, i) for seed, label, lost, kinds in rows for i in range(len(lost))]
    for length, seed, label, lost, kinds, i in sorted(flat, key=lambda t: -t[0])[:longest]:
        table.add_row(str(seed), label, str(lost.wall[i]), f"{lost.start[i]:.1f}-{lost.end[i]:.1f}", f"{length:.1f}",
                      str(lost.n_views[i]), _num(lost.nearest_m[i], ".1f"), _num(lost.nearest_incidence_deg[i], ".1f"),
                      _num(lost.best_incidence_deg[i], ".1f"), str(lost.max_hits[i]), kinds[i])
    return [by_kind, table]


def fusion_loss_table(results: list[WorldResult], methods: list[str]) -> Table:
    """Where each method's fused maps lose the segments' coverage, pooled over the worlds looked into."""
    table = Table(title="observed wall length the segments cover and the fused map does not, by cause "
                        f"({sum(r.losses is not None for r in results)} worlds; metres)")
    for col in ("method", "coverage - recall", "support filter", "fit", "gained", "support filter, worlds (most metres)",
                "dropped on walls", "dropped elsewhere"):
        table.add_column(col, justify="left" if col in ("method", "support filter, worlds (most metres)") else "right")
    for name in methods:
        per = [(r.seed, r.methods[name]["fusion_loss"]) for r in results if "fusion_loss" in r.methods[name]]
        tot = lambda key: sum(loss[key] for _, loss in per)  # noqa: E731
        worst = sorted(((loss["filtered_m"], seed) for seed, loss in per), reverse=True)[:4]
        observed = tot("observed_m")
        gap = tot("segments_m") - tot("fused_m")
        table.add_row(name, f"{gap:.1f} ({gap / observed:.4f})" if observed else "-", f"{tot('filtered_m'):.1f}",
                      f"{tot('fit_m'):.1f}", f"{tot('gained_m'):.1f}",
                      ", ".join(f"{seed} ({m:.1f})" for m, seed in worst if m > 0.05),
                      f"{tot('dropped_wall_m'):.0f}", f"{tot('dropped_other_m'):.0f}")
    return table


def clutter_table(results: list[WorldResult], methods: list[str]) -> Table:
    """What the per-scan segments and each method's features lie on where they lie on no building wall
    (``featmap.evaluation.clutter``), pooled over the worlds looked into: the simulated counterpart of the
    real scans' segments on clutter."""
    rows = [r for r in results if r.clutter is not None]
    scans = sum(r.scans for r in rows)
    table = Table(title=f"segments lying on no building wall, by what they lie on ({len(rows)} worlds, {scans} "
                        "scans; a segment counts where most of its length does)")
    columns = ["kind", "per-scan segments", "per 100 scans", "per-scan m"]
    columns += [f"{name} {what}" for name in methods for what in ("features", "m")]
    columns += ["worlds (most per-scan segments)"]
    for col in columns:
        table.add_column(col, justify="left" if col in ("kind", "worlds (most per-scan segments)") else "right")
    for k, kind in enumerate(CLUTTER_KINDS):
        count = sum(r.clutter["segments_on"][k] for r in rows)
        worst = sorted(((r.clutter["segments_on"][k], r.seed) for r in rows), reverse=True)[:4]
        fused = [cell for name in methods
                 for cell in (str(sum(r.methods[name]["clutter"]["segments_on"][k] for r in rows)),
                              f"{sum(r.methods[name]['clutter']['metres'][k] for r in rows):.1f}")]
        table.add_row(kind, str(count), _num(100 * count / scans if scans else None, ".1f"),
                      f"{sum(r.clutter['metres'][k] for r in rows):.0f}", *fused,
                      ", ".join(f"{seed} ({n})" for n, seed in worst if n > 0))
    return table


def print_losses(results: list[WorldResult], longest: int, methods: list[str], console: Console) -> None:
    """Print :func:`loss_tables`, :func:`fusion_loss_table` and :func:`clutter_table`."""
    for table in (*loss_tables(results, longest), fusion_loss_table(results, methods), clutter_table(results, methods)):
        console.print(table)


def _losses_json(lost: UncoveredStretches) -> dict:
    kinds = lost.kind()
    return {"observed_m": lost.observed_m, "metres_by_kind": {k: float(lost.length[kinds == k].sum()) for k in LOSS_KINDS},
            "stretches": [{"wall": int(lost.wall[i]), "start": float(lost.start[i]), "end": float(lost.end[i]),
                           "views": int(lost.n_views[i]), "nearest_m": float(lost.nearest_m[i]),
                           "nearest_incidence_deg": float(lost.nearest_incidence_deg[i]),
                           "best_incidence_deg": float(lost.best_incidence_deg[i]), "max_hits": int(lost.max_hits[i]),
                           "kind": str(kinds[i])} for i in range(len(lost))]}


# --- variants --------------------------------------------------------------------------------------------

def parse_variant(text: str) -> list[str]:
    """The ``KEY=VALUE`` overrides of one ``--variant`` (separated by spaces); checked by ``load_config``."""
    overrides = text.split()
    if not overrides:
        raise FeatmapError("--variant '': give one or more KEY=VALUE settings, "
                           "e.g. --variant extraction.vertical_structure.tall_m=2.0")
    return overrides


def _mean_worst(results: list[WorldResult], value, worst=min) -> str:
    """'mean / worst (seed)' of ``value(r)`` over the worlds where it is known."""
    known = [(value(r), r.seed) for r in results if value(r) is not None]
    if not known:
        return "-"
    v, seed = worst(known, key=lambda t: t[0])
    return f"{np.mean([k for k, _ in known]):.3f} / {v:.3f} ({seed})"


def variant_tables(baseline: list[WorldResult], variants: list[tuple[str, list[WorldResult]]],
                   methods: list[str]) -> list[Table]:
    """Every variant against ``baseline`` (the same worlds, in the same order): one row per setting and
    method, then the worlds where a variant moved precision, recall or segment coverage by >= ``CHANGED``."""
    table = Table(title=f"variants on {len(baseline)} worlds (mean / worst world)")
    for col in ("setting", "method", "obs recall", "segment cov.", "precision", "recall", "redundancy"):
        table.add_column(col, justify="left" if col in ("setting", "method") else "right")
    for label, results in [("as configured", baseline), *variants]:
        for name in methods:
            table.add_row(label, name, _share(sum(r.found for r in results), sum(r.n_obs for r in results)),
                          _mean_worst(results, lambda r: r.segment_coverage),
                          _mean_worst(results, lambda r: r.methods[name]["precision"]),
                          _mean_worst(results, lambda r: r.methods[name]["recall"]),
                          _mean_worst(results, lambda r: r.methods[name]["redundancy"], max))
    changes = Table(title=f"worlds a variant moved by >= {CHANGED} (precision, recall or segment coverage)")
    for col in ("setting", "seed", "method", "precision", "recall", "segment cov."):
        changes.add_column(col, justify="left" if col in ("setting", "method") else "right")

    def moved(a, b) -> bool:
        return a is not None and b is not None and abs(b - a) >= CHANGED

    def arrow(a, b) -> str:
        return f"{_num(a, '.3f')} -> {_num(b, '.3f')}"

    for label, results in variants:
        for before, after in zip(baseline, results):
            for name in methods:
                m0, m1 = before.methods[name], after.methods[name]
                if (moved(m0["precision"], m1["precision"]) or moved(m0["recall"], m1["recall"])
                        or moved(before.segment_coverage, after.segment_coverage)):
                    changes.add_row(label, str(before.seed), name, arrow(m0["precision"], m1["precision"]),
                                    arrow(m0["recall"], m1["recall"]),
                                    arrow(before.segment_coverage, after.segment_coverage))
    return [table, changes]


def _world_json(r: WorldResult) -> dict:
    return {**{k: v for k, v in r.__dict__.items() if k not in ("extract_ms", "points", "losses")},
            **({"losses": _losses_json(r.losses)} if r.losses is not None else {}),
            "median_extract_ms": statistics.median(r.extract_ms) if r.extract_ms else None,
            "median_points": statistics.median(r.points)}


def markdown_summary(results: list[WorldResult], methods: list[str], split: str, frames: str | None) -> str:
    """The summary the README and docs/results.md quote: per-scan extraction and the fused maps per method
    (mean over the worlds and the worst world)."""
    import platform

    from featmap.io.markdown import markdown_table

    tot = lambda f: sum(f(r) for r in results)  # noqa: E731
    share = lambda a, b: a / b if b else None  # noqa: E731
    cov = [r.segment_coverage for r in results if r.segment_coverage is not None]
    extraction = markdown_table(
        ["worlds", "scans", "observations", "observation recall", "50-300 hits", "> 50 m", "segment coverage (mean / min)"],
        [[len(results), tot(lambda r: r.scans), tot(lambda r: r.n_obs), share(tot(lambda r: r.found), tot(lambda r: r.n_obs)),
          share(tot(lambda r: r.few[0]), tot(lambda r: r.few[1])), share(tot(lambda r: r.far[0]), tot(lambda r: r.far[1])),
          f"{np.mean(cov):.3f} / {np.min(cov):.3f}" if cov else "-"]], 3)
    rows = []
    for name in methods:
        vals = {k: [r.methods[name][k] for r in results if r.methods[name][k] is not None]
                for k in ("precision", "recall", "redundancy", "offset_cm", "corner_err_cm")}
        gaps = [r.segment_coverage - r.methods[name]["recall"] for r in results
                if r.segment_coverage is not None and r.methods[name]["recall"] is not None]

        def pair(key, worst, digits):
            v = vals[key]
            return f"{np.mean(v):.{digits}f} / {worst(v):.{digits}f}" if v else "-"

        rows.append([name, pair("precision", min, 3), pair("recall", min, 3),
                     f"{np.mean(gaps):+.3f} / {max(gaps):+.3f}" if gaps else "-", pair("redundancy", max, 2),
                     pair("offset_cm", max, 2), pair("corner_err_cm", max, 1)])
    fused = markdown_table(["method", "precision", "recall", "coverage - recall", "redundancy", "offset cm",
                            "corner cm"], rows)
    seeds = ", ".join(str(r.seed) for r in results)
    return (f"{split} worlds (seeds {seeds}; frames {frames or 'all'}; {platform.machine()}, "
            f"{time.strftime('%Y-%m-%d')}). Per-scan extraction:\n\n{extraction}\n\n"
            f"Fused maps (default configuration), mean / worst world:\n\n{fused}\n")


# --- main --------------------------------------------------------------------------------------------

def _foliage(text: str) -> tuple[float, float, float, float] | str:
    """``--foliage``: ``drawn``, or four values checked by the world model's own bounds (a tree's and a hedge's)."""
    from pydantic import ValidationError

    from featmap.simulation.worlds import Hedge, Tree

    if text == "drawn":
        return text
    try:
        values = tuple(float(v) for v in text.split(","))
        if len(values) != 4:
            raise ValueError
        Tree(kind="tree", position=(0, 0), crown_porosity=values[0], crown_depth_m=values[1])
        Hedge(kind="hedge", line=[(0, 0), (1, 0)], porosity=values[2], depth_m=values[3])
    except (ValueError, ValidationError):
        raise argparse.ArgumentTypeError(f"{text!r}: expected CROWN_POROSITY,CROWN_DEPTH_M,HEDGE_POROSITY,"
                                         "HEDGE_DEPTH_M with porosities in [0, 1) and depths >= 0, e.g. 0.3,0.3,0.15,0.2, "
                                         "or drawn"
                                         ) from None
    return values


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--split", choices=tuple(SPLITS), default="tuning")
    parser.add_argument("--seeds", type=int, nargs="+",
                        help="a subset of the split's seeds; with --split tuning also any seed that is not held out "
                             "(a probe world to develop on)")
    parser.add_argument("--frames", default=None, help="start:stop:step selection of every world's frames (default: all)")
    parser.add_argument("--cache-dir", type=Path, default=Path("data/cache"), help="content-keyed extraction cache")
    parser.add_argument("--no-cache", action="store_true", help="extract every scan (for timing)")
    parser.add_argument("--workers", type=int, default=2, help=f"extraction processes (at most {MAX_WORKERS})")
    parser.add_argument("--methods", default="all", help="fusion methods (all, or a comma-separated list)")
    parser.add_argument("--set", action="append", default=[], dest="overrides", help="config overrides")
    parser.add_argument("--sim-root", type=Path, default=Path("data/sim"), help="where drives are cached")
    parser.add_argument("--drop-drives", action="store_true",
                        help="for a disk short of space: simulate, score and delete the worlds --workers at a time "
                             "(each is simulated again on its next use; the extraction cache still serves its scans)")
    parser.add_argument("--json", type=Path, help="also write every number to this JSON file")
    parser.add_argument("--losses", type=int, default=0, metavar="K",
                        help="also print where the segment coverage is lost: the uncovered observed wall length by "
                             "how the drive saw it, and the K longest uncovered stretches (not on held-out splits)")
    parser.add_argument("--docs", action="store_true",
                        help="write the summary into docs/results.md (block generalization_<split>)")
    parser.add_argument("--foliage", type=_foliage, metavar="CP,CD,HP,HD|drawn",
                        help="make every tree crown and hedge porous: crown porosity, crown depth (m), hedge "
                             "porosity, hedge depth (m), e.g. 0.3,0.3,0.15,0.2 (--docs writes block "
                             "generalization_<split>_foliage), or drawn: each its own, from the world's seed "
                             "(block generalization_<split>_foliage_drawn); drives cached apart")
    parser.add_argument("--variant", action="append", default=[], metavar='"KEY=VALUE ..."',
                        help="also run the worlds with these settings on top of --set and compare (repeatable; "
                             "not on held-out splits, nor with --docs)")
    args = parser.parse_args(argv)
    console = Console(highlight=False, width=None if os.isatty(1) else 200)
    try:
        return _run(args, console)
    except FeatmapError as exc:
        console.print(f"error: {exc}")
        return 2


def score_split(args, seeds: list[int], config, methods: list[str], store: SegmentStore, workers: int,
                losses: bool = False) -> tuple[list[WorldResult], float, int, int]:
    """Extract (through the cache) and score every world of ``seeds`` with ``config`` (with ``losses``, also
    where the segment coverage is lost): the worlds' results, the extraction's wall seconds, the scans
    extracted now (not from the cache) and all the scans."""
    frames_of: dict[int, list[int]] = {}
    per_seed: dict[int, dict] = {}
    start = time.perf_counter()
    extracted_now = 0
    with (ProcessExecutor(workers) if workers > 1 else SerialExecutor()) as executor:
        for seed in seeds:
            ds = KittiRawDataset(drive_root(args.sim_root, args.split, seed, args.foliage), DRIVE, args.frames)
            extraction = extract_source(ds, config.extraction, store, executor)
            table = extraction.world_table()
            frames_of[seed] = extraction.frames
            extracted_now += extraction.extracted_now
            per_seed[seed] = {"table": table, "ms": [1000 * t for t in extraction.scan_seconds],
                              "points": [len(ds[0].points)]}
    wall_seconds = time.perf_counter() - start
    results = []
    for seed in seeds:
        acc = per_seed[seed]
        table = acc["table"]
        root = drive_root(args.sim_root, args.split, seed, args.foliage)
        scored = score_world(root, frames_of[seed], table, config, methods, losses=losses)
        g = generate(seed).settings
        label = f"{g.sensor.name} {g.sensor.azimuth_step_deg:.2f}° {100 * g.noise_m:.1f}cm {100 * g.dropout:.0f}%"
        results.append(WorldResult(seed, label, len(frames_of[seed]), scored["n_obs"], scored["found"], scored["few"],
                                   scored["far"], scored["covered_m"], scored["observed_m"], scored["segment_coverage"],
                                   len(table), acc["ms"], acc["points"], scored["methods"], scored.get("losses"),
                                   scored.get("clutter")))
    return results, wall_seconds, extracted_now, sum(len(f) for f in frames_of.values())


def simulate_worlds(args, seeds: list[int], workers: int, missing: list[int], console: Console) -> float:
    """Simulate the drives of ``seeds`` that are missing or stale, ``workers`` processes at a time (those in
    ``missing`` print their time): the wall seconds."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    start = time.perf_counter()
    ctx = mp.get_context("spawn")            # Open3D and fork do not mix
    with ProcessPoolExecutor(workers, mp_context=ctx) as pool:
        for seed, seconds in pool.map(_simulate_task, [(str(args.sim_root), args.split, s, args.foliage) for s in seeds]):
            if seed in missing:
                console.print(f"  procedural_{seed}: {seconds:.0f} s")
    return time.perf_counter() - start


def _run(args, console: Console) -> int:
    from featmap.fusion.registry import resolve_methods

    if args.losses < 0:
        raise FeatmapError(f"--losses {args.losses}: the number of stretches to list must be >= 0")
    allowed = split_seeds(args.split)
    seeds = list(args.seeds or allowed)
    if args.split == "tuning":               # any world that is not held out may be developed on
        held = held_out_seeds()
        stray = [s for s in seeds if s in held]
        if stray:
            names = ", ".join(n for n, held in HELDOUT_SPLITS.items() if set(stray) & set(held))
            raise FeatmapError(f"--seeds {stray}: held-out worlds; run them with --split {names}, only to report")
    else:
        if args.losses:
            raise FeatmapError("--losses: held-out worlds are run only to report, not looked into; "
                               "look into tuning or probe worlds (--split tuning)")
        if args.variant:
            raise FeatmapError("--variant: held-out worlds are run only to report, not to compare settings on; "
                               "compare on tuning or probe worlds (--split tuning)")
        stray = [s for s in seeds if s not in allowed]
        if stray:
            raise FeatmapError(f"--seeds {stray}: not in the {args.split} split ({', '.join(map(str, allowed))})")
    if args.foliage and args.docs and args.losses:
        raise FeatmapError("--losses with --foliage and --docs: the docs' loss tables are the generator's worlds'; "
                           "run the losses of porous worlds without --docs")
    if args.variant and args.docs:
        raise FeatmapError("--variant with --docs: the docs hold the configuration without variants; "
                           "run the variants without --docs")
    workers = max(1, min(MAX_WORKERS, args.workers))
    config = load_config(None, args.overrides)
    variants = [(text, load_config(None, [*args.overrides, *parse_variant(text)])) for text in args.variant]
    methods = resolve_methods(args.methods)
    extractor = config.extraction.method_3d
    store = SegmentStore(None if args.no_cache else args.cache_dir)
    console.print(f"{args.split} split: {len(seeds)} world(s) (seeds {', '.join(map(str, seeds))}), frames "
                  f"{args.frames or 'all'}, extractor {extractor}, {workers} worker(s)"
                  + (f", porous foliage {foliage_tag(args.foliage)}" if args.foliage else ""))
    missing = [s for s in seeds if not is_current(args.sim_root, args.split, s, args.foliage)]
    if missing:
        console.print(f"simulating {len(missing)} {args.split} world(s) into "
                      f"{drive_root(args.sim_root, args.split, 0, args.foliage).parent} (first use, or the generator "
                      "changed them)" + (f", {workers} at a time, each deleted once scored" if args.drop_drives else ""))
    # With --drop-drives the worlds go `workers` at a time (simulated, scored with every variant, deleted),
    # so the disk holds at most `workers` drives; otherwise all are simulated first and kept.
    batches = [seeds[i:i + workers] for i in range(0, len(seeds), workers)] if args.drop_drives else [seeds]
    results, wall_seconds, extracted_now, scans = [], 0.0, 0, 0
    scored_variants: list[list[WorldResult]] = [[] for _ in variants]
    simulated_seconds = 0.0
    for batch in batches:
        simulated_seconds += simulate_worlds(args, batch, workers, missing, console)
        batch_results, batch_seconds, batch_now, batch_scans = score_split(args, batch, config, methods, store,
                                                                           workers, losses=args.losses > 0)
        results += batch_results
        wall_seconds += batch_seconds
        extracted_now += batch_now
        scans += batch_scans
        for i, (text, variant_config) in enumerate(variants):
            console.print(f"variant {text}" + (f" (worlds {', '.join(map(str, batch))})" if args.drop_drives else "") + ":")
            scored_variants[i] += score_split(args, batch, variant_config, methods, store, workers)[0]
        if args.drop_drives:
            for seed in batch:
                shutil.rmtree(drive_root(args.sim_root, args.split, seed, args.foliage), ignore_errors=True)
    if missing:
        console.print(f"simulated in {simulated_seconds:.0f} s")

    if extracted_now < scans:
        console.print(f"{scans - extracted_now} scans came from the cache ({args.cache_dir}); the speed below "
                      f"counts only the {extracted_now} extracted now")
    print_report(results, methods, args.split, wall_seconds, workers, console, extracted_now)
    if args.losses:
        print_losses(results, args.losses, methods, console)
    compared = [(text, scored) for (text, _), scored in zip(variants, scored_variants)]
    if compared:
        for table in variant_tables(results, compared, methods):
            console.print(table)
    if args.docs:
        sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
        from doc_blocks import replace_block, rich_table_markdown

        results_md = Path(__file__).resolve().parents[1] / "docs" / "results.md"
        command = f"`.venv/bin/python benchmarks/bench_generalization.py --split {args.split}"
        if args.losses:
            command += f" --losses {args.losses}"
        block, label = f"generalization_{args.split}", args.split
        if args.foliage == "drawn":
            command += " --foliage drawn"
            block, label = f"{block}_foliage_drawn", f"{args.split} (every crown and hedge porous, each its own drawn)"
        elif args.foliage:
            values = foliage_tag(args.foliage)
            command += f" --foliage {values}"
            block, label = f"{block}_foliage", f"{args.split} (every crown and hedge porous: {values})"
        replace_block(results_md, block, f"{command} --docs`: " + markdown_summary(results, methods, label, args.frames))
        console.print(f"wrote the {label} summary into docs/results.md")
        if args.losses:
            replace_block(results_md, "generalization_losses",
                          f"{command} --docs` ({args.split} worlds, seeds {', '.join(map(str, seeds))}):\n\n"
                          + "\n\n".join(rich_table_markdown(t) for t in (*loss_tables(results, args.losses),
                                                                          fusion_loss_table(results, methods),
                                                                          clutter_table(results, methods))))
            console.print("wrote where the segment coverage is lost into docs/results.md")
    if args.json:
        from featmap.io.atomic import atomic_write_text

        payload = {"split": args.split, "foliage": args.foliage, "frames": args.frames, "extractor": extractor, "workers": workers,
                   "extraction_wall_seconds": wall_seconds,
                   "worlds": [_world_json(r) for r in results],
                   "variants": [{"variant": text, "worlds": [_world_json(r) for r in rs]} for text, rs in compared]}
        atomic_write_text(args.json, json.dumps(payload, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
