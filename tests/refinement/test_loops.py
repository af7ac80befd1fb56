"""Loop closures by a wide search: known motions come back, corridors are refused, open loops close."""

import numpy as np
import pytest

from featmap.datasets.carmen import pose_matrix
from featmap.refinement import planar_difference
from featmap.refinement.loops import LoopConfig, Loops, align_points, candidate_pairs, find_loops, loop_errors
from featmap.refinement.pose_graph import PoseGraphConfig, refine_pose_graph
from featmap.extraction.lines_2d import extract_lines_2d
from featmap.simulation.segments import cast_rays_2d
from tests.refinement.conftest import ANGLES, FLOOR, path, refinement_input


def _points(segments: np.ndarray, step: float = 0.05) -> np.ndarray:
    out = []
    for x1, y1, x2, y2 in segments:
        n = int(np.ceil(np.hypot(x2 - x1, y2 - y1) / step)) + 1
        t = np.linspace(0, 1, n)[:, None]
        out.append(np.column_stack([x1 + t[:, 0] * (x2 - x1), y1 + t[:, 0] * (y2 - y1)]))
    return np.concatenate(out)


def _turn(points, pivot, angle):
    c, s = np.cos(angle), np.sin(angle)
    rel = points - pivot
    return pivot + np.column_stack([c * rel[:, 0] - s * rel[:, 1], s * rel[:, 0] + c * rel[:, 1]])


def test_a_known_motion_of_a_room_is_found():
    """The hall's walls moved by 1.3 m / -0.8 m and turned 3 deg come back within a cell and a degree."""
    target = _points(FLOOR)
    pivot = np.array([12.0, 7.0])
    source = _turn(target, pivot, np.deg2rad(-3.0)) + [-1.3, 0.8]         # where the wrong poses put them
    angle, shift, score, ambiguity = align_points(source, target, pivot, np.deg2rad(np.arange(-6, 7)), 4.0)
    moved = _turn(source, pivot, angle) + shift
    assert np.rad2deg(angle) == pytest.approx(3.0, abs=1.0)
    assert np.abs(moved - target).max() < 0.35                             # 0.2 m cells, a degree's lever
    assert score > 0.4 and ambiguity < LoopConfig().max_ambiguity


def test_a_corridor_is_ambiguous_along_its_length():
    """Two long parallel walls say nothing about the motion along them: the second-best shift a metre
    away explains nearly as much as the best, so no loop is taken from it."""
    corridor = _points(np.array([[0, 0, 40, 0], [0, 2.5, 40, 2.5]], float))
    _, _, score, ambiguity = align_points(corridor + [1.7, 0.1], corridor, np.array([20.0, 1.2]), np.zeros(1), 4.0)
    assert score > 0.6 and ambiguity > LoopConfig().max_ambiguity


def test_candidates_need_travel_and_proximity():
    lap = path(48)[:, :2]
    two_laps = np.concatenate([lap, lap + [0.5, 0.0]])
    pairs = candidate_pairs(two_laps, 2.0, 20.0, 4)
    assert len(pairs) and np.all(pairs[:, 1] - pairs[:, 0] >= 40)          # a lap later, not the next scans
    assert len(candidate_pairs(lap[:10], 2.0, 20.0, 1)) == 0               # 10 scans never travel 20 m


def _niche(x0, x1, depth, y=0.0):
    """Wall pieces of a niche in a wall along x at ``y`` (opening outwards by ``depth``)."""
    return [[x0, y, x0, y - depth], [x0, y - depth, x1, y - depth], [x1, y - depth, x1, y]]


def _ring() -> np.ndarray:
    """A 3 m wide corridor around a 34 m x 18 m block: plain straights, niches and a pillar near the
    corners only (as in a building with long corridors: along a straight, the walls in range say
    nothing about how far the robot went)."""
    walls = [[0, 0, 4, 0], *_niche(4, 5.5, 0.8), [5.5, 0, 35, 0], *_niche(35, 36, 0.6), [36, 0, 40, 0],
             [40, 0, 40, 24], [40, 24, 33, 24], [33, 24, 33, 25.2], [33, 25.2, 31, 25.2], [31, 25.2, 31, 24],
             [31, 24, 0, 24], [0, 24, 0, 19], [0, 19, -0.7, 19], [-0.7, 19, -0.7, 17.5], [-0.7, 17.5, 0, 17.5],
             [0, 17.5, 0, 0],
             [3, 3, 37, 3], [37, 3, 37, 21], [37, 21, 3, 21], [3, 21, 3, 3],
             [1.2, 5.0, 1.8, 5.0], [1.8, 5.0, 1.8, 5.6], [1.8, 5.6, 1.2, 5.6], [1.2, 5.6, 1.2, 5.0]]    # a pillar
    return np.asarray(walls, float)


