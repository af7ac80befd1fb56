import hashlib

import numpy as np
import pytest

from featmap.io.kitti_raw import read_velo_bin
from featmap.simulation.sensors import SENSORS
from featmap.simulation.simulate import simulate_drive
from featmap.simulation.worlds import load_world, world_from_dict

WALL_Y = 12.0
WALL_H = 8.0


def _single_wall_world():
    # A 200 m long, 1 m deep building whose south face is the wall y = WALL_Y; the vehicle drives east along y = 0.
    return world_from_dict({
        "name": "wall", "route": {"waypoints": [[0, 0], [40, 0]], "speed_mps": 8, "turn_radius_m": 0},
        "objects": [{"id": "W", "kind": "building", "height": WALL_H,
                     "footprint": [[-100, WALL_Y], [100, WALL_Y], [100, WALL_Y + 1], [-100, WALL_Y + 1]]}],
    }, "wall.yaml")


@pytest.fixture(scope="module")
def wall_drive(tmp_path_factory):
    root = tmp_path_factory.mktemp("wall")
    return simulate_drive(_single_wall_world(), root, SENSORS["hdl64"], n_frames=2, noise_m=0.02, seed=1)


def _world_points(drive, k):
    import pykitti

    data = pykitti.raw(str(drive.root), drive.date, drive.drive_id)
    pts = data.get_velo(k)[:, :3]
    T_w_velo = data.oxts[k].T_w_imu @ np.linalg.inv(data.calib.T_velo_imu)
    return pts, (T_w_velo[:3, :3] @ pts.T).T + T_w_velo[:3, 3]


def test_wall_returns_lie_within_three_sigma_of_the_plane(wall_drive):
    _, world = _world_points(wall_drive, 0)
    # local frame: origin at the first IMU position, which is at world (0, 0), so the wall is y = WALL_Y
    on_wall = (np.abs(world[:, 1] - WALL_Y) < 0.5) & (world[:, 2] > -0.5)
    assert on_wall.sum() > 1000
    residual = world[on_wall, 1] - WALL_Y
    # Gaussian range noise along the ray: 99.7% within 3 sigma of the plane (more, at oblique incidence)
    assert np.mean(np.abs(residual) <= 3 * 0.02) > 0.997
    assert np.all(np.abs(residual) < 6 * 0.02)
    assert abs(residual.mean()) < 0.005
    assert 0.015 < residual.std() < 0.025


def test_elevation_pattern_and_count_match_the_preset(wall_drive):
    sensor = SENSORS["hdl64"]
    pts = read_velo_bin(wall_drive.drive_dir / "velodyne_points" / "data" / "0000000000.bin")
    elev = np.degrees(np.arctan2(pts[:, 2], np.hypot(pts[:, 0], pts[:, 1])))
    preset = np.asarray(sensor.elevations_deg)
    # every return was fired by one of the 64 beams (range noise moves points along the ray only)
    assert np.abs(elev[:, None] - preset[None, :]).min(axis=1).max() < 1e-3
    # looking straight at the wall (azimuth 90 deg, velodyne y axis), the beams that hit it are those whose
    # ray meets the plane between the ground and the top of the wall
    az = np.degrees(np.arctan2(pts[:, 1], pts[:, 0]))
    ahead = (np.abs(az - 90) < 0.5 * sensor.azimuth_step_deg + 1e-6) & (pts[:, 1] > WALL_Y - 1)
    hit_height = sensor.height_m + (WALL_Y + 0.32) * np.tan(np.deg2rad(preset))   # velodyne sits 0.32 m left of the IMU
    expected = (hit_height > 0.3) & (hit_height < WALL_H - 0.3)
    borderline = (np.abs(hit_height) < 0.3) | (np.abs(hit_height - WALL_H) < 0.3)
    got = np.zeros(len(preset), bool)
    got[np.abs(elev[ahead][:, None] - preset[None, :]).argmin(axis=1)] = True
    assert np.array_equal(got[~borderline], expected[~borderline])
    n_azimuths = round(360 / sensor.azimuth_step_deg)
    assert len(pts) <= sensor.n_beams * n_azimuths


