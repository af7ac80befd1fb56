"""The mapping pipeline: the one place that loops, times, caches, writes and reports.

``fuse_and_write`` is the fusion-only path (``featmap fuse``). :class:`MappingPipeline` runs a whole
drive (``featmap run``):

1. extraction, scan by scan, streamed over ``workers`` processes, each scan's segments cached on
   disk as soon as it is done (so a re-run with new fusion parameters never re-extracts and an
   interrupted run resumes);
2. every requested fusion method (with the shared corner optimisation);
3. the writers (CSV, GeoJSON, config, metrics; every file atomic) and, when the drive has ground
   truth, the metrics of EVALUATION.md;
4. a summary table.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from featmap.config import FeatmapConfig, save_config
from featmap.errors import DatasetError
from featmap.fusion import FusionResult, fuse
from featmap.io.atomic import atomic_path, atomic_write_text
from featmap.io.segments_csv import SegmentTable, write_fused_csv, write_segments_csv

console = Console(highlight=False, width=None if os.isatty(1) else 140)
EXTRACTION_CACHE_VERSION = 1
SEGMENT_FIELDS = ("x1", "y1", "x2", "y2", "n_points", "z_min", "z_max", "rms")


PROGRESS_MIN_SEGMENTS = 200_000
"""Fusions of at least this many segments (a few seconds or more) show a progress bar."""


@dataclass(frozen=True)
class MethodRun:
    """One method's result on one input, with its wall-clock time in seconds.

    ``prepare_seconds`` is the one-off import/compilation cost paid before the clock started.
    """

    name: str
    result: FusionResult
    seconds: float
    prepare_seconds: float = 0.0


def run_methods(table: SegmentTable, methods: list[str], config: FeatmapConfig) -> list[MethodRun]:
    """Fuse ``table`` with every method in ``methods`` (corner optimisation included), timing each.

    Library imports and compiled-code loading happen before each clock starts (``prepare_seconds``).
    """
    from featmap.fusion.registry import prepare_method
    from featmap.progress import ProgressBar

    runs = []
    for name in methods:
        start = time.perf_counter()
        prepare_method(name)
        prepared = time.perf_counter()
        if len(table) >= PROGRESS_MIN_SEGMENTS and console.is_terminal:
            with ProgressBar(f"fusing {len(table):,} segments ({name})") as bar:
                result = fuse(name, table.segments, table.scan, config, progress=bar.update)
        else:
            result = fuse(name, table.segments, table.scan, config)
        runs.append(MethodRun(name, result, time.perf_counter() - prepared, prepared - start))
    return runs


def summary_table(table: SegmentTable, runs: list[MethodRun], title: str = "featmap fuse") -> Table:
    out = Table(title=title)
    for col in ("method", "segments in", "features out", "clusters dropped", "zero-length skipped", "seconds"):
        out.add_column(col, justify="left" if col == "method" else "right")
    for run in runs:
        r = run.result
        out.add_row(run.name, str(len(table)), str(len(r)), str(r.clusters_dropped),
                    str(r.skipped_zero_length + table.skipped_zero_length), f"{run.seconds:.3f}")
    return out


def fuse_and_write(table: SegmentTable, methods: list[str], config: FeatmapConfig, out: str | Path) -> list[MethodRun]:
    """Fuse a segment table and write ``fused_<method>.csv`` + ``config.yaml`` into ``out``.

    Everything is computed before the first file is written, so a failure leaves nothing behind.
    """
    runs = run_methods(table, methods, config)
    out = Path(out)
    for run in runs:
        write_fused_csv(out / f"fused_{run.name}.csv", run.result.segments, run.result.support)
    save_config(config, out / "config.yaml")
    console.print(summary_table(table, runs))
    console.print(f"loading the methods' libraries took {sum(r.prepare_seconds for r in runs):.2f} s (not in the seconds column)")
    if table.skipped_zero_length:
        console.print(f"skipped {table.skipped_zero_length} zero-length row(s) of the input (no direction, no feature circle)")
    console.print(f"wrote {', '.join(f'fused_{r.name}.csv' for r in runs)} and config.yaml to {out}")
    return runs


def distinct_scans(labels: np.ndarray, scan: np.ndarray, n_features: int) -> np.ndarray:
    """(M,) number of different scans among the members of each fused feature."""
    keep = labels >= 0
    pairs = np.unique(np.stack([labels[keep], scan[keep]]), axis=1)
    return np.bincount(pairs[0], minlength=n_features) if pairs.size else np.zeros(n_features, np.int64)


# --- extraction with a per-scan cache ----------------------------------------------------------------

def extract_scan(item, config) -> np.ndarray:
    """Segments of one :class:`ScanItem` in the world frame: (K, 8) rows of ``SEGMENT_FIELDS``."""
    from featmap.extraction import extract_segments, segments_to_world

    scan_segments = extract_segments(item.points, config)
    world = segments_to_world(scan_segments, item.T_w_velo)
    z_off = item.T_w_velo[2, 3]
    return np.column_stack([world, scan_segments.n_points, scan_segments.z_min + z_off,
                            scan_segments.z_max + z_off, scan_segments.rms]).reshape(-1, len(SEGMENT_FIELDS))


_WORKER: dict = {}


def _init_worker(dataset_cls, dataset_kwargs: dict, config_dict: dict) -> None:
    from featmap.config import ExtractionConfig

    _WORKER["dataset"] = dataset_cls(**dataset_kwargs)
    _WORKER["config"] = ExtractionConfig.model_validate(config_dict)


def _work(position: int) -> tuple[int, np.ndarray | None, str | None, float]:
    ds = _WORKER["dataset"]
    start = time.perf_counter()
    try:
        item = ds[position]
    except DatasetError as exc:
        return position, None, str(exc), 0.0
    rows = extract_scan(item, _WORKER["config"])
    return position, rows, None, time.perf_counter() - start


def _save_npy(path: Path, array: np.ndarray) -> None:
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.save(fh, array)


@dataclass
class ExtractionStats:
    scans_total: int = 0
    scans_extracted: int = 0
    scans_from_cache: int = 0
    skipped: dict = field(default_factory=dict)
    seconds: float = 0.0
    scan_seconds: list = field(default_factory=list)


class MappingPipeline:
    """Extract, fuse, write and score one drive.

    Args:
        dataset: a dataset (``len``, ``[i]`` -> ScanItem) with ``drive``, ``drive_dir``, ``frames``,
            ``geo_frame`` and ``spec()`` (the constructor arguments, to rebuild it in workers).
        config: the resolved configuration.
        out_dir: run folder.
        methods: fusion methods to run.
        workers: extraction processes (1 = in this process).
        cache_dir: root of the per-drive, per-extraction-config segment cache.
        skip_bad_scans: skip unreadable scans instead of failing (they are listed in the summary).
    """

    def __init__(self, dataset, config: FeatmapConfig, out_dir: str | Path, methods: list[str], workers: int = 1,
                 cache_dir: str | Path = "data/cache", skip_bad_scans: bool = False):
        self.dataset = dataset
        self.config = config
        self.out_dir = Path(out_dir)
        self.methods = methods
        self.workers = max(1, int(workers))
        self.skip_bad_scans = skip_bad_scans
        key = json.dumps({"drive": str(Path(dataset.drive_dir).resolve()), "geo": dataset.geo_frame.to_dict(),
                          "extraction": config.extraction.model_dump(mode="json"),
                          "version": EXTRACTION_CACHE_VERSION}, sort_keys=True)
        digest = hashlib.sha1(key.encode()).hexdigest()[:12]
        self.cache = Path(cache_dir) / f"{dataset.drive}-{digest}"
        self.stats = ExtractionStats()

    # -- 1. extraction ------------------------------------------------------------------------------------
    def _cache_file(self, frame: int) -> Path:
        return self.cache / f"{frame:010d}.npy"

    def extract(self) -> SegmentTable:
        """Segments of every selected scan (world frame), from the cache where possible."""
        from featmap.progress import track

        ds = self.dataset
        self.cache.mkdir(parents=True, exist_ok=True)
        atomic_write_text(self.cache / "extraction.yaml", self.config.to_yaml().split("fusion:")[0])
        todo = [i for i, f in enumerate(ds.frames) if not self._cache_file(f).exists()]
        self.stats = ExtractionStats(scans_total=len(ds), scans_from_cache=len(ds) - len(todo))
        start = time.perf_counter()
        if todo:
            for position, rows, error, seconds in track(self._run_extraction(todo), len(todo),
                                                        f"extracting {ds.drive}"):
                frame = ds.frames[position]
                if error is not None:
                    if not self.skip_bad_scans:
                        raise DatasetError(error + " (use --skip-bad-scans to leave it out)")
                    self.stats.skipped[frame] = error
                    continue
                _save_npy(self._cache_file(frame), rows)
                self.stats.scans_extracted += 1
                self.stats.scan_seconds.append(seconds)
        self.stats.seconds = time.perf_counter() - start
        return self._assemble()

    def _run_extraction(self, positions: list[int]):
        if self.workers == 1:
            _WORKER["dataset"], _WORKER["config"] = self.dataset, self.config.extraction
            try:
                yield from (_work(p) for p in positions)
            finally:
                _WORKER.clear()
            return
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        os.environ.setdefault("OMP_NUM_THREADS", "1")
        ctx = mp.get_context("spawn")   # Open3D and fork do not mix
        with ProcessPoolExecutor(self.workers, mp_context=ctx, initializer=_init_worker,
                                 initargs=(type(self.dataset), self.dataset.spec(),
                                           self.config.extraction.model_dump(mode="json"))) as pool:
            yield from pool.map(_work, positions, chunksize=4)

    def _assemble(self) -> SegmentTable:
        scans, rows = [], []
        for frame in self.dataset.frames:
            path = self._cache_file(frame)
            if not path.exists():
                continue
            data = np.load(path).reshape(-1, len(SEGMENT_FIELDS))
            rows.append(data)
            scans.append(np.full(len(data), frame, np.int64))
        data = np.concatenate(rows) if rows else np.zeros((0, len(SEGMENT_FIELDS)))
        scan = np.concatenate(scans) if scans else np.zeros(0, np.int64)
        return SegmentTable(scan=scan, segments=data[:, :4],
                            extra={name: data[:, 4 + k] for k, name in enumerate(SEGMENT_FIELDS[4:])})

    # -- 2-4. fuse, write, score, report ------------------------------------------------------------------
    def run(self) -> dict:
        """The whole job; returns the metrics dictionary written to ``metrics.json``."""
        from featmap.evaluation import compute_metrics, load_truth
        from featmap.io.geojson import write_fused_geojson

        t0 = time.perf_counter()
        table = self.extract()
        runs = run_methods(table, self.methods, self.config)
        truth_dir = getattr(self.dataset, "truth_dir", None)
        frames_done = [f for f in self.dataset.frames if f not in self.stats.skipped]
        truth = load_truth(truth_dir, self.dataset.geo_frame, frames_done) if truth_dir is not None else None
        t_eval = time.perf_counter()
        scores = {run.name: compute_metrics(run.result.segments, truth) if truth is not None else {} for run in runs}
        eval_seconds = time.perf_counter() - t_eval

        t_write = time.perf_counter()
        out = self.out_dir
        write_segments_csv(out / "segments.csv", table)
        for run in runs:
            write_fused_csv(out / f"fused_{run.name}.csv", run.result.segments, run.result.support)
            if self.config.output.geojson:
                write_fused_geojson(out / f"fused_{run.name}.geojson", run.result.segments, run.result.support,
                                    self.dataset.geo_frame, run.name, distinct_scans(run.result.labels, table.scan,
                                                                                     len(run.result)))
        poses = self.dataset.poses()
        self._write_trajectory(out / "trajectory.csv", poses)
        self._write_maps(out, table, runs, truth, poses[:, :2, 3])
        save_config(self.config, out / "config.yaml")
        write_seconds = time.perf_counter() - t_write
        scan_s = np.asarray(self.stats.scan_seconds)
        metrics = {
            "drive": self.dataset.drive,
            "data_dir": str(self.dataset.data_dir),
            "frames": [int(self.dataset.frames[0]), int(self.dataset.frames[-1])],
            "frames_processed": [int(f) for f in frames_done],
            "scans_total": self.stats.scans_total,
            "scans_processed": self.stats.scans_total - len(self.stats.skipped),
            "scans_extracted_now": self.stats.scans_extracted,
            "scans_from_cache": self.stats.scans_from_cache,
            "scans_skipped": {str(k): v for k, v in sorted({**getattr(self.dataset, "skipped", {}),
                                                             **self.stats.skipped}.items())},
            "poor_gps_frames": list(map(int, getattr(self.dataset, "poor_gps", []))),
            "segments": int(len(table)),
            "geo_frame": self.dataset.geo_frame.to_dict(),
            "ground_truth": str(truth_dir) if truth_dir is not None else None,
            "timings_s": {
                "extraction": round(self.stats.seconds, 3),
                "extraction_per_scan_median": round(float(np.median(scan_s)), 4) if len(scan_s) else None,
                **{f"fusion_{r.name}": round(r.seconds, 4) for r in runs},
                "fusion_library_loading": round(sum(r.prepare_seconds for r in runs), 3),
                "evaluation": round(eval_seconds, 3),
                "writing": round(write_seconds, 3),
            },
            "methods": {r.name: {"count": len(r.result), "clusters_dropped": r.result.clusters_dropped,
                                 "seconds": round(r.seconds, 4), **scores[r.name]} for r in runs},
        }
        metrics["timings_s"]["total"] = round(time.perf_counter() - t0, 3)
        atomic_write_text(out / "metrics.json", json.dumps(metrics, indent=1))
        from featmap.compare import write_comparison

        write_comparison(out)
        self.report(metrics)
        return metrics

    def _write_maps(self, out: Path, table: SegmentTable, runs: list[MethodRun], truth, traj: np.ndarray) -> None:
        """GeoJSON of segments/trajectory/truth, KML, the interactive HTML map and an overview plot."""
        from featmap.io.geojson import write_segments_geojson

        frame = self.dataset.geo_frame
        cfg = self.config.output
        layers = {r.name: (r.result.segments, r.result.support) for r in runs}
        if cfg.geojson:
            write_segments_geojson(out / "segments.geojson", table.segments, frame,
                                   [{"scan": int(s)} for s in table.scan], {"layer": "extracted"})
            write_segments_geojson(out / "trajectory.geojson", np.column_stack([traj[:-1], traj[1:]]), frame,
                                   common={"layer": "trajectory"})
            if truth is not None:
                write_segments_geojson(out / "truth.geojson", truth.walls, frame,
                                       [{"building": str(b)} for b in truth.building], {"layer": "truth"})
        if cfg.kml:
            from featmap.io.kml import write_kml

            write_kml(out / "map.kml", layers, frame, trajectory=traj)
        if cfg.html:
            from featmap.io.html_map import write_html_map

            write_html_map(out / "map.html", {"segments": (table.segments, None), **layers}, frame, traj,
                           truth.walls if truth is not None else None)
        if cfg.plots and runs:
            from featmap.plotting.overview import overview_plot

            overview_plot(out / "map_overview.png", layers, frame, traj, truth, cfg)

    def _write_trajectory(self, path: Path, poses: np.ndarray) -> None:
        lines = ["frame,x,y,z,yaw"]
        for frame, T in zip(self.dataset.frames, poses):
            yaw = np.arctan2(T[1, 0], T[0, 0])
            lines.append(f"{frame},{T[0, 3]:.4f},{T[1, 3]:.4f},{T[2, 3]:.4f},{yaw:.6f}")
        atomic_write_text(path, "\n".join(lines) + "\n")

    def report(self, metrics: dict) -> None:
        table = Table(title=f"featmap run: {metrics['drive']} ({metrics['scans_processed']} scans, "
                            f"{metrics['segments']} segments)")
        cols = ["method", "features", "seconds"]
        has_truth = metrics["ground_truth"] is not None
        if has_truth:
            cols += ["count_ratio", "precision", "recall", "redundancy", "offset cm", "corner cm"]
        for c in cols:
            table.add_column(c, justify="left" if c == "method" else "right")

        def fmt(v, nd=3):
            return "-" if v is None else f"{v:.{nd}f}"

        for name, m in metrics["methods"].items():
            row = [name, str(m["count"]), f"{m['seconds']:.2f}"]
            if has_truth:
                row += [fmt(m["count_ratio"], 2), fmt(m["precision"]), fmt(m["recall"]), fmt(m["redundancy"], 2),
                        fmt(m["offset_cm"], 1), fmt(m["corner_err_cm"], 1)]
            table.add_row(*row)
        console.print(table)
        t = metrics["timings_s"]
        per_scan = t["extraction_per_scan_median"]
        console.print(f"extraction {t['extraction']:.1f} s ({metrics['scans_extracted_now']} scans extracted, "
                      f"{metrics['scans_from_cache']} from cache"
                      + (f", median {1000 * per_scan:.0f} ms/scan" if per_scan else "") + f"); total {t['total']:.1f} s")
        if metrics["scans_skipped"]:
            console.print(f"[yellow]skipped {len(metrics['scans_skipped'])} bad scan(s): "
                          + "; ".join(list(metrics["scans_skipped"].values())[:3]) + "[/yellow]")
        if metrics["poor_gps_frames"]:
            console.print(f"[yellow]{len(metrics['poor_gps_frames'])} frame(s) with poor GPS (navstat/numsats/pos_accuracy); "
                          "their segments may be misplaced[/yellow]")
        console.print(f"wrote segments.csv, fused_<method>.csv/.geojson, metrics.json, comparison.md, config.yaml, "
                      f"map.kml, map.html, map_overview.png to {self.out_dir} (figures: featmap figures {self.out_dir})")
