"""The overview plot every run writes: fused features of every method over map tiles (or the truth)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from featmap.geo import GeoFrame
from featmap.io.atomic import atomic_path
from featmap.plotting.basemap import BasemapWarning, add_basemap
from featmap.plotting.maps import draw_truth
from featmap.plotting.style import draw_segments, finish_map_axes, method_color, method_label


def overview_plot(path: str | Path, layers: dict, frame: GeoFrame, trajectory: np.ndarray, truth, output_config,
                  size=(12, 12)) -> Path:
    """PNG of every method's fused features over tiles; without tiles, over the ground truth, with a warning."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=size)
    pts = [np.asarray(s).reshape(-1, 2) for s, _ in layers.values() if len(s)] + [np.asarray(trajectory)]
    pts = np.concatenate(pts)
    lo, hi = pts.min(0) - 10, pts.max(0) + 10
    centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo).max()
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", BasemapWarning)
        ok = add_basemap(ax, frame, output_config.tile_source, output_config.tile_cache_dir, output_config.tile_timeout_s)
    for w in caught:
        warnings.warn(str(w.message), BasemapWarning, stacklevel=2)
    if not ok:
        draw_truth(ax, truth)
    styles = {"proposed": "-", "meanshift": "--", "density": ":"}
    for name, (segments, _) in layers.items():
        draw_segments(ax, segments, method_color(name), lw=2, linestyles=styles.get(name, "-"),
                      label=f"{method_label(name)} ({len(segments)})", zorder=3)
    ax.plot(*np.asarray(trajectory).T, "-", color="m", lw=1, label="trajectory")
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    finish_map_axes(ax, "fused features" + (" over map tiles" if ok else " (no tiles: over ground truth)" if truth is not None else " (no tiles)"))
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)
    return Path(path)