def test_pykitti_poses_put_returns_on_the_true_walls(tmp_path):
    world = load_world("prescan_case1")
    drive = simulate_drive(world, tmp_path, SENSORS["vlp32"], n_frames=6, noise_m=0.02, seed=3)
    import csv

    walls = list(csv.DictReader(open(drive.drive_dir / "truth" / "walls.csv")))
    segs = np.array([[float(w[c]) for c in ("x1", "y1", "x2", "y2")] for w in walls])
    from featmap.geometry import point_segment_distance

    dists = []
    for k in (0, 5):
        _, pts = _world_points(drive, k)
        high = pts[pts[:, 2] > -0.3]       # above the ground (local z = 0 is the IMU, 0.93 m above ground)
        d = np.min([point_segment_distance(high[:, :2], np.repeat(s[None], len(high), 0)) for s in segs], axis=0)
        dists.append(d[d < 0.5])
    dists = np.concatenate(dists)
    assert len(dists) > 1000
    assert dists.mean() < 0.05


def _digest(root):
    h = {}
    for p in sorted(root.rglob("*")):
        if p.is_file():
            h[str(p.relative_to(root))] = hashlib.sha256(p.read_bytes()).hexdigest()
    return h


def test_same_seed_gives_byte_identical_files(tmp_path):
    world = load_world("prescan_case1")
    a = simulate_drive(world, tmp_path / "a", SENSORS["vlp32"], n_frames=3, pose_noise=(0.1, 0.2), seed=5)
    b = simulate_drive(world, tmp_path / "b", SENSORS["vlp32"], n_frames=3, pose_noise=(0.1, 0.2), seed=5)
    c = simulate_drive(world, tmp_path / "c", SENSORS["vlp32"], n_frames=3, pose_noise=(0.1, 0.2), seed=6)
    da, db, dc = _digest(a.root), _digest(b.root), _digest(c.root)
    assert da == db and len(da) > 10
    assert da != dc


def test_truth_records_what_the_drive_observed(wall_drive):
    import csv

    rows = list(csv.DictReader(open(wall_drive.drive_dir / "truth" / "walls.csv")))
    south = [r for r in rows if abs(float(r["y1"]) - WALL_Y) < 1e-6 and abs(float(r["y2"]) - WALL_Y) < 1e-6][0]
    north = [r for r in rows if abs(float(r["y1"]) - WALL_Y - 1) < 1e-6 and abs(float(r["y2"]) - WALL_Y - 1) < 1e-6][0]
    assert int(south["n_returns"]) > 1000 and float(south["observed_m"]) > 20
    assert int(north["n_returns"]) == 0 and float(north["observed_m"]) == 0


def test_pose_noise_correlation_time(tmp_path):
    """The OXTS error is a Gauss-Markov drift with the given correlation time (2 s unless told), drawn first
    from the seed; only a non-default correlation time is recorded in simulation.json."""
    import csv
    import json

    from featmap.simulation.simulate import gauss_markov, gauss_markov_at, oxts_drift

    world = load_world("prescan_case1")
    default = simulate_drive(world, tmp_path / "a", SENSORS["vlp32"], n_frames=6, pose_noise=(0.3, 0.5), seed=5)
    same = simulate_drive(world, tmp_path / "b", SENSORS["vlp32"], n_frames=6, pose_noise=(0.3, 0.5), seed=5,
                          pose_noise_tau_s=2.0)
    slow = simulate_drive(world, tmp_path / "c", SENSORS["vlp32"], n_frames=6, pose_noise=(0.3, 0.5), seed=5,
                          pose_noise_tau_s=5.0)
    assert _digest(default.root) == _digest(same.root)
    assert "pose_noise_tau_s" not in json.loads((default.drive_dir / "truth" / "simulation.json").read_text())
    assert json.loads((slow.drive_dir / "truth" / "simulation.json").read_text())["pose_noise_tau_s"] == 5.0
    rows = list(csv.DictReader(open(slow.drive_dir / "truth" / "trajectory.csv")))
    err_x = np.array([float(r["oxts_x"]) - float(r["x"]) for r in rows])
    rng = np.random.default_rng(5)
    expected = gauss_markov(rng, 6, 0.3, 0.1, 5.0)
    assert np.allclose(err_x, expected, atol=2e-4)
    # the same process at any times: equal spacing draws the same values; three axes in the simulator's order
    times = np.arange(6) * 0.1
    assert np.allclose(gauss_markov_at(np.random.default_rng(5), times, 0.3, 5.0), expected)
    drift = oxts_drift(np.random.default_rng(5), times, (0.3, 0.5), 5.0)
    assert np.allclose(drift[:, 0], expected) and drift.shape == (6, 3)
    from featmap.errors import FeatmapError

    with pytest.raises(FeatmapError, match="pose-noise-tau"):
        simulate_drive(world, tmp_path / "d", SENSORS["vlp32"], n_frames=3, pose_noise_tau_s=0.0)


