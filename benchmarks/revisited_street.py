"""Sensor positions for the synthetic revisited street of the fusion benchmarks (numpy in, numpy out).

Kept out of :mod:`featmap.simulation`: that package's source is part of every simulated drive's
fingerprint, and nothing here makes a drive.
"""

from __future__ import annotations

import numpy as np


def street_sensor_positions(walls: np.ndarray, scan: np.ndarray, scans_per_wall: int, walls_per_scan: float = 4.0,
                            street_m: float = 7.5) -> np.ndarray:
    """(N, 2) where the sensor stood for each of N segments of ``observe_revisits`` of ``city_walls``
    (:mod:`featmap.simulation.segments`), given their ``scan`` (N,): the sensor-position columns
    (``sensor_x`` / ``sensor_y``) the visibility clause of the support filter reads.

    Approximate by design, as the observations are: a scan's sensor stands on the street's centre line,
    ``street_m`` in front of the wall whose views began last at or before that scan (on the street side
    ``city_walls`` gives wall ``w``: ``w % 4``), advanced along that wall by the view's share of its
    ``scans_per_wall`` views; the other walls the scan sees are wherever the layout puts them. Every
    segment of one scan (clutter included) gets the same position.
    """
    walls = np.asarray(walls, float).reshape(-1, 4)
    scan = np.asarray(scan, dtype=np.int64)
    n_walls = len(walls)
    stride = max(1, int(round(scans_per_wall / walls_per_scan)))
    scans_per_pass = (n_walls - 1) * stride + scans_per_wall
    local = scan % scans_per_pass
    w = np.minimum(local // stride, n_walls - 1)
    share = np.clip((local - w * stride) / scans_per_wall, 0.0, 1.0)
    p, q = walls[w, :2], walls[w, 2:]
    towards_street = np.array([[0.0, 1.0], [0.0, -1.0], [1.0, 0.0], [-1.0, 0.0]])[w % 4]
    return p + share[:, None] * (q - p) + street_m * towards_street
