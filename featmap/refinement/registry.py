"""Registry of pose-refinement methods by name, each with its own typed config section.

``RefinementConfig`` (the ``refinement:`` section of a run's config) is derived from ``METHODS``: which
method runs (``method``), plus one section per method that has settings, plus ``drives`` (the rigid
alignment of a batch's drives before their merged map is fused, :mod:`featmap.refinement.drives`). A new method is one module
(its function, config section and a ``METHOD`` entry) plus one line in ``METHODS``.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field, create_model

from featmap.config import Section
from featmap.errors import ConfigError
from featmap.refinement import fixed_lag, pose_graph, scan_to_map
from featmap.refinement.base import RefinementInput, RefinementMethod, RefinementResult
from featmap.refinement.drives import DriveAlignmentConfig
from featmap.refinement.terms import AlignmentConfig, with_slam_prior


def _keep_poses(inp: RefinementInput, config: object = None) -> RefinementResult:
    """The ``none`` method: every correction is zero, the poses stay as given."""
    return RefinementResult(np.zeros((inp.n_scans, 3)), inp.poses.copy(), stats={"applied": False})


NONE = RefinementMethod(name="none", title="no refinement (poses as given)", config_type=None, refine=_keep_poses)
METHODS: tuple[RefinementMethod, ...] = (NONE, pose_graph.METHOD, scan_to_map.METHOD, fixed_lag.METHOD)
REFINEMENT_METHODS: dict[str, RefinementMethod] = {m.name: m for m in METHODS}
DEFAULT_METHOD = "pose_graph"

RefinementConfig = create_model(
    "RefinementConfig", __base__=Section,
    __doc__="Pose refinement before fusion: the method and the settings of each.",
    method=(Literal[tuple(REFINEMENT_METHODS)], Field(DEFAULT_METHOD, description="none, or how to refine the scans' poses before fusion")),
    **{m.name: (m.config_type, m.config_type()) for m in METHODS if m.config_type is not None},
    drives=(DriveAlignmentConfig, DriveAlignmentConfig()))


def get_refinement(name: str) -> RefinementMethod:
    try:
        return REFINEMENT_METHODS[name]
    except KeyError:
        raise ConfigError(f"refinement.method '{name}': unknown; allowed: {', '.join(REFINEMENT_METHODS)}") from None


def refine(inp: RefinementInput, config: RefinementConfig = RefinementConfig()) -> RefinementResult:  # type: ignore[valid-type]
    """Refine the poses of ``inp`` with the method ``config.method`` and its section of ``config``
    (with its ``slam_absolute_*`` priors when ``inp.slam_poses``)."""
    method = get_refinement(config.method)
    section = getattr(config, method.name) if method.config_type is not None else None
    if isinstance(section, AlignmentConfig):
        section = with_slam_prior(section, inp.slam_poses)
    return method.refine(inp, section)
