"""Many drives: every drive's run as a task on a Dask cluster, a summary, and one merged map.

A batch file (paths relative to the current folder, like ``featmap run`` and sweep files)::

    scheduler: tcp://10.0.0.5:8786   # optional: an existing Dask cluster (--scheduler overrides it);
                                     # without one, a LocalCluster sized to this machine
    workers: 2                       # LocalCluster worker processes (default: the machine's cores)
    out: runs/batch/example          # optional (--out overrides it)
    config: configs/default.yaml     # base config of every drive (--config replaces it)
    set: [output.plots=false]        # overrides for every drive (--set adds to them)
    methods: all                     # or [proposed, density]
    cache_dir: data/cache            # the segment cache (shared by every drive)
    sim_root: data/sim               # where simulated drives are simulated on first use
    merge: true                      # fuse every drive into OUT/merged/
    scan_tasks: false                # true: each drive's scans are tasks of their own (fewer drives than workers)
    drives:
      - world: residential                     # a simulated world (built-in name or file)
      - world: residential_cross
        set: [fusion.proposed.eta_m=0.4]       # this drive only
      - kitti: 2011_09_26_drive_00*            # KITTI raw drives by name (globbed), with data_dir
        data_dir: data/kitti
        frames: "0:200"
      - dataset: carmen                        # any registered format: kind + location (globbed)
        location: data/carmen/intel.log.gz
        name: intel                            # run folder name (default: from the source)
        config: indoor_2d

Each drive runs exactly as ``featmap run`` would run it alone (same source, resolved config, methods
and cache): the config of a drive is its ``config`` (else ``--config``, else the batch's ``config``,
else the preset of its format), then the batch's ``set``, ``--set`` and the drive's ``set``. Its run
folder ``OUT/<name>`` therefore has the same contents as ``featmap run ... --out OUT/<name>``, plus
``batch.json``: the content key of the run (source identity and data fingerprint, resolved config,
methods, featmap version). A re-run skips every drive whose key is unchanged. A drive that fails is
reported in the summary and does not stop the others.

The task graph: one simulation task per simulated world not yet simulated -> one task per drive ->
one merge task (``OUT/merged/``: every drive's segments in the first drive's local frame, fused
together, with the drives that saw each feature). ``OUT/summary.json`` records every drive, the
totals and the graph's critical path.
"""

from __future__ import annotations

import asyncio
import contextlib
import glob
import hashlib
import json
import os
import signal
import threading
import time
import traceback
import uuid
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Iterable, Optional, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from featmap import __version__
from featmap.config import read_yaml_mapping
from featmap.datasets import SourceSpec
from featmap.datasets.base import parse_frames
from featmap.errors import ConfigError, FeatmapError, InputFileError
from featmap.io.batch_records import (BatchSummary, DriveKey, DriveRecord, MergedDrive, MergedRecord,
                                      read_drive_key, write_batch_summary, write_drive_key, write_merged_record)
from featmap.pipeline.config import load_config
from featmap.pipeline.run_folder import check_folder_path, is_leftover
from featmap.reporting import NullReporter, RecordingReporter, Reporter

KEY_FILE = "batch.json"
MERGED = "merged"
SUMMARY_FILE = "summary.json"
ERRORS_FILE = "errors.txt"
BATCH_ENTRIES = (MERGED, SUMMARY_FILE, ERRORS_FILE)
"""What a batch writes at the top of its output folder besides the drives' run folders: no drive may be named so."""
GLOB_CHARS = set("*?[")


# --- the batch file --------------------------------------------------------------------------------------