def test_perturbed_poses_turn_about_the_body():
    from featmap.simulation.simulate import perturb_poses

    T = np.eye(4)
    T[:3, 3] = [10.0, 0.0, 1.7]                            # the sensor
    T_sensor_body = np.eye(4)
    T_sensor_body[:3, 3] = [-1.0, 0.0, -0.8]               # the body (IMU) 1 m behind it
    out = perturb_poses(T[None], np.array([[0.1, 0.2, np.pi / 2]]), T_sensor_body)[0]
    assert np.allclose(out[:3, 3], [9.0 + 0.1, 1.0 + 0.2, 1.7])   # swung about the body, then moved
    assert np.allclose(out[:2, :2], [[0, -1], [1, 0]])
    plain = perturb_poses(T[None], np.array([[0.1, 0.2, np.pi / 2]]))[0]
    assert np.allclose(plain[:3, 3], [10.1, 0.2, 1.7])


def test_a_repeated_waypoint_counts_once():
    """Routes from OSM or GeoJSON often repeat a point: the drive is the same as without the repeat."""
    from featmap.simulation.trajectory import fillet_polyline, sample_poses

    route = np.array([[0, 0], [20, 0], [20, 20]], float)
    repeated = np.array([[0, 0], [0, 0], [20, 0], [20, 0], [20, 20]], float)
    assert np.array_equal(fillet_polyline(repeated, 8.0), fillet_polyline(route, 8.0))
    positions, headings = sample_poses(repeated, 8.0, 8.0, 10.0)
    assert np.isfinite(positions).all() and np.isfinite(headings).all() and len(positions) > 30


def test_a_drive_that_starts_across_the_date_line_is_placed_there(tmp_path):
    # the world's origin just west of 180 deg, the first pose 50 m east of it: the drive's origin wraps to -180
    world = world_from_dict({
        "name": "dateline", "geo_origin": {"lat": 10.0, "lon": 179.9999},
        "route": {"waypoints": [[50, 0], [60, 0]], "speed_mps": 8, "turn_radius_m": 0},
        "objects": [{"id": "W", "kind": "building", "height": 8.0, "footprint": [[40, 12], [70, 12], [70, 13], [40, 13]]}],
    }, "dateline.yaml")
    drive = simulate_drive(world, tmp_path, SENSORS["vlp32"], n_frames=2, seed=0)
    import json

    origin = json.loads((drive.drive_dir / "truth" / "simulation.json").read_text())["geo_origin"]
    assert -180.0 < origin["lon0_deg"] < -179.999 and origin["lat0_deg"] == pytest.approx(10.0, abs=1e-6)


HEDGE_Y = 8.0       # the hedge's centre line, 4 m in front of the wall
HEDGE_H = 1.5


