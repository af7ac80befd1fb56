"""The overview plot every run writes: fused features of every method over map tiles (or the truth)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from featmap.geo import GeoFrame
from featmap.plotting.basemap import BasemapWarning, Tiles, add_basemap
from featmap.plotting.maps import draw_truth
from featmap.plotting.style import (TRAJECTORY_COLOR, draw_segments, finish_map_axes, method_color, method_label,
                                    method_linestyle, new_figure, save_png)


def overview_plot(path: str | Path, layers: dict[str, np.ndarray], frame: GeoFrame | None, trajectory: np.ndarray,
                  truth=None, tiles: Tiles | None = Tiles(), size=(12, 12)) -> Path:
    """PNG of every method's fused features (name -> (M, 4) local frame) over map tiles.

    Without tiles (no geo origin, ``tiles=None``, or unreachable: a BasemapWarning), the features are
    drawn over the ground truth when there is one.
    """
    fig, ax = new_figure(size=size)
    pts = [np.asarray(s).reshape(-1, 2) for s in layers.values() if len(s)] + [np.asarray(trajectory).reshape(-1, 2)]
    pts = np.concatenate(pts) if sum(len(p) for p in pts) else np.zeros((1, 2))
    lo, hi = pts.min(0) - 10, pts.max(0) + 10
    centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo).max()
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ok = False
    if frame is not None and tiles is not None:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", BasemapWarning)
            ok = add_basemap(ax, frame, tiles)
        for w in caught:                # (each with its own category: not every warning is the basemap's)
            warnings.warn(str(w.message), w.category, stacklevel=2)
    if not ok:
        draw_truth(ax, truth)
    for name, segments in layers.items():
        draw_segments(ax, segments, method_color(name), lw=2, linestyles=method_linestyle(name),
                      label=f"{method_label(name)} ({len(segments)})", zorder=3)
    if len(trajectory):
        ax.plot(*np.asarray(trajectory).T, "-", color=TRAJECTORY_COLOR, lw=1, label="trajectory")
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    suffix = " over map tiles" if ok else " (no tiles: over ground truth)" if truth is not None else ""
    finish_map_axes(ax, "fused features" + suffix)
    return save_png(fig, path)
