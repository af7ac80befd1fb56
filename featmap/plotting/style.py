"""Colours, labels and small decorations shared by every figure and map.

Methods are drawn in the colour, line style and title of their entry in the fusion registry
(:data:`featmap.fusion.METHODS`); the other layers use the colours below.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from featmap.fusion import FUSION_METHODS
from featmap.io.atomic import atomic_path

TRUTH_COLOR = "#595959"
SEGMENT_COLOR = "#ff7f0e"
TRAJECTORY_COLOR = "#e377c2"
OTHER_COLOR = "#9467bd"
DPI = 100


def method_color(name: str) -> str:
    method = FUSION_METHODS.get(name)
    return method.color if method else OTHER_COLOR


def method_label(name: str) -> str:
    method = FUSION_METHODS.get(name)
    return method.title if method else name


def method_linestyle(name: str) -> str:
    method = FUSION_METHODS.get(name)
    return method.linestyle if method else "-"


def save_png(fig, path: str | Path, dpi: int = DPI) -> Path:
    """Save a matplotlib figure as PNG atomically and close it."""
    import matplotlib.pyplot as plt

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    plt.close(fig)
    return Path(path)


def new_figure(nrows: int = 1, ncols: int = 1, size=(10, 8), **kwargs):
    """A figure on the non-interactive Agg backend: ``(fig, axes)`` as ``plt.subplots`` returns them."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt.subplots(nrows, ncols, figsize=size, **kwargs)


def draw_segments(ax, segments: np.ndarray, color, lw: float = 1.5, label: str | None = None, **kwargs):
    """Draw (M, 4) segments as one LineCollection; returns it."""
    from matplotlib.collections import LineCollection

    segments = np.asarray(segments, float).reshape(-1, 4)
    lc = LineCollection(segments.reshape(-1, 2, 2), colors=color, linewidths=lw, label=label, **kwargs)
    ax.add_collection(lc)
    return lc


def add_scalebar(ax, length_m: float | None = None, loc: str = "lower right") -> None:
    """A labelled scale bar (metres) sized to about a fifth of the view."""
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

    if length_m is None:
        width = abs(ax.get_xlim()[1] - ax.get_xlim()[0])
        raw = width / 5
        exp = 10 ** np.floor(np.log10(raw))
        length_m = float(min((1, 2, 5, 10), key=lambda m: abs(m * exp - raw)) * exp)
    label = f"{length_m:g} m" if length_m >= 1 else f"{100 * length_m:g} cm"
    bar = AnchoredSizeBar(ax.transData, length_m, label, loc, pad=0.4, sep=4, frameon=True, size_vertical=0)
    bar.patch.set_alpha(0.8)
    ax.add_artist(bar)


def finish_map_axes(ax, title: str, legend: bool = True, scalebar: bool = True) -> None:
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x east [m]")
    ax.set_ylabel("y north [m]")
    ax.set_title(title)
    if legend:
        handles, labels = ax.get_legend_handles_labels()
        if handles:
            ax.legend(loc="best", fontsize=8, framealpha=0.85)
    if scalebar:
        add_scalebar(ax)
