"""Planar corrections: applying, re-anchoring, interpolating; keyframes."""

import numpy as np

from featmap.datasets.carmen import pose_matrix
from featmap.refinement.base import (apply_corrections, correct_points, interpolate_corrections, keyframes,
                                     planar_difference, reanchor)


def test_a_correction_turns_the_scan_about_its_own_sensor_position():
    T = pose_matrix(np.array([10.0, 5.0, 0.0]))[None]
    c = np.array([[0.5, -0.25, np.pi / 2]])
    out = apply_corrections(T, c)[0]
    assert np.allclose(out[:2, 3], [10.5, 4.75])                          # the sensor only moves by dx, dy
    assert np.allclose(out[:2, :2], [[0, -1], [1, 0]])                    # and turns by 90 degrees
    # A point 2 m ahead of the sensor: turned about the sensor, then moved.
    world = correct_points(np.array([[12.0, 5.0]]), np.array([0]), T[:, :2, 3], c)
    assert np.allclose(world, [[10.5, 6.75]])
    assert np.allclose(out @ [2, 0, 0, 1], [10.5, 6.75, 0, 1])            # the same as the corrected pose


def test_a_3d_pose_keeps_its_height_roll_and_pitch():
    T = np.eye(4)
    T[:3, :3] = [[1, 0, 0], [0, np.cos(0.1), -np.sin(0.1)], [0, np.sin(0.1), np.cos(0.1)]]   # rolled
    T[:3, 3] = [3, 4, 1.7]
    out = apply_corrections(T[None], np.array([[0.1, 0.2, 0.05]]))[0]
    assert np.isclose(out[2, 3], 1.7) and np.allclose(out[2, :3], T[2, :3])
    assert np.allclose(planar_difference(out[None], T[None]), [[0.1, 0.2, 0.05]])


def test_reanchored_corrections_are_the_same_motion():
    c = np.array([[0.3, -0.1, 0.2]])
    a, b = np.array([[1.0, 2.0]]), np.array([[4.0, -3.0]])
    moved = reanchor(c, a, b)
    p = np.array([[7.0, 1.0]])
    assert np.allclose(correct_points(p, np.array([0]), a, c), correct_points(p, np.array([0]), b, moved))


def test_interpolation_reproduces_keyframes_and_a_common_motion():
    poses = np.stack([pose_matrix(np.array([k * 0.1, 0.0, 0.0])) for k in range(10)])
    keys = keyframes(poses, 0.3, 10.0)
    assert keys.tolist() == [0, 3, 6, 9]
    anchors = poses[:, :2, 3]
    # Every keyframe moved by the same rigid motion of the whole trajectory: so is every scan between them.
    common = np.array([0.2, -0.1, 0.03])
    key_c = reanchor(np.tile(common, (4, 1)), np.zeros((4, 2)), anchors[keys])
    full = interpolate_corrections(anchors, keys, key_c)
    assert np.allclose(full, reanchor(np.tile(common, (10, 1)), np.zeros((10, 2)), anchors))
    assert np.array_equal(interpolate_corrections(anchors, np.arange(10), full), full)


def test_keyframes_follow_turns_too():
    poses = np.stack([pose_matrix(np.array([0.0, 0.0, np.deg2rad(4 * k)])) for k in range(6)])
    assert keyframes(poses, 0.3, 10.0).tolist() == [0, 3, 5]
    assert keyframes(poses, 0.0, 0.0).tolist() == list(range(6))
