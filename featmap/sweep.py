"""Parameter sweeps over fusion settings, on cached extracted segments (a sweep never re-extracts).

A sweep file::

    base: configs/default.yaml            # optional (a file or preset; --config replaces it, --set applies on
                                          # top); without one, the config the input was made with (see made_with)
    input: runs/residential/segments.csv  # a run's segments (its metrics.json gives the reference), or
    drive: default                        # a source: default (the simulated residential drive),
    #   drive: 2011_09_30_drive_0018 (+ data_dir, frames), or dataset: NAME + location: PATH, or
    #   batch: runs/batch/example           # a finished batch's merged segments (aligned and scored as its merge was)
    truth: path/to/truth_or_footprints    # optional; found from the run's metrics.json otherwise
    methods: [proposed, meanshift]
    grid:
      fusion.proposed.delta_deg: [2, 5, 10]
      fusion.proposed.eta_m: {start: 0.2, stop: 2.0, num: 10}
      fusion.meanshift.center_bandwidth_m: {start: 1, stop: 10, step: 1}
    samples: 0          # > 0: that many random combinations instead of the full grid
    seed: 0
    select: {metric: quality, goal: max}

Each method is swept over the keys of its own section (``fusion.<method>.*``) and of the sections all
methods share (``fusion.refine.*``, ``fusion.corners.*``); other methods' keys stay at the base value for it. Every combination is
validated before anything runs. Results are appended to ``results.jsonl`` as they finish, so an
interrupted sweep resumes where it stopped; the file starts with the sweep's identity (the input's
content and the resolved base config), and a sweep of other inputs into the same folder is refused.

A source (``drive``, ``dataset``) is extracted (cached), its poses refined and its reference found as
``featmap run`` does, so a row scores the map a run with its settings would make. The reference is
the run's primary one: the ground truth of a simulated drive or footprints, else the truth-free map
metric against the scans' own points (real KITTI drives, CARMEN logs).

``quality`` = F1(precision, recall) / max(1, count_ratio) against a ground truth, and
F1 / (1 + redundancy) against the scans' own points: accurate *and* concise.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from featmap.config import apply_overrides, closest_key, leaf_keys, read_yaml_mapping
from featmap.datasets.base import parse_frames
from featmap.errors import ConfigError, DatasetError, FeatmapError, shown
from featmap.evaluation import Evaluator, Reference
from featmap.fusion import FUSION_METHODS, fuse
from featmap.fusion.registry import fuse_columns
from featmap.io.atomic import atomic_file_set, atomic_write_text
from featmap.io.segments_csv import SegmentTable
from featmap.pipeline.config import FeatmapConfig, config_from_dict, resolve_config_path
from featmap.pipeline.executor import Executor, SerialExecutor
from featmap.pipeline.run_folder import check_folder_path
from featmap.reporting import NullReporter, Reporter, track

METRICS = ("count", "count_ratio", "precision", "precision_any", "recall", "redundancy", "compression", "offset_cm",
           "corner_err_cm", "f1", "quality", "seconds")
MAX_COMBINATIONS = 100_000


class Range(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    start: float
    stop: float
    num: Optional[int] = Field(None, ge=1)
    step: Optional[float] = Field(None, gt=0)

    @model_validator(mode="after")
    def _check(self):
        if self.stop < self.start:
            raise ValueError(f"stop {self.stop} < start {self.start}")
        if (self.num is None) == (self.step is None):
            raise ValueError("give exactly one of num or step")
        if self.step is not None and (self.stop - self.start) / self.step > MAX_COMBINATIONS:
            raise ValueError(f"{(self.stop - self.start) / self.step:.0f} values; at most {MAX_COMBINATIONS}")
        if self.num is not None and self.num > MAX_COMBINATIONS:
            raise ValueError(f"num {self.num}; at most {MAX_COMBINATIONS}")
        return self

    def values(self) -> list[float]:
        if self.num is not None:
            return [float(v) for v in np.linspace(self.start, self.stop, self.num)]
        n = int(math.floor((self.stop - self.start) / self.step + 1e-9)) + 1
        return [float(round(self.start + k * self.step, 10)) for k in range(n)]


class Select(BaseModel):
    model_config = ConfigDict(extra="forbid")
    metric: Literal[METRICS] = "quality"  # type: ignore[valid-type]
    goal: Literal["max", "min"] = "max"


class SweepSpec(BaseModel):
    model_config = ConfigDict(extra="forbid")
    base: Optional[str] = None
    input: Optional[str] = None
    drive: Optional[str] = None
    batch: Optional[str] = None
    data_dir: str = "data/kitti"
    dataset: Optional[str] = None
    location: Optional[str] = None
    frames: Optional[str] = None
    truth: Optional[str] = None
    methods: list[str] = Field(["proposed"], min_length=1)
    grid: dict[str, Any]
    samples: int = Field(0, ge=0, le=MAX_COMBINATIONS)
    seed: int = Field(0, ge=0)
    select: Select = Select()

    @model_validator(mode="after")
    def _check(self):
        given = [k for k in ("input", "drive", "dataset", "batch") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError("give exactly one of 'input' (a segments.csv), 'drive', 'dataset' (+ 'location') or "
                             "'batch' (a batch's output folder)")
        if self.dataset is not None and self.location is None:
            raise ValueError("'dataset' needs a 'location'")
        if self.frames is not None:
            try:
                parse_frames(self.frames, "'frames':")
            except DatasetError as exc:
                raise ValueError(str(exc)) from None
        if not self.grid:
            raise ValueError("the grid is empty")
        for key, val in list(self.grid.items()):
            if isinstance(val, dict):
                try:
                    self.grid[key] = Range.model_validate(val)
                except ValidationError as exc:
                    err = exc.errors()[0]
                    where = ".".join(str(p) for p in err["loc"])
                    raise ValueError(f"grid key '{key}': {where + ' ' if where else ''}"
                                     f"{err['msg'].removeprefix('Value error, ')}") from None
            elif not isinstance(val, list):
                raise ValueError(f"grid key '{key}': expected a list of values or {{start, stop, num|step}}, "
                                 f"got {shown(val)}")
        return self


@dataclass(frozen=True)
class Combination:
    method: str
    params: dict

    @property
    def key(self) -> str:
        text = json.dumps({"method": self.method, "params": self.params}, sort_keys=True)
        return hashlib.sha1(text.encode()).hexdigest()[:16]


def load_sweep(path: str | Path) -> SweepSpec:
    path = Path(path)
    data = read_yaml_mapping(path, "sweep file")
    try:
        return SweepSpec.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        where = ".".join(str(p) for p in err["loc"])
        if err["type"] == "extra_forbidden":
            raise ConfigError(f"{path}: unknown key '{where}' (allowed: {', '.join(SweepSpec.model_fields)})") from None
        msg = err["msg"].removeprefix("Value error, ")
        raise ConfigError(f"{path}: {where + ': ' if where else ''}{msg}") from None


def applies_to(key: str, method: str) -> bool:
    """Whether grid key ``key`` (``fusion.*``) varies ``method``: its own section's keys, and the keys of the
    sections every method shares (``fusion.refine.*``, ``fusion.corners.*``)."""
    section = key.split(".")[1]
    return section == method or section not in FUSION_METHODS


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def expand(spec: SweepSpec, base: dict, source: str = "sweep") -> tuple[list[Combination], dict[str, FeatmapConfig]]:
    """Validate keys, values and every combination; return the combinations and their configs."""
    leaves = set(leaf_keys(FeatmapConfig))
    values: dict[str, list] = {}
    for key, val in spec.grid.items():
        if key not in leaves:
            inside = sorted(leaf for leaf in leaves if leaf.startswith(key + "."))
            if inside:
                raise ConfigError(f"{source}: grid key '{key}' is a section; sweep its settings, e.g. '{inside[0]}'")
            hint = closest_key(key, FeatmapConfig)
            raise ConfigError(f"{source}: grid key '{key}' does not exist" + (f"; did you mean '{hint}'?" if hint else ""))
        if not key.startswith("fusion."):
            raise ConfigError(f"{source}: grid key '{key}': a sweep re-fuses cached segments and never re-extracts; "
                              "sweep fusion.* keys only")
        vals = val.values() if isinstance(val, Range) else list(val)
        if not vals:
            raise ConfigError(f"{source}: grid key '{key}' has no values")
        same = [("number", float(v)) if _number(v) else (type(v).__name__, repr(v)) for v in vals]
        repeated = [v for k, v in enumerate(vals) if same[k] in same[:k]]
        if repeated:
            raise ConfigError(f"{source}: grid key '{key}' lists the value {repeated[0]!r} more than once")
        values[key] = vals
    for name in spec.methods:
        if name not in FUSION_METHODS:
            raise ConfigError(f"{source}: unknown method '{name}'; allowed: {', '.join(FUSION_METHODS)}")
    keys_of = {name: [k for k in values if applies_to(k, name)] for name in spec.methods}
    unused = [k for k in values if not any(k in keys for keys in keys_of.values())]
    if unused:
        raise ConfigError(f"{source}: grid key '{unused[0]}' applies to none of the methods swept "
                          f"({', '.join(spec.methods)}); add its method to 'methods' or remove the key")
    total = sum(math.prod(len(values[k]) for k in keys) for keys in keys_of.values())
    limit = spec.samples or MAX_COMBINATIONS
    if total > MAX_COMBINATIONS and not spec.samples:
        raise ConfigError(f"{source}: the grid has {total:,} combinations (more than {MAX_COMBINATIONS:,}); "
                          "use 'samples: N' for a random search or fewer values")
    combos: list[Combination] = []
    if total <= MAX_COMBINATIONS:
        for name in spec.methods:
            keys = keys_of[name]
            grid = [dict(zip(keys, v)) for v in itertools.product(*(values[k] for k in keys))] if keys else [{}]
            combos += [Combination(name, params) for params in grid]
        if spec.samples and spec.samples < len(combos):
            rng = np.random.default_rng(spec.seed)
            combos = [combos[i] for i in sorted(rng.choice(len(combos), spec.samples, replace=False))]
    else:   # a huge grid sampled without expanding it
        rng = np.random.default_rng(spec.seed)
        seen: dict[str, Combination] = {}
        weights = np.array([math.prod(len(values[k]) for k in keys_of[n]) for n in spec.methods], float)
        while len(seen) < limit:
            name = spec.methods[int(rng.choice(len(spec.methods), p=weights / weights.sum()))]
            combo = Combination(name, {k: values[k][int(rng.integers(len(values[k])))] for k in keys_of[name]})
            seen.setdefault(combo.key, combo)
        combos = list(seen.values())
    configs = {}
    for combo in combos:
        overrides = [f"{k}={json.dumps(v)}" for k, v in combo.params.items()]
        configs[combo.key] = config_from_dict(apply_overrides(base, overrides, FeatmapConfig),
                                              f"{source} ({combo.method} {combo.params})")
    return combos, configs


def _score(metrics: dict) -> dict:
    """``metrics`` with ``f1`` and ``quality`` (see the module doc) added."""
    p, r, cr, red = (metrics.get(k) for k in ("precision", "recall", "count_ratio", "redundancy"))
    f1 = 2 * p * r / (p + r) if p is not None and r is not None and (p + r) > 0 else None
    quality = None
    if f1 is not None and cr is not None:               # against a ground truth
        quality = f1 / max(1.0, cr)
    elif f1 is not None and red is not None:            # against the scans' own points (truth-free)
        quality = f1 / (1.0 + red)
    return {**metrics, "f1": f1, "quality": quality}


@dataclass(frozen=True)
class SweepInputs:
    """What every combination is evaluated on: world-frame segments (N, 4), their scans (N,), the reference
    (an evaluator with its prepared reference) or None, a digest of all of it, and ``columns``: the keyword
    arguments of :func:`~featmap.fusion.fuse` their per-segment columns give
    (:func:`~featmap.fusion.registry.fuse_columns`: ``rms``, ``max_gap``, ``sensor_xy``, each None when absent)."""

    segments: np.ndarray
    scan: np.ndarray
    reference: tuple[Evaluator, Reference] | None
    digest: str
    columns: dict = field(default_factory=dict)


def _evaluate(task: tuple[SweepInputs, str, str, dict]) -> tuple[str, dict]:
    """Executor task: fuse the inputs with one combination and score it."""
    inputs, key, method, config_dict = task
    config = FeatmapConfig.model_validate(config_dict)
    start = time.perf_counter()
    result = fuse(method, inputs.segments, inputs.scan, config.fusion, **inputs.columns)
    seconds = time.perf_counter() - start
    metrics: dict = {"count": len(result)}
    if inputs.reference is not None:
        evaluator, reference = inputs.reference
        metrics.update({k: v for k, v in evaluator.score(reference, result.segments).items() if k in METRICS})
    return key, {**_score(metrics), "seconds": seconds}


def _read_log(log: Path, identity: dict, out: Path) -> dict[str, dict]:
    """Finished rows of an interrupted sweep (``results.jsonl``); another sweep's log is refused."""
    done: dict[str, dict] = {}
    try:
        lines = log.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"--out {out}: cannot read its {log.name} ({exc}); choose another --out or delete it"
                          ) from None
    try:
        header = json.loads(lines[0]) if lines else None
    except json.JSONDecodeError:
        header = None
    if not isinstance(header, dict) or header.get("sweep") != identity:
        raise ConfigError(f"--out {out}: holds the results of another sweep (other input, base config or version); "
                          "choose another --out or delete it")
    broken = False
    for line in lines[1:]:
        try:
            row = json.loads(line)
            done[row["key"]] = row
        except (json.JSONDecodeError, KeyError, TypeError):
            broken = True       # a line cut short by an interruption
    if broken:
        atomic_write_text(log, "".join(json.dumps(r) + "\n" for r in [header, *done.values()]))
    return done