def _corridor_path(step: float = 0.8) -> np.ndarray:
    """(n, 3) one lap and 40 % of a second along the corridor's middle, ``step`` apart."""
    corners = np.array([[1.5, 1.5], [38.5, 1.5], [38.5, 22.5], [1.5, 22.5], [1.5, 1.5]])
    pts, heading = [], []
    for a, b in zip(corners[:-1], corners[1:]):
        n = int(np.hypot(*(b - a)) / step)
        t = np.arange(n)[:, None] / n
        pts.append(a + t * (b - a))
        heading.append(np.full(n, np.arctan2(*(b - a)[::-1])))
    lap = np.column_stack([np.concatenate(pts), np.concatenate(heading)])
    return np.concatenate([lap, lap[: int(0.4 * len(lap))]])


def _odometry(truth: np.ndarray, scale_along_x: float = 1.08) -> np.ndarray:
    """Wheel odometry of the true poses (n, 3) that overestimates the distance driven along +x."""
    odo = [truth[0]]
    for a, b in zip(truth[:-1], truth[1:]):
        c, s = np.cos(a[2]), np.sin(a[2])
        d = b[:2] - a[:2]
        dx, dy = c * d[0] + s * d[1], -s * d[0] + c * d[1]
        if abs(a[2]) < 0.1:
            dx *= scale_along_x
        x, y, th = odo[-1]
        c, s = np.cos(th), np.sin(th)
        odo.append([x + c * dx - s * dy, y + s * dx + c * dy, th + (b[2] - a[2])])
    return np.array(odo)


@pytest.fixture(scope="module")
def two_laps():
    """True poses, odometry poses and the scans (10 m range) of a drive around the corridor ring."""
    truth = _corridor_path()
    rng = np.random.default_rng(1)
    scans = []
    for pose in truth:
        r = cast_rays_2d(RING, pose, ANGLES, max_range=10.0)
        hit = r < 10.0
        r = r[hit] + rng.normal(0, 0.01, hit.sum())
        scans.append(extract_lines_2d(np.column_stack([r * np.cos(ANGLES[hit]), r * np.sin(ANGLES[hit])])))
    return truth, _odometry(truth), scans


RING = _ring()


def _odometry_config(loops: bool) -> PoseGraphConfig:
    return PoseGraphConfig(absolute_sigma_m=None, absolute_sigma_deg=None, motion_sigma_m=0.01, motion_sigma_deg=0.05,
                           motion_sigma_m_per_sqrt_m=0.05, motion_sigma_deg_per_sqrt_m=1.0, robust_gate_fraction=0.3,
                           loops=LoopConfig(radius_m=8.0 if loops else None))


def _lap_error(poses: np.ndarray, truth: np.ndarray) -> float:
    """Mean error (m) of the relative pose between the scans of the second lap and the same places a lap before."""
    T = np.stack([pose_matrix(p) for p in truth])
    lap = int(round(len(truth) / 1.4))
    first, second = np.arange(len(truth) - lap), np.arange(lap, len(truth))
    rel_est = np.linalg.inv(poses[first]) @ poses[second]
    rel_true = np.linalg.inv(T[first]) @ T[second]
    return float(np.hypot(*planar_difference(rel_est, rel_true)[:, :2].T).mean())


def test_an_open_loop_is_closed(two_laps):
    truth, odo, scans = two_laps
    inp = refinement_input(scans, odo)
    raw = _lap_error(inp.poses, truth)
    without = refine_pose_graph(inp, _odometry_config(False))
    with_loops = refine_pose_graph(inp, _odometry_config(True))
    assert raw > 2.0                                                       # the drift opened the loop
    assert _lap_error(without.poses, truth) > 0.5                           # the matching alone cannot close it
    assert with_loops.stats["loops"] > 0
    assert _lap_error(with_loops.poses, truth) < 0.05
    c = np.zeros((inp.n_scans, 3))
    found = find_loops(inp, c, LoopConfig(radius_m=8.0))
    assert len(found) and loop_errors(inp, c, found).max() > 1.0           # measured on the open loop


def test_loops_are_off_by_default_and_leave_a_drive_unchanged(two_laps):
    truth, odo, scans = two_laps
    inp = refinement_input(scans, odo)
    config = _odometry_config(False)
    assert PoseGraphConfig().loops.radius_m is None
    a, b = refine_pose_graph(inp, config), refine_pose_graph(inp, config)
    assert a.stats["loops"] is None and np.array_equal(a.poses, b.poses)


def test_a_wrong_loop_is_dropped_when_it_bends_the_walls(two_laps, monkeypatch):
    """A loop measured 3 m off (what a row of identical doors could give) makes the scans agree worse
    than without it: the pose graph keeps the solution without loops."""
    import featmap.refinement.pose_graph as pose_graph

    truth, odo, scans = two_laps
    inp = refinement_input(scans, odo)
    real = pose_graph.find_loops

    def wrong(sub, c, config):
        found = real(sub, c, config)
        return Loops(found.i, found.j, found.delta + [3.0, 0.0, 0.0], found.score, found.ambiguity, found.candidates)

    monkeypatch.setattr(pose_graph, "find_loops", wrong)
    result = refine_pose_graph(inp, _odometry_config(True))
    without = refine_pose_graph(inp, _odometry_config(False))
    assert result.stats["loops_found"] > 0 and result.stats["loops"] == 0
    assert np.array_equal(result.poses, without.poses)
