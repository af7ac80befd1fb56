"""The vertical-structure extractor's walls do not depend on how the scan is turned, lifted or listed.

Each scene is ray-cast once (``cast_scan`` of the extractor's own tests: the simulator's HDL-64E or
VLP-32 at the origin, 2 cm range noise, fixed seed), its walls are known (the buildings' visible
faces), and every transformed copy of the scan must give the same walls, mapped back:

* yaw: the whole scan turned about the z axis;
* a constant z offset of all points (the ground is estimated locally);
* point order, and every point given twice.

Tolerances, from measurements on these scenes (1440 yaws 0.25 deg apart; z offsets -2..2 m in 5 cm
steps; the orders and duplications below):

* ``LINE_TOL_M`` = 2 cm: both ends of a turned scan's segment lie this close to the unturned one's
  line. Measured <= 4.4 mm: a line is a fit through thousands of returns, and only the few cells at
  its ends change with the 15 cm grid.
* ``FREE_END_TOL_M`` = 5 cm: a wall's end where it stops in the open moves at most this far along
  it. Measured <= 1.1 cm.
* ``RAGGED_END_TOL_M`` = 0.30 m (two 15 cm cells), for ends at a corner or at the edge of a shadow.
  At a corner the top-view cells hold returns of both faces and go to one face's piece or the
  other's depending on how the grid cuts the corner, so the faces' ends there trade up to about a
  cell diagonal (0.21 m); where a shadow ends a wall seen by one beam only (van_near), the last
  returns are ~10 cm apart and the last cell may drop out. Measured <= 0.21 m (corner), 0.22 m (shadow).
* order and duplicates (same grid, same points): ``EXACT_TOL_M`` = 1 cm. Measured <= 3.5 mm (a
  duplicated scan thins the returns the levelling uses differently, which tilts it by ~0.01 deg).

Against the known answer every segment lies on a true face within ``TRUE_LINE_TOL_M`` (5 cm, as in
test_vertical_structure.py), each visible face gives exactly one segment, and its ends lie within
``TRUE_END_TOL_M`` (0.35 m: the far ends of walls seen at a slant stop up to 0.26 m short) of the
face's ends.

Known failures (``xfail(strict=True)``, see the reasons):

* a z offset changes which structures stop the "top beam": the top-beam tests measure elevations
  about the frame's origin, which they take to be the sensor (walls lost, vans become walls).
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from featmap.extraction.vertical_structure import extract_vertical_structure
from featmap.pipeline.config import load_config
from tests.extraction.test_vertical_structure import building, cast_scan

LINE_TOL_M = 0.02
FREE_END_TOL_M = 0.05
RAGGED_END_TOL_M = 0.30
EXACT_TOL_M = 0.01
TRUE_LINE_TOL_M = 0.05
TRUE_END_TOL_M = 0.35

CONFIG = load_config(None).extraction.vertical_structure

# name -> (simulator objects, sensor, visible faces as ((x1, y1), (x2, y2))[, ends at the edge of a shadow])
SCENES = {
    # three buildings 8-40 m away, a corner of each in view, a fence and a car as clutter
    "street": ([building(15, 6, 27, 18, 9.0), building(-30, -22, -12, -9, 12.0), building(24, -30, 38, -14, 8.0),
                {"kind": "fence", "line": [[-9, 4], [-9, 14]], "height": 1.4},
                {"kind": "car", "position": [9, -5], "heading_deg": 20}], "hdl64",
               [((15, 6), (15, 18)), ((15, 6), (27, 6)), ((-30, -9), (-12, -9)), ((-12, -22), (-12, -9)),
                ((24, -30), (24, -14)), ((24, -14), (38, -14))]),
    # test_fences_cars_vans_and_trees_are_not_walls: only the building's front is a wall
    "clutter": ([building(30, -25, 45, 25, 12.0), {"kind": "fence", "line": [[8, 3], [8, 15]], "height": 1.4},
                 {"kind": "car", "position": [10, -6], "heading_deg": 90},
                 {"kind": "car", "position": [11, -12], "heading_deg": 0, "size": [5.0, 2.0, 2.1]},
                 {"kind": "tree", "position": [14, 20]}, {"kind": "pole", "position": [6, -2], "height": 6}], "hdl64",
                [((30, -25), (30, 25))]),
    # a facade seen over a 1.6 m fence only up to the top beam (it is a wall because it stops that beam)
    "over_fence": ([building(15, -10, 25, 10), {"kind": "fence", "line": [[13, -12], [13, 12]], "height": 1.6}],
                   "hdl64", [((15, -10), (15, 10))]),
    # a 1.95 m van 6 m away under the top beam (no wall: the beam passes there below 2 m); it shades
    # the facade beyond y = -16.5 m, where the last returns of the top beam are
    "van_near": ([building(30, -25, 45, 25, 12.0),
                  {"kind": "car", "position": [5, -4], "heading_deg": 0, "size": [4.8, 1.9, 1.95]}], "hdl64",
                 [((30, -16.5), (30, 25))], [(30, -16.5)]),
    # a rear facade seen only over the 3 m building in front of it
    "over_building": ([building(10, -15, 30, 15, 3.0), building(36, -25, 51, 25, 7.5)], "vlp32",
                      [((10, -15), (10, 15)), ((36, -25), (36, 25))]),
}


@cache
def scene(name: str) -> tuple[np.ndarray, np.ndarray]:
    """(scan (N, 4) float32, walls found in it (K, 4)); cast once per test session."""
    objects, sensor = SCENES[name][:2]
    scan = cast_scan(objects, sensor=sensor)
    scan.setflags(write=False)
    return scan, extract_vertical_structure(scan, CONFIG).segments


def faces(name: str) -> list[tuple[np.ndarray, np.ndarray]]:
    return [(np.asarray(p, float), np.asarray(q, float)) for p, q in SCENES[name][2]]


def rotation(deg: float) -> np.ndarray:
    c, s = np.cos(np.deg2rad(deg)), np.sin(np.deg2rad(deg))
    return np.array([[c, -s], [s, c]])


def turned(scan: np.ndarray, deg: float) -> np.ndarray:
    out = scan.copy()
    out[:, :2] = scan[:, :2] @ rotation(deg).T
    return out


def turned_back(segments: np.ndarray, deg: float) -> np.ndarray:
    """(K, 4) segments found in a scan turned by ``deg``, in the unturned scan's frame."""
    R = rotation(deg)
    return np.column_stack([segments[:, :2] @ R, segments[:, 2:] @ R]).reshape(-1, 4)


