"""A named, styled set of segments: what the map writers (KML, HTML) draw, one folder or layer each."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class MapLayer:
    """Segments to draw as one layer.

    Attributes:
        name: layer (folder) name, e.g. a method name, ``segments``, ``truth``.
        segments: (M, 4) local-frame segments, metres.
        support: (M,) member counts shown in popups, or None (e.g. for raw segments or ground truth).
        color: ``#rrggbb``.
        width: line width in pixels.
        show: visible when the map opens (HTML).
    """

    name: str
    segments: np.ndarray
    support: np.ndarray | None
    color: str
    width: float = 2.0
    show: bool = True
