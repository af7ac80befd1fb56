"""Online mapping (``featmap run --online N``): each scan is extracted, moved to the world frame with the
source's pose and linked into the map as it comes; the fused map is made every ``N`` scans.

This is how a vehicle would run featmap while it drives: scans in order, one at a time, no look-ahead and
no segment cache (every scan is extracted now, so its time is the real cost). Pose refinement needs the
whole drive and is not done: the source's poses are used as they are. The fusion is
:class:`featmap.fusion.online.OnlineFusion` (the proposed method): the last map is the one ``featmap run
--method proposed --set refinement.method=none`` makes of the same scans. :func:`map_online` returns the
per-scan times (extraction, linking, and making the map where it was made) beside the usual extraction
record, so that the run folder and its scores are those of any run.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from featmap.datasets.base import ScanSource
from featmap.errors import ConfigError, DatasetError
from featmap.extraction import extractor_for, segments_to_world, world_fields
from featmap.fusion import FusionResult
from featmap.fusion.online import OnlineFusion
from featmap.pipeline.config import FeatmapConfig
from featmap.pipeline.extract import Extraction, check_poses
from featmap.reporting import NullReporter, Reporter

ONLINE_METHODS = ("proposed",)
"""The methods that can fuse one scan at a time (mean shift and density cluster all segments at once)."""


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

    def csv_text(self) -> str:
        """``online.csv``: ``frame,segments,extract_ms,link_ms,fused_ms,features`` per scan (the last two
        empty where the map was not made)."""
        lines = ["frame,segments,extract_ms,link_ms,fused_ms,features"]
        for f, n, e, ln, m, k in zip(self.frames, self.segments, self.extract_s, self.link_s, self.fused_s,
                                     self.features):
            made = np.isfinite(m)
            lines.append(f"{f},{n},{1e3 * e:.3f},{1e3 * ln:.3f},{f'{1e3 * m:.3f}' if made else ''},"
                         f"{k if made else ''}")
        return "\n".join(lines) + "\n"

    def timings(self) -> dict[str, float]:
        """Medians and maxima (seconds) for metrics.json's ``timings_s``."""
        made = self.fused_s[np.isfinite(self.fused_s)]

        def stat(values, f):
            return round(float(f(values)), 5) if len(values) else 0.0

        return {"online_extraction_per_scan_median": stat(self.extract_s, np.median),
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
                          f"{', '.join(other)} (they cluster all segments at once): use --method proposed")
    if config.refinement.method != "none":
        raise ConfigError(f"--online uses the source's poses as they come, but refinement.method is "
                          f"'{config.refinement.method}' (it needs the whole drive): add --set refinement.method=none")


def map_online(source: ScanSource, config: FeatmapConfig, every: int, reporter: Reporter = NullReporter(),
               skip_bad_scans: bool = False) -> OnlineMapping:
    """Extract and fuse ``source`` one scan at a time (see the module docstring).

    Raises:
        DatasetError: an unreadable scan (unless ``skip_bad_scans``: then it is left out and listed), or
            poses that are not finite.
    """
    extractor = extractor_for(source.dimension, config.extraction)
    section = getattr(config.extraction, extractor.name)
    all_poses = source.poses()
    check_poses(source, list(source.frames), all_poses)
    online = OnlineFusion(config.fusion)
    out = Extraction(frames=[], scans=[], poses=np.zeros((0, 4, 4)), dimension=source.dimension,
                     slam_poses=bool(getattr(source, "slam_poses", False)))
    stamps, poses, rows = [], [], []
    result = online.fused()
    n = len(source.frames)
    start = time.perf_counter()
    with reporter.progress(f"mapping {source.name} online", n) as advance:
        for position, frame in enumerate(source.frames):
            try:
                scan = source[position]
            except DatasetError as exc:
                if not skip_bad_scans:
                    raise DatasetError(f"{exc} (use --skip-bad-scans to leave it out)") from None
                out.skipped[frame] = str(exc)
                advance(1)
                continue
            t0 = time.perf_counter()
            segments = extractor.extract(scan.points, section)
            t1 = time.perf_counter()
            T = all_poses[position]
            online.add_scan(segments_to_world(segments, T), world_fields(segments, T)["rms"])
            t2 = time.perf_counter()
            fused_s, features = np.nan, -1
            if len(out.frames) % every == every - 1 or position == n - 1:
                result = online.fused()
                fused_s, features = time.perf_counter() - t2, len(result)
            out.frames.append(frame)
            out.scans.append(segments)
            out.scan_seconds.append(t1 - t0)
            poses.append(T)
            stamps.append(float(scan.timestamp))
            rows.append((frame, len(segments), t1 - t0, t2 - t1, fused_s, features))
            advance(1)
    if rows and not np.isfinite(rows[-1][4]):          # the last scans were unreadable: the map of what was read
        t2 = time.perf_counter()
        result = online.fused()
        rows[-1] = rows[-1][:4] + (time.perf_counter() - t2, len(result))
    out.seconds = time.perf_counter() - start
    out.extracted_now = len(out.frames)
    out.poses = np.array(poses) if poses else np.zeros((0, 4, 4))
    out.timestamps = np.array(stamps, dtype=float)
    columns = list(zip(*rows)) if rows else [()] * 6
    return OnlineMapping(extraction=out, result=result, every=every,
                         frames=np.array(columns[0], np.int64), segments=np.array(columns[1], np.int64),
                         extract_s=np.array(columns[2], float), link_s=np.array(columns[3], float),
                         fused_s=np.array(columns[4], float), features=np.array(columns[5], np.int64))


def report_online(online: OnlineMapping, reporter: Reporter) -> None:
    """One line on what mapping online cost per scan."""
    t = online.timings()
    made = int(np.isfinite(online.fused_s).sum())
    reporter.info(f"online: {len(online.frames)} scans one at a time: extraction {1e3 * t['online_extraction_per_scan_median']:.1f} ms "
                  f"and linking {1e3 * t['online_link_per_scan_median']:.2f} ms per scan (medians; linking at most "
                  f"{1e3 * t['online_link_per_scan_max']:.1f} ms), the map made {made} times (every {online.every} scans) in "
                  f"{1e3 * t['online_map_median']:.0f} ms (median; at most {1e3 * t['online_map_max']:.0f} ms); online.csv has each scan")