class DriveEntry(BaseModel):
    """One entry of ``drives:`` (a glob may expand to several drives)."""

    model_config = ConfigDict(extra="forbid")
    world: Optional[str] = Field(None, description="a simulated world: built-in name or file (simulated on first use)")
    kitti: Optional[str] = Field(None, description="KITTI raw drive name YYYY_MM_DD_drive_NNNN (globbed), with data_dir")
    data_dir: Optional[str] = Field(None, description="KITTI raw root (default data/kitti)")
    dataset: Optional[str] = Field(None, description="a registered scan format, with location")
    location: Optional[str] = Field(None, description="the dataset's folder or file (globbed)")
    name: Optional[str] = Field(None, description="run folder name (one drive only; default: from the source)")
    frames: Optional[str] = None
    skip_bad_scans: bool = False
    config: Optional[str] = Field(None, description="this drive's base config file or preset")
    set: list[str] = Field(default_factory=list, description="this drive's --set overrides")

    @model_validator(mode="after")
    def _check(self):
        given = [k for k in ("world", "kitti", "dataset") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError("give exactly one of 'world', 'kitti' (+ 'data_dir') or 'dataset' (+ 'location')")
        if self.dataset is not None and self.location is None:
            raise ValueError("'dataset' needs a 'location'")
        if self.location is not None and self.dataset is None:
            raise ValueError("'location' goes with 'dataset'")
        if self.data_dir is not None and self.kitti is None:
            raise ValueError("'data_dir' goes with 'kitti'")
        if self.frames is not None:
            try:
                parse_frames(self.frames, "'frames':")
            except FeatmapError as exc:
                raise ValueError(str(exc)) from None
        if self.skip_bad_scans and self.dataset == "carmen":
            raise ValueError("'skip_bad_scans' leaves out unreadable scan files; a CARMEN log is read whole")
        return self


class BatchSpec(BaseModel):
    model_config = ConfigDict(extra="forbid")
    scheduler: Optional[str] = None
    workers: Optional[int] = Field(None, ge=1)
    out: Optional[str] = None
    config: Optional[str] = None
    set: list[str] = Field(default_factory=list)
    methods: Union[str, list[str]] = "all"
    cache_dir: str = "data/cache"
    sim_root: str = "data/sim"
    merge: bool = True
    scan_tasks: bool = False
    drives: list[DriveEntry] = Field(min_length=1)


def _pydantic_message(exc: ValidationError, path: Path, model: type[BaseModel]) -> str:
    errors = exc.errors()
    err = next((e for e in errors if e["type"] == "extra_forbidden"), errors[0])   # a typo explains the rest
    loc = [str(p) for p in err["loc"]]
    where = ".".join(loc)
    if len(loc) >= 2 and loc[0] == "drives" and loc[1].isdigit():
        where = f"drives[{loc[1]}]" + ("." + ".".join(loc[2:]) if loc[2:] else "")
    if err["type"] == "extra_forbidden":
        allowed = DriveEntry.model_fields if loc[0] == "drives" else model.model_fields
        return f"{path}: unknown key '{where}' (allowed: {', '.join(allowed)})"
    if err["type"] == "missing" and where == "drives":
        return f"{path}: no 'drives' (a list of drives: world, kitti or dataset + location)"
    msg = err["msg"].removeprefix("Value error, ")
    return f"{path}: {where + ': ' if where else ''}{msg}"


def load_batch(path: str | Path) -> BatchSpec:
    """Read and validate a batch file; a one-line ConfigError naming the file and key otherwise."""
    path = Path(path)
    data = read_yaml_mapping(path, "batch file")
    try:
        return BatchSpec.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(_pydantic_message(exc, path, BatchSpec)) from None


# --- planning: drives, configs, keys (in the client; nothing runs yet) --------------------------------------

@dataclass(frozen=True)
class DriveTask:
    """Everything a worker needs to run one drive (picklable; every path absolute).

    Attributes:
        name: the drive's run folder name.
        spec: its source (simulated drives carry their ``sim_root`` in ``spec.options``).
        config: the resolved configuration (JSON form of a FeatmapConfig).
        methods: fusion methods.
        out: the run folder.
        cache_dir: the segment cache.
        world: the world file of a simulated drive (its simulation task's key), else None.
        topic: Dask event topic for progress (None: no events).
        scan_tasks: extract the scans as tasks of their own (through the worker's client).
    """

    name: str
    spec: SourceSpec
    config: dict
    methods: tuple[str, ...]
    out: str
    cache_dir: str
    world: Optional[str] = None
    topic: Optional[str] = None
    scan_tasks: bool = False


@dataclass(frozen=True)
class BatchPlan:
    """A validated batch: its drives (in the order of the file), where it writes, what it merges."""

    path: Path
    out: Path
    drives: list[DriveTask]
    methods: tuple[str, ...]
    merge_config: dict
    merge: bool
    scheduler: Optional[str]
    workers: Optional[int]
    cache_dir: str = "data/cache"
    scheduler_given_by: str = "--scheduler"
    """Where ``scheduler`` came from, for errors: the flag, or the batch file's key."""


def _strip_name(name: str) -> str:
    for suffix in (".gz", ".bz2", ".log", ".clf", ".yaml", ".yml", ".geojson", ".json"):
        name = name.removesuffix(suffix)
    return name.removesuffix("_sync")


def _expand(pattern: str, what: str, path: Path, index: int, dirs_only: bool = False) -> list[str]:
    """Absolute paths a glob matches (sorted); the path itself when it has no glob characters."""
    if not GLOB_CHARS & set(pattern):
        return [str(Path(pattern).expanduser().absolute())]
    matches = sorted(p for p in glob.glob(str(Path(pattern).expanduser())) if not dirs_only or Path(p).is_dir())
    if not matches:
        raise ConfigError(f"{path}: drives[{index}]: {what} {pattern!r} matches nothing")
    return [str(Path(m).absolute()) for m in matches]


def _sources(entry: DriveEntry, index: int, path: Path, sim_root: Path) -> list[tuple[str, SourceSpec, Optional[str]]]:
    """(default name, source spec, world file) of every drive an entry names."""
    from featmap.datasets import DATASETS
    from featmap.datasets.kitti_raw import parse_drive
    from featmap.simulation.worlds import load_world, resolve_world_path

    where = f"{path}: drives[{index}]"
    if entry.world is not None:
        try:
            world_path = str(resolve_world_path(entry.world).absolute())
            load_world(world_path)                          # a bad world file fails now, before any work
        except FeatmapError as exc:
            raise ConfigError(f"{where}: {exc}") from None
        location = entry.world if Path(world_path).parent == _builtin_dir() else world_path
        spec = SourceSpec("simulated", location, entry.frames, entry.skip_bad_scans, (("sim_root", str(sim_root)),))
        return [(Path(entry.world).stem, spec, world_path)]
    if entry.kitti is not None:
        data_dir = Path(entry.data_dir or "data/kitti")
        out = []
        if GLOB_CHARS & set(entry.kitti):
            folders = _expand(str(data_dir / "*" / f"{entry.kitti}_sync"), "kitti", path, index, dirs_only=True)
        else:
            try:
                date, _ = parse_drive(entry.kitti, "kitti:")
            except FeatmapError as exc:
                raise ConfigError(f"{where}: {exc}") from None
            folders = [str((data_dir / date / f"{entry.kitti}_sync").absolute())]
        for folder in folders:
            out.append((_strip_name(Path(folder).name),
                        SourceSpec("kitti_raw", folder, entry.frames, entry.skip_bad_scans), None))
        return out
    if entry.dataset not in DATASETS:
        raise ConfigError(f"{where}: unknown dataset {entry.dataset!r}; allowed: {', '.join(DATASETS)}")
    if entry.dataset == "simulated":
        raise ConfigError(f"{where}: give a simulated drive as 'world: NAME_OR_FILE'")
    return [(_strip_name(Path(loc).name), SourceSpec(entry.dataset, loc, entry.frames, entry.skip_bad_scans), None)
            for loc in _expand(entry.location, "location", path, index)]


def _builtin_dir() -> Path:
    from featmap.simulation.worlds import WORLDS_DIR

    return WORLDS_DIR


def _run_folder_evidence(folder: Path) -> Optional[str]:
    """The file that makes ``folder`` a folder written whole by one featmap command (``featmap run``'s
    ``metrics.json`` with its ``config.yaml``, or the list of entries any run folder keeps, ``MANIFEST``),
    or None."""
    from featmap.pipeline.run_folder import MANIFEST

    if (folder / MANIFEST).is_file():
        return MANIFEST
    if (folder / "metrics.json").is_file() and (folder / "config.yaml").is_file():
        return "metrics.json"
    return None


def _is_batch_folder(folder: Path, drive_names: Iterable[str] = ()) -> bool:
    """``folder`` is a batch's output: its summary, its merged map, a drive's run folder with its key (a batch
    stopped before the summary), or the run folder of one of ``drive_names`` (a batch stopped between
    swapping that folder in and writing its key)."""
    if (folder / SUMMARY_FILE).is_file() or (folder / MERGED / "merged.json").is_file():
        return True
    names = set(drive_names)
    return any(entry.is_dir() and ((entry / KEY_FILE).is_file()
                                   or (entry.name in names and _run_folder_evidence(entry) is not None))
               for entry in folder.iterdir())


def check_batch_folder(folder: str | Path, what: str = "--out", drive_names: Iterable[str] = ()) -> None:
    """Fail (one line naming ``what`` and the folder) unless ``folder`` is new, empty (but for the leftovers of
    killed runs) or a batch's own output folder (which the batch resumes; ``drive_names``: the batch's
    drives, whose run folders count as its own): a batch never mixes its run folders with a run folder's
    files, nor with other files, nor writes inside a run folder (a new run of it would replace the folder
    whole)."""
    folder = Path(folder)
    for above in [folder, *folder.absolute().parents]:
        evidence = _run_folder_evidence(above) if above.is_dir() else None
        if evidence is None:
            continue
        where = "is" if above == folder else f"is inside {above}, which is"
        raise ConfigError(f"{what} {folder}: {where} the output folder of a featmap run (it holds {evidence}), not "
                          "of a batch; give a new or empty folder, or an earlier batch's output folder")
    if not folder.is_dir():
        return
    try:
        entries = [p.name for p in folder.iterdir() if not is_leftover(p.name)]
        if entries and not _is_batch_folder(folder, drive_names):
            raise ConfigError(f"{what} {folder}: holds other files (such as {sorted(entries)[0]}) and is not a "
                              f"featmap batch output folder (no {SUMMARY_FILE}); give a new or empty folder, or an "
                              "earlier batch's output folder")
    except OSError as exc:
        raise ConfigError(f"{what} {folder}: cannot read it ({exc.strerror or exc})") from None


def plan_batch(path: str | Path, out: str | Path | None = None, config: str | Path | None = None,
               overrides: list[str] = (), scheduler: str | None = None) -> BatchPlan:
    """Validate a batch file and resolve every drive (globs, names, configs, absolute paths).

    Args:
        out: the batch's output folder (default: the file's ``out``, else ``runs/batch/<file stem>``).
        config: replaces the file's ``config`` (the command's ``--config``).
        overrides: ``--set`` overrides for every drive (after the file's ``set``).
        scheduler: replaces the file's ``scheduler``.
    Raises:
        ConfigError: a bad key, value, glob, world, config or duplicate drive name, or an output folder that
            is not new, empty or an earlier batch's (:func:`check_batch_folder`) (nothing has run).
    """
    from featmap.datasets import DATASETS
    from featmap.fusion import resolve_methods

    path = Path(path)
    spec = load_batch(path)
    methods = tuple(resolve_methods(spec.methods, f"{path}: methods"))
    folder = Path(out or spec.out or Path("runs") / "batch" / path.stem)
    what = "--out" if out else f"{path}: out"
    check_folder_path(folder, what)
    out = folder.absolute()
    cache_dir = str(Path(spec.cache_dir).expanduser().absolute())
    sim_root = Path(spec.sim_root).expanduser().absolute()
    base = config if config is not None else spec.config
    common = list(spec.set) + list(overrides)
    drives: list[DriveTask] = []
    seen: dict[str, int] = {}
    world_of_stem: dict[str, tuple[str, int]] = {}    # simulated drives live in sim_root/<world stem>
    for index, entry in enumerate(spec.drives):
        sources = _sources(entry, index, path, sim_root)
        for _, _, world in sources:
            if world is None:
                continue
            other = world_of_stem.setdefault(Path(world).stem, (world, index))
            if other[0] != world:
                raise ConfigError(f"{path}: drives[{index}]: world {world} and drives[{other[1]}]'s {other[0]} would "
                                  f"both be simulated into {sim_root / Path(world).stem}; rename one of the files")
        if entry.name is not None and len(sources) != 1:
            raise ConfigError(f"{path}: drives[{index}]: 'name' names one drive, but the entry matches {len(sources)}")
        for default_name, source, world in sources:
            name = entry.name or default_name
            if not name or "/" in name or name.startswith("."):
                raise ConfigError(f"{path}: drives[{index}]: {name!r} cannot be a run folder name; give another 'name'")
            if name in BATCH_ENTRIES:
                raise ConfigError(f"{path}: drives[{index}]: {name!r} cannot be a run folder name: the batch writes its "
                                  f"own {name} in {out}; give another 'name'")
            if name in seen:
                raise ConfigError(f"{path}: drives[{index}]: a second drive named {name!r} (drives[{seen[name]}]); "
                                  "give each a different 'name'")
            seen[name] = index
            preset = DATASETS[source.kind].preset
            drive_base = entry.config or base or preset
            try:
                cfg = load_config(drive_base, common + list(entry.set))
            except ConfigError as exc:
                raise ConfigError(f"{path}: drives[{index}] ({name}): {exc}") from None
            drives.append(DriveTask(name, source, cfg.model_dump(mode="json"), methods, str(out / name), cache_dir,
                                    world))
    check_batch_folder(folder, what, seen)
    presets = {DATASETS[d.spec.kind].preset for d in drives}
    try:   # the merged map: the batch-level config (or the drives' common preset)
        merge_config = load_config(base or (presets.pop() if len(presets) == 1 else None), common)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    if spec.scan_tasks:
        drives = [replace(d, scan_tasks=True) for d in drives]
    return BatchPlan(path.absolute(), out, drives, methods, merge_config.model_dump(mode="json"), spec.merge,
                     scheduler or spec.scheduler, spec.workers, cache_dir,
                     "--scheduler" if scheduler else f"{path}: scheduler:")


# --- the tasks (they run on the workers) --------------------------------------------------------------------

class EventReporter(RecordingReporter):
    """A worker-side reporter: records everything, and sends progress and warnings to the client as Dask
    events on ``topic`` (``{"drive", "kind": "advance"|"warning"|"info", ...}``)."""

    def __init__(self, topic: str | None, drive: str):
        super().__init__()
        self.topic, self.drive = topic, drive

    def _send(self, **message) -> None:
        if self.topic is None:
            return
        try:
            from distributed import get_worker

            get_worker().log_event(self.topic, {"drive": self.drive, **message})
        except (ImportError, ValueError):        # not on a Dask worker (e.g. a task run in-process)
            pass

    def progress(self, description: str, total: int | None):
        import contextlib

        counted = description.startswith("extracting")

        @contextlib.contextmanager
        def context():
            yield (lambda n=1: self._send(kind="advance", n=int(n))) if counted else (lambda n=1: None)

        return context()

    def info(self, text: str) -> None:
        super().info(text)
        if text.startswith("first run: simulating"):
            self._send(kind="info", text=text)

    def warning(self, text: str) -> None:
        super().warning(text)
        self._send(kind="warning", text=text)


_TASK = threading.local()
"""The reporter of the drive task running on this worker thread (``_TASK.reporter``), if any."""
_SHOWN_BEFORE = [warnings.showwarning]
"""The ``warnings.showwarning`` that :func:`_route_warning` replaced: it shows what no task raised."""
_INSTALL = threading.Lock()


def _route_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """``warnings.showwarning`` on a worker: a warning raised while a drive task runs goes to that task's
    reporter (to the client, one line, prefixed with the drive), featmap's as its message and others with
    their category; outside a task, to the hook it replaced."""
    reporter = getattr(_TASK, "reporter", None)
    if reporter is None:
        _SHOWN_BEFORE[0](message, category, filename, lineno, file, line)
    else:
        reporter.warning(str(message) if category.__module__.startswith("featmap") else f"{category.__name__}: {message}")


@contextlib.contextmanager
def _warnings_to(reporter: "EventReporter"):
    """While the block runs on this thread, the warnings it raises go to ``reporter`` instead of the worker's
    stderr (where a Dask worker prints them in Python's two-line format). The hook is installed once per
    process and looks the reporter up per thread, so tasks on threads of one worker keep theirs apart; but
    Python's warnings state is process-wide, so a ``warnings.catch_warnings`` block running on another
    thread meanwhile takes what is raised in it (exact on workers of one thread, as featmap's LocalCluster
    starts them)."""
    with _INSTALL:
        if warnings.showwarning is not _route_warning:
            _SHOWN_BEFORE[0] = warnings.showwarning
            warnings.showwarning = _route_warning
    previous = getattr(_TASK, "reporter", None)
    _TASK.reporter = reporter
    try:
        yield
    finally:
        _TASK.reporter = previous


@dataclass(frozen=True)
class SimOutcome:
    world: str
    seconds: float
    error: Optional[str] = None


def simulate_task(world: str, sim_root: str, topic: str | None = None) -> SimOutcome:
    """Dask task: simulate a world's drive into ``sim_root`` unless it is there (one task per world, so two
    drives of one world never simulate it at once)."""
    from featmap.datasets.simulated import ensure_simulated_drive

    start = time.perf_counter()
    try:
        ensure_simulated_drive(world, sim_root, EventReporter(topic, Path(world).stem))
    except Exception as exc:            # reported in the summary of every drive that needs this world
        return SimOutcome(world, time.perf_counter() - start, _one_line(exc))
    return SimOutcome(world, time.perf_counter() - start)


@dataclass(frozen=True)
class DriveOutcome:
    """What a drive task reports back (its record for the summary, and what its reporter collected)."""

    record: DriveRecord
    warnings: list[str] = field(default_factory=list)
    detail: Optional[str] = None


def _one_line(exc: BaseException) -> str:
    if isinstance(exc, FeatmapError):
        return str(exc)
    if isinstance(exc, OSError):
        return f"{exc.filename + ': ' if exc.filename else ''}{exc.strerror or exc}"
    return f"{type(exc).__name__}: {exc}"


def fingerprint(location: str | Path) -> dict:
    """A cheap fingerprint of a source's data: number, total size and a hash of the names, sizes and
    modification times of its files (a re-simulated, re-downloaded or edited drive gets a new one)."""
    location = Path(location)
    entries = []
    if location.is_dir():
        for root, dirs, files in os.walk(location):
            dirs.sort()
            for name in sorted(files):
                p = Path(root) / name
                st = p.stat()
                entries.append((str(p.relative_to(location)), st.st_size, st.st_mtime_ns))
    elif location.exists():
        st = location.stat()
        entries.append((location.name, st.st_size, st.st_mtime_ns))
    h = hashlib.blake2b(json.dumps(entries).encode(), digest_size=16).hexdigest()
    return {"files": len(entries), "bytes": int(sum(e[1] for e in entries)), "hash": h}


MERGE_ONLY = (("refinement", "drives"),)
"""Config sections only the merge reads: they are not part of a drive's content key."""


def drive_key(task: DriveTask, location: str) -> DriveKey:
    """The content key of a drive's run: source identity (+ data fingerprint), resolved config (without
    the sections only the merge reads, :data:`MERGE_ONLY`), methods, version."""
    source = {"kind": task.spec.kind, "location": str(location), "frames": task.spec.frames,
              "skip_bad_scans": task.spec.skip_bad_scans, "data": fingerprint(location)}
    config = json.loads(json.dumps(task.config))
    for section, key in MERGE_ONLY:
        config.get(section, {}).pop(key, None)
    text = json.dumps({"source": source, "config": config, "methods": list(task.methods),
                       "featmap": __version__}, sort_keys=True)
    return DriveKey(key=hashlib.blake2b(text.encode(), digest_size=20).hexdigest(), featmap_version=__version__,
                    source=source, methods=list(task.methods))


def _is_up_to_date(out: Path, key: DriveKey) -> bool:
    """The run folder ``out`` was made with ``key`` and holds every file the merge reads from it (a folder
    missing one, e.g. half deleted or copied, is run again)."""
    if not (out / KEY_FILE).is_file() or not (out / "metrics.json").is_file():
        return False
    try:
        if read_drive_key(out / KEY_FILE).key != key.key:
            return False
        return all((out / name).is_file() for name in merge_reads(out, key.methods))
    except FeatmapError:
        return False


def _record_from_run(task: DriveTask, status: str, location: str, seconds: float, worker: str | None,
                     cpu_seconds: float = 0.0) -> DriveRecord:
    from featmap.io.run_metrics import read_run_metrics

    m = read_run_metrics(Path(task.out) / "metrics.json")
    return DriveRecord(name=task.name, status=status, run_dir=task.out, kind=task.spec.kind, location=location,
                       scans=m.scans.processed, segments=m.segments,
                       counts={k: r.count for k, r in m.methods.items()},
                       scores={k: {s: v for s, v in m.primary_scores(k).items() if not isinstance(v, dict)}
                               for k in m.methods},
                       primary=m.primary, seconds=round(seconds, 3), cpu_seconds=round(cpu_seconds, 3), worker=worker)


def run_drive_task(task: DriveTask, sim: SimOutcome | None = None) -> DriveOutcome:
    """Dask task: run one drive exactly as ``featmap run`` would, unless its run folder is up to date.

    Never raises for a failing drive: the outcome says ``failed`` with a one-line error (and the traceback
    of an unexpected exception in ``detail``).
    """
    from featmap.datasets import open_source
    from featmap.pipeline import MappingPipeline, SegmentStore
    from featmap.pipeline.config import config_from_dict
    from featmap.pipeline.executor import DaskExecutor, SerialExecutor

    start, cpu_start = time.perf_counter(), time.process_time()
    reporter = EventReporter(task.topic, task.name)
    worker = _worker_address()
    location = task.spec.location

    def failed(message: str, detail: str | None = None) -> DriveOutcome:
        return DriveOutcome(DriveRecord(name=task.name, status="failed", run_dir=task.out, kind=task.spec.kind,
                                        location=str(location), error=message,
                                        seconds=round(time.perf_counter() - start, 3), worker=worker),
                            reporter.warnings, detail)

    if sim is not None and sim.error is not None:
        return failed(f"simulating {sim.world}: {sim.error}")
    with _warnings_to(reporter):       # (a worker would print them in Python's own format)
        try:
            config = config_from_dict(task.config, f"{task.name} config")
            source = open_source(task.spec, reporter)
            location = str(source.location)
            key = drive_key(task, location)
            out = Path(task.out)
            if _is_up_to_date(out, key):
                record = _record_from_run(task, "skipped", location, 0.0, worker)
                reporter._send(kind="advance", n=record.scans)
                return DriveOutcome(record, reporter.warnings)
            pipeline_args = (config, list(task.methods), SegmentStore(task.cache_dir))
            if task.scan_tasks:
                from distributed import worker_client

                with worker_client() as client:
                    MappingPipeline(*pipeline_args, DaskExecutor(client), reporter, task.spec.skip_bad_scans).run(source, out)
            else:
                MappingPipeline(*pipeline_args, SerialExecutor(), reporter, task.spec.skip_bad_scans).run(source, out)
            write_drive_key(out / KEY_FILE, key)
            record = _record_from_run(task, "done", location, time.perf_counter() - start, worker,
                                      time.process_time() - cpu_start)
            return DriveOutcome(record, reporter.warnings)
        except Exception as exc:
            detail = None if isinstance(exc, (FeatmapError, OSError)) else traceback.format_exc()
            return failed(_one_line(exc), detail)


def _worker_address() -> str | None:
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):
        return None