def run_sweep(combos: list[Combination], configs: dict[str, FeatmapConfig], inputs: SweepInputs, out: Path,
              identity: dict, executor: Executor = SerialExecutor(), reporter: Reporter = NullReporter()) -> list[dict]:
    """Evaluate every combination (resuming from ``out/results.jsonl``); returns one row per combination."""
    check_folder_path(out)
    out.mkdir(parents=True, exist_ok=True)
    log = out / "results.jsonl"
    done = _read_log(log, identity, out) if log.exists() else {}
    if not log.exists():        # the header whole or not at all (a cut one would refuse every resume)
        atomic_write_text(log, json.dumps({"sweep": identity}) + "\n")
    todo = [c for c in combos if c.key not in done]
    by_key = {c.key: c for c in combos}
    shared = executor.share(inputs) if todo and hasattr(executor, "share") else inputs   # sent once to a cluster
    jobs = ((shared, c.key, c.method, configs[c.key].model_dump(mode="json")) for c in todo)
    if todo:
        with open(log, "a") as fh:
            for key, metrics in track(reporter, executor.imap(_evaluate, jobs), len(todo), "sweeping"):
                combo = by_key[key]
                row = {"key": key, "method": combo.method, **combo.params, **metrics}
                fh.write(json.dumps(row) + "\n")
                fh.flush()
                done[key] = row
    return [done[c.key] for c in combos]


