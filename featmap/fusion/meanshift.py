"""Competing algorithm 1 (the paper's Section 2.1, after Lakaemper 2009): sequential mean shift.

1. Mean shift on segment orientations (pi-periodic, embedded on a circle so 179 deg meets -1 deg).
2. Within each orientation cluster, mean shift on segment centres (2D, world frame).
3. Each cluster is merged by projecting its segments onto a representative segment in the middle
   of the cluster: the line through the mean centre at the mean orientation.

No support filter: every cluster, however small, becomes a fused feature. This is the method the
paper criticises: orientation is clustered before space, and a large centre bandwidth lets features
of different walls share a cluster.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from pydantic import Field

from featmap.config import Section
from featmap.fusion.base import (TINY_INPUT, FusionMethod, FusionResult, cluster_orientations, finish_clusters, mean_shift,
                                 merge_onto_mean_line, validate_input)
from featmap.geometry import segment_midpoints, segment_orientations


class MeanShiftConfig(Section):
    """Competing algorithm 1 (after Lakaemper 2009): mean shift on orientation, then on centres."""

    orientation_bandwidth_deg: float = Field(3.0, gt=0, le=90, description="mean-shift bandwidth on orientation")
    center_bandwidth_m: float = Field(3.0, gt=0, description="mean-shift bandwidth on segment centres")


def fuse_meanshift(segments, scan, config: MeanShiftConfig = MeanShiftConfig(),
                   progress: Callable[[int, int], None] | None = None) -> FusionResult:
    """Fuse (N, 4) world-frame segments; ``scan`` (N,) is accepted for a common signature but unused.

    ``progress(done, total)`` is called after each orientation cluster's centre mean shift.
    """
    segments, scan, valid = validate_input(segments, scan)
    seg = segments[valid]
    groups = np.zeros(len(seg), dtype=np.int64)
    if len(seg):
        orient = cluster_orientations(segment_orientations(seg), np.deg2rad(config.orientation_bandwidth_deg))
        centres = segment_midpoints(seg)
        next_id = 0
        clusters = np.unique(orient)
        for done, o in enumerate(clusters, start=1):
            members = np.flatnonzero(orient == o)
            sub = mean_shift(centres[members], config.center_bandwidth_m)
            groups[members] = next_id + sub
            next_id += int(sub.max()) + 1
            if progress is not None:
                progress(done, len(clusters))
    return finish_clusters(segments, scan, valid, groups, merge_onto_mean_line)


METHOD = FusionMethod(name="meanshift", title="Competing 1: mean shift (Lakaemper 2009)", color="#1f77b4",
                      linestyle="--", config_type=MeanShiftConfig, fuse=fuse_meanshift,
                      prepare=lambda: fuse_meanshift(*TINY_INPUT))
