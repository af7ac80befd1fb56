"""The vehicle's path: waypoints with rounded corners, sampled at the sensor rate."""

from __future__ import annotations

import numpy as np

from featmap.errors import WorldError

MAX_FRAMES = 100_000
"""Most frames a simulated drive may have: 2.8 hours at 10 Hz, about 80 GB of HDL-64E scans (KITTI's longest
drives have about 5,000). A route that takes more (a speed typed a thousand times too small) is refused
before anything is computed; ``n_frames`` may cap it."""


def fillet_polyline(waypoints: np.ndarray, radius: float, step: float = 0.2) -> np.ndarray:
    """Densify a polyline (K, 2) into points ~``step`` apart, replacing each corner by a circular arc.

    The arc's tangent length is clamped to half of each adjacent leg, so short legs still work. A
    waypoint repeated (as OSM and GeoJSON routes often do) counts once.
    """
    pts = np.asarray(waypoints, float).reshape(-1, 2)
    if len(pts) > 1:
        pts = pts[np.concatenate([[True], np.hypot(*np.diff(pts, axis=0).T) > 1e-9])]
    out = [pts[0]]
    for k in range(1, len(pts) - 1):
        a, b, c = pts[k - 1], pts[k], pts[k + 1]
        u = (a - b) / np.linalg.norm(a - b)
        v = (c - b) / np.linalg.norm(c - b)
        cos_t = np.clip(u @ v, -1.0, 1.0)
        turn = np.pi - np.arccos(cos_t)                     # heading change at this corner
        if radius <= 0 or turn < 1e-6:
            out.append(b)
            continue
        tangent = min(radius * np.tan(turn / 2), 0.5 * np.linalg.norm(a - b), 0.5 * np.linalg.norm(c - b))
        r = tangent / np.tan(turn / 2)
        p_in, p_out = b + u * tangent, b + v * tangent
        bis = (u + v) / np.linalg.norm(u + v)
        centre = b + bis * (r / np.cos(turn / 2) if turn < np.pi - 1e-6 else r)
        a0 = np.arctan2(*(p_in - centre)[::-1])
        a1 = np.arctan2(*(p_out - centre)[::-1])
        sweep = (a1 - a0 + np.pi) % (2 * np.pi) - np.pi
        n = max(2, int(np.ceil(abs(sweep) * r / step)))
        ang = a0 + np.linspace(0, sweep, n)
        out.append(p_in)
        out.extend(centre + r * np.stack([np.cos(ang), np.sin(ang)], axis=1))
        out.append(p_out)
    out.append(pts[-1])
    dense = [np.asarray(out[0], float)]
    for p in out[1:]:                                       # resample straight legs too
        p = np.asarray(p, float)
        gap = np.linalg.norm(p - dense[-1])
        if gap < 1e-9:
            continue
        start = dense[-1]
        n = int(np.ceil(gap / step))
        dense.extend(start + (p - start) * t for t in np.linspace(0, 1, n + 1)[1:])
    return np.asarray(dense)


def sample_poses(waypoints: np.ndarray, speed_mps: float, turn_radius_m: float, rate_hz: float,
                 n_frames: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Vehicle positions (F, 2) and headings (F,) (radians, 0 = east, counter-clockwise) at ``rate_hz``.

    The vehicle drives the filleted route at constant speed; ``n_frames`` caps the number of frames
    (default: the whole route).

    Raises:
        WorldError: the route would take more than :data:`MAX_FRAMES` frames.
    """
    spacing = speed_mps / rate_hz
    legs = np.asarray(waypoints, float).reshape(-1, 2)
    length = float(np.hypot(*np.diff(legs, axis=0).T).sum())     # (rounding the corners only shortens it)
    with np.errstate(over="ignore"):
        most = min(length / spacing + 1, n_frames if n_frames is not None else np.inf)   # (inf for a speed ~1e-310)
    if most > MAX_FRAMES:
        frames = f"{most:,.0f}" if most < 1e12 else f"{most:.1e}"
        raise WorldError(f"the route takes about {frames} frames ({length:,.0f} m at {speed_mps:g} m/s, {rate_hz:g} Hz); "
                         f"at most {MAX_FRAMES:,}: raise route.speed_mps or shorten the route")
    path = fillet_polyline(legs, turn_radius_m)
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    total = int(np.floor(s[-1] / spacing)) + 1
    n = total if n_frames is None else min(n_frames, total)
    s_frames = np.arange(n) * spacing
    x = np.interp(s_frames, s, path[:, 0])
    y = np.interp(s_frames, s, path[:, 1])
    ds = 0.5
    xa, ya = np.interp(np.minimum(s_frames + ds, s[-1]), s, path[:, 0]), np.interp(np.minimum(s_frames + ds, s[-1]), s, path[:, 1])
    xb, yb = np.interp(np.maximum(s_frames - ds, 0), s, path[:, 0]), np.interp(np.maximum(s_frames - ds, 0), s, path[:, 1])
    heading = np.arctan2(ya - yb, xa - xb)
    return np.stack([x, y], axis=1), heading
