"""Which owners (features, clusters) have points within a distance of each other: a uniform grid in one
compiled pass, instead of listing every close pair of points (most of which, along one line's own
samples, belong to the same owner and are thrown away).

Positions in any metric frame (metres); numpy in, numpy out.
"""

from __future__ import annotations

import numpy as np

from featmap.fusion.link_forest import _grow, compiled


@compiled()
def _close_owner_pairs_kernel(points, owner, cell_keys, cell_start, row_stride, reach2, n_owners):
    """Keys ``lower * n_owners + higher`` (with repeats) of the owners of every two points (sorted by cell:
    the points of cell ``cell_keys[c]`` are ``cell_start[c]:cell_start[c + 1]``) within ``sqrt(reach2)``
    of each other, of different owners. A cell's key is ``column * row_stride + row``; each cell meets
    itself and its four forward neighbours, so each pair of cells is visited once."""
    out = np.empty(1024, dtype=np.int64)
    m = 0
    n_cells = cell_keys.shape[0]
    for c in range(n_cells):
        for step in range(5):
            if step == 0:
                other = c
            else:
                # forward neighbours: (0, +1), (+1, -1), (+1, 0), (+1, +1) in (column, row)
                neighbour = cell_keys[c] + (1 if step == 1 else row_stride + step - 3)
                other = np.searchsorted(cell_keys, neighbour)
                if other >= n_cells or cell_keys[other] != neighbour:
                    continue
            for i in range(cell_start[c], cell_start[c + 1]):
                first = i + 1 if other == c else cell_start[other]
                for j in range(first, cell_start[other + 1]):
                    if owner[i] == owner[j]:
                        continue
                    dx = points[i, 0] - points[j, 0]
                    dy = points[i, 1] - points[j, 1]
                    if dx * dx + dy * dy <= reach2:
                        if m == out.shape[0]:
                            out = _grow(out)
                        lo, hi = min(owner[i], owner[j]), max(owner[i], owner[j])
                        out[m] = lo * n_owners + hi
                        m += 1
    return out[:m]


def close_owner_pairs(points: np.ndarray, owner: np.ndarray, reach: float, n_owners: int) -> np.ndarray:
    """The pairs of owners with some two of their points at most ``reach`` apart.

    Args:
        points: (P, 2) positions; owner: (P,) the owner of each, in ``[0, n_owners)``.
        reach: the distance (> 0), in the points' unit.
    Returns:
        (K,) sorted unique int64 keys ``lower * n_owners + higher`` of the pairs of different owners
        (``np.divmod(keys, n_owners)`` gives the pairs): the same pairs as the owners of
        ``cKDTree(points).query_pairs(reach)`` (squared distances against ``reach ** 2``).
    """
    points = np.ascontiguousarray(np.asarray(points, dtype=float).reshape(-1, 2))
    owner = np.asarray(owner, dtype=np.int64).reshape(-1)
    if len(points) < 2:
        return np.zeros(0, dtype=np.int64)
    cells = np.floor((points - points.min(axis=0)) / reach).astype(np.int64)
    row_stride = int(cells[:, 1].max()) + 3                     # rows 1 .. max + 1: a neighbour never wraps
    keys = cells[:, 0] * row_stride + cells[:, 1] + 1
    order = np.argsort(keys)                    # (the order within a cell changes nothing)
    sorted_keys = keys[order]
    cell_start = np.flatnonzero(np.concatenate([[True], sorted_keys[1:] != sorted_keys[:-1]]))
    cell_keys = sorted_keys[cell_start]
    cell_start = np.append(cell_start, len(order)).astype(np.int64)
    found = _close_owner_pairs_kernel(points[order], owner[order], cell_keys, cell_start, row_stride,
                                      float(reach) ** 2, int(n_owners))
    return np.unique(found)


def prepare() -> None:
    """Load the compiled code (a one-off cost per process; from numba's disk cache when it has one)."""
    close_owner_pairs(np.array([[0.0, 0.0], [0.1, 0.0], [0.3, 0.0]]), np.array([0, 1, 1]), 0.2, 2)
