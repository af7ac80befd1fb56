"""One run: a scan source in, a run folder out.

:meth:`MappingPipeline.run` opens the run folder (so a bad ``--out`` fails first), extracts every scan
through the segment store and the executor, refines the scans' poses from their segments (``refinement``),
moves the segments to the world frame with those poses, fuses them with every requested method, scores the results with every evaluation plug-in that finds its reference, writes the
output plug-ins and the run's record (``config.yaml``, ``metrics.json``) into the folder, swaps it into
place, and reports a summary through the reporter.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from featmap import __version__
from featmap.datasets.base import TIME_GOES_BACK, ScanSource
from featmap.evaluation import EVALUATORS, EvaluationContext, Evaluator, Reference
from featmap.evaluation.references import observation_record
from featmap.io.atomic import atomic_write_text
from featmap.io.run_metrics import (GeoRecord, MethodRecord, OnlineRecord, RefinementRecord, RunMetrics,
                                    ScanCounts, SourceRecord, write_run_metrics)
from featmap.outputs import OUTPUTS, Output, RunProducts, write_outputs
from featmap.pipeline.config import FeatmapConfig
from featmap.pipeline.executor import Executor, SerialExecutor
from featmap.pipeline.extract import Extraction, extract_source
from featmap.pipeline.fuse import MethodRun, fuse_methods, warm_up
from featmap.pipeline.online import check_online, map_online, report_online
from featmap.pipeline.refine import RefinementRun, refine_extraction
from featmap.pipeline.run_folder import RunFolder
from featmap.pipeline.segment_store import SegmentStore
from featmap.reporting import NullReporter, Reporter


@dataclass(frozen=True)
class RunResult:
    """What a run produced: its record, everything the writers got, and the files written."""

    out: Path
    metrics: RunMetrics
    products: RunProducts
    files: list[str]


def score_methods(runs: list[MethodRun], references: dict[str, tuple[Evaluator, Reference]]) -> dict[str, dict]:
    """method -> evaluator name -> metrics."""
    return {run.name: {name: ev.score(ref, run.result.segments) for name, (ev, ref) in references.items()}
            for run in runs}


def found_references(context: EvaluationContext, evaluators: tuple[Evaluator, ...] = EVALUATORS):
    """Yield (evaluator, reference) for the evaluators that find their reference, in order, each prepared
    only when the one before it has been taken."""
    for evaluator in evaluators:
        reference = evaluator.prepare(context)
        if reference is not None:
            yield evaluator, reference


def prepare_references(context: EvaluationContext,
                       evaluators: tuple[Evaluator, ...] = EVALUATORS) -> dict[str, tuple[Evaluator, Reference]]:
    """The evaluators that found their reference, in order (the first is the run's primary score)."""
    return {evaluator.name: (evaluator, reference) for evaluator, reference in found_references(context, evaluators)}


def primary_reference(context: EvaluationContext, evaluators: tuple[Evaluator, ...] = EVALUATORS
                      ) -> tuple[Evaluator, Reference] | None:
    """The first evaluator that finds its reference (the run's primary score), without preparing the others."""
    return next(found_references(context, evaluators), None)


class MappingPipeline:
    """Extract, fuse, score and write one scan source.

    Args:
        config: the resolved configuration.
        methods: fusion methods to run (registry names).
        store: the segment cache (``SegmentStore(None)`` keeps nothing).
        executor: where per-scan extraction runs.
        reporter: progress and summaries.
        skip_bad_scans: leave unreadable scans out (listed in metrics.json) instead of failing.
        outputs: the output plug-ins to run.
        online_every: map online (:mod:`featmap.pipeline.online`): scans extracted and fused one at a time, the
            map made every this many scans, the source's poses as they are; None = the whole drive at once.
    """

    def __init__(self, config: FeatmapConfig, methods: list[str], store: SegmentStore,
                 executor: Executor = SerialExecutor(), reporter: Reporter = NullReporter(),
                 skip_bad_scans: bool = False, outputs: tuple[Output, ...] = OUTPUTS,
                 online_every: int | None = None):
        if online_every is not None:
            check_online(config, methods, online_every)
        self.online_every = online_every
        self.config = config
        self.methods = methods
        self.store = store
        self.executor = executor
        self.reporter = reporter
        self.skip_bad_scans = skip_bad_scans
        self.outputs = outputs

    def extract(self, source: ScanSource) -> Extraction:
        return extract_source(source, self.config.extraction, self.store, self.executor, self.reporter,
                              self.skip_bad_scans)

    def run(self, source: ScanSource, out: str | Path) -> RunResult:
        t0 = time.perf_counter()
        inputs = [Path(source.location)] + [Path(p) for p in (self.config.evaluation.footprints,) if p]
        with RunFolder(out, inputs=inputs) as folder:
            online = None
            if self.online_every is not None:
                import_seconds = warm_up(self.methods)          # not charged to the first scan
                online = map_online(source, self.config, self.online_every, self.reporter, self.skip_bad_scans)
                extraction = online.extraction
            else:
                extraction = self.extract(source)
            for message in extraction.discarded:
                self.reporter.warning(f"discarded a corrupt cache entry and extracted again: {message}")
            # (online, the poses were refined causally while mapping)
            refinement = refine_extraction(extraction, self.config.refinement) if online is None else online.refinement
            poses = refinement.poses
            table = extraction.world_table(poses)
            if online is None:
                import_seconds = warm_up(self.methods)
                runs = fuse_methods(table, self.methods, self.config.fusion, self.reporter)
            else:       # the fusion's cost: every scan's linking and the last map
                runs = [MethodRun("proposed", online.result, online.fusion_seconds)]
            t_eval = time.perf_counter()
            context = EvaluationContext(source.location, extraction.frames, source.geo_origin, self.config.evaluation,
                                        extraction.world_points(poses), table.segments, self.executor.workers,
                                        extraction.world_point_scans())
            references = prepare_references(context)
            scores = score_methods(runs, references)
            eval_seconds = time.perf_counter() - t_eval

            metrics = RunMetrics(
                featmap_version=__version__,
                source=SourceRecord(kind=source.kind, name=source.name, location=str(source.location),
                                    dimension=source.dimension, frames=list(map(int, source.frames)),
                                    frames_processed=list(map(int, extraction.frames)),
                                    skipped={str(k): v for k, v in sorted({**source.notes.skipped,
                                                                           **extraction.skipped}.items())},
                                    flags={k: list(map(int, v)) for k, v in source.notes.flags.items()}),
                geo_frame=GeoRecord(**source.geo_origin.to_dict()) if source.geo_origin is not None else None,
                references={name: ref.path for name, (_, ref) in references.items()},
                primary=next(iter(references), None),
                scans=ScanCounts(total=len(source), processed=len(extraction.frames),
                                 extracted_now=extraction.extracted_now, from_cache=extraction.from_cache),
                segments=len(table),
                timings_s={"extraction": round(extraction.seconds, 3),
                           "extraction_per_scan_median": _median(extraction.scan_seconds),
                           "refinement": round(refinement.seconds, 3),
                           "fusion_library_loading": round(import_seconds, 3),
                           **{f"fusion_{r.name}": round(r.seconds, 4) for r in runs},
                           "evaluation": round(eval_seconds, 3),
                           **({} if online is None else online.timings())},
                methods={r.name: MethodRecord(count=len(r.result), clusters_dropped=r.result.clusters_dropped,
                                              seconds=round(r.seconds, 4), scores=scores[r.name]) for r in runs},
                refinement=refinement_record(refinement),
                online=None if online is None else OnlineRecord(every=online.every, maps=online.maps),
            )
            primary = references.get(metrics.primary)
            truth = primary[1].data if primary is not None and hasattr(primary[1].data, "walls") else None
            products = RunProducts(table=table, results={r.name: r.result for r in runs}, frames=extraction.frames,
                                   poses=poses, geo_frame=source.geo_origin, truth=truth,
                                   config_yaml=self.config.to_yaml(), metrics=metrics, output=self.config.output,
                                   source_poses=extraction.poses,
                                   corrections=None if refinement.method == "none" else refinement.result.corrections,
                                   footprints=(observation_record(references["footprints"][1].data, references["footprints"][1].path)
                                               if "footprints" in references else None))
            t_write = time.perf_counter()
            files = write_outputs(products, folder.tmp, self.outputs)
            atomic_write_text(folder.tmp / "config.yaml", products.config_yaml)
            if online is not None:
                atomic_write_text(folder.tmp / "online.csv", online.csv_text())
                files.append("online.csv")
            metrics.timings_s["writing"] = round(time.perf_counter() - t_write, 3)
            metrics.timings_s["total"] = round(time.perf_counter() - t0, 3)
            write_run_metrics(folder.tmp / "metrics.json", metrics)
            files += ["config.yaml", "metrics.json"]
            folder.commit()
        result = RunResult(Path(out), metrics, products, files)
        if online is not None:
            report_online(online, self.reporter)
        report_run(result, self.reporter)
        return result


def refinement_record(run: RefinementRun) -> RefinementRecord:
    """The ``refinement`` record of metrics.json."""
    r = run.result
    moved, turned = r.translation_m, r.rotation_deg
    stats = r.stats

    def rounded(value, nd):
        return None if value is None or value != value else round(float(value), nd)

    return RefinementRecord(method=run.method, applied=bool(stats.get("applied", False)), seconds=round(run.seconds, 3),
                            scans=len(run.frames), keyframes=stats.get("keyframes"), iterations=r.iterations,
                            matches=r.matches, converged=r.converged,
                            correction_mean_m=round(float(moved.mean()), 4) if len(moved) else 0.0,
                            correction_max_m=round(float(moved.max()), 4) if len(moved) else 0.0,
                            rotation_mean_deg=round(float(turned.mean()), 4) if len(turned) else 0.0,
                            rotation_max_deg=round(float(turned.max()), 4) if len(turned) else 0.0,
                            residual_before_mm=rounded(stats.get("residual_before_mm"), 3),
                            residual_after_mm=rounded(stats.get("residual_after_mm"), 3),
                            loops=stats.get("loops"), slam_poses=run.slam_poses)


def _median(values: list[float]) -> float | None:
    import statistics

    return round(statistics.median(values), 4) if values else None


SUMMARY_COLUMNS = [("count_ratio", 2, "count_ratio"), ("precision", 3, "precision"), ("recall", 3, "recall"),
                   ("redundancy", 2, "redundancy"), ("offset_cm", 1, "offset cm"), ("corner_err_cm", 1, "corner cm"),
                   ("compression", 1, "compression")]


def report_refinement(record: RefinementRecord | None, reporter: Reporter) -> None:
    """One line on what pose refinement did."""
    if record is None or record.method == "none":
        return
    agree = (f"mean mismatch between scans {record.residual_before_mm:.1f} -> {record.residual_after_mm:.1f} mm"
             if record.residual_before_mm is not None and record.residual_after_mm is not None else "no segments matched")
    loops = f", {record.loops} loop(s) closed" if record.loops else ""
    loops += ", the source's poses taken as a SLAM result" if record.slam_poses else ""
    if record.applied:
        reporter.info(f"pose refinement ({record.method}): moved {record.scans} scans by {100 * record.correction_mean_m:.1f} cm "
                      f"and {record.rotation_mean_deg:.2f} deg on average (max {100 * record.correction_max_m:.1f} cm, "
                      f"{record.rotation_max_deg:.2f} deg){loops}, {agree}, {record.seconds:.1f} s")
    else:
        reporter.info(f"pose refinement ({record.method}): kept the source poses ({agree}: not a clear improvement), "
                      f"{record.seconds:.1f} s")


def report_run(result: RunResult, reporter: Reporter) -> None:
    """The summary table (one row per method) and a few lines on extraction, skips and files."""
    m = result.metrics
    columns = ["method", "features", "seconds"]
    first = m.primary_scores(next(iter(m.methods))) if m.methods else {}
    shown = [(key, nd, title) for key, nd, title in SUMMARY_COLUMNS if key in first]
    columns += [title for _, _, title in shown]

    def fmt(value, nd):
        return "-" if value is None else f"{value:.{nd}f}"

    rows = []
    for name, record in m.methods.items():
        scores = m.primary_scores(name)
        rows.append([name, str(record.count), f"{record.seconds:.2f}"] + [fmt(scores.get(k), nd) for k, nd, _ in shown])
    against = f", scored against {m.primary}" if m.primary else ", no reference to score against"
    reporter.table(f"featmap run: {m.source.name} ({m.scans.processed} scans, {m.segments} segments{against})",
                   columns, rows)
    t = m.timings_s
    per_scan = t.get("extraction_per_scan_median")
    reporter.info(f"extraction {t['extraction']:.1f} s ({m.scans.extracted_now} scans extracted, {m.scans.from_cache} "
                  "from cache" + (f", median {1000 * per_scan:.0f} ms/scan" if per_scan else "")
                  + f"); total {t['total']:.1f} s")
    report_refinement(m.refinement, reporter)
    if m.source.skipped:
        reporter.warning(f"skipped {len(m.source.skipped)} bad scan(s): " + "; ".join(list(m.source.skipped.values())[:3]))
    if m.source.flags.get(TIME_GOES_BACK):
        back = m.source.flags[TIME_GOES_BACK]
        reporter.warning(f"{len(back)} frame(s) whose timestamp is not after the one before (first: frame {back[0]}); "
                         "the source's clock stepped back or stood still there (pose refinement takes each such step "
                         "as a tenth of the median one)")
    if m.source.flags.get("poor_gps"):
        reporter.warning(f"{len(m.source.flags['poor_gps'])} frame(s) with poor GPS (navstat/numsats/pos_accuracy); "
                         "their segments may be misplaced")
    reporter.info(f"wrote {', '.join(result.files)} to {result.out} (figures: featmap figures {result.out})")
