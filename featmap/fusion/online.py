"""The proposed method one scan at a time (online mapping).

:class:`OnlineFusion` keeps the state of the link forest (:mod:`featmap.fusion.link_forest`) between
scans: a uniform grid of the segments seen so far, grouped per cell by connected component, and the
union-find of the components. :meth:`OnlineFusion.add_scan` links a new scan's segments to those of
the earlier scans with the very kernel the offline method runs (scans in increasing order, each segment
against the groups near it); its cost depends on how many groups of *other* components lie near the new
segments, not on the size of the map nor on how often its walls were seen before (a wall seen a
hundred times is one group per cell, met once). :meth:`OnlineFusion.fused` turns everything seen so far
into the fused map: clusters, support filter, fit, the shared refinement and the corner optimisation.
That costs about linear time in the map's size, so an online mapper calls it every few scans, not after
each one.

Why it is the offline map: the link forest's components and first-link scans do not depend on the grid
(see :mod:`featmap.fusion.link_forest`), and the pairs whose criteria lie within rounding of a threshold
are decided with numpy as offline. So ``fused()`` equals ``fuse("proposed", segments, scan, config,
rms=rms, max_gap=max_gap, sensor_xy=sensor_xy)`` of the same segments (scans numbered in the order they were added) bit for bit, whenever both
work in the same frame: the online fusion fixes its working origin (a whole-kilometre point,
:func:`featmap.fusion.registry.working_origin`) from the first scan with segments, the offline one from
all segments, and both are the frame's origin for a map within 500 m of it. Elsewhere the two differ
by the rounding of that shift (far below a micrometre) and can, rarely, decide a pair that lies exactly
on a threshold differently. Only ``extras["links_kept"]`` differs always (another spanning forest of the
same components).

Numpy in, numpy out; world-frame segments (metres).
"""

from __future__ import annotations

import numpy as np

from featmap.fusion import link_forest as lf
from featmap.fusion.base import MIN_SEGMENT_LENGTH_M, FusionResult, segment_column
from featmap.fusion.proposed import decided_links, fuse_links, support_rule
from featmap.fusion.registry import FusionConfig, finish_fusion, working_origin
from featmap.geometry import MAX_MAP_SPAN_M, as_segments, segment_lengths

GRID_OFFSET_CELLS = 2 ** 25
"""The grid's cell (0, 0) lies this many cells south-west of the first segment: with cells of at least
``2 * MAX_MAP_SPAN_M / 2**26`` (0.6 m), the grid reaches ``MAX_MAP_SPAN_M`` from it every way."""