def best_row(rows: list[dict], select: Select) -> dict | None:
    valid = [r for r in rows if r.get(select.metric) is not None]
    if not valid:
        return None
    return (max if select.goal == "max" else min)(valid, key=lambda r: r[select.metric])


# --- the sweep command: inputs, outputs ----------------------------------------------------------------

def _digest(*parts: bytes) -> str:
    h = hashlib.blake2b(digest_size=16)
    for part in parts:
        h.update(part)
    return h.hexdigest()


def _reference_content(path: str | Path | None) -> bytes:
    """What a reference was read from, for the sweep's identity: the bytes of the file, or of every file of
    the folder (with their relative paths), so that an edited truth never serves the old rows. ``path``
    may join several with ``;`` (a batch); anything that is not a file or folder counts by its name."""
    if path is None or str(path) == "":
        return b""
    if ";" in str(path):                                   # a batch's truths, united
        return b"\0;".join(_reference_content(part) for part in str(path).split(";"))
    path = Path(path)
    if path.is_file():
        return path.read_bytes()
    if path.is_dir():
        return b"".join(str(p.relative_to(path)).encode() + b"\0" + p.read_bytes()
                        for p in sorted(path.rglob("*")) if p.is_file())
    return str(path).encode()


def load_inputs(spec: SweepSpec, spec_path: Path, base: FeatmapConfig, executor: Executor,
                reporter: Reporter, cache_dir: str | Path = "data/cache") -> SweepInputs:
    """The segments, scans and reference a sweep evaluates on."""
    from featmap.datasets import SourceSpec, open_source
    from featmap.datasets.kitti_raw import parse_drive
    from featmap.evaluation import EvaluationContext
    from featmap.evaluation.plugins import Footprints, SimulatorTruth
    from featmap.evaluation.references import footprints_truth
    from featmap.io.run_metrics import read_run_metrics
    from featmap.io.sim_truth import FOOTPRINT_WALLS_FILE
    from featmap.io.segments_csv import read_segments_csv
    from featmap.pipeline.extract import extract_source
    from featmap.pipeline.refine import refine_extraction
    from featmap.pipeline.run import primary_reference
    from featmap.pipeline.segment_store import SegmentStore

    if spec.input is not None:
        table = read_segments_csv(spec.input)
        meta_path = Path(spec.input).parent / "metrics.json"
        meta = read_run_metrics(meta_path) if meta_path.exists() else None
        frame = meta.geo_frame.frame() if meta is not None and meta.geo_frame is not None else None
        reference = record = None
        truth_path = Path(spec.truth) if spec.truth else None
        if truth_path is None and meta is not None and meta.primary in ("truth", "footprints"):
            truth_path = meta.reference_path(meta.primary, meta_path.parent)
        if truth_path is not None:
            if truth_path.is_dir():
                ev = SimulatorTruth()
                ref = ev.prepare(EvaluationContext(truth_path, meta.source.frames_processed if meta else None, frame,
                                                   base.evaluation))
                if ref is None:
                    raise FeatmapError(f"{spec_path}: truth {truth_path} is not a truth/ folder or a footprints file")
            else:
                if frame is None:
                    raise FeatmapError(f"{spec_path}: truth {truth_path} is WGS84 but {spec.input} has no metrics.json "
                                       "with a geo origin beside it to place it in the local frame")
                own = meta is not None and meta.scored_against("footprints", truth_path, meta_path.parent)
                run_dir = meta_path.parent if own else None
                record = None if run_dir is None else run_dir / FOOTPRINT_WALLS_FILE    # as the run observed them
                ev = Footprints()
                ref = Reference(footprints_truth(truth_path, frame, run_dir), str(truth_path.resolve()))
            reference = (ev, ref)
        digest = _digest(Path(spec.input).read_bytes(), _reference_content(truth_path), _reference_content(record))
        return SweepInputs(table.segments, table.scan, reference, digest, fuse_columns(table.extra, len(table)))
    if spec.batch is not None:
        return _batch_inputs(Path(spec.batch), base, cache_dir)
    if spec.dataset is not None:
        source_spec = SourceSpec(spec.dataset, spec.location, spec.frames)
    elif spec.drive == "default":
        source_spec = SourceSpec("simulated", "residential", spec.frames)
    else:
        date, drive_id = parse_drive(spec.drive, f"{spec_path}: drive:")
        source_spec = SourceSpec("kitti_raw", str(Path(spec.data_dir) / date / f"{spec.drive}_sync"), spec.frames)
    try:
        source = open_source(source_spec, reporter)
    except DatasetError as exc:         # its message names the flag a run takes (--frames, --dataset): say which file
        raise DatasetError(f"{spec_path}: {exc}") from None
    extraction = extract_source(source, base.extraction, SegmentStore(cache_dir), executor, reporter)
    poses = refine_extraction(extraction, base.refinement).poses       # the poses a run would fuse with
    table = extraction.world_table(poses)
    ctx = EvaluationContext(source.location, extraction.frames, source.geo_origin, base.evaluation,
                            extraction.world_points(poses), table.segments, point_scans=extraction.world_point_scans())
    reference = primary_reference(ctx)
    return _table_inputs(table, reference)