# --- the merged map --------------------------------------------------------------------------------------

@dataclass(frozen=True)
class MergedInputs:
    """Every drive's segments in one local frame.

    Attributes:
        table: segments (N, 4) in the merged frame, scan ids made unique (drive offset + frame), column
            ``drive`` (index into ``drives``).
        drives: the drives in it, with their scan offsets, frames and truth.
        names: drive names, in order.
        frame: the merged frame's geo origin (the first drive's), or None (drives of one indoor log).
        left_out: drive -> why it is not in the merged map.
        trajectories: drive -> (F, 2) sensor positions in the merged frame.
        alignment: the drives' rigid alignment (already applied to ``table`` and ``trajectories``), or None.
    """

    table: Any
    drives: list[MergedDrive]
    names: list[str]
    frame: Any
    left_out: dict[str, str]
    trajectories: dict[str, np.ndarray]
    alignment: Any = None

    def drive_map(self, index: int, method: str) -> np.ndarray:
        """(K, 4) drive ``index``'s own fused map (``fused_<method>.csv``) in the merged frame, aligned as
        its segments are."""
        from featmap.geo import reproject_segments
        from featmap.io.segments_csv import read_fused_csv

        d = self.drives[index]
        fused, _ = read_fused_csv(Path(d.run_dir) / f"fused_{method}.csv")
        if d.geo_frame is not None and self.frame is not None:
            fused = reproject_segments(fused, d.geo_frame.frame(), self.frame)
        if self.alignment is not None:
            fused = self.alignment.segments(fused, np.full(len(fused), index))
        return fused