class OnlineFusion:
    """The proposed method, fed one scan at a time; see the module docstring.

    Args:
        config: the ``fusion`` section (``proposed``, ``refine`` and ``corners`` are used).
    """

    def __init__(self, config: FusionConfig = FusionConfig()):  # type: ignore[valid-type]
        self.config = config
        self.section = config.proposed
        self.origin: np.ndarray | None = None      # (2,) working origin, fixed by the first scan with segments
        self._scans: list[np.ndarray] = []          # per scan: (K, 4) segments as given
        self._rms: list[np.ndarray | None] = []
        self._max_gap: list[np.ndarray | None] = []
        self._sensor_xy: list[np.ndarray | None] = []
        self._valid: list[np.ndarray] = []
        self._n = 0                                 # valid segments so far (the kernel's indices 0 .. n-1)
        self._cell_size: float | None = None        # the grid, fixed by the first valid segments
        self._capacity = 0
        self._cells: dict[int, int] = {}            # grid key -> cell index
        self._n_groups = self._n_links = self._n_undecided = 0
        self._undecided_i = np.empty(1024, np.int64)
        self._undecided_j = np.empty(1024, np.int64)
        self.stats = np.zeros(4, np.int64)
        """(4,) cells visited, groups of other components met, groups tested, pairs evaluated (so far)."""

    # --- what has been seen ----------------------------------------------------------------------------

    @property
    def n_scans(self) -> int:
        return len(self._scans)

    @property
    def n_segments(self) -> int:
        return sum(len(s) for s in self._scans)

    def segments(self) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """(segments (N, 4), scan (N,), rms (N,) or None when a scan came without) of every scan so far."""
        if not self._scans:
            return np.zeros((0, 4)), np.zeros(0, np.int64), None
        scan = np.repeat(np.arange(len(self._scans), dtype=np.int64), [len(s) for s in self._scans])
        return np.concatenate(self._scans), scan, _joined(self._rms)

    def max_gap(self) -> np.ndarray | None:
        """(N,) every segment's ``max_gap`` column so far, or None when a scan came without."""
        return _joined(self._max_gap)

    def sensor_xy(self) -> np.ndarray | None:
        """(N, 2) where the sensor stood for every segment so far, or None when a scan came without."""
        return _joined(self._sensor_xy)

    # --- one scan in -----------------------------------------------------------------------------------

    def add_scan(self, segments, rms=None, max_gap=None, sensor_xy=None) -> int:
        """Link one scan's segments to those of the scans before it; returns the scan's index.

        Args:
            segments: (K, 4) world-frame segments ``x1, y1, x2, y2`` (metres); K may be 0.
            rms: (K,) each segment's fit rms from the extraction (metres), or None (then no segment
                counts as a clean view in :meth:`fused`, as offline without an rms column).
            max_gap: (K,) each segment's longest stretch between consecutive returns (metres), or None
                (then ``fusion.refine.resolved_gap_m`` cuts nothing in :meth:`fused`, as offline).
            sensor_xy: (2,) where the sensor stood when the scan was taken (world frame, metres), or None
                (then the visibility clause ``visible_share`` keeps nothing in :meth:`fused`, as offline).
        Raises:
            ValueError: a NaN or infinite coordinate, ``rms`` or ``max_gap`` of another length, or a segment
                farther than ``MAX_MAP_SPAN_M`` from the first ones (nothing of the scan is kept then).
        """
        segments = as_segments(segments).astype(np.float64, copy=True)
        if not np.isfinite(segments).all():
            raise ValueError("segments contain NaN or inf")
        rms, max_gap = segment_column("rms", rms, len(segments)), segment_column("max_gap", max_gap, len(segments))
        if self.origin is None and len(segments):
            self.origin = working_origin(segments)
        shift = np.tile(self.origin, 2) if self.origin is not None else np.zeros(4)
        valid = segment_lengths(segments - shift) > MIN_SEGMENT_LENGTH_M
        new = segments[valid] - shift
        keys = None
        if len(new):
            if self._cell_size is None:
                self._start_grid(new)
            centres = 0.5 * (new[:, :2] + new[:, 2:])
            cell_xy = np.floor((centres - self._grid_origin) / self._cell_size).astype(np.int64)
            if cell_xy.min() < 0 or cell_xy.max() >= self._ny:
                raise ValueError(f"segments lie more than {MAX_MAP_SPAN_M:g} m from the first scan's (the grid's reach)")
            keys = cell_xy[:, 0] * self._ny + cell_xy[:, 1]
        self._scans.append(segments)
        self._rms.append(rms)
        self._max_gap.append(max_gap)
        self._sensor_xy.append(None if sensor_xy is None else
                               np.tile(np.asarray(sensor_xy, dtype=float).reshape(2), (len(segments), 1)))
        self._valid.append(valid)
        if keys is not None:
            self._link(new, keys)
        return len(self._scans) - 1

    def _link(self, new: np.ndarray, keys: np.ndarray) -> None:
        """Link the (K, 4) valid new segments (working frame; grid ``keys`` (K,)) to the earlier ones."""
        start = self._n
        end = start + len(new)
        self._reserve(end)
        self._seg[start:end] = new
        self._parent[start:end] = np.arange(start, end)
        self._comp_size[start:end] = 1
        fresh = [k for k in dict.fromkeys(keys.tolist()) if k not in self._cells]
        if fresh:
            self._add_cells(np.array(fresh, np.int64))
        self._cell_of[start:end] = [self._cells[k] for k in keys.tolist()]
        scan_start = np.array([start, end], np.int64)
        # The band within which a criterion is left to numpy grows with the coordinates (as offline), and
        # here also covers the rounding of cell coordinates about 2^25 cells from the grid's origin.
        self._max_abs = max(self._max_abs, float(np.abs(new).max()))
        dist_band = 1e-9 + lf.DISTANCE_BAND_REL * self._max_abs + 16.0 * self._cell_size * 2.0 ** -27
        (self._n_groups, self._n_links, self._n_undecided,
         self._undecided_i, self._undecided_j) = lf.link_forest_kernel(
            self._seg, self._order, scan_start, 0, 1, self._cell_of,
            self._table_keys, self._table_cell, self._mask, self._ny,
            float(self._grid_origin[0]), float(self._grid_origin[1]), self._cell_size,
            float(np.cos(np.deg2rad(self.section.delta_deg))), float(self.section.gamma), float(self.section.eta_m),
            dist_band, self.section.delta_deg < 90.0, self.section.gamma > 0.0,
            self._parent, self._comp_size, self._cell_head, self._group_next, self._group_root,
            self._group_head, self._group_tail, self._group_box, self._seg_next,
            self._n_groups, self._links_i, self._links_j, self._n_links,
            self._undecided_i, self._undecided_j, self._n_undecided, self.stats)
        self._n = end

    def _add_cells(self, fresh: np.ndarray) -> None:
        """New grid cells (their keys (K,), none known yet): into the hash table (rebuilt, twice as large,
        only when it would be more than half full) and the per-cell arrays (grown by doubling)."""
        first, n = len(self._cells), len(self._cells) + len(fresh)
        for c, k in enumerate(fresh.tolist()):
            self._cells[k] = first + c
        if n > len(self._cell_keys):
            size = max(2 * len(self._cell_keys), n, 64)
            self._cell_keys = np.concatenate([self._cell_keys[:first], np.zeros(size - first, np.int64)])
            self._cell_head = np.concatenate([self._cell_head[:first], np.full(size - first, -1, np.int64)])
        self._cell_keys[first:n] = fresh
        if 2 * n + 16 > len(self._table_keys):
            self._table_keys, self._table_cell, self._mask = lf._build_cell_table(self._cell_keys[:n])
        else:
            lf.insert_cell_keys(self._table_keys, self._table_cell, self._mask, fresh, first)

    def _start_grid(self, first: np.ndarray) -> None:
        """Fix the grid from the first segments: the offline method's cell (:func:`link_forest.grid_cell_size`;
        only the speed depends on it), large enough that the grid reaches ``MAX_MAP_SPAN_M`` from the first
        segment every way (cell coordinates from 0 to 2^26)."""
        eta = float(self.section.eta_m)
        self._cell_size = lf.grid_cell_size(eta, float(np.median(segment_lengths(first))), 2 * MAX_MAP_SPAN_M)
        centre = 0.5 * (first[0, :2] + first[0, 2:])
        self._grid_origin = np.floor(centre / self._cell_size) * self._cell_size - GRID_OFFSET_CELLS * self._cell_size
        self._ny = 2 * GRID_OFFSET_CELLS
        self._max_abs = 0.0
        self._cell_keys = np.zeros(0, np.int64)
        self._cell_head = np.zeros(0, np.int64)
        self._table_keys = np.zeros(0, np.int64)

    def _reserve(self, n: int) -> None:
        """Grow the per-segment arrays (doubling) to hold ``n`` segments."""
        if n <= self._capacity:
            return
        old, cap = self._capacity, max(1024, self._capacity)
        while cap < n:
            cap *= 2

        def grown(name, fill, shape=(), dtype=np.int64):
            out = np.full((cap, *shape), fill, dtype=dtype)
            if old:
                out[:old] = getattr(self, name)[:old]
            setattr(self, name, out)

        grown("_seg", 0.0, (4,), np.float64)
        grown("_group_box", 0.0, (8,), np.float64)
        for name in ("_parent", "_comp_size", "_group_next", "_group_root", "_group_head", "_group_tail", "_seg_next",
                     "_links_i", "_links_j", "_cell_of"):
            grown(name, -1)
        self._order = np.arange(cap, dtype=np.int64)
        self._capacity = cap

    # --- the map so far ------------------------------------------------------------------------------

    def links(self) -> tuple[np.ndarray, np.ndarray]:
        """(i (K,), j (K,)), ``i < j``: linked pairs of the valid segments so far (indices in the order they
        were added), with the components and first-link scans of all linked pairs."""
        if self._capacity == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        return decided_links(self._seg[:self._n], self._links_i[:self._n_links], self._links_j[:self._n_links],
                             self._undecided_i[:self._n_undecided], self._undecided_j[:self._n_undecided], self.section)

    def fused(self) -> FusionResult:
        """The fused map of every scan so far (what ``fuse("proposed", *self.segments()[:2], config,
        rms=..., max_gap=..., sensor_xy=...)`` gives; see the module docstring). Labels index the segments of :meth:`segments`."""
        segments, scan, rms = self.segments()
        origin = self.origin if self.origin is not None else np.zeros(2)
        valid = np.concatenate(self._valid) if self._valid else np.zeros(0, bool)
        rule = support_rule(self.section)
        max_gap = self.max_gap()
        views = rule.views(segments, rms, max_gap, self.sensor_xy()).moved(origin)
        i, j = self.links()
        result = fuse_links(segments - np.tile(origin, 2), scan, valid, i, j, self.section, views)
        return finish_fusion(result, segments, scan, origin, self.config, rule, views, max_gap)


def _joined(parts: list[np.ndarray | None]) -> np.ndarray | None:
    """One per-segment column of every scan so far, or None when there is none or a scan came without."""
    return None if not parts or any(p is None for p in parts) else np.concatenate(parts)
