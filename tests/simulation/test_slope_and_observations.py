"""Sloped ground with curbs keeps poses exact; per-scan observation truth counts the right rays."""

import csv
import json

import numpy as np
import pytest

from featmap.io.sim_truth import read_observations
from featmap.simulation.sensors import SENSORS, SensorPreset
from featmap.simulation.simulate import simulate_drive, vehicle_attitude
from featmap.simulation.worlds import world_from_dict

GRADE = (0.04, -0.03)
CURB = 0.12
ROAD_W = 8.0


def _sloped_world():
    # a street along the route (30 m north-east), a 130 m wall 12 m north of it, a hedge and a car
    return world_from_dict({
        "name": "slope", "route": {"waypoints": [[0, 0], [30, 20]], "speed_mps": 8, "turn_radius_m": 0},
        "ground": {"grade": list(GRADE), "curb_height": CURB,
                   "streets": [{"line": [[-60, -40], [90, 60]], "width": ROAD_W}]},
        "objects": [{"id": "W", "kind": "building", "height": 8, "footprint": [[-50, 12], [80, 12], [80, 14], [-50, 14]]},
                    {"id": "h", "kind": "hedge", "line": [[0, 8], [20, 8]], "height": 1.0, "seed": 3},
                    {"id": "c", "kind": "car", "position": [10, 5]}],
    }, "slope.yaml")


@pytest.fixture(scope="module")
def slope_drive(tmp_path_factory):
    root = tmp_path_factory.mktemp("slope")
    return simulate_drive(_sloped_world(), root, SENSORS["vlp16"].with_azimuth_step(0.4), n_frames=8, noise_m=0.0,
                          seed=1, scan_observations=True)


def _world_points(drive, k):
    import pykitti

    data = pykitti.raw(str(drive.root), drive.date, drive.drive_id)
    sim = json.loads((drive.drive_dir / "truth" / "simulation.json").read_text())
    offset = np.array(sim["world_offset_xy"] + [sim["world_offset_z"]])
    T_w_velo = data.oxts[k].T_w_imu @ np.linalg.inv(data.calib.T_velo_imu)
    pts = data.get_velo(k)[:, :3].astype(float)
    return pts @ T_w_velo[:3, :3].T + T_w_velo[:3, 3] + offset, T_w_velo[:3, 3] + offset


def test_a_wall_on_a_slope_comes_back_where_it_is(slope_drive):
    for k in (0, 7):
        pts, _ = _world_points(slope_drive, k)
        ground = pts[:, :2] @ np.asarray(GRADE)
        wall = (np.abs(pts[:, 1] - 12.0) < 0.2) & (pts[:, 2] > ground + 0.5)
        assert wall.sum() > 500
        assert np.abs(pts[wall, 1] - 12.0).max() < 2e-3          # exact poses (float32 scans)


def test_road_and_sidewalk_lie_on_the_sloped_plane_a_curb_apart(slope_drive):
    from shapely import intersects_xy
    from shapely.geometry import LineString

    pts, origin = _world_points(slope_drive, 3)
    road = LineString([[-60, -40], [90, 60]]).buffer(ROAD_W / 2, cap_style="flat")
    inner = road.buffer(-0.3)
    outer = road.buffer(0.3)
    residual = pts[:, 2] - pts[:, :2] @ np.asarray(GRADE)
    near = np.hypot(*(pts[:, :2] - origin[:2]).T) < 25
    free = (np.hypot(pts[:, 0] - 10, pts[:, 1] - 5) > 3.5) & (pts[:, 1] < 11)        # away from the car and the wall
    free &= ~((pts[:, 1] > 6.5) & (pts[:, 1] < 9.5) & (pts[:, 0] > -1.5) & (pts[:, 0] < 21.5))   # and the hedge
    on_road = near & free & intersects_xy(inner, pts[:, 0], pts[:, 1])
    off_road = near & free & ~intersects_xy(outer, pts[:, 0], pts[:, 1])
    assert on_road.sum() > 300 and off_road.sum() > 300
    assert np.abs(residual[on_road]).max() < 2e-3                  # the street: on the sloped plane
    assert np.abs(residual[off_road] - CURB).max() < 2e-3          # the sidewalk: a curb higher


def test_oxts_and_trajectory_follow_the_slope(slope_drive):
    rows = list(csv.DictReader(open(slope_drive.drive_dir / "truth" / "trajectory.csv")))
    xy = np.array([[float(r["x"]), float(r["y"])] for r in rows])
    z = np.array([float(r["z"]) for r in rows])
    np.testing.assert_allclose(z, xy @ np.asarray(GRADE), atol=2e-4)
    packets = [np.array(p.read_text().split(), float) for p in sorted((slope_drive.drive_dir / "oxts" / "data").glob("*.txt"))]
    roll, pitch = np.array([p[3] for p in packets]), np.array([p[4] for p in packets])
    heading = np.arctan2(20, 30)
    exp_roll, exp_pitch = vehicle_attitude(GRADE, np.full(len(packets), heading))
    np.testing.assert_allclose(roll, exp_roll, atol=1e-12)
    np.testing.assert_allclose(pitch, exp_pitch, atol=1e-12)
    # driving up a 0.04 * cos + -0.03 * sin grade: the nose is up, i.e. pitch negative in KITTI's convention
    along = GRADE[0] * np.cos(heading) + GRADE[1] * np.sin(heading)
    assert pitch[0] == pytest.approx(-np.arctan(along), abs=1e-9)


