"""Fusion of a segment table with several methods, timed; and the fusion-only job (``featmap fuse``)."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

from featmap.fusion import FusionConfig, FusionResult, fuse, get_method, prepare_method
from featmap.fusion.registry import fuse_columns
from featmap.io.atomic import atomic_write_text
from featmap.io.segments_csv import SegmentTable, write_fused_csv
from featmap.reporting import NullReporter, Reporter

FUSE_RECORD = "fuse.json"
"""What ``featmap fuse`` fused (source, counts): it marks a folder as its output."""
PROGRESS_MIN_SEGMENTS = 200_000
"""Fusions of at least this many segments (a few seconds and more) show a progress bar of their own."""


@dataclass(frozen=True)
class MethodRun:
    """One method's result on one input, with its wall-clock time in seconds (imports excluded)."""

    name: str
    result: FusionResult
    seconds: float


def warm_up(methods: list[str]) -> float:
    """Load every method's libraries and compiled code (numba) so that this one-off cost is
    not charged to the first method's fusion time. Returns the seconds it took."""
    start = time.perf_counter()
    for name in methods:
        prepare_method(name)
    return time.perf_counter() - start


def fuse_methods(table: SegmentTable, methods: list[str], config: FusionConfig,  # type: ignore[valid-type]
                 reporter: Reporter = NullReporter()) -> list[MethodRun]:
    """Fuse ``table`` with every method in ``methods`` (corner optimisation included), timing each."""
    rules = _support_rules(methods, config)
    columns = fuse_columns(table.extra, len(table))
    if columns["rms"] is None and len(table):
        off = [f"fusion.{name}.clean_rms_ratio" for name, rule in rules.items() if rule.clean_rms_ratio is not None]
        if off:
            reporter.warning(f"the segments have no rms column, so no segment counts as a clean view ({', '.join(off)} "
                             "has nothing to compare): small clusters are kept by count and length only")
    if columns["max_gap"] is None and len(table):
        idle = ["fusion.refine.resolved_gap_m cuts nothing"] if config.refine.resolved_gap_m > 0 else []
        idle += [f"fusion.{name}.coarse_gap_m finds no coarse view" for name, rule in rules.items()
                 if rule.coarse_clause_acts]
        if idle:
            reporter.warning("the segments have no max_gap column (their extractor does not measure it), so "
                             + " and ".join(idle))
    if columns["sensor_xy"] is None and len(table):
        blind = [f"fusion.{name}.visible_share" for name, rule in rules.items() if rule.visible_share is not None]
        if blind:
            reporter.warning(f"the segments have no sensor_x / sensor_y columns, so {', '.join(blind)} keeps "
                             "nothing (no scan position to see from)")
    runs = []
    if len(table) < PROGRESS_MIN_SEGMENTS:
        with reporter.progress("fusing", len(methods)) as advance:
            for name in methods:
                start = time.perf_counter()
                result = fuse(name, table.segments, table.scan, config, **columns)
                runs.append(MethodRun(name, result, time.perf_counter() - start))
                advance(1)
    else:
        for name in methods:
            with reporter.progress(f"fusing {len(table):,} segments ({name}), %", 100) as advance:
                shown = [0]

                def progress(done: int, total: int) -> None:      # the method's own units, shown in per cent
                    percent = int(100 * done / max(total, 1))
                    advance(percent - shown[0])
                    shown[0] = percent

                start = time.perf_counter()
                result = fuse(name, table.segments, table.scan, config, progress, **columns)
                runs.append(MethodRun(name, result, time.perf_counter() - start))
    for run in runs:
        if len(run.result) == 0 and len(table) > 0:
            reporter.warning(f"{run.name}: no feature from {len(table)} segments ({run.result.clusters_dropped} "
                             f"clusters dropped); check the fusion.{run.name} settings")
    return runs


def _support_rules(methods: list[str], config: FusionConfig) -> dict:  # type: ignore[valid-type]
    """``{name: SupportRule}`` for the ``methods`` that drop small clusters, each with its config section."""
    rules = {}
    for name in methods:
        method = get_method(name)
        if method.support_rule is not None:
            rules[name] = method.support_rule(getattr(config, name))
    return rules


def fuse_and_write(table: SegmentTable, methods: list[str], config, out: str | Path,
                   reporter: Reporter = NullReporter(), source: str | Path | None = None) -> list[MethodRun]:
    """Fuse a segment table and write ``fused_<method>.csv``, ``config.yaml`` and ``fuse.json`` into ``out``.

    ``config`` is the whole config (saved as config.yaml); ``source``: the file the table was read from
    (an ``out`` that holds it is refused). ``out`` is replaced whole, like a run folder: it is written
    into a temporary twin and swapped in at the end, so it never mixes the files of two fusions (a
    previous fusion's ``fused_<method>.csv`` beside a new config), and a failure leaves it as it was. A
    folder that holds other files (a run folder, say) is refused.
    """
    from featmap.pipeline.config import save_config
    from featmap.pipeline.run_folder import RunFolder

    out = Path(out)
    import_seconds = warm_up(methods)
    with RunFolder(out, marker=FUSE_RECORD, inputs=[source] if source is not None else []) as folder:
        runs = fuse_methods(table, methods, config.fusion, reporter)
        for run in runs:
            write_fused_csv(folder.tmp / f"fused_{run.name}.csv", run.result.segments, run.result.support)
        save_config(config, folder.tmp / "config.yaml")
        record = {"source": None if source is None else str(Path(source).absolute()), "segments": len(table),
                  "features": {run.name: len(run.result) for run in runs}}
        atomic_write_text(folder.tmp / FUSE_RECORD, json.dumps(record, indent=1) + "\n")
        folder.commit()
    rows = [[run.name, str(len(table)), str(len(run.result)), str(run.result.clusters_dropped),
             str(run.result.skipped_zero_length + table.skipped_zero_length), f"{run.seconds:.3f}"] for run in runs]
    reporter.table("featmap fuse", ["method", "segments in", "features out", "clusters dropped", "zero-length skipped",
                                    "seconds"], rows)
    if table.skipped_zero_length:
        reporter.info(f"skipped {table.skipped_zero_length} zero-length row(s) of the input (no direction, no feature circle)")
    if table.skipped_duplicates:
        reporter.warning(f"skipped {table.skipped_duplicates} duplicate row(s) of the input (same scan and endpoints "
                         "as an earlier row; they would count twice in a feature's support)")
    if len(table) == 0:
        reporter.warning(f"{source if source is not None else 'the input'}: no segment to fuse (a header and no "
                         "rows, or only zero-length ones); the maps written are empty")
    reporter.info(f"loading the methods' libraries and compiled code took {import_seconds:.2f} s (not in the seconds above)")
    reporter.info(f"wrote {', '.join(f'fused_{r.name}.csv' for r in runs)}, config.yaml and {FUSE_RECORD} to {out}")
    return runs
