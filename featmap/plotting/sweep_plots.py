"""Plots of a sweep: heatmaps over delta x gamma, curves per swept key, and a Pareto plot."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from featmap.io.atomic import atomic_file_set
from featmap.plotting.style import method_color, method_label, new_figure, save_png

PLOT_NAMES = ("heatmap_delta_gamma.png", "curves.png", "pareto.png")
"""Every plot a sweep may write. Which of them it writes depends on its grid and rows; one it did not
write this time is another sweep's into the same folder, and is removed (nothing else is)."""


def pareto_front(points: np.ndarray) -> np.ndarray:
    """Indices of the non-dominated points of (K, 2) ``(cost, benefit)``: lower cost, higher benefit."""
    order = np.lexsort((-points[:, 1], points[:, 0]))
    front, best = [], -np.inf
    for i in order:
        if points[i, 1] > best:
            front.append(i)
            best = points[i, 1]
    return np.asarray(front, dtype=int)


def _mean_table(rows, x_key, y_key, value):
    xs = sorted({r[x_key] for r in rows})
    ys = sorted({r[y_key] for r in rows})
    grid = np.full((len(ys), len(xs)), np.nan)
    for i, y in enumerate(ys):
        for j, x in enumerate(xs):
            vals = [r[value] for r in rows if r[x_key] == x and r[y_key] == y and r.get(value) is not None]
            if vals:
                grid[i, j] = np.mean(vals)
    return xs, ys, grid


def plot_sweep(rows: list[dict], keys: list[str], out: Path, metric: str) -> list[Path]:
    """Heatmap over delta x gamma, a curve per swept key and the Pareto plot, as PNGs in ``out``.

    Afterwards ``out`` holds the plots of these rows only: a plot of ``PLOT_NAMES`` not drawn for them (a
    previous sweep's, e.g. the heatmap of a grid that swept delta and gamma) is removed. The plots are drawn
    into a hidden staging folder inside ``out`` and moved in together at the end (``atomic_file_set``): an
    error or Ctrl-C while drawing leaves ``out`` with the earlier plots whole. Returns their paths in ``out``.
    """
    out = Path(out)
    with atomic_file_set(out, PLOT_NAMES) as stage:
        paths = draw_sweep_plots(rows, keys, stage, metric)
    return [out / p.name for p in paths]


def draw_sweep_plots(rows: list[dict], keys: list[str], out: Path, metric: str) -> list[Path]:
    """The plots of ``plot_sweep`` (those of ``PLOT_NAMES`` these rows make), written into ``out`` as they are
    drawn: a staging folder of ``atomic_file_set``, which removes the earlier ones these rows do not make."""
    paths = []
    proposed = [r for r in rows if r["method"] == "proposed"]
    dkey, gkey = "fusion.proposed.delta_deg", "fusion.proposed.gamma"
    if proposed and dkey in keys and gkey in keys:
        fig, axes = new_figure(1, 2, size=(13, 5.5))
        for ax, value in zip(axes, ("count", metric)):
            xs, ys, grid = _mean_table(proposed, dkey, gkey, value)
            im = ax.imshow(grid, origin="lower", aspect="auto", cmap="viridis")
            ax.set_xticks(range(len(xs)), [f"{x:g}" for x in xs])
            ax.set_yticks(range(len(ys)), [f"{y:g}" for y in ys])
            ax.set_xlabel("delta [deg]")
            ax.set_ylabel("gamma [-]")
            ax.set_title(f"proposed: {value} (mean over other swept keys)")
            fig.colorbar(im, ax=ax, label=value)
            for i in range(len(ys)):
                for j in range(len(xs)):
                    if np.isfinite(grid[i, j]):
                        ax.text(j, i, f"{grid[i, j]:.3g}", ha="center", va="center", fontsize=7, color="w")
        fig.tight_layout()
        save_png(fig, out / "heatmap_delta_gamma.png")
        paths.append(out / "heatmap_delta_gamma.png")
    curve_keys = [k for k in keys if len({r.get(k) for r in rows if k in r}) >= 2]
    if curve_keys:
        fig, axes = new_figure(len(curve_keys), 2, size=(12, 3.6 * len(curve_keys)), squeeze=False)
        methods = {r["method"] for r in rows}
        for row_axes, key in zip(axes, curve_keys):
            method = key.split(".")[1]
            shared = method not in methods                   # e.g. fusion.refine.*, fusion.corners.*: every method
            for ax, value in zip(row_axes, ("count", metric)):
                positions, ys, labels = curve(rows, key, value)
                ax.plot(positions, ys, "o-", color="0.3" if shared else method_color(method),
                        label="all methods" if shared else method_label(method))
                if labels is not None:
                    ax.set_xticks(positions, labels)
                ax.set_xlabel(key)
                ax.set_ylabel(value)
                ax.grid(True, alpha=0.3)
                ax.legend(fontsize=8)
            row_axes[0].set_title(f"{key}: count (mean over other keys)")
            row_axes[1].set_title(f"{key}: {metric}")
        fig.tight_layout()
        save_png(fig, out / "curves.png")
        paths.append(out / "curves.png")
    # Conciseness: fused features per observable wall against a ground truth, else the feature count.
    cost = "count_ratio" if any(r.get("count_ratio") is not None for r in rows) else "count"
    scored = [r for r in rows if r.get(cost) is not None and r.get("f1") is not None]
    if scored:
        fig, ax = new_figure(size=(9, 7))
        pts = np.array([[r[cost], r["f1"]] for r in scored], float)
        for method in sorted({r["method"] for r in scored}):
            m = np.array([r["method"] == method for r in scored])
            ax.scatter(pts[m, 0], pts[m, 1], color=method_color(method), label=method_label(method), alpha=0.7)
        front = pareto_front(pts)
        ax.plot(pts[front, 0], pts[front, 1], "k--", lw=1, label="Pareto front")
        if cost == "count_ratio":
            ax.axvline(1.0, color="0.6", lw=0.8)
            ax.set_xlabel("count_ratio = fused features / observable walls (conciseness; 1 is ideal)")
        else:
            ax.set_xlabel("fused features (conciseness; scored against the scans' own points)")
        ax.set_ylabel("F1 of precision and recall (accuracy)")
        ax.set_title("Conciseness against accuracy across all methods and settings")
        ax.grid(True, alpha=0.3)
        ax.legend()
        save_png(fig, out / "pareto.png")
        paths.append(out / "pareto.png")
    return paths


def curve(rows: list[dict], key: str, value: str) -> tuple[list, list[float], list[str] | None]:
    """(x positions, mean ``value`` at each, tick labels or None) of a swept ``key`` over the rows of the
    method it belongs to (``fusion.<method>.*``), or of every method for a shared section's key."""
    method = key.split(".")[1]
    shared = method not in {r["method"] for r in rows}
    sub = [r for r in rows if key in r and (shared or r["method"] == method)]
    xs, positions, labels = _curve_axis([r[key] for r in sub])
    ys = [float(np.mean([r[value] for r in sub if r[key] == x and r.get(value) is not None] or [np.nan])) for x in xs]
    return positions, ys, labels


def _curve_axis(values: list) -> tuple[list, list, list[str] | None]:
    """(distinct values in order, their x positions, tick labels or None) of a swept key: numbers on a
    numeric axis; anything else (null, true/false, names) as evenly spaced categories."""
    distinct = list(dict.fromkeys(values))
    if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in distinct):
        xs = sorted(distinct)
        return xs, xs, None
    xs = sorted(distinct, key=lambda v: (v is not None, type(v).__name__, str(v)))
    return xs, list(range(len(xs))), ["null" if v is None else str(v) for v in xs]