def test_vehicle_attitude_is_level_on_flat_ground():
    roll, pitch = vehicle_attitude((0.0, 0.0), np.linspace(-3, 3, 7))
    assert np.all(roll == 0) and np.allclose(pitch, 0)


# --- per-scan observations on a hand-made world -----------------------------------------------------

THREE_BEAMS = SensorPreset("three", (4.0, 0.0, -4.0), azimuth_step_deg=1.0, max_range_m=120.0, min_range_m=1.0,
                           height_m=1.73)


def _wall_world(y: float, half_length: float, height: float, extra=()):
    return world_from_dict({
        "name": "w", "route": {"waypoints": [[0, 0], [10, 0]], "speed_mps": 5, "turn_radius_m": 0},
        "objects": [{"id": "W", "kind": "building", "height": height,
                     "footprint": [[-half_length, y], [half_length, y], [half_length, y + 2], [-half_length, y + 2]]},
                    *extra]}, "w.yaml")


def _expected_hits(drive, y: float, half_length: float, height: float, sensor: SensorPreset, margin=0.01):
    """Rays of frame 0 that certainly / possibly hit the wall face y = ``y`` (an independent ray-plane test)."""
    import pykitti

    data = pykitti.raw(str(drive.root), drive.date, drive.drive_id)
    sim = json.loads((drive.drive_dir / "truth" / "simulation.json").read_text())
    T = data.oxts[0].T_w_imu @ np.linalg.inv(data.calib.T_velo_imu)
    # flat ground, level vehicle: the velodyne origin is sensor.height_m above the ground
    origin = np.array([T[0, 3] + sim["world_offset_xy"][0], T[1, 3] + sim["world_offset_xy"][1], sensor.height_m])
    d = sensor.ray_directions() @ T[:3, :3].T
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (y - origin[1]) / d[:, 1]
    hit = origin + t[:, None] * d
    ok = (d[:, 1] > 0) & (t >= sensor.min_range_m) & (t <= sensor.max_range_m)
    inside = ok & (np.abs(hit[:, 0]) <= half_length) & (hit[:, 2] >= 0) & (hit[:, 2] <= height)
    sure = ok & (np.abs(hit[:, 0]) <= half_length - margin) & (hit[:, 2] >= margin) & (hit[:, 2] <= height - margin)
    xs = hit[sure, 0] + half_length                         # along the wall from its first vertex
    return int(sure.sum()), int(inside.sum()), xs


def test_observations_count_the_rays_that_hit_each_wall(tmp_path):
    y, half, height = 12.0, 20.0, 6.0
    drive = simulate_drive(_wall_world(y, half, height), tmp_path, THREE_BEAMS, n_frames=2, noise_m=0.02, seed=0,
                           scan_observations=True)
    obs = read_observations(drive.drive_dir / "truth")
    walls = list(csv.DictReader(open(drive.drive_dir / "truth" / "walls.csv")))
    front = [i for i, r in enumerate(walls) if float(r["y1"]) == float(r["y2"]) == y][0]
    mine = np.flatnonzero((obs.frame == 0) & (obs.wall == front))
    assert len(mine) == 1 and set(obs.wall[obs.frame == 0]) == {front}     # the only visible face
    o = mine[0]
    sure, possible, xs = _expected_hits(drive, y, half, height, THREE_BEAMS)
    assert sure > 100
    assert sure <= obs.n_hits[o] <= possible
    assert obs.s_min[o] == pytest.approx(xs.min(), abs=0.02)
    assert obs.s_max[o] == pytest.approx(xs.max(), abs=0.02)
    assert obs.intervals(o) == [(obs.s_min[o], obs.s_max[o])]           # nothing in front of it: one stretch
    assert obs.observed_m[o] == pytest.approx(obs.extent_m[o])
    assert obs.counting()[o]
    assert read_observations(drive.drive_dir / "truth", frames=[1]).frame.tolist() == [1]


def test_a_pole_in_front_of_the_wall_splits_the_observation(tmp_path):
    # a 0.6 m thick pole halfway to the wall casts a ~1.2 m shadow on it
    pole = {"id": "p", "kind": "pole", "position": [0.0, 6.0], "radius": 0.3, "height": 20.0}
    drive = simulate_drive(_wall_world(12.0, 20.0, 6.0, [pole]), tmp_path, THREE_BEAMS, n_frames=2, noise_m=0.0,
                           seed=0, scan_observations=True)
    obs = read_observations(drive.drive_dir / "truth", frames=[0])
    assert len(obs) == 1
    (a0, b0), (a1, b1) = obs.intervals(0)
    assert 1.0 < a1 - b0 < 1.7
    assert obs.observed_m[0] == pytest.approx((b0 - a0) + (b1 - a1))
    assert obs.extent_m[0] > obs.observed_m[0] + 1.0


def test_walls_beyond_fifty_metres_are_observed(tmp_path):
    # a wall 80 m away: no 50 m cap in the per-scan truth (walls.csv keeps its 50 m truth range)
    drive = simulate_drive(_wall_world(80.0, 60.0, 15.0), tmp_path, THREE_BEAMS.with_azimuth_step(0.2), n_frames=2,
                           noise_m=0.0, seed=0, scan_observations=True)
    obs = read_observations(drive.drive_dir / "truth", frames=[0])
    sure, possible, _ = _expected_hits(drive, 80.0, 60.0, 15.0, THREE_BEAMS.with_azimuth_step(0.2))
    assert len(obs) == 1 and sure <= obs.n_hits[0] <= possible and obs.counting()[0]
    walls = list(csv.DictReader(open(drive.drive_dir / "truth" / "walls.csv")))
    assert max(int(r["n_returns"]) for r in walls) == 0
