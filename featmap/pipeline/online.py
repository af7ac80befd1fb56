"""Online mapping (``featmap run --online N``): each scan is extracted, moved to the world frame with the
source's pose and linked into the map as it comes; the fused map is made every ``N`` scans.

This is how a vehicle would run featmap while it drives: scans in order, one at a time, no look-ahead and
no segment cache (every scan is extracted now, so its time is the real cost). The poses are corrected
causally (``refinement.method: fixed_lag``, :mod:`featmap.refinement.fixed_lag`): a scan's correction is
decided once ``lag_scans`` newer scans have come, and only then does it go into the map, so the map lags
that many scans behind the newest; ``refinement.method: none`` uses the source's poses as they come. The
fusion is :class:`featmap.fusion.online.OnlineFusion` (the proposed method): the last map is the one
``featmap run --method proposed --set refinement.method=<the same>`` makes of the same scans (bit for bit
when both fuse in the same whole-kilometre frame, as a drive within 500 m of its origin always does; see
that module).
:func:`map_online` returns the per-scan times (extraction, pose correction, linking, and making the map
where it was made)
beside the usual extraction record, so that the run folder and its scores are those of any run.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from threadpoolctl import threadpool_limits

from featmap.datasets.base import ScanSource
from featmap.errors import ConfigError
from featmap.extraction import extractor_for, segments_to_world, world_fields
from featmap.fusion import FusionResult
from featmap.fusion.online import OnlineFusion
from featmap.pipeline.config import FeatmapConfig
from featmap.pipeline.extract import Extraction, check_poses, empty_extraction, readable_scans
from featmap.pipeline.refine import RefinementRun
from featmap.refinement import RefinementResult, apply_corrections
from featmap.refinement.fixed_lag import FixedLagRefiner
from featmap.refinement.terms import with_slam_prior
from featmap.reporting import NullReporter, Reporter

ONLINE_METHODS = ("proposed",)
"""The methods that can fuse one scan at a time (mean shift and density cluster all segments at once)."""
ONLINE_REFINEMENT = ("fixed_lag", "none")
"""The pose refinements that run one scan at a time (the first is what ``--online`` uses unless told)."""


@dataclass(frozen=True)
class OnlineMapping:
    """What an online pass over a source gave.

    Attributes:
        extraction: the scans' segments (sensor frame), poses and counts, as :func:`extract_source` gives.
        result: the proposed map after the last scan.
        frames: (F,) frame of each processed scan; segments: (F,) its segment count.
        extract_s, link_s: (F,) seconds to extract the scan and to link its segments into the map.
        fused_s: (F,) seconds to make the map after that scan (NaN where it was not made); features: (F,)
            the map's features then (-1 where it was not made).
        every: the map was made after every ``every``-th scan and after the last.
        refine_s: (F,) seconds the pose refinement took after the scan came (0 without refinement).
        refinement: the poses the map was made with (the causal refinement's, or the source's).
    """

    extraction: Extraction
    result: FusionResult
    frames: np.ndarray
    segments: np.ndarray
    extract_s: np.ndarray
    link_s: np.ndarray
    fused_s: np.ndarray
    features: np.ndarray
    every: int
    refine_s: np.ndarray
    refinement: RefinementRun

    def csv_text(self) -> str:
        """``online.csv``: ``frame,segments,extract_ms,refine_ms,link_ms,fused_ms,features`` per scan (the
        last two empty where the map was not made; link_ms: linking the scans decided after this one came)."""
        lines = ["frame,segments,extract_ms,refine_ms,link_ms,fused_ms,features"]
        for f, n, e, r, ln, m, k in zip(self.frames, self.segments, self.extract_s, self.refine_s, self.link_s,
                                        self.fused_s, self.features):
            made = np.isfinite(m)
            lines.append(f"{f},{n},{1e3 * e:.3f},{1e3 * r:.3f},{1e3 * ln:.3f},{f'{1e3 * m:.3f}' if made else ''},"
                         f"{k if made else ''}")
        return "\n".join(lines) + "\n"

    @property
    def maps(self) -> int:
        """How many times the map was made."""
        return int(np.isfinite(self.fused_s).sum())

    @property
    def fusion_seconds(self) -> float:
        """The fusion's share of the run: every scan's linking and making the last map."""
        return float(self.link_s.sum() + np.nansum(self.fused_s[-1:]))

    def timings(self) -> dict[str, float | None]:
        """Medians and maxima (seconds) for metrics.json's ``timings_s`` (None when no scan was mapped)."""
        made = self.fused_s[np.isfinite(self.fused_s)]

        def stat(values, f):
            return round(float(f(values)), 5) if len(values) else None

        return {"online_extraction_per_scan_median": stat(self.extract_s, np.median),
                "online_refinement_per_scan_median": stat(self.refine_s, np.median),
                "online_refinement_per_scan_max": stat(self.refine_s, np.max),
                "online_link_per_scan_median": stat(self.link_s, np.median),
                "online_link_per_scan_max": stat(self.link_s, np.max),
                "online_map_median": stat(made, np.median), "online_map_max": stat(made, np.max)}


