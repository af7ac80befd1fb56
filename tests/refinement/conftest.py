"""A synthetic 2D floor (walls in several directions) scanned by a 360-degree laser along a known path."""

import numpy as np
import pytest

from featmap.datasets.carmen import pose_matrix
from featmap.extraction.base import segments_to_world
from featmap.extraction.lines_2d import extract_lines_2d
from featmap.refinement import RefinementInput
from featmap.simulation.segments import cast_rays_2d

# A 24 m x 14 m hall: outer walls, a slanted wall, two free-standing walls and a pillar (walls in four directions).
FLOOR = np.array([[0, 0, 24, 0], [24, 0, 24, 14], [24, 14, 0, 14], [0, 14, 0, 0],
                  [16, 14, 22, 9],                                   # slanted
                  [6, 4, 6, 10], [10, 10, 15, 10],                   # free-standing walls
                  [18, 3, 19.5, 3], [19.5, 3, 19.5, 4.5], [19.5, 4.5, 18, 4.5], [18, 4.5, 18, 3]], float)
ANGLES = np.deg2rad(np.arange(-180.0, 180.0, 0.5))


def path(n: int = 24) -> np.ndarray:
    """(n, 3) ``x, y, theta``: a loop through the hall, 0.5 s apart (about 1.5 m/s)."""
    phi = np.linspace(0, 2 * np.pi, n, endpoint=False)
    x, y = 12 + 7 * np.cos(phi), 7 + 3.5 * np.sin(phi)
    return np.column_stack([x, y, phi + np.pi / 2])


def scan_segments(true_poses: np.ndarray, rng: np.random.Generator, noise_m: float = 0.01):
    """Per scan, the 2D extractor's segments (sensor frame) of a scan taken at each true pose."""
    out = []
    for pose in true_poses:
        r = cast_rays_2d(FLOOR, pose, ANGLES, max_range=40.0)
        hit = r < 40.0
        r = r[hit] + rng.normal(0, noise_m, hit.sum())
        pts = np.column_stack([r * np.cos(ANGLES[hit]), r * np.sin(ANGLES[hit])])
        out.append(extract_lines_2d(pts))
    return out


def refinement_input(scans, given_poses: np.ndarray, dt_s: float = 0.5) -> RefinementInput:
    """The scans' segments placed in the world with ``given_poses`` (F, 3)."""
    T = np.stack([pose_matrix(p) for p in given_poses])
    segs = [segments_to_world(s, t) for s, t in zip(scans, T)]
    scan = np.concatenate([np.full(len(s), k) for k, s in enumerate(segs)])
    return RefinementInput(np.concatenate(segs), scan, T, np.arange(len(T)) * dt_s)


@pytest.fixture(scope="module")
def hall():
    """(true poses (24, 3), their scans' segments)."""
    poses = path()
    return poses, scan_segments(poses, np.random.default_rng(0))
