import numpy as np
import pytest

from featmap.config import ExtractionConfig
from featmap.extraction import extract_segments, segments_to_world
from featmap.io.kitti_raw import read_velo_bin
from tests.conftest import shared_data

SENSOR_HEIGHT = 1.73
RANSAC = ExtractionConfig(method="ransac_planes")      # these tests are about the RANSAC extractor


def _ground(rng, n=20000, extent=40.0):
    xy = rng.uniform(-extent, extent, (n, 2))
    return np.column_stack([xy, rng.normal(-SENSOR_HEIGHT, 0.02, n)])


def _wall(rng, p, q, z_top, density=400, noise=0.02):
    """Points on the vertical wall over segment p-q (velodyne frame), from the ground to z_top."""
    p, q = np.asarray(p, float), np.asarray(q, float)
    length = np.linalg.norm(q - p)
    n = int(density * length)
    t = rng.uniform(0, 1, n)
    z = rng.uniform(-SENSOR_HEIGHT, z_top, n)
    normal = np.array([-(q - p)[1], (q - p)[0]]) / length
    xy = p + t[:, None] * (q - p) + rng.normal(0, noise, n)[:, None] * normal
    return np.column_stack([xy, z])


def _scan(*parts):
    pts = np.concatenate(parts)
    return np.column_stack([pts, np.full(len(pts), 0.3)]).astype(np.float32)


def test_noisy_wall_comes_back_as_one_segment_within_5cm():
    rng = np.random.default_rng(0)
    scan = _scan(_ground(rng), _wall(rng, [12, -10], [12, 8], 2.5))
    result = extract_segments(scan, RANSAC)
    assert len(result) == 1
    seg = result.segments[0]
    assert np.abs(seg[[0, 2]] - 12).max() < 0.05
    assert sorted(seg[[1, 3]]) == pytest.approx([-10, 8], abs=0.3)
    assert result.rms[0] == pytest.approx(0.02, abs=0.01)
    assert result.z_max[0] - result.z_min[0] > 3


def test_a_plane_spanning_two_walls_is_split_at_the_gap():
    rng = np.random.default_rng(1)
    scan = _scan(_ground(rng), _wall(rng, [-15, 10], [-3, 10], 2.5), _wall(rng, [2, 10], [14, 10], 2.5))
    result = extract_segments(scan, RANSAC)
    assert len(result) == 2
    xs = sorted(sorted(s[[0, 2]].tolist()) for s in result.segments)
    assert xs[0] == pytest.approx([-15, -3], abs=0.3) and xs[1] == pytest.approx([2, 14], abs=0.3)


def test_fences_and_cars_are_not_walls():
    rng = np.random.default_rng(2)
    fence = _wall(rng, [5, -6], [20, -6], -SENSOR_HEIGHT + 1.4)          # 1.4 m fence
    car = _wall(rng, [8, 4], [12.5, 4], -SENSOR_HEIGHT + 1.5)            # side of a parked car
    scan = _scan(_ground(rng), fence, car, _wall(rng, [-10, 15], [10, 15], 3.0))
    result = extract_segments(scan, RANSAC)
    assert len(result) == 1
    assert result.segments[0, [1, 3]] == pytest.approx([15, 15], abs=0.05)
    kept = extract_segments(scan, ExtractionConfig(method="ransac_planes", min_top_height_m=0.0, min_vertical_extent_m=0.5))
    assert len(kept) == 3


def test_deterministic_and_empty():
    rng = np.random.default_rng(3)
    scan = _scan(_ground(rng), _wall(rng, [12, -10], [12, 8], 2.5), _wall(rng, [-5, 9], [6, 20], 2.5))
    a, b = extract_segments(scan, RANSAC), extract_segments(scan, RANSAC)
    assert np.array_equal(a.segments, b.segments)
    assert len(extract_segments(np.zeros((0, 4), np.float32), RANSAC)) == 0
    assert len(extract_segments(_scan(_ground(rng, 500)), RANSAC)) == 0


def test_segments_to_world_applies_the_pose():
    rng = np.random.default_rng(4)
    result = extract_segments(_scan(_ground(rng), _wall(rng, [12, -10], [12, 8], 2.5)), RANSAC)
    T = np.eye(4)
    c, s = np.cos(np.pi / 2), np.sin(np.pi / 2)
    T[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    T[:3, 3] = [100, 50, 2]
    world = segments_to_world(result, T)
    # x = 12 in the velodyne frame becomes y = 50 + 12 after a 90 degree turn
    assert np.abs(world[0, [1, 3]] - 62).max() < 0.05


def test_real_kitti_scans():
    folder = shared_data("kitti_object_velodyne")
    found = {}
    for path in sorted(folder.glob("*.bin")):
        result = extract_segments(read_velo_bin(path), RANSAC)
        found[path.stem] = result
        assert np.isfinite(result.segments).all()
    # scan 000000: the long building wall about 15 m ahead, running across the view (along y)
    walls = found["000000"].segments
    lengths = np.hypot(walls[:, 2] - walls[:, 0], walls[:, 3] - walls[:, 1])
    across = np.abs(walls[:, 3] - walls[:, 1]) > 0.9 * lengths
    ahead = (np.abs(walls[:, [0, 2]].mean(axis=1) - 15) < 3)
    assert (across & ahead & (lengths > 10)).any(), walls.round(1)
    # most scans of this street set have walls
    assert sum(len(r) > 0 for r in found.values()) >= 4