def check_online(config: FeatmapConfig, methods: list[str], every: int) -> None:
    """A one-line ConfigError when ``--online`` cannot run as asked."""
    if every < 1:
        raise ConfigError(f"--online {every}: make the map every N >= 1 scans")
    other = [m for m in methods if m not in ONLINE_METHODS]
    if other:
        raise ConfigError(f"--online fuses one scan at a time with {', '.join(ONLINE_METHODS)} only, not "
                          f"{', '.join(other)} ({'it clusters' if len(other) == 1 else 'they cluster'} all segments at once): "
                          "use --method proposed")
    if config.refinement.method not in ONLINE_REFINEMENT:
        raise ConfigError(f"--online corrects the poses causally (refinement.method fixed_lag) or not at all (none), "
                          f"but refinement.method is '{config.refinement.method}' (it needs the whole drive): "
                          "add --set refinement.method=fixed_lag")


def map_online(source: ScanSource, config: FeatmapConfig, every: int, reporter: Reporter = NullReporter(),
               skip_bad_scans: bool = False) -> OnlineMapping:
    """Extract and fuse ``source`` one scan at a time (see the module docstring).

    Raises:
        DatasetError: an unreadable scan (unless ``skip_bad_scans``: then it is left out and listed), or
            the pose of a scan read that is not finite (as it comes), or poses that span more than any map.
    """
    extractor = extractor_for(source.dimension, config.extraction)
    section = getattr(config.extraction, extractor.name)
    all_poses = source.poses()
    online = OnlineFusion(config.fusion)
    out = empty_extraction(source)
    refiner = None
    if config.refinement.method == "fixed_lag":
        refiner = FixedLagRefiner(with_slam_prior(config.refinement.fixed_lag, out.slam_poses))
    waiting: dict[int, tuple[object, np.ndarray]] = {}   # scan position -> (segments, source pose) not yet in the map

    def link(positions: list[int]) -> None:
        """Put the decided scans at ``positions`` into the map, with their refined poses."""
        for k in positions:
            segments, T = waiting.pop(k)
            if refiner is not None:
                T = refiner.decided_pose(k)
            columns = world_fields(segments, T)
            online.add_scan(segments_to_world(segments, T), columns["rms"], columns.get("max_gap"), T[:2, 3])

    stamps, poses, rows = [], [], []
    result = online.fused()
    n = len(source.frames)
    start = time.perf_counter()
    # One core, as a vehicle's mapper would have: and BLAS threads left spinning after the smoother's solves
    # would slow the next scan's extraction by a tenth.
    with threadpool_limits(1, user_api="blas"), reporter.progress(f"mapping {source.name} online", n) as advance:
        for position, frame, scan in readable_scans(source, skip_bad_scans, out.skipped, advance):
            T = all_poses[position]
            check_poses(source, [frame], T[None])
            t0 = time.perf_counter()
            segments = extractor.extract(scan.points, section)
            t1 = time.perf_counter()
            k = len(out.frames)
            waiting[k] = (segments, T)
            decided = [k] if refiner is None else refiner.add_scan(segments_to_world(segments, T), T, float(scan.timestamp))
            if position == n - 1 and refiner is not None:       # the end of the drive: decide the rest
                decided += refiner.finish()
            t2 = time.perf_counter()
            link(decided)
            t3 = time.perf_counter()
            fused_s, features = np.nan, -1
            if k % every == every - 1 or position == n - 1:
                result = online.fused()
                fused_s, features = time.perf_counter() - t3, len(result)
            out.frames.append(frame)
            out.scans.append(segments)
            out.scan_seconds.append(t1 - t0)
            poses.append(T)
            stamps.append(float(scan.timestamp))
            rows.append((frame, len(segments), t1 - t0, t2 - t1, t3 - t2, fused_s, features))
            advance(1)
    if rows and (waiting or not np.isfinite(rows[-1][5])):   # the last scans were unreadable: the map of what was read
        t2 = time.perf_counter()
        decided = refiner.finish() if refiner is not None else []
        t3 = time.perf_counter()
        link(decided)
        t4 = time.perf_counter()
        result = online.fused()
        frame, count, extract_s, refine_s, link_s = rows[-1][:5]
        rows[-1] = (frame, count, extract_s, refine_s + t3 - t2, link_s + t4 - t3, time.perf_counter() - t4, len(result))
    columns = list(zip(*rows)) if rows else [()] * 7
    out.poses = np.array(poses) if poses else np.zeros((0, 4, 4))
    corrections = refiner.corrections if refiner is not None else np.zeros((len(out.frames), 3))
    refined = RefinementResult(corrections, apply_corrections(out.poses, corrections),
                               iterations=0 if refiner is None else refiner.solves,
                               matches=0 if refiner is None else refiner.matches,
                               stats=refiner.stats() if refiner is not None else {"applied": False})
    refine_s = np.array(columns[3], float)
    mapping = OnlineMapping(extraction=out, result=result, every=every,
                            frames=np.array(columns[0], np.int64), segments=np.array(columns[1], np.int64),
                            extract_s=np.array(columns[2], float), refine_s=refine_s, link_s=np.array(columns[4], float),
                            fused_s=np.array(columns[5], float), features=np.array(columns[6], np.int64),
                            refinement=RefinementRun(config.refinement.method, list(out.frames), out.poses, refined,
                                                     float(refine_s.sum()), out.slam_poses))
    # the extraction's time: reading and extracting, without the refinement, the linking and the maps
    out.seconds = time.perf_counter() - start - float(refine_s.sum() + mapping.link_s.sum() + np.nansum(mapping.fused_s))
    out.extracted_now = len(out.frames)
    out.timestamps = np.array(stamps, dtype=float)
    check_poses(source, out.frames, out.poses)          # (the span of the poses used, as offline)
    return mapping


def report_online(online: OnlineMapping, reporter: Reporter) -> None:
    """One line on what mapping online cost per scan."""
    if not len(online.frames):
        reporter.info("online: no scan could be mapped")
        return
    t = online.timings()
    refined = (f"pose correction {online.refine_s.sum() / len(online.frames) * 1e3:.1f} ms per scan on average "
               f"({online.refinement.method}), " if online.refinement.method != "none" else "")
    reporter.info(f"online: {len(online.frames)} scans one at a time: extraction {1e3 * t['online_extraction_per_scan_median']:.1f} ms "
                  f"(median), {refined}linking {1e3 * t['online_link_per_scan_median']:.2f} ms per scan (medians; linking at most "
                  f"{1e3 * t['online_link_per_scan_max']:.1f} ms), the map made {online.maps} time{'s' * (online.maps != 1)} "
                  f"(every {online.every} scans) in {1e3 * t['online_map_median']:.0f} ms (median; at most "
                  f"{1e3 * t['online_map_max']:.0f} ms); online.csv has each scan")
