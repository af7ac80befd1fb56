"""Parameter sweeps over fusion settings, on cached extracted segments (a sweep never re-extracts).

A sweep file::

    base: configs/default.yaml            # optional
    input: runs/residential/segments.csv  # or: drive: 2011_09_30_drive_0018 (+ data_dir, frames); drive: default
    truth: path/to/truth_or_footprints    # optional; found automatically next to a run's segments.csv
    methods: [proposed, meanshift]
    grid:
      fusion.proposed.delta_deg: [2, 5, 10]
      fusion.proposed.eta_m: {start: 0.2, stop: 2.0, num: 10}
      fusion.meanshift.center_bandwidth_m: {start: 1, stop: 10, step: 1}
    samples: 0          # > 0: that many random combinations instead of the full grid
    seed: 0
    select: {metric: quality, goal: max}

Each method is swept over the keys of its own section (``fusion.<method>.*``) and the shared
``fusion.corners.*``; other methods' keys stay at the base value for it. Every combination is
validated before anything runs. Results are appended to ``results.jsonl`` as they finish, so an
interrupted sweep resumes where it stopped.

``quality`` = F1(precision, recall) / max(1, count_ratio): accurate *and* concise.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from featmap.config import FeatmapConfig, _valid_keys, apply_overrides, closest_key, config_from_dict, read_yaml_mapping
from featmap.errors import ConfigError, FeatmapError
from featmap.fusion.registry import FUSION_METHODS

METRICS = ("count", "count_ratio", "precision", "precision_any", "recall", "redundancy", "offset_cm",
           "corner_err_cm", "f1", "quality", "seconds")


class Range(BaseModel):
    model_config = ConfigDict(extra="forbid")
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
    data_dir: str = "data/kitti"
    frames: Optional[str] = None
    truth: Optional[str] = None
    methods: list[str] = ["proposed"]
    grid: dict[str, Any]
    samples: int = Field(0, ge=0)
    seed: int = 0
    select: Select = Select()

    @model_validator(mode="after")
    def _check(self):
        if (self.input is None) == (self.drive is None):
            raise ValueError("give exactly one of 'input' (a segments.csv) or 'drive'")
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
                                 f"got {val!r}")
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
    data = read_yaml_mapping(path)
    try:
        return SweepSpec.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        where = ".".join(str(p) for p in err["loc"])
        if err["type"] == "extra_forbidden":
            raise ConfigError(f"{path}: unknown key '{where}' (allowed: {', '.join(SweepSpec.model_fields)})") from None
        msg = err["msg"].removeprefix("Value error, ")
        raise ConfigError(f"{path}: {where + ': ' if where else ''}{msg}") from None


def expand(spec: SweepSpec, base: dict, source: str = "sweep") -> tuple[list[Combination], dict[str, FeatmapConfig]]:
    """Validate keys, values and every combination; return the combinations and their configs."""
    leaves = {k for k in _valid_keys(FeatmapConfig) if k.count(".") >= 1}
    values: dict[str, list] = {}
    for key, val in spec.grid.items():
        if key not in leaves:
            hint = closest_key(key)
            raise ConfigError(f"{source}: grid key '{key}' does not exist" + (f"; did you mean '{hint}'?" if hint else ""))
        if not key.startswith("fusion."):
            raise ConfigError(f"{source}: grid key '{key}': a sweep re-fuses cached segments and never re-extracts; "
                              "sweep fusion.* keys only")
        vals = val.values() if isinstance(val, Range) else list(val)
        if not vals:
            raise ConfigError(f"{source}: grid key '{key}' has no values")
        values[key] = vals
    for name in spec.methods:
        if name not in FUSION_METHODS:
            raise ConfigError(f"{source}: unknown method '{name}'; allowed: {', '.join(FUSION_METHODS)}")
    combos: list[Combination] = []
    for name in spec.methods:
        keys = [k for k in values if k.startswith(f"fusion.{name}.") or k.startswith("fusion.corners.")]
        grid = [dict(zip(keys, v)) for v in itertools.product(*(values[k] for k in keys))] if keys else [{}]
        combos += [Combination(name, params) for params in grid]
    if spec.samples and spec.samples < len(combos):
        rng = np.random.default_rng(spec.seed)
        combos = [combos[i] for i in sorted(rng.choice(len(combos), spec.samples, replace=False))]
    configs = {}
    for combo in combos:
        overrides = [f"{k}={json.dumps(v)}" for k, v in combo.params.items()]
        configs[combo.key] = config_from_dict(apply_overrides(base, overrides), f"{source} ({combo.method} {combo.params})")
    return combos, configs


def _score(metrics: dict) -> dict:
    p, r, cr = metrics.get("precision"), metrics.get("recall"), metrics.get("count_ratio")
    f1 = 2 * p * r / (p + r) if p is not None and r is not None and (p + r) > 0 else None
    quality = f1 / max(1.0, cr) if f1 is not None and cr is not None else None
    return {**metrics, "f1": f1, "quality": quality}


_STATE: dict = {}


def _init(segments, scan, truth) -> None:
    _STATE.update(segments=segments, scan=scan, truth=truth)


def _evaluate(args: tuple[str, str, dict]) -> tuple[str, dict]:
    from featmap.evaluation import compute_metrics
    from featmap.fusion import fuse

    key, method, config_dict = args
    config = FeatmapConfig.model_validate(config_dict)
    start = time.perf_counter()
    result = fuse(method, _STATE["segments"], _STATE["scan"], config)
    seconds = time.perf_counter() - start
    metrics = {"count": len(result)}
    if _STATE["truth"] is not None:
        metrics.update({k: v for k, v in compute_metrics(result.segments, _STATE["truth"]).items()
                        if k in METRICS})
    return key, {**_score(metrics), "seconds": seconds}


def run_sweep(combos: list[Combination], configs: dict[str, FeatmapConfig], segments, scan, truth,
              out: Path, workers: int = 2, progress=None) -> list[dict]:
    """Evaluate every combination (resuming from ``out/results.jsonl``); returns one row per combination."""
    out.mkdir(parents=True, exist_ok=True)
    log = out / "results.jsonl"
    done: dict[str, dict] = {}
    if log.exists():
        broken = False
        for line in log.read_text().splitlines():
            try:
                row = json.loads(line)
                done[row["key"]] = row
            except (json.JSONDecodeError, KeyError):
                broken = True       # a line cut short by an interruption
        if broken:
            from featmap.io.atomic import atomic_write_text

            atomic_write_text(log, "".join(json.dumps(r) + "\n" for r in done.values()))
    todo = [c for c in combos if c.key not in done]
    by_key = {c.key: c for c in combos}
    jobs = [(c.key, c.method, configs[c.key].model_dump(mode="json")) for c in todo]
    if jobs:
        if workers > 1 and len(jobs) > 1:
            import multiprocessing as mp
            from concurrent.futures import ProcessPoolExecutor

            pool = ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"), initializer=_init,
                                       initargs=(segments, scan, truth))
            results = pool.map(_evaluate, jobs)
        else:
            _init(segments, scan, truth)
            pool, results = None, map(_evaluate, jobs)
        try:
            iterator = progress(results, len(jobs)) if progress else results
            with open(log, "a") as fh:
                for key, metrics in iterator:
                    combo = by_key[key]
                    row = {"key": key, "method": combo.method, **combo.params, **metrics}
                    fh.write(json.dumps(row) + "\n")
                    fh.flush()
                    done[key] = row
        finally:
            if pool is not None:
                pool.shutdown(cancel_futures=True)
    return [done[c.key] for c in combos]


def best_row(rows: list[dict], select: Select) -> dict | None:
    valid = [r for r in rows if r.get(select.metric) is not None]
    if not valid:
        return None
    return (max if select.goal == "max" else min)(valid, key=lambda r: r[select.metric])


def pareto_front(points: np.ndarray) -> np.ndarray:
    """Indices of the non-dominated points of (K, 2) ``(cost, benefit)``: lower cost, higher benefit."""
    order = np.lexsort((-points[:, 1], points[:, 0]))
    front, best = [], -np.inf
    for i in order:
        if points[i, 1] > best:
            front.append(i)
            best = points[i, 1]
    return np.asarray(front, dtype=int)


# --- the sweep command: inputs, outputs ----------------------------------------------------------------

def _load_inputs(spec: SweepSpec, spec_path: Path):
    """(segments (N, 4), scan (N,), truth or None, geo frame or None) for a sweep."""
    from featmap.evaluation import load_truth, truth_from_footprints
    from featmap.geo import GeoFrame
    from featmap.io.jsonfile import read_json
    from featmap.io.segments_csv import read_segments_csv

    if spec.input is not None:
        table = read_segments_csv(spec.input)
        meta_path = Path(spec.input).parent / "metrics.json"
        meta = read_json(meta_path) if meta_path.exists() else {}
        frame = GeoFrame(**meta["geo_frame"]) if "geo_frame" in meta else None
        truth_path = spec.truth or meta.get("ground_truth")
        truth = None
        if truth_path:
            truth_path = Path(truth_path)
            if truth_path.is_dir():
                truth = load_truth(truth_path, frame, meta.get("frames_processed"))
            elif frame is None:
                raise FeatmapError(f"{spec_path}: truth {truth_path} is WGS84 but {spec.input} has no metrics.json "
                                   "beside it to place it in the local frame")
            else:
                truth = truth_from_footprints(truth_path, frame)
        return table.segments, table.scan, truth
    from featmap.datasets import KittiRawDataset, parse_frames
    from featmap.pipeline import MappingPipeline
    from featmap.simulation.default import ensure_default_drive

    if spec.drive == "default":
        data_dir, drive = ensure_default_drive()
    else:
        data_dir, drive = Path(spec.data_dir), spec.drive
    ds = KittiRawDataset(data_dir, drive, parse_frames(spec.frames))
    base = config_from_dict(read_yaml_mapping(spec.base) if spec.base else {}, spec.base or "defaults")
    pipe = MappingPipeline(ds, base, spec_path.parent, [], workers=2)
    table = pipe.extract()
    truth = load_truth(ds.truth_dir, ds.geo_frame, ds.frames) if ds.truth_dir is not None else None
    return table.segments, table.scan, truth


def run_sweep_file(spec_path: str | Path, out: str | Path, workers: int = 2, progress=None) -> tuple[list[dict], dict | None]:
    """Validate, run (resumably), and write ``sweep.csv``, ``best.yaml`` and the plots into ``out``."""
    import csv
    import io

    from featmap.io.atomic import atomic_write_text
    from featmap.plotting.sweep_plots import plot_sweep

    spec_path = Path(spec_path)
    spec = load_sweep(spec_path)
    base = read_yaml_mapping(spec.base) if spec.base else {}
    config_from_dict(base, spec.base or "defaults")
    combos, configs = expand(spec, base, str(spec_path))          # every combination validated first
    segments, scan, truth = _load_inputs(spec, spec_path)
    out = Path(out)
    rows = run_sweep(combos, configs, segments, scan, truth, out, workers, progress)
    keys = list(dict.fromkeys(k for c in combos for k in c.params))
    cols = ["method"] + keys + [m for m in METRICS if any(m in r for r in rows)]
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(cols)
    for r in rows:
        writer.writerow(["" if r.get(c) is None else r.get(c) for c in cols])
    atomic_write_text(out / "sweep.csv", buf.getvalue())
    best = best_row(rows, spec.select) if truth is not None else None
    if best is not None:
        overrides = [f"{k}={json.dumps(best[k])}" for k in keys if k in best and k.startswith(f"fusion.{best['method']}.")
                     or (k in best and k.startswith("fusion.corners."))]
        cfg = config_from_dict(apply_overrides(base, overrides), "best")
        header = (f"# best of {len(rows)} combinations for {spec.select.goal} {spec.select.metric} "
                  f"= {best[spec.select.metric]:.4f} (method {best['method']}); use with --config\n")
        atomic_write_text(out / "best.yaml", header + cfg.to_yaml())
    plot_sweep(rows, keys, out, spec.select.metric if truth is not None else "count")
    return rows, best
