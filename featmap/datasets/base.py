"""What a dataset yields per scan."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ScanItem:
    """One LiDAR scan.

    Attributes:
        frame: frame number within the drive (the file number, not the position in a selection).
        points: (N, 4) float32 ``x, y, z, reflectance`` in the velodyne frame (x forward, y left, z up).
        T_w_velo: (4, 4) velodyne-to-world transform, world = the drive's local metric frame.
        timestamp: seconds since the drive's first frame.
    """

    frame: int
    points: np.ndarray
    T_w_velo: np.ndarray
    timestamp: float
