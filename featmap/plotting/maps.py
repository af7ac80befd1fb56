"""Map-style drawings on a matplotlib ``ax`` (local metric frame, metres)."""

from __future__ import annotations

import numpy as np

from featmap.plotting.style import TRUTH_COLOR, draw_segments, method_color, method_label


def draw_feature_circles(ax, segments: np.ndarray, color="C0", numbers: bool = True, label: str | None = None,
                         start: int = 1) -> None:
    """The paper's feature circles (Figs. 2-3): centre = midpoint, diameter = length; numbered from ``start``."""
    from matplotlib.patches import Circle

    segments = np.asarray(segments, float).reshape(-1, 4)
    for k, seg in enumerate(segments):
        centre = 0.5 * (seg[:2] + seg[2:])
        radius = 0.5 * np.hypot(*(seg[2:] - seg[:2]))
        ax.add_patch(Circle(centre, radius, fill=False, ec=color, lw=1, alpha=0.8, label=label if k == 0 else None))
        ax.plot(*centre, ".", color=color, ms=3)
        if numbers:
            ax.annotate(str(start + k), centre, fontsize=8, color=color, ha="center", va="bottom")
    draw_segments(ax, segments, color, lw=2)


def draw_truth(ax, truth, label: str = "ground truth (building walls)") -> None:
    if truth is None:
        return
    draw_segments(ax, truth.walls, TRUTH_COLOR, lw=2.5, label=label, zorder=1, alpha=0.6)


def draw_method(ax, name: str, segments: np.ndarray, lw: float = 2.0, endpoints: bool = False, **kwargs) -> None:
    color = method_color(name)
    draw_segments(ax, segments, color, lw=lw, label=f"{method_label(name)} ({len(segments)})", zorder=3, **kwargs)
    if endpoints and len(segments):
        ends = np.asarray(segments).reshape(-1, 2)
        ax.plot(ends[:, 0], ends[:, 1], "o", color=color, ms=3, zorder=4)


def view_box(ax, centre: np.ndarray, half: float) -> None:
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)


def draw_walls_3d(ax, segments: np.ndarray, z_low: np.ndarray, z_high: np.ndarray, color, label=None) -> None:
    """Extrude (M, 4) segments into vertical quads between ``z_low`` and ``z_high`` (Fig. 9)."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    quads = []
    for seg, lo, hi in zip(np.asarray(segments).reshape(-1, 4), z_low, z_high):
        quads.append([(seg[0], seg[1], lo), (seg[2], seg[3], lo), (seg[2], seg[3], hi), (seg[0], seg[1], hi)])
    if quads:
        coll = Poly3DCollection(quads, facecolor=color, edgecolor="k", linewidths=0.3, alpha=0.55, label=label)
        ax.add_collection3d(coll)