def _hedge_world(porosity: float = 0.0, depth_m: float = 0.0):
    world = _single_wall_world().model_dump(mode="json", exclude_none=True)
    hedge = {"id": "h", "kind": "hedge", "line": [[-20, HEDGE_Y], [60, HEDGE_Y]], "height": HEDGE_H, "width": 0.8,
             "irregularity": 0.0}
    if porosity or depth_m:
        hedge.update(porosity=porosity, depth_m=depth_m)
    world["objects"] = world["objects"] + [hedge]
    return world_from_dict(world, "hedge.yaml")


def _hedge_returns(tmp_path, name, world):
    import pykitti

    drive = simulate_drive(world, tmp_path / name, SENSORS["hdl64"], n_frames=2, noise_m=0.005, seed=2)
    _, pts = _world_points(drive, 0)
    data = pykitti.raw(str(drive.root), drive.date, drive.drive_id)
    origin = (data.oxts[0].T_w_imu @ np.linalg.inv(data.calib.T_velo_imu))[:3, 3]
    ground_z = np.median(pts[np.abs(pts[:, 1]) < 3, 2])                  # the road's returns (this frame's z)
    pts = pts[(pts[:, 0] > 5) & (pts[:, 0] < 35) & (pts[:, 1] > 5)]
    # where each ray crosses the hedge's line, and how high above the ground it is there
    s = (HEDGE_Y - origin[1]) / (pts[:, 1] - origin[1])
    z_at_hedge = origin[2] + s * (pts[:, 2] - origin[2]) - ground_z
    through_hedge = (z_at_hedge < HEDGE_H - 0.2) & (z_at_hedge > 0.2)
    return pts, through_hedge, origin


def test_a_porous_hedge_lets_rays_through_to_the_wall_and_returns_from_inside(tmp_path):
    solid, solid_through, solid_origin = _hedge_returns(tmp_path, "solid", _hedge_world())
    porous, porous_through, porous_origin = _hedge_returns(tmp_path, "porous", _hedge_world(porosity=0.4, depth_m=0.3))
    on_wall = lambda p: np.abs(p[:, 1] - WALL_Y) < 0.05     # noqa: E731
    on_hedge = lambda p: np.abs(p[:, 1] - HEDGE_Y) < 1.5    # noqa: E731
    # a solid hedge hides the wall below its top; a porous one lets about 40 % of those rays reach it
    assert (on_wall(solid) & solid_through).sum() == 0
    aimed = porous_through & (on_wall(porous) | on_hedge(porous))
    share = (on_wall(porous) & porous_through).sum() / aimed.sum()
    assert aimed.sum() > 500 and 0.3 < share < 0.5
    # the rays it stops return from inside it, at an exponential depth of mean 0.3 m along the ray (median
    # 0.3 ln 2), never more than 3 mean depths; a solid hedge returns from its face (y = HEDGE_Y - 0.4)
    def depth_along_ray(pts, origin):
        ray = pts - origin
        return (pts[:, 1] - (HEDGE_Y - 0.4)) * np.linalg.norm(ray, axis=1) / ray[:, 1]

    stopped = lambda p, through: through & (np.abs(p[:, 1] - HEDGE_Y) < 0.6)   # noqa: E731
    assert np.abs(depth_along_ray(solid[stopped(solid, solid_through)], solid_origin)).max() < 0.03
    inside = depth_along_ray(porous[stopped(porous, porous_through)], porous_origin)
    assert abs(np.median(inside) - 0.3 * np.log(2)) < 0.04 and -0.03 < inside.min() and inside.max() < 0.93


def test_porosity_must_be_below_one_and_the_depth_not_negative():
    from featmap.errors import WorldError

    with pytest.raises(WorldError, match="porosity"):
        _hedge_world(porosity=1.0)
    with pytest.raises(WorldError, match="depth_m"):
        _hedge_world(depth_m=-0.1)


