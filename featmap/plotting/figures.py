"""The paper's figures from one run (``featmap figures RUN_DIR``); its Tables 1-3 are ``featmap compare``.

Fig. 2-3 feature circles; Fig. 6 fusion of one cluster; Fig. 7 corner optimisation; Fig. 8 global map
before/after fusion; Figs. 9-10 four local maps for the three methods in 3D and 2D (with the feature
counts per local map in ``fig10_counts.csv``); Fig. 11 the local maps over map tiles; Figs. 13-14 ground
truth against fused features with zoomed vertices.
"""

from __future__ import annotations

import csv
import io
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from featmap.fusion import fuse
from featmap.fusion.registry import fuse_columns
from featmap.io.atomic import atomic_file_set, atomic_write_text
from featmap.io.segments_csv import SegmentTable
from featmap.plotting.basemap import Tiles
from featmap.plotting.maps import draw_feature_circles, draw_method, draw_truth, draw_walls_3d, view_box
from featmap.plotting.style import (SEGMENT_COLOR, add_scalebar, draw_segments, finish_map_axes, method_color,
                                    method_label, method_linestyle, new_figure, save_png)

LOCAL_HALF_M = 30.0
FIGURE_FILES = ("fig02_feature_circles_one_scan.png", "fig03_feature_circles_two_scans.png", "fig06_cluster_fusion.png",
                "fig07_corner_optimisation.png", "fig08_global_map.png", "fig09_local_maps_3d.png",
                "fig10_local_maps_2d.png", "fig10_counts.csv", "fig11_local_maps_tiles.png",
                "fig13_14_truth_vs_fused.png")
"""Every file ``make_figures`` may write. Figs. 6-7 need the proposed method and Figs. 13-14 a ground
truth: one a call did not write is an earlier call's into the same folder, and is removed (nothing else is)."""


@dataclass(frozen=True)
class FigureInputs:
    """What the figures draw, in the run's local metric frame.

    Attributes:
        segments: the extracted segments (world frame) with their scans.
        methods: fusion methods to draw (re-fused here with ``fusion`` to get clusters and labels).
        fusion: the run's ``fusion:`` config section.
        trajectory: (F, 2) sensor positions.
        frame: WGS84 origin of the local frame, or None (no map tiles then).
        truth: ground truth with ``walls`` (W, 4) and ``labels`` (W, 2), or None.
        tiles: where map tiles come from (Fig. 11).
    """

    segments: SegmentTable
    methods: list[str]
    fusion: Any
    trajectory: np.ndarray
    frame: Any
    truth: Any
    tiles: Tiles


