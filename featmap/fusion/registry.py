"""Registry of fusion methods by name, each with its own typed config section.

``fusion.<name>`` in the config holds a method's parameters; ``fusion.corners`` the corner
optimisation that runs identically after every method (as the paper does for its Table 2).
A new method is one entry here plus its config model in :mod:`featmap.config`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from featmap.config import FeatmapConfig
from featmap.errors import ConfigError
from featmap.fusion.base import FusionResult
from featmap.fusion.corners import optimise_corners
from featmap.fusion.density import fuse_density
from featmap.fusion.meanshift import fuse_meanshift
from featmap.fusion.proposed import fuse_proposed


@dataclass(frozen=True)
class FusionMethod:
    """A registered method: ``fuse(segments (N, 4), scan (N,), config, progress=None) -> FusionResult``.

    ``prepare()`` imports the method's heavy libraries and loads its compiled code, so that callers can
    keep that one-off cost out of fusion timings.
    """

    name: str
    title: str
    fuse: Callable[..., FusionResult]
    prepare: Callable[[], None] = lambda: None

    def config_of(self, config: FeatmapConfig):
        return getattr(config.fusion, self.name)


def _prepare_proposed() -> None:
    fuse_proposed(np.array([[0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 1.0, 0.0]]), np.array([0, 1]))


def _prepare_scikit_learn() -> None:
    import sklearn.cluster  # noqa: F401


FUSION_METHODS: dict[str, FusionMethod] = {
    "proposed": FusionMethod("proposed", "Proposed (three criteria)", fuse_proposed, _prepare_proposed),
    "meanshift": FusionMethod("meanshift", "Competing 1: mean shift (Lakaemper 2009)", fuse_meanshift,
                              _prepare_scikit_learn),
    "density": FusionMethod("density", "Competing 2: density clustering (Sarkar et al. 2014)", fuse_density,
                            _prepare_scikit_learn),
}


def get_method(name: str) -> FusionMethod:
    try:
        return FUSION_METHODS[name]
    except KeyError:
        raise ConfigError(f"unknown method '{name}'; allowed: {', '.join(FUSION_METHODS)} or all") from None


def resolve_methods(spec: str | list[str] | None) -> list[str]:
    """Turn ``--method`` values ("all", "proposed", "proposed,density", a list) into method names."""
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
                get_method(part)
                names.append(part)
    if not names:
        raise ConfigError(f"--method: no method given; allowed: {', '.join(FUSION_METHODS)} or all")
    return list(dict.fromkeys(names))


def prepare_method(name: str) -> None:
    """Import method ``name``'s libraries and load its compiled code (a one-off cost per process)."""
    get_method(name).prepare()


def fuse(name: str, segments, scan, config: FeatmapConfig = FeatmapConfig(),
         progress: Callable[[int, int], None] | None = None) -> FusionResult:
    """Run method ``name`` with its config section, then the shared corner optimisation.

    ``progress(done, total)`` is called now and then by long fusions (units are the method's own).
    """
    method = get_method(name)
    result = method.fuse(segments, scan, method.config_of(config), progress=progress)
    before = result.segments_before_corners
    return replace(result, segments=optimise_corners(before, config.fusion.corners))

