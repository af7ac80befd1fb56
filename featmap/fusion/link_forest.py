"""A spanning forest of the proposed method's link graph, in time linear in the number of segments.

The paper's clusters are the connected components of the graph whose edges are the linked pairs
(three criteria, different scans). Enumerating every linked pair costs O(n^2) per wall seen n times,
which is what revisits do. This module finds a *sparse* set of real links with exactly the same
connected components, and exactly the same "first link" scan per component, without enumerating the
pairs inside a component:

1. Scans are processed in increasing order. Segment ``i`` of scan ``t`` is compared with the segments
   of scans ``< t`` only (every pair is considered once, from its newer segment).
2. Earlier segments live in a uniform grid (by feature-circle centre). Inside a cell they are kept as
   *groups*, one per connected component (union-find): a group whose component is already ``i``'s is
   skipped whole; a group that cannot hold a partner of ``i`` (by criterion 3 on the group's bounding
   boxes) is skipped whole; otherwise its members are tested until the first link, which joins the
   whole group to ``i``'s component.
3. Only cells within ``eta`` of segment ``i`` can hold the centre of a partner (criterion 3), so the
   cells visited are a thin band along the segment.

Why the components are the paper's: every recorded link is a real link (the criteria are evaluated in
full), and a pair ``(a, b)`` that is not evaluated is skipped only because ``a`` and ``b`` are already in
one component (or because a bound proves that the criteria fail). Why the first-link scan is the same:
pairs are met in increasing ``max(scan_a, scan_b)``; the link that minimises it over a component is
either recorded, or skipped because its ends were already joined by recorded links that were met no
later, so the minimum over recorded links equals the minimum over all links.

Floating point: the criteria are computed with the same formulas as
:func:`featmap.fusion.proposed.evaluate_pairs`, but compiled code and numpy may round the last bit of a
transcendental function differently. A pair whose value lies within a tiny band around a threshold is
therefore not decided here: it is returned as *undecided* and the caller evaluates it with numpy, as
the exhaustive version does. The decision for every pair is thus bit-for-bit the exhaustive one.

Compiled with numba (cached on disk after the first call, where numba finds a writable place for it).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# Half-widths of the bands around each threshold inside which a pair is left to numpy (see above).
COS_BAND = 1e-9          # on cos(beta); covers the steep arccos near beta = 0 too
EPSILON_BAND = 1e-7      # on the overlap ratio
DISTANCE_BAND_REL = 1e-12  # on d_max, times the largest absolute coordinate (plus 1e-9 m)

_PASS, _FAIL, _UNDECIDED = 0, 1, 2


def compiled(**options):
    """``numba.njit(cache=True, **options)``, or without the disk cache where numba has no writable place
    for it (a read-only install with no writable user cache folder): compiled on each start, not an error."""

    def decorate(func):
        try:
            return njit(cache=True, **options)(func)
        except RuntimeError:          # numba: "cannot cache function ...: no locator available"
            return njit(**options)(func)

    return decorate


@compiled(inline="always")
def _find(parent, x):
    root = x
    while parent[root] != root:
        root = parent[root]
    while parent[x] != root:
        nxt = parent[x]
        parent[x] = root
        x = nxt
    return root


@compiled(inline="always")
def _point_segment_distance(px, py, x1, y1, x2, y2):
    """As :func:`featmap.geometry.point_segment_distance` for one pair (same operations)."""
    abx = x2 - x1
    aby = y2 - y1
    denom = abx * abx + aby * aby
    t = (px - x1) * abx + (py - y1) * aby
    if denom > 0:
        t = t / denom
    else:
        t = 0.0
    if t < 0.0:
        t = 0.0
    elif t > 1.0:
        t = 1.0
    cx = x1 + t * abx
    cy = y1 + t * aby
    return math.hypot(px - cx, py - cy)


@compiled(inline="always")
def _acos_clipped(v):
    if v < -1.0:
        v = -1.0
    elif v > 1.0:
        v = 1.0
    return math.acos(v)


@compiled()
def _decide(seg, i, j, cos_delta, gamma, eta, dist_band, check_angle, check_overlap):
    """PASS, FAIL or UNDECIDED for the three criteria of the pair (i, j) (formulas of evaluate_pairs)."""
    x1i, y1i, x2i, y2i = seg[i, 0], seg[i, 1], seg[i, 2], seg[i, 3]
    x1j, y1j, x2j, y2j = seg[j, 0], seg[j, 1], seg[j, 2], seg[j, 3]
    cxi, cyi = 0.5 * (x1i + x2i), 0.5 * (y1i + y2i)
    cxj, cyj = 0.5 * (x1j + x2j), 0.5 * (y1j + y2j)
    undecided = False
    # criterion 3 first: the cheapest to fail
    d_max = max(_point_segment_distance(cxi, cyi, x1j, y1j, x2j, y2j),
                _point_segment_distance(cxj, cyj, x1i, y1i, x2i, y2i))
    if d_max > eta + dist_band:
        return _FAIL
    if d_max >= eta - dist_band:
        undecided = True
    if check_angle:     # criterion 1: included angle from the line coefficients A = y2 - y1, B = x1 - x2
        ai, bi = y2i - y1i, x1i - x2i
        aj, bj = y2j - y1j, x1j - x2j
        num = abs(ai * aj + bi * bj)
        den = math.hypot(ai, bi) * math.hypot(aj, bj)
        cos = num / den if den > 0 else 1.0
        cos = min(max(cos, 0.0), 1.0)
        if cos < cos_delta - COS_BAND:
            return _FAIL
        if cos <= cos_delta + COS_BAND:
            undecided = True
    if check_overlap:   # criterion 2: feature-circle overlap over the smaller circle's area
        ri = 0.5 * math.hypot(x2i - x1i, y2i - y1i)
        rj = 0.5 * math.hypot(x2j - x1j, y2j - y1j)
        d = math.hypot(cxi - cxj, cyi - cyj)
        rmin = min(ri, rj)
        s_min = math.pi * rmin ** 2
        if d <= abs(ri - rj):
            area = math.pi * rmin ** 2
        elif d < ri + rj:
            a1 = _acos_clipped((d ** 2 + ri ** 2 - rj ** 2) / (2 * d * ri))
            a2 = _acos_clipped((d ** 2 + rj ** 2 - ri ** 2) / (2 * d * rj))
            area = a1 * ri ** 2 + a2 * rj ** 2 - d * ri * math.sin(a1)
        else:
            area = 0.0
        eps = min(max(area / s_min, 0.0), 1.0)
        if eps < gamma - EPSILON_BAND:
            return _FAIL
        if eps <= gamma + EPSILON_BAND:
            undecided = True
    return _UNDECIDED if undecided else _PASS


@compiled(inline="always")
def _hash_slot(key, mask):
    h = np.uint64(key) * np.uint64(0x9E3779B97F4A7C15)
    return np.int64(h >> np.uint64(33)) & mask


@compiled()
def _build_cell_table(keys):
    """Open-addressing table of the distinct cell keys: (table_keys, table_cell, mask)."""
    size = 16
    while size < 2 * len(keys) + 16:
        size *= 2
    mask = size - 1
    table_keys = np.full(size, -1, np.int64)
    table_cell = np.full(size, -1, np.int64)
    for c in range(len(keys)):
        s = _hash_slot(keys[c], mask)
        while table_keys[s] != -1:
            s = (s + 1) & mask
        table_keys[s] = keys[c]
        table_cell[s] = c
    return table_keys, table_cell, mask


@compiled()
def insert_cell_keys(table_keys, table_cell, mask, keys, first_cell):
    """Add the distinct new cell ``keys`` (not yet in the table) as cells ``first_cell, first_cell + 1, ...``
    to a table of :func:`_build_cell_table` with room for them (at most half full afterwards)."""
    for c in range(len(keys)):
        s = _hash_slot(keys[c], mask)
        while table_keys[s] != -1:
            s = (s + 1) & mask
        table_keys[s] = keys[c]
        table_cell[s] = first_cell + c


def grid_cell_size(eta: float, median_length: float, span: float) -> float:
    """The link forest's cell (metres): a few eta or a quarter of a typical segment (only the speed depends on
    it, not the links' components), and large enough that ``span`` metres are at most 2^26 cells (int64
    cell keys)."""
    return max(4.0 * eta, median_length / 4.0, span / 2**26, 1e-3)


@compiled(inline="always")
def _lookup(table_keys, table_cell, mask, key):
    s = _hash_slot(key, mask)
    while True:
        k = table_keys[s]
        if k == key:
            return table_cell[s]
        if k == -1:
            return -1
        s = (s + 1) & mask


@compiled(inline="always")
def _box_point_distance(x0, x1, y0, y1, px, py):
    dx = max(x0 - px, 0.0, px - x1)
    dy = max(y0 - py, 0.0, py - y1)
    return math.hypot(dx, dy)


@compiled()
def _box_segment_distance(x0, x1, y0, y1, ax, ay, bx, by):
    """Distance between the axis-aligned box [x0, x1] x [y0, y1] and the segment a-b (0 if they meet)."""
    # an endpoint inside the box
    if x0 <= ax <= x1 and y0 <= ay <= y1:
        return 0.0
    if x0 <= bx <= x1 and y0 <= by <= y1:
        return 0.0
    # the segment crosses the box (Liang-Barsky clipping)
    dx, dy = bx - ax, by - ay
    t0, t1 = 0.0, 1.0
    crosses = True
    for p, q in ((-dx, ax - x0), (dx, x1 - ax), (-dy, ay - y0), (dy, y1 - ay)):
        if p == 0.0:
            if q < 0.0:
                crosses = False
                break
        else:
            r = q / p
            if p < 0.0:
                if r > t1:
                    crosses = False
                    break
                if r > t0:
                    t0 = r
            else:
                if r < t0:
                    crosses = False
                    break
                if r < t1:
                    t1 = r
    if crosses:
        return 0.0
    # disjoint convex sets: the closest pair involves a vertex of one of them
    best = min(_box_point_distance(x0, x1, y0, y1, ax, ay), _box_point_distance(x0, x1, y0, y1, bx, by))
    best = min(best, _point_segment_distance(x0, y0, ax, ay, bx, by))
    best = min(best, _point_segment_distance(x1, y0, ax, ay, bx, by))
    best = min(best, _point_segment_distance(x0, y1, ax, ay, bx, by))
    best = min(best, _point_segment_distance(x1, y1, ax, ay, bx, by))
    return best


@compiled()
def _union(parent, size, a, b):
    """Join the components of roots a and b (union by size); return the new root."""
    if size[a] < size[b]:
        a, b = b, a
    parent[b] = a
    size[a] += size[b]
    return a


@compiled()
def link_forest_kernel(seg, order, scan_start, scan_from, scan_to, cell_of,
                       table_keys, table_cell, mask, ny, x_origin, y_origin, cell_size,
                       cos_delta, gamma, eta, dist_band, check_angle, check_overlap,
                       parent, comp_size, cell_head, group_next, group_root, group_head, group_tail, group_box, seg_next,
                       n_groups, links_i, links_j, n_links, undecided_i, undecided_j, n_undecided, stats):
    """Process scans ``scan_from .. scan_to - 1`` (indices into ``scan_start``); state arrays are updated in place.

    ``order`` (N,) lists segment indices scan by scan; ``scan_start`` (S + 1,) the start of each scan in it;
    ``cell_of`` (N,) the grid cell of each segment's centre (an index into the cell hash table's values).
    ``stats`` (4,) counts cells visited, groups of other clusters met, groups tested and pairs evaluated.
    Returns (n_groups, n_links, n_undecided, undecided_i, undecided_j) (the undecided buffers may grow).
    """
    reach = eta + dist_band
    reach_cells = reach / cell_size
    for s in range(scan_from, scan_to):
        # 1. query: each segment of scan s against the groups of earlier scans near it
        for k in range(scan_start[s], scan_start[s + 1]):
            i = order[k]
            ax, ay, bx, by = seg[i, 0], seg[i, 1], seg[i, 2], seg[i, 3]
            cxi, cyi = 0.5 * (ax + bx), 0.5 * (ay + by)
            # cells within `reach` of the segment, column by column along its major axis
            gx0, gy0 = (ax - x_origin) / cell_size, (ay - y_origin) / cell_size
            gx1, gy1 = (bx - x_origin) / cell_size, (by - y_origin) / cell_size
            steep = abs(gy1 - gy0) > abs(gx1 - gx0)
            if steep:
                gx0, gy0, gx1, gy1 = gy0, gx0, gy1, gx1
            if gx1 < gx0:
                gx0, gy0, gx1, gy1 = gx1, gy1, gx0, gy0
            slope = (gy1 - gy0) / (gx1 - gx0) if gx1 > gx0 else 0.0
            for col in range(int(math.floor(gx0 - reach_cells)), int(math.floor(gx1 + reach_cells)) + 1):
                lo = max(col - reach_cells, gx0)
                hi = min(col + 1 + reach_cells, gx1)
                if hi < lo:
                    lo = hi = gx0 if col < gx0 else gx1
                ya, yb = gy0 + slope * (lo - gx0), gy0 + slope * (hi - gx0)
                row_lo = int(math.floor(min(ya, yb) - reach_cells))
                row_hi = int(math.floor(max(ya, yb) + reach_cells))
                for row in range(row_lo, row_hi + 1):
                    if steep:
                        qx, qy = row, col
                    else:
                        qx, qy = col, row
                    if qx < 0 or qy < 0 or qy >= ny:
                        continue
                    cell = _lookup(table_keys, table_cell, mask, np.int64(qx) * ny + qy)
                    if cell < 0:
                        continue
                    stats[0] += 1
                    mine = -1          # the group of i's component in this cell, if any
                    prev = -1
                    g = cell_head[cell]
                    while g >= 0:
                        nxt = group_next[g]
                        rg = _find(parent, group_root[g])
                        group_root[g] = rg
                        ri = _find(parent, i)
                        if rg == ri:
                            if mine < 0:
                                mine = g
                                prev = g
                            else:       # two groups of one component: merge g into mine
                                _merge_groups(mine, g, group_head, group_tail, group_box, seg_next)
                                group_next[prev] = nxt
                            g = nxt
                            continue
                        stats[1] += 1
                        # criterion 3 bounds: the centre of a partner lies within eta of segment i, and
                        # the centre of i lies within eta of the partner segment
                        if (_box_segment_distance(group_box[g, 0], group_box[g, 1], group_box[g, 2], group_box[g, 3],
                                                  ax, ay, bx, by) > reach
                                or _box_point_distance(group_box[g, 4], group_box[g, 5], group_box[g, 6],
                                                       group_box[g, 7], cxi, cyi) > reach):
                            prev = g
                            g = nxt
                            continue
                        stats[2] += 1
                        linked = False
                        j = group_head[g]
                        while j >= 0:
                            stats[3] += 1
                            verdict = _decide(seg, i, j, cos_delta, gamma, eta, dist_band, check_angle, check_overlap)
                            if verdict == _PASS:
                                links_i[n_links] = i
                                links_j[n_links] = j
                                n_links += 1
                                linked = True
                                break
                            if verdict == _UNDECIDED:
                                if n_undecided == len(undecided_i):
                                    undecided_i = _grow(undecided_i)
                                    undecided_j = _grow(undecided_j)
                                undecided_i[n_undecided] = i
                                undecided_j[n_undecided] = j
                                n_undecided += 1
                            j = seg_next[j]
                        if linked:
                            root = _union(parent, comp_size, rg, ri)
                            group_root[g] = root
                            if mine < 0:
                                mine = g
                                prev = g
                            else:       # g joins the group of i's component in this cell
                                _merge_groups(mine, g, group_head, group_tail, group_box, seg_next)
                                group_next[prev] = nxt
                        else:
                            prev = g
                        g = nxt
        # 2. insert the segments of scan s into their cells (after the queries: same-scan pairs never link)
        for k in range(scan_start[s], scan_start[s + 1]):
            j = order[k]
            cell = cell_of[j]
            rj = _find(parent, j)
            g = cell_head[cell]
            target = -1
            while g >= 0:
                rg = _find(parent, group_root[g])
                group_root[g] = rg
                if rg == rj:
                    target = g
                    break
                g = group_next[g]
            cxj, cyj = 0.5 * (seg[j, 0] + seg[j, 2]), 0.5 * (seg[j, 1] + seg[j, 3])
            ex0, ex1 = min(seg[j, 0], seg[j, 2]), max(seg[j, 0], seg[j, 2])
            ey0, ey1 = min(seg[j, 1], seg[j, 3]), max(seg[j, 1], seg[j, 3])
            if target < 0:
                target = n_groups
                n_groups += 1
                group_root[target] = rj
                group_head[target] = -1
                group_tail[target] = j
                group_next[target] = cell_head[cell]
                cell_head[cell] = target
                group_box[target, 0] = cxj
                group_box[target, 1] = cxj
                group_box[target, 2] = cyj
                group_box[target, 3] = cyj
                group_box[target, 4] = ex0
                group_box[target, 5] = ex1
                group_box[target, 6] = ey0
                group_box[target, 7] = ey1
            else:
                group_box[target, 0] = min(group_box[target, 0], cxj)
                group_box[target, 1] = max(group_box[target, 1], cxj)
                group_box[target, 2] = min(group_box[target, 2], cyj)
                group_box[target, 3] = max(group_box[target, 3], cyj)
                group_box[target, 4] = min(group_box[target, 4], ex0)
                group_box[target, 5] = max(group_box[target, 5], ex1)
                group_box[target, 6] = min(group_box[target, 6], ey0)
                group_box[target, 7] = max(group_box[target, 7], ey1)
            seg_next[j] = group_head[target]     # newest first: recent views link most readily
            group_head[target] = j
    return n_groups, n_links, n_undecided, undecided_i, undecided_j


@compiled()
def _merge_groups(a, b, group_head, group_tail, group_box, seg_next):
    """Append group b's members to group a and widen a's boxes (b is then unlinked by the caller)."""
    seg_next[group_tail[a]] = group_head[b]
    group_tail[a] = group_tail[b]
    group_head[b] = -1
    for c in (0, 2, 4, 6):
        group_box[a, c] = min(group_box[a, c], group_box[b, c])
        group_box[a, c + 1] = max(group_box[a, c + 1], group_box[b, c + 1])


@compiled()
def _grow(buffer):
    out = np.empty(2 * len(buffer), buffer.dtype)
    out[:len(buffer)] = buffer
    return out


# --- connected components of the density method's neighbour graph --------------------------------------

@compiled()
def band_components_kernel(order, umin, umax, v, entry_start, entry_cells, cell_count, lateral_eps, gap, slack,
                           cell_key_of, table_keys, table_cell, mask, u_origin, u_size, v_origin, v_size, nu, nv):
    """Union-find components of "``|v_i - v_j| <= lateral_eps`` and the u-intervals leave a gap ``<= gap``".

    Segments are taken in ``order``; each is compared with the groups of earlier segments in the cells its
    reach covers, then inserted into every cell its interval ``[umin, umax]`` covers (entries
    ``entry_start[i] .. entry_start[i + 1]`` of ``entry_cells``). Cells carry the orientation cluster in
    their key, so clusters never mix. Same group skipping as :func:`link_forest_kernel`. Returns the
    union-find parent array (N,) (roots label the components) and statistics.
    """
    n = len(umin)
    n_entries = entry_start[n]
    parent = np.arange(n)
    comp_size = np.ones(n, np.int64)
    cell_head = np.full(cell_count, -1, np.int64)
    group_next = np.full(n_entries, -1, np.int64)
    group_root = np.full(n_entries, -1, np.int64)
    group_head = np.full(n_entries, -1, np.int64)
    group_tail = np.full(n_entries, -1, np.int64)
    group_box = np.zeros((n_entries, 4))          # min umin, max umax, min v, max v
    entry_next = np.full(n_entries, -1, np.int64)
    entry_seg = np.full(n_entries, -1, np.int64)
    n_groups = 0
    stats = np.zeros(3, np.int64)
    for k in range(n):
        i = order[k]
        key_base = cell_key_of[i]               # orientation cluster * nu * nv
        lo_u, hi_u = umin[i] - gap - slack, umax[i] + gap + slack
        lo_v, hi_v = v[i] - lateral_eps - slack, v[i] + lateral_eps + slack
        cu0 = max(int(math.floor((lo_u - u_origin) / u_size)), 0)
        cu1 = min(int(math.floor((hi_u - u_origin) / u_size)), nu - 1)
        cv0 = max(int(math.floor((lo_v - v_origin) / v_size)), 0)
        cv1 = min(int(math.floor((hi_v - v_origin) / v_size)), nv - 1)
        for cu in range(cu0, cu1 + 1):
            for cv in range(cv0, cv1 + 1):
                cell = _lookup(table_keys, table_cell, mask, key_base + cu * nv + cv)
                if cell < 0:
                    continue
                mine = -1
                prev = -1
                g = cell_head[cell]
                while g >= 0:
                    nxt = group_next[g]
                    rg = _find(parent, group_root[g])
                    group_root[g] = rg
                    ri = _find(parent, i)
                    if rg == ri:
                        if mine < 0:
                            mine = g
                            prev = g
                        else:
                            _merge_band_groups(mine, g, group_head, group_tail, group_box, entry_next)
                            group_next[prev] = nxt
                        g = nxt
                        continue
                    stats[0] += 1
                    if (group_box[g, 0] > hi_u or group_box[g, 1] < lo_u
                            or group_box[g, 2] > hi_v or group_box[g, 3] < lo_v):
                        prev = g
                        g = nxt
                        continue
                    linked = False
                    e = group_head[g]
                    while e >= 0:
                        j = entry_seg[e]
                        stats[1] += 1
                        if (abs(v[i] - v[j]) <= lateral_eps
                                and max(umin[i], umin[j]) - min(umax[i], umax[j]) <= gap):
                            linked = True
                            break
                        e = entry_next[e]
                    if linked:
                        stats[2] += 1
                        root = _union(parent, comp_size, rg, ri)
                        group_root[g] = root
                        if mine < 0:
                            mine = g
                            prev = g
                        else:
                            _merge_band_groups(mine, g, group_head, group_tail, group_box, entry_next)
                            group_next[prev] = nxt
                    else:
                        prev = g
                    g = nxt
        # insert i into every cell its interval covers
        ri = _find(parent, i)
        for e in range(entry_start[i], entry_start[i + 1]):
            cell = entry_cells[e]
            entry_seg[e] = i
            target = -1
            g = cell_head[cell]
            while g >= 0:
                rg = _find(parent, group_root[g])
                group_root[g] = rg
                if rg == ri:
                    target = g
                    break
                g = group_next[g]
            if target < 0:
                target = n_groups
                n_groups += 1
                group_root[target] = ri
                group_next[target] = cell_head[cell]
                cell_head[cell] = target
                group_head[target] = e
                group_tail[target] = e
                group_box[target, 0] = umin[i]
                group_box[target, 1] = umax[i]
                group_box[target, 2] = v[i]
                group_box[target, 3] = v[i]
            else:
                entry_next[e] = group_head[target]
                group_head[target] = e
                group_box[target, 0] = min(group_box[target, 0], umin[i])
                group_box[target, 1] = max(group_box[target, 1], umax[i])
                group_box[target, 2] = min(group_box[target, 2], v[i])
                group_box[target, 3] = max(group_box[target, 3], v[i])
    for x in range(n):
        parent[x] = _find(parent, x)
    return parent, stats


@compiled()
def _merge_band_groups(a, b, group_head, group_tail, group_box, entry_next):
    entry_next[group_tail[a]] = group_head[b]
    group_tail[a] = group_tail[b]
    group_head[b] = -1
    group_box[a, 0] = min(group_box[a, 0], group_box[b, 0])
    group_box[a, 1] = max(group_box[a, 1], group_box[b, 1])
    group_box[a, 2] = min(group_box[a, 2], group_box[b, 2])
    group_box[a, 3] = max(group_box[a, 3], group_box[b, 3])
