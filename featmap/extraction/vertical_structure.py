"""Walls of one LiDAR scan from its vertical structure (``extraction.method: vertical_structure``).

A wall is a thin, straight line in the top view whose points rise high above the ground next to
it. The scan is never searched for planes, so no ground slab, car roof or tree crown can take a
wall's points away. One pass, no randomness:

1. **Crop** (velodyne frame): returns within ``min_range_m`` .. ``max_range_m``. The upper limit is
   the sensor's, not an accuracy crop: far walls are kept or dropped by their sampling (step 6).
2. **Local ground**: the lowest return of each ``ground_cell_m`` cell (returns far below their
   neighbours' are outliers), lowered where a nearby cell's ground plus a slope of at most
   ``ground_max_slope`` is lower (a wall's base hidden behind a fence takes the road's height).
   Heights are measured from this, so sloped roads, curbs and embankments need no global plane.
3. **Structure cells**: returns more than ``ground_margin_m`` above the ground are binned in
   ``cell_m`` cells; a cell is a candidate when its highest return is at least ``cell_min_top_m``
   up (this drops curbs, low bushes and the lower half of cars, not a wall seen behind them).
4. **Lines of cells**: every candidate cell votes, with its neighbours (within ``link_radius_m``,
   or within ``link_azimuth_deg`` and ``link_radial_m`` as seen from the sensor, which reaches the
   sparse samples of far walls and of walls seen at grazing incidence), for its dominant direction; two cells are linked when both have a line
   through them, the lines agree within ``link_angle_deg`` and each cell lies within
   ``line_tolerance_m`` of the other's line. Connected cells form a line piece, so a hedge, a car
   or a tree next to a wall does not bend it, and walls meeting at a corner stay apart.
5. **Pieces**: a total-least-squares line through each group's returns; returns farther than
   ``inlier_tolerance_m`` from it are dropped, the rest is cut where it leaves a gap longer than
   ``max_gap_m``; pieces on one line with ends less than ``merge_gap_m`` apart are joined.
6. **Walls**: a piece is a wall when it has ``min_points`` returns, ``min_length_m`` of length,
   ``max_rms_m`` of spread about its line at most, spans ``min_span_m`` in height, reaches
   ``min_top_m`` above the local ground, and is tall in one of three ways: it is hit by the scan's
   top beam (half of its 0.5 m columns within ``envelope_margin_deg`` of it), or it is ``tall_m``
   high, or it is ``long_m`` long and ``long_min_top_m`` high. Heights are the median over the
   columns, so a tree crown over a fence does not lift it. A facade at 20 m is seen only up to
   ~2.5 m by an HDL-64 (upper beam +2 deg), but it is hit by the top beam; a 1.5 m car never is,
   nor is a 2 m van at 11 m, which is also too short to pass as a boundary wall.

Numpy in, numpy out; the same scan always gives the same segments (no random sampling).
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from featmap.errors import FeatmapError
from featmap.extraction.segments import ScanSegments, StageClock


class VerticalStructureConfig(BaseModel):
    """Wall extraction from vertical structure (velodyne frame, metres).

    Same model settings as ``featmap.config._Section`` (a test keeps them equal); it does not derive
    from it because ``featmap.config`` composes this model (config -> extraction, never back).
    """

    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)

    min_range_m: float = Field(2.5, ge=0, description="drop returns closer than this (vehicle body)")
    max_range_m: float = Field(120.0, gt=0, description="drop returns farther than this (the sensor's range; far walls are judged by their sampling)")
    ground_cell_m: float = Field(2.0, gt=0, description="cell of the local ground (lowest return per cell)")
    ground_max_slope: float = Field(0.1, ge=0, description="the ground rises at most this much per metre away from a cell (rise/run)")
    ground_reach_m: float = Field(12.0, ge=0, description="... over at most this distance (fills cells whose ground is hidden)")
    ground_outlier_m: float = Field(1.0, gt=0, description="a cell whose lowest return is this far below its neighbours' median is an outlier")
    ground_margin_m: float = Field(0.25, ge=0, description="returns this close above the local ground are ground")
    cell_m: float = Field(0.15, gt=0, description="top-view cell of the structure grid")
    cell_min_top_m: float = Field(1.2, ge=0, description="a cell takes part when its highest return is this far above the ground")
    link_radius_m: float = Field(0.45, gt=0, description="cells this close are neighbours ...")
    link_azimuth_deg: float = Field(0.6, gt=0, description="... and so are cells seen this close in azimuth (a few of the sensor's azimuth steps) ...")
    link_radial_m: float = Field(2.0, gt=0, description="... that are this close in range (far walls, walls seen at grazing incidence)")
    link_angle_deg: float = Field(10.0, gt=0, le=90, description="linked cells' line directions differ by at most this")
    line_tolerance_m: float = Field(0.08, gt=0, description="a linked cell lies this close to its neighbour's line")
    min_support: int = Field(2, ge=1, description="a cell has a line through it when this many neighbours lie on it")
    inlier_tolerance_m: float = Field(0.15, gt=0, description="returns farther than this from a piece's line are not part of it")
    max_gap_m: float = Field(1.0, gt=0, description="cut a piece where its returns leave a gap this long")
    merge_gap_m: float = Field(1.5, ge=0, description="join pieces on one line whose ends are this close")
    merge_angle_deg: float = Field(3.0, ge=0, le=90, description="... whose directions differ by at most this")
    merge_offset_m: float = Field(0.12, ge=0, description="... and whose midpoints lie this close to the other's line")
    min_points: int = Field(20, ge=2, description="a wall has at least this many returns")
    min_length_m: float = Field(1.0, ge=0, description="a wall is at least this long")
    max_rms_m: float = Field(0.08, gt=0, description="a wall's returns spread at most this much about its line (rms)")
    min_span_m: float = Field(0.8, ge=0, description="a wall's returns span at least this much in height")
    min_top_m: float = Field(1.5, ge=0, description="a wall reaches at least this high above the local ground, and ...")
    tall_m: float = Field(2.5, ge=0, description="... is hit by the scan's top beam, or is this high (taller than vans, fences, hedges), ...")
    long_m: float = Field(6.0, ge=0, description="... or is at least this long (longer than a vehicle) ...")
    long_min_top_m: float = Field(1.8, ge=0, description="... and this high (a garden or boundary wall; taller than cars and fences)")
    envelope_margin_deg: float = Field(0.5, ge=0, description="reaching the top beam = a return within this elevation of the scan's top beam")
    top_beam_quantile: float = Field(0.999, gt=0, le=1, description="the scan's top beam = this quantile of its returns' elevation angles")


COLUMN_M = 0.5
"""Length of the columns along a wall in which its height is judged (metres)."""


# --- stage 0: input -------------------------------------------------------------------------------------

def validated_xyz(points) -> np.ndarray:
    """(N, 3) float64 x, y, z of an (N, >=3) point array; a one-line FeatmapError for anything else."""
    arr = np.asarray(points)
    if arr.ndim != 2 or arr.shape[1] < 3:
        raise FeatmapError(f"scan points: expected an (N, 3) or (N, 4) array, got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.number):
        raise FeatmapError(f"scan points: expected numbers, got {arr.dtype}")
    xyz = arr[:, :3].astype(np.float64)
    finite = np.isfinite(xyz).all(axis=1)
    if not finite.all():
        raise FeatmapError(f"scan points: {int((~finite).sum())} point(s) with NaN or inf coordinates")
    return xyz


# --- stage 2: local ground ------------------------------------------------------------------------------

def heights_above_local_ground(xyz: np.ndarray, config: VerticalStructureConfig) -> np.ndarray:
    """(N,) height of each (N, 3) point above the local ground under it (metres).

    The ground of a ``ground_cell_m`` cell is its lowest return; a cell whose lowest return lies more
    than ``ground_outlier_m`` below the median of its 3 x 3 neighbourhood (a stray return under the
    road) takes that median instead. The ground may then rise at most ``ground_max_slope`` away from
    any cell, up to ``ground_reach_m``: a cell with no visible ground (a wall's base hidden behind a
    fence or a car, a car's own cell) takes the road next to it plus that slope, while a sloped road
    keeps its own lowest returns.
    """
    from scipy import ndimage

    if len(xyz) == 0:
        return np.zeros(0)
    cell = config.ground_cell_m
    ix = np.floor(xyz[:, 0] / cell).astype(np.int64)
    iy = np.floor(xyz[:, 1] / cell).astype(np.int64)
    ix -= ix.min()
    iy -= iy.min()
    nx, ny = int(ix.max()) + 1, int(iy.max()) + 1
    flat = ix * ny + iy
    big = np.finfo(float).max / 4                           # an empty cell (finite, so sums stay finite)
    ground = np.full(nx * ny, big)
    np.minimum.at(ground, flat, xyz[:, 2])
    ground = ground.reshape(nx, ny)
    median = ndimage.median_filter(ground, size=3, mode="nearest")
    outlier = (median < big) & (ground < median - config.ground_outlier_m)
    ground[outlier] = median[outlier]
    rise = config.ground_max_slope * cell * np.array([[np.sqrt(2), 1, np.sqrt(2)], [1, 0, 1], [np.sqrt(2), 1, np.sqrt(2)]])
    for _ in range(int(np.ceil(config.ground_reach_m / cell))):
        ground = ndimage.grey_erosion(ground, structure=-rise, mode="nearest")
    return xyz[:, 2] - ground.ravel()[flat]


# --- stage 3: structure cells ---------------------------------------------------------------------------

def structure_cells(xy: np.ndarray, height: np.ndarray, config: VerticalStructureConfig):
    """Group (M, 2) non-ground points into ``cell_m`` cells and keep the cells that rise high enough.

    Returns (point_cell (M,) index of each point's candidate cell or -1, centroids (C, 2) of the
    candidate cells' points, weights (C,) points per candidate cell).
    """
    ci = np.floor(xy[:, 0] / config.cell_m).astype(np.int64)
    cj = np.floor(xy[:, 1] / config.cell_m).astype(np.int64)
    key = (ci - ci.min()) * (int(cj.max() - cj.min()) + 1) + (cj - cj.min())
    _, cell = np.unique(key, return_inverse=True)
    n_cells = int(cell.max()) + 1 if len(cell) else 0
    top = np.full(n_cells, -np.inf)
    np.maximum.at(top, cell, height)
    candidate = top >= config.cell_min_top_m
    renumber = np.full(n_cells, -1)
    renumber[candidate] = np.arange(int(candidate.sum()))
    point_cell = renumber[cell]
    inside = point_cell >= 0
    n = int(candidate.sum())
    weights = np.bincount(point_cell[inside], minlength=n).astype(float)
    centroids = np.column_stack([np.bincount(point_cell[inside], xy[inside, 0], n),
                                 np.bincount(point_cell[inside], xy[inside, 1], n)]) / np.maximum(weights, 1)[:, None]
    return point_cell, centroids, weights


# --- stage 4: lines of cells ----------------------------------------------------------------------------

def neighbour_pairs(centroids: np.ndarray, config: VerticalStructureConfig) -> np.ndarray:
    """(P, 2) index pairs i < j of neighbouring cells (C, 2): closer than ``link_radius_m``, or seen
    within ``link_azimuth_deg`` of each other from the sensor and less than ``link_radial_m`` apart in
    range. The second kind links the samples of far walls and of walls seen at grazing incidence,
    which lie a few azimuth steps apart but can be metres apart on the ground.
    """
    from scipy.spatial import cKDTree

    n = len(centroids)
    near = cKDTree(centroids).query_pairs(config.link_radius_m, output_type="ndarray")
    azimuth = np.mod(np.arctan2(centroids[:, 1], centroids[:, 0]), 2 * np.pi)
    a_scale = np.deg2rad(config.link_azimuth_deg)
    polar = np.column_stack([azimuth / a_scale, np.hypot(centroids[:, 0], centroids[:, 1]) / config.link_radial_m])
    polar[:, 0] = np.minimum(polar[:, 0], 2 * np.pi / a_scale - 1e-9)
    tree = cKDTree(polar, boxsize=[2 * np.pi / a_scale, 1e12])
    angular = np.sort(tree.query_pairs(1.0, output_type="ndarray"), axis=1)
    key = np.unique(np.concatenate([near[:, 0] * n + near[:, 1], angular[:, 0] * n + angular[:, 1]]))
    return np.column_stack([key // n, key % n]).astype(np.int64)


def link_cells(centroids: np.ndarray, weights: np.ndarray, config: VerticalStructureConfig) -> np.ndarray:
    """(C,) line-piece label of each candidate cell (-1: no line through it).

    Each cell's direction is the dominant direction towards its neighbours (a weighted vote over
    5 degree bins), refined by a principal-axis fit to the neighbours within ``line_tolerance_m``
    of it. Linked cells (see the module docstring) are grouped by connected components.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(centroids)
    pairs = neighbour_pairs(centroids, config)
    if n < 2 or len(pairs) == 0:
        return np.full(n, -1)
    i = np.concatenate([pairs[:, 0], pairs[:, 1]])
    j = np.concatenate([pairs[:, 1], pairs[:, 0]])
    d = centroids[j] - centroids[i]
    bins = 36
    angle = np.mod(np.arctan2(d[:, 1], d[:, 0]), np.pi)
    b = np.minimum((angle * (bins / np.pi)).astype(np.int64), bins - 1)
    votes = np.bincount(i * bins + b, weights=weights[j], minlength=n * bins).reshape(n, bins)
    votes = votes + 0.5 * (np.roll(votes, 1, axis=1) + np.roll(votes, -1, axis=1))
    theta = (np.argmax(votes, axis=1) + 0.5) * (np.pi / bins)
    normal = np.column_stack([-np.sin(theta), np.cos(theta)])
    on_line = np.abs((d * normal[i]).sum(1)) <= config.line_tolerance_m
    # Refine each direction by a weighted principal axis of the neighbours on the dominant line.
    ii, dd, ww = i[on_line], d[on_line], weights[j[on_line]]
    total = np.bincount(ii, ww, n) + weights
    mx = np.bincount(ii, ww * dd[:, 0], n) / total
    my = np.bincount(ii, ww * dd[:, 1], n) / total
    sxx = np.bincount(ii, ww * dd[:, 0] ** 2, n) / total - mx ** 2
    syy = np.bincount(ii, ww * dd[:, 1] ** 2, n) / total - my ** 2
    sxy = np.bincount(ii, ww * dd[:, 0] * dd[:, 1], n) / total - mx * my
    theta = 0.5 * np.arctan2(2 * sxy, sxx - syy)
    direction = np.column_stack([np.cos(theta), np.sin(theta)])
    normal = np.column_stack([-direction[:, 1], direction[:, 0]])
    has_line = np.bincount(ii, minlength=n) >= config.min_support
    linked = has_line[i] & has_line[j]
    linked &= np.abs((direction[i] * direction[j]).sum(1)) >= np.cos(np.deg2rad(config.link_angle_deg))
    linked &= np.abs((d * normal[i]).sum(1)) <= config.line_tolerance_m
    linked &= np.abs((d * normal[j]).sum(1)) <= config.line_tolerance_m
    graph = coo_matrix((np.ones(int(linked.sum())), (i[linked], j[linked])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    labels[~has_line] = -1
    return labels


# --- stage 5: pieces ------------------------------------------------------------------------------------

def _tls_lines(label: np.ndarray, xy: np.ndarray, n: int):
    """Per-label total-least-squares lines of (M, 2) points: centroids (n, 2), unit directions (n, 2), counts (n,)."""
    count = np.bincount(label, minlength=n).astype(float)
    safe = np.maximum(count, 1)
    mx = np.bincount(label, xy[:, 0], n) / safe
    my = np.bincount(label, xy[:, 1], n) / safe
    dx, dy = xy[:, 0] - mx[label], xy[:, 1] - my[label]
    sxx = np.bincount(label, dx * dx, n)
    syy = np.bincount(label, dy * dy, n)
    sxy = np.bincount(label, dx * dy, n)
    theta = 0.5 * np.arctan2(2 * sxy, sxx - syy)
    return np.column_stack([mx, my]), np.column_stack([np.cos(theta), np.sin(theta)]), count


def _cut_at_gaps(label: np.ndarray, along: np.ndarray, max_gap: float):
    """Order points by (label, along) and number the runs without gaps: (order (M,), piece (M,), count)."""
    order = np.lexsort((along, label))
    lab, t = label[order], along[order]
    new = np.ones(len(order), bool)
    new[1:] = (lab[1:] != lab[:-1]) | (np.diff(t) > max_gap)
    piece = np.cumsum(new) - 1
    return order, piece, int(piece[-1]) + 1 if len(piece) else 0


class _Pieces:
    """Line pieces over a set of points: label per point, and per piece its TLS line and extent."""

    def __init__(self, label: np.ndarray, xy: np.ndarray, n: int):
        self.label, self.n = label, n
        self.centroid, self.direction, self.count = _tls_lines(label, xy, n)
        rel = xy - self.centroid[label]
        self.along = (rel * self.direction[label]).sum(1)
        self.offset = rel[:, 0] * self.direction[label, 1] - rel[:, 1] * self.direction[label, 0]
        self.t_min = np.full(n, np.inf)
        self.t_max = np.full(n, -np.inf)
        np.minimum.at(self.t_min, label, self.along)
        np.maximum.at(self.t_max, label, self.along)
        self.rms = np.sqrt(np.bincount(label, self.offset ** 2, n) / np.maximum(self.count, 1))

    def endpoints(self) -> tuple[np.ndarray, np.ndarray]:
        return (self.centroid + self.t_min[:, None] * self.direction,
                self.centroid + self.t_max[:, None] * self.direction)


def line_pieces(xy: np.ndarray, group: np.ndarray, config: VerticalStructureConfig) -> np.ndarray:
    """(M,) piece label of each (M, 2) point from its cell group (``group`` -1 = none); -1 = not on a piece.

    The group's line is fitted, points off it are dropped, the rest is cut at gaps, refitted once
    more (a corner's other wall or a bush no longer pulls it), and collinear pieces whose ends are
    close are joined.
    """
    label = np.full(len(xy), -1)
    member = np.flatnonzero(group >= 0)
    if len(member) == 0:
        return label
    _, grp = np.unique(group[member], return_inverse=True)
    fit = _Pieces(grp, xy[member], int(grp.max()) + 1)
    keep = np.abs(fit.offset) <= config.inlier_tolerance_m
    member, grp, along = member[keep], grp[keep], fit.along[keep]
    order, piece, n = _cut_at_gaps(grp, along, config.max_gap_m)
    member = member[order]
    # Refit each piece on its own points and drop what now lies off it.
    fit = _Pieces(piece, xy[member], n)
    keep = np.abs(fit.offset) <= config.inlier_tolerance_m
    member, piece = member[keep], piece[keep]
    if len(member) == 0:
        return label
    _, piece = np.unique(piece, return_inverse=True)
    piece = merge_collinear(xy[member], piece, config)
    label[member] = piece
    return label


def merge_collinear(xy: np.ndarray, piece: np.ndarray, config: VerticalStructureConfig) -> np.ndarray:
    """Join pieces of one line whose ends lie within ``merge_gap_m``; returns the new (M,) piece labels."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    n = int(piece.max()) + 1
    if n < 2 or config.merge_gap_m <= 0:
        return piece
    fit = _Pieces(piece, xy, n)
    a, b = fit.endpoints()
    ends = np.concatenate([a, b])
    pairs = cKDTree(ends).query_pairs(config.merge_gap_m, output_type="ndarray")
    i, j = pairs[:, 0] % n, pairs[:, 1] % n
    i, j = i[i != j], j[i != j]
    u = fit.direction
    normal = np.column_stack([-u[:, 1], u[:, 0]])
    mid = (a + b) / 2
    dm = mid[j] - mid[i]
    ok = np.abs((u[i] * u[j]).sum(1)) >= np.cos(np.deg2rad(config.merge_angle_deg))
    ok &= np.abs((dm * normal[i]).sum(1)) <= config.merge_offset_m
    ok &= np.abs((dm * normal[j]).sum(1)) <= config.merge_offset_m
    graph = coo_matrix((np.ones(int(ok.sum())), (i[ok], j[ok])), shape=(n, n))
    _, merged = connected_components(graph, directed=False)
    return merged[piece]


# --- stage 6: walls -------------------------------------------------------------------------------------

def top_beam_tangent(xyz: np.ndarray, config: VerticalStructureConfig) -> float:
    """tan of the scan's top-beam elevation: the ``top_beam_quantile`` of z / range over returns beyond 3 m."""
    rng = np.hypot(xyz[:, 0], xyz[:, 1])
    far = rng > 3.0
    if not far.any():
        return np.inf
    return float(np.quantile(xyz[far, 2] / rng[far], config.top_beam_quantile))


def _group_median(group: np.ndarray, value: np.ndarray, n: int) -> np.ndarray:
    """(n,) median (the upper one of an even count) of ``value`` per ``group`` label; nan for empty groups."""
    order = np.lexsort((value, group))
    count = np.bincount(group, minlength=n)
    start = np.concatenate([[0], np.cumsum(count)[:-1]])
    out = np.full(n, np.nan)
    has = count > 0
    out[has] = value[order][start[has] + count[has] // 2]
    return out


def wall_segments(xyz: np.ndarray, height: np.ndarray, label: np.ndarray, tan_top: float,
                  config: VerticalStructureConfig) -> ScanSegments:
    """The pieces (``label`` per point of (M, 3) ``xyz``, -1 = none) that are walls, as ScanSegments.

    Heights are judged along the wall, in ``COLUMN_M`` columns: a piece's top is the median of its
    columns' highest returns and it reaches the top beam when at least half of its columns do, so a
    tree crown hanging over a fence does not make the fence a wall.
    """
    member = np.flatnonzero(label >= 0)
    if len(member) == 0:
        return ScanSegments.empty()
    _, piece = np.unique(label[member], return_inverse=True)
    n = int(piece.max()) + 1
    pts, h = xyz[member], height[member]
    fit = _Pieces(piece, pts[:, :2], n)
    # Columns along each piece: highest return and smallest shortfall below the top beam.
    column = np.floor((fit.along - fit.t_min[piece]) / COLUMN_M).astype(np.int64)
    _, col = np.unique(piece * (int(column.max()) + 1) + column, return_inverse=True)
    n_col = int(col.max()) + 1
    col_piece = np.zeros(n_col, np.int64)
    col_piece[col] = piece
    col_top = np.full(n_col, -np.inf)
    np.maximum.at(col_top, col, h)
    rng = np.hypot(pts[:, 0], pts[:, 1])
    shortfall = np.arctan(tan_top) - np.arctan2(pts[:, 2], rng)
    col_short = np.full(n_col, np.inf)
    np.minimum.at(col_short, col, shortfall)
    top = _group_median(col_piece, col_top, n)
    reach = np.bincount(col_piece, col_short <= np.deg2rad(config.envelope_margin_deg), n)
    reaches_top = reach >= 0.5 * np.bincount(col_piece, minlength=n)
    bottom = np.full(n, np.inf)
    np.minimum.at(bottom, piece, h)
    z_min = np.full(n, np.inf)
    z_max = np.full(n, -np.inf)
    np.minimum.at(z_min, piece, pts[:, 2])
    np.maximum.at(z_max, piece, pts[:, 2])
    z_mean = np.bincount(piece, pts[:, 2], n) / fit.count
    length = fit.t_max - fit.t_min
    wall = (fit.count >= config.min_points) & (length >= config.min_length_m) & (fit.rms <= config.max_rms_m)
    wall &= (top - bottom >= config.min_span_m) & (top >= config.min_top_m)
    wall &= reaches_top | (top >= config.tall_m) | ((length >= config.long_m) & (top >= config.long_min_top_m))
    if not wall.any():
        return ScanSegments.empty()
    a, b = fit.endpoints()
    order = np.lexsort((a[wall, 1], a[wall, 0]))
    sel = np.flatnonzero(wall)[order]
    return ScanSegments(segments=np.column_stack([a[sel], b[sel]]), z_mean=z_mean[sel],
                        n_points=fit.count[sel].astype(np.int64), z_min=z_min[sel], z_max=z_max[sel],
                        rms=fit.rms[sel])


# --- the extractor --------------------------------------------------------------------------------------

def extract_vertical_structure(points, config: VerticalStructureConfig = VerticalStructureConfig(),
                               timings: dict[str, float] | None = None) -> ScanSegments:
    """Wall segments of one scan from its vertical structure (see the module docstring).

    Args:
        points: (N, 3) or (N, 4) velodyne-frame points (x forward, y left, z up; metres); any order.
        config: extraction parameters.
        timings: if given, seconds spent per stage are added to it (crop, ground, cells, lines,
            pieces, walls).
    Returns:
        ScanSegments in the velodyne frame, sorted by first endpoint (possibly empty).
    Raises:
        FeatmapError: points that are not an (N, >=3) numeric array, or with NaN/inf coordinates.
    """
    clock = StageClock(timings)
    xyz = validated_xyz(points)
    rng = np.hypot(xyz[:, 0], xyz[:, 1])
    xyz = xyz[(rng >= config.min_range_m) & (rng <= config.max_range_m)]
    clock.lap("crop")
    if len(xyz) < config.min_points:
        return ScanSegments.empty()
    height = heights_above_local_ground(xyz, config)
    tan_top = top_beam_tangent(xyz, config)
    clock.lap("ground")
    above = height > config.ground_margin_m
    xyz, height = xyz[above], height[above]
    if len(xyz) < config.min_points:
        return ScanSegments.empty()
    point_cell, centroids, weights = structure_cells(xyz[:, :2], height, config)
    clock.lap("cells")
    cell_group = link_cells(centroids, weights, config)
    group = np.where(point_cell >= 0, cell_group[np.maximum(point_cell, 0)], -1)
    clock.lap("lines")
    label = line_pieces(xyz[:, :2], group, config)
    clock.lap("pieces")
    result = wall_segments(xyz, height, label, tan_top, config)
    clock.lap("walls")
    return result