def _table_inputs(table: SegmentTable, reference: tuple[Evaluator, Reference] | None) -> SweepInputs:
    """Sweep inputs from a world-frame segment table (the per-segment columns the fusion reads, when it has
    them, go along: :func:`~featmap.fusion.registry.fuse_columns`)."""
    columns = fuse_columns(table.extra, len(table))
    parts = [table.segments.tobytes(), table.scan.tobytes()] + [np.asarray(c).tobytes() for c in columns.values()
                                                                if c is not None]
    digest = _digest(*parts, _reference_content(reference[1].path if reference else None), _observation_content(reference))
    return SweepInputs(table.segments, table.scan, reference, digest, columns)


def _observation_content(reference: tuple[Evaluator, Reference] | None) -> bytes:
    """What footprints were scored on besides their file: the walls kept and what the scans observed of
    them (the rule may change while the file and the segments do not); nothing for other references."""
    if reference is None or reference[0].name != "footprints":
        return b""
    truth = reference[1].data
    return np.asarray(truth.walls, float).tobytes() + repr(truth.observed).encode()


def _batch_inputs(folder: Path, base: FeatmapConfig, cache_dir) -> SweepInputs:
    """A finished batch's merged segments (its drives aligned by ``base.refinement.drives``), scored as its
    merged map is (``featmap.batch.merged_reference``: the drives' truths united, footprints, or the
    drives' scan points)."""
    from featmap.batch import MERGED, merged_inputs, merged_reference
    from featmap.io.batch_records import read_merged_record

    record = read_merged_record(folder / MERGED / "merged.json")
    inputs = merged_inputs([(d.name, d.run_dir) for d in record.drives], base.refinement.drives)
    reference = merged_reference(inputs, base.evaluation, cache_dir)
    table = inputs.table
    return _table_inputs(table, reference)


