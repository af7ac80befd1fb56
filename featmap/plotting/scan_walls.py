"""One scan's extracted walls over a top view of its points, with the eye-checked list they are scored on."""

from __future__ import annotations

import numpy as np

from featmap.plotting.style import add_scalebar, draw_segments

STATUS_COLORS = {"wall": "#1f77b4", "optional": "#17becf", "clutter": "#d62728", "unlisted": "#9467bd"}


def draw_scan_points(ax, points: np.ndarray) -> None:
    """A top view of (N, >=3) velodyne-frame points: those more than 0.3 m above the scan's 5th height
    percentile darker (a rough ground split, for the eye only)."""
    xyz = np.asarray(points, float)[:, :3]
    floor = np.percentile(xyz[:, 2], 5) if len(xyz) else 0.0
    low = xyz[:, 2] < floor + 0.3
    ax.scatter(xyz[low, 0], xyz[low, 1], s=0.05, c="0.85", lw=0, rasterized=True)
    ax.scatter(xyz[~low, 0], xyz[~low, 1], s=0.15, c="0.45", lw=0, rasterized=True)


def plot_scan_walls(ax, points: np.ndarray, segments: np.ndarray, wall_list, score, view: tuple[float, float, float, float] | None = None) -> None:
    """Draw a scan and its walls on ``ax``.

    Args:
        points: (N, >=3) velodyne-frame points; returns more than 0.3 m above the scan's 5th height
            percentile are drawn darker (a rough ground split, for the eye only).
        segments: (K, 4) extracted segments (velodyne frame), coloured by ``score.status``.
        wall_list: a :class:`featmap.evaluation.wall_lists.ScanWallList`: the scan's listed walls (found: green, missed: red, optional: dashed grey) and
            clutter boxes (orange).
        score: its :class:`featmap.evaluation.wall_lists.WallListScore` against ``segments``.
        view: x_min, x_max, y_min, y_max; default: the listed structure and segments plus a margin.
    """
    from matplotlib.patches import Rectangle

    draw_scan_points(ax, points)
    for (x0, x1, y0, y1) in wall_list.clutter:
        ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ec="#ff7f0e", lw=0.8, ls=":"))
    if wall_list.optional:
        draw_segments(ax, np.array([w.segment for w in wall_list.optional]), "0.55", lw=3, alpha=0.5, linestyles="--")
    if wall_list.walls:
        colors = ["#2ca02c" if f else "#d62728" for f in score.found]
        draw_segments(ax, np.array([w.segment for w in wall_list.walls]), colors, lw=6, alpha=0.35)
    segments = np.asarray(segments, float).reshape(-1, 4)
    if len(segments):
        draw_segments(ax, segments, [STATUS_COLORS.get(s, "k") for s in score.status], lw=1.4)
        ends = segments.reshape(-1, 2)
        ax.plot(ends[:, 0], ends[:, 1], "|", color="k", ms=3, mew=0.6)
    listed = [w.segment for w in wall_list.walls + wall_list.optional]
    finish_scan_view(ax, view, np.concatenate([np.array(listed).reshape(-1, 2), segments.reshape(-1, 2)]))


def finish_scan_view(ax, view: tuple[float, float, float, float] | None, extent: np.ndarray) -> None:
    """The sensor at the origin, the ``view`` (x_min, x_max, y_min, y_max; None: the (K, 2) points ``extent``
    and the sensor, plus 5 m), equal axes in metres of the velodyne frame and a scale bar."""
    ax.plot(0, 0, marker=(3, 0, -90), color="k", ms=7)
    if view is None:
        pts = np.concatenate([np.asarray(extent, float).reshape(-1, 2), [[0.0, 0.0]]])
        lo, hi = pts.min(0) - 5, pts.max(0) + 5
        view = (lo[0], hi[0], lo[1], hi[1])
    ax.set_xlim(view[0], view[1])
    ax.set_ylim(view[2], view[3])
    ax.set_aspect("equal")
    ax.set_xlabel("x (m, velodyne frame)")
    ax.set_ylabel("y (m)")
    add_scalebar(ax)