def merge_reads(run_dir: str | Path, methods) -> list[str]:
    """The files of a drive's run folder the merge reads (:func:`merged_inputs`, :meth:`MergedInputs.drive_map`
    and, for the map metric, :func:`drive_points`): ``batch.json``, ``metrics.json``, ``config.yaml``,
    ``segments.csv``, ``trajectory.csv``, ``fused_<method>.csv`` of each method, and ``pose_corrections.csv``
    when the run refined its poses (its metrics.json says so).

    Raises:
        FeatmapError: the run's metrics.json is unreadable.
    """
    from featmap.io.run_metrics import read_run_metrics

    refinement = read_run_metrics(Path(run_dir) / "metrics.json").refinement
    return [KEY_FILE, "metrics.json", "config.yaml", "segments.csv", "trajectory.csv",
            *(f"fused_{m}.csv" for m in methods),
            *(["pose_corrections.csv"] if refinement is not None and refinement.method != "none" else [])]


def merged_inputs(run_dirs: list[tuple[str, str | Path]], align=None) -> MergedInputs:
    """Read the drives' run folders and put their segments into the first drive's local frame.

    Drives with a geo origin are moved through WGS84 into the first one's frame. Drives without one
    (indoor logs) can only be merged with drives of the same source location (one log, several frame
    ranges): they share its frame. Others are left out (listed in ``left_out``). With ``align`` (a
    ``refinement.drives`` section that is enabled) and several drives, each drive is then moved as a
    whole so that the drives' own maps agree (:func:`featmap.refinement.drives.align_drives` on each
    drive's ``fused_<method>.csv``, the proposed method's when the drives ran it).
    """
    from featmap.fusion.visibility import sensor_xy_column
    from featmap.geo import reproject, reproject_segments
    from featmap.io.pose_csv import read_trajectory_xy
    from featmap.io.run_metrics import GeoRecord, read_run_metrics
    from featmap.io.segments_csv import SegmentTable, read_segments_csv

    runs = []
    for name, run_dir in run_dirs:
        run_dir = Path(run_dir)
        metrics = read_run_metrics(run_dir / "metrics.json")
        runs.append((name, run_dir, metrics))
    left_out: dict[str, str] = {}
    with_geo = [r for r in runs if r[2].geo_frame is not None]
    if with_geo:
        frame = with_geo[0][2].geo_frame.frame()
        for name, _, m in runs:
            if m.geo_frame is None:
                left_out[name] = "no geo origin (an indoor log) to place it among drives that have one"
        runs = with_geo
    else:
        frame = None
        first_location = runs[0][2].source.location if runs else None
        for name, _, m in runs:
            if m.source.location != first_location:
                left_out[name] = (f"no geo origin, and another source than {runs[0][0]}: the two local frames "
                                  "cannot be related")
        runs = [r for r in runs if r[0] not in left_out]
    segs, scans, drive_col, drives, trajectories = [], [], [], [], {}
    carried: dict[str, list] = {"rms": [], "max_gap": [], "sensor_x": [], "sensor_y": []}  # the columns the fusion reads
    offset = 0
    for index, (name, run_dir, m) in enumerate(runs):
        table = read_segments_csv(run_dir / "segments.csv")
        src = m.geo_frame.frame() if m.geo_frame is not None else None
        moved = reproject_segments(table.segments, src, frame) if frame is not None else table.segments
        segs.append(moved)
        scans.append(table.scan + offset)
        drive_col.append(np.full(len(table), index, np.int64))
        sensor = sensor_xy_column(table.extra, len(table))
        if sensor is not None and frame is not None:                   # where the scans were taken, moved too
            sensor = reproject(sensor, src, frame)
        columns = {**table.extra, **({} if sensor is None else {"sensor_x": sensor[:, 0], "sensor_y": sensor[:, 1]})}
        for column, parts in carried.items():
            parts.append(columns.get(column))
        truth = m.reference_path("truth", run_dir)
        drives.append(MergedDrive(name=name, run_dir=str(run_dir), scan_offset=offset, segments=len(table),
                                  geo_frame=GeoRecord(**src.to_dict()) if src is not None else None,
                                  truth=str(truth) if truth is not None and truth.exists() else None,
                                  frames_processed=m.source.frames_processed))
        traj_path = run_dir / "trajectory.csv"
        if traj_path.exists():
            xy = read_trajectory_xy(traj_path)
            trajectories[name] = reproject(xy, src, frame) if frame is not None else xy
        top = max([int(table.scan.max()) if len(table) else -1, *m.source.frames_processed, -1])
        offset += top + 1
    if segs:
        extra = {"drive": np.concatenate(drive_col).astype(float)}
        for column, parts in carried.items():
            if all(p is not None for p in parts):                # used only when every drive has it
                extra[column] = np.concatenate(parts).astype(float)
        table = SegmentTable(scan=np.concatenate(scans).astype(np.int64), segments=np.concatenate(segs).reshape(-1, 4),
                             extra=extra)
    else:
        table = SegmentTable(scan=np.zeros(0, np.int64), segments=np.zeros((0, 4)), extra={"drive": np.zeros(0)})
    inputs = MergedInputs(table, drives, [d.name for d in drives], frame, left_out, trajectories)
    if align is None or not align.enabled or len(drives) < 2:
        return inputs
    from featmap.refinement.drives import align_drives

    methods = [list(m.methods) for _, _, m in runs]
    method = "proposed" if all("proposed" in ms for ms in methods) else next(
        (k for k in methods[0] if all(k in ms for ms in methods)), None)
    if method is None:                                  # no fused map all drives have
        return inputs
    alignment = align_drives([inputs.drive_map(k, method) for k in range(len(drives))], align)
    if not alignment.applied:
        return replace(inputs, alignment=alignment)
    drive_index = table.extra["drive"].astype(np.int64)
    moved = replace(table, segments=alignment.segments(table.segments, drive_index))
    sensor = sensor_xy_column(table.extra, len(table))
    if sensor is not None:
        for k in range(len(drives)):
            sensor[drive_index == k] = alignment.points(sensor[drive_index == k], k)
        moved = replace(moved, extra={**moved.extra, "sensor_x": sensor[:, 0], "sensor_y": sensor[:, 1]})
    positions = {d.name: k for k, d in enumerate(drives)}
    paths = {name: alignment.points(xy, positions[name]) for name, xy in trajectories.items()}
    drives = [d.model_copy(update={"correction": [round(float(v), 4) for v in alignment.corrections[k, :2]]
                                                 + [round(float(np.rad2deg(alignment.corrections[k, 2])), 5)]})
              for k, d in enumerate(drives)]
    return MergedInputs(moved, drives, inputs.names, frame, left_out, paths, alignment)


