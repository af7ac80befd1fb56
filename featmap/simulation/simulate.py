"""Drive a simulated vehicle through a world and write a KITTI raw drive with its ground truth.

The vehicle's IMU follows the route at the sensor rate; the velodyne sits on it through a
KITTI-like ``T_velo_imu`` (velodyne origin ``sensor.height_m`` above flat ground), so
``T_w_velo = T_w_imu @ inv(T_velo_imu)`` exactly as pykitti users compute it. On a sloped world
the vehicle stands on the street plane: its height follows the slope and it pitches and rolls
with it, and the OXTS packets carry that altitude, pitch and roll, so pykitti's poses stay exact. Rays are cast from the
true velodyne pose (no motion distortion: every scan is an instantaneous sweep); the OXTS packets
carry the true pose, or a perturbed one with ``pose_noise`` (a smooth Gauss-Markov error with a
``pose_noise_tau_s`` correlation time, 2 s by default, the way GPS/INS errors drift rather than jump).

Ground truth written to ``<drive>/truth/``:

- ``walls.csv``: every building wall in the local frame, its vertex labels, and what the drive
  observed of it (returns within ``truth_range_m``, observed intervals along the wall);
- ``objects_local.json`` / ``objects.geojson``: every object with its kind (local frame / WGS84);
- ``footprints.geojson``: building footprints (WGS84), usable with ``featmap evaluate --truth``;
- ``trajectory.csv`` and ``simulation.json`` (parameters, seed, geo origin);
- ``observations.npz`` (with ``scan_observations=True``): per (scan, wall) the rays that hit the
  wall and where along it, with no range cap (:mod:`featmap.simulation.observations`).

Flat worlds simulated with a built-in sensor preset write exactly the files they always did;
sloped worlds add ``z, roll, pitch`` to ``trajectory.csv`` and the ground to ``simulation.json``,
and a sensor that differs from its preset (e.g. another azimuth step) is described there too.
"""

from __future__ import annotations

import csv
import datetime as dt
import io
import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from featmap.errors import FeatmapError, WorldError
from featmap.geo import GeoFrame, latlon_to_mercator, mercator_to_latlon, open_ring
from featmap.io.atomic import atomic_write_text, missing_folders, remove_empty_folders
from featmap.io.kitti_raw import (drive_paths, format_oxts_packet, write_calib_file, write_timestamps,
                                  write_velo_bin)
from featmap.io.sim_truth import COVERAGE_BIN_M, OBSERVATIONS_FILE, observed_intervals, write_coverage, write_observations
from featmap.simulation.ground import GroundSurface
from featmap.simulation.observations import concatenate, observe_scan
from featmap.simulation.scene import REFLECTANCE, build_scene, cast, through_foliage
from featmap.simulation.sensors import SENSORS, SensorPreset
from featmap.simulation.trajectory import sample_poses
from featmap.simulation.worlds import World

SIM_DATE = "2000_01_01"
"""Simulated drives use this date, so they never collide with a real KITTI drive."""
FOLIAGE_STREAM = 0xF011A6E
"""The second key of the porous foliage's random stream, ``default_rng([seed, FOLIAGE_STREAM])``."""