def face_of(seg: np.ndarray, name: str) -> int | None:
    """Index of the true face both ends of ``seg`` lie on (within TRUE_LINE_TOL_M, within its extent +-
    TRUE_END_TOL_M), or None."""
    for k, (p, q) in enumerate(faces(name)):
        u = (q - p) / np.linalg.norm(q - p)
        rel = seg.reshape(2, 2) - p
        t, off = rel @ u, rel @ [-u[1], u[0]]
        within = (t >= -TRUE_END_TOL_M) & (t <= np.linalg.norm(q - p) + TRUE_END_TOL_M)
        if np.all(np.abs(off) <= TRUE_LINE_TOL_M) and np.all(within):
            return k
    return None


def is_ragged(end: np.ndarray, name: str) -> bool:
    """The true end closest to ``end`` is a corner (shared by two faces) or the edge of a shadow."""
    ends = np.array([e for pq in faces(name) for e in pq])
    nearest = ends[np.argmin(np.linalg.norm(ends - end, axis=1))]
    shadow = np.array(SCENES[name][3] if len(SCENES[name]) > 3 else np.zeros((0, 2)), float).reshape(-1, 2)
    return int((np.linalg.norm(ends - nearest, axis=1) < 1e-9).sum()) > 1 or bool(
        (np.linalg.norm(shadow - nearest, axis=1) < 1e-9).any())


