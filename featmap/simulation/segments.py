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


def observe_revisits(walls: np.ndarray, passes: int, scans_per_wall: int, rng: np.random.Generator,
                     noise_m: float = 0.03, pose_noise_m: float = 0.05, pose_noise_deg: float = 0.1,
                     min_fraction: float = 0.3, walls_per_scan: float = 4.0,
                     clutter_fraction: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """The same street driven ``passes`` times: noisy partial observations of ``walls`` (W, 4).

    In each pass every wall is seen in ``scans_per_wall`` consecutive scans; about ``walls_per_scan``
    walls share a scan (wall ``w`` is first seen ``w * scans_per_wall / walls_per_scan`` scans into the
    pass). Each pass has its own localisation error per wall (a shift of ``pose_noise_m`` per axis and a
    rotation of ``pose_noise_deg`` about the wall's midpoint, shared by that pass's views of the wall);
    each view covers a random sub-interval of at least ``min_fraction`` of the wall, with Gaussian noise
    of ``noise_m`` on every endpoint coordinate. ``clutter_fraction`` of the output are short (0.5-4 m)
    pieces of clutter (parked cars, fences, bushes) 0.8-6 m in front of a random wall at any
    orientation, each seen in 1-3 consecutive scans of one pass.
    Returns (segments (N, 4), scan (N,)), scans numbered consecutively over the passes.
    """
    walls = np.asarray(walls, float).reshape(-1, 4)
    n_walls = len(walls)
    stride = max(1, int(round(scans_per_wall / walls_per_scan)))
    scans_per_pass = (n_walls - 1) * stride + scans_per_wall
    per_pass = n_walls * scans_per_wall
    wall_idx = np.tile(np.repeat(np.arange(n_walls), scans_per_wall), passes)
    pass_idx = np.repeat(np.arange(passes), per_pass)
    view = np.tile(np.arange(scans_per_wall), n_walls * passes)
    scan = pass_idx * scans_per_pass + wall_idx * stride + view
    # one localisation error per (pass, wall)
    shift = rng.normal(0.0, pose_noise_m, (passes, n_walls, 2))
    turn = np.deg2rad(rng.normal(0.0, pose_noise_deg, (passes, n_walls)))
    span = rng.uniform(min_fraction, 1.0, len(wall_idx))
    start = rng.uniform(0.0, 1.0 - span)
    p, q = walls[wall_idx, :2], walls[wall_idx, 2:]
    a = p + start[:, None] * (q - p)
    b = p + (start + span)[:, None] * (q - p)
    mid = 0.5 * (p + q)
    c, s = np.cos(turn[pass_idx, wall_idx]), np.sin(turn[pass_idx, wall_idx])

    def moved(pt):
        d = pt - mid
        return mid + np.stack([c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1]], axis=1) + shift[pass_idx, wall_idx]

    segments = np.concatenate([moved(a), moved(b)], axis=1) + rng.normal(0.0, noise_m, (len(wall_idx), 4))
    n_clutter_segments = int(round(clutter_fraction * len(segments) / (1.0 - clutter_fraction))) if n_walls else 0
    if n_clutter_segments:
        views = rng.integers(1, 4, n_clutter_segments)          # each piece is seen in 1-3 scans
        seen = np.cumsum(views)
        n_clutter = int(np.searchsorted(seen, n_clutter_segments)) + 1
        views = views[:n_clutter]
        views[-1] -= seen[n_clutter - 1] - n_clutter_segments
        host = rng.integers(0, n_walls, n_clutter)
        d = walls[host, 2:] - walls[host, :2]
        u = d / np.hypot(d[:, 0], d[:, 1])[:, None]
        normal = np.stack([-u[:, 1], u[:, 0]], axis=1)
        centre = (walls[host, :2] + rng.uniform(0, 1, n_clutter)[:, None] * d
                  + rng.choice([-1.0, 1.0], n_clutter)[:, None] * rng.uniform(0.8, 6.0, n_clutter)[:, None] * normal)
        angle = rng.uniform(0, np.pi, n_clutter)
        half = 0.5 * rng.uniform(0.5, 4.0, n_clutter)
        e = np.stack([np.cos(angle), np.sin(angle)], axis=1) * half[:, None]
        rep = np.repeat(np.arange(n_clutter), views)
        clutter = np.concatenate([centre[rep] - e[rep], centre[rep] + e[rep]], axis=1)
        clutter += rng.normal(0.0, noise_m, clutter.shape)
        first = rng.integers(0, passes, n_clutter) * scans_per_pass + host * stride + rng.integers(0, scans_per_wall, n_clutter)
        clutter_scan = first[rep] + (np.arange(len(rep)) - np.repeat(np.cumsum(views) - views, views))
        segments = np.concatenate([segments, clutter])
        scan = np.concatenate([scan, clutter_scan])
    return segments, scan.astype(np.int64)


