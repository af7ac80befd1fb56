"""Vertical planes of one LiDAR scan -> 2D ground segments.

1. Crop by range and height (velodyne frame).
2. Voxel down-sampling (Open3D).
3. Ground removal: RANSAC plane on the low points; if it is near-horizontal, drop every point less
   than ``ground_margin_m`` above it. The plane also gives each wall piece its height above ground:
   pieces whose top stays below ``min_top_height_m`` (fences, low walls, parked cars: the paper's
   "trivial features") are not walls of buildings.
4. Repeated Open3D ``segment_plane`` on what is left (on a random subset of at most
   ``ransac_max_points`` points, for speed; the plane's inliers are then taken from all points). A
   plane whose normal is within
   ``max_normal_tilt_deg`` of horizontal is a wall candidate; other planes (car roofs, leftover
   ground) are removed and the search goes on.
5. The inliers of one wall plane are split into pieces wherever they leave a gap longer than
   ``max_gap_m`` along the wall (one RANSAC plane often spans several separate walls in a row).
6. Each piece with enough points, length and height becomes a segment: a total-least-squares line
   through its points' (x, y), cut at their extreme projections.

Everything is seeded (``seed``), so the same scan gives the same segments.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from featmap.config import Section
from featmap.extraction.base import Extractor, ScanSegments, StageClock
from featmap.geometry import fit_line_tls


class RansacPlanesConfig(Section):
    """Vertical planes by sequential RANSAC (velodyne frame, metres)."""

    min_range_m: float = Field(2.5, ge=0, description="drop returns closer than this (vehicle body)")
    max_range_m: float = Field(50.0, gt=0, description="drop returns farther than this (sparse, noisy)")
    z_min_m: float = Field(-3.0, description="drop returns below this height in the velodyne frame")
    z_max_m: float = Field(6.0, description="drop returns above this height in the velodyne frame")
    voxel_size_m: float = Field(0.15, ge=0, description="voxel down-sampling before RANSAC (0 = off)")
    ground_threshold_m: float = Field(0.15, gt=0, description="RANSAC inlier distance of the ground plane")
    ground_margin_m: float = Field(0.3, ge=0, description="also drop points this close above the ground plane")
    plane_threshold_m: float = Field(0.08, gt=0, description="RANSAC inlier distance of a wall plane")
    ransac_iterations: int = Field(200, ge=10, description="RANSAC iterations per plane")
    ransac_max_points: int = Field(1200, ge=100, description="RANSAC hypotheses come from a random subset of this many points")
    max_planes: int = Field(25, ge=1, description="planes tried per scan")
    max_normal_tilt_deg: float = Field(10.0, ge=0, le=90, description="a wall's normal lies within this of horizontal")
    min_plane_inliers: int = Field(60, ge=3, description="stop when the best plane has fewer inliers")
    min_vertical_extent_m: float = Field(1.2, ge=0, description="a wall piece spans at least this in height")
    min_top_height_m: float = Field(1.85, ge=0, description="a wall piece reaches at least this high above the ground (0 = keep fences and cars)")
    max_gap_m: float = Field(1.5, gt=0, description="split a plane's inliers where they leave a gap this long")
    min_segment_length_m: float = Field(1.0, ge=0, description="drop wall pieces shorter than this")
    min_segment_points: int = Field(25, ge=2, description="drop wall pieces with fewer points")
    seed: int = Field(0, description="seed for Open3D's RANSAC (reproducible results)")


def crop(points: np.ndarray, config: RansacPlanesConfig) -> np.ndarray:
    """Keep (N, >=3) points within the range and height limits; returns (M, 3)."""
    xyz = np.asarray(points, dtype=np.float64)[:, :3]
    r = np.hypot(xyz[:, 0], xyz[:, 1])
    keep = (r >= config.min_range_m) & (r <= config.max_range_m)
    keep &= (xyz[:, 2] >= config.z_min_m) & (xyz[:, 2] <= config.z_max_m)
    return xyz[keep]


def _ransac_plane(xyz: np.ndarray, threshold: float, iterations: int, max_points: int | None = None,
                  rng: np.random.Generator | None = None):
    """Open3D RANSAC plane: returns (unit normal (3,), offset d, inlier indices into ``xyz``).

    With ``max_points``, the hypotheses are searched on a random subset of that size and the inliers
    are then every point of ``xyz`` within ``threshold`` of the plane.
    """
    import open3d as o3d

    sample = xyz
    if max_points is not None and len(xyz) > max_points:
        rng = rng or np.random.default_rng(0)
        sample = xyz[np.sort(rng.choice(len(xyz), max_points, replace=False))]
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(sample))
    model, inliers = cloud.segment_plane(distance_threshold=threshold, ransac_n=3, num_iterations=iterations)
    normal = np.asarray(model[:3], float)
    norm = np.linalg.norm(normal)
    if norm == 0 or len(inliers) < 3:
        return np.array([0.0, 0.0, 1.0]), 0.0, np.zeros(0, np.int64)
    normal, d = normal / norm, float(model[3]) / norm
    if sample is xyz:
        return normal, d, np.asarray(inliers, dtype=np.int64)
    return normal, d, np.flatnonzero(np.abs(xyz @ normal + d) <= threshold)


def remove_ground(xyz: np.ndarray, config: RansacPlanesConfig) -> tuple[np.ndarray, np.ndarray, float]:
    """Drop the ground: a near-horizontal RANSAC plane fitted to the lowest points, plus a margin above it.

    Returns (remaining points (M, 3), ground unit normal (3,) pointing up, offset d): the height of a
    point p above the ground is ``p @ normal + d``.
    """
    if len(xyz) < 10:
        return xyz, np.array([0.0, 0.0, 1.0]), -float(xyz[:, 2].min()) if len(xyz) else 0.0
    low = xyz[:, 2] < np.percentile(xyz[:, 2], 30) + 0.5
    candidates = xyz[low]
    if len(candidates) >= 10:
        normal, d, inliers = _ransac_plane(candidates, config.ground_threshold_m, config.ransac_iterations,
                                           config.ransac_max_points, np.random.default_rng(config.seed))
        if len(inliers) >= 10 and abs(normal[2]) > np.cos(np.deg2rad(15.0)):
            if normal[2] < 0:
                normal, d = -normal, -d
            height = xyz @ normal + d
            return xyz[height > config.ground_margin_m], normal, d
    # No clear ground plane (e.g. a scan full of walls): the 5th height percentile is the ground.
    floor = float(np.percentile(xyz[:, 2], 5))
    return xyz[xyz[:, 2] > floor + config.ground_margin_m], np.array([0.0, 0.0, 1.0]), -floor


def split_pieces(t: np.ndarray, max_gap: float) -> list[np.ndarray]:
    """Indices of runs of sorted positions ``t`` (K,) separated by gaps longer than ``max_gap``."""
    order = np.argsort(t, kind="stable")
    gaps = np.flatnonzero(np.diff(t[order]) > max_gap)
    return np.split(order, gaps + 1)


def extract_segments(points: np.ndarray, config: RansacPlanesConfig = RansacPlanesConfig(),
                     timings: dict[str, float] | None = None) -> ScanSegments:
    """Wall segments of one scan.

    Args:
        points: (N, 3) or (N, 4) velodyne-frame points (x forward, y left, z up; metres).
        config: extraction parameters.
        timings: if given, seconds spent per stage are added to it (crop, voxel, ground, planes, pieces).
    Returns:
        ScanSegments in the velodyne frame (possibly empty).
    """
    import open3d as o3d

    # Open3D's RANSAC runs its iterations on several threads, which makes the chosen plane depend on
    # scheduling even with a seed; one thread per scan is reproducible (the pipeline parallelises scans).
    threads = o3d.utility.get_max_threads()
    o3d.utility.set_max_threads(1)
    try:
        return _extract(points, config, timings)
    finally:
        o3d.utility.set_max_threads(threads)


def _extract(points: np.ndarray, config: RansacPlanesConfig, timings: dict[str, float] | None) -> ScanSegments:
    import open3d as o3d

    clock = StageClock(timings)
    o3d.utility.random.seed(int(config.seed))
    xyz = crop(points, config)
    clock.lap("crop")
    if config.voxel_size_m > 0 and len(xyz):
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz))
        xyz = np.asarray(cloud.voxel_down_sample(config.voxel_size_m).points)
    clock.lap("voxel")
    xyz, ground_normal, ground_d = remove_ground(xyz, config)
    clock.lap("ground")
    max_nz = np.sin(np.deg2rad(config.max_normal_tilt_deg))
    rows = []
    remaining = xyz
    rng = np.random.default_rng(config.seed)
    for _ in range(config.max_planes):
        if len(remaining) < config.min_plane_inliers:
            break
        normal, _, inliers = _ransac_plane(remaining, config.plane_threshold_m, config.ransac_iterations,
                                           config.ransac_max_points, rng)
        clock.lap("planes")
        if len(inliers) < config.min_plane_inliers:
            break
        plane_pts = remaining[inliers]
        mask = np.ones(len(remaining), bool)
        mask[inliers] = False
        remaining = remaining[mask]
        if abs(normal[2]) > max_nz:
            continue                                          # not a wall: car roof, ramp, leftover ground
        horizontal = np.array([-normal[1], normal[0]])
        horizontal /= np.linalg.norm(horizontal)
        for piece in split_pieces(plane_pts[:, :2] @ horizontal, config.max_gap_m):
            if len(piece) < config.min_segment_points:
                continue
            pts = plane_pts[piece]
            z_lo, z_hi = pts[:, 2].min(), pts[:, 2].max()
            if z_hi - z_lo < config.min_vertical_extent_m:
                continue
            if (pts @ ground_normal + ground_d).max() < config.min_top_height_m:
                continue                                      # fences, low walls, parked cars
            centroid, direction = fit_line_tls(pts[:, :2])
            t = (pts[:, :2] - centroid) @ direction
            if t.max() - t.min() < config.min_segment_length_m:
                continue
            normal2d = np.array([-direction[1], direction[0]])
            rms = float(np.sqrt(np.mean(((pts[:, :2] - centroid) @ normal2d) ** 2)))
            p1, p2 = centroid + t.min() * direction, centroid + t.max() * direction
            rows.append((p1[0], p1[1], p2[0], p2[1], pts[:, 2].mean(), len(pts), z_lo, z_hi, rms))
        clock.lap("pieces")
    if not rows:
        return ScanSegments.empty()
    arr = np.asarray(rows, float)
    return ScanSegments(segments=arr[:, :4], z_mean=arr[:, 4], n_points=arr[:, 5].astype(np.int64),
                        z_min=arr[:, 6], z_max=arr[:, 7], rms=arr[:, 8])


EXTRACTOR = Extractor(name="ransac_planes", dimension=3, config_type=RansacPlanesConfig, extract=extract_segments,
                      version=1)
