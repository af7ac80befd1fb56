"""Synthetic segment observations with known answers, for tests and benchmarks (no I/O).

A *wall* is a ground-truth segment (4,); an *observation* is a noisy, partial copy of it as one scan
would extract it.
"""

from __future__ import annotations

import numpy as np


def observe_walls(walls: np.ndarray, scans_per_wall: int | np.ndarray, noise_m: float, rng: np.random.Generator,
                  min_fraction: float = 0.5, first_scan: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Noisy partial observations of ``walls`` (W, 4).

    Each wall is seen in ``scans_per_wall`` consecutive scans (starting at ``first_scan[w]``, default
    ``w * scans_per_wall``); each observation covers a random sub-interval of at least
    ``min_fraction`` of the wall, with Gaussian noise of ``noise_m`` on every endpoint coordinate.
    Returns (segments (N, 4), scan (N,)).
    """
    walls = np.asarray(walls, float).reshape(-1, 4)
    counts = np.broadcast_to(np.asarray(scans_per_wall), (len(walls),)).astype(int)
    if first_scan is None:
        first_scan = np.concatenate([[0], np.cumsum(counts)[:-1]])
    wall_idx = np.repeat(np.arange(len(walls)), counts)
    scan = np.concatenate([first_scan[w] + np.arange(c) for w, c in enumerate(counts)]) if len(walls) else np.zeros(0, int)
    span = rng.uniform(min_fraction, 1.0, len(wall_idx))
    start = rng.uniform(0.0, 1.0 - span)
    t0, t1 = start, start + span
    p, q = walls[wall_idx, :2], walls[wall_idx, 2:]
    a = p + t0[:, None] * (q - p)
    b = p + t1[:, None] * (q - p)
    segments = np.concatenate([a, b], axis=1) + rng.normal(0.0, noise_m, (len(wall_idx), 4))
    return segments, scan.astype(np.int64)


def city_walls(n_walls: int, rng: np.random.Generator, block_m: float = 60.0) -> np.ndarray:
    """``n_walls`` building walls (W, 4) of 5-50 m laid out along a Manhattan grid of streets.

    Walls face the streets on both sides (15 m apart), so parallel walls on opposite sides of a street
    and collinear walls of neighbouring buildings are both common, as in a real residential drive.
    """
    per_side = max(1, int(np.ceil(np.sqrt(n_walls / 4))))
    walls = []
    for k in range(n_walls):
        block = k // 4
        bx, by = (block % per_side) * block_m, (block // per_side) * block_m
        side = k % 4
        length = rng.uniform(5.0, min(50.0, block_m - 8.0))
        offset = rng.uniform(0.0, block_m - length - 4.0)
        if side == 0:
            walls.append([bx + offset, by, bx + offset + length, by])
        elif side == 1:
            walls.append([bx + offset, by + 15.0, bx + offset + length, by + 15.0])
        elif side == 2:
            walls.append([bx, by + 20.0 + offset, bx, by + 20.0 + offset + length])
        else:
            walls.append([bx + 15.0, by + 20.0 + offset, bx + 15.0, by + 20.0 + offset + length])
    return np.asarray(walls)


def cast_rays_2d(walls: np.ndarray, pose: np.ndarray, angles: np.ndarray, max_range: float = 80.0) -> np.ndarray:
    """Ranges (n,) of a 2D laser at ``pose`` (x, y, theta) with beams at ``angles`` (n,) (laser frame)
    through ``walls`` (W, 4); ``max_range`` where a beam hits nothing. Exact ray-segment intersection."""
    walls = np.asarray(walls, float).reshape(-1, 4)
    heading = pose[2] + np.asarray(angles, float)
    d = np.stack([np.cos(heading), np.sin(heading)], axis=1)[:, None, :]          # (n, 1, 2)
    a, e = walls[None, :, :2], (walls[:, 2:] - walls[:, :2])[None]                # (1, W, 2)
    w = a - np.asarray(pose[:2], float)
    cross = d[..., 0] * e[..., 1] - d[..., 1] * e[..., 0]                          # (n, W)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[..., 0] * e[..., 1] - w[..., 1] * e[..., 0]) / cross               # distance along the beam
        u = (w[..., 0] * d[..., 1] - w[..., 1] * d[..., 0]) / cross               # position on the wall
    hit = (np.abs(cross) > 1e-12) & (t > 0) & (u >= 0) & (u <= 1)
    t = np.where(hit, t, np.inf).min(axis=1)
    return np.where(np.isfinite(t) & (t <= max_range), t, max_range)