def indoor_loop_walls(rng: np.random.Generator, loop_m: tuple[float, float] = (60.0, 40.0),
                      corridor_m: float = 2.2, piece_m: tuple[float, float] = (1.0, 8.0), door_m: float = 0.9,
                      room_depth_m: float = 5.0) -> np.ndarray:
    """Walls (W, 4) of a building whose corridors form a rectangular loop (an office floor).

    Both sides of the corridor are pieces of ``piece_m`` metres between door gaps of ``door_m`` (so
    collinear walls with small gaps are everywhere), and every second door on the outer side opens on
    a room whose two side walls (``room_depth_m``, perpendicular to the corridor) are visible.
    """
    w, h = loop_m
    corners = np.array([[0, 0], [w, 0], [w, h], [0, h], [0, 0]], float)
    walls = []
    for k in range(4):
        p, q = corners[k], corners[k + 1]
        length = np.hypot(*(q - p))
        u = (q - p) / length
        n = np.array([-u[1], u[0]])            # points inside the loop
        for side in (-1.0, 1.0):
            offset = side * corridor_m / 2
            t, door = 0.0, 0
            while t < length:
                piece = min(rng.uniform(*piece_m), length - t)
                a = p + t * u + offset * n
                b = p + (t + piece) * u + offset * n
                walls.append([*a, *b])
                t += piece + door_m
                door += 1
                if side < 0 and door % 2 == 0 and t < length:      # a room behind the outer wall
                    for tt in (t - door_m, t):
                        base = p + tt * u + offset * n
                        walls.append([*base, *(base - room_depth_m * n)])
    return np.asarray(walls)


def observe_indoor_loop(walls: np.ndarray, laps: int, rng: np.random.Generator, loop_m: tuple[float, float] = (60.0, 40.0),
                        scan_spacing_m: float = 0.35, range_m: float = 6.0, noise_m: float = 0.02,
                        pose_noise_m: float = 0.03, pose_noise_deg: float = 0.2,
                        min_view_m: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """A robot driving ``laps`` times around the corridor loop of :func:`indoor_loop_walls`.

    A scan every ``scan_spacing_m`` along the corridor's centre line sees the part of every wall
    within ``range_m`` of the robot (clipped to a disc; pieces shorter than ``min_view_m`` are not
    extracted), so views are partial as the robot approaches and leaves. Each lap has its own
    localisation error (``pose_noise_m`` per axis, ``pose_noise_deg``), shared by the lap's views of
    one wall; endpoints get ``noise_m`` Gaussian noise. Returns (segments (N, 4), scan (N,)).
    """
    walls = np.asarray(walls, float).reshape(-1, 4)
    w, h = loop_m
    perimeter = 2 * (w + h)
    stations = np.arange(0.0, perimeter, scan_spacing_m)
    corners = np.array([[0, 0], [w, 0], [w, h], [0, h], [0, 0]], float)
    cum = np.array([0.0, w, w + h, 2 * w + h, perimeter])
    k = np.clip(np.searchsorted(cum, stations, side="right") - 1, 0, 3)
    frac = (stations - cum[k]) / (cum[k + 1] - cum[k])
    robot = corners[k] + frac[:, None] * (corners[k + 1] - corners[k])
    p, d = walls[:, :2], walls[:, 2:] - walls[:, :2]
    length = np.hypot(d[:, 0], d[:, 1])
    u = d / length[:, None]
    seg_list, scan_list = [], []
    for lap in range(laps):
        shift = rng.normal(0.0, pose_noise_m, (len(walls), 2))
        turn = np.deg2rad(rng.normal(0.0, pose_noise_deg, len(walls)))
        for s, pos in enumerate(robot):
            rel = pos - p
            t0 = np.einsum("ij,ij->i", rel, u)
            perp2 = np.einsum("ij,ij->i", rel, rel) - t0**2
            half = np.sqrt(np.maximum(range_m**2 - perp2, 0.0))
            lo, hi = np.maximum(t0 - half, 0.0), np.minimum(t0 + half, length)
            seen = (perp2 < range_m**2) & (hi - lo >= min_view_m)
            if not seen.any():
                continue
            i = np.flatnonzero(seen)
            a = p[i] + lo[i, None] * u[i]
            b = p[i] + hi[i, None] * u[i]
            mid = p[i] + 0.5 * d[i]
            c, sn = np.cos(turn[i]), np.sin(turn[i])

            def moved(pt):
                r = pt - mid
                return mid + np.stack([c * r[:, 0] - sn * r[:, 1], sn * r[:, 0] + c * r[:, 1]], axis=1) + shift[i]

            seg_list.append(np.concatenate([moved(a), moved(b)], axis=1) + rng.normal(0.0, noise_m, (len(i), 4)))
            scan_list.append(np.full(len(i), lap * len(robot) + s))
    if not seg_list:
        return np.zeros((0, 4)), np.zeros(0, np.int64)
    return np.concatenate(seg_list), np.concatenate(scan_list).astype(np.int64)