def merged_reference(inputs: MergedInputs, evaluation=None, cache_dir: str | Path | None = None):
    """(evaluator, Reference) the merged map is scored against, or None.

    The drives' simulator truths united in the merged frame when every drive has one; otherwise, with the
    ``evaluation:`` section given, what a run of its own would be scored against: building footprints
    (``evaluation.footprints``, when the merged frame has a geo origin), else the truth-free map metric.
    The footprints come with what the drives observed of them (:func:`merged_footprints`: their runs'
    records, or their scan points read again from the segment cache in ``cache_dir``); every drive's scan
    points (``merged_points``) are also the map metric's reference. Without ``cache_dir``, footprints of a
    drive that kept no record count every wall as observable, and there is no map metric.

    Raises:
        FeatmapError: a drive's scans cannot be read again (moved, changed).
    """
    from featmap.evaluation import EvaluationContext, Reference
    from featmap.evaluation.plugins import Footprints, SimulatorTruth
    from featmap.evaluation.references import load_simulator_truth, merge_truths
    from featmap.pipeline.run import primary_reference

    if not inputs.drives:
        return None
    if all(d.truth is not None for d in inputs.drives):
        truths = [load_simulator_truth(d.truth, inputs.frame, d.frames_processed) for d in inputs.drives]
        return SimulatorTruth(), Reference(merge_truths(truths), ";".join(d.truth for d in inputs.drives))
    if evaluation is None:
        return None
    if evaluation.footprints is not None and inputs.frame is not None:
        footprints = Path(evaluation.footprints).expanduser().resolve()
        united = merged_footprints(inputs, footprints, cache_dir)
        if united is not None:
            return Footprints(), Reference(united, str(footprints))
    context = EvaluationContext(None, None, inputs.frame, evaluation)
    found = None if cache_dir is None else merged_points(inputs, cache_dir)
    if found is not None:           # the map metric's reference
        context = replace(context, points=found[0], point_scans=found[1], raw_segments=inputs.table.segments)
    return primary_reference(context)


def merged_footprints(inputs: MergedInputs, footprints: Path, cache_dir: str | Path | None = None):
    """The footprints as the merged map's drives observed them, in the merged frame, or None when that
    cannot be known (a drive to read again without ``cache_dir``, or whose extractor gives no points).

    Each drive contributes the record its run kept (``footprint_walls.csv``) when its run was scored
    against these footprints and the drive was not moved by the alignment; otherwise its scan points,
    read again and placed as its segments are (``merged_drive_points``), observe the footprints anew. The
    drives' observations are united as their simulator truths are (:func:`merge_truths`).

    Raises:
        FeatmapError: a drive's record is unreadable or not of these footprints, or its scans cannot be read
            again.
    """
    from featmap.evaluation.references import footprints_truth, merge_truths, observed_footprints, truth_from_footprints
    from featmap.io.run_metrics import read_run_metrics
    from featmap.io.sim_truth import FOOTPRINT_WALLS_FILE

    truths, whole = [], truth_from_footprints(footprints, inputs.frame)      # (read once for every drive)
    for k, d in enumerate(inputs.drives):
        run_dir = Path(d.run_dir)
        own = read_run_metrics(run_dir / "metrics.json").scored_against("footprints", footprints, run_dir)
        moved = inputs.alignment is not None and bool(inputs.alignment.corrections[k].any())
        if own and (run_dir / FOOTPRINT_WALLS_FILE).is_file() and not moved:
            truths.append(footprints_truth(footprints, inputs.frame, run_dir,
                                           d.geo_frame.frame() if d.geo_frame is not None else None, whole))
            continue
        found = None if cache_dir is None else merged_drive_points(inputs, k, cache_dir)
        if found is None:
            return None
        truths.append(observed_footprints(whole, *found))
    return merge_truths(truths)


def drive_points(run_dir: str | Path, cache_dir: str | Path) -> tuple[np.ndarray, np.ndarray] | None:
    """(points (P, 2), their frame numbers (P,)): the scan points of a batch drive (its extractor's structure
    points) in its run's local frame, placed with the poses the run fused with (the source's, moved by
    ``pose_corrections.csv``), or None when its extractor gives none. The scans are read again and their
    segments taken from the segment cache (extracted again where the cache lacks them).

    Raises:
        FeatmapError: the drive's ``batch.json``, config or pose corrections are unreadable, or its
            source can no longer be opened as it was.
    """
    from featmap.datasets import open_source
    from featmap.io.pose_csv import read_corrections_csv
    from featmap.io.run_metrics import read_run_metrics
    from featmap.pipeline import SegmentStore
    from featmap.pipeline.extract import extract_source
    from featmap.refinement.base import apply_corrections

    run_dir = Path(run_dir)
    source = read_drive_key(run_dir / KEY_FILE).source
    if not isinstance(source.get("kind"), str) or not isinstance(source.get("location"), str):
        raise InputFileError(run_dir / KEY_FILE, "its source has no kind or location (run the batch again to rewrite it)")
    # The key holds where the scans were read (a simulated drive: the KITTI raw drive it was written as).
    kind = "kitti_raw" if source["kind"] == "simulated" else source["kind"]
    spec = SourceSpec(kind, source["location"], source.get("frames"), bool(source.get("skip_bad_scans")))
    extraction = extract_source(open_source(spec), load_config(run_dir / "config.yaml").extraction,
                                SegmentStore(cache_dir), skip_bad_scans=spec.skip_bad_scans)
    poses = extraction.poses
    corrections_path = run_dir / "pose_corrections.csv"
    refinement = read_run_metrics(run_dir / "metrics.json").refinement
    if refinement is not None and refinement.method != "none":       # the run wrote its corrections
        frames, corrections = read_corrections_csv(corrections_path)
        if list(frames) != list(extraction.frames):
            raise InputFileError(corrections_path, f"its frames are not the {len(extraction.frames)} frames of "
                                 f"{spec.location} the run used (the source changed since?)")
        poses = apply_corrections(poses, corrections)
    points = extraction.world_points(poses)
    return None if points is None else (points, extraction.world_point_scans())


