"""One scan's pieces over a top view of its points, each coloured by the first test it failed
(``featmap explain --plot``)."""

from __future__ import annotations

import numpy as np

from featmap.plotting.scan_walls import draw_scan_points, finish_scan_view
from featmap.plotting.style import draw_segments

WALL_COLOR = "k"


def plot_explanation(ax, points: np.ndarray, explanation, view: tuple[float, float, float, float] | None = None) -> None:
    """Draw a scan, the pieces its extraction dropped and the walls it kept on ``ax`` (velodyne frame).

    Args:
        points: (N, >=3) velodyne-frame points (grey; darker above a rough ground).
        explanation: a :class:`featmap.extraction.explain.ScanExplanation` of them. A piece dropped at the
            height stage is a thin solid line, one dropped at the final stage a dashed one, each in the colour
            of the first test it failed (the legend names them); the walls are thick and black.
        view: x_min, x_max, y_min, y_max; default: every piece and the sensor plus 5 m.
    """
    import matplotlib

    draw_scan_points(ax, points)
    palette = matplotlib.colormaps["tab20"]
    names = [f"{stage}: {test}" for stage, tests in explanation.stages.items() for test in tests.passed]
    drawn = []
    for stage, tests in explanation.stages.items():
        segments = explanation.segments(stage)
        drawn.append(segments)
        first = np.array([(tests.failed(k) or [""])[0] for k in range(len(segments))])
        for test in tests.passed:
            sel = first == test
            if sel.any():
                color = palette(names.index(f"{stage}: {test}") % palette.N)
                draw_segments(ax, segments[sel], color, lw=1.0 if stage == "height" else 1.4,
                              linestyles="-" if stage == "height" else "--", label=f"{stage}: {test} ({int(sel.sum())})")
    walls = explanation.result.segments
    draw_segments(ax, walls, WALL_COLOR, lw=2.2, label=f"walls ({len(walls)})")
    ax.legend(loc="upper left", fontsize=6, title="first test failed (pieces in the scan)", title_fontsize=6)
    finish_scan_view(ax, view, np.concatenate([s.reshape(-1, 2) for s in drawn] + [walls.reshape(-1, 2)]))