def local_map_centres(run: FigureInputs, results: dict, n: int = 4) -> np.ndarray:
    """Centres (n, 2) of the local maps: the trajectory points with most fused walls nearby, spread along the drive."""
    traj = run.trajectory
    if len(traj) == 0:
        segs = run.segments.segments
        centre = 0.5 * (segs[:, :2] + segs[:, 2:]).mean(0) if len(segs) else np.zeros(2)
        return np.tile(centre, (n, 1))
    fused = results["proposed" if "proposed" in results else next(iter(results))].segments if results else np.zeros((0, 4))
    mids = 0.5 * (fused[:, :2] + fused[:, 2:]) if len(fused) else np.zeros((0, 2))
    chunks = np.array_split(np.arange(len(traj)), min(n, len(traj)))        # fewer scans: fewer maps
    centres = []
    for idx in chunks:
        cand = traj[idx]
        if len(mids):
            counts = (np.abs(mids[None, :, 0] - cand[:, None, 0]) < LOCAL_HALF_M * 0.8) & \
                     (np.abs(mids[None, :, 1] - cand[:, None, 1]) < LOCAL_HALF_M * 0.8)
            centres.append(cand[np.argmax(counts.sum(1))])
        else:
            centres.append(cand[len(cand) // 2])
    return np.asarray(centres)


def _in_box(segments: np.ndarray, centre: np.ndarray, half: float) -> np.ndarray:
    mids = 0.5 * (segments[:, :2] + segments[:, 2:])
    return (np.abs(mids - centre) <= half).all(axis=1)


# --- individual figures --------------------------------------------------------------------------------

def fig_feature_circles(run: FigureInputs, out: Path) -> list[Path]:
    table = run.segments
    scans, counts = np.unique(table.scan, return_counts=True)
    k = int(scans[np.argmax(counts)]) if len(scans) else 0              # the scan with most segments (none: empty)
    nxt = scans[scans > k]
    k2 = int(nxt[0]) if len(nxt) else k
    paths = []
    fig, ax = new_figure()
    draw_feature_circles(ax, table.segments[table.scan == k], "C0", label=f"scan {k}")
    finish_map_axes(ax, f"Fig. 2: feature circles of one scan (scan {k}, {int((table.scan == k).sum())} features)")
    paths.append(save_png(fig, out / "fig02_feature_circles_one_scan.png"))
    fig, ax = new_figure()
    a = table.segments[table.scan == k]
    draw_feature_circles(ax, a, "C0", label=f"scan {k} (time k-1)")
    draw_feature_circles(ax, table.segments[table.scan == k2], "C1", label=f"scan {k2} (time k)", start=len(a) + 1)
    finish_map_axes(ax, f"Fig. 3: feature circles of two consecutive scans ({k} and {k2})")
    paths.append(save_png(fig, out / "fig03_feature_circles_two_scans.png"))
    return paths


def fig_cluster_fusion(run: FigureInputs, result, out: Path) -> Path:
    """Fig. 6 in the fused line's own frame: along the wall in metres, across it in centimetres.

    The members of one cluster differ by centimetres over metres of wall, so the across axis is
    stretched to make the least-squares fit and the endpoint projections visible.
    """
    seg = run.segments.segments
    support = result.support
    c = int(np.argsort(support)[len(support) // 2]) if len(support) else -1
    fig, ax = new_figure()
    if c >= 0:
        members = seg[result.labels == c]
        fused = result.segments_before_corners[c]
        origin = fused[:2]
        d = (fused[2:] - fused[:2]) / max(np.hypot(*(fused[2:] - fused[:2])), 1e-9)
        n = np.array([-d[1], d[0]])

        def frame(points):                       # (K, 2) world -> (along m, across cm)
            rel = points - origin
            return np.column_stack([rel @ d, 100 * (rel @ n)])

        ends = frame(members.reshape(-1, 2))
        for k in range(len(members)):
            a, b = ends[2 * k], ends[2 * k + 1]
            ax.plot([a[0], b[0]], [a[1], b[1]], "-", color=SEGMENT_COLOR, lw=1, alpha=0.8,
                    label=f"member segments ({len(members)} scans)" if k == 0 else None)
        ax.plot(ends[:, 0], ends[:, 1], "k.", ms=4, label="member endpoints (fitted points)")
        for p in ends:
            ax.plot([p[0], p[0]], [p[1], 0.0], ":", color="0.5", lw=0.6)
        length = np.hypot(*(fused[2:] - fused[:2]))
        ax.axhline(0.0, ls="--", color="0.3", lw=1, label="least-squares line")
        ax.plot(ends[:, 0], np.zeros(len(ends)), "x", color="0.3", ms=5, label="projected endpoints")
        ax.plot([0, length], [0, 0], "-", color=method_color("proposed"), lw=3, label="fused feature (extreme projections)")
        ax.set_xlim(-0.05 * length - 0.5, 1.05 * length + 0.5)
    ax.set_xlabel("along the fused feature [m]")
    ax.set_ylabel("across the fused feature [cm] (stretched)")
    ax.set_title(f"Fig. 6: fusion of one cluster (support {int(support[c]) if c >= 0 else 0})")
    ax.legend(loc="best", fontsize=8)
    ax.grid(True, alpha=0.3)
    return save_png(fig, out / "fig06_cluster_fusion.png")


def fig_corner_optimisation(run: FigureInputs, result, out: Path) -> Path:
    before, after = result.segments_before_corners, result.segments
    moved = np.hypot(*(before.reshape(-1, 2) - after.reshape(-1, 2)).T)
    fig, axes = new_figure(1, 2, size=(14, 7))
    if len(moved) and moved.max() > 0:
        k = int(np.argmax(np.where(moved > 0, moved, -1)))
        centre = after.reshape(-1, 2)[k]
    else:
        centre = before.reshape(-1, 2)[0] if len(before) else np.zeros(2)
    for ax, segs, title in ((axes[0], before, "before corner optimisation"), (axes[1], after, "after corner optimisation")):
        draw_truth(ax, run.truth)
        draw_method(ax, "proposed", segs, endpoints=True)
        view_box(ax, centre, 4.0)
        finish_map_axes(ax, f"Fig. 7: {title}")
    corners = run.fusion.corners
    fig.suptitle(f"corner mode: {corners.mode}, snap distance {corners.snap_distance_m} m")
    return save_png(fig, out / "fig07_corner_optimisation.png")


def fig_global_map(run: FigureInputs, results: dict, out: Path) -> Path:
    fig, axes = new_figure(1, 2, size=(16, 8))
    draw_segments(axes[0], run.segments.segments, SEGMENT_COLOR, lw=0.6, label=f"extracted segments ({len(run.segments)})")
    name = "proposed" if "proposed" in results else next(iter(results), None)
    if name is not None:
        draw_method(axes[1], name, results[name].segments)
    for ax, title in ((axes[0], "Fig. 8a: global map before fusion"), (axes[1], "Fig. 8b: global map after fusion")):
        if len(run.trajectory):
            ax.plot(run.trajectory[:, 0], run.trajectory[:, 1], "-", color="m", lw=0.8, label="trajectory")
        ax.autoscale_view()
        finish_map_axes(ax, title)
    return save_png(fig, out / "fig08_global_map.png")


def _heights(run: FigureInputs, result) -> tuple[np.ndarray, np.ndarray]:
    extra = run.segments.extra
    if "z_min" not in extra or len(result.segments) == 0:
        return np.zeros(len(result.segments)), np.full(len(result.segments), 3.0)
    lo = np.full(len(result.segments), np.inf)
    hi = np.full(len(result.segments), -np.inf)
    keep = result.labels >= 0
    np.minimum.at(lo, result.labels[keep], extra["z_min"][keep])
    np.maximum.at(hi, result.labels[keep], extra["z_max"][keep])
    return np.where(np.isfinite(lo), lo, 0.0), np.where(np.isfinite(hi), hi, 3.0)


def fig_local_maps(run: FigureInputs, results: dict, centres: np.ndarray, out: Path) -> list[Path]:
    methods = list(results)
    n = len(centres)
    letters = "abcd"
    fig, axes = new_figure(len(methods), n, size=(4.2 * n, 4.0 * len(methods)), subplot_kw={"projection": "3d"}, squeeze=False)
    for r, name in enumerate(methods):
        res = results[name]
        lo, hi = _heights(run, res)
        for c, centre in enumerate(centres):
            ax = axes[r, c]
            sel = _in_box(res.segments, centre, LOCAL_HALF_M)
            draw_walls_3d(ax, res.segments[sel], lo[sel], hi[sel], method_color(name))
            ax.set_xlim(centre[0] - LOCAL_HALF_M, centre[0] + LOCAL_HALF_M)
            ax.set_ylim(centre[1] - LOCAL_HALF_M, centre[1] + LOCAL_HALF_M)
            ax.set_zlim(float(np.min(lo[sel])) if sel.any() else 0, float(np.max(hi[sel])) + 1 if sel.any() else 5)
            ax.set_xlabel("x [m]", fontsize=7)
            ax.set_ylabel("y [m]", fontsize=7)
            ax.set_zlabel("z [m]", fontsize=7)
            ax.tick_params(labelsize=6)
            ax.set_title(f"({letters[c]}) {method_label(name)}: {int(sel.sum())} planes", fontsize=8)
    from matplotlib.patches import Patch

    fig.legend(handles=[Patch(facecolor=method_color(m), alpha=0.55, label=method_label(m)) for m in methods],
               loc="lower center", ncol=len(methods))
    fig.suptitle(f"Fig. 9: fused planes of the three methods in 3D, four local maps ({2 * LOCAL_HALF_M:.0f} m x {2 * LOCAL_HALF_M:.0f} m, axes in metres)")
    fig.tight_layout()
    p9 = save_png(fig, out / "fig09_local_maps_3d.png")

    fig, axes = new_figure(len(methods), n, size=(4.2 * n, 4.2 * len(methods)), squeeze=False)
    for r, name in enumerate(methods):
        res = results[name]
        for c, centre in enumerate(centres):
            ax = axes[r, c]
            sel = _in_box(res.segments, centre, LOCAL_HALF_M)
            draw_truth(ax, run.truth)
            draw_method(ax, name, res.segments[sel], endpoints=True)
            view_box(ax, centre, LOCAL_HALF_M)
            finish_map_axes(ax, f"({letters[c]}) {name}: {int(sel.sum())} features")
            ax.title.set_fontsize(9)
    fig.suptitle("Fig. 10: fused features of the three methods in 2D, four local maps")
    fig.tight_layout()
    return [p9, save_png(fig, out / "fig10_local_maps_2d.png")]


def fig_tile_overlays(run: FigureInputs, results: dict, centres: np.ndarray, out: Path) -> Path:
    from featmap.plotting.basemap import add_basemap

    fig, axes = new_figure(2, 2, size=(13, 13))
    ok_all = True
    for ax, centre, letter in zip(axes.flat, centres, "abcd"):
        view_box(ax, centre, LOCAL_HALF_M)
        ok = run.frame is not None and add_basemap(ax, run.frame, run.tiles)
        ok_all &= ok
        if not ok:
            draw_truth(ax, run.truth, label="ground truth (no tiles)")
        for name, res in results.items():
            sel = _in_box(res.segments, centre, LOCAL_HALF_M)
            draw_segments(ax, res.segments[sel], method_color(name), lw=2.5, linestyles=method_linestyle(name),
                          label=f"{method_label(name)} ({int(sel.sum())})", zorder=3)
        if len(run.trajectory):
            near = np.abs(run.trajectory - centre).max(1) < LOCAL_HALF_M
            ax.plot(*run.trajectory[near].T, "-", color="m", lw=1, label="trajectory")
        view_box(ax, centre, LOCAL_HALF_M)
        finish_map_axes(ax, f"({letter}) local map {letter}")
    fig.suptitle("Fig. 11: fused features over map tiles" + ("" if ok_all else " (tiles unreachable: drawn over ground truth)"))
    fig.tight_layout()
    return save_png(fig, out / "fig11_local_maps_tiles.png")


def fig_truth_comparison(run: FigureInputs, results: dict, out: Path) -> Path | None:
    from matplotlib.patches import Rectangle

    truth = run.truth
    if truth is None:
        return None
    labels = [(lab, truth.walls[w, 2 * e:2 * e + 2]) for w in range(len(truth.walls)) for e, lab in enumerate(truth.labels[w]) if lab]
    seen, vertices = set(), []
    for lab, p in labels:
        if lab not in seen:
            seen.add(lab)
            vertices.append((lab, p))
    vertices = sorted(vertices)[:4] if vertices else []
    fig = new_figure(size=(16, 9))[0]
    fig.clf()
    grid = fig.add_gridspec(2, 4)
    main = fig.add_subplot(grid[:, :2])
    draw_truth(main, truth)
    order = sorted(results, key=lambda m: m == "proposed")      # the proposed method on top
    for name in order:
        draw_method(main, name, results[name].segments, lw=1.5, linestyles=method_linestyle(name))
    for lab, p in vertices:
        main.annotate(lab, p, fontsize=14, fontweight="bold", xytext=(6, 6), textcoords="offset points")
        main.add_patch(Rectangle(p - 1.5, 3, 3, fill=False, ec="g", lw=1.5))
    if len(truth.walls):
        w = truth.walls.reshape(-1, 2)
        lo, hi = w.min(0), w.max(0)
        main.set_xlim(lo[0] - 10, hi[0] + 10)
        main.set_ylim(lo[1] - 10, hi[1] + 10)
    finish_map_axes(main, "Figs. 13-14: ground truth and fused features")
    for k, (lab, p) in enumerate(vertices):
        ax = fig.add_subplot(grid[k // 2, 2 + k % 2])
        draw_truth(ax, truth)
        for name in order:
            draw_method(ax, name, results[name].segments, endpoints=True, linestyles=method_linestyle(name))
        view_box(ax, p, 1.5)
        ax.set_aspect("equal", adjustable="box")
        ax.set_title(f"vertex {lab} (zoom)", fontsize=9)
        ax.set_xlabel("x [m]", fontsize=7)
        ax.set_ylabel("y [m]", fontsize=7)
        ax.tick_params(labelsize=6)
        add_scalebar(ax, 0.5)
    fig.tight_layout()
    return save_png(fig, out / "fig13_14_truth_vs_fused.png")


def write_local_map_counts(results: dict, centres: np.ndarray, out: Path) -> Path:
    """``fig10_counts.csv``: fused features per method in each local map of Figs. 9-11 and in the whole map."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(["map"] + list(results))
    for letter, c in zip("abcd", centres):
        writer.writerow([f"local map {letter}"] + [int(_in_box(r.segments, c, LOCAL_HALF_M).sum()) for r in results.values()])
    writer.writerow(["global map"] + [len(r.segments) for r in results.values()])
    return atomic_write_text(out / "fig10_counts.csv", buf.getvalue())


def make_figures(run: FigureInputs, out: str | Path) -> list[Path]:
    """Every figure for one run, written into ``out``; returns their paths in ``out``.

    Afterwards ``out`` holds this call's figures only among ``FIGURE_FILES`` (an earlier call's Fig. 6 or
    Figs. 13-14, say, that this run's methods or reference do not make are removed); other files stay. The
    figures are drawn into a hidden staging folder inside ``out`` and moved in together at the end
    (``atomic_file_set``): an error or Ctrl-C while drawing leaves ``out`` as it was, with the earlier
    call's figures whole, never some of each.
    """
    out = Path(out)
    results = {name: fuse(name, run.segments.segments, run.segments.scan, run.fusion,
                          **fuse_columns(run.segments.extra, len(run.segments)))
               for name in run.methods}
    centres = local_map_centres(run, results)
    with atomic_file_set(out, FIGURE_FILES) as stage:
        paths = fig_feature_circles(run, stage)
        if "proposed" in results:
            paths.append(fig_cluster_fusion(run, results["proposed"], stage))
            paths.append(fig_corner_optimisation(run, results["proposed"], stage))
        paths.append(fig_global_map(run, results, stage))
        paths += fig_local_maps(run, results, centres, stage)
        paths.append(write_local_map_counts(results, centres, stage))
        with warnings.catch_warnings():
            warnings.simplefilter("always")
            paths.append(fig_tile_overlays(run, results, centres, stage))
        p = fig_truth_comparison(run, results, stage)
        if p is not None:
            paths.append(p)
    return [out / p.name for p in paths]