def merged_drive_points(inputs: MergedInputs, k: int, cache_dir: str | Path) -> tuple[np.ndarray, np.ndarray] | None:
    """(points (P, 2), merged scan ids (P,)): drive ``k``'s scan points (``drive_points``) in the merged
    frame, aligned as its segments are, with the scan ids of the merged segments (its ``scan_offset`` +
    frame), or None when its extractor gives none."""
    from featmap.geo import reproject

    d = inputs.drives[k]
    found = drive_points(d.run_dir, cache_dir)
    if found is None:
        return None
    points, frames = found
    if inputs.frame is not None and d.geo_frame is not None:
        points = reproject(points, d.geo_frame.frame(), inputs.frame)
    if inputs.alignment is not None:
        points = inputs.alignment.points(points, k)
    return points, d.scan_offset + frames


def merged_points(inputs: MergedInputs, cache_dir: str | Path) -> tuple[np.ndarray, np.ndarray] | None:
    """(points (P, 2), merged scan ids (P,)): every drive's scan points (:func:`merged_drive_points`), or
    None when a drive has none."""
    parts = [merged_drive_points(inputs, k, cache_dir) for k in range(len(inputs.drives))]
    if not parts or any(p is None for p in parts):
        return None
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


def drive_provenance(labels: np.ndarray, drive: np.ndarray, n_features: int) -> list[list[int]]:
    """For each fused feature, the sorted drive indices among its member segments (labels (N,), drive (N,))."""
    keep = labels >= 0
    pairs = np.unique(np.stack([labels[keep], drive[keep]]), axis=1) if keep.any() else np.zeros((2, 0), np.int64)
    out: list[list[int]] = [[] for _ in range(n_features)]
    for feature, d in pairs.T:
        out[int(feature)].append(int(d))
    return out


def merge_task(run_dirs: list[tuple[str, str]], out: str, methods: tuple[str, ...], config: dict,
               cache_dir: str | None = None) -> MergedRecord:
    """Dask task (or a plain call): fuse the drives' segments together into ``out`` (a run folder) and
    score it (``merged_reference``; the map metric reads the drives' scans again, their segments from
    the segment cache ``cache_dir``).

    Writes ``segments.csv`` (merged frame, unique scan ids, ``drive`` column), ``fused_<method>.csv``
    (with ``n_drives`` and ``drives``: who saw each feature), ``fused_<method>.geojson`` (the same as
    properties), ``map.kml`` and ``map.html`` (a layer per method and per drive's trajectory),
    ``config.yaml`` and ``merged.json`` (frame, drives, counts, scores and what they are against).
    """
    from featmap.evaluation.references import observation_record
    from featmap.io.atomic import atomic_write_text
    from featmap.io.run_metrics import GeoRecord
    from featmap.io.segments_csv import write_fused_csv, write_segments_csv
    from featmap.io.sim_truth import FOOTPRINT_WALLS_FILE, write_walls_csv
    from featmap.pipeline.config import config_from_dict
    from featmap.pipeline.fuse import fuse_methods
    from featmap.pipeline.run_folder import RunFolder

    start = time.perf_counter()
    cfg = config_from_dict(config, "batch config")
    inputs = merged_inputs(run_dirs, cfg.refinement.drives)
    table = inputs.table
    runs = fuse_methods(table, list(methods), cfg.fusion)
    unscored = None
    try:
        reference = merged_reference(inputs, cfg.evaluation, cache_dir)
    except FeatmapError as exc:                  # the map is still written, without scores
        reference, unscored = None, f"not scored: {_one_line(exc)}"
    drive_index = table.extra["drive"].astype(np.int64)
    scores, drive_scores, counts, multi = {}, {}, {}, {}
    provenance = {}
    for run in runs:
        r = run.result
        provenance[run.name] = drive_provenance(r.labels, drive_index, len(r))
        counts[run.name] = len(r)
        multi[run.name] = sum(len(p) > 1 for p in provenance[run.name])
        if reference is not None:
            evaluator, ref = reference
            scores[run.name] = evaluator.score(ref, r.segments)
            drive_scores[run.name] = {}
            for k, d in enumerate(inputs.drives):
                drive_scores[run.name][d.name] = evaluator.score(ref, inputs.drive_map(k, run.name))
    with RunFolder(out, marker="merged.json") as folder:
        write_segments_csv(folder.tmp / "segments.csv", table)
        for run in runs:
            names = [";".join(inputs.names[i] for i in p) for p in provenance[run.name]]
            write_fused_csv(folder.tmp / f"fused_{run.name}.csv", run.result.segments, run.result.support,
                            {"n_drives": [len(p) for p in provenance[run.name]], "drives": names})
        if inputs.frame is not None:
            _write_merged_maps(folder.tmp, inputs, runs, provenance, cfg)
        atomic_write_text(folder.tmp / "config.yaml", cfg.to_yaml())
        record = MergedRecord(featmap_version=__version__,
                              geo_frame=GeoRecord(**inputs.frame.to_dict()) if inputs.frame is not None else None,
                              drives=inputs.drives, left_out=inputs.left_out, segments=len(table), counts=counts,
                              multi_drive=multi, reference=reference[1].path if reference is not None else None,
                              evaluator=reference[0].name if reference is not None else None, unscored=unscored,
                              alignment=inputs.alignment.stats if inputs.alignment is not None else None,
                              scores=_plain(scores), drive_scores=_plain(drive_scores),
                              seconds=round(time.perf_counter() - start, 3))
        write_merged_record(folder.tmp / "merged.json", record)
        if reference is not None and reference[0].name == "footprints":
            write_walls_csv(folder.tmp / FOOTPRINT_WALLS_FILE, observation_record(reference[1].data, reference[1].path))
        folder.commit()
    return record


@dataclass(frozen=True)
class MergeOutcome:
    """What the merge task reports back: the merged map's record, or why there is none.

    Attributes:
        record: the merged map's record (None: the merge failed).
        error: the failure in one line.
        known: the failure is a FeatmapError or OSError (the user's to fix, e.g. a file in the way), not a bug.
        detail: the traceback of an unexpected exception.
    """

    record: Optional[MergedRecord] = None
    error: Optional[str] = None
    known: bool = False
    detail: Optional[str] = None


def merge_outcome_task(run_dirs: list[tuple[str, str]], out: str, methods: tuple[str, ...], config: dict,
                       cache_dir: str | None = None) -> MergeOutcome:
    """Dask task: :func:`merge_task`, never raising (as a drive task): an exception is returned as one line
    (and a traceback in ``detail`` when it is not a FeatmapError or OSError), so no worker logs it."""
    try:
        return MergeOutcome(merge_task(run_dirs, out, methods, config, cache_dir))
    except Exception as exc:
        known = isinstance(exc, (FeatmapError, OSError))
        return MergeOutcome(error=_one_line(exc), known=known, detail=None if known else traceback.format_exc())


class MergeError(FeatmapError):
    """The merged map could not be written for a reason the user can fix (the drives' run folders and the
    summary are written); ``result`` is the batch's result."""

    def __init__(self, message: str, result: "BatchResult"):
        super().__init__(message)
        self.result = result


def _plain(scores: dict) -> dict:
    """Nested score dicts with only numbers (or None) at the leaves (as metrics.json keeps them)."""
    return {k: _plain(v) if isinstance(v, dict) else v for k, v in scores.items()
            if isinstance(v, (dict, int, float)) or v is None}