def rotation_xyz(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """pykitti's rotation ``Rz(yaw) @ Ry(pitch) @ Rx(roll)``."""
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def vehicle_attitude(grade: tuple[float, float], yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Roll and pitch (radians, pykitti's convention) of a vehicle standing on the plane of ``grade``.

    The vehicle's x axis points along ``yaw`` (radians, 0 = east) up or down the slope, its z axis
    along the plane's normal; ``rotation_xyz(roll, pitch, yaw)`` is then its exact attitude.
    Returns (roll (F,), pitch (F,)) for ``yaw`` (F,).
    """
    gx, gy = grade
    yaw = np.asarray(yaw, float)
    forward = np.stack([np.cos(yaw), np.sin(yaw), gx * np.cos(yaw) + gy * np.sin(yaw)], axis=1)
    forward /= np.linalg.norm(forward, axis=1, keepdims=True)
    up = np.array([-gx, -gy, 1.0]) / np.sqrt(gx * gx + gy * gy + 1.0)
    left = np.cross(up, forward)
    pitch = -np.arcsin(np.clip(forward[:, 2], -1.0, 1.0))
    roll = np.arctan2(left[:, 2], np.full(len(yaw), up[2]))
    return roll, pitch


def synthetic_T_velo_imu() -> np.ndarray:
    """A KITTI-like IMU-to-velodyne transform (velodyne 0.80 m above and 0.81 m ahead of the IMU, ~0.85 deg tilt)."""
    T = np.eye(4)
    T[:3, :3] = rotation_xyz(0.0148, -0.0020, 0.0008)
    T[:3, 3] = (-0.81, 0.32, -0.80)
    return T


def write_calibration(calib_dir: Path, T_velo_imu: np.ndarray) -> None:
    """The three KITTI calibration files (synthetic, KITTI-like values; cameras are not simulated)."""
    write_calib_file(calib_dir / "calib_imu_to_velo.txt",
                     {"calib_time": "01-Jan-2000 00:00:00", "R": T_velo_imu[:3, :3], "T": T_velo_imu[:3, 3]})
    R_cam_velo = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    write_calib_file(calib_dir / "calib_velo_to_cam.txt",
                     {"calib_time": "01-Jan-2000 00:00:00", "R": R_cam_velo, "T": np.array([0.0, -0.08, -0.27]),
                      "delta_f": np.zeros(2), "delta_c": np.zeros(2)})
    cam: dict = {"calib_time": "01-Jan-2000 00:00:00", "corner_dist": np.array([0.0995])}
    for k, bx in enumerate((0.0, -0.54, 0.06, -0.48)):
        K = np.array([[720.0, 0, 610.0], [0, 720.0, 175.0], [0, 0, 1.0]])
        cam.update({f"S_{k:02d}": np.array([1392.0, 512.0]), f"K_{k:02d}": K, f"D_{k:02d}": np.zeros(5),
                    f"R_{k:02d}": np.eye(3), f"T_{k:02d}": np.array([bx, 0.0, 0.0]),
                    f"S_rect_{k:02d}": np.array([1242.0, 375.0]), f"R_rect_{k:02d}": np.eye(3),
                    f"P_rect_{k:02d}": np.hstack([K, [[bx * 720.0], [0.0], [0.0]]])})
    write_calib_file(calib_dir / "calib_cam_to_cam.txt", cam)


DEFAULT_POSE_NOISE_TAU_S = 2.0
"""Correlation time of the simulated OXTS error unless ``pose_noise_tau_s`` says otherwise (seconds)."""


def gauss_markov(rng: np.random.Generator, n: int, sigma: float, dt_s: float,
                 tau_s: float = DEFAULT_POSE_NOISE_TAU_S) -> np.ndarray:
    """(n,) stationary first-order Gauss-Markov sequence with std ``sigma`` and correlation time ``tau_s``,
    ``dt_s`` seconds apart."""
    if tau_s <= 0:
        raise FeatmapError(f"pose-noise correlation time {tau_s} s: must be positive")
    if sigma <= 0 or n == 0:
        return np.zeros(n)
    a = np.exp(-dt_s / tau_s)
    out = np.empty(n)
    out[0] = rng.normal(0, sigma)
    shocks = rng.normal(0, sigma * np.sqrt(1 - a * a), n)
    for k in range(1, n):
        out[k] = a * out[k - 1] + shocks[k]
    return out


def gauss_markov_at(rng: np.random.Generator, times: np.ndarray, sigma: float,
                    tau_s: float = DEFAULT_POSE_NOISE_TAU_S) -> np.ndarray:
    """(n,) stationary first-order Gauss-Markov process with std ``sigma`` and correlation time ``tau_s``
    sampled at increasing ``times`` (n,) seconds (any spacing; the same draws as :func:`gauss_markov`)."""
    if tau_s <= 0:
        raise FeatmapError(f"pose-noise correlation time {tau_s} s: must be positive")
    times = np.asarray(times, float).reshape(-1)
    n = len(times)
    if sigma <= 0 or n == 0:
        return np.zeros(n)
    a = np.exp(-np.maximum(np.diff(times, prepend=times[0]), 0.0) / tau_s)     # a repeated or earlier time: no decay
    out = np.empty(n)
    out[0] = rng.normal(0, sigma)
    shocks = rng.normal(0, sigma * np.sqrt(1 - a * a), n)
    for k in range(1, n):
        out[k] = a[k] * out[k - 1] + shocks[k]
    return out


def oxts_drift(rng: np.random.Generator, times: np.ndarray, pose_noise: tuple[float, float],
               tau_s: float = DEFAULT_POSE_NOISE_TAU_S) -> np.ndarray:
    """(n, 3) OXTS pose error ``x, y`` (metres, world frame) and ``yaw`` (radians) at ``times`` (n,) seconds.

    Each axis is an independent first-order Gauss-Markov process (:func:`gauss_markov_at`) with std
    ``pose_noise = (metres, degrees)`` and correlation time ``tau_s``; drawn from ``rng`` in the order
    x, y, yaw, as :func:`simulate_drive` draws them.
    """
    return np.column_stack([gauss_markov_at(rng, times, pose_noise[0], tau_s),
                            gauss_markov_at(rng, times, pose_noise[0], tau_s),
                            gauss_markov_at(rng, times, np.deg2rad(pose_noise[1]), tau_s)])


def perturb_poses(T_world_sensor: np.ndarray, error: np.ndarray, T_sensor_body: np.ndarray | None = None) -> np.ndarray:
    """Poses with an OXTS-style error: the body (IMU) moved by ``error[:, :2]`` and turned by ``error[:, 2]``
    about its own position, in the world frame, the sensor riding on it.

    Args:
        T_world_sensor: (F, 4, 4) true poses.
        error: (F, 3) ``dx, dy, dyaw`` (metres, radians), e.g. from :func:`oxts_drift`.
        T_sensor_body: (4, 4) the body's pose in the sensor frame (``T_velo_imu`` of a KITTI drive);
            None when the pose is the sensor's own (a 2D laser log).
    Returns:
        (F, 4, 4) perturbed ``T_world_sensor``: what :func:`simulate_drive` with the same error writes.
    """
    T = np.asarray(T_world_sensor, float)
    error = np.asarray(error, float).reshape(-1, 3)
    body = T[:, :3, 3] if T_sensor_body is None else (T @ np.asarray(T_sensor_body, float)[:, 3])[:, :3]
    c, s = np.cos(error[:, 2]), np.sin(error[:, 2])
    out = T.copy()
    rot = np.zeros((len(T), 3, 3))
    rot[:, 0, 0], rot[:, 0, 1], rot[:, 1, 0], rot[:, 1, 1], rot[:, 2, 2] = c, -s, s, c, 1.0
    out[:, :3, :3] = rot @ T[:, :3, :3]
    out[:, :3, 3] = np.einsum("fij,fj->fi", rot, T[:, :3, 3] - body) + body
    out[:, :2, 3] += error[:, :2]
    return out


@dataclass(frozen=True)
class SimulatedDrive:
    """Where a simulated drive was written."""

    root: Path          # KITTI raw root (contains DATE/)
    date: str
    drive_id: str
    n_frames: int

    @property
    def drive(self) -> str:
        return f"{self.date}_drive_{self.drive_id}"

    @property
    def drive_dir(self) -> Path:
        return drive_paths(self.root, self.date, self.drive_id)[1]


NOT_SIMULATOR_CODE = frozenset({"splits.py"})
"""Modules of :mod:`featmap.simulation` left out of :func:`simulation_fingerprint`: which seeds form which
split does not change how any drive is simulated."""

SIMULATOR_DEPENDENCIES = ("featmap.geo", "featmap.geometry", "featmap.io.carmen", "featmap.io.kitti_raw",
                          "featmap.io.sim_truth")
"""Modules outside :mod:`featmap.simulation` whose code shapes what a simulated drive's files hold (the OXTS
positions, calibration and packet format, the truth's observed intervals and coverage, the indoor beams):
part of :func:`simulation_fingerprint`, so that an edit to them simulates the cached drives again."""
NOT_OUTPUT_DEPENDENCIES = ("featmap.config", "featmap.errors", "featmap.io.atomic", "featmap.io.jsonfile")
"""The other modules the simulator imports: they read world files (whose content is in the fingerprint's
spec), name errors, or make writes atomic, and shape none of a drive's files. A test keeps the two lists
equal to everything :mod:`featmap.simulation` imports, at any depth."""


def simulation_fingerprint(spec: dict) -> str:
    """16 hex digits naming what a simulated drive is made from: ``spec`` (JSON-able: the world, sensor,
    noise, seed, ...), the source code of :mod:`featmap.simulation` (but for :data:`NOT_SIMULATOR_CODE`) and
    that of :data:`SIMULATOR_DEPENDENCIES`, so that a cached drive is simulated again when any changes."""
    import hashlib
    import importlib.util

    import featmap.simulation as simulation

    sources = sorted(p for p in Path(simulation.__file__).parent.glob("*.py") if p.name not in NOT_SIMULATOR_CODE)
    sources += [Path(importlib.util.find_spec(name).origin) for name in SIMULATOR_DEPENDENCIES]
    spec = {**spec, "simulator": hashlib.sha256(b"".join(p.read_bytes() for p in sources)).hexdigest()}
    return hashlib.sha256(json.dumps(spec, sort_keys=True, default=list).encode()).hexdigest()[:16]


def simulate_drive(world: World, out_root: str | Path, sensor: SensorPreset, n_frames: int | None = None,
                   noise_m: float = 0.02, dropout: float = 0.0, pose_noise: tuple[float, float] = (0.0, 0.0),
                   seed: int = 0, drive_id: str = "0001", truth_range_m: float = 50.0,
                   progress: Callable[[Iterable, int], Iterable] | None = None,
                   scan_observations: bool = False,
                   pose_noise_tau_s: float = DEFAULT_POSE_NOISE_TAU_S) -> SimulatedDrive:
    """Simulate ``world`` and write the drive under ``out_root`` (KITTI raw layout).

    The drive is written into a hidden temporary folder and moved into place at the end, so an
    interrupted simulation never leaves a drive that looks complete.

    Args:
        world: validated world.
        out_root: KITTI raw root; the drive lands in ``out_root/2000_01_01/2000_01_01_drive_<id>_sync``.
        sensor: beam pattern, range and mounting height.
        n_frames: cap on the number of frames (default: the whole route).
        noise_m: standard deviation of the Gaussian range noise (metres).
        dropout: probability that a return is lost.
        pose_noise: (position std in metres, yaw std in degrees) of the error added to the OXTS poses.
        pose_noise_tau_s: correlation time of that error (seconds; a first-order Gauss-Markov process per axis).
        seed: seeds every random draw; the same seed writes byte-identical files.
        truth_range_m: wall returns closer than this count as observations in the ground truth.
        progress: wraps the frame loop, e.g. ``lambda it, n: rich.progress.track(it, total=n)``.
        scan_observations: also write ``truth/observations.npz``, what each scan saw of each wall.
    """
    calib_dir, final_dir = drive_paths(Path(out_root), SIM_DATE, drive_id)
    partial = final_dir.parent / f".{final_dir.name}.partial"
    made = missing_folders(calib_dir)
    try:
        return _simulate_drive(world, out_root, sensor, n_frames, noise_m, dropout, pose_noise, seed, drive_id,
                               truth_range_m, progress, scan_observations, pose_noise_tau_s)
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)      # a failed simulation leaves nothing that looks like a drive
        remove_empty_folders(made)                      # nor the empty folders it made
        raise


def _simulate_drive(world: World, out_root: str | Path, sensor: SensorPreset, n_frames: int | None = None,
                    noise_m: float = 0.02, dropout: float = 0.0, pose_noise: tuple[float, float] = (0.0, 0.0),
                    seed: int = 0, drive_id: str = "0001", truth_range_m: float = 50.0,
                    progress: Callable[[Iterable, int], Iterable] | None = None,
                    scan_observations: bool = False,
                    pose_noise_tau_s: float = DEFAULT_POSE_NOISE_TAU_S) -> SimulatedDrive:
    """The body of :func:`simulate_drive` (which removes its temporary folder when this fails)."""
    if not (0.0 <= dropout < 1.0):
        raise FeatmapError(f"--dropout {dropout}: must be in [0, 1)")
    if not all(np.isfinite(v) and v >= 0 for v in (noise_m, *pose_noise)):
        raise FeatmapError("--noise and --pose-noise must be finite and non-negative")
    if not pose_noise_tau_s > 0:
        raise FeatmapError(f"--pose-noise-tau {pose_noise_tau_s}: must be positive (seconds)")
    rng = np.random.default_rng(seed)
    out_root = Path(out_root)
    calib_dir, final_dir = drive_paths(out_root, SIM_DATE, drive_id)
    if final_dir.exists():
        raise FeatmapError(f"{final_dir}: drive already exists; choose another --out or remove it")
    tmp_dir = calib_dir / f".{final_dir.name}.partial"
    if tmp_dir.exists():
        shutil.rmtree(tmp_dir)

    dt_s = 1.0 / sensor.rate_hz
    try:
        xy, yaw = sample_poses(np.asarray(world.route.waypoints), world.route.speed_mps, world.route.turn_radius_m,
                               sensor.rate_hz, n_frames)
    except WorldError as exc:
        raise WorldError(f"{world.source or world.name}: {exc}") from None
    n = len(xy)
    if n < 2:
        raise FeatmapError(f"{world.source or world.name}: the route is too short for two frames")
    T_velo_imu = synthetic_T_velo_imu()
    T_imu_velo = np.linalg.inv(T_velo_imu)
    imu_z = sensor.height_m - T_imu_velo[2, 3]           # puts the velodyne origin at sensor.height_m
    surface = GroundSurface(world.ground)
    flat = surface.is_flat
    if flat:
        z_imu = np.full(n, imu_z)
        roll = pitch = np.zeros(n)
    else:                                                # the vehicle stands on the street plane
        z_imu = surface.plane_height(xy) + imu_z
        roll, pitch = vehicle_attitude(world.ground.grade, yaw)
    p0 = np.array([xy[0, 0], xy[0, 1], z_imu[0]])

    # Geographic anchor: the first OXTS packet is at the world's geo origin shifted to the first pose.
    s0 = np.cos(np.deg2rad(world.geo_origin.lat))
    mx, my = latlon_to_mercator(world.geo_origin.lat, world.geo_origin.lon, s0)
    lat0, lon0 = mercator_to_latlon(mx + p0[0], my + p0[1], s0)
    lon0 = float(lon0)
    if not -180.0 <= lon0 <= 180.0:       # the first pose across the date line: the same meridian, wrapped
        lon0 = (lon0 + 180.0) % 360.0 - 180.0
    geo = GeoFrame(float(lat0), lon0, 100.0)

    scene, index = build_scene(world)
    foliage_cast = _foliage_caster(world, index, seed) if index.foliage else None
    directions = sensor.ray_directions()
    edges = index.edges
    n_bins = np.array([max(1, int(np.ceil(np.linalg.norm(e["q"] - e["p"]) / COVERAGE_BIN_M))) for e in edges], np.int64)
    bin_offset = np.concatenate([[0], np.cumsum(n_bins)]).astype(np.int64)
    coverage = np.zeros(int(bin_offset[-1]), np.int64)
    edge_p = np.array([e["p"] for e in edges]).reshape(-1, 2)
    edge_u = np.array([(e["q"] - e["p"]) / np.linalg.norm(e["q"] - e["p"]) for e in edges]).reshape(-1, 2)
    kind_of_gid = index.kinds
    azimuth_step_rad = np.deg2rad(sensor.azimuth_step_deg)
    scan_obs = []

    err_x = gauss_markov(rng, n, pose_noise[0], dt_s, pose_noise_tau_s)
    err_y = gauss_markov(rng, n, pose_noise[0], dt_s, pose_noise_tau_s)
    err_yaw = gauss_markov(rng, n, np.deg2rad(pose_noise[1]), dt_s, pose_noise_tau_s)

    drive_tmp = tmp_dir
    velo_dir = drive_tmp / "velodyne_points" / "data"
    oxts_dir = drive_tmp / "oxts" / "data"
    velo_dir.mkdir(parents=True)
    oxts_dir.mkdir(parents=True)
    per_frame: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []     # (frame, bin, count) per scan
    frames = range(n) if progress is None else progress(range(n), n)
    yaw_rate = np.gradient(np.unwrap(yaw), dt_s)
    speed = world.route.speed_mps
    for k in frames:
        T_w_imu = np.eye(4)
        T_w_imu[:3, :3] = rotation_xyz(0.0, 0.0, yaw[k]) if flat else rotation_xyz(roll[k], pitch[k], yaw[k])
        T_w_imu[:3, 3] = (xy[k, 0], xy[k, 1], z_imu[k])
        T_w_velo = T_w_imu @ T_imu_velo
        R, origin = T_w_velo[:3, :3], T_w_velo[:3, 3]
        directions_w = directions @ R.T
        t_hit, gid, prim = cast(scene, origin, directions_w)
        if foliage_cast is not None:
            t_hit, gid, prim = foliage_cast(t_hit, gid, prim, origin, directions_w)
        keep = np.isfinite(t_hit) & (t_hit <= sensor.max_range_m) & (t_hit >= sensor.min_range_m)
        if dropout > 0:
            keep &= rng.random(len(t_hit)) >= dropout
        rng_noise = rng.normal(0.0, noise_m, len(t_hit)) if noise_m > 0 else np.zeros(len(t_hit))
        r = t_hit[keep] + rng_noise[keep]
        pts = directions[keep] * r[:, None]
        kinds = gid[keep]
        refl = np.zeros(len(r))
        for g, kind in kind_of_gid.items():
            refl[kinds == g] = REFLECTANCE[kind]
        refl = np.clip(refl + rng.normal(0.0, 0.03, len(r)), 0.0, 1.0)
        write_velo_bin(velo_dir / f"{k:010d}.bin", np.column_stack([pts, refl]))

        # Ground truth: which stretches of which walls this scan saw (true geometry, no noise).
        wall = keep & (gid == index.wall_geometry_id) & (t_hit <= truth_range_m)
        if wall.any():
            hit_w = origin + directions_w[wall] * t_hit[wall, None]
            e = index.wall_edge_of_triangle[prim[wall]]
            s = np.einsum("ij,ij->i", hit_w[:, :2] - edge_p[e], edge_u[e])
            b = np.clip((s / COVERAGE_BIN_M).astype(np.int64), 0, n_bins[e] - 1)
            bins, counts = np.unique(bin_offset[e] + b, return_counts=True)
            coverage[bins] += counts
            per_frame.append((np.full(len(bins), k, np.int32), bins.astype(np.int32), counts.astype(np.int32)))
        if scan_observations:
            scan_obs.append(_observe(k, keep & (gid == index.wall_geometry_id), origin, directions_w, t_hit, prim,
                                     index.wall_edge_of_triangle, edge_p, edge_u, azimuth_step_rad))

        # OXTS: the (possibly perturbed) IMU pose of this frame.
        noisy_x, noisy_y, noisy_yaw = xy[k, 0] + err_x[k], xy[k, 1] + err_y[k], yaw[k] + err_yaw[k]
        lat, lon = geo.to_wgs84(noisy_x - p0[0], noisy_y - p0[1])
        wrapped_yaw = (noisy_yaw + np.pi) % (2 * np.pi) - np.pi
        alt = geo.alt0_m if flat else geo.alt0_m + float(z_imu[k] - z_imu[0])
        packet = {"lat": float(lat), "lon": float(lon), "alt": alt, "roll": float(roll[k]), "pitch": float(pitch[k]),
                  "yaw": wrapped_yaw, "vn": speed * np.sin(yaw[k]), "ve": speed * np.cos(yaw[k]), "vf": speed,
                  "az": 9.81, "ay": speed * yaw_rate[k], "al": speed * yaw_rate[k], "au": 9.81,
                  "wz": yaw_rate[k], "wu": yaw_rate[k], "pos_accuracy": max(0.02, pose_noise[0]),
                  "vel_accuracy": 0.02, "navstat": 4, "numsats": 10, "posmode": 5, "velmode": 5, "orimode": 6}
        (oxts_dir / f"{k:010d}.txt").write_text(format_oxts_packet(packet))

    start = dt.datetime(2000, 1, 1, 12, 0, 0)
    seconds = np.arange(n) * dt_s
    for sub in ("velodyne_points", "oxts"):
        write_timestamps(drive_tmp / sub / "timestamps.txt", seconds, start)
    (drive_tmp / "oxts" / "dataformat.txt").write_text(_OXTS_DATAFORMAT)
    write_calibration(calib_dir, T_velo_imu)
    write_coverage(drive_tmp / "truth" / "coverage.npz", per_frame, bin_offset)
    if scan_observations:
        write_observations(drive_tmp / "truth" / OBSERVATIONS_FILE, concatenate(scan_obs), len(edges))
    params = {
        "world": world.name, "world_source": world.source, "sensor": sensor.name,
        "noise_m": noise_m, "dropout": dropout, "pose_noise": list(pose_noise), "seed": seed,
        "frames": n, "truth_range_m": truth_range_m, "speed_mps": speed,
        "geo_origin": geo.to_dict(), "world_offset_xy": [float(p0[0]), float(p0[1])],
    }
    if pose_noise_tau_s != DEFAULT_POSE_NOISE_TAU_S:     # drives with the default stay byte-identical
        params["pose_noise_tau_s"] = pose_noise_tau_s
    if SENSORS.get(sensor.name) != sensor:               # a customised preset: say what was simulated
        params["sensor_spec"] = {"n_beams": sensor.n_beams, "elevations_deg": list(sensor.elevations_deg),
                                 "azimuth_step_deg": sensor.azimuth_step_deg, "max_range_m": sensor.max_range_m,
                                 "min_range_m": sensor.min_range_m, "height_m": sensor.height_m,
                                 "rate_hz": sensor.rate_hz}
    if not flat:
        params["ground"] = world.ground.model_dump(mode="json")
        params["world_offset_z"] = float(p0[2])
    trajectory_z = None if flat else (z_imu - p0[2], roll, pitch)
    _write_truth(drive_tmp / "truth", world, edges, coverage, bin_offset, n_bins, p0, geo, xy, yaw,
                 err_x, err_y, err_yaw, params, trajectory_z)
    os.replace(drive_tmp, final_dir)
    return SimulatedDrive(out_root, SIM_DATE, drive_id, n)


def _foliage_caster(world: World, index, seed: int):
    """``(t_hit, gid, prim, origin, directions_w) -> (t_hit, gid, prim)`` applying the world's porous foliage
    (:func:`featmap.simulation.scene.through_foliage`) with its own random stream (``seed``'s, so the drive's
    other draws stay as they are), rays passing through foliage cast again in the scene without it."""
    bare_scene, bare_index = build_scene(world, without_foliage=True)
    gid_of_kind = {kind: g for g, kind in index.kinds.items()}
    to_full = {g: gid_of_kind[kind] for g, kind in bare_index.kinds.items()}
    rng = np.random.default_rng([seed, FOLIAGE_STREAM])

    def apply(t_hit, gid, prim, origin, directions_w):
        def cast_without_foliage(rows):
            t2, g2, p2 = cast(bare_scene, origin, directions_w[rows])
            mapped = g2.copy()
            for g_bare, g_full in to_full.items():
                mapped[g2 == g_bare] = g_full
            return t2, mapped, p2

        return through_foliage(t_hit, gid, prim, index, rng, cast_without_foliage)

    return apply


def _observe(frame: int, wall_rays: np.ndarray, origin: np.ndarray, directions_w: np.ndarray, t_hit: np.ndarray,
             prim: np.ndarray, edge_of_triangle: np.ndarray, edge_p: np.ndarray, edge_u: np.ndarray,
             azimuth_step_rad: float):
    """Observations of one scan: where its (true, noise-free) wall hits land along each wall."""
    d = directions_w[wall_rays]
    t = t_hit[wall_rays]
    e = edge_of_triangle[prim[wall_rays]]
    hit_xy = origin[:2] + d[:, :2] * t[:, None]
    s = np.einsum("ij,ij->i", hit_xy - edge_p[e], edge_u[e])
    horizontal = np.hypot(d[:, 0], d[:, 1])
    normal = np.column_stack([-edge_u[e, 1], edge_u[e, 0]])
    cos_incidence = np.abs(np.einsum("ij,ij->i", d[:, :2], normal)) / np.maximum(horizontal, 1e-9)
    spacing = t * horizontal * azimuth_step_rad / np.maximum(cos_incidence, 0.1)
    return observe_scan(frame, e, s, spacing)


def _write_truth(folder: Path, world: World, edges, coverage, bin_offset, n_bins, p0, geo: GeoFrame,
                 xy, yaw, err_x, err_y, err_yaw, params: dict, trajectory_z=None) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    off = p0[:2]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["building", "ring", "edge", "x1", "y1", "x2", "y2", "height", "label_1", "label_2",
                "n_returns", "observed_m", "observed_intervals"])
    for k, e in enumerate(edges):
        counts = coverage[bin_offset[k]:bin_offset[k] + n_bins[k]]
        length = float(np.linalg.norm(e["q"] - e["p"]))
        intervals = observed_intervals(counts, length=length)
        observed = sum(b - a for a, b in intervals)
        p, q = e["p"] - off, e["q"] - off
        w.writerow([e["building"], e["ring"], e["edge"], f"{p[0]:.4f}", f"{p[1]:.4f}", f"{q[0]:.4f}", f"{q[1]:.4f}",
                    e["height"], e["label_p"], e["label_q"], int(counts.sum()), f"{observed:.2f}",
                    ";".join(f"{a:.2f}-{b:.2f}" for a, b in intervals)])
    atomic_write_text(folder / "walls.csv", buf.getvalue())

    objects_local, features = [], []
    for n, obj in enumerate(world.objects):
        oid = obj.id or f"{obj.kind}{n}"
        if obj.kind == "building":
            rings = [np.asarray(open_ring(obj.footprint), float)] + [np.asarray(open_ring(h), float) for h in obj.holes]
            local = [(r - off).round(4).tolist() for r in rings]
            geom_local = {"type": "Polygon", "coordinates": local}
            extra = {"height": obj.height, "vertex_labels": obj.vertex_labels}
        elif obj.kind in ("fence", "hedge"):
            geom_local = {"type": "LineString", "coordinates": (np.asarray(obj.line) - off).round(4).tolist()}
            extra = {"height": obj.height}
        elif obj.kind == "car":
            L, W, H = obj.size
            c, s = np.cos(np.deg2rad(obj.heading_deg)), np.sin(np.deg2rad(obj.heading_deg))
            corners = np.array([[-L / 2, -W / 2], [L / 2, -W / 2], [L / 2, W / 2], [-L / 2, W / 2]]) @ np.array([[c, s], [-s, c]])
            geom_local = {"type": "Polygon", "coordinates": [(corners + np.asarray(obj.position) - off).round(4).tolist()]}
            extra = {"height": H}
        else:
            geom_local = {"type": "Point", "coordinates": (np.asarray(obj.position) - off).round(4).tolist()}
            extra = {"radius": getattr(obj, "radius", getattr(obj, "trunk_radius", 0.2))}
        objects_local.append({"id": oid, "kind": obj.kind, "geometry": geom_local, **extra})
        features.append({"type": "Feature", "properties": {"id": oid, "kind": obj.kind, **extra},
                         "geometry": _geometry_to_wgs84(geom_local, geo)})
    atomic_write_text(folder / "objects_local.json", json.dumps({"frame": "local (pykitti), metres",
                                                                  "objects": objects_local}, indent=1))
    fc = {"type": "FeatureCollection", "features": features}
    atomic_write_text(folder / "objects.geojson", json.dumps(fc))
    buildings = {"type": "FeatureCollection", "features": [f for f in features if f["properties"]["kind"] == "building"]}
    atomic_write_text(folder / "footprints.geojson", json.dumps(buildings))

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    header = ["frame", "x", "y", "yaw", "oxts_x", "oxts_y", "oxts_yaw"]
    w.writerow(header if trajectory_z is None else header + ["z", "roll", "pitch"])
    for k in range(len(xy)):
        row = [k, f"{xy[k, 0] - off[0]:.4f}", f"{xy[k, 1] - off[1]:.4f}", f"{yaw[k]:.6f}",
               f"{xy[k, 0] + err_x[k] - off[0]:.4f}", f"{xy[k, 1] + err_y[k] - off[1]:.4f}", f"{yaw[k] + err_yaw[k]:.6f}"]
        if trajectory_z is not None:
            row += [f"{trajectory_z[0][k]:.4f}", f"{trajectory_z[1][k]:.6f}", f"{trajectory_z[2][k]:.6f}"]
        w.writerow(row)
    atomic_write_text(folder / "trajectory.csv", buf.getvalue())
    atomic_write_text(folder / "simulation.json", json.dumps(params, indent=1, default=str))


def _geometry_to_wgs84(geom: dict, geo: GeoFrame) -> dict:
    def conv(coords):
        arr = np.asarray(coords, float)
        lat, lon = geo.to_wgs84(arr[..., 0], arr[..., 1])
        return np.stack([lon, lat], axis=-1).round(9).tolist()

    if geom["type"] == "Polygon":
        rings = []
        for ring in geom["coordinates"]:
            closed = list(ring) + [ring[0]]
            rings.append(conv(closed))
        return {"type": "Polygon", "coordinates": rings}
    return {"type": geom["type"], "coordinates": conv(geom["coordinates"])}


_OXTS_DATAFORMAT = "\n".join([
    "lat:   latitude of the oxts-unit (deg)", "lon:   longitude of the oxts-unit (deg)",
    "alt:   altitude of the oxts-unit (m)", "roll:  roll angle (rad)", "pitch: pitch angle (rad)",
    "yaw:   heading (rad), 0 = east, positive = counter clockwise",
    "(the remaining 24 fields follow the KITTI raw OXTS format; see featmap.io.kitti_raw.OXTS_FIELDS)", ""])