def assert_known_walls(segments: np.ndarray, name: str) -> None:
    """One segment per visible face, on it, with ends near the face's ends; nothing else."""
    on = [face_of(s, name) for s in segments]
    assert None not in on, f"segments on no wall: {segments[[k is None for k in on]].round(2).tolist()}"
    assert sorted(on) == list(range(len(faces(name)))), f"segments per face: {on}"
    for s, k in zip(segments, on):
        p, q = faces(name)[k]
        ends = s.reshape(2, 2)
        if np.linalg.norm(ends[0] - p) > np.linalg.norm(ends[0] - q):
            ends = ends[::-1]
        assert np.linalg.norm(ends - [p, q], axis=1).max() <= TRUE_END_TOL_M, (s.round(3), p, q)


def wall_deviation(segments: np.ndarray, reference: np.ndarray, name: str) -> tuple[float, float, float]:
    """(line, free end, ragged end) largest deviations of ``segments`` from ``reference`` (both (K, 4), one
    segment per face, matched by face): the distance of each end from the reference's line, and its
    shift along it, at open ends and at corners or shadows' edges."""
    by_face = {face_of(s, name): s for s in segments}
    line = free = ragged = 0.0
    for r in reference:
        s = by_face[face_of(r, name)]
        p, q = r[:2], r[2:]
        u = (q - p) / np.linalg.norm(q - p)
        ends = s.reshape(2, 2)
        if np.linalg.norm(ends[0] - p) > np.linalg.norm(ends[0] - q):
            ends = ends[::-1]
        line = max(line, float(np.abs((ends - p) @ [-u[1], u[0]]).max()))
        for end, ref in zip(ends, (p, q)):
            shift = abs(float((end - ref) @ u))
            if is_ragged(ref, name):
                ragged = max(ragged, shift)
            else:
                free = max(free, shift)
    return line, free, ragged


def assert_same_walls(segments: np.ndarray, name: str, exact: bool = False) -> None:
    """``segments`` (in the original scan's frame) are the scene's known walls and the original scan's."""
    assert_known_walls(segments, name)
    line, free, ragged = wall_deviation(segments, scene(name)[1], name)
    if exact:
        assert max(line, free, ragged) <= EXACT_TOL_M, (line, free, ragged)
    else:
        assert line <= LINE_TOL_M and free <= FREE_END_TOL_M and ragged <= RAGGED_END_TOL_M, (line, free, ragged)


@pytest.mark.parametrize("name", list(SCENES))
def test_the_unchanged_scans_give_their_known_walls(name):
    assert_known_walls(scene(name)[1], name)


# --- yaw ------------------------------------------------------------------------------------------------

# Until extractor version 14, at 58 of 1440 yaws 0.25 deg apart (16.75-67.75 deg, 196.75-247.75 deg and a
# few more; 17 deg among them) the tree at (14, 20) of the clutter scene gave a 1.1-1.5 m wall at its trunk
# (returns 1.2-2.6 m up: the 0.4 m trunk and the underside of the crown): the 15 cm top-view grid and the
# 5 deg direction vote are fixed to the sensor's axes, so which cells of the round blob form a line piece
# depends on yaw, and at 17 deg the piece faced the sensor, was thin and reached near the ground. Since
# version 15 (trunk_max_share: its cells reach down over less than half of its length, beside low thin
# slivers) none of the 1440 yaws gives it.


@pytest.mark.parametrize("name", ["street", "clutter", "over_fence", "van_near", "over_building"])
@pytest.mark.parametrize("deg", [0.0, 17.0, 45.0, 90.0, 133.0, 200.0])
def test_turning_the_scan_turns_its_walls(name, deg):
    scan, _ = scene(name)
    assert_same_walls(turned_back(extract_vertical_structure(turned(scan, deg), CONFIG).segments, deg), name)


@settings(max_examples=15, deadline=None, database=None, derandomize=True)
@given(deg=st.floats(-360.0, 360.0, allow_nan=False))
def test_any_yaw_gives_the_same_street(deg):
    """Derandomized so that CI draws the same yaws every run (the yaws below once failed 0.2 % of draws)."""
    scan, _ = scene("street")
    assert_same_walls(turned_back(extract_vertical_structure(turned(scan, deg), CONFIG).segments, deg), "street")