def _write_merged_maps(folder: Path, inputs: MergedInputs, runs, provenance: dict, cfg) -> None:
    from featmap.io.geojson import write_segments_geojson
    from featmap.io.html_map import write_html_map
    from featmap.io.kml import write_kml
    from featmap.io.layers import MapLayer
    from featmap.plotting.style import SEGMENT_COLOR, method_color

    palette = ["#1f77b4", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf"]
    for run in runs:
        r = run.result
        props = [{"support": int(s), "n_drives": len(p), "drives": [inputs.names[i] for i in p]}
                 for s, p in zip(r.support, provenance[run.name])]
        write_segments_geojson(folder / f"fused_{run.name}.geojson", r.segments, inputs.frame, props,
                               {"method": run.name})
    layers = [MapLayer(run.name, run.result.segments, run.result.support, method_color(run.name), width=3)
              for run in runs]
    for run in runs:
        several = np.array([len(p) > 1 for p in provenance[run.name]], bool)
        layers.append(MapLayer(f"{run.name}: seen by several drives", run.result.segments[several],
                               run.result.support[several], method_color(run.name), width=5, show=False))
    for k, (name, xy) in enumerate(inputs.trajectories.items()):
        if len(xy) > 1:
            layers.append(MapLayer(f"trajectory {name}", np.column_stack([xy[:-1], xy[1:]]), None,
                                   palette[k % len(palette)], width=2))
    if cfg.output.kml:
        write_kml(folder / "map.kml", layers, inputs.frame)
    if cfg.output.html:
        segments = MapLayer("segments", inputs.table.segments, None, SEGMENT_COLOR, show=False)
        write_html_map(folder / "map.html", [segments, *layers], inputs.frame)


# --- running a batch on a Dask client ------------------------------------------------------------------------

@dataclass
class BatchResult:
    summary: BatchSummary
    outcomes: list[DriveOutcome]
    merged: Optional[MergedRecord]

    @property
    def failed(self) -> list[DriveRecord]:
        return [d for d in self.summary.drives if d.status == "failed"]


WORKER_ENVIRON_UNSET = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}
"""Dask's nannies start workers with ``MALLOC_TRIM_THRESHOLD_=65536``, which also turns off glibc's
adaptive mmap threshold: every array over 128 kB is then mapped and unmapped afresh, and a drive spends
4x the system time in page faults (``featmap run -j 1`` on the default drive: 43 s -> 57 s, system
time 4.4 s -> 18.6 s). featmap's local workers start without it."""


