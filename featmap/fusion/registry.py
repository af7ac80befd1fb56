"""Registry of fusion methods by name, each with its own typed config section.

``METHODS`` is the one table of methods: name, title, colour and line style for figures, config
section and function. ``FusionConfig`` (the ``fusion:`` section of a run's config) is derived from it:
one section per method, plus ``refine`` (the clean-up) and ``corners`` (the corner optimisation) that run
identically after every method (as the paper does for its Table 2).

A new method is one module (its function, its config section and a ``METHOD`` entry) plus one line in
``METHODS`` below.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable, Mapping

import numpy as np
from pydantic import create_model

from featmap.config import Section
from featmap.errors import ConfigError
from featmap.fusion import density, meanshift, proposed
from featmap.fusion.base import FusionMethod, FusionResult, SupportRule, SupportViews
from featmap.fusion.close_pairs import prepare as prepare_close_pairs
from featmap.fusion.corners import CornerConfig, optimise_corners
from featmap.fusion.refine import RefineConfig, refine
from featmap.fusion.visibility import sensor_xy_column
from featmap.geometry import as_segments

METHODS: tuple[FusionMethod, ...] = (proposed.METHOD, meanshift.METHOD, density.METHOD)
FUSION_METHODS: dict[str, FusionMethod] = {m.name: m for m in METHODS}

FusionConfig = create_model(
    "FusionConfig", __base__=Section, __doc__="Fusion: one section per method, and the shared clean-up and corner optimisation.",
    **{m.name: (m.config_type, m.config_type()) for m in METHODS}, refine=(RefineConfig, RefineConfig()),
    corners=(CornerConfig, CornerConfig()))


def get_method(name: str) -> FusionMethod:
    try:
        return FUSION_METHODS[name]
    except KeyError:
        raise ConfigError(f"unknown method '{name}'; allowed: {', '.join(FUSION_METHODS)} or all") from None


def resolve_methods(spec: str | list[str] | None, flag: str = "--method") -> list[str]:
    """Turn ``--method`` values ("all", "proposed", "proposed,density", a list) into method names; errors
    name ``flag`` (where the values came from)."""
    if spec is None:
        return list(FUSION_METHODS)
    items = [spec] if isinstance(spec, str) else list(spec)
    names: list[str] = []
    for item in items:
        for part in str(item).split(","):
            part = part.strip()
            if not part:
                continue
            if part == "all":
                names.extend(FUSION_METHODS)
            else:
                try:
                    get_method(part)
                except ConfigError as exc:
                    raise ConfigError(f"{flag}: {exc}") from None
                names.append(part)
    if not names:
        raise ConfigError(f"{flag}: no method given; allowed: {', '.join(FUSION_METHODS)} or all")
    return list(dict.fromkeys(names))


def working_origin(segments: np.ndarray) -> np.ndarray:
    """(2,) a whole-kilometre point near the segments' median midpoint.

    Methods work on coordinates relative to it, so a map far from its frame's origin (UTM northings,
    1e6-1e9 m) is fused like the same map near 0: the result does not depend on a global translation, and
    numerical libraries (scikit-learn's mean shift) see small numbers. Subtracting a whole number of
    kilometres is exact in floating point, and a map within 500 m of its origin is not moved at all.
    """
    if len(segments) == 0:
        return np.zeros(2)
    mid = 0.5 * (segments[:, :2] + segments[:, 2:])
    return np.round(np.median(mid, axis=0), -3)


def prepare_method(name: str) -> None:
    """Import method ``name``'s libraries and load its compiled code and the shared refinement's (a one-off
    cost per process)."""
    get_method(name).prepare()
    prepare_close_pairs()


def fuse(name: str, segments, scan, config: FusionConfig = FusionConfig(),  # type: ignore[valid-type]
         progress: Callable[[int, int], None] | None = None,
         rms: np.ndarray | None = None, max_gap: np.ndarray | None = None,
         sensor_xy: np.ndarray | None = None) -> FusionResult:
    """Run method ``name`` with its section of ``config`` (the ``fusion:`` section), then the shared
    refinement (``fusion.refine``: consistent clusters, gap splitting) and corner optimisation.

    Args:
        segments: (N, 4) world-frame segments ``x1, y1, x2, y2`` (metres).
        scan: (N,) scan index of each segment.
        progress: called as ``progress(done, total)`` now and then by long fusions (the method's own units).
        rms: (N,) each segment's fit rms from the extraction (metres; the ``rms`` column of segments.csv),
            or None; a support rule with a clean-view clause needs it (without it no view is clean).
        max_gap: (N,) each segment's longest stretch between consecutive returns (metres; the ``max_gap``
            column), or None; ``fusion.refine.resolved_gap_m`` needs it (without it that split is off).
        sensor_xy: (N, 2) where the sensor stood when each segment's scan was taken (world frame, metres;
            the ``sensor_x`` / ``sensor_y`` columns, :func:`featmap.fusion.visibility.sensor_xy_column`), or
            None; a support rule with a visibility clause (``visible_share``) needs it.
    """
    method = get_method(name)
    segments = as_segments(segments)
    origin = working_origin(segments[np.isfinite(segments).all(axis=1)])
    shift = np.tile(origin, 2)
    section = getattr(config, name)
    if method.support_rule is None:
        rule, views = SupportRule(), SupportViews()
        result = method.fuse(segments - shift, scan, section, progress=progress)
    else:
        rule = method.support_rule(section)
        views = rule.views(segments, rms, max_gap, sensor_xy).moved(origin)
        result = method.fuse(segments - shift, scan, section, progress=progress, views=views)
    return finish_fusion(result, segments, scan, origin, config, rule, views, max_gap)


def fuse_columns(columns: Mapping[str, np.ndarray], n_segments: int) -> dict:
    """The keyword arguments of :func:`fuse` that N segments' per-segment columns give (a segment table's
    ``extra``, segments.csv's columns): ``rms``, ``max_gap`` and ``sensor_xy`` (from ``sensor_x`` /
    ``sensor_y``), each None when absent."""
    return {"rms": columns.get("rms"), "max_gap": columns.get("max_gap"),
            "sensor_xy": sensor_xy_column(columns, n_segments)}


def finish_fusion(result: FusionResult, segments: np.ndarray, scan, origin: np.ndarray,
                  config: FusionConfig = FusionConfig(),  # type: ignore[valid-type]
                  rule: SupportRule = SupportRule(), views: SupportViews = SupportViews(),
                  max_gap: np.ndarray | None = None) -> FusionResult:
    """What runs after every method: the shared refinement and corner optimisation, then back from the
    working frame (``origin`` (2,) subtracted, see :func:`working_origin`) to the frame of ``segments``
    ((N, 4), the method's input before the shift; ``result`` was fused from ``segments - origin``);
    ``max_gap`` (N,) or None as for :func:`fuse`; ``views``: the rule's clean and coarse views of the N."""
    shift = np.tile(origin, 2)
    result = refine(result, segments - shift, scan, config.refine, rule, views, max_gap)
    before = result.segments_before_corners
    after = optimise_corners(before, config.corners)
    if not origin.any():
        return replace(result, segments=after)
    return replace(result, segments=after + shift, segments_before_corners=before + shift)