# Until 2026-12-04, 74 of 36,000 yaws 0.01 deg apart (windows 0.01-0.04 deg wide, repeating every 90 deg)
# left the wall (15, 6)-(27, 6) 0.41-0.44 m short of its corner, or (24, -14)-(38, -14) 0.37 m short: the
# cells next to the corner lost their direction vote in link_cells to the other face's denser cells and
# fell out of the wall's piece, as the grid (fixed to the sensor's axes) happened to cut the corner.
# rejoin_corner_cells gives them back; a 0.01 deg scan of 0-90 deg finds no such yaw since.
@pytest.mark.parametrize("deg", [10.09, 37.35, 59.62, 59.92, 60.14, 60.84, 64.93, 68.79, 68.82, 190.09375])
def test_a_yaw_at_a_corner_cell_boundary_keeps_the_wall_end(deg):
    scan, _ = scene("street")
    assert_same_walls(turned_back(extract_vertical_structure(turned(scan, deg), CONFIG).segments, deg), "street")


# --- z offset -------------------------------------------------------------------------------------------

Z_OFFSET = ("not invariant under a constant z offset: the top-beam tests take the frame's origin for the "
            "sensor. top_beam_tangent (featmap/extraction/vertical_structure.py, a quantile of z / range) gives "
            "-1.86 deg for the HDL-64's +2 deg top beam at dz = -1.5 m and +8.3 deg at dz = +0.5 m (near returns "
            "gain dz / range); structure_cells' reach (z - range * tan_top), highest_returns' slopes ("
            "z / range; seen_over / hidden) and top_beam_reach_from follow, so Cells.reaches_top / "
            "hidden_above flip: the facade seen over the fence no longer stops the top beam (lost for dz <= -1.2), "
            "a van within reach_from now does (a wall; the clutter scene's 2.1 m van, 2 cm outside the envelope "
            "margin, already at dz = +0.05), the rear facade over the house is 'hidden above' (lost for "
            "dz >= +0.75). The local ground itself is invariant")


def z_case(name, dz, fails=False):
    marks = [pytest.mark.xfail(strict=True, raises=AssertionError, reason=Z_OFFSET)] if fails else []
    return pytest.param(name, dz, marks=marks, id=f"{name}-{dz:+.2f}")


@pytest.mark.parametrize("name, dz", [
    z_case("street", -1.5), z_case("street", -0.75), z_case("street", 0.75), z_case("street", 1.5),
    z_case("clutter", -1.5), z_case("clutter", 1.5), z_case("clutter", 0.5, fails=True),      # the van: two walls
    z_case("over_fence", 1.5), z_case("over_fence", -1.5, fails=True),                        # the facade is lost
    z_case("van_near", -1.5), z_case("van_near", 0.5, fails=True),                            # the van is a wall
    z_case("over_building", -1.5), z_case("over_building", 1.5, fails=True),                  # the rear facade is lost
])
def test_lifting_every_point_keeps_the_walls(name, dz):
    scan, _ = scene(name)
    lifted = scan.copy()
    lifted[:, 2] += np.float32(dz)
    assert_same_walls(extract_vertical_structure(lifted, CONFIG).segments, name)


# --- point order and duplicates ---------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["street", "clutter", "over_fence", "van_near", "over_building"])
@pytest.mark.parametrize("how", ["reversed", "shuffled", "twice", "twice_interleaved", "twice_shuffled"])
def test_order_and_duplicates_do_not_matter(name, how):
    scan, _ = scene(name)
    rng = np.random.default_rng(7)
    points = {"reversed": lambda: scan[::-1],
              "shuffled": lambda: scan[rng.permutation(len(scan))],
              "twice": lambda: np.concatenate([scan, scan]),
              "twice_interleaved": lambda: np.repeat(scan, 2, axis=0),
              "twice_shuffled": lambda: np.concatenate([scan, scan])[rng.permutation(2 * len(scan))]}[how]()
    assert_same_walls(extract_vertical_structure(points, CONFIG).segments, name, exact=True)
