import numpy as np
import pytest

from featmap.extraction.lines_2d import Lines2DConfig, breakpoints, extract_lines, lines_to_world
from featmap.io.carmen import carmen_beam_angles
from featmap.simulation.segments import cast_rays_2d

# A 10 m x 6 m room with a 2 m x 1 m cabinet standing free in it (world frame = laser frame here).
ROOM = np.array([[0, 0, 10, 0], [10, 0, 10, 6], [10, 6, 0, 6], [0, 6, 0, 0]], float)
CABINET = np.array([[6, 3.5, 8, 3.5], [8, 3.5, 8, 4.5], [8, 4.5, 6, 4.5], [6, 4.5, 6, 3.5]], float)


def _scan(walls, pose, n_beams=361, noise=0.0, seed=0):
    angles = carmen_beam_angles(n_beams)
    r = cast_rays_2d(walls, np.asarray(pose, float), angles)
    r = r + np.random.default_rng(seed).normal(0, noise, len(r))
    return np.stack([r * np.cos(angles), r * np.sin(angles)], axis=1)


def _line_offsets(segment, wall):
    """Perpendicular distances of a segment's two endpoints to the infinite line of ``wall``."""
    a, b = wall[:2], wall[2:]
    n = np.array([-(b - a)[1], (b - a)[0]]) / np.hypot(*(b - a))
    return np.abs((segment.reshape(2, 2) - a) @ n)


def _match(segments, wall, tol=0.01):
    return [s for s in segments if _line_offsets(s, wall).max() <= tol]


@pytest.mark.parametrize("noise", [0.0, 0.01])
def test_room_scan_gives_each_wall_once_within_1cm(noise):
    pose = np.array([3.0, 2.0, 0.3])
    pts = _scan(ROOM, pose, noise=noise)
    found = extract_lines(pts)
    world = lines_to_world(found.segments, pose)
    # The laser looks from -90 deg to +90 deg around heading 0.3 rad: it sees the right, far and
    # left walls over their visible stretch, and the wall behind it not at all.
    for wall in ROOM[:3]:
        hits = _match(world, wall)
        assert len(hits) == 1, (wall, world)
    assert len(_match(world, ROOM[3])) == 0
    assert len(world) == 3
    # The segment spans the seen part of the far wall up to its corners (within a beam's spacing).
    far = _match(world, ROOM[1])[0]
    assert min(far[1], far[3]) < 0.15 and max(far[1], far[3]) > 5.85
    assert np.all(found.rms <= 0.03) and np.all(found.n_points >= 6)


def test_free_standing_cabinet_is_cut_off_the_wall_behind_it():
    pose = np.array([2.0, 4.0, 0.0])
    walls = np.concatenate([ROOM, CABINET])
    world = lines_to_world(extract_lines(_scan(walls, pose, noise=0.005)).segments, pose)
    cabinet_front = CABINET[3]
    hits = _match(world, cabinet_front)
    assert len(hits) == 1 and abs(hits[0][1] - hits[0][3]) > 0.9     # the whole 1 m face
    # The far wall is split where the cabinet hides it: no segment crosses the shadow (y 3.6..4.4).
    far = _match(world, ROOM[1])
    assert len(far) == 2
    for s in far:
        lo, hi = sorted([s[1], s[3]])
        assert hi < 3.6 or lo > 4.4


def test_curved_wall_becomes_several_segments_on_the_arc():
    # A quarter circle of radius 5 m around the laser, as 200 short facets (a smooth curve).
    phi = np.linspace(-0.8, 0.8, 201)
    arc = np.c_[5 * np.cos(phi[:-1]), 5 * np.sin(phi[:-1]), 5 * np.cos(phi[1:]), 5 * np.sin(phi[1:])]
    found = extract_lines(_scan(arc, np.zeros(3), noise=0.003))
    assert len(found) >= 3
    mid = 0.5 * (found.segments[:, :2] + found.segments[:, 2:])
    # Each chord stays within the split distance of the arc.
    assert np.all(np.abs(np.hypot(*mid.T) - 5) < 0.05)
    assert np.all(np.abs(np.hypot(*found.segments[:, :2].T) - 5) < 0.05)


def test_range_jump_breaks_but_steady_wall_does_not():
    cfg = Lines2DConfig()
    # A wall 3 m ahead, seen from -40 to 40 deg, then a jump to 8 m.
    ang = np.deg2rad(np.arange(-40, 41))
    r = np.where(ang < np.deg2rad(20), 3 / np.cos(ang), 8.0)
    pts = np.c_[r * np.cos(ang), r * np.sin(ang)]
    cuts = np.flatnonzero(breakpoints(pts, cfg))
    assert cuts.tolist() == [59]                         # between 19 deg and 20 deg only


def test_short_or_sparse_pieces_are_dropped():
    cfg = Lines2DConfig(min_points=6, min_length_m=0.4)
    pts = np.c_[np.full(5, 2.0), np.linspace(-0.1, 0.1, 5)]   # 5 points
    assert len(extract_lines(pts, cfg)) == 0
    assert len(extract_lines(np.zeros((0, 2)), cfg)) == 0


def test_lines_to_world_moves_with_the_pose():
    seg = np.array([[1.0, 0.0, 2.0, 0.0]])
    out = lines_to_world(seg, np.array([1.0, 1.0, np.pi / 2]))
    assert np.allclose(out, [[1.0, 2.0, 1.0, 3.0]])
