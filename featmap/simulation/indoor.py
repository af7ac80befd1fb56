"""Procedural indoor floors and the 2D laser logs of a robot driving through them, with ground truth.

A floor is a ring corridor (1.8-3 m wide) around an inner block, lined on both sides by rooms of 3-6 m
with doors (0.8-1.2 m; a few rooms closed), cabinets standing 2-10 cm before some rooms' back walls, and
on about one floor in two a round hall (a circle of 3-5 m radius drawn as 2-degree chords) opening off
one end of the corridor. The robot drives the corridor's centre line twice around, with a scan every
0.25-0.5 m, and its SICK-like laser (180 or 361 beams over 180 degrees, 1-2 cm range noise, no return
beyond 81.83 m) sees into the rooms through their doors. The log's poses carry 1.5 cm / 0.2 deg of
independent error per scan, as a SLAM-corrected log would.

Seeds are held out: :data:`INDOOR_SEEDS` were run only to report how the indoor defaults generalise
(``benchmarks/bench_indoor_2d.py``); nothing was tuned on them. :data:`INDOOR_TUNING_SEEDS` chose the
strength of the pose prior for SLAM-corrected logs, some with :func:`drifting_poses` (SLAM poses that are
locally off by centimetres). Everything here is deterministic in the
seed and does no I/O (:func:`featmap.io.carmen.flaser_log_text` writes the log).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from featmap.io.carmen import carmen_beam_angles
from featmap.simulation.segments import cast_rays_2d

INDOOR_SEEDS: tuple[int, ...] = (9001, 9002, 9003, 9004, 9005, 9006)
"""Floors never used to tune anything: run only to report."""
INDOOR_TUNING_SEEDS: tuple[int, ...] = (8101, 8102, 8103, 8104, 8105, 8106)
"""Floors the indoor preset's SLAM pose prior was chosen on (``bench_indoor_2d.py --prior-sweep``)."""
NO_RETURN_M = 81.83
"""The range a beam that hits nothing reports (as in the Radish intel log)."""


@dataclass(frozen=True)
class IndoorDrive:
    """One simulated floor and the log of a drive through it (the floor's frame, metres, radians).

    Attributes:
        seed: what made it.
        surfaces: (S, 4) every surface the laser can hit (walls, door jambs, the hall's chords, cabinet
            fronts and sides): the ground truth of a line map.
        poses: (K, 3) true laser pose ``x, y, theta`` of each scan.
        logged: (K, 3) the poses the log carries (true + per-scan error).
        ranges: (K, n) measured range per beam (``NO_RETURN_M``: no return); beams at
            :func:`carmen_beam_angles` ``(n)``.
        stamps: (K,) seconds.
        description: one line on the floor and the sensor.
    """

    seed: int
    surfaces: np.ndarray
    poses: np.ndarray
    logged: np.ndarray
    ranges: np.ndarray
    stamps: np.ndarray
    description: str


def _wall_with_door(a: np.ndarray, b: np.ndarray, door: tuple[float, float] | None) -> list[np.ndarray]:
    """The wall a-b (2,) as one segment, or two with the gap ``door`` = (start, end) metres from ``a``."""
    if door is None:
        return [np.r_[a, b]]
    u = (b - a) / np.linalg.norm(b - a)
    return [np.r_[a, a + door[0] * u], np.r_[a + door[1] * u, b]]


def _rooms(rng: np.random.Generator, x0: float, x1: float, y_wall: float, depth: float) -> list[np.ndarray]:
    """Rooms along the corridor wall ``y = y_wall`` between ``x0`` and ``x1``, reaching ``depth`` (signed:
    away from the corridor) behind it: corridor walls with doors, side walls, back walls, cabinets."""
    out: list[np.ndarray] = []
    edges = [x0]
    while x1 - edges[-1] > 7.0:
        edges.append(edges[-1] + rng.uniform(3.0, 6.0))
    edges.append(x1)
    back = y_wall + depth
    for left, right in zip(edges[:-1], edges[1:]):
        width = right - left
        door = None
        if rng.random() < 0.85 and width > 1.6:
            w = rng.uniform(0.8, 1.2)
            start = rng.uniform(0.3, width - w - 0.3)
            door = (start, start + w)
        out += _wall_with_door(np.array([left, y_wall]), np.array([right, y_wall]), door)
        out.append(np.array([right, y_wall, right, back]))
        out.append(np.array([left, back, right, back]))
        if rng.random() < 0.5 and width > 2.5:                 # a cabinet before the back wall
            length, thick, gap = rng.uniform(0.8, min(2.0, width - 1.0)), rng.uniform(0.4, 0.6), rng.uniform(0.02, 0.1)
            cx = rng.uniform(left + 0.3, right - 0.3 - length)
            front = back - np.sign(depth) * (gap + thick)
            near = back - np.sign(depth) * gap
            out += [np.array([cx, front, cx + length, front]), np.array([cx, front, cx, near]),
                    np.array([cx + length, front, cx + length, near])]
    out.append(np.array([x0, y_wall, x0, back]))
    return out