def test_a_world_without_porous_foliage_simulates_as_before(tmp_path):
    """Porosity 0 takes no extra random draws: the drive is byte for byte the one without the fields."""
    plain = simulate_drive(_hedge_world(), tmp_path / "a", SENSORS["vlp32"], n_frames=2, noise_m=0.02, seed=4)
    world = _hedge_world().model_dump(mode="json", exclude_none=True)
    world["objects"][-1].update(porosity=0.0, depth_m=0.0)
    explicit = simulate_drive(world_from_dict(world, "hedge.yaml"), tmp_path / "b", SENSORS["vlp32"], n_frames=2,
                              noise_m=0.02, seed=4)
    assert _digest(plain.root) == _digest(explicit.root)


def test_a_porous_crown_lets_rays_through_but_its_trunk_does_not(tmp_path):
    world = _single_wall_world().model_dump(mode="json", exclude_none=True)
    # a low tree 8 m away, so that the HDL-64E's beams (+2 to -24.8 deg) reach its crown: the trunk up to
    # 1 m, the crown's centre 1 m + 0.8 x 1.5 m up
    tree = {"id": "t", "kind": "tree", "position": [12, 8], "trunk_radius": 0.4, "trunk_height": 1.0,
            "crown_radius": 1.5, "crown_porosity": 0.5}
    world["objects"] = world["objects"] + [tree]
    drive = simulate_drive(world_from_dict(world, "tree.yaml"), tmp_path, SENSORS["hdl64"], n_frames=2,
                           noise_m=0.005, seed=3)
    _, pts = _world_points(drive, 0)
    import pykitti

    data = pykitti.raw(str(drive.root), drive.date, drive.drive_id)
    origin = (data.oxts[0].T_w_imu @ np.linalg.inv(data.calib.T_velo_imu))[:3, 3]
    ground_z = np.median(pts[np.abs(pts[:, 1]) < 3, 2])
    # each return's ray where it crosses the tree's line y = 8: within the trunk, or within the crown's core
    ray = pts - origin
    s = (8.0 - origin[1]) / ray[:, 1]
    at = origin + s[:, None] * ray
    ahead = (pts[:, 1] > 6) & (s > 0) & (s < 1.2)
    height = at[:, 2] - ground_z
    trunk = ahead & (np.abs(at[:, 0] - 12) < 0.2) & (height > 0.2) & (height < 0.6)     # below the crown
    crown_core = ahead & (np.abs(at[:, 0] - 12) < 0.8) & (height > 1.3) & (height < 2.6)  # above the trunk
    on_wall = np.abs(pts[:, 1] - WALL_Y) < 0.05
    assert trunk.sum() > 20 and not (trunk & on_wall).any()
    assert crown_core.sum() > 200 and 0.4 < (crown_core & on_wall).sum() / crown_core.sum() < 0.6


@pytest.mark.parametrize("speed,frames", [(0.008, "325,001"), (1e-300, "2.6e+303"), (1e-310, "inf")])
def test_a_route_of_more_than_max_frames_is_refused_before_anything_is_written(tmp_path, speed, frames):
    """A speed typed a thousand times too small took hours and ~80 GB per 100,000 frames; 1e-300 m/s asked
    numpy for an array larger than memory (ValueError: Maximum allowed size exceeded)."""
    import re

    from featmap.errors import WorldError
    from featmap.simulation.trajectory import MAX_FRAMES

    world = world_from_dict({"name": "slow", "route": {"waypoints": [[0, 0], [260, 0]], "speed_mps": speed}}, "slow.yaml")
    with pytest.raises(WorldError, match=rf"^slow.yaml: the route takes about {re.escape(frames)} frames \(260 m at {speed:g} m/s, "
                                         rf"10 Hz\); at most {MAX_FRAMES:,}: raise route.speed_mps"):
        simulate_drive(world, tmp_path / "sim", SENSORS["hdl64"])
    assert not any((tmp_path / "sim").rglob("*.bin"))
    # capped by n_frames, the same route is simulated (its first frames)
    if speed == 0.008:
        drive = simulate_drive(world, tmp_path / "capped", SENSORS["vlp16"], n_frames=3)
        assert drive.n_frames == 3