def made_with(spec: SweepSpec) -> str | None:
    """The config a sweep that names no base varies: the one its input was made with (a batch's merged map's
    ``config.yaml``, the ``config.yaml`` of the run folder that holds its segments), or for a source the
    preset of its format (``indoor_2d`` for CARMEN logs, as ``featmap run`` picks); None = the defaults."""
    from featmap.datasets import DATASETS

    if spec.batch is not None or spec.input is not None:
        from featmap.batch import MERGED

        path = Path(spec.batch) / MERGED / "config.yaml" if spec.batch is not None else Path(spec.input).parent / "config.yaml"
        return str(path) if path.is_file() else None
    return DATASETS[spec.dataset].preset if spec.dataset in DATASETS else None


def run_sweep_file(spec_path: str | Path, out: str | Path, executor: Executor = SerialExecutor(),
                   reporter: Reporter = NullReporter(), config_path: str | Path | None = None,
                   overrides: list[str] = (), cache_dir: str | Path = "data/cache") -> tuple[list[dict], dict | None]:
    """Validate, run (resumably), and write ``sweep.csv``, ``best.yaml`` and the plots into ``out``.

    ``out`` then holds this sweep's outputs only: a ``best.yaml`` or plot an earlier sweep into it wrote
    and this one does not (another grid's) is removed; other files are left alone. The table, ``best.yaml``
    and the plots are written as one set (``atomic_file_set``): an error or Ctrl-C while they are drawn
    leaves the earlier sweep's whole set (the resumable log ``results.jsonl`` is written as the sweep goes).

    The base config is the sweep file's ``base``, or ``config_path`` when given, then ``overrides``.
    """
    import csv
    import io

    from featmap import __version__
    from featmap.plotting.sweep_plots import PLOT_NAMES, draw_sweep_plots

    spec_path = Path(spec_path)
    spec = load_sweep(spec_path)
    base_path = config_path or spec.base
    if base_path is None:
        base_path = made_with(spec)
        if base_path is not None:
            reporter.info(f"base config: {base_path}, the one the input was made with ('base:' or --config to change)")
    flag = "--config" if config_path is not None or spec.base is None else f"{spec_path}: base:"
    base = read_yaml_mapping(resolve_config_path(base_path, flag)) if base_path else {}
    if overrides:
        base = apply_overrides(base, overrides, FeatmapConfig)
    base_config = config_from_dict(base, str(base_path or "defaults"))
    combos, configs = expand(spec, base, str(spec_path))          # every combination validated first
    inputs = load_inputs(spec, spec_path, base_config, executor, reporter, cache_dir)
    if inputs.reference is None:
        reporter.warning(f"{spec_path}: nothing to score against (no ground truth for this input), so the sweep "
                         "reports feature counts only; a 'dataset:' or 'drive:' source is scored with the truth-free "
                         "metric against its scans' own points")
    identity = {"input": inputs.digest, "base": base_config.model_dump(mode="json"), "featmap": __version__}
    out = Path(out)
    rows = run_sweep(combos, configs, inputs, out, identity, executor, reporter)
    keys = list(dict.fromkeys(k for c in combos for k in c.params))
    cols = ["method"] + keys + [m for m in METRICS if any(m in r for r in rows)]
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(cols)
    for r in rows:
        writer.writerow(["" if r.get(c) is None else r.get(c) for c in cols])
    best = best_row(rows, spec.select) if inputs.reference is not None else None
    with atomic_file_set(out, ("sweep.csv", "best.yaml", *PLOT_NAMES)) as stage:
        atomic_write_text(stage / "sweep.csv", buf.getvalue())
        if best is not None:      # (no best: an earlier grid's best.yaml is removed with the set)
            overrides_best = [f"{k}={json.dumps(best[k])}" for k in keys if k in best and applies_to(k, best["method"])]
            cfg = config_from_dict(apply_overrides(base, overrides_best, FeatmapConfig), "best")
            header = (f"# best of {len(rows)} combinations for {spec.select.goal} {spec.select.metric} "
                      f"= {best[spec.select.metric]:.4f} (method {best['method']}); use with --config\n")
            atomic_write_text(stage / "best.yaml", header + cfg.to_yaml())
        draw_sweep_plots(rows, keys, stage, spec.select.metric if inputs.reference is not None else "count")
    return rows, best
