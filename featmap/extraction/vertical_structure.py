"""Walls of one LiDAR scan from its vertical structure (``extraction.method_3d: vertical_structure``).

A wall is a thin, straight line in the top view whose returns stand high above the ground next to
it. The scan is never searched for planes, so no ground slab, car roof or tree crown can take a
wall's points away. One pass, no randomness:

1. **Crop** (velodyne frame): returns within ``min_range_m`` .. ``max_range_m``. The upper limit is
   the sensor's (250 m), not an accuracy crop: far walls are kept or dropped by their sampling.
2. **Local ground**: the lowest return of each ``ground_cell_m`` cell (returns far below their
   neighbours' are outliers), lowered where a nearby cell's ground plus a slope of at most
   ``ground_max_slope`` is lower (a wall's base hidden behind a fence takes the road's height), and
   never higher than the road around the sensor plus that slope (a wall seen only over the building
   in front of it).
   Heights are measured from this, so sloped roads, curbs and embankments need no global plane.
3. **Levelling** (``level``): a vehicle on a sloped street pitches and rolls its sensor, and a wall,
   vertical in the world, leans in the sensor's frame (2 deg move a 15 m high wall's top by half a
   metre). Lines of cells are found (steps 4-5) among the returns within ``LEAN_BAND_M`` of the
   sensor's height (thinned to ``LEAN_POINTS``), each straight group's offset from its line is
   regressed on height, and the common lean of all groups (least squares, weighted by their height
   spread, without the groups that disagree) gives the world's vertical; the returns are rotated
   to make it the z axis. Later stages place lines in this levelled frame; the beams' elevations
   (the top-beam tests) stay measured in the sensor's frame; the walls found are given back in the
   sensor's frame, where the plane of each cuts the height of its returns, so that
   ``segments_to_world`` puts them exactly back on the wall. A levelled wall may lean at most
   ``max_lean_deg`` more (the per-piece lean taken out of its spread).
4. **Structure cells**: returns more than ``ground_margin_m`` above the ground are binned in
   ``cell_m`` cells; a cell is a candidate when its top is at least ``cell_min_top_m`` up (this
   drops curbs, low bushes and the lower half of cars, not a wall seen behind them). Its top is its
   highest return reached from its lowest without a gap in height longer than ``max_column_gap_m``
   (0.8 m; 0: its highest return) plus 3 beam spacings at its range, so a tree crown over a fence or
   a car does not lift it (:func:`continuous_tops`). Each
   cell knows whether the scan's top beam hit it (and the sensor does not see over it), or whether
   the top beam stopped in front of it (its top is hidden), and reaching the top beam counts only
   where that beam passes ``reach_min_m`` above the ground under the sensor (beyond ~8 m for an
   HDL-64: closer, a van stops it too).
5. **Lines of cells**: every candidate cell votes, with its neighbours (within ``link_radius_m``,
   or within ``link_azimuth_steps`` of the scan's azimuth steps and ``link_radial_m`` as seen from the
   sensor (an ellipse in azimuth and range), which reaches the sparse samples of far walls; or, for
   two columns of returns one azimuth step apart outside that ellipse, ranges as on a wall seen up to
   ``link_grazing_deg`` from head-on: far walls along the street, whose columns lie metres apart; with
   ``link_column_stack_m``, measured and not adopted, a cell counts as a column together with the cells
   right above and below it in its azimuth step),
   for its dominant direction; two cells are
   linked when both have a line through them, the lines agree within ``link_angle_deg`` and each
   cell lies within ``line_tolerance_m`` of the other's line. Connected cells form a line piece, so
   a hedge, a car or a tree next to a wall does not bend it, and walls meeting at a corner stay
   apart.
6. **Pieces**: a total-least-squares line through each group's returns; returns farther than
   ``inlier_tolerance_m`` from it are dropped, the rest is cut where it leaves a gap longer than
   ``max_gap_m``; pieces on one line with ends less than ``merge_gap_m`` apart are joined, and so
   are single columns of returns one azimuth step apart in line (a far wall seen at grazing
   incidence by a tilted sensor: each column a slanted streak a metre long, the next metres farther,
   and no cell of it a metre high, so the columns' cells are never linked). The pieces that pass
   every test but the final per-point ones (see 7) take back the cells beside a corner that are in
   no piece at least ``min_length_m`` long, when they lie beyond a piece's end (within
   ``link_radius_m``) on its line (within ``line_tolerance_m``): there the other face's denser cells
   can outvote them for their direction, and how the grid cuts the corner decides it
   (:func:`rejoin_corner_cells`).
7. **Walls**: a piece is a wall when it has ``min_points`` returns, ``min_length_m`` of length,
   ``max_rms_m`` of spread about its line at most, ``min_core_fraction`` of them close to their
   column's median offset and little seen through it (``max_behind``), is not seen edge-on
   (``max_incidence_deg``), is not two columns of returns with nothing between them (a gap longer
   than ``max_gap_m`` within ``min_azimuth_steps`` as seen from the sensor: a far corner and a pole
   one step apart fit any line), is, when seen in one or two columns of returns, straight in them
   (``max_column_curve_m``: the columns' slanted sheets of beams cut a wall in straight lines; a
   tree crown seen from afar, whose depth follows its round, lines up with the ray as a curve),
   spans ``min_span_m`` in height, reaches ``min_top_m`` above the local ground, and is tall in one
   of three ways: it stops the scan's top beam (half of its 0.5 m columns whose top is seen), or it
   is ``tall_m`` high, or it is ``long_m`` long and ``long_min_top_m`` high. Heights are medians over
   the columns whose top is seen (when at least ``MIN_SEEN_FRACTION`` of them are; else over all), so
   a tree crown over a fence does not lift it, nor when street trees hide the top of the rest of the
   fence. A facade at 20 m is seen only up to ~2.5 m by an HDL-64 (upper beam +2 deg),
   but it stops the top beam; a 1.5 m car never does, nor does a 2 m van at 11 m.
   With ``cut_above_counts_as_tall`` (adopted 2026-12-04 as version 12; measured in ``docs/results.md``) a
   fourth way: its top is cut by something well in front (in at least half of its cells, the nearest
   return up to 2 beam spacings above the highest one, in its direction, lies 0.5 m nearer and at most
   ``cut_above_max_ratio`` of its range away: a wall seen under a tree crown or behind a nearer roof).
   A piece whose returns leave gaps (columns of a far wall seen at grazing incidence, metres apart)
   must be straight in each column (``sparse_curve_factor``) and its columns must lie on one line
   (``sparse_offset_factor``), which lets ``link_grazing_deg`` reach 87 deg (with
   ``link_grazing_max_m``) without rows of trees or parked cars seen that obliquely; and it must hide
   what is behind it (``sparse_max_through``, see :func:`seen_through`: a row of trees or poles lined
   up like a wall lets most rays through). Adopted 2026-12-03 (``docs/results.md``).
   *Long pieces* (``solid_length_m``) are no tree crown: they may float (a wall seen over the house
   in front of it), may be seen over a narrow band when they stop the top beam (``solid_min_span_m``:
   a facade behind a hedge, or up a slope under the beam), and may have few returns
   (``solid_min_points``). *Shorter pieces* must reach down near the ground
   (``short_max_bottom_m``: a crown floats), unless (``short_hidden_below``, adopted 2026-12-04 as version 11;
   measured in ``docs/results.md``) their bottom is hidden by something in front: in at least half of their cells,
   the nearest return up to 2 beam spacings below the lowest one, in its direction, lies 0.5 m nearer (a
   house front seen over a hedge or a car; rays pass under a crown). And (``floating_min_top_m``, adopted
   2026-12-05 as version 13; measured in ``docs/results.md``) a piece shorter than ``long_m`` that floats in
   at least half of its 0.5 m columns (their bottom neither near the ground nor hidden in front) is no wall
   when at least half of those floating columns are low and thin (top below ``floating_min_top_m``, height
   span below ``floating_min_span_m``): a tree's trunk is one column reaching the ground, and the underside
   of its crown curving towards the sensor beside it is seen in slivers 2-4 m up; it reaches down and is
   as tall as a van, so the other tests let it through. With ``trunk_max_share`` (adopted 2026-12-05 as
   version 15; measured in ``docs/results.md``) the same shape seen finer: a piece shorter than
   ``solid_length_m`` whose cells reach down over less than that share of its length, beside low thin ones
   (a trunk often straddles two of a 1.5 m piece's three columns). Where the sensor's beams lie more than
   ``min_span_m`` apart in height (a 16-beam sensor beyond 23 m), a wall may be cut by a single beam and
   span nothing: a piece at least ``one_ring_min_length_m`` long whose top is at least ``tall_m`` up needs
   no span there (adopted 2026-12-05 as version 14; measured in ``docs/results.md``). The spread of the scan's long walls
   (their median rms; not those joined from single columns, whose noise lies along them) bounds everyone's:
   ``short_rms_factor`` times it for short pieces (a crown's facets, a wall merged with a crown in
   line with it, are thicker than the scan's walls), and ``solid_rms_factor`` times that of the long
   walls seen within ``NOISE_MAX_INCIDENCE_DEG`` of head-on (when there are 3: the sensor's noise; else
   all long walls') for long ones. A wall's spread is the range noise times the cosine of its incidence, so where most long
   walls are far walls seen obliquely, theirs would put the bar below the spread of a near wall seen
   head-on (2026-12-04, ``docs/results.md``).
8. **Walls hidden above** (``extend_hidden_m``): only returns ``line_min_height_m`` up place a wall,
   so a bush or a tree crown in front of a garden wall ends it where its upper part disappears
   behind them, though the wall goes on below. Each wall's ends move along its line over its low
   returns (within ``inlier_tolerance_m`` of the line) whose column is hidden above: the first
   return above the column's highest one on the line lies nearer (something in front stopped the
   rays that would have shown the rest of the wall). A fence or a hedge in line with a wall shows
   its top (the next ray passes over it) and is not joined. At most ``extend_hidden_m`` past an end
   and no gap longer than ``max_gap_m``; two pieces of one wall whose ends meet this way become one
   (:func:`extend_hidden_ends`).

Numpy in, numpy out; the same scan always gives the same segments (no random sampling).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from pydantic import Field

from featmap.config import Section
from featmap.errors import FeatmapError
from featmap.extraction.base import Extractor, ScanSegments, StageClock


class VerticalStructureConfig(Section):
    """Wall extraction from vertical structure (velodyne frame, metres)."""

    # crop and local ground
    min_range_m: float = Field(2.5, ge=0, description="drop returns closer than this (vehicle body)")
    max_range_m: float = Field(250.0, gt=0, description="drop returns farther than this (the sensor's range; far walls are judged by their sampling)")
    ground_cell_m: float = Field(2.0, gt=0, description="cell of the local ground (lowest return per cell)")
    ground_max_slope: float = Field(0.1, ge=0, description="the ground rises at most this much per metre away from a cell and from the road around the sensor (rise/run)")
    ground_reach_m: float = Field(12.0, ge=0, description="... over at most this distance (fills cells whose ground is hidden)")
    ground_outlier_m: float = Field(1.0, gt=0, description="a cell whose lowest return is this far below its neighbours' median is an outlier")
    ground_margin_m: float = Field(0.25, ge=0, description="returns this close above the local ground are ground")
    # levelling
    level: bool = Field(True, description="measure how the sensor leans from the walls' lean and level the returns before placing lines")
    max_lean_deg: float = Field(3.0, ge=0, le=15, description="a levelled wall leans at most this much (its spread is measured about that lean; a tree crown's facets lean more)")
    # structure cells and lines of cells
    cell_m: float = Field(0.15, gt=0, description="top-view cell of the structure grid")
    cell_min_top_m: float = Field(1.2, ge=0, description="a cell takes part when its top (see max_column_gap_m) is this far above the ground")
    max_column_gap_m: float = Field(0.8, ge=0, description="a cell's top is its highest return reached from its lowest without a gap in height longer than this plus 3 of the sensor's beam spacings at its range (a tree crown over a fence or a car does not make it tall; 0 = off: its highest return)")
    line_min_height_m: float = Field(1.0, ge=0, description="only returns this high above the ground place the lines (a car or bush in front of a wall does not pull it)")
    link_radius_m: float = Field(0.45, gt=0, description="cells this close are neighbours ...")
    link_azimuth_steps: float = Field(3.33, ge=0, description="... and so are cells seen within this many of the scan's azimuth steps (measured from its returns) ...")
    link_azimuth_deg: float = Field(0.6, gt=0, description="... (or within this azimuth when the step cannot be measured; 0 steps = always) ...")
    link_radial_m: float = Field(2.0, gt=0, description="... that are this close in range (far walls, walls seen at grazing incidence) ...")
    link_grazing_deg: float = Field(87.0, ge=0, lt=90, description="... and so are two columns one azimuth step apart whose ranges differ as on a wall seen up to this far from head-on (far walls along the street; 0 = off) ...")
    link_grazing_max_m: float = Field(8.0, ge=0, description="... when their ranges differ by at most this (two buildings in line far away, seen one azimuth step apart, are not one wall; 0 = any) ...")
    link_column_m: float = Field(1.0, ge=0, description="... a column being a cell whose returns stand this high (a wall's; a tree crown's returns at several depths do not) ...")
    link_column_stack_m: float = Field(0.0, ge=0, description="... together with the cells right above or below it in the same azimuth step whose ranges differ by at most this (a tilted sensor's column on a far wall seen at grazing incidence is a slanted streak across several cells, none a metre high; 0 = each cell alone; measured in docs/results.md, not adopted)")
    link_angle_deg: float = Field(10.0, gt=0, le=90, description="linked cells' line directions differ by at most this")
    line_tolerance_m: float = Field(0.08, gt=0, description="a linked cell lies this close to its neighbour's line")
    min_support: int = Field(2, ge=1, description="a cell has a line through it when this many neighbours lie on it")
    # pieces
    inlier_tolerance_m: float = Field(0.15, gt=0, description="returns farther than this from a piece's line are not part of it")
    max_gap_m: float = Field(1.0, gt=0, description="cut a piece where its returns leave a gap this long")
    merge_gap_m: float = Field(1.5, ge=0, description="join pieces on one line whose ends are this close")
    merge_angle_deg: float = Field(3.0, ge=0, le=90, description="... whose directions differ by at most this")
    merge_offset_m: float = Field(0.12, ge=0, description="... and whose midpoints lie this close to the other's line")
    # walls: every piece
    min_points: int = Field(20, ge=2, description="a wall has at least this many returns")
    min_length_m: float = Field(1.0, ge=0, description="a wall is at least this long")
    max_rms_m: float = Field(0.08, gt=0, description="a wall's returns spread at most this much about its line (rms) ...")
    core_m: float = Field(0.05, gt=0, description="... and at least min_core_fraction of them lie this close to the median of their 0.5 m column ...")
    min_core_fraction: float = Field(0.65, ge=0, le=1, description="... (foliage scatters its returns evenly; a facade's recesses shift whole columns) ...")
    max_behind: float = Field(1.0, ge=0, description="... and at most this many returns per wall return lie up to 1 m behind it (a wall hides what is behind it; foliage does not)")
    max_incidence_deg: float = Field(88.0, ge=0, le=90, description="a wall is seen at most this far from head-on (returns along a ray are a round thing seen at several depths, not a surface seen edge-on)")
    min_azimuth_steps: float = Field(1.5, ge=0, description="a wall whose returns leave a gap longer than max_gap_m spans at least this many of the scan's azimuth steps as seen from the sensor (two columns of returns with nothing between, e.g. a far corner and a pole one step apart, fit any line)")
    sparse_curve_factor: float = Field(2.0, ge=0, description="a wall whose returns leave gaps longer than max_gap_m (a far wall seen at grazing incidence: columns of returns metres apart) is straight in each column: its returns' positions along it within max_column_curve_m and within this many times the scan's range noise (its long walls' spread over the cosine of their incidence, from those seen within 60 deg of head-on; not applied without 3 of them) of a fit on height and lateral position per column (a tree crown's depth follows its round; 0 = off) ...")
    sparse_offset_factor: float = Field(3.0, ge=0, description="... and its columns lie on one line: their mean offsets from it spread (rms) at most this many times the spread within the columns plus sparse_offset_floor_m (parked cars in a row are not coplanar; 0 = off)")
    sparse_offset_floor_m: float = Field(0.01, ge=0, description="... (see sparse_offset_factor)")
    sparse_max_through: float = Field(0.4, ge=0, le=1, description="... and it hides what is behind it: of the returns whose rays cross its line within its extent and height, at most this share lie beyond it (a row of trees or poles seen obliquely lets most rays through; 0 = off)")
    max_column_curve_m: float = Field(0.07, gt=0, description="a wall spanning fewer than min_azimuth_steps has its returns' positions along it within this (median) of a fit on their height, azimuth and product (one or two columns of returns cut a wall in straight lines; a tree crown seen from afar curves)")
    min_span_m: float = Field(0.8, ge=0, description="a wall's returns span at least this much in height ...")
    min_top_m: float = Field(1.5, ge=0, description="... and reach at least this high above the local ground, and it ...")
    tall_m: float = Field(2.3, ge=0, description="... is hit by the scan's top beam, or is this high (taller than vans, fences, hedges), ...")
    long_m: float = Field(6.0, ge=0, description="... or is at least this long (longer than a vehicle) ...")
    long_min_top_m: float = Field(1.8, ge=0, description="... and this high (a garden or boundary wall; taller than cars and fences)")
    reach_min_m: float = Field(2.0, ge=0, description="reaching the top beam counts only where it passes this high above the ground under the sensor (higher than cars)")
    envelope_margin_m: float = Field(0.15, ge=0, description="reaching the top beam = a return this close below it ...")
    envelope_margin_deg: float = Field(0.3, ge=0, description="... or within this elevation of it (far away)")
    top_beam_quantile: float = Field(0.999, gt=0, le=1, description="the scan's top beam = this quantile of its returns' elevation angles")
    elevation_step_deg: float = Field(0.5, ge=0, description="the sensor's beam spacing near the horizon, when it cannot be measured from the scan")
    # walls: long pieces and short ones
    solid_length_m: float = Field(3.0, ge=0, description="a piece this long is no tree crown (nor other round thing): it may float (seen over something in front), ...")
    solid_min_span_m: float = Field(0.3, ge=0, description="... may span only this much in height and reach only cell_min_top_m when it stops the top beam (seen over a hedge, or under the beam up a slope) ...")
    solid_min_points: int = Field(20, ge=2, description="... needs this many returns (fewer: sparse far walls) ...")
    solid_rms_factor: float = Field(2.0, gt=0, description="... and spreads at most this many times as much as the scan's long walls seen within 60 deg of head-on do (their median, when there are 3: the sensor's noise; else all long walls')")
    short_max_bottom_m: float = Field(1.0, ge=0, description="a shorter piece reaches down to this height above the ground (plus one of the scan's beam spacings at its range): a tree crown floats ...")
    short_hidden_below: bool = Field(True, description="... unless its bottom is hidden by something in front (in at least half of its cells, the nearest return up to 2 beam spacings below the lowest one, in its direction, lies 0.5 m nearer: a wall seen over a hedge or a car, not a crown, under which the rays pass)")
    cut_above_counts_as_tall: bool = Field(True, description="a piece whose top is hidden just above by something in front (in at least half of its cells, the nearest return up to 2 beam spacings above the highest one, in its direction, lies 0.5 m nearer: a wall seen under a tree crown or behind a nearer roof) passes the height test as if it reached the top beam (its top is not seen; a car or hedge under a crown's base is rarely cut exactly at its top)")
    cut_above_max_ratio: float = Field(0.8, gt=0, le=1, description="... the return cutting its top lies at most this share of the piece's range away (a crown or roof well in front, not the near end of the same van seen obliquely)")
    short_rms_factor: float = Field(2.0, gt=0, description="... and spreads at most this many times as much as the scan's long walls do")
    typical_spread_skips_sparse: bool = Field(False, description="the long walls whose spread sets these bars (solid_rms_factor, short_rms_factor) leave out those whose returns leave gaps longer than max_gap_m (far walls at grazing incidence, sampled in columns metres apart: their range noise lies along them, so they are thinner than the sensor's noise; measured in docs/results.md, not adopted)")
    floating_min_top_m: float = Field(4.0, ge=0, description="a piece shorter than long_m that floats in at least half of its 0.5 m columns (their bottom neither within short_max_bottom_m of the ground nor hidden by something in front) is no wall when at least half of those floating columns are low and thin: their top below this height above the ground ... (a tree's trunk beside the underside of its crown; 0 = off)")
    floating_min_span_m: float = Field(1.0, ge=0, description="... and their height span below this (a crown's underside is seen in thin slivers; a wall's upper storey seen over a lower roof stands higher)")
    trunk_max_share: float = Field(0.5, ge=0, le=1, description="a piece shorter than solid_length_m that reaches down (its cells' bottom within short_max_bottom_m of the ground, or hidden in front) over less than this share of its length, and at least half of whose other cells are low and thin (floating_min_top_m, floating_min_span_m), is a tree's trunk beside the underside of its crown (0 = off, and so is floating_min_top_m 0; measured in docs/results.md)")
    one_ring_min_length_m: float = Field(6.0, ge=0, description="a piece at least this long, at a range where the sensor's beams lie more than min_span_m apart in height, whose top is at least tall_m above the ground, needs no height span: a far wall cut by a single beam (0 = off)")
    extend_hidden_m: float = Field(3.0, ge=0, description="a wall goes on past its ends, up to this far along its line, over its low returns whose column is hidden above by something in front (a bush before a garden wall; 0 = off)")


COLUMN_GAP_BEAMS = 3.0
"""Beam spacings (at a cell's range) added to ``max_column_gap_m``: a wall's returns lie one beam apart in height."""
COLUMN_M = 0.5
"""Length of the columns along a wall in which its height is judged (metres)."""
MAX_TILT_DEG = 15.0
"""Largest lean of a wall (or tilt of the sensor) taken out of its spread (degrees)."""
BEHIND_M = 1.0
"""How far behind a wall's line returns count as seen through it (metres) ..."""
BEHIND_MAX_HEIGHT_M = 1.8
"""... if they are at most this high above the ground (a tree crown behind a low wall does not count)."""
THROUGH_BEYOND_M = 0.5
"""A return this much farther along its ray than where the ray crosses a piece's line was seen through
the piece (metres; more than the range noise, less than any gap between a row of trees and a facade)."""
THROUGH_BAND_M = (0.2, 0.3)
"""Rays count for the see-through share when they cross a piece's line this far above its lowest and below
its highest return (metres): a ray over the top or under the bottom of a wall passes it legitimately."""
NOISE_MAX_INCIDENCE_DEG = 60.0
"""The scan's range noise is measured on its long walls seen at most this far from head-on (degrees)."""
TOP_BEAM_DEG = 0.1
"""Returns within this elevation of the top beam are the top beam's (degrees)."""
MIN_SEEN_FRACTION = 0.25
"""A piece's top and top-beam reach are judged over its columns whose top is seen when they are at least
this share of its columns (else over all its columns)."""
SEEN_OVER_M = 0.5
"""A return this much farther away than a structure, and higher, was seen over it (metres)."""
HIDDEN_BELOW_BEAMS = 2.0
"""How far below a cell's lowest return (in beam spacings) a nearer return hides its bottom (``short_hidden_below``),
and how far above its highest one a nearer return cuts its top (``cut_above_counts_as_tall``)."""
CORNER_MIN_DEG = 45.0
"""Two pieces whose directions differ at least this much meet at a corner (degrees): see :func:`rejoin_corner_cells`."""


# --- stage 0: input -------------------------------------------------------------------------------------

def validated_xyz(points) -> np.ndarray:
    """(N, 3) float64 x, y, z of an (N, >=3) point array; a one-line FeatmapError for anything else."""
    arr = np.asarray(points)
    if arr.ndim != 2 or arr.shape[1] < 3:
        raise FeatmapError(f"scan points: expected an (N, 3) or (N, 4) array, got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.number):
        raise FeatmapError(f"scan points: expected numbers, got {arr.dtype}")
    xyz = np.array(arr[:, :3], dtype=np.float64, order="F")     # (a copy, column-major: see _rows)
    if not np.isfinite(xyz).all():
        finite = np.isfinite(xyz).all(axis=1)
        raise FeatmapError(f"scan points: {int((~finite).sum())} point(s) with NaN or inf coordinates")
    return xyz


def _rows(xyz: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """The (K, 3) ``rows`` (a boolean mask or indices) of (N, 3) points, column-major: the stages read
    x, y and z as columns, which is several times faster on contiguous ones."""
    return (xyz.T[:, rows] if rows.dtype != bool else np.compress(rows, xyz.T, axis=1)).T


# --- stage 2: local ground ------------------------------------------------------------------------------

SENSOR_GROUND_RADIUS_M = 10.0
"""The road around the sensor: ground cells within this distance of it (metres) bound the ground's rise."""


def heights_above_local_ground(xyz: np.ndarray, config: VerticalStructureConfig) -> np.ndarray:
    """(N,) height of each (N, 3) point above the local ground under it (metres).

    The ground of a ``ground_cell_m`` cell is its lowest return; a cell whose lowest return lies more
    than ``ground_outlier_m`` below the median of its 3 x 3 neighbourhood (a stray return under the
    road) takes that median instead. The ground may then rise at most ``ground_max_slope`` away from
    any cell, up to ``ground_reach_m``: a cell with no visible ground (a wall's base hidden behind a
    fence or a car, a car's own cell) takes the road next to it plus that slope, while a sloped road
    keeps its own lowest returns. Nor may it rise more than that slope away from the median ground
    of the cells within ``SENSOR_GROUND_RADIUS_M`` of the sensor: a wall seen only as a band over the
    building in front of it, with no road within ``ground_reach_m``, would otherwise be its own ground.
    """
    from scipy import ndimage

    if len(xyz) == 0:
        return np.zeros(0)
    cell = config.ground_cell_m
    ix = np.floor(xyz[:, 0] / cell).astype(np.int64)
    iy = np.floor(xyz[:, 1] / cell).astype(np.int64)
    x0, y0 = ix.min(), iy.min()
    ix -= x0
    iy -= y0
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
    # Nor does it rise faster than that from the road around the sensor: a wall seen only over the
    # building in front of it, farther than ground_reach_m from any road, keeps its height.
    r = np.hypot((np.arange(nx) + 0.5 + x0)[:, None] * cell, (np.arange(ny) + 0.5 + y0)[None, :] * cell)
    near = (r <= SENSOR_GROUND_RADIUS_M) & (ground < big)
    if near.any():
        ground = np.minimum(ground, float(np.median(ground[near])) + config.ground_max_slope * r)
    return xyz[:, 2] - ground.ravel()[flat]


# --- stage 3: structure cells ---------------------------------------------------------------------------

@dataclass(frozen=True)
class Cells:
    """Candidate cells and what the later stages need of their points (C cells, M non-ground points).

    Attributes:
        point_cell: (M,) each point's candidate cell, or -1.
        count: (C,) points per cell at least ``line_min_height_m`` high (the ones that place lines).
        centroid: (C, 2) mean x, y of those points.
        scatter: (C, 3) sums of dx*dx, dx*dy, dy*dy about the centroid (for exact line fits of groups).
        top, bottom: (C,) highest and lowest point above the local ground.
        reaches_top: (C,) a point of the cell is hit by (within the envelope margins of) the top beam,
            and the sensor does not see over the cell.
        hidden_above: (C,) the top beam stopped nearer in the cell's direction: its top is not seen.
        hidden_below: (C,) the nearest return up to ``HIDDEN_BELOW_BEAMS`` beam spacings below the cell's
            lowest one, in its azimuth bin, lies ``SEEN_OVER_M`` nearer: its bottom is not seen (None unless
            ``short_hidden_below``).
        cut_above: (C,) the nearest return up to ``HIDDEN_BELOW_BEAMS`` beam spacings above the cell's highest
            one, in its azimuth bin, lies ``SEEN_OVER_M`` nearer and at most ``cut_above_max_ratio`` of its range
            away: its top is cut by something in front (None unless ``cut_above_counts_as_tall``).
        grid_keys, grid_counts, grid_origin: every cell (sorted keys) with non-ground points at most
            ``BEHIND_MAX_HEIGHT_M`` high, and how many, to count such points anywhere (``points_at``).
    """

    point_cell: np.ndarray
    count: np.ndarray
    centroid: np.ndarray
    scatter: np.ndarray
    top: np.ndarray
    bottom: np.ndarray
    reaches_top: np.ndarray
    hidden_above: np.ndarray
    grid_keys: np.ndarray
    grid_counts: np.ndarray
    grid_origin: tuple
    hidden_below: np.ndarray | None = None
    cut_above: np.ndarray | None = None

    def points_at(self, xy: np.ndarray) -> np.ndarray:
        """(K,) low non-ground points in the ``cell_m`` cell under each (K, 2) position."""
        if len(self.grid_keys) == 0:                # no low non-ground point anywhere
            return np.zeros(len(xy), np.int64)
        size, i0, j0, width = self.grid_origin[0], self.grid_origin[1], self.grid_origin[2], self.grid_origin[3]
        ci = np.floor(xy[:, 0] / size).astype(np.int64) - i0
        cj = np.floor(xy[:, 1] / size).astype(np.int64) - j0
        key = ci * width + cj
        valid = (cj >= 0) & (cj < width) & (ci >= 0)
        pos = np.minimum(np.searchsorted(self.grid_keys, key), len(self.grid_keys) - 1)
        return np.where(valid & (self.grid_keys[pos] == key), self.grid_counts[pos], 0)

    def __len__(self) -> int:
        return len(self.count)


def structure_cells(xyz: np.ndarray, height: np.ndarray, tan_top: float, config: VerticalStructureConfig,
                    sensor_xyz: np.ndarray | None = None, reach_from_m: float = 0.0, lines_only: bool = False,
                    sensor_rng: np.ndarray | None = None) -> Cells:
    """Group (M, 3) non-ground points (``height`` (M,) above the local ground) into ``cell_m`` cells and
    keep the cells whose top (:func:`continuous_tops` with ``max_column_gap_m``, else their highest point)
    is at least ``cell_min_top_m`` up. The cells' positions and
    line moments come from their points at least ``line_min_height_m`` up; heights from all.

    ``xyz`` may be levelled (see ``level_rotation``); ``sensor_xyz`` (M, 3) are then the same points in
    the sensor's own frame, where the beams' elevations (the top-beam test) are measured. Cells
    closer than ``reach_from_m`` never count as reaching the top beam. ``lines_only``: only what
    placing lines needs (point_cell, count, centroid, scatter, top, bottom; the rest empty).
    ``sensor_rng`` (M,): the horizontal ranges of ``sensor_xyz``, if already known."""
    sensor_xyz = xyz if sensor_xyz is None else sensor_xyz
    if sensor_rng is None and (not lines_only or config.max_column_gap_m > 0):
        sensor_rng = np.hypot(sensor_xyz[:, 0], sensor_xyz[:, 1])
    ci = np.floor(xyz[:, 0] / config.cell_m).astype(np.int64)
    cj = np.floor(xyz[:, 1] / config.cell_m).astype(np.int64)
    i0, j0, width = int(ci.min()), int(cj.min()), int(cj.max() - cj.min()) + 1
    key = (ci - i0) * width + (cj - j0)
    keys, cell = _labels(key)
    n_all = len(keys)
    if lines_only:
        grid_keys, grid_counts = np.zeros(0, np.int64), np.zeros(0, np.int64)
    else:
        grid_counts = np.bincount(cell[height <= BEHIND_MAX_HEIGHT_M], minlength=n_all)
        grid_keys, grid_counts = keys[grid_counts > 0], grid_counts[grid_counts > 0]
    if config.max_column_gap_m > 0:
        gap = config.max_column_gap_m + COLUMN_GAP_BEAMS * sensor_rng * np.tan(np.deg2rad(config.elevation_step_deg))
        top = continuous_tops(cell, height, n_all, gap)
    else:
        top = np.full(n_all, -np.inf)
        np.maximum.at(top, cell, height)
    candidate = top >= max(config.cell_min_top_m, config.line_min_height_m)
    renumber = np.full(n_all, -1)
    renumber[candidate] = np.arange(int(candidate.sum()))
    point_cell = renumber[cell]
    n = int(candidate.sum())
    inside = np.flatnonzero(point_cell >= 0)
    bottom = np.full(n, np.inf)
    np.minimum.at(bottom, point_cell[inside], height[inside])
    upper = inside[height[inside] >= config.line_min_height_m]
    c = point_cell[upper]
    x, y = xyz[upper, 0], xyz[upper, 1]
    count = np.bincount(c, minlength=n).astype(float)
    centroid = np.column_stack([np.bincount(c, x, n), np.bincount(c, y, n)]) / np.maximum(count, 1)[:, None]
    dx, dy = x - centroid[c, 0], y - centroid[c, 1]
    scatter = np.column_stack([np.bincount(c, dx * dx, n), np.bincount(c, dx * dy, n), np.bincount(c, dy * dy, n)])
    if lines_only:
        none = np.zeros(n, bool)
        return Cells(point_cell, count, centroid, scatter, top[candidate], bottom, none, none,
                     grid_keys, grid_counts, (config.cell_m, i0, j0, width))
    # How close each cell comes to the top beam: the largest z - range * tan(top beam) (<= 0 below it),
    # and whether the sensor sees over it (a higher return farther away in the same direction).
    sz, rng = sensor_xyz[upper, 2], sensor_rng[upper]
    reach = np.full(n, -np.inf)
    np.maximum.at(reach, c, sz - rng * tan_top)
    slope = np.full(n, -np.inf)
    np.maximum.at(slope, c, sz / np.maximum(rng, 1e-9))
    cell_range = np.hypot(centroid[:, 0], centroid[:, 1])
    margin = np.maximum(config.envelope_margin_m, cell_range * np.tan(np.deg2rad(config.envelope_margin_deg)))
    return_slope = sensor_xyz[:, 2] / np.maximum(sensor_rng, 1e-9)
    over_slope, over_range, top_range, az_bin = highest_returns(sensor_xyz, tan_top, config, sensor_rng,
                                                                return_slope)
    b = az_bin(centroid)
    seen_over = (over_slope[b] > slope + 1e-4) & (over_range[b] > cell_range + SEEN_OVER_M)
    reaches = (reach >= -margin) & ~seen_over & (cell_range >= reach_from_m)
    hidden = ~reaches & (top_range[b] < cell_range - SEEN_OVER_M)
    below = (_hidden_next_to(sensor_xyz, sensor_rng, return_slope, point_cell, inside, n, cell_range, b, az_bin,
                             config, above=False)
             if config.short_hidden_below else None)
    cut = (_hidden_next_to(sensor_xyz, sensor_rng, return_slope, point_cell, inside, n, cell_range, b, az_bin,
                           config, above=True, max_ratio=config.cut_above_max_ratio)
           if config.cut_above_counts_as_tall else None)
    return Cells(point_cell, count, centroid, scatter, top[candidate], bottom, reaches, hidden,
                 grid_keys, grid_counts, (config.cell_m, i0, j0, width), below, cut)


def _hidden_next_to(sensor_xyz: np.ndarray, sensor_rng: np.ndarray, slope: np.ndarray, point_cell: np.ndarray,
                    inside: np.ndarray, n: int, cell_range: np.ndarray, cell_bin: np.ndarray, az_bin,
                    config: VerticalStructureConfig, above: bool, max_ratio: float = 1.0) -> np.ndarray:
    """(n,) the cells whose bottom (``above`` False) or top (``above`` True) is hidden: in their azimuth bin
    (``az_bin``, ``cell_bin`` (n,)), the nearest return at most ``HIDDEN_BELOW_BEAMS`` beam spacings (in
    tan(elevation)) below the cell's lowest return (above its highest) lies ``SEEN_OVER_M`` nearer than the
    cell (``cell_range`` (n,): its centroid's horizontal range) and at most ``max_ratio`` of its range away.
    ``sensor_xyz`` (M, 3) and ``sensor_rng`` (M,): the non-ground returns in the sensor's frame, ``slope``
    (M,) their z / range; ``point_cell`` (M,) their candidate cell (-1: none); ``inside``: the indices of
    those in one."""
    edge = np.full(n, -np.inf if above else np.inf)
    (np.maximum if above else np.minimum).at(edge, point_cell[inside], slope[inside])
    # Returns sorted by (bin, slope): each cell's window of slopes next to its edge is one slice. The
    # stride between bins exceeds the slopes' span plus the window, so no window reaches into the next bin.
    band = HIDDEN_BELOW_BEAMS * np.tan(np.deg2rad(config.elevation_step_deg))
    lim = 1e3                                   # |slope| beyond it: within 0.06 deg of straight up or down
    stride = 2 * lim + band + 1.0
    key = az_bin(sensor_xyz[:, :2]) * stride + np.clip(slope, -lim, lim)
    order = np.argsort(key)
    key = key[order]
    near = np.append(sensor_rng[order], np.inf)       # (a window may end after the last return)
    edge_key = cell_bin * stride + np.clip(edge, -lim, lim)
    if above:                                   # the window (highest, highest + band]
        lo = np.searchsorted(key, edge_key, side="right")
        hi = np.searchsorted(key, edge_key + band, side="right")
    else:                                       # the window [lowest - band, lowest)
        hi = np.searchsorted(key, edge_key, side="left")
        lo = np.searchsorted(key, edge_key - band, side="left")
    # The nearest return in each non-empty window near[lo:hi]: reduceat over the pairs (lo, hi).
    out = np.zeros(n, bool)
    has = np.flatnonzero(hi > lo)
    if len(has):
        nearest = np.minimum.reduceat(near, np.column_stack([lo[has], hi[has]]).ravel())[::2]
        out[has] = nearest < np.minimum(cell_range[has] - SEEN_OVER_M, max_ratio * cell_range[has])
    return out


def continuous_tops(cell: np.ndarray, height: np.ndarray, n: int, gap: np.ndarray) -> np.ndarray:
    """(n,) per cell the highest of its points reached from its lowest without a step in height longer
    than the upper point's ``gap`` (M,) (-inf: no point). ``cell`` (M,) in 0..n-1, ``height`` (M,)."""
    top = np.full(n, -np.inf)
    if len(cell) == 0:
        return top
    order = _group_order(cell, height)
    c, h, g = cell[order], height[order], gap[order]
    first = np.concatenate([[True], c[1:] != c[:-1]])
    broken = np.concatenate([[False], ~first[1:] & (np.diff(h) > g[1:])])
    breaks = np.cumsum(broken)
    start = np.flatnonzero(first)
    keep = breaks == breaks[start][np.cumsum(first) - 1]
    np.maximum.at(top, c[keep], h[keep])
    return top


def highest_returns(xyz: np.ndarray, tan_top: float, config: VerticalStructureConfig, rng: np.ndarray | None = None,
                    slope: np.ndarray | None = None):
    """The highest return in each ``link_azimuth_deg / 2`` azimuth bin, among returns near the top beam.

    Returns (slope (B,) largest z / range per bin (-inf: none), range (B,) of that return, range (B,)
    of the nearest return of the top beam (within ``TOP_BEAM_DEG``; inf: none), a function mapping
    (K, 2) x, y to their bin numbers (K,)). A structure whose bin holds a higher return farther away
    does not stop the top beams: the sensor sees over it (a van, a hedge, a garden wall); one whose
    top beam stopped nearer is hidden above (its top is not seen). ``rng`` (N,) and ``slope`` (N,): the
    (N, 3) returns' horizontal ranges and z / range, if already known.
    """
    width = np.deg2rad(config.link_azimuth_deg) / 2
    n_bins = int(np.ceil(2 * np.pi / width))

    def az_bin(xy: np.ndarray) -> np.ndarray:
        return np.minimum(((np.arctan2(xy[:, 1], xy[:, 0]) + np.pi) / width).astype(np.int64), n_bins - 1)

    rng = np.hypot(xyz[:, 0], xyz[:, 1]) if rng is None else rng
    slope = xyz[:, 2] / np.maximum(rng, 1e-9) if slope is None else slope
    high = np.flatnonzero(slope >= np.tan(np.arctan(tan_top) - np.deg2rad(2.0)))
    bins = az_bin(xyz[high, :2])
    best = np.full(n_bins, -np.inf)
    np.maximum.at(best, bins, slope[high])
    at_best = slope[high] >= best[bins]
    best_range = np.zeros(n_bins)
    best_range[bins[at_best]] = rng[high][at_best]
    # No top beam measured (no return beyond 3 m: tan_top is inf): no return is of the top beam.
    top_slope = tan_top - np.deg2rad(TOP_BEAM_DEG) * (1 + tan_top ** 2) if np.isfinite(tan_top) else np.inf
    top = slope[high] >= top_slope
    top_range = np.full(n_bins, np.inf)
    np.minimum.at(top_range, bins[top], rng[high][top])
    return best, best_range, top_range, az_bin


# --- stage 4: lines of cells ----------------------------------------------------------------------------

def neighbour_pairs(centroids: np.ndarray, config: VerticalStructureConfig,
                    columns: np.ndarray | None = None) -> np.ndarray:
    """(P, 2) index pairs i < j of neighbouring cells (C, 2): closer than ``link_radius_m``, or seen
    within ``link_azimuth_deg`` of each other from the sensor and less than ``link_radial_m`` apart in
    range (together: an ellipse, ``_sensor_view``). The second kind links the samples of far walls
    and of walls seen at grazing incidence, which lie a few azimuth steps apart but can be metres
    apart on the ground. Two ``columns`` ((C,) bool: cells whose returns stand at least
    ``link_column_m`` high) one azimuth step apart and outside that ellipse are also neighbours when
    their ranges differ as on a wall seen up to ``link_grazing_deg`` from head-on (a far wall along
    the street: one column of returns per azimuth step, metres apart).
    """
    return _close_pairs(centroids, config.link_radius_m, config, columns)


def _close_pairs(points: np.ndarray, radius: float, config: VerticalStructureConfig,
                 columns: np.ndarray | None = None) -> np.ndarray:
    """(P, 2) index pairs i < j of (K, 2) points at most ``radius`` apart or close as seen from the
    sensor (inside the ellipse of ``link_azimuth_deg`` in azimuth and ``link_radial_m`` in range,
    ``_sensor_view``; with ``columns`` (K,) bool, also columns one azimuth step apart outside it, see
    ``neighbour_pairs``)."""
    from scipy.spatial import cKDTree

    near = cKDTree(points).query_pairs(radius, output_type="ndarray")
    angular = cKDTree(_sensor_view(points, config)).query_pairs(1.0, output_type="ndarray")
    parts = [near, angular[np.hypot(*(points[angular[:, 0]] - points[angular[:, 1]]).T) > radius]]
    if columns is not None:
        parts.append(_grazing_pairs(points, columns, config))
    return np.concatenate(parts).astype(np.int64).reshape(-1, 2)


def _sensor_view(points: np.ndarray, config: VerticalStructureConfig) -> np.ndarray:
    """(K, 3) the (K, 2) points as seen from the sensor, scaled so that two points are close in
    azimuth and range (within ``link_azimuth_deg`` and ``link_radial_m``, an ellipse) when their
    distance is at most 1: the azimuth as a point on a circle of radius 1 / ``link_azimuth_deg``
    (chord ~ angle for small angles) and the range over ``link_radial_m``."""
    rng = np.hypot(points[:, 0], points[:, 1])
    unit = points / np.maximum(rng, 1e-9)[:, None] / np.deg2rad(config.link_azimuth_deg)
    return np.column_stack([unit, rng / config.link_radial_m])


def column_cells(centroid: np.ndarray, top: np.ndarray, bottom: np.ndarray, config: VerticalStructureConfig
                 ) -> np.ndarray:
    """(C,) True for the cells ((C, 2) ``centroid`` in the sensor's x-y plane, (C,) ``top`` and ``bottom``
    above the local ground) that stand as a column of returns: ``link_column_m`` high, alone or (with
    ``link_column_stack_m``) together with the cells in the same azimuth step (within a quarter of it)
    whose ranges differ from its by at most ``link_column_stack_m``: a tilted sensor cuts a far wall seen at
    grazing incidence in slanted streaks that cross several cells, none of them a metre high."""
    tall = top - bottom >= config.link_column_m
    if config.link_column_stack_m <= 0 or config.link_azimuth_steps <= 0 or len(tall) < 2:
        return tall
    from scipy.spatial import cKDTree

    step = np.deg2rad(config.link_azimuth_deg / config.link_azimuth_steps)
    rng = np.hypot(centroid[:, 0], centroid[:, 1])
    view = np.column_stack([centroid / np.maximum(rng, 1e-9)[:, None] / (0.25 * step),
                            rng / config.link_column_stack_m])
    pairs = cKDTree(view).query_pairs(1.0, output_type="ndarray")
    if len(pairs) == 0:
        return tall
    i = np.concatenate([pairs[:, 0], pairs[:, 1]])
    j = np.concatenate([pairs[:, 1], pairs[:, 0]])
    stack_top, stack_bottom = top.copy(), bottom.copy()      # over each cell and its direct neighbours only
    np.maximum.at(stack_top, i, top[j])
    np.minimum.at(stack_bottom, i, bottom[j])
    return stack_top - stack_bottom >= config.link_column_m


def _grazing_pairs(points: np.ndarray, columns: np.ndarray, config: VerticalStructureConfig) -> np.ndarray:
    """(P, 2) index pairs of ``columns`` ((K,) bool) among (K, 2) points one azimuth step apart that are not
    close in azimuth and range (see ``_sensor_view``) and whose ranges differ as on a wall seen up to
    ``link_grazing_deg`` from head-on."""
    if columns.sum() < 2 or config.link_grazing_deg <= 0 or config.link_azimuth_steps <= 0:
        return np.zeros((0, 2), np.int64)
    from scipy.spatial import cKDTree

    # Neighbouring azimuth steps on a wall seen up to link_grazing_deg from head-on: their ranges
    # differ by up to r * step * tan(grazing) (a relative change: log range).
    rng = np.hypot(points[:, 0], points[:, 1])
    step = np.deg2rad(config.link_azimuth_deg / config.link_azimuth_steps)
    tan = np.tan(np.deg2rad(config.link_grazing_deg))
    unit_step = points / np.maximum(rng, 1e-9)[:, None] / (1.5 * step)
    col = np.flatnonzero(columns)
    graze = cKDTree(np.column_stack([unit_step[col], np.log(np.maximum(rng[col], 1e-3)) / (1.5 * step * tan)]
                                    )).query_pairs(np.sqrt(2.0), output_type="ndarray")
    graze = col[graze.reshape(-1, 2)]
    i, j = graze[:, 0], graze[:, 1]
    dphi = _azimuth_gap(points[i], points[j])
    dr = np.abs(rng[i] - rng[j])
    # (Pairs within the azimuth-and-range ellipse are the other rule's; a range difference just below
    # link_radial_m one step apart lies outside it, and is this rule's.)
    apart = np.hypot.reduce(_sensor_view(points[i], config) - _sensor_view(points[j], config), axis=1) > 1.0
    keep = (dphi <= 1.5 * step) & apart & (dr <= np.minimum(rng[i], rng[j]) * dphi * tan)
    if config.link_grazing_max_m > 0:
        keep &= dr <= config.link_grazing_max_m
    return graze[keep]


def link_cells(centroids: np.ndarray, weights: np.ndarray, config: VerticalStructureConfig,
               columns: np.ndarray | None = None) -> np.ndarray:
    """(C,) line-piece label of each candidate cell (-1: no line through it).

    Each cell's direction is the dominant direction towards its neighbours (a weighted vote over
    5 degree bins), refined by a principal-axis fit to the neighbours within ``line_tolerance_m``
    of it. Linked cells (see the module docstring) are grouped by connected components.
    """
    n = len(centroids)
    pairs = neighbour_pairs(centroids, config, columns)
    if n < 2 or len(pairs) == 0:
        return np.full(n, -1)
    p, q = pairs[:, 0], pairs[:, 1]
    x, y = centroids[:, 0], centroids[:, 1]
    dx, dy = x[q] - x[p], y[q] - y[p]                        # one entry per undirected pair
    bins = 36
    b = (np.mod(np.arctan2(dy, dx), np.pi) * (bins / np.pi)).astype(np.int64)
    b = np.minimum(b, bins - 1)
    votes = (np.bincount(p * bins + b, weights=weights[q], minlength=n * bins)
             + np.bincount(q * bins + b, weights=weights[p], minlength=n * bins)).reshape(n, bins)
    around = np.concatenate([votes[:, -1:], votes, votes[:, :1]], axis=1)     # (n, bins + 2), cyclic
    votes += 0.5 * (around[:, :-2] + around[:, 2:])
    theta = (np.argmax(votes, axis=1) + 0.5) * (np.pi / bins)
    nx, ny = -np.sin(theta), np.cos(theta)
    # Refine each direction by a weighted principal axis of the neighbours on its dominant line
    # (moments about the cell itself; a pair seen from its other end has the opposite offset).
    # (The voted direction is a bin's centre: a far neighbour, linked as seen from the sensor, may
    # lie |d| sin(bin) off its line.)
    tol = config.line_tolerance_m
    dist = np.hypot(dx, dy)
    reach = tol + np.where(dist > config.link_radius_m, dist * np.sin(np.pi / bins), 0.0)
    at_p = np.abs(dx * nx[p] + dy * ny[p]) <= reach
    at_q = np.abs(dx * nx[q] + dy * ny[q]) <= reach
    owner = np.concatenate([p[at_p], q[at_q]])
    w = np.concatenate([weights[q[at_p]], weights[p[at_q]]])
    ddx, ddy = np.concatenate([dx[at_p], -dx[at_q]]), np.concatenate([dy[at_p], -dy[at_q]])
    total = np.bincount(owner, w, n) + weights
    mx = np.bincount(owner, w * ddx, n) / total
    my = np.bincount(owner, w * ddy, n) / total
    sxx = np.bincount(owner, w * ddx ** 2, n) / total - mx ** 2
    syy = np.bincount(owner, w * ddy ** 2, n) / total - my ** 2
    sxy = np.bincount(owner, w * ddx * ddy, n) / total - mx * my
    theta = 0.5 * np.arctan2(2 * sxy, sxx - syy)
    ux, uy = np.cos(theta), np.sin(theta)                     # direction; the normal is (-uy, ux)
    has_line = np.bincount(owner, minlength=n) >= config.min_support
    linked = has_line[p] & has_line[q]
    linked &= np.abs(ux[p] * ux[q] + uy[p] * uy[q]) >= np.cos(np.deg2rad(config.link_angle_deg))
    linked &= np.abs(dx * -uy[p] + dy * ux[p]) <= tol
    linked &= np.abs(dx * -uy[q] + dy * ux[q]) <= tol
    labels = connected_labels(n, p[linked], q[linked])
    labels[~has_line] = -1
    return labels


def connected_labels(n: int, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """(n,) connected-component label of each of n nodes joined by the (E,) undirected edges i-j,
    numbered in the order of each component's smallest node (as scipy's ``connected_components``).

    Every root takes the smallest root it shares an edge with, and the roots' chains are shortened
    until each node points at its root; this repeats until no edge joins two roots.
    """
    root = np.arange(n)
    while len(i):
        ri, rj = root[i], root[j]
        apart = ri != rj
        if not apart.any():
            break
        ri, rj = ri[apart], rj[apart]
        low = np.minimum(ri, rj)
        np.minimum.at(root, ri, low)
        np.minimum.at(root, rj, low)
        while True:
            up = root[root]
            if np.array_equal(up, root):
                break
            root = up
    return _labels(root)[1] if n else root


# --- stage 5: pieces (on cells) ------------------------------------------------------------------------

def _point_labels(cells: Cells, label: np.ndarray) -> np.ndarray:
    """(M,) the ``label`` ((C,) per candidate cell) of each point's cell; -1 for points in none (all of
    them when there is no candidate cell)."""
    if len(label) == 0:
        return np.full(len(cells.point_cell), -1)
    return np.where(cells.point_cell >= 0, label[np.maximum(cells.point_cell, 0)], -1)


def _group_lines(label: np.ndarray, cells: Cells, members: np.ndarray, n: int):
    """Exact TLS lines of groups of cells from their moments (parallel-axis theorem).

    ``members`` (K,) cell indices with ``label`` (K,) group numbers < n. Returns centroids (n, 2),
    unit directions (n, 2), point counts (n,) and mean squared distances of the points to the line (n,).
    """
    w = cells.count[members]
    c = cells.centroid[members]
    total = np.bincount(label, w, n)
    safe = np.maximum(total, 1)
    mean = np.column_stack([np.bincount(label, w * c[:, 0], n), np.bincount(label, w * c[:, 1], n)]) / safe[:, None]
    d = c - mean[label]
    sc = cells.scatter[members]
    sxx = np.bincount(label, sc[:, 0] + w * d[:, 0] ** 2, n)
    sxy = np.bincount(label, sc[:, 1] + w * d[:, 0] * d[:, 1], n)
    syy = np.bincount(label, sc[:, 2] + w * d[:, 1] ** 2, n)
    theta = 0.5 * np.arctan2(2 * sxy, sxx - syy)
    direction = np.column_stack([np.cos(theta), np.sin(theta)])
    # Scatter across the line: the smaller eigenvalue of the 2 x 2 scatter matrix.
    across = 0.5 * (sxx + syy) - np.sqrt(0.25 * (sxx - syy) ** 2 + sxy ** 2)
    return mean, direction, total, np.maximum(across, 0) / safe


def _azimuth_gap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle (rad) between the directions of (K, 2) points a and b as seen from the sensor."""
    return np.abs(np.angle((a[:, 0] + 1j * a[:, 1]) * np.conj(b[:, 0] + 1j * b[:, 1])))


def _configured_step_deg(config: VerticalStructureConfig) -> float | None:
    """The scan's azimuth step (degrees) as ``extract_vertical_structure`` put it into ``config``
    (``link_azimuth_deg`` = ``link_azimuth_steps`` steps), or None when ``link_azimuth_steps`` is 0."""
    return config.link_azimuth_deg / config.link_azimuth_steps if config.link_azimuth_steps > 0 else None


def sparse_pieces(a: np.ndarray, b: np.ndarray, max_gap: np.ndarray, step_deg: float,
                  config: VerticalStructureConfig) -> np.ndarray:
    """(K,) True where the piece a-b ((K, 2) ends) is *sparse*: its returns leave a gap longer than
    ``max_gap_m`` (``max_gap`` (K,)) and it spans at least ``min_azimuth_steps`` of ``step_deg`` (columns
    of a far wall seen at grazing incidence, metres apart; not two columns with nothing between)."""
    return ~_few_columns(a, b, step_deg, config) & (max_gap > config.max_gap_m)


def _few_columns(a: np.ndarray, b: np.ndarray, step_deg: float, config: VerticalStructureConfig) -> np.ndarray:
    """(K,) True where the piece a-b ((K, 2) ends) spans fewer than ``min_azimuth_steps`` azimuth steps
    of ``step_deg`` as seen from the sensor: one or two columns of returns."""
    return _azimuth_gap(a, b) < np.deg2rad(config.min_azimuth_steps * step_deg)


def cell_pieces(cells: Cells, group: np.ndarray, config: VerticalStructureConfig) -> tuple[np.ndarray, np.ndarray]:
    """(C,) piece label of each candidate cell from its line group (``group``, -1 = none; -1 = none) and
    (C,) True for the cells of pieces joined from single columns of returns (see ``merge_collinear``).

    Each group's line is fitted to its points; cells whose centroid lies farther than
    ``inlier_tolerance_m`` from it are dropped; the rest is cut where consecutive cells along the line
    are more than ``max_gap_m`` apart *and* more than ``link_azimuth_deg`` apart as seen from the
    sensor (a far or grazing wall's samples are sparse, not gapped); each piece is refitted, cleaned
    the same way, and collinear pieces whose ends are close are joined.
    """
    label = np.full(len(cells), -1)
    chain = np.zeros(len(cells), bool)
    members = np.flatnonzero(group >= 0)
    if len(members) == 0:
        return label, chain
    _, grp = _labels(group[members])
    for _ in range(2):
        n = int(grp.max()) + 1
        mean, direction, _, _ = _group_lines(grp, cells, members, n)
        rel = cells.centroid[members] - mean[grp]
        offset = rel[:, 0] * direction[grp, 1] - rel[:, 1] * direction[grp, 0]
        keep = np.abs(offset) <= config.inlier_tolerance_m
        members, grp = members[keep], grp[keep]
        if len(members) == 0:
            return label, chain
        along = (rel[keep] * direction[grp]).sum(1)
        order = np.lexsort((along, grp))
        members, grp, along = members[order], grp[order], along[order]
        c = cells.centroid[members]
        new = np.ones(len(members), bool)
        gap = (np.diff(along) > config.max_gap_m) & (_azimuth_gap(c[1:], c[:-1]) > np.deg2rad(config.link_azimuth_deg))
        new[1:] = (grp[1:] != grp[:-1]) | gap
        grp = np.cumsum(new) - 1
    label[members], chain[members] = merge_collinear(cells, members, grp, config)
    return label, chain


def _piece_ends(cells: Cells, members: np.ndarray, label: np.ndarray, n: int):
    """Lines and end points (from cell centroids) of pieces: mean, direction, count, msd, a (n, 2), b (n, 2)."""
    mean, direction, count, msd = _group_lines(label, cells, members, n)
    along = ((cells.centroid[members] - mean[label]) * direction[label]).sum(1)
    t_min = np.full(n, np.inf)
    t_max = np.full(n, -np.inf)
    np.minimum.at(t_min, label, along)
    np.maximum.at(t_max, label, along)
    return mean, direction, count, msd, mean + t_min[:, None] * direction, mean + t_max[:, None] * direction, along


def merge_collinear(cells: Cells, members: np.ndarray, piece: np.ndarray,
                    config: VerticalStructureConfig) -> tuple[np.ndarray, np.ndarray]:
    """Join pieces (labels ``piece`` of cells ``members``) of one line whose ends are close: within
    ``merge_gap_m``, or within ``link_azimuth_deg`` and ``link_radial_m`` as seen from the sensor, or,
    for two single columns of returns (pieces spanning fewer than ``min_azimuth_steps`` whose returns
    stand ``link_column_m`` high), one azimuth step apart as on a wall seen up to ``link_grazing_deg``
    from head-on (a far wall seen at grazing incidence: each column a streak a metre or two long along
    it, the next one metres farther). Returns the new (K,) labels and (K,) True for the cells of
    pieces joined from such columns."""
    n = int(piece.max()) + 1
    if n < 2 or config.merge_gap_m <= 0:
        return piece, np.zeros(len(piece), bool)
    _, u, _, _, a, b, _ = _piece_ends(cells, members, piece, n)
    ends = np.concatenate([a, b])
    step = _configured_step_deg(config)
    column = _few_columns(a, b, step, config) if step else np.zeros(n, bool)
    top, bottom = np.full(n, -np.inf), np.full(n, np.inf)
    np.maximum.at(top, piece, cells.top[members])
    np.minimum.at(bottom, piece, cells.bottom[members])
    column &= top - bottom >= config.link_column_m
    close = _close_pairs(ends, config.merge_gap_m, config)
    pairs = np.concatenate([close, _grazing_pairs(ends, np.concatenate([column, column]), config)])
    grazing = np.arange(len(pairs)) >= len(close)
    i, j = pairs[:, 0] % n, pairs[:, 1] % n
    normal = np.column_stack([-u[:, 1], u[:, 0]])
    mid = (a + b) / 2
    dm = mid[j] - mid[i]
    ok = i != j
    ok &= np.abs((u[i] * u[j]).sum(1)) >= np.cos(np.deg2rad(config.merge_angle_deg))
    ok &= np.abs((dm * normal[i]).sum(1)) <= config.merge_offset_m
    ok &= np.abs((dm * normal[j]).sum(1)) <= config.merge_offset_m
    joined = connected_labels(n, i[ok], j[ok])
    chain = np.zeros(n, bool)
    chain[joined[i[ok & grazing]]] = True
    return joined[piece], chain[joined[piece]]


def stray_cells(cells: Cells, label: np.ndarray, config: VerticalStructureConfig) -> np.ndarray:
    """(C,) True for the candidate cells in no piece (``label`` (C,) -1) or in one shorter than
    ``min_length_m``: the cells no wall is made of as they are."""
    out = label < 0
    members = np.flatnonzero(~out)
    if len(members):
        _, piece = _labels(label[members])
        _, _, _, _, a, b, _ = _piece_ends(cells, members, piece, int(piece.max()) + 1)
        out[members] = np.hypot(*(b - a).T)[piece] < config.min_length_m
    return out


def rejoin_corner_cells(cells: Cells, label: np.ndarray, stray: np.ndarray,
                        config: VerticalStructureConfig) -> np.ndarray:
    """(C,) piece labels: ``label`` ((C,) values >= 0 as the caller numbers its pieces, -1 = none) with
    the ``stray`` cells ((C,) bool; only those at -1 in ``label``) beside a corner given to the piece
    whose end they continue. ``label`` itself is returned when no cell changes.

    A stray cell joins the piece with the nearest end among those that lie within ``link_radius_m`` of
    it, when it lies outside that piece's extent along its line and within ``line_tolerance_m`` of the
    line, and a cell of another piece whose direction differs from that line's by ``CORNER_MIN_DEG`` or
    more lies within ``link_radius_m`` of it (the other face of a corner; it need not reach the line).
    One pass: a piece grows by at most ``link_radius_m`` at an end, and no two pieces are joined
    through a stray cell. When both faces of a corner have lost their corner cells, neither gets them
    back (the face seen head-on is the one whose cells outvote, and it keeps its own).

    Why: a cell next to a corner has the other face's cells among its neighbours, denser when that
    face is seen head-on; they can outvote the wall's direction in ``link_cells``, so the cell gets no
    line or one not linked to the wall, and the wall stops up to three cells short of its corner, or
    not, as the grid (fixed to the sensor) happens to cut the corner.
    """
    members = np.flatnonzero(label >= 0)
    stray_idx = np.flatnonzero(stray & (label < 0))
    if len(members) == 0 or len(stray_idx) == 0:
        return label
    from scipy.spatial import cKDTree

    piece_label, piece = _labels(label[members])
    n = len(piece_label)
    mean, direction, _, _, a, b, _ = _piece_ends(cells, members, piece, n)
    t_a, t_b = ((a - mean) * direction).sum(1), ((b - mean) * direction).sum(1)     # t_a <= t_b
    ends = np.concatenate([a, b])
    # (stray, piece end) pairs within link_radius_m whose stray lies outside the piece, on its line
    ends_near = cKDTree(ends).query_ball_point(cells.centroid[stray_idx], config.link_radius_m)
    k = np.repeat(np.arange(len(stray_idx)), [len(x) for x in ends_near])
    if len(k) == 0:
        return label
    end = np.concatenate([np.asarray(x, np.int64) for x in ends_near])
    target = end % n
    rel = cells.centroid[stray_idx[k]] - mean[target]
    along = (rel * direction[target]).sum(1)
    offset = np.abs(rel[:, 0] * direction[target, 1] - rel[:, 1] * direction[target, 0])
    ok = ((along < t_a[target]) | (along > t_b[target])) & (offset <= config.line_tolerance_m)
    k, end, target = k[ok], end[ok], target[ok]
    if len(k) == 0:
        return label
    # each stray cell's nearest end
    order = np.lexsort((np.hypot(*(cells.centroid[stray_idx[k]] - ends[end]).T), k))
    k, target = k[order], target[order]
    first = np.ones(len(k), bool)
    first[1:] = k[1:] != k[:-1]
    take, into = stray_idx[k[first]], target[first]
    # ... when a cell of a piece at a corner to that line lies within link_radius_m of it
    cells_near = cKDTree(cells.centroid[members]).query_ball_point(cells.centroid[take], config.link_radius_m)
    pair_of = np.repeat(np.arange(len(take)), [len(x) for x in cells_near])
    other = piece[np.concatenate([np.asarray(x, np.int64) for x in cells_near])]
    at_corner = np.abs((direction[other] * direction[into[pair_of]]).sum(1)) <= np.cos(np.deg2rad(CORNER_MIN_DEG))
    beside = np.zeros(len(take), bool)
    beside[pair_of[at_corner]] = True
    if not beside.any():
        return label
    out = label.copy()
    out[take[beside]] = piece_label[into[beside]]
    return out


# --- levelling ----------------------------------------------------------------------------------------

LEAN_BAND_M = 2.0
"""The lean of the walls is measured on returns at most this far above or below the sensor (metres),
where a tilt of a few degrees shifts a wall by less than a cell."""
LEAN_POINTS = 30000
"""About this many returns are enough to measure the lean (denser scans are thinned for it)."""
LEAN_MAX_RESIDUAL = 0.02
"""A piece whose lean differs from the common one by more than this (metres per metre) is left out."""


def wall_lean(xyz: np.ndarray, height: np.ndarray, cells: Cells, label: np.ndarray,
              config: VerticalStructureConfig, min_points: int = 30) -> np.ndarray:
    """(2,) the horizontal lean ``g`` of the world's vertical in the (N, 3) points' frame (metres of x, y
    per metre of z), measured from the lean of line pieces (``label`` per cell of ``cells``, -1 = none).

    A wall is vertical in the world; in the frame of a sensor that pitches and rolls with the road its
    returns drift sideways with height: the offset from the piece's line grows by ``n . g`` per metre
    (``n`` its normal). Every piece with >= ``min_points`` returns (``line_min_height_m`` up) spread over
    at least 0.5 m of height (standard deviation; 0.25 m of it not following the position along it), 2 m
    long and straight once its lean is taken out (rms <= 5 cm) gives one such equation (its lean and
    its line fitted together, :func:`lean_fit`: a grazing wall's slanted columns would turn a plain
    line); ``g`` is their least-squares solution weighted by that independent spread, refitted twice
    without the pieces that disagree by more than ``LEAN_MAX_RESIDUAL`` (clutter), and damped where
    the pieces do not constrain it (walls of one direction only: the lean along them moves nothing).
    At most ``MAX_TILT_DEG``. Zero when no piece qualifies.
    """
    point_piece = _point_labels(cells, label)
    member = np.flatnonzero((point_piece >= 0) & (height >= config.line_min_height_m))
    if len(member) == 0:
        return np.zeros(2)
    _, piece = _labels(point_piece[member])
    n = int(piece.max()) + 1
    pts = _rows(xyz, member)
    count = np.bincount(piece, minlength=n).astype(float)
    safe = np.maximum(count, 1)
    mean = np.column_stack([np.bincount(piece, pts[:, i], n) for i in range(3)]) / safe[:, None]
    d = pts - mean[piece]
    theta = 0.5 * np.arctan2(2 * np.bincount(piece, d[:, 0] * d[:, 1], n), np.bincount(piece, d[:, 0] ** 2 - d[:, 1] ** 2, n))
    normal = np.column_stack([-np.sin(theta), np.cos(theta)])
    offset = d[:, 0] * normal[piece, 0] + d[:, 1] * normal[piece, 1]
    along = d[:, 0] * -normal[piece, 1] + d[:, 1] * normal[piece, 0]
    szz = np.bincount(piece, d[:, 2] ** 2, n)
    turn, slope, unique = lean_fit(offset, along, d[:, 2], piece, n)
    rest = np.bincount(piece, (offset - turn[piece] * along - slope[piece] * d[:, 2]) ** 2, n) / safe
    t_min = np.full(n, np.inf)
    t_max = np.full(n, -np.inf)
    np.minimum.at(t_min, piece, along)
    np.maximum.at(t_max, piece, along)
    ok = (count >= min_points) & (szz / safe >= 0.25) & (unique / safe >= 0.25 ** 2) & (t_max - t_min >= 2.0)
    ok &= rest <= 0.05 ** 2
    if not ok.any():
        return np.zeros(2)
    nrm, s, w = normal[ok], slope[ok], unique[ok]
    g = np.zeros(2)
    for _ in range(3):
        A = (nrm * w[:, None]).T @ nrm
        A += np.eye(2) * (1e-3 * np.trace(A) + 1e-9)
        g = np.linalg.solve(A, (nrm * (w * s)[:, None]).sum(0))
        agree = np.abs(s - nrm @ g) <= LEAN_MAX_RESIDUAL
        if not agree.any():
            return np.zeros(2)
        w = np.where(agree, w, 0.0)
    limit = np.tan(np.deg2rad(MAX_TILT_DEG))
    norm = float(np.hypot(*g))
    return g * min(1.0, limit / norm) if norm > 0 else g


def scan_lean(xyz: np.ndarray, height: np.ndarray, tan_top: float, step: float | None,
              config: VerticalStructureConfig) -> np.ndarray:
    """(2,) the lean of the world's vertical in the frame of (N, 3) non-ground returns (``height`` (N,)
    above the local ground; ``step`` the scan's azimuth step in degrees, or None): ``wall_lean`` of
    the groups of linked cells (step 5) among the returns within ``LEAN_BAND_M`` of the sensor's height. Dense scans
    are thinned to about ``LEAN_POINTS`` returns by keeping every k-th azimuth step (the links reach
    k times as far), which leaves the walls' lean measurable at a fraction of the cost."""
    band = np.flatnonzero(np.abs(xyz[:, 2]) <= LEAN_BAND_M)
    k = int(np.ceil(len(band) / LEAN_POINTS))
    if k > 1 and step is not None:
        az_bin = np.floor((np.arctan2(xyz[band, 1], xyz[band, 0]) + np.pi) / np.deg2rad(step)).astype(np.int64)
        band = band[az_bin % k == 0]
        config = config.model_copy(update={"link_azimuth_deg": config.link_azimuth_deg * k})
    if len(band) < config.min_points:
        return np.zeros(2)
    xyz, height = _rows(xyz, band), height[band]
    cells = structure_cells(xyz, height, tan_top, config, lines_only=True)
    # The groups of linked cells are straight enough to measure a lean: no need to cut them into pieces.
    label = link_cells(cells.centroid, cells.count, config)
    return wall_lean(xyz, height, cells, label, config, min_points=max(10, 30 // k))


def level_rotation(g: np.ndarray) -> np.ndarray:
    """(3, 3) the smallest rotation that turns the leaning vertical (g_x, g_y, 1) into the z axis."""
    up = np.array([g[0], g[1], 1.0]) / np.sqrt(1.0 + g[0] ** 2 + g[1] ** 2)
    axis = np.array([up[1], -up[0], 0.0])              # up x e_z
    s, c = float(np.hypot(*axis[:2])), float(up[2])
    if s < 1e-12:
        return np.eye(3)
    k = axis / s
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * K + (1 - c) * K @ K


def unlevel_segments(result: ScanSegments, R: np.ndarray) -> ScanSegments:
    """Segments found in the levelled frame ``R @ sensor`` (``R`` (3, 3)) back in the sensor frame.

    Each wall is a vertical plane of the levelled frame; its line is given where that plane cuts the
    sensor's horizontal plane at the height of the segment's middle, so ``segments_to_world`` (which
    lifts both ends to ``z_mean``) puts it back on the wall exactly.
    """
    support = result.support_points
    if support is not None:
        support = (np.column_stack([support, np.zeros(len(support))]) @ R)[:, :2]
    if len(result) == 0:
        return replace(result, support_points=support)
    seg = result.segments
    up = R.T[:, 2]                                      # the levelled z axis in the sensor frame
    ends = [np.column_stack([seg[:, 2 * k], seg[:, 2 * k + 1], result.z_mean]) @ R for k in (0, 1)]
    z = 0.5 * (ends[0][:, 2] + ends[1][:, 2])
    moved = [e + ((z - e[:, 2]) / up[2])[:, None] * up for e in ends]
    shift = z - result.z_mean
    return replace(result, segments=np.column_stack([moved[0][:, :2], moved[1][:, :2]]), z_mean=z,
                   z_min=result.z_min + shift, z_max=result.z_max + shift, support_points=support)


# --- stage 6: walls -------------------------------------------------------------------------------------

def azimuth_step_deg(xyz: np.ndarray, rng: np.ndarray | None = None) -> float | None:
    """The scan's azimuth step (degrees) measured from its (N, 3) returns (``rng`` (N,): their horizontal
    ranges, if already known), or None.

    Returns beyond 10 m are grouped by elevation in 0.02 deg bins (one laser each, mostly); in each of
    the five fullest bins the median angle between azimuth-neighbours is a step estimate (a missed
    return doubles one gap, two lasers in one bin halve them); the smallest estimate is taken.
    """
    rng = np.hypot(xyz[:, 0], xyz[:, 1]) if rng is None else rng
    far = np.flatnonzero(rng > 10.0)
    if len(far) < 200:
        return None
    elevation = np.degrees(np.arctan2(xyz[far, 2], rng[far]))
    b = np.floor(elevation / 0.02).astype(np.int64)
    b -= b.min()
    estimates = []
    for ring in np.argsort(np.bincount(b))[-5:]:
        on = far[b == ring]
        gaps = np.diff(np.sort(np.degrees(np.arctan2(xyz[on, 1], xyz[on, 0]))))
        gaps = gaps[(gaps > 1e-4) & (gaps < 3.0)]
        if len(gaps) >= 20:
            estimates.append(float(np.median(gaps)))
    return min(estimates) if estimates else None


def elevation_step_deg(xyz: np.ndarray, azimuth_step: float, rng: np.ndarray | None = None) -> float | None:
    """The scan's typical beam spacing (degrees) from its (N, 3) returns beyond 15 m, or None: the
    median elevation difference of returns that follow each other in elevation within one azimuth
    step (every eighth azimuth bin is enough). ``rng`` (N,): their horizontal ranges, if already known."""
    rng = np.hypot(xyz[:, 0], xyz[:, 1]) if rng is None else rng
    far = np.flatnonzero(rng > 15.0)
    az_bin = np.floor((np.arctan2(xyz[far, 1], xyz[far, 0]) + np.pi) / np.deg2rad(azimuth_step)).astype(np.int64)
    far, az_bin = far[az_bin % 8 == 0], az_bin[az_bin % 8 == 0]
    if len(far) < 200:
        return None
    elevation = np.arctan2(xyz[far, 2], rng[far])
    order = _group_order(az_bin, elevation)
    gaps = np.diff(elevation[order])
    gaps = gaps[(az_bin[order][1:] == az_bin[order][:-1]) & (gaps > np.deg2rad(0.05)) & (gaps < np.deg2rad(5.0))]
    return float(np.degrees(np.median(gaps))) if len(gaps) >= 20 else None


def top_beam_tangent(xyz: np.ndarray, config: VerticalStructureConfig, rng: np.ndarray | None = None) -> float:
    """tan of the scan's top-beam elevation: the ``top_beam_quantile`` of z / range over returns beyond 3 m
    (``rng`` (N,): the (N, 3) returns' horizontal ranges, if already known)."""
    rng = np.hypot(xyz[:, 0], xyz[:, 1]) if rng is None else rng
    far = rng > 3.0
    if not far.any():
        return np.inf
    return float(np.quantile(xyz[far, 2] / rng[far], config.top_beam_quantile))


def top_beam_reach_from(xyz: np.ndarray, height: np.ndarray, tan_top: float, config: VerticalStructureConfig,
                        rng: np.ndarray | None = None) -> float:
    """Range (metres) from which the scan's top beam passes ``reach_min_m`` above the ground under the
    sensor (the median of z - height of the (N, 3) returns within 10 m), so that reaching it says a
    structure is taller than a car; 0 when the ground near the sensor is not seen or the top beam
    points down. ``rng`` (N,): the returns' horizontal ranges, if already known."""
    near = (np.hypot(xyz[:, 0], xyz[:, 1]) if rng is None else rng) <= 10.0
    if near.sum() < 10 or not np.isfinite(tan_top) or tan_top <= 0:
        return 0.0
    sensor_height = -float(np.median(xyz[near, 2] - height[near]))
    return max(0.0, (config.reach_min_m - sensor_height) / tan_top)


def _group_order(group: np.ndarray, value: np.ndarray) -> np.ndarray:
    """(K,) an order that sorts (K,) ``group`` labels (>= 0) and, within each group, their (K,) ``value``
    (equal values of a group in any order)."""
    k = len(value)
    by_value = np.argsort(value)
    if k and int(group.max()) < 2 ** 16:        # (a stable radix sort by group keeps each group's values in order)
        return by_value[np.argsort(group[by_value].astype(np.uint16), kind="stable")]
    rank = np.empty(k, np.int64)
    rank[by_value] = np.arange(k)
    return by_value[np.sort(group * k + rank) % k]


LABEL_TABLE_RATIO = 32
"""``_labels`` numbers labels by a table when their range is at most this many times their number (+ 65536) ..."""
LABEL_TABLE_MAX = 1 << 23
"""... and at most this many entries (9 bytes each: 75 MB), whatever the number of labels."""


def _labels(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(values, return_inverse=True)`` of (K,) integer labels (>= 0): the sorted distinct
    labels and the (K,) index of each value among them (by a table when the labels' range is small
    enough: up to ``LABEL_TABLE_RATIO`` times their number, at most ``LABEL_TABLE_MAX``; a scan's cell
    keys span about 20 times as many cells as it has returns, and the table takes a third of the time
    of sorting them)."""
    top = int(values.max()) + 1 if len(values) else 0
    if top == 0 or top > min(LABEL_TABLE_RATIO * len(values) + 65536, LABEL_TABLE_MAX):
        return np.unique(values, return_inverse=True)
    present = np.zeros(top, bool)
    present[values] = True
    distinct = np.flatnonzero(present)
    index = np.empty(top, np.intp)                 # (only the entries of present labels are written and read)
    index[distinct] = np.arange(len(distinct))
    return distinct, index[values]


def _group_median(group: np.ndarray, value: np.ndarray, n: int) -> np.ndarray:
    """(n,) median (the upper one of an even count) of ``value`` per ``group`` label; nan for empty groups."""
    order = _group_order(group, value)
    count = np.bincount(group, minlength=n)
    start = np.concatenate([[0], np.cumsum(count)[:-1]])
    out = np.full(n, np.nan)
    has = count > 0
    out[has] = value[order][start[has] + count[has] // 2]
    return out


@dataclass(frozen=True)
class PieceTests:
    """Which of n pieces pass each of a stage's tests, by name, in the order the extractor applies them
    (a piece is kept when it passes them all).

    Attributes:
        a, b: (n, 2) the pieces' ends (the levelled velodyne frame of :func:`extract_vertical_structure`).
        passed: test name -> (n,) bool, True where the piece passes that test.
        cell_piece: (C,) the piece of each cell in ``[0, n)``, -1 for none (the height tests only; None for
            the final ones, which are made on :class:`PieceMeasures`, one row per piece).
        measured: name -> (n,) some of what the tests looked at, for a reader (``returns``; names ending in
            ``_m`` are metres, heights above the local ground).
    """

    a: np.ndarray
    b: np.ndarray
    passed: dict[str, np.ndarray]
    cell_piece: np.ndarray | None = None
    measured: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def kept(self) -> np.ndarray:
        """(n,) True for the pieces that pass every test."""
        kept = np.ones(len(self.a), bool)
        for passed in self.passed.values():
            kept &= passed
        return kept

    def failed(self, k: int) -> list[str]:
        """The names of the tests piece ``k`` fails, in order."""
        return [name for name, passed in self.passed.items() if not passed[k]]

    def velodyne_segments(self, rotation: np.ndarray) -> np.ndarray:
        """(n, 4) the pieces' ends turned back from the levelled frame (``x_levelled = rotation @ x``) into
        the velodyne frame at height 0: within a few centimetres of the wall's line there where the sensor
        leans by a degree or two (a wall's line is exact at its own height, see :func:`unlevel_segments`)."""
        ends = [(np.column_stack([e, np.zeros(len(e))]) @ rotation)[:, :2] for e in (self.a, self.b)]
        return np.column_stack(ends)

    @staticmethod
    def empty(cells: int | None = None) -> "PieceTests":
        """No piece (of ``cells`` cells, none in a piece; None: the final tests, made on no cells)."""
        return PieceTests(a=np.zeros((0, 2)), b=np.zeros((0, 2)), passed={},
                          cell_piece=None if cells is None else np.full(cells, -1))


def kept_cells(tests: PieceTests) -> np.ndarray:
    """(C,) the piece label of each cell whose piece passes every one of the height ``tests``
    (:func:`height_tests`); -1 = none."""
    piece = tests.cell_piece
    keep = piece >= 0
    keep[keep] = tests.kept[piece[keep]]
    return np.where(keep, piece, -1)


def height_tests(cells: Cells, label: np.ndarray, config: VerticalStructureConfig) -> PieceTests:
    """The tests on the pieces' cells (``label`` (C,) per cell, -1 = none) before the final per-point
    ones: enough returns (``points``), ``length``, spread of the cells about the piece's line (``rms``),
    height ``span``, ``top``, ``reaches_down`` (short pieces), ``tall`` (one of its ways),
    ``not_crown_underside`` (``floating_min_top_m``) and ``not_trunk`` (``trunk_max_share``).

    Heights are judged along the piece, in ``COLUMN_M`` columns: its top is the median of its columns'
    highest points, and it reaches the top beam when at least half of its columns do (within
    ``envelope_margin_m`` or ``envelope_margin_deg``), so a tree crown hanging over a fence does not
    make the fence a wall; columns whose top is hidden by something in front count for neither.
    Long pieces (``solid_length_m``) may float, and may be seen over a narrow band when they reach
    the top beam, or cut by a single beam where the beams lie far apart (``one_ring_min_length_m``);
    shorter ones must reach down near the ground (see the module docstring).
    """
    members = np.flatnonzero(label >= 0)
    if len(members) == 0:
        return PieceTests.empty(len(cells))
    _, piece = _labels(label[members])
    n = int(piece.max()) + 1
    cell_piece = np.full(len(cells), -1)
    cell_piece[members] = piece
    _, _, count, msd, a, b, along = _piece_ends(cells, members, piece, n)
    t_min = np.full(n, np.inf)
    np.minimum.at(t_min, piece, along)
    column = np.floor((along - t_min[piece]) / COLUMN_M).astype(np.int64)
    _, col = _labels(piece * (int(column.max()) + 1) + column)
    n_col = int(col.max()) + 1
    col_piece = np.zeros(n_col, np.int64)
    col_piece[col] = piece
    col_top = np.full(n_col, -np.inf)
    np.maximum.at(col_top, col, cells.top[members])
    reaching = np.zeros(n_col, bool)
    np.logical_or.at(reaching, col, cells.reaches_top[members])
    hidden = np.ones(n_col, bool)
    np.logical_and.at(hidden, col, cells.hidden_above[members])
    # The piece's top: the median of its columns' tops, over the columns whose top is seen (a tree
    # crown over a fence does not lift it; one in front of a wall does not lower it).
    seen_col = ~hidden | reaching
    # Columns whose top beam stopped in front of them (a tree crown, a van) do not count, unless too
    # few are seen: then those few may be the ones a crown hangs over, and every column counts.
    seen = np.bincount(col_piece, seen_col, n)
    columns = np.bincount(col_piece, minlength=n)
    enough = seen >= MIN_SEEN_FRACTION * columns
    seen_col &= enough[col_piece]
    seen = np.where(enough, seen, 0)
    top = _group_median(col_piece[seen_col], col_top[seen_col], n)
    top = np.where(np.isnan(top), _group_median(col_piece, col_top, n), top)
    reaches_top = (seen > 0) & (np.bincount(col_piece, reaching & seen_col, n) >= 0.5 * seen)
    bottom = np.full(n, np.inf)
    np.minimum.at(bottom, piece, cells.bottom[members])
    # How far each cell's lowest return floats above the ground, less one beam spacing at its range
    # (a far wall's lowest returns can be a beam apart, and the lowest of them counts as ground).
    spacing = np.hypot(cells.centroid[members, 0], cells.centroid[members, 1]) * np.tan(np.deg2rad(config.elevation_step_deg))
    floats = np.full(n, np.inf)
    np.minimum.at(floats, piece, cells.bottom[members] - spacing)
    cells_per_piece = np.bincount(piece, minlength=n)
    length = np.hypot(*(b - a).T)
    floating_short = _floating_short_pieces(cells, members, piece, col, col_piece, col_top, spacing, n, config)
    trunk = _trunk_pieces(cells, members, piece, along, spacing, n, config)

    def in_half_of_its_cells(flag: np.ndarray | None) -> np.ndarray:
        """(n,) the pieces with ``flag`` (per cell, or None: off) in at least half of their cells."""
        if flag is None:
            return np.zeros(n, bool)
        return np.bincount(piece, flag[members], n) >= 0.5 * cells_per_piece

    # With short_hidden_below, a piece whose bottom is hidden by something in front in at least half of its
    # cells (cells, not columns) may float: rays pass under a crown, not under a wall seen over a hedge.
    hidden_below = in_half_of_its_cells(cells.hidden_below)
    # With cut_above_counts_as_tall, a piece whose top is cut by something in front in at least half of its
    # cells is as tall as the sensor can tell, like one that reaches the top beam.
    cut_above = in_half_of_its_cells(cells.cut_above)
    solid = length >= config.solid_length_m
    passed = {"points": count >= np.where(solid, config.solid_min_points, config.min_points),
              "length": length >= config.min_length_m,
              "rms": np.sqrt(msd) <= config.max_rms_m}
    # A long piece that stops the top beam may be seen over a narrow band (a hedge in front, an
    # uphill street under the beam): it is higher than the beam there, which is above cars.
    seen_to_top = solid & reaches_top
    min_span = np.where(seen_to_top, config.solid_min_span_m, config.min_span_m)
    if config.one_ring_min_length_m > 0:
        # Where the beams lie farther apart in height than min_span_m, a long wall may be cut by one beam
        # (a 16-beam sensor's beams are 3.5 m apart at 100 m): its returns span nothing in height.
        piece_spacing = np.full(n, np.inf)
        np.minimum.at(piece_spacing, piece, spacing)
        one_ring = (length >= config.one_ring_min_length_m) & (piece_spacing >= config.min_span_m) & (top >= config.tall_m)
        min_span = np.where(one_ring, 0.0, min_span)
    passed["span"] = top - bottom >= min_span
    passed["top"] = top >= np.where(seen_to_top, config.cell_min_top_m, config.min_top_m)
    passed["reaches_down"] = (floats <= np.where(solid, np.inf, config.short_max_bottom_m)) | hidden_below
    passed["tall"] = (reaches_top | cut_above | (top >= config.tall_m)
                      | ((length >= config.long_m) & (top >= config.long_min_top_m)))
    passed["not_crown_underside"] = ~(floating_short & (length < config.long_m))
    passed["not_trunk"] = ~(trunk & (length < config.solid_length_m))
    return PieceTests(a=a, b=b, passed=passed, cell_piece=cell_piece,
                      measured={"returns": count, "top_m": top, "bottom_m": bottom})


def _settled_cells(cells: Cells, members: np.ndarray, spacing: np.ndarray, config: VerticalStructureConfig) -> np.ndarray:
    """(K,) the cells ``members`` (K,) that reach down: their lowest return, less ``spacing`` (K,), one beam
    spacing at their range, within ``short_max_bottom_m`` of the ground, or their bottom hidden in front."""
    settled = cells.bottom[members] - spacing <= config.short_max_bottom_m
    if cells.hidden_below is not None:
        settled |= cells.hidden_below[members]
    return settled


def _floating_short_pieces(cells: Cells, members: np.ndarray, piece: np.ndarray, col: np.ndarray,
                           col_piece: np.ndarray, col_top: np.ndarray, spacing: np.ndarray, n: int,
                           config: VerticalStructureConfig) -> np.ndarray:
    """(n,) pieces that float over most of their length in low, thin columns (``floating_min_top_m``).

    A column (``COLUMN_M`` along the piece) is settled when one of its cells is (:func:`_settled_cells`: its
    lowest return, less one beam spacing at its range, within ``short_max_bottom_m`` of the ground, or its
    bottom hidden by something in front, ``Cells.hidden_below``); else it floats, and a floating column is low and thin when its top is
    below ``floating_min_top_m`` and its height span below ``floating_min_span_m``. A piece settled in at
    most half of its columns, at least half of whose floating columns are low and thin, is flagged: a
    tree's trunk is one settled column, and the underside of its crown curving towards the sensor beside
    it is seen in thin slivers 2-4 m up, where a wall's upper storey seen over a lower roof stands higher.
    """
    if config.floating_min_top_m <= 0:
        return np.zeros(n, bool)
    n_col = len(col_piece)
    col_bottom = np.full(n_col, np.inf)
    np.minimum.at(col_bottom, col, cells.bottom[members])
    settled = np.zeros(n_col, bool)
    np.logical_or.at(settled, col, _settled_cells(cells, members, spacing, config))
    low_thin = ~settled & (col_top < config.floating_min_top_m) & (col_top - col_bottom < config.floating_min_span_m)
    columns = np.bincount(col_piece, minlength=n)
    n_settled = np.bincount(col_piece, settled, n)
    return (n_settled <= 0.5 * columns) & (np.bincount(col_piece, low_thin, n) >= 0.5 * (columns - n_settled)) \
        & (n_settled < columns)


def _trunk_pieces(cells: Cells, members: np.ndarray, piece: np.ndarray, along: np.ndarray, spacing: np.ndarray,
                  n: int, config: VerticalStructureConfig) -> np.ndarray:
    """(n,) pieces that reach down over a narrow stretch only, beside low, thin cells (``trunk_max_share``).

    ``members`` (K,): the pieces' cells, ``piece`` (K,) their piece in ``[0, n)``, ``along`` (K,) their
    position along it (metres), ``spacing`` (K,) one beam spacing at their range. A cell is settled when
    its lowest return, less that spacing, is within ``short_max_bottom_m`` of the ground or its bottom is
    hidden in front (``Cells.hidden_below``), else it floats, and a floating cell is low and thin as in
    :func:`_floating_short_pieces`. A piece some but not all of whose cells are settled is flagged when its
    settled cells span less than ``trunk_max_share`` of the span of all its cells and at least half of its
    floating cells are low and thin: a tree's trunk, 0.3-0.5 m wide, reaches the ground, and the underside
    of its crown beside it is seen in thin slivers 2-4 m up. In 0.5 m columns (``floating_min_top_m``) a
    trunk often straddles two of a 1.5 m piece's three columns, so that test sees it settled in most of
    them. A wall reaches down, or is hidden below, along all of its length.
    """
    if config.trunk_max_share <= 0:
        return np.zeros(n, bool)
    settled = _settled_cells(cells, members, spacing, config)
    top, bottom = cells.top[members], cells.bottom[members]
    low_thin = ~settled & (top < config.floating_min_top_m) & (top - bottom < config.floating_min_span_m)
    lo, hi = np.full(n, np.inf), np.full(n, -np.inf)
    np.minimum.at(lo, piece, along)
    np.maximum.at(hi, piece, along)
    settled_lo, settled_hi = np.full(n, np.inf), np.full(n, -np.inf)
    np.minimum.at(settled_lo, piece[settled], along[settled])
    np.maximum.at(settled_hi, piece[settled], along[settled])
    cells_per_piece = np.bincount(piece, minlength=n)
    n_settled = np.bincount(piece, settled, n)
    return (n_settled > 0) & (n_settled < cells_per_piece) \
        & (settled_hi - settled_lo < config.trunk_max_share * (hi - lo)) \
        & (np.bincount(piece, low_thin, n) >= 0.5 * (cells_per_piece - n_settled))


@dataclass(frozen=True)
class PieceMeasures:
    """What the final tests look at, per piece (n pieces), from the points of each piece's cells.

    Attributes:
        a, b: (n, 2) ends (extreme projections of the inliers on their TLS line).
        count: (n,) inlier points at least ``line_min_height_m`` up (they place the line);
        n_points: (n,) inliers of any height; z_min, z_max: (n,) their height range (velodyne frame);
        z_mean: (n,) mean height of the ``count`` returns (where the line holds).
        rms: (n,) rms distance of the inliers to the line.
        core: (n,) share of inliers within ``core_m`` of the median offset of their 0.5 m column.
        behind: (n,) non-ground points up to ``BEHIND_M`` behind the line (seen from the sensor), per inlier.
        max_gap: (n,) longest stretch of the line between two consecutive inliers.
        column_curve: (n,) median distance of the inliers' positions along the line from their best fit on
            height, azimuth and their product (a wall seen in one or two columns of returns: the straight
            lines where the columns' slanted sheets of beams cut it, ~1 cm; a round thing: a curve); only
            for pieces spanning fewer than ``min_azimuth_steps`` (0 for the others).
        column_chain: (n,) the piece was joined from single columns of returns one azimuth step apart (a far
            wall seen at grazing incidence, see ``merge_collinear``); None = none was.
        sparse_curve, sparse_offset, sparse_within: (n,) see :func:`sparse_columns`; None when neither
            ``sparse_curve_factor`` nor ``sparse_offset_factor`` is set.
        through: (n,) share of the returns whose rays cross the piece's line that lie beyond it (see
            :func:`seen_through`), for the pieces with gaps longer than ``max_gap_m`` spanning at least
            ``min_azimuth_steps`` (0 for the others); None when ``sparse_max_through`` is not set.
    """

    a: np.ndarray
    b: np.ndarray
    count: np.ndarray
    n_points: np.ndarray
    z_mean: np.ndarray
    z_min: np.ndarray
    z_max: np.ndarray
    rms: np.ndarray
    core: np.ndarray
    behind: np.ndarray
    max_gap: np.ndarray
    column_curve: np.ndarray
    column_chain: np.ndarray | None = None
    sparse_curve: np.ndarray | None = None
    sparse_offset: np.ndarray | None = None
    sparse_within: np.ndarray | None = None
    through: np.ndarray | None = None

    @property
    def length(self) -> np.ndarray:
        return np.hypot(*(self.b - self.a).T)


def piece_measures(xyz: np.ndarray, height: np.ndarray, cells: Cells, label: np.ndarray,
                   config: VerticalStructureConfig, max_lean_deg: float = None,
                   chain: np.ndarray | None = None) -> PieceMeasures | None:
    """Measures of the pieces (``label`` per cell, -1 = none) from the (M, 3) non-ground points ``xyz``
    (``height`` (M,) above the ground) that ``cells`` was made of. Only points at least
    ``line_min_height_m`` up and within ``inlier_tolerance_m`` of the piece's line (refitted once
    after dropping the others) count; distances to the line are taken about its lean (see
    ``_untilted``). ``chain`` (C,): the cells of pieces joined from single columns. None when no piece
    is left."""
    point_piece = _point_labels(cells, label)
    low = height < config.line_min_height_m
    member = np.flatnonzero((point_piece >= 0) & ~low)
    if len(member) == 0:
        return None
    labels, piece = _labels(point_piece[member])
    n = int(piece.max()) + 1
    for _ in range(2):
        pts = _rows(xyz, member)
        count = np.bincount(piece, minlength=n).astype(float)
        safe = np.maximum(count, 1)
        mean = np.column_stack([np.bincount(piece, pts[:, 0], n), np.bincount(piece, pts[:, 1], n)]) / safe[:, None]
        dx, dy = pts[:, 0] - mean[piece, 0], pts[:, 1] - mean[piece, 1]
        theta = 0.5 * np.arctan2(2 * np.bincount(piece, dx * dy, n), np.bincount(piece, dx * dx - dy * dy, n))
        u = np.column_stack([np.cos(theta), np.sin(theta)])
        offset = _untilted(dx * u[piece, 1] - dy * u[piece, 0], pts[:, 2], piece, n,
                           MAX_TILT_DEG if max_lean_deg is None else max_lean_deg)
        keep = np.abs(offset) <= config.inlier_tolerance_m
        member, piece = member[keep], piece[keep]
        if len(member) == 0:
            return None
    along = dx[keep] * u[piece, 0] + dy[keep] * u[piece, 1]
    offset = offset[keep]
    t_min = np.full(n, np.inf)
    t_max = np.full(n, -np.inf)
    np.minimum.at(t_min, piece, along)
    np.maximum.at(t_max, piece, along)
    count = np.bincount(piece, minlength=n).astype(float)
    safe = np.maximum(count, 1)
    # Heights and the number of returns include the piece's lower returns on its line.
    lower = np.flatnonzero((point_piece >= 0) & low)
    lower_piece = np.minimum(np.searchsorted(labels, point_piece[lower]), n - 1)
    rel = xyz[lower, :2] - mean[lower_piece]
    on = np.abs(rel[:, 0] * u[lower_piece, 1] - rel[:, 1] * u[lower_piece, 0]) <= config.inlier_tolerance_m
    on &= labels[lower_piece] == point_piece[lower]
    z_piece = np.concatenate([piece, lower_piece[on]])
    z = np.concatenate([xyz[member, 2], xyz[lower[on], 2]])
    z_min = np.full(n, np.inf)
    z_max = np.full(n, -np.inf)
    np.minimum.at(z_min, z_piece, z)
    np.maximum.at(z_max, z_piece, z)
    all_count = np.bincount(z_piece, minlength=n).astype(float)
    # Thinness along the wall: distance of each point to the median offset of its 0.5 m column (a
    # facade's recesses shift whole columns; foliage scatters the points of every column).
    column = np.floor((along - t_min[piece]) / COLUMN_M).astype(np.int64)
    _, col = _labels(piece * (int(column.max()) + 1) + column)
    col_median = _group_median(col, offset, int(col.max()) + 1)
    a = mean + t_min[:, None] * u
    b = mean + t_max[:, None] * u
    max_gap = _max_gap(piece, along, n)
    # z_mean: the height at which the line was fitted (the mean of the returns that placed it), where
    # segments_to_world lifts it; with a tilted sensor another height would shift the wall sideways.
    return PieceMeasures(a=a, b=b, count=count, n_points=all_count, z_mean=np.bincount(piece, xyz[member, 2], n) / safe,
                         z_min=z_min, z_max=z_max,
                         rms=np.sqrt(np.bincount(piece, offset ** 2, n) / safe),
                         core=np.bincount(piece, np.abs(offset - col_median[col]) <= config.core_m, n) / safe,
                         behind=_points_behind(cells, a, b, config) / safe,
                         max_gap=max_gap,
                         column_curve=_narrow_column_curve(_rows(xyz, member), along, piece, mean, a, b, config),
                         column_chain=None if chain is None else np.isin(labels, label[chain]),
                         **_sparse_measures(_rows(xyz, member), along, offset, piece, mean, n, config),
                         **_through_measure(xyz, a, b, z_min, z_max, max_gap, config))


def _through_measure(xyz: np.ndarray, a: np.ndarray, b: np.ndarray, z_min: np.ndarray, z_max: np.ndarray,
                     max_gap: np.ndarray, config: VerticalStructureConfig) -> dict:
    """The ``through`` field of :class:`PieceMeasures` (none when ``sparse_max_through`` is off)."""
    step = _configured_step_deg(config)
    if step is None or config.sparse_max_through <= 0:
        return {}
    through = np.zeros(len(a))
    sparse = np.flatnonzero(sparse_pieces(a, b, max_gap, step, config))
    if len(sparse):
        through[sparse] = seen_through(xyz, a[sparse], b[sparse], z_min[sparse], z_max[sparse], np.deg2rad(step))
    return {"through": through}


def seen_through(xyz: np.ndarray, a: np.ndarray, b: np.ndarray, z_min: np.ndarray, z_max: np.ndarray,
                 step_rad: float) -> np.ndarray:
    """(n,) share of the returns whose rays cross each line a-b that lie beyond it: a wall hides what is
    behind it; a row of trees, poles or parked cars seen obliquely, lined up like a wall, does not.

    A return counts for a line when its azimuth (as seen from the sensor) lies within the line's, half an
    azimuth step in from either end, and its ray crosses the line between ``THROUGH_BAND_M`` above the
    line's ``z_min`` and below its ``z_max``; it lies beyond when it is more than ``THROUGH_BEYOND_M``
    farther along its ray. Lines no counting ray crosses get 0.

    Args:
        xyz: (M, 3) returns in a frame whose origin is the sensor and whose z axis is vertical (metres).
        a, b: (n, 2) the lines' ends (same frame); z_min, z_max: (n,) their returns' height range.
        step_rad: the scan's azimuth step (radians).
    """
    out = np.zeros(len(a))
    azimuth = np.arctan2(xyz[:, 1], xyz[:, 0])
    order = np.argsort(azimuth)
    sorted_azimuth = azimuth[order]
    centre = np.angle((a[:, 0] + b[:, 0]) + 1j * (a[:, 1] + b[:, 1]))
    to_centre = np.exp(-1j * centre)
    for k in range(len(a)):                              # a line not through the sensor spans < pi
        lo, hi = np.angle((a[k, 0] + 1j * a[k, 1]) * to_centre[k]), np.angle((b[k, 0] + 1j * b[k, 1]) * to_centre[k])
        lo, hi = min(lo, hi) + step_rad / 2, max(lo, hi) - step_rad / 2
        if hi <= lo:
            continue
        rows = []
        for start, end in _wrapped_ranges(centre[k] + lo, centre[k] + hi):
            rows.append(order[np.searchsorted(sorted_azimuth, start):np.searchsorted(sorted_azimuth, end)])
        p = xyz[np.concatenate(rows)]
        normal = np.array([a[k, 1] - b[k, 1], b[k, 0] - a[k, 0]])
        rng = np.hypot(p[:, 0], p[:, 1])
        towards = (p[:, 0] * normal[0] + p[:, 1] * normal[1]) / np.maximum(rng, 1e-9)
        with np.errstate(divide="ignore", invalid="ignore"):
            cross = (a[k] @ normal) / towards                # range at which each ray crosses the line
            cross_z = p[:, 2] * cross / rng
        counting = (cross > 0) & (cross_z > z_min[k] + THROUGH_BAND_M[0]) & (cross_z < z_max[k] - THROUGH_BAND_M[1])
        n_counting = int(counting.sum())
        if n_counting:
            out[k] = float((counting & (rng > cross + THROUGH_BEYOND_M)).sum()) / n_counting
    return out


def _wrapped_ranges(start: float, end: float) -> list[tuple[float, float]]:
    """The azimuth range ``start``..``end`` (radians, ``end - start`` < 2 pi) as ranges within [-pi, pi]."""
    if start < -np.pi:
        return [(start + 2 * np.pi, np.pi), (-np.pi, end)]
    if end > np.pi:
        return [(start, np.pi), (-np.pi, end - 2 * np.pi)]
    return [(start, end)]


def _sparse_measures(pts: np.ndarray, along: np.ndarray, offset: np.ndarray, piece: np.ndarray, mean: np.ndarray,
                     n: int, config: VerticalStructureConfig) -> dict:
    """The ``sparse_*`` fields of :class:`PieceMeasures` (all None when their tests are off)."""
    step = _configured_step_deg(config)
    if step is None or (config.sparse_curve_factor <= 0 and config.sparse_offset_factor <= 0):
        return {}
    curve, spread, within = sparse_columns(pts, along, offset, piece, mean, n, config.max_gap_m,
                                           np.deg2rad(config.min_azimuth_steps * step))
    return {"sparse_curve": curve, "sparse_offset": spread, "sparse_within": within}


def sparse_columns(pts: np.ndarray, along: np.ndarray, offset: np.ndarray, piece: np.ndarray, mean: np.ndarray,
                   n: int, gap_m: float, column_rad: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """How straight and how coplanar the columns of returns of each piece are.

    A piece's returns are cut into stretches where they leave a gap along it longer than ``gap_m``; a
    stretch spanning less than ``column_rad`` in azimuth (as seen from the sensor) with >= 4 returns is
    a *column* (one azimuth of a far wall seen at grazing incidence: the columns lie metres apart).

    Args:
        pts: (K, 3) the pieces' returns (levelled frame, metres); ``along``, ``offset``: (K,) their
            positions along and across their piece's line; ``piece``: (K,) labels 0..n-1.
        mean: (n, 2) each piece's centre (its azimuth is the reference for the returns').
    Returns:
        curve: (n,) median |residual| of the ``along`` positions of the returns of the piece's columns
            after a least-squares fit per column on height and lateral position (a wall column is a
            straight line; a tree crown's depth follows its round); 0 for a piece with no column.
        offset_spread: (n,) rms over the piece's returns of the mean offset of their stretch;
        within: (n,) rms of the returns' offsets about their stretch's mean.
    """
    curve, spread, within = np.zeros(n), np.zeros(n), np.zeros(n)
    if len(piece) == 0:
        return curve, spread, within
    order = np.lexsort((along, piece))
    p, t, off, q = piece[order], along[order], offset[order], pts[order]
    new = np.ones(len(p), bool)
    new[1:] = (p[1:] != p[:-1]) | (np.diff(t) > gap_m)
    stretch = np.cumsum(new) - 1
    m = int(stretch[-1]) + 1
    count = np.bincount(stretch, minlength=m).astype(float)
    per_piece = np.maximum(np.bincount(p, minlength=n), 1).astype(float)
    centre = mean[p, 0] + 1j * mean[p, 1]
    azimuth = np.angle((q[:, 0] + 1j * q[:, 1]) * np.conj(centre))
    lo, hi = np.full(m, np.inf), np.full(m, -np.inf)
    np.minimum.at(lo, stretch, azimuth)
    np.maximum.at(hi, stretch, azimuth)
    column = (count >= 4) & (hi - lo < column_rad)

    def centred(v):
        return v - (np.bincount(stretch, v, m) / count)[stretch]

    x = np.column_stack([np.ones(len(t)), centred(q[:, 2]), centred(azimuth * np.abs(centre))])
    residual = _group_residuals(x, centred(t), stretch, m, np.ones(len(t)))
    use = column[stretch]
    if use.any():
        has = np.bincount(p[use], minlength=n) > 0
        curve[has] = _group_median(p[use], residual[use], n)[has]
    stretch_offset = np.bincount(stretch, off, m) / count
    spread = np.sqrt(np.bincount(p, stretch_offset[stretch] ** 2, n) / per_piece)
    within = np.sqrt(np.bincount(p, (off - stretch_offset[stretch]) ** 2, n) / per_piece)
    return curve, spread, within


def _narrow_column_curve(pts: np.ndarray, along: np.ndarray, piece: np.ndarray, mean: np.ndarray, a: np.ndarray,
                         b: np.ndarray, config: VerticalStructureConfig) -> np.ndarray:
    """:func:`_column_curve` of the pieces (ends ``a``, ``b`` (n, 2)) spanning fewer than
    ``min_azimuth_steps`` of the scan's azimuth steps (the only ones the wall test asks it of); 0 for the
    others, and for all when the scan's step is not known (``link_azimuth_steps`` = 0)."""
    n = len(a)
    out = np.zeros(n)
    step = _configured_step_deg(config)
    if step is None:
        return out
    narrow = np.flatnonzero(_few_columns(a, b, step, config))
    if len(narrow) == 0:
        return out
    index = np.full(n, -1)
    index[narrow] = np.arange(len(narrow))
    keep = index[piece] >= 0
    out[narrow] = _column_curve(pts[keep], along[keep], index[piece[keep]], mean[narrow], len(narrow))
    return out


def _column_curve(pts: np.ndarray, along: np.ndarray, piece: np.ndarray, mean: np.ndarray, n: int) -> np.ndarray:
    """(n,) median absolute residual of each piece's (K,) ``along`` positions of its (K, 3) points ``pts``
    after a least-squares fit (refitted once without the returns more than three medians off) on their
    height, their azimuth (as seen from the sensor, relative to the direction
    of the piece's centre ``mean`` (n, 2)) and their product (each column of returns cuts a wall in a
    line of its own slope); ``piece`` (K,) labels the points."""
    centre = mean[piece, 0] + 1j * mean[piece, 1]
    azimuth = np.angle((pts[:, 0] + 1j * pts[:, 1]) * np.conj(centre))
    count = np.maximum(np.bincount(piece, minlength=n), 1).astype(float)

    def centred(v):
        return v - (np.bincount(piece, v, n) / count)[piece]

    def scaled(v):                                       # unit spread per piece: a well-conditioned fit
        v = centred(v)
        return v / np.sqrt(np.maximum(np.bincount(piece, v * v, n) / count, 1e-30))[piece]

    z, az = scaled(pts[:, 2]), scaled(azimuth)
    x = np.column_stack([np.ones(len(z)), z, az, scaled(z * az)])
    y = along
    weight = np.ones(len(y))
    for _ in range(2):                                   # fit, then refit without returns 3 medians off
        residual = _group_residuals(x, y, piece, n, weight)
        median = _group_median(piece, residual, n)
        weight = (residual <= 3 * median[piece] + 1e-9).astype(float)
    return median


def _group_residuals(x: np.ndarray, y: np.ndarray, group: np.ndarray, n: int, weight: np.ndarray) -> np.ndarray:
    """(K,) |y - x @ coef[group]| after a weighted least-squares fit per group: ``x`` (K, P) regressors, ``y``
    (K,), ``group`` (K,) labels 0..n-1, ``weight`` (K,). Rank-deficient groups take the minimum-norm fit."""
    p = x.shape[1]
    normal = np.stack([np.stack([np.bincount(group, weight * x[:, i] * x[:, j], n) for j in range(p)], -1)
                       for i in range(p)], -2)                                                       # (n, P, P)
    rhs = np.stack([np.bincount(group, weight * x[:, i] * y, n) for i in range(p)], -1)[..., None]  # (n, P, 1)
    coef = (np.linalg.pinv(normal, rcond=1e-9) @ rhs)[..., 0]                                     # (n, P)
    return np.abs(y - (x * coef[group]).sum(-1))


def _max_gap(piece: np.ndarray, along: np.ndarray, n: int) -> np.ndarray:
    """(n,) longest gap between consecutive ``along`` positions (K,) of each piece (``piece`` (K,))."""
    order = _group_order(piece, along)
    g, t = piece[order], along[order]
    gap = np.zeros(n)
    same = g[1:] == g[:-1]
    np.maximum.at(gap, g[1:][same], np.diff(t)[same])
    return gap


def _untilted(offset: np.ndarray, z: np.ndarray, piece: np.ndarray, n: int, max_deg: float = MAX_TILT_DEG) -> np.ndarray:
    """Offsets (K,) from a piece's line minus their linear trend with height (at most ``MAX_TILT_DEG``).

    A wall is vertical in the world, not in the sensor's frame when the vehicle pitches or rolls:
    a 1 deg tilt moves a 10 m high wall's top 17 cm sideways. The trend is measured about the
    piece's mean height, so the line itself (through the centroid) stays where it is.
    """
    count = np.maximum(np.bincount(piece, minlength=n), 1)
    dz = z - (np.bincount(piece, z, n) / count)[piece]
    slope = np.bincount(piece, offset * dz, n) / np.maximum(np.bincount(piece, dz * dz, n), 1e-9)
    limit = np.tan(np.deg2rad(max_deg))
    return offset - np.clip(slope, -limit, limit)[piece] * dz


def lean_fit(offset: np.ndarray, along: np.ndarray, dz: np.ndarray, piece: np.ndarray,
             n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per piece, the turn ``b`` and lean ``c`` (both metres per metre) of ``offset ~ b along + c dz``.

    ``offset``, ``along`` (K,): each point's distance from its piece's line through the piece's
    centroid and position along it; ``dz`` (K,): its height above the piece's mean height; ``piece``
    (K,) in ``[0, n)``. A wall leans in a tilted sensor's frame (its offset grows with height). Where
    its returns also climb along it (a wall at grazing incidence, each column of returns slanting
    across it), a line fitted in the top view turns to follow part of that lean, and the lean left
    about that line is too small: fitting both together measures all of it. Only the part of the
    height spread that does not follow the position along the line tells a lean from a turn, so
    also returns that part's (n,) sum of squares, the weight of the lean (about 0 for one column).
    """
    saa = np.maximum(np.bincount(piece, along * along, n), 1e-9)
    saz = np.bincount(piece, along * dz, n)
    sao = np.bincount(piece, along * offset, n)
    unique = np.maximum(np.bincount(piece, dz * dz, n) - saz * saz / saa, 0.0)
    lean = (np.bincount(piece, dz * offset, n) - saz * sao / saa) / np.maximum(unique, 1e-9)
    turn = (sao - lean * saz) / saa
    return turn, lean, unique


def _points_behind(cells: Cells, a: np.ndarray, b: np.ndarray, config: VerticalStructureConfig) -> np.ndarray:
    """(n,) non-ground points in the band from ``inlier_tolerance_m`` to ``BEHIND_M`` behind each (n, 2)
    a-b line, on the side away from the sensor (a solid wall hides that band; foliage does not)."""
    if len(cells.grid_keys) == 0:                   # no low non-ground point anywhere: nothing behind any line
        return np.zeros(len(a))
    step = cells.grid_origin[0]
    length = np.hypot(*(b - a).T)
    u = (b - a) / np.maximum(length, 1e-9)[:, None]
    away = np.column_stack([-u[:, 1], u[:, 0]])
    away *= np.where(((a + b) / 2 * away).sum(1) < 0, -1.0, 1.0)[:, None]
    n_along = np.ceil(length / step).astype(np.int64) + 1
    offsets = np.arange(config.inlier_tolerance_m + step / 2, BEHIND_M, step)
    owner = np.repeat(np.arange(len(a)), n_along)
    t = (np.arange(len(owner)) - np.repeat(np.cumsum(n_along) - n_along, n_along)) * step
    t = np.minimum(t, np.repeat(length, n_along))
    base = a[owner] + t[:, None] * u[owner]
    owner = np.repeat(owner, len(offsets))
    xy = np.repeat(base, len(offsets), axis=0) + np.tile(offsets, len(base))[:, None] * away[owner]
    # Count each grid cell once per line.
    size, i0, j0, width = cells.grid_origin
    key = (np.floor(xy[:, 0] / size).astype(np.int64) - i0) * width + (np.floor(xy[:, 1] / size).astype(np.int64) - j0)
    _, first = np.unique(owner * (cells.grid_keys.max() + width + 1) + key, return_index=True)
    return np.bincount(owner[first], cells.points_at(xy[first]), len(a))


def wall_segments(measures: PieceMeasures | None, config: VerticalStructureConfig,
                  azimuth_step_deg: float | None = None) -> ScanSegments:
    """The pieces that pass the final tests (:func:`final_tests`) as segments (in the frame of
    ``measures``). ``azimuth_step_deg``: the scan's (None: not measured; the column test then takes
    ``link_azimuth_deg / link_azimuth_steps``)."""
    return kept_segments(measures, final_tests(measures, config, azimuth_step_deg))


def kept_pieces(measures: PieceMeasures, tests: PieceTests) -> np.ndarray:
    """(K,) the rows of ``measures`` that pass every one of the final ``tests``, sorted by first end (x, then y)."""
    sel = np.flatnonzero(tests.kept)
    return sel[np.lexsort((measures.a[sel, 1], measures.a[sel, 0]))]


def kept_segments(measures: PieceMeasures | None, tests: PieceTests) -> ScanSegments:
    """The pieces of ``measures`` (None: no piece) that pass every one of the final ``tests``, as segments
    (:func:`kept_pieces`)."""
    if measures is None:
        return ScanSegments.empty()
    m = measures
    sel = kept_pieces(measures, tests)
    if len(sel) == 0:
        return ScanSegments.empty()
    return ScanSegments(segments=np.column_stack([m.a[sel], m.b[sel]]), z_mean=m.z_mean[sel],
                        n_points=m.n_points[sel].astype(np.int64), z_min=m.z_min[sel], z_max=m.z_max[sel],
                        rms=m.rms[sel], max_gap=m.max_gap[sel])


def final_tests(measures: PieceMeasures | None, config: VerticalStructureConfig,
                azimuth_step_deg: float | None = None) -> PieceTests:
    """The final tests on the pieces' returns (``measures``; None: no piece), in order: enough returns
    (``points``), ``length``, spread (``rms``), thinness (``core``), opacity (``behind``), not seen edge-on
    (``incidence``); with the scan's azimuth step (``azimuth_step_deg``, None: not measured, see
    :func:`wall_segments`), not two columns with nothing between (``two_columns``), straight when seen in
    one or two columns (``column_curve``), and, for pieces whose returns leave gaps (``sparse_pieces``),
    straight in each column (``sparse_curve``), on one line (``sparse_offset``) and hiding what is behind
    them (``sparse_through``); then spread against the scan's long walls (``typical_spread``) and, for the
    sparse ones, against its range noise (``sparse_noise_curve``). A test that is off passes every piece."""
    if measures is None:
        return PieceTests.empty()
    m = measures
    solid = m.length >= config.solid_length_m
    passed = {"points": m.count >= np.where(solid, config.solid_min_points, config.min_points),
              "length": m.length >= config.min_length_m,
              "rms": m.rms <= config.max_rms_m,
              "core": m.core >= config.min_core_fraction,
              "behind": m.behind <= config.max_behind}
    mid = (m.a + m.b) / 2
    along_ray = np.abs(((m.b - m.a) * mid).sum(1)) / np.maximum(m.length * np.hypot(mid[:, 0], mid[:, 1]), 1e-9)
    passed["incidence"] = along_ray <= np.sin(np.deg2rad(config.max_incidence_deg))
    if azimuth_step_deg is None:
        azimuth_step_deg = _configured_step_deg(config)
    sparse = np.zeros(len(m.a), bool)
    if azimuth_step_deg:
        two_columns = _few_columns(m.a, m.b, azimuth_step_deg, config)
        passed["two_columns"] = ~(two_columns & (m.max_gap > config.max_gap_m))
        # Seen in one or two columns, a wall is where their slanted sheets of beams cut it: straight
        # lines in height and azimuth. A tree crown seen from afar curves (its depth follows its round).
        passed["column_curve"] = ~(two_columns & (m.column_curve > config.max_column_curve_m))
        # Seen in columns metres apart (a far wall at grazing incidence), each column is such a line, and
        # the columns lie on one: a row of trees or parked cars seen that obliquely is neither.
        sparse = sparse_pieces(m.a, m.b, m.max_gap, azimuth_step_deg, config)
        if m.sparse_curve is not None and config.sparse_curve_factor > 0:
            passed["sparse_curve"] = ~(sparse & (m.sparse_curve > config.max_column_curve_m))
        if m.sparse_offset is not None and config.sparse_offset_factor > 0:
            passed["sparse_offset"] = ~(sparse & (m.sparse_offset > config.sparse_offset_factor * m.sparse_within
                                                  + config.sparse_offset_floor_m))
        if m.through is not None and config.sparse_max_through > 0:
            passed["sparse_through"] = ~(sparse & (m.through > config.sparse_max_through))
    wall = np.logical_and.reduce(list(passed.values()))     # (the tests so far)
    # A piece must be about as thin as this scan's long walls are (not those joined from single columns:
    # seen at grazing incidence, their range noise lies along the wall). A wall's returns scatter across it
    # by the range noise times the cosine of their incidence, so the long walls that set a long piece's bar
    # are those seen within NOISE_MAX_INCIDENCE_DEG of head-on (their spread is the sensor's noise; 3 of
    # them, else all long walls): where most long walls are far walls seen obliquely, theirs would put it
    # below the spread of a near wall seen head-on. Short pieces keep all long walls' median (crown facets).
    typical_of = wall & solid if m.column_chain is None else wall & solid & ~m.column_chain
    if config.typical_spread_skips_sparse:
        typical_of &= ~sparse
    cos_incidence = np.sqrt(np.maximum(1.0 - along_ray ** 2, 0.0))
    noise_of = typical_of & (cos_incidence >= np.cos(np.deg2rad(NOISE_MAX_INCIDENCE_DEG)))
    if typical_of.sum() >= 3:
        typical = float(np.median(m.rms[typical_of]))
        typical_solid = float(np.median(m.rms[noise_of])) if noise_of.sum() >= 3 else typical
        passed["typical_spread"] = m.rms <= np.where(solid, config.solid_rms_factor * typical_solid,
                                                     config.short_rms_factor * typical)
        if m.sparse_curve is not None and config.sparse_curve_factor > 0 and azimuth_step_deg:
            # A column's returns lie along its ray, so they scatter along the wall by the range noise: the
            # scan's range noise is its long walls' spread over the cosine of their incidence (those
            # within NOISE_MAX_INCIDENCE_DEG of head-on: an oblique wall's spread would underrate it).
            if noise_of.sum() >= 3:
                noise = float(np.median(m.rms[noise_of] / cos_incidence[noise_of]))
                passed["sparse_noise_curve"] = ~(sparse & (m.sparse_curve > config.sparse_curve_factor * noise))
    return PieceTests(a=m.a, b=m.b, passed=passed,
                      measured={"returns": m.count, "rms_m": m.rms, "core": m.core, "behind": m.behind})


# --- stage 8: walls hidden above --------------------------------------------------------------------------

def extend_hidden_ends(result: ScanSegments, xyz: np.ndarray, height: np.ndarray,
                       config: VerticalStructureConfig) -> ScanSegments:
    """``result`` with each wall's ends moved along its line over its hidden low returns.

    ``xyz`` (M, 3): the non-ground returns in the frame of ``result`` (the levelled frame; sensor at
    the origin), ``height`` (M,) above the local ground. A low return (below ``line_min_height_m``)
    within ``inlier_tolerance_m`` of a wall's line and at most ``extend_hidden_m`` past one of its ends
    continues the wall when its column (the returns in its azimuth bin and the two next to it, bins
    one of the scan's azimuth steps wide, ``link_azimuth_deg / link_azimuth_steps``) is hidden above:
    the first return above the column's highest return on the line lies nearer than that one by more
    than ``inlier_tolerance_m``. An end moves to the farthest such return reached from it without a
    gap longer than ``max_gap_m`` (returns whose column is not hidden are no stepping stones; a stretch
    of them shorter than that is crossed); ``max_gap`` grows by the gaps crossed. Walls whose ends
    meet are joined (:func:`_join_reached`) and the result is ordered by first endpoint again. The
    returns' heights and number are not updated. Approximate: the bins do not wrap at +-180 deg, so
    a column right behind the sensor is judged on one side of it only.

    Why: only returns ``line_min_height_m`` up place a wall, so a bush or a tree crown in front of a garden
    wall ends it where its upper part disappears behind them, though the wall goes on below. A fence
    or a hedge in line with a wall is not joined: its top is seen (the rays above it pass over).
    """
    if config.extend_hidden_m <= 0 or len(result) == 0:
        return result
    low = np.flatnonzero(height < config.line_min_height_m)
    if len(low) == 0:
        return result
    seg = result.segments
    length = np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1])
    u = (seg[:, 2:] - seg[:, :2]) / np.maximum(length, 1e-12)[:, None]
    ends = np.concatenate([seg[:, :2], seg[:, 2:]])                        # (2K, 2): every a, then every b
    out_dir = np.concatenate([-u, u])                                       # away from the wall
    tol = config.inlier_tolerance_m
    end, point = _returns_past_ends(xyz[low, :2], ends, out_dir, config.extend_hidden_m, tol)
    point = low[point]
    rel = xyz[point, :2] - ends[end]
    past = (rel * out_dir[end]).sum(1)
    offset = np.abs(rel[:, 0] * out_dir[end, 1] - rel[:, 1] * out_dir[end, 0])
    keep = (past > 0) & (past <= config.extend_hidden_m) & (offset <= tol)
    end, point, past = end[keep], point[keep], past[keep]
    if len(end) == 0:
        return result
    hidden = _hidden_above(xyz, end, point, ends, out_dir, config)
    end, past = end[hidden], past[hidden]
    moved = np.zeros(len(ends))
    crossed = np.zeros(len(ends))
    order = np.lexsort((past, end))
    end, past = end[order], past[order]
    first = np.ones(len(end), bool)
    first[1:] = end[1:] != end[:-1]
    gap = np.where(first, past, np.diff(past, prepend=0.0))          # from the end, then return to return
    # an end stops before its first gap longer than max_gap_m
    wide = gap > config.max_gap_m
    wide_so_far = np.cumsum(wide)
    group = np.cumsum(first) - 1
    reach = wide_so_far - (wide_so_far - wide)[first][group] == 0
    np.maximum.at(moved, end[reach], past[reach])
    np.maximum.at(crossed, end[reach], gap[reach])
    if not moved.any():
        return result
    k = len(seg)
    new_ends = ends + moved[:, None] * out_dir
    max_gap = result.max_gap
    if max_gap is not None:
        max_gap = np.maximum(max_gap, np.maximum(crossed[:k], crossed[k:]))
    extended = replace(result, segments=np.column_stack([new_ends[:k], new_ends[k:]]), max_gap=max_gap)
    return _by_first_end(_join_reached(extended, (moved[:k] > 0) | (moved[k:] > 0), config))


def _by_first_end(result: ScanSegments) -> ScanSegments:
    """``result`` ordered by first endpoint (x, then y), as :func:`wall_segments` orders it."""
    seg = result.segments
    order = np.lexsort((seg[:, 1], seg[:, 0]))
    if np.array_equal(order, np.arange(len(seg))):
        return result
    pick = lambda x: None if x is None else x[order]
    return replace(result, segments=seg[order], n_points=result.n_points[order], rms=result.rms[order],
                   z_mean=pick(result.z_mean), z_min=pick(result.z_min), z_max=pick(result.z_max),
                   max_gap=pick(result.max_gap))


def _returns_past_ends(xy: np.ndarray, ends: np.ndarray, out_dir: np.ndarray, reach: float, tol: float):
    """(end, point) index pairs ((P,) each) of the (N, 2) points ``xy`` that may lie within ``reach`` past
    ``ends`` (E, 2) along ``out_dir`` (E, 2) and within ``tol`` of that line: those in the grid cells
    (of side ``reach + 2 tol``, so each end's stretch meets at most 2 x 2 of them) its stretch meets."""
    side = reach + 2 * tol
    cell = np.floor(xy / side).astype(np.int64)
    far = ends + reach * out_dir
    first = np.floor((np.minimum(ends, far) - tol) / side).astype(np.int64)
    last = np.floor((np.maximum(ends, far) + tol) / side).astype(np.int64)
    # every (end, cell) its stretch meets: first + (0 or 1) per axis, up to last
    e = np.repeat(np.arange(len(ends)), 4)
    c = np.repeat(first, 4, axis=0) + np.tile([[0, 0], [0, 1], [1, 0], [1, 1]], (len(ends), 1))
    ok = (c <= last[e]).all(1)
    e, c = e[ok], c[ok]
    low = np.minimum(cell.min(0), c.min(0))
    width = int(max(cell[:, 1].max(), c[:, 1].max()) - low[1]) + 1
    key = (cell[:, 0] - low[0]) * width + (cell[:, 1] - low[1])
    wanted = (c[:, 0] - low[0]) * width + (c[:, 1] - low[1])
    table = np.zeros(int(max(key.max(), wanted.max())) + 1, bool)
    table[wanted] = True
    sel = np.flatnonzero(table[key])
    sel = sel[np.argsort(key[sel], kind="stable")]
    sorted_key = key[sel]
    lo, hi = np.searchsorted(sorted_key, wanted, "left"), np.searchsorted(sorted_key, wanted, "right")
    owner, at = _ranges(lo, hi)
    return e[owner], sel[at]


def _ranges(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ranges ``lo[k] .. hi[k] - 1`` ((K,) each) one after another: (owner k (S,), index (S,))."""
    n = hi - lo
    owner = np.repeat(np.arange(len(n)), n)
    return owner, np.arange(n.sum()) - (np.cumsum(n) - n)[owner] + lo[owner]


def _join_reached(result: ScanSegments, moved: np.ndarray, config: VerticalStructureConfig) -> ScanSegments:
    """Join the walls of ``result`` on one line (directions within ``merge_angle_deg``, the ends of the
    one with fewer returns within ``merge_offset_m`` of the other's line) that overlap
    or lie within ``max_gap_m`` of each other along it, where one of them was extended (``moved`` (K,)):
    a wall hidden above in its middle was two pieces, and their extensions meet. The joined wall lies
    on the line of its member with the most returns, from the extreme projection of their ends
    ((K, 4) segments in the frame of ``result``); returns are added, spreads and mean heights weighted by
    them, heights their extremes, and ``max_gap`` the largest of the members' own and of the stretches
    between them that none covers. Joined walls take the place of their first member: the order is not
    kept (see :func:`_by_first_end`)."""
    seg = result.segments
    k = len(seg)
    i, j = np.triu_indices(k, 1)
    pair = moved[i] | moved[j]
    i, j = i[pair], j[pair]
    if len(i) == 0:
        return result
    a, b = seg[:, :2], seg[:, 2:]
    length = np.hypot(*(b - a).T)
    u = (b - a) / np.maximum(length, 1e-12)[:, None]
    normal = np.column_stack([-u[:, 1], u[:, 0]])
    ok = np.abs((u[i] * u[j]).sum(1)) >= np.cos(np.deg2rad(config.merge_angle_deg))
    # the ends of the one with fewer returns lie on the other's line
    major = np.where(result.n_points[i] >= result.n_points[j], i, j)
    minor = i + j - major
    for end in (a, b):
        ok &= np.abs(((end[minor] - a[major]) * normal[major]).sum(1)) <= config.merge_offset_m
    # along the major's line: the gap between the two intervals
    t_a, t_b = ((a[minor] - a[major]) * u[major]).sum(1), ((b[minor] - a[major]) * u[major]).sum(1)
    gap = np.maximum(np.minimum(t_a, t_b) - length[major], -np.maximum(t_a, t_b))
    ok &= gap <= config.max_gap_m
    if not ok.any():
        return result
    _, group = np.unique(connected_labels(k, i[ok], j[ok]), return_inverse=True)
    n = int(group.max()) + 1
    weight = result.n_points.astype(float)
    order = np.lexsort((-weight, group))
    lead = order[np.searchsorted(group[order], np.arange(n))]    # the member with the most returns (first of ties)
    base, direction = a[lead[group]], u[lead[group]]
    t = np.column_stack([((a - base) * direction).sum(1), ((b - base) * direction).sum(1)])
    lo = np.full(n, np.inf)
    hi = np.full(n, -np.inf)
    np.minimum.at(lo, group, t.min(1))
    np.maximum.at(hi, group, t.max(1))
    start, stop = a[lead] + lo[:, None] * u[lead], a[lead] + hi[:, None] * u[lead]
    total = np.bincount(group, weight, n)
    safe = np.maximum(total, 1)

    def extreme(values, fn, fill):
        if values is None:
            return None
        out = np.full(n, fill)
        fn.at(out, group, values)
        return out

    def weighted(values):
        return None if values is None else np.bincount(group, weight * values, n) / safe

    max_gap = extreme(result.max_gap, np.maximum, -np.inf)
    if max_gap is not None:
        # the joined members' own gaps, and any stretch between them that none covers
        t_lo, t_hi = t.min(1), t.max(1)
        along = np.lexsort((t_lo, group))
        g, t_lo, t_hi = group[along], t_lo[along], t_hi[along]
        first = np.ones(len(g), bool)
        first[1:] = g[1:] != g[:-1]
        # the farthest end reached by the members before each one, within its group
        reached = t_hi.copy()
        for m in np.flatnonzero(~first):        # (a few members per joined wall)
            reached[m] = max(reached[m - 1], t_hi[m])
        between = np.where(first, 0.0, t_lo - np.roll(reached, 1))
        np.maximum.at(max_gap, g, np.maximum(between, 0.0))
    return replace(result, segments=np.column_stack([start, stop]), n_points=total.astype(np.int64),
                   rms=np.sqrt(weighted(result.rms ** 2)), z_mean=weighted(result.z_mean),
                   z_min=extreme(result.z_min, np.minimum, np.inf), z_max=extreme(result.z_max, np.maximum, -np.inf),
                   max_gap=max_gap)


def _hidden_above(xyz: np.ndarray, end: np.ndarray, point: np.ndarray, ends: np.ndarray, out_dir: np.ndarray,
                  config: VerticalStructureConfig) -> np.ndarray:
    """(P,) True where the column of low return ``point`` (P,) (indices into ``xyz`` (M, 3)), on the
    line through ``ends[end]`` along ``out_dir[end]`` ((E, 2) each), is hidden above: among the
    returns in its azimuth bin and the two next to it (bins of one azimuth step), the first one above
    (in elevation) the highest on that line is nearer than that one by more than ``inlier_tolerance_m``.
    Columns are shared: each (line, azimuth bin) is judged once."""
    step = np.deg2rad(_configured_step_deg(config) or config.link_azimuth_deg)
    col = np.floor(np.arctan2(xyz[:, 1], xyz[:, 0]) / step).astype(np.int64)
    col -= col.min() - 1                                     # >= 1, so bin - 1 is a valid index
    # the returns of the bins next to a tested one, by bin; their range and elevation
    wanted = np.zeros(int(col.max()) + 2, bool)
    wanted[col[point] - 1], wanted[col[point]], wanted[col[point] + 1] = True, True, True
    near = np.flatnonzero(wanted[col])
    near = near[np.argsort(col[near], kind="stable")]
    sorted_col = col[near]
    rng_near = np.hypot(xyz[near, 0], xyz[near, 1])
    elevation_near = np.arctan2(xyz[near, 2], rng_near)
    # one test per (line, bin); its column: the returns in bins bin-1 .. bin+1
    key = end * (int(col.max()) + 2) + col[point]
    unique, first_of, inverse = np.unique(key, return_index=True, return_inverse=True)
    u_end = end[first_of]
    u_bin = col[point[first_of]]
    lo = np.searchsorted(sorted_col, u_bin - 1, side="left")
    hi = np.searchsorted(sorted_col, u_bin + 1, side="right")
    test, at = _ranges(lo, hi)
    idx = near[at]
    rel = xyz[idx, :2] - ends[u_end[test]]
    d = out_dir[u_end[test]]
    on = np.abs(rel[:, 0] * d[:, 1] - rel[:, 1] * d[:, 0]) <= config.inlier_tolerance_m
    rng, elevation = rng_near[at], elevation_near[at]
    top = np.full(len(unique), -np.inf)
    np.maximum.at(top, test[on], elevation[on])
    top_range = np.full(len(unique), np.nan)
    at_top = on & (elevation == top[test])
    top_range[test[at_top]] = rng[at_top]
    above = elevation > top[test]
    next_up = np.full(len(unique), np.inf)
    np.minimum.at(next_up, test[above], elevation[above])
    first_above = above & (elevation == next_up[test])
    front = np.zeros(len(unique), bool)
    front[test[first_above]] = rng[first_above] < top_range[test[first_above]] - config.inlier_tolerance_m
    return front[inverse]


# --- the extractor --------------------------------------------------------------------------------------

def extract_vertical_structure(points, config: VerticalStructureConfig = VerticalStructureConfig(),
                               timings: dict[str, float] | None = None, trace: dict | None = None) -> ScanSegments:
    """Wall segments of one scan from its vertical structure (see the module docstring).

    Args:
        points: (N, 3) or (N, 4) velodyne-frame points (x forward, y left, z up; metres); any order.
        config: extraction parameters.
        timings: if given, seconds spent per stage are added to it (crop, ground, cells, lines,
            pieces, walls).
        trace: if given, why each piece was kept or dropped is put in it (the result is the same):
            ``"height"`` the :class:`PieceTests` of the pieces of cells (:func:`height_tests`), ``"final"``
            those of the pieces that passed them, on their returns (:func:`final_tests`), ``"measures"``
            the :class:`PieceMeasures` of the latter, ``"xyz"`` the (M, 3) returns above the ground and
            ``"config"`` the parameters with the scan's measured sampling, all in the levelled frame whose
            rotation from the velodyne frame is ``"rotation"`` (3, 3) (``x_levelled = R @ x_velodyne``).
            Stays empty when the scan has too few returns for any piece.
    Returns:
        ScanSegments in the velodyne frame, sorted by first endpoint (possibly empty).
    Raises:
        FeatmapError: points that are not an (N, >=3) numeric array, or with NaN/inf coordinates.
    """
    clock = StageClock(timings)
    xyz = validated_xyz(points)
    rng = np.hypot(xyz[:, 0], xyz[:, 1])
    in_range = (rng >= config.min_range_m) & (rng <= config.max_range_m)
    if not in_range.all():
        xyz, rng = _rows(xyz, in_range), rng[in_range]
    clock.lap("crop")
    if len(xyz) < config.min_points:
        return ScanSegments.empty()
    height = heights_above_local_ground(xyz, config)
    tan_top = top_beam_tangent(xyz, config, rng)
    reach_from = top_beam_reach_from(xyz, height, tan_top, config, rng)
    step = azimuth_step_deg(xyz, rng) if config.link_azimuth_steps > 0 else None
    if step is not None:                       # later stages see the scan's own sampling
        update = {"link_azimuth_deg": config.link_azimuth_steps * step}
        beams = elevation_step_deg(xyz, step, rng)
        if beams is not None:
            update["elevation_step_deg"] = beams
        config = config.model_copy(update=update)
    clock.lap("ground")
    above = height > config.ground_margin_m
    xyz, height, rng = _rows(xyz, above), height[above], rng[above]
    if len(xyz) < config.min_points:
        return ScanSegments.empty()
    sensor_xyz, R = xyz, None
    if config.level:
        g = scan_lean(xyz, height, tan_top, step, config)
        if np.hypot(*g) > 1e-4:
            R = level_rotation(g)
            # (Sums of products, not a matrix product: BLAS threads would spin on a busy machine.)
            xyz = np.empty_like(sensor_xyz, order="F")
            for k in range(3):
                xyz[:, k] = sensor_xyz[:, 0] * R[k, 0] + sensor_xyz[:, 1] * R[k, 1] + sensor_xyz[:, 2] * R[k, 2]
        clock.lap("level")
    cells = structure_cells(xyz, height, tan_top, config, sensor_xyz, reach_from, sensor_rng=rng)
    clock.lap("cells")
    group = link_cells(cells.centroid, cells.count, config,
                       column_cells(cells.centroid, cells.top, cells.bottom, config))
    clock.lap("lines")
    label, chain = cell_pieces(cells, group, config)
    clock.lap("pieces")
    stray = stray_cells(cells, label, config)
    heights = height_tests(cells, label, config)
    label = kept_cells(heights)
    chain &= label >= 0                  # (a rejoined stray cell from a chain of columns does not make its new piece one)
    label = rejoin_corner_cells(cells, label, stray, config)
    lean = config.max_lean_deg if R is not None else None
    measures = piece_measures(xyz, height, cells, label, config, lean, chain)
    finals = final_tests(measures, config, step)
    if trace is not None:
        trace.update(height=heights, final=finals, measures=measures, xyz=xyz, config=config,
                     rotation=np.eye(3) if R is None else R)
    result = kept_segments(measures, finals)
    result = extend_hidden_ends(result, xyz, height, config)
    result = replace(result, support_points=cells.centroid)
    if R is not None:
        result = unlevel_segments(result, R)
    clock.lap("walls")
    return result


EXTRACTOR = Extractor(name="vertical_structure", dimension=3, config_type=VerticalStructureConfig,
                      extract=extract_vertical_structure, version=15)