def generate_indoor(seed: int) -> IndoorDrive:
    """The floor and drive of ``seed`` (see the module docstring)."""
    rng = np.random.default_rng([seed, 10])
    length, height, corridor = rng.uniform(30.0, 60.0), rng.uniform(16.0, 26.0), rng.uniform(1.8, 3.0)
    depth_out = rng.uniform(4.0, 7.0)
    depth_in = min(rng.uniform(4.0, 7.0), 0.5 * (height - 2 * corridor) - 0.2)
    walls: list[np.ndarray] = []
    # rooms outside the ring (below y = 0 and above y = height) and inside the inner block
    walls += _rooms(rng, 0.0, length, 0.0, -depth_out)
    walls += _rooms(rng, 0.0, length, height, depth_out)
    walls += _rooms(rng, corridor, length - corridor, corridor, depth_in)
    walls += _rooms(rng, corridor, length - corridor, height - corridor, -depth_in)
    # the inner block's end walls; the ring's end walls (one may open into a round hall)
    walls += [np.array([corridor, corridor, corridor, height - corridor]),
              np.array([length - corridor, corridor, length - corridor, height - corridor])]
    walls.append(np.array([0.0, 0.0, 0.0, height]))
    hall = rng.random() < 0.5
    if hall:
        radius = rng.uniform(3.0, 5.0)
        mid, opening = 0.5 * height, min(2.0 * radius - 1.0, height - 2.0)
        walls += _wall_with_door(np.array([length, 0.0]), np.array([length, height]),
                                 (mid - 0.5 * opening, mid + 0.5 * opening))
        # a circle through the opening's two ends, centred beyond the wall: its part beyond the wall
        half = 0.5 * opening
        beyond = np.sqrt(radius**2 - half**2)
        reach = np.pi - np.arctan2(half, beyond)
        phi = np.linspace(-reach, reach, int(np.ceil(2 * reach / np.deg2rad(2.0))) + 1)
        arc = np.column_stack([length + beyond + radius * np.cos(phi), mid + radius * np.sin(phi)])
        walls += [np.r_[p, q] for p, q in zip(arc[:-1], arc[1:])]
    else:
        walls.append(np.array([length, 0.0, length, height]))
    surfaces = np.array(walls, float)

    # Twice around the corridor's centre line, a scan every 0.25-0.5 m.
    c = 0.5 * corridor
    corners = np.array([[c, c], [length - c, c], [length - c, height - c], [c, height - c], [c, c]])
    step = rng.uniform(0.25, 0.5)
    points, headings = [], []
    for _ in range(2):
        for p, q in zip(corners[:-1], corners[1:]):
            n = max(int(np.linalg.norm(q - p) / step), 1)
            t = np.arange(n)[:, None] / n
            points.append(p + t * (q - p))
            headings.append(np.full(n, np.arctan2(*(q - p)[::-1])))
    xy = np.concatenate(points)
    theta = np.concatenate(headings) + rng.normal(0.0, np.deg2rad(2.0), len(xy))
    poses = np.column_stack([xy + rng.normal(0.0, 0.03, xy.shape), theta])

    beams = int(rng.choice([180, 361]))
    noise = rng.uniform(0.01, 0.02)
    angles = carmen_beam_angles(beams)
    ranges = np.array([cast_rays_2d(surfaces, pose, angles, max_range=NO_RETURN_M) for pose in poses])
    hit = ranges < NO_RETURN_M
    ranges = np.where(hit, np.maximum(ranges + rng.normal(0.0, noise, ranges.shape), 0.02), NO_RETURN_M)
    logged = poses + np.column_stack([rng.normal(0.0, 0.015, (len(poses), 2)), rng.normal(0.0, np.deg2rad(0.2), len(poses))])
    stamps = 0.2 * np.arange(len(poses))
    description = (f"floor {length:.0f} x {height:.0f} m, corridor {corridor:.1f} m, {'a round hall, ' if hall else ''}"
                   f"{len(poses)} scans of {beams} beams, {100 * noise:.1f} cm noise")
    return IndoorDrive(seed, surfaces, poses, logged, ranges, stamps, description)


def drifting_poses(drive: IndoorDrive, seed: int) -> np.ndarray:
    """(K, 3) poses of ``drive`` as a SLAM result that is locally off: the true poses plus a slowly
    varying error (a random walk over the scans, centred and scaled to 5 cm / 0.5 deg rms per axis) plus
    half of the log's per-scan error. Deterministic in ``seed``."""
    walk = np.cumsum(np.random.default_rng(seed).normal(0.0, 1.0, drive.poses.shape), axis=0)
    walk = (walk - walk.mean(axis=0)) / walk.std(axis=0)
    return drive.poses + walk * np.array([0.05, 0.05, np.deg2rad(0.5)]) + 0.5 * (drive.logged - drive.poses)