def dask_setup(worker) -> None:
    """Dask's preload hook, run in each worker process of :func:`local_cluster` as it starts: the worker
    ignores Ctrl-C. A terminal sends SIGINT to every process in its foreground group, the workers too; each
    then printed a KeyboardInterrupt traceback of its own under featmap's one-line message, while the batch
    process closes the cluster, and with it its workers, anyway."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def local_cluster(workers: int | None = None):
    """A LocalCluster on 127.0.0.1 (no dashboard; the scheduler's HTTP endpoints on a free port, not Dask's
    8787, which a second cluster would find taken): ``workers`` processes of one thread (default: the cores),
    started without Dask's malloc trim setting (:data:`WORKER_ENVIRON_UNSET`) and ignoring Ctrl-C (the
    preloads of Dask's configuration run first, then :func:`dask_setup`).

    Scripts that call this need the ``if __name__ == "__main__":`` guard (the workers are spawned).
    """
    import dask
    from distributed import LocalCluster

    n = workers or os.cpu_count() or 1
    preload = [*(dask.config.get("distributed.worker.preload", None) or []), __name__]
    with dask.config.set(WORKER_ENVIRON_UNSET), _closed_on_interrupt():
        return LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                            dashboard_address=None, silence_logs=40, preload=preload,
                            scheduler_kwargs={"dashboard_address": "127.0.0.1:0"})


def _default_client():
    from distributed import default_client

    try:
        return default_client()
    except ValueError:
        return None


@contextlib.contextmanager
def _closed_on_interrupt():
    """Ctrl-C (KeyboardInterrupt) inside the block: close every Dask cluster and the default client started in
    it, then re-raise. A LocalCluster interrupted while it starts is otherwise left half-started, and Dask's
    exit hook fails closing it (an ``AssertionError: Status.init`` traceback after featmap's own message)."""
    from distributed.deploy.spec import SpecCluster

    clusters = set(SpecCluster._instances)
    client = _default_client()
    try:
        yield
    except KeyboardInterrupt:
        started = _default_client()
        if started is not None and started is not client:
            with contextlib.suppress(Exception, asyncio.CancelledError):
                started.close(timeout=5)
        for cluster in set(SpecCluster._instances) - clusters:
            _abort_cluster(cluster)
        raise


def _abort_cluster(cluster) -> None:
    """Close a cluster whose start was interrupted: wait for the workers still starting (their start is not
    cancelled with the cluster's), close every worker it made, then the cluster (its scheduler), and take it
    off the list Dask's exit hook closes."""
    from distributed.core import Status
    from distributed.deploy.spec import SpecCluster

    def retrieve(task) -> None:                        # a worker's start that failed (its process got the
        if not task.cancelled():                        # Ctrl-C too): no "exception never retrieved" log
            task.exception()

    async def settle() -> None:
        for task in asyncio.all_tasks():                # the cluster's loop: the workers' starts under way
            coro = task.get_coro()
            if task is not asyncio.current_task() and getattr(coro, "__name__", "") == "_wrap_awaitable":
                task.add_done_callback(retrieve)
        for worker in list(getattr(cluster, "_created", ())):
            lock = getattr(worker, "_startup_lock", None)
            if lock is not None:
                async with lock:                        # its start, if one is under way, ends
                    pass
            if worker.status not in (Status.closing, Status.closed, Status.failed):
                await worker.close()
        waiting = getattr(cluster, "_correct_state_waiting", None)
        if waiting is not None and waiting.done():      # the interrupted start of the workers
            cluster._correct_state_waiting = None
        if cluster.status == Status.starting:           # interrupted while the scheduler started
            cluster.status = Status.failed              # (so close() closes the scheduler too)

    try:
        with contextlib.suppress(Exception, asyncio.CancelledError):
            cluster.sync(settle, callback_timeout=30)
        with contextlib.suppress(Exception, asyncio.CancelledError):
            cluster.close(timeout=30)
    finally:
        SpecCluster._instances.discard(cluster)
        with contextlib.suppress(Exception):
            cluster._loop_runner.stop()


def run_batch(plan: BatchPlan, client, reporter: Reporter = NullReporter()) -> BatchResult:
    """Run every drive of ``plan`` as a task on ``client``, then the merge; write ``OUT/summary.json``.

    Progress: one bar of scans extracted (or found up to date) across drives; a line per finished drive;
    workers' warnings prefixed with their drive.

    Raises:
        MergeError: the merge failed with a FeatmapError or OSError (e.g. a file in the way in ``OUT/merged``),
            after the summary is written and reported (another failure of the merge is a warning, its
            traceback in ``OUT/errors.txt``).
    """
    from distributed import as_completed

    from featmap.io.atomic import atomic_write_text

    start = time.perf_counter()
    topic = f"featmap-batch-{uuid.uuid4().hex[:12]}"
    plan.out.mkdir(parents=True, exist_ok=True)
    tasks = [replace(d, topic=topic) for d in plan.drives]
    outcomes: dict[str, DriveOutcome] = {}
    sim_seconds: dict[str, float] = {}
    with reporter.progress(f"batch of {len(tasks)} drives: scans", None) as advance:
        def on_event(event) -> None:
            message = event[1] if isinstance(event, tuple) else event
            kind = message.get("kind")
            if kind == "advance":
                advance(message.get("n", 1))
            elif kind == "warning":
                reporter.warning(f"{message.get('drive')}: {message.get('text')}")
            elif kind == "info":
                reporter.info(f"{message.get('drive')}: {message.get('text')}")

        client.subscribe_topic(topic, on_event)
        try:
            sims = {}
            for task in tasks:
                if task.world is not None and task.world not in sims:
                    sim_root = dict(task.spec.options)["sim_root"]
                    sims[task.world] = client.submit(simulate_task, task.world, sim_root, topic, pure=False,
                                                     key=f"simulate-{Path(task.world).stem}-{uuid.uuid4().hex[:6]}")
            futures = {client.submit(run_drive_task, task, sims.get(task.world), pure=False,
                                     key=f"drive-{task.name}-{uuid.uuid4().hex[:6]}"): task for task in tasks}
            for future in as_completed(futures):
                task = futures[future]
                try:
                    outcome = future.result()
                except Exception as exc:            # the worker died (KilledWorker), or the task could not run
                    outcome = DriveOutcome(DriveRecord(name=task.name, status="failed", run_dir=task.out,
                                                       kind=task.spec.kind, location=task.spec.location,
                                                       error=_one_line(exc)))
                outcomes[task.name] = outcome
                _report_drive(outcome.record, reporter)
            for world, future in sims.items():
                try:
                    sim_seconds[world] = future.result().seconds
                except Exception:
                    sim_seconds[world] = 0.0
        finally:
            client.unsubscribe_topic(topic)
    ordered = []
    for task in tasks:
        outcome = outcomes[task.name]
        record = outcome.record.model_copy(update={"simulation_seconds": round(sim_seconds.get(task.world, 0.0), 3)
                                                   if task.world else 0.0})
        ordered.append(DriveOutcome(record, outcome.warnings, outcome.detail))
    merged = None
    merge_seconds = None
    merge = MergeOutcome()
    usable = [(o.record.name, o.record.run_dir) for o in ordered if o.record.status != "failed"]
    if plan.merge and usable:
        merge_future = client.submit(merge_outcome_task, usable, str(plan.out / MERGED), plan.methods,
                                     plan.merge_config, plan.cache_dir, pure=False, key=f"merge-{uuid.uuid4().hex[:6]}")
        try:
            merge = merge_future.result()
        except Exception as exc:                # the worker died (KilledWorker), or the task could not run
            merge = MergeOutcome(error=_one_line(exc))
        merged = merge.record
        if merged is not None:
            merge_seconds = merged.seconds
        elif not merge.known:                   # a known error is raised below, after the summary
            reporter.warning(f"merged map: {merge.error}")
    elif plan.merge:
        reporter.warning("merged map: no drive finished, nothing to merge")
    if merged is None and (plan.out / MERGED / "merged.json").exists():
        reporter.warning(f"{plan.out / MERGED} is the merged map of an earlier batch, not of this one")
    records = [o.record for o in ordered]
    chains = [r.simulation_seconds + r.seconds for r in records] or [0.0]
    summary = BatchSummary(
        featmap_version=__version__, batch_file=str(plan.path), scheduler=str(client.scheduler.address),
        workers=int(sum(client.nthreads().values())), drives=records,
        wall_seconds=round(time.perf_counter() - start, 3),
        work_seconds=round(sum(r.seconds for r in records) + sum(sim_seconds.values()) + (merge_seconds or 0.0), 3),
        work_cpu_seconds=round(sum(r.cpu_seconds for r in records), 3),
        critical_path_seconds=round(max(chains) + (merge_seconds or 0.0), 3), merge_seconds=merge_seconds,
        merged=str(plan.out / MERGED) if merged is not None else None)
    write_batch_summary(plan.out / SUMMARY_FILE, summary)
    details = {o.record.name: o.detail for o in ordered if o.detail}
    if merge.detail:
        details[MERGED] = merge.detail            # no drive has this name
    if details:
        atomic_write_text(plan.out / ERRORS_FILE, "".join(f"== {k}\n{v}\n" for k, v in details.items()))
    else:
        (plan.out / ERRORS_FILE).unlink(missing_ok=True)      # an earlier batch's tracebacks are not this one's
    result = BatchResult(summary, ordered, merged)
    report_batch(result, reporter)
    if merge.known:
        failed = len(result.failed)
        raise MergeError(f"merged map: {merge.error} (the drives' run folders and {plan.out / SUMMARY_FILE} are "
                         f"written{f'; {failed} drive(s) failed' if failed else ''})", result)
    return result


def _report_drive(record: DriveRecord, reporter: Reporter) -> None:
    if record.status == "failed":
        reporter.warning(f"{record.name}: failed: {record.error}")
    elif record.status == "skipped":
        reporter.info(f"{record.name}: up to date ({record.run_dir}), skipped")
    else:
        counts = ", ".join(f"{k} {v}" for k, v in record.counts.items())
        reporter.info(f"{record.name}: {record.scans} scans, {record.segments} segments -> {counts} "
                      f"in {record.seconds:.1f} s")


def _fmt(value, nd) -> str:
    return "-" if value is None or isinstance(value, dict) else f"{value:.{nd}f}"


def report_batch(result: BatchResult, reporter: Reporter) -> None:
    """The summary table (a row per drive, a total row) and the merged map's table."""
    s = result.summary
    method = next((m for r in s.drives for m in r.counts), None)
    columns = ["drive", "status", "scans", "segments", f"{method or 'features'}", "precision", "recall", "seconds",
               "note"]
    rows = []
    for r in s.drives:
        sc = r.scores.get(method, {}) if method else {}
        note = r.error if r.status == "failed" else ("up to date" if r.status == "skipped" else (r.worker or ""))
        rows.append([r.name, r.status, str(r.scans), str(r.segments), str(r.counts.get(method, "-")),
                     _fmt(sc.get("precision"), 3), _fmt(sc.get("recall"), 3), f"{r.seconds:.1f}", note or ""])
    n = {k: sum(r.status == k for r in s.drives) for k in ("done", "skipped", "failed")}
    rows.append(["total", f"{n['done']} done, {n['skipped']} skipped, {n['failed']} failed",
                 str(sum(r.scans for r in s.drives)), str(sum(r.segments for r in s.drives)),
                 str(sum(r.counts.get(method, 0) for r in s.drives)) if method else "-", "", "",
                 f"{s.wall_seconds:.1f}", f"work {s.work_seconds:.1f} s, critical path {s.critical_path_seconds:.1f} s, "
                 f"{s.workers} worker threads"])
    reporter.table(f"featmap batch: {len(s.drives)} drives on {s.scheduler}", columns, rows)
    m = result.merged
    if m is not None:
        mcols = ["method", "features", "seen by 2+ drives"]
        keys = [("count_ratio", 2), ("precision", 3), ("recall", 3), ("redundancy", 2)]
        if m.evaluator == "map":                    # the truth-free metric: no walls to count features per
            keys = [("compression", 1), ("precision", 3), ("recall", 3), ("redundancy", 3)]
        if m.scores:
            mcols += [k for k, _ in keys] + ["best single drive recall"]
        mrows = []
        for name, count in m.counts.items():
            row = [name, str(count), str(m.multi_drive.get(name, 0))]
            if m.scores:
                sc = m.scores.get(name, {})
                best = max((d.get("recall") or 0.0 for d in m.drive_scores.get(name, {}).values()), default=None)
                row += [_fmt(sc.get(k), nd) for k, nd in keys] + [_fmt(best, 3)]
            mrows.append(row)
        against = {"truth": " (scored against the drives' truths, united)", "footprints": f" (scored against {m.reference})",
                   "map": " (scored against the drives' scan points)"}.get(m.evaluator or "truth", "") if m.scores else ""
        reporter.table(f"merged map: {len(m.drives)} drives, {m.segments} segments{against}", mcols, mrows)
        for name, why in m.left_out.items():
            reporter.warning(f"merged map: left out {name}: {why}")
        if m.unscored:
            reporter.warning(f"merged map: {m.unscored}")
    written = sum(d.status == "done" for d in s.drives)
    kept = sum(d.status == "skipped" for d in s.drives)
    failed = sum(d.status == "failed" for d in s.drives)
    parts = [f"{written} run folder{'s' if written != 1 else ''}"] + ([f"{kept} kept (up to date)"] if kept else []) \
        + ([f"{failed} failed"] if failed else [])
    reporter.info(f"wrote {', '.join(parts)}, summary.json" + (", merged/" if m is not None else "")
                  + f" to {Path(s.drives[0].run_dir).parent if s.drives else ''}")


def connect(scheduler: str | None, workers: int | None = None, timeout_s: float = 20.0, given_by: str = "--scheduler"):
    """(client, cluster): a client of the scheduler at ``scheduler`` (cluster None), or of a new LocalCluster;
    errors name ``given_by`` (the flag or file key the address came from)."""
    from distributed import Client

    with _closed_on_interrupt():                    # Ctrl-C while it starts: nothing is left half-started
        if scheduler:
            try:
                return Client(scheduler, timeout=f"{timeout_s}s"), None
            except (OSError, TimeoutError) as exc:
                raise ConfigError(f"{given_by} {scheduler}: cannot connect ({exc})") from None
            except (ValueError, TypeError) as exc:     # distributed's address parser: no port, unknown scheme
                raise ConfigError(f"{given_by} {scheduler}: not a scheduler address such as tcp://HOST:8786 ({exc})") from None
        cluster = local_cluster(workers)
        return Client(cluster), cluster
