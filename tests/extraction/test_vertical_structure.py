"""The vertical-structure extractor on small ray-cast scenes with known answers.

Scenes are cast with the simulator's sensor models (HDL-64E: top beam +2 deg, 1.73 m up) from the
origin of a world frame that is also the velodyne frame, so a wall at x = 20 in the world is at
x = 20 in the scan.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from featmap.config import Section
from featmap.errors import FeatmapError
from featmap.extraction import ExtractionConfig, extract_scan
from featmap.extraction.vertical_structure import VerticalStructureConfig, extract_vertical_structure
from featmap.simulation.scene import build_scene, cast
from featmap.simulation.sensors import SENSORS
from featmap.simulation.worlds import world_from_dict


def cast_scan(objects: list[dict], sensor: str = "hdl64", noise: float = 0.02, seed: int = 0,
              azimuth_step: float | None = None) -> np.ndarray:
    """(N, 4) float32 scan of ``objects`` (simulator world objects) from a sensor at (0, 0, height)."""
    world = world_from_dict({"name": "test", "route": {"waypoints": [[-1, 0], [1, 0]]}, "objects": objects}, "test")
    scene, _ = build_scene(world)
    preset = SENSORS[sensor] if azimuth_step is None else SENSORS[sensor].with_azimuth_step(azimuth_step)
    directions = preset.ray_directions()
    t, _, _ = cast(scene, np.array([0.0, 0.0, preset.height_m]), directions)
    hit = np.isfinite(t) & (t <= preset.max_range_m) & (t >= preset.min_range_m)
    r = t[hit] + np.random.default_rng(seed).normal(0, noise, hit.sum())
    pts = directions[hit] * r[:, None]
    return np.column_stack([pts, np.full(len(pts), 0.3)]).astype(np.float32)


def building(x0, y0, x1, y1, height=10.0) -> dict:
    return {"kind": "building", "footprint": [[x0, y0], [x1, y0], [x1, y1], [x0, y1]], "height": height}


def on_line(seg: np.ndarray, p, q, tol: float) -> bool:
    """Both ends of (4,) ``seg`` within ``tol`` of the infinite line p-q."""
    p, q = np.asarray(p, float), np.asarray(q, float)
    n = np.array([-(q - p)[1], (q - p)[0]]) / np.linalg.norm(q - p)
    return bool(np.all(np.abs((seg.reshape(2, 2) - p) @ n) <= tol))


def test_facade_at_20_m_seen_only_to_2_5_m_is_one_segment_within_5_cm():
    scan = cast_scan([building(20, -10, 35, 10)])
    assert scan[np.abs(scan[:, 0] - 20) < 0.1, 2].max() + 1.73 < 2.6      # the top beam sees it up to ~2.4 m
    result = extract_vertical_structure(scan)
    assert len(result) == 1
    seg = result.segments[0]
    assert np.abs(seg[[0, 2]] - 20).max() < 0.05
    assert sorted(seg[[1, 3]]) == pytest.approx([-10, 10], abs=0.3)
    assert result.rms[0] == pytest.approx(0.02, abs=0.01)
    assert result.z_min[0] < -1.2 and result.z_max[0] == pytest.approx(20 * np.tan(np.deg2rad(2.0)), abs=0.1)
    assert result.n_points[0] > 1000
    assert 0 < result.max_gap[0] < 0.2               # 0.17 deg steps at 20-22 m: returns ~6 cm apart


def test_fences_cars_vans_and_trees_are_not_walls():
    objects = [building(30, -25, 45, 25, 12.0),
               {"kind": "fence", "line": [[8, 3], [8, 15]], "height": 1.4},
               {"kind": "car", "position": [10, -6], "heading_deg": 90},
               {"kind": "car", "position": [11, -12], "heading_deg": 0, "size": [5.0, 2.0, 2.1]},   # a van
               {"kind": "tree", "position": [14, 20]},
               {"kind": "pole", "position": [6, -2], "height": 6}]
    result = extract_vertical_structure(cast_scan(objects))
    assert len(result) >= 1
    for seg in result.segments:                  # everything found lies on the building's front
        assert on_line(seg, [30, -25], [30, 25], 0.1), seg


def test_the_trace_names_the_tests_a_fence_fails_and_changes_no_result():
    objects = [building(30, -25, 45, 25, 12.0),
               {"kind": "fence", "line": [[8, 3], [8, 15]], "height": 1.4},
               {"kind": "car", "position": [11, -12], "heading_deg": 0, "size": [5.0, 2.0, 2.1]}]   # a van
    scan = cast_scan(objects)
    trace: dict = {}
    traced = extract_vertical_structure(scan, trace=trace)
    plain = extract_vertical_structure(scan)
    np.testing.assert_array_equal(traced.segments, plain.segments)
    heights, finals = trace["height"], trace["final"]

    def piece_on(tests, p, q):
        on = [k for k in range(len(tests.a)) if on_line(np.r_[tests.a[k], tests.b[k]], p, q, 0.3)
              and np.hypot(*(tests.b[k] - tests.a[k])) > 3]
        assert len(on) == 1, on
        return on[0]

    assert heights.failed(piece_on(heights, [8, 3], [8, 15])) == ["top", "tall"]     # 1.4 m: low, and not tall
    assert "tall" in heights.failed(piece_on(heights, [8.6, -11], [13.4, -11]))      # the van's side
    assert heights.failed(piece_on(heights, [30, -25], [30, 25])) == []
    assert finals.failed(piece_on(finals, [30, -25], [30, 25])) == []
    assert finals.kept.sum() == len(plain) == 1
    assert list(heights.passed) == ["points", "length", "rms", "span", "top", "reaches_down", "tall",
                                    "not_crown_underside", "not_trunk"]
    assert trace["xyz"].shape[1] == 3 and trace["rotation"].shape == (3, 3)


def test_the_trace_stays_empty_when_a_scan_has_too_few_returns():
    trace: dict = {}
    assert len(extract_vertical_structure(np.array([[10.0, 0.0, 0.5]] * 5), trace=trace)) == 0
    assert trace == {}


def test_corner_of_a_building_gives_two_segments_meeting_at_it():
    result = extract_vertical_structure(cast_scan([building(15, 5, 25, 15)]))
    assert len(result) == 2
    ends = result.segments.reshape(-1, 2)
    assert np.linalg.norm(ends - [15, 5], axis=1).min() < 0.3
    assert sorted(on_line(s, [15, 5], [15, 15], 0.05) + 2 * on_line(s, [15, 5], [25, 5], 0.05) for s in result.segments) == [1, 2]


def test_two_houses_in_a_row_stay_two_segments():
    result = extract_vertical_structure(cast_scan([building(-20, 12, -4, 20), building(1, 12, 17, 20)]))
    fronts = [s for s in result.segments if on_line(s, [-20, 12], [17, 12], 0.05)]
    assert len(fronts) == 2
    xs = sorted(sorted(s[[0, 2]].tolist()) for s in fronts)
    assert xs[0] == pytest.approx([-20, -4], abs=0.3) and xs[1] == pytest.approx([1, 17], abs=0.3)


def test_a_densely_sampled_wall_at_85_m_is_found():
    result = extract_vertical_structure(cast_scan([building(85, -20, 100, 20, 20.0)]))
    fronts = [s for s in result.segments if on_line(s, [85, -20], [85, 20], 0.1)]
    assert fronts and max(abs(s[3] - s[1]) for s in fronts) > 20


def test_uphill_road_has_a_local_ground():
    """A 6 % grade rising ahead: the facade is found and the fence on the slope is still a fence."""
    objects = [building(25, -10, 40, 10), {"kind": "fence", "line": [[12, -8], [12, 8]], "height": 1.3}]
    scan = cast_scan(objects)
    scan[:, 2] += 0.06 * scan[:, 0]               # terrain (and everything on it) rises with x
    result = extract_vertical_structure(scan)
    assert len(result) == 1 and on_line(result.segments[0], [25, -10], [25, 10], 0.05)
    # measured from one ground for the whole scan, the fence would stand 2 m high and pass as a wall
    # (and the facade would float 1.5 m up; the floating test is off here to show the ground alone)
    flat = extract_vertical_structure(scan, VerticalStructureConfig(ground_max_slope=0.0, ground_reach_m=300.0,
                                                                    short_max_bottom_m=10.0))
    assert any(on_line(s, [12, -8], [12, 8], 0.05) for s in flat.segments)


def test_a_rolled_sensor_still_sees_thin_walls():
    """Walls are vertical in the world, not in a sensor rolled by 2 deg; a 32-beam sensor sees them 10 m high."""
    scan = cast_scan([building(15, -10, 30, 10, 15.0)], sensor="vlp32")
    roll = np.deg2rad(2.0)
    c, s = np.cos(roll), np.sin(roll)
    scan[:, 1:3] = scan[:, 1:3] @ np.array([[c, -s], [s, c]]).T
    result = extract_vertical_structure(scan)
    assert len(result) == 1 and result.rms[0] < 0.04


def test_a_tilted_sensor_is_levelled_by_the_walls_lean():
    """A sensor pitched by 1.5 deg and rolled by 2 deg (a vehicle on a sloped street): the lean of the
    walls gives the tilt within 0.1 deg, the walls come out 2 cm thin, and moved to the world with
    the sensor's true attitude (as segments_to_world does) they lie on the footprint within 3 cm."""
    from featmap.extraction import segments_to_world
    from featmap.extraction.vertical_structure import heights_above_local_ground, scan_lean
    from featmap.simulation.simulate import rotation_xyz

    sensor_height = SENSORS["vlp32"].height_m
    world = cast_scan([building(12, 6, 30, 20, 15.0), building(-25, -20, -8, -9, 12.0)], sensor="vlp32")
    world[:, 2] += sensor_height                                  # world frame: the ground at z = 0
    R = rotation_xyz(np.deg2rad(2.0), np.deg2rad(1.5), 0.0)      # sensor -> world
    T = np.eye(4)
    T[:3, :3], T[2, 3] = R, sensor_height
    scan = world.copy()
    scan[:, :3] = (world[:, :3] - T[:3, 3]) @ R                   # the same returns in the tilted sensor's frame
    xyz = scan[:, :3].astype(float)
    config = VerticalStructureConfig()
    height = heights_above_local_ground(xyz, config)
    above = height > config.ground_margin_m
    g = scan_lean(xyz[above], height[above], np.inf, None, config)
    up = R[2]                                                     # the world's vertical in the sensor frame
    assert np.degrees(np.abs(g - up[:2] / up[2])).max() < 0.1
    result = extract_vertical_structure(scan)
    assert result.rms.max() < 0.03
    walls = [([12, 6], [30, 6]), ([12, 6], [12, 20]), ([-8, -20], [-8, -9]), ([-25, -9], [-8, -9])]
    for seg in segments_to_world(result, T):
        assert any(on_line(seg, p, q, 0.03) for p, q in walls), seg
    assert len(result) >= 3


@pytest.mark.parametrize("sensor, roll_deg, pitch_deg", [("vlp32", 2.0, 1.5), ("vlp32", -2.5, 2.0),
                                                        ("hdl64", 2.0, 1.5), ("hdl64", 1.0, -3.0)])
def test_a_tilted_sensor_between_two_street_walls_measures_its_roll(sensor, roll_deg, pitch_deg):
    """Walls along the street, 9 m to each side, seen at grazing incidence: each column of returns
    slants across the leaning wall, so a plain top-view line follows part of the lean (the roll came
    out 0.05-1 deg off that way). The line and the lean fitted together give the roll within 0.03 deg."""
    from featmap.extraction.vertical_structure import heights_above_local_ground, scan_lean
    from featmap.simulation.simulate import rotation_xyz

    sensor_height = SENSORS[sensor].height_m
    world = cast_scan([building(-20, 9, 120, 15, 14.0), building(-20, -15, 120, -9, 10.0)], sensor=sensor)
    world[:, 2] += sensor_height
    R = rotation_xyz(np.deg2rad(roll_deg), np.deg2rad(pitch_deg), 0.0)
    xyz = (world[:, :3] - np.array([0.0, 0.0, sensor_height])) @ R
    config = VerticalStructureConfig()
    height = heights_above_local_ground(xyz, config)
    above = height > config.ground_margin_m
    g = scan_lean(xyz[above], height[above], np.inf, None, config)
    up = R[2]
    assert np.degrees(abs(g[1] - up[1] / up[2])) < 0.03


def test_lean_fit_separates_a_lean_from_a_turn():
    """Offsets that grow with height (lean) and along the line (turn), with height and position
    correlated as in a grazing wall's slanted columns: both come back exactly; for one column (height
    follows position) nothing is left to measure a lean with."""
    from featmap.extraction.vertical_structure import lean_fit

    rng = np.random.default_rng(3)
    along = rng.uniform(-10, 10, 400)
    dz = 0.4 * along + rng.uniform(-2, 2, 400)
    offset = 0.01 * along + 0.035 * dz
    along, dz = along - along.mean(), dz - dz.mean()
    offset = offset - offset.mean()
    turn, lean, unique = lean_fit(offset, along, dz, np.zeros(400, np.int64), 1)
    assert turn[0] == pytest.approx(0.01, abs=1e-9) and lean[0] == pytest.approx(0.035, abs=1e-9)
    assert unique[0] == pytest.approx(400 * 4 / 3, rel=0.15)        # the variance of uniform(-2, 2)
    column = lean_fit(offset, along, 0.4 * along, np.zeros(400, np.int64), 1)[2]
    assert column[0] < 1e-6


def test_a_facade_seen_over_a_fence_up_to_the_top_beam_is_found():
    """Behind a 1.6 m fence 2 m in front of it, a facade at 15 m is seen by the HDL-64 from 1.6 m up to its
    top beam at 2.25 m only: a band too narrow for min_span_m, but a long piece that stops the top beam
    is higher than the beam there (above any car). The fence itself is no wall."""
    scan = cast_scan([building(15, -10, 25, 10), {"kind": "fence", "line": [[13, -12], [13, 12]], "height": 1.6}])
    result = extract_vertical_structure(scan)
    assert len(result) == 1 and on_line(result.segments[0], [15, -10], [15, 10], 0.05)
    assert len(extract_vertical_structure(scan, VerticalStructureConfig(solid_min_span_m=0.8))) == 0


@pytest.mark.parametrize("sensor, rear_height", [("vlp32", 7.5), ("vls128", 7.5), ("vlp16", 9.0)])
def test_a_wall_seen_only_over_the_building_in_front_is_found(sensor, rear_height):
    """A 3 m building 10-30 m ahead hides the road behind it; the rear building's facade at 36 m is seen
    only above 6.3 m, as a band under its roof, with no ground within ground_reach_m. Its lowest return
    must not become its ground (the band would be 0-1 m 'high', below every height test): the ground
    rises at most ground_max_slope from the road around the sensor. One segment within 5 cm."""
    scan = cast_scan([building(10, -15, 30, 15, 3.0), building(36, -25, 51, 25, rear_height)], sensor=sensor)
    result = extract_vertical_structure(scan)
    rear = [s for s in result.segments if on_line(s, [36, -25], [36, 25], 0.05)]
    assert len(rear) == 1 and abs(rear[0][3] - rear[0][1]) > 45
    assert any(on_line(s, [10, -15], [10, 15], 0.05) for s in result.segments)


def test_a_tall_car_next_to_the_sensor_under_its_top_beam_is_no_wall():
    """Within ~8 m the HDL-64's top beam passes below 2 m: a 1.95 m van there stops it, but that is no
    evidence of a wall (reach_min_m)."""
    scan = cast_scan([building(30, -25, 45, 25, 12.0),
                      {"kind": "car", "position": [5, -4], "heading_deg": 0, "size": [4.8, 1.9, 1.95]}])
    result = extract_vertical_structure(scan)
    assert len(result) == 1 and on_line(result.segments[0], [30, -25], [30, 25], 0.05)
    assert len(extract_vertical_structure(scan, VerticalStructureConfig(reach_min_m=0.0))) > 1


def test_a_wall_along_the_street_is_followed_far_out():
    """A wall 8 m to the side, 20-110 m ahead: beyond ~70 m the samples of successive azimuth steps lie
    metres apart (seen 84-86 deg from head-on); the columns of returns are linked one step to the next."""
    scan = cast_scan([building(20, 8, 110, 14, 10.0)])
    far_end = lambda result: max([max(s[0], s[2]) for s in result.segments if on_line(s, [20, 8], [110, 8], 0.1)])
    assert far_end(extract_vertical_structure(scan)) > 85
    assert far_end(extract_vertical_structure(scan, VerticalStructureConfig(link_grazing_deg=0.0))) < 75


def test_pieces_seen_edge_on_are_not_walls():
    """A piece lying along the sensor's ray (returns of a round thing at several depths) is dropped."""
    from featmap.extraction.vertical_structure import PieceMeasures, wall_segments

    def measures(a, b):
        one = np.ones(1)
        return PieceMeasures(a=np.array([a], float), b=np.array([b], float), count=100 * one, n_points=100 * one,
                             z_mean=0 * one, z_min=-1 * one, z_max=2 * one, rms=0.01 * one, core=one, behind=0 * one,
                             max_gap=0 * one, column_curve=0 * one)

    assert len(wall_segments(measures([40, 1.0], [43, 3.0]), VerticalStructureConfig())) == 1    # 60 deg
    assert len(wall_segments(measures([40, 1.0], [43, 1.1]), VerticalStructureConfig())) == 0    # 89 deg


def test_two_columns_with_nothing_between_are_not_a_wall():
    """Two columns of returns one azimuth step apart (a far corner and a pole) fit any line: a piece
    spanning less than 1.5 steps as seen from the sensor is dropped when its returns leave a gap, kept
    when they cover it (a grazing wall) or when it spans three steps or more."""
    from featmap.extraction.vertical_structure import PieceMeasures, wall_segments

    def measures(a, b, max_gap):
        one = np.ones(1)
        return PieceMeasures(a=np.array([a], float), b=np.array([b], float), count=100 * one, n_points=100 * one,
                             z_mean=0 * one, z_min=-1 * one, z_max=2 * one, rms=0.01 * one, core=one, behind=0 * one,
                             max_gap=max_gap * one, column_curve=0 * one)

    step = 0.38
    far = np.array([130.0, 0.0])
    grazing = np.array([np.cos(np.deg2rad(10)), np.sin(np.deg2rad(10))])     # seen 80 deg from head-on
    across = np.array([np.sin(np.deg2rad(10)), np.cos(np.deg2rad(10))])      # seen 10 deg from head-on
    one_step = far + 5.0 * grazing          # 0.87 m across the ray at 130 m: 1.0 step
    config = VerticalStructureConfig()
    assert len(wall_segments(measures(far, one_step, 4.2), config, step)) == 0           # two columns
    assert len(wall_segments(measures(far, one_step, 0.3), config, step)) == 1           # returns all along
    assert len(wall_segments(measures(far, one_step, 4.2), VerticalStructureConfig(min_azimuth_steps=0), step)) == 1
    three_steps = far + 3.0 * across       # 2.95 m across the ray at 130 m: 3.4 steps
    assert len(wall_segments(measures(far, three_steps, 1.2), config, step)) == 1


def test_tree_crowns_seen_along_the_ray_from_afar_are_not_walls():
    """A crown 40-75 m away shows a single column of returns at several depths that lines up with the ray
    (edge-on, within max_incidence_deg); a wall seen in one column would be a straight line in height
    and azimuth, the crown's round is not (max_column_curve_m). The building beside them is still found."""
    trees = [{"kind": "tree", "position": [40 + 5 * k, -12 + 3 * k], "trunk_height": 2.6, "crown_radius": 2.9}
             for k in range(8)]
    scan = cast_scan(trees + [building(-40, 10, -25, 25)], sensor="vls128", azimuth_step=0.27)
    result = extract_vertical_structure(scan)
    assert len(result) >= 1
    for seg in result.segments:
        assert on_line(seg, [-40, 10], [-25, 10], 0.1) or on_line(seg, [-25, 10], [-25, 25], 0.1), seg
    # Without the rule a crown passes (floating_min_top_m, which drops some of them too, off as well).
    loose = extract_vertical_structure(scan, VerticalStructureConfig(max_column_curve_m=100.0, floating_min_top_m=0.0))
    assert any(seg[[0, 2]].min() > 35 for seg in loose.segments)


# A spread bar loose enough to pass the clutter of the scenes below (3x the head-on walls' noise; the default
# 2x, adopted 2026-12-04, rejects it too), so that a test sees the rule it is about.
LOOSE_SPREAD = dict(solid_rms_factor=3.0)


def test_a_fence_under_a_crown_behind_street_trees_is_no_wall(monkeypatch):
    """Street trees stop the top beam in front of most of a 1.5 m fence; the few columns whose top is seen
    are the ones a crown hangs over. Judged over those alone, the fence would be as high as the crown
    and reach the top beam; too few of its columns are seen, so all of them count (MIN_SEEN_FRACTION)."""
    import featmap.extraction.vertical_structure as vs

    fence = {"kind": "fence", "line": [[6, 4], [16, 8]], "height": 1.5}
    crown = {"kind": "tree", "position": [8, 4.3], "trunk_height": 2.7, "crown_radius": 2.3}
    street = [{"kind": "tree", "position": [x, 2.5], "trunk_height": 2.2, "crown_radius": 1.5} for x in (7, 10, 13)]
    scan = cast_scan([fence, crown, *street, building(-40, 10, -25, 25)], sensor="vls128", azimuth_step=0.27)

    def on_fence(result):
        return [seg for seg in result.segments if on_line(seg, [6, 4], [16, 8], 0.3)]

    assert on_fence(extract_vertical_structure(scan)) == []
    assert len(extract_vertical_structure(scan)) == 2                 # the building's two faces
    loose = VerticalStructureConfig(**LOOSE_SPREAD)
    assert on_fence(extract_vertical_structure(scan, loose)) == []    # the height rules alone reject it
    monkeypatch.setattr(vs, "MIN_SEEN_FRACTION", 0.0)
    assert len(on_fence(extract_vertical_structure(scan, loose))) == 1       # judged over the seen columns alone


def test_deterministic_and_independent_of_point_order():
    scan = cast_scan([building(15, 5, 25, 15), building(-30, -20, -10, -8)])
    a, b = extract_vertical_structure(scan), extract_vertical_structure(scan)
    assert np.array_equal(a.segments, b.segments)
    shuffled = scan[np.random.default_rng(1).permutation(len(scan))]
    c = extract_vertical_structure(shuffled)
    assert c.segments == pytest.approx(a.segments, abs=1e-6)


@pytest.mark.parametrize("n", [0, 1, 10])
def test_tiny_scans_give_nothing(n):
    assert len(extract_vertical_structure(np.ones((n, 4), np.float32) * [5, 5, 0, 0])) == 0


def test_ground_only_and_out_of_range_scans_give_nothing():
    ground = cast_scan([])
    assert len(ground) > 10000 and len(extract_vertical_structure(ground)) == 0
    far = cast_scan([building(20, -10, 35, 10)])
    far[:, :2] *= 10                              # everything beyond max_range_m
    assert len(extract_vertical_structure(far)) == 0


def test_a_scan_with_no_return_beyond_3_m_gives_a_result_without_warnings():
    """Everything within 3 m (a van beside the sensor hides the street): no top beam is measured (its
    tangent is inf), which made the top-beam test compute inf - inf (a RuntimeWarning in a benchmark run)."""
    rng = np.random.default_rng(0)
    side = np.c_[np.full(3000, 2.0), rng.uniform(-2, 2, 3000), rng.uniform(-1.7, 1.3, 3000), np.zeros(3000)]
    ground = np.c_[rng.uniform(-2, 2, (2000, 2)), np.full(2000, -1.73), np.zeros(2000)]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = extract_vertical_structure(np.vstack([side, ground]))
    assert result.segments.shape[1:] == (4,)


def test_a_scan_with_nothing_tall_enough_for_a_wall_gives_nothing():
    """Only a 0.9 m high box above the ground (a hedge, a low wall): no cell is high enough to take part,
    and the levelling and the pieces' measures get no cell at all (this raised an IndexError)."""
    low = cast_scan([building(10, -5, 14, 5, 0.9)])
    assert len(low) > 10000 and len(extract_vertical_structure(low)) == 0


def grazing_columns(step_deg: float = 0.4, wall_x: float = 11.2, y_near: float = -64.0, y_far: float = -83.0,
                    slant: float = 0.35, noise: float = 0.01) -> np.ndarray:
    """(N, 4) returns of the wall x = ``wall_x`` (``y_far`` .. ``y_near``) 64-84 m away, seen 80-82 deg from
    head-on by a sensor ``step_deg`` apart in azimuth and 0.45 m apart in height there: one column of returns
    per azimuth step, 4 m apart along the wall, each slanting ``slant`` m along it per metre of height (the
    beams of one azimuth of a sensor tilted on a sloped street cut the wall in a slanted line), over an
    azimuth-sampled ground at z = -1.73."""
    rng = np.random.default_rng(0)
    pts = []
    for az in np.arange(np.arctan2(y_far, wall_x), np.arctan2(y_near, wall_x), np.deg2rad(step_deg)):
        for z in np.arange(-1.5, 3.0, 0.45):
            pts.append([wall_x + rng.normal(0, noise), wall_x * np.tan(az) + slant * z, z])
    az, r = np.meshgrid(np.deg2rad(np.arange(-180, 180, step_deg)), np.arange(4.0, 90.0, 1.5))
    ground = np.column_stack([(r * np.cos(az)).ravel(), (r * np.sin(az)).ravel(), np.full(r.size, -1.73)])
    return np.column_stack([np.vstack([np.array(pts), ground]), np.full(len(pts) + len(ground), 0.3)]).astype(np.float32)


def test_a_far_wall_seen_at_grazing_incidence_as_single_columns_is_one_wall():
    """Six columns of returns 4 m apart along a far wall, each a metre-long slanted streak spanning less
    than an azimuth step: no two cells of different columns are neighbours (each cell holds one return,
    so none stands a metre high), but the columns, one azimuth step apart and in line, are joined."""
    result = extract_vertical_structure(grazing_columns())
    on_wall = [s for s in result.segments if on_line(s, [11.2, -64], [11.2, -83], 0.05)]
    assert len(on_wall) == 1
    assert min(on_wall[0][1], on_wall[0][3]) < -82.5 and max(on_wall[0][1], on_wall[0][3]) > -65.5
    gap = result.max_gap[[i for i, s in enumerate(result.segments) if on_line(s, [11.2, -64], [11.2, -83], 0.05)]]
    assert 2.5 < gap[0] < 4.0                        # its columns lie 4 m apart (less the streaks' length)


def test_a_far_wall_whose_columns_slant_across_cells_none_a_metre_high_is_found_with_stacked_columns():
    """Columns slanting 0.1 m along the wall per metre of height cross three or four 0.15 m cells each, and no
    cell stands a metre high: each column is too short to be a piece and not a column for the grazing
    links, so the wall is lost. Counting a cell together with the cells right above and below it in its
    azimuth step (link_column_stack_m) makes each column a column, and the columns one step apart one wall."""
    scan = grazing_columns(slant=0.1)

    def on_wall(config):
        return [s for s in extract_vertical_structure(scan, config).segments
                if on_line(s, [11.2, -64], [11.2, -83], 0.05)]

    assert on_wall(VerticalStructureConfig(link_column_stack_m=0.0)) == []
    found = on_wall(VerticalStructureConfig(link_column_stack_m=0.3))
    assert len(found) == 1
    assert min(found[0][1], found[0][3]) < -82.5 and max(found[0][1], found[0][3]) > -66.0


def test_a_cell_stands_as_a_column_with_the_cells_above_and_below_it_in_its_azimuth_step_only():
    """Three cells of one azimuth step 0.1 m apart in range, 0.6 m high each, stack to 2 m: a column with
    link_column_stack_m 0.3, not without it. A tree crown's cells in one azimuth lie at several depths
    (0.5 m apart here) and cells in the next azimuth step are another column: neither stacks."""
    from featmap.extraction.vertical_structure import column_cells

    step = 0.2
    config = VerticalStructureConfig(link_azimuth_deg=3.33 * step, link_column_stack_m=0.3)

    def cells(azimuths_deg, ranges):
        az = np.deg2rad(azimuths_deg)
        return np.column_stack([ranges * np.cos(az), ranges * np.sin(az)])

    bottom, top = np.array([0.3, 1.0, 1.7]), np.array([0.9, 1.6, 2.3])
    streak = cells([5.0, 5.01, 5.02], np.array([50.0, 50.1, 50.2]))
    assert column_cells(streak, top, bottom, config).tolist() == [True, True, True]
    assert column_cells(streak, top, bottom, config.model_copy(update={"link_column_stack_m": 0.0})).tolist() == [False] * 3
    crown = cells([5.0, 5.01, 5.02], np.array([50.0, 50.5, 51.0]))
    assert column_cells(crown, top, bottom, config).tolist() == [False] * 3
    next_steps = cells([5.0, 5.0 + step, 5.0 + 2 * step], np.array([50.0, 50.1, 50.2]))
    assert column_cells(next_steps, top, bottom, config).tolist() == [False] * 3
    tall = column_cells(streak[:1], np.array([1.5]), np.array([0.3]), config)
    assert tall.tolist() == [True]                  # a cell a metre high is a column by itself


def test_walls_joined_from_single_columns_do_not_set_the_scans_typical_spread():
    """Seen at grazing incidence a wall's range noise lies along it, so a wall joined from single columns
    is thinner than the sensor's noise: it must not lower the spread a short wall is held to."""
    from featmap.extraction.vertical_structure import PieceMeasures, wall_segments

    n = 7
    along_x = np.column_stack([np.arange(n) * 30.0 + 10, np.full(n, 20.0)])
    a, b = along_x, along_x + [8.0, 0.0]
    b[-1] = a[-1] + [2.0, 0.0]                                    # the last piece: a short wall
    rms = np.array([0.02, 0.02, 0.02, 0.002, 0.002, 0.002, 0.035])
    chain = np.array([False, False, False, True, True, True, False])
    one = np.ones(n)

    def kept(column_chain):
        m = PieceMeasures(a=a, b=b, count=100 * one, n_points=100 * one, z_mean=0 * one, z_min=-1 * one,
                          z_max=2 * one, rms=rms, core=one, behind=0 * one, max_gap=0.3 * one,
                          column_curve=0 * one, column_chain=column_chain)
        return len(wall_segments(m, VerticalStructureConfig(), 0.2))

    assert kept(chain) == 7                       # typical 0.02 (the three head-on walls): 0.035 <= 2 x 0.02
    assert kept(None) == 6                        # typical 0.011 with the chains: the short wall is dropped


def test_sparse_walls_can_be_left_out_of_the_scans_typical_spread():
    """Walls sampled in columns metres apart (returns leaving gaps longer than max_gap_m) are as thin as
    the walls joined from single columns; with typical_spread_skips_sparse they do not lower the spread a
    short wall is held to either (by default, as in version 15, they do)."""
    from featmap.extraction.vertical_structure import PieceMeasures, wall_segments

    n = 7
    along_x = np.column_stack([np.arange(n) * 30.0 + 10, np.full(n, 20.0)])
    a, b = along_x, along_x + [8.0, 0.0]
    b[-1] = a[-1] + [2.0, 0.0]                                    # the last piece: a short wall
    rms = np.array([0.02, 0.02, 0.02, 0.002, 0.002, 0.002, 0.035])
    max_gap = np.array([0.3, 0.3, 0.3, 2.5, 2.5, 2.5, 0.3])       # three sparse walls
    one = np.ones(n)
    m = PieceMeasures(a=a, b=b, count=100 * one, n_points=100 * one, z_mean=0 * one, z_min=-1 * one,
                      z_max=2 * one, rms=rms, core=one, behind=0 * one, max_gap=max_gap, column_curve=0 * one)
    skip = wall_segments(m, VerticalStructureConfig(typical_spread_skips_sparse=True), 0.2)
    assert len(skip) == 7                         # typical 0.02 (the three dense walls): 0.035 <= 2 x 0.02
    assert len(wall_segments(m, VerticalStructureConfig(), 0.2)) == 6      # typical 0.011: the short wall goes


def test_far_walls_seen_obliquely_do_not_set_the_spread_a_near_wall_is_held_to():
    """A wall's returns scatter across it by the range noise times the cosine of its incidence: where most
    of a scan's long walls are far walls seen obliquely, their thin spread must not reject the near walls
    seen head-on (a street of apartment blocks: walls of 13,000 returns at 6-10 m were dropped)."""
    from featmap.extraction.vertical_structure import PieceMeasures, wall_segments

    def kept(n_head_on):
        oblique_a = np.column_stack([100.0 + 30 * np.arange(5), np.full(5, 20.0)])    # along x, 78-85 deg
        head_on_a = np.column_stack([10.0 + 5 * np.arange(n_head_on), np.full(n_head_on, -4.0)])   # along y
        a = np.vstack([oblique_a, head_on_a])
        b = np.vstack([oblique_a + [8.0, 0.0], head_on_a + [0.0, 8.0]])
        rms = np.r_[np.full(5, 0.002), np.full(n_head_on, 0.02)]
        one = np.ones(len(a))
        m = PieceMeasures(a=a, b=b, count=100 * one, n_points=100 * one, z_mean=0 * one, z_min=-1 * one,
                          z_max=2 * one, rms=rms, core=one, behind=0 * one, max_gap=0.3 * one,
                          column_curve=0 * one)
        return wall_segments(m, VerticalStructureConfig(), 0.2).segments

    assert len(kept(3)) == 8                        # the noise from the three head-on walls: 0.02
    kept_two = kept(2)                              # too few head-on walls: all long walls' median, 0.002
    assert len(kept_two) == 5 and np.all(kept_two[:, 1] == 20.0)


@pytest.mark.parametrize("points,message", [
    (np.array([[1.0, 2.0, np.nan, 0.0]] * 30), "1 point|30 point"),
    (np.zeros((30, 2)), "expected an \\(N, 3\\) or \\(N, 4\\) array"),
    (np.array([["a", "b", "c"]] * 30), "expected numbers"),
])
def test_bad_points_are_one_line_errors(points, message):
    with pytest.raises(FeatmapError, match=message):
        extract_vertical_structure(points)


def test_default_extraction_is_vertical_structure_and_ransac_stays_available():
    scan = cast_scan([building(20, -10, 35, 10)])
    assert ExtractionConfig().method_3d == "vertical_structure"
    assert np.array_equal(extract_scan(scan, 3, ExtractionConfig()).segments, extract_vertical_structure(scan).segments)
    ransac = extract_scan(scan, 3, ExtractionConfig(method_3d="ransac_planes"))
    assert len(ransac) >= 1 and on_line(ransac.segments[0], [20, -10], [20, 10], 0.1)


def test_config_model_behaves_like_every_config_section():
    assert issubclass(VerticalStructureConfig, Section)
    with pytest.raises(Exception, match="extra"):
        VerticalStructureConfig(no_such_key=1)


def test_timings_per_stage():
    timings: dict[str, float] = {}
    extract_vertical_structure(cast_scan([building(20, -10, 35, 10)]), timings=timings)
    assert set(timings) == {"crop", "ground", "level", "cells", "lines", "pieces", "walls"}


def test_a_scan_whose_structure_is_all_high_up_gives_its_wall():
    """Only the upper part of a tall far facade is seen (a 16-beam sensor driving away from it): no
    non-ground return is low enough to count as seen through a line (it used to fail on that); the facade,
    long and floating, is one wall."""
    rng = np.random.default_rng(0)
    gx, gy = np.meshgrid(np.linspace(-40, 40, 240), np.linspace(-40, 40, 240))
    ground = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, -1.73)])
    y, z = np.meshgrid(np.linspace(-10, 10, 200), np.linspace(0.8, 6.3, 12))
    wall = np.column_stack([np.full(y.size, 30.0) + rng.normal(0, 0.02, y.size), y.ravel(), z.ravel()])
    result = extract_vertical_structure(np.concatenate([ground, wall]))
    assert len(result) == 1 and on_line(result.segments[0], [30, -10], [30, 10], 0.05)


# Before walls seen 85-87 deg from head-on were linked (adopted 2026-12-03, docs/results.md): columns
# linked up to 85 deg, without the tests that sparse pieces now pass.
SPARSE_TESTS_OFF = dict(link_grazing_max_m=0.0, sparse_curve_factor=0.0, sparse_offset_factor=0.0, sparse_max_through=0.0)


def test_linking_columns_up_to_87_deg_finds_a_side_along_the_street_but_not_a_row_of_trees_behind():
    """A building's side along the street, 45-57 m ahead and 3 m to the right, is seen 86-87 deg from
    head-on (one column of returns per azimuth step, metres apart): linking columns up to 85 deg misses
    it. Linking up to 87 deg finds it, and without more tests also draws a line through a row of street
    trees 120-150 m behind, whose crowns stand one azimuth step apart in line with the ray. Each column of
    a wall is a straight line in height; a crown's curves with its round (sparse_curve_factor): the
    default finds the side and not the trees."""
    trees = [{"kind": "tree", "position": [-119.6 - 9.0 * k, -4.0 + 0.31 * k], "trunk_height": 2.4,
              "crown_radius": 2.5} for k in range(4)]
    scan = cast_scan(trees + [building(45, -13, 70, -3.0, 8.0)], sensor="vls128", noise=0.011, azimuth_step=0.235)

    def side(result):
        return [s for s in result.segments if on_line(s, [45, -3.0], [70, -3.0], 0.05) and min(s[0], s[2]) > 45.5]

    def behind(result):
        return [s for s in result.segments if max(s[0], s[2]) < -100]

    narrow = extract_vertical_structure(scan, VerticalStructureConfig(link_grazing_deg=85.0, **SPARSE_TESTS_OFF))
    assert side(narrow) == [] and behind(narrow) == []
    wide = extract_vertical_structure(scan, VerticalStructureConfig(link_grazing_deg=87.0, **SPARSE_TESTS_OFF, **LOOSE_SPREAD))
    assert len(side(wide)) == 1 and len(behind(wide)) == 1
    assert behind(extract_vertical_structure(scan, VerticalStructureConfig(**LOOSE_SPREAD))) == []   # the sparse tests
    default = extract_vertical_structure(scan)
    assert behind(default) == []
    assert len(side(default)) == 1 and abs(side(default)[0][2] - side(default)[0][0]) > 8.0


@pytest.mark.parametrize("setting, measures", [
    # Parked cars in a row, seen at grazing incidence, give columns of returns that each lie on a plane
    # but not on one: their mean offsets spread more than sparse_offset_factor times the spread within
    # them (plus sparse_offset_floor_m). A far wall's columns lie on one line.
    ({"sparse_offset_factor": 3.0}, {"sparse_curve": np.full(2, 0.005), "sparse_offset": np.array([0.002, 0.03]),
                                     "sparse_within": np.array([0.002, 0.003])}),
    # A row of trees or poles lined up like a wall lets most rays that cross its line go on beyond it; a
    # wall hides what is behind it.
    ({"sparse_max_through": 0.4}, {"through": np.array([0.05, 0.6])}),
], ids=["columns_not_coplanar", "lets_rays_through"])
def test_a_sparse_piece_failing_a_test_for_sparse_pieces_is_no_wall(setting, measures):
    """Of two pieces with gaps (sparse), the first passes the test ``setting`` turns on and the second
    does not; only sparse pieces are asked, and only when the test is on (it is by default)."""
    from featmap.extraction.vertical_structure import PieceMeasures, wall_segments

    one = np.ones(2)
    m = PieceMeasures(a=np.array([[40.0, 1.0], [40.0, -1.0]]), b=np.array([[50.0, 3.0], [50.0, -3.0]]),
                      count=100 * one, n_points=100 * one, z_mean=0 * one, z_min=-1 * one, z_max=2 * one,
                      rms=0.01 * one, core=one, behind=0 * one, max_gap=3.0 * one, column_curve=0 * one, **measures)
    only = VerticalStructureConfig(**{**SPARSE_TESTS_OFF, **setting})
    kept = wall_segments(m, only, 0.2)
    assert len(kept) == 1 and kept.segments[0][1] == pytest.approx(1.0)                    # the first one
    assert len(wall_segments(m, VerticalStructureConfig(**SPARSE_TESTS_OFF), 0.2)) == 2     # test off
    (name, value), = setting.items()
    assert getattr(VerticalStructureConfig(), name) == value                                # on by default
    dense = PieceMeasures(**{**m.__dict__, "max_gap": 0.5 * one})                           # no gap: not sparse
    assert len(wall_segments(dense, only, 0.2)) == 2


def test_a_facade_seen_obliquely_behind_a_row_of_poles_is_kept():
    """Poles in a row 6 m in front of a facade cut it into stretches with gaps, so its pieces are sparse,
    and every wall of the scan is seen 75-88 deg from head-on. A column's returns scatter along the wall by
    the range noise, its returns across the wall by that noise times the cosine of the incidence: the
    sparse_curve_factor bound takes the range noise from walls seen within 60 deg of head-on (here none),
    not from these oblique walls' spread, which would reject the facade."""
    poles = [{"kind": "pole", "position": [25.0 + 6.0 * k, -3.0], "radius": 0.15, "height": 6.0} for k in range(6)]
    scan = cast_scan(poles + [building(20, -15, 90, -9, 12.0)], sensor="vls128", azimuth_step=0.235)

    def facade(result):
        return [s for s in result.segments if on_line(s, [20, -9], [90, -9], 0.05)]

    assert len(facade(extract_vertical_structure(scan, VerticalStructureConfig(link_grazing_deg=85.0,
                                                                               **SPARSE_TESTS_OFF)))) >= 1
    found = facade(extract_vertical_structure(scan))
    assert sum(abs(s[2] - s[0]) for s in found) > 50.0


def test_grazing_links_can_be_capped_in_range():
    """Two columns one azimuth step apart 150 and 160 m away are linked as a wall seen 87 deg from
    head-on, unless link_grazing_max_m is below their 10 m difference in range."""
    from featmap.extraction.vertical_structure import _grazing_pairs

    step = 0.235
    az = np.deg2rad([10.0, 10.0 + step])
    points = np.column_stack([[150.0, 160.0] * np.cos(az), [150.0, 160.0] * np.sin(az)])
    config = VerticalStructureConfig(link_grazing_deg=87.0, link_grazing_max_m=0.0, link_azimuth_deg=3.33 * step)
    columns = np.ones(2, bool)
    assert _grazing_pairs(points, columns, config).tolist() == [[0, 1]]
    assert len(_grazing_pairs(points, columns, config.model_copy(update={"link_grazing_max_m": 8.0}))) == 0
    assert _grazing_pairs(points, columns, config.model_copy(update={"link_grazing_max_m": 12.0})).tolist() == [[0, 1]]


@pytest.mark.parametrize("range_step", [1.0, 1.8, 1.95, 1.99, 2.5, 4.0])
def test_two_columns_one_azimuth_step_apart_on_a_grazing_wall_are_neighbours_once(range_step):
    """Columns of a far wall seen about 83 deg from head-on lie one azimuth step apart and about 2 m apart
    in range: neighbours whether that is just below link_radial_m (2 m; outside the azimuth-and-range
    ellipse one step apart, so the grazing rule's: world 16's wall 134 was cut there) or above it, and
    listed once (a pair counted twice would weigh twice in the direction vote)."""
    from featmap.extraction.vertical_structure import neighbour_pairs

    step = 0.218
    az = np.deg2rad([-172.956, -172.956 - step])
    rng = np.array([60.8, 60.8 + range_step])
    points = np.column_stack([rng * np.cos(az), rng * np.sin(az)])
    config = VerticalStructureConfig(link_azimuth_deg=3.33 * step)
    assert neighbour_pairs(points, config, np.ones(2, bool)).tolist() == [[0, 1]]
    assert len(neighbour_pairs(points, config, np.zeros(2, bool))) == (range_step < 1.9)  # not columns


def test_a_garden_wall_behind_a_bush_goes_on_under_it():
    """A 2.2 m garden wall 15 m to the right, 10-35 m ahead; a bush (a crown on a short stem) 1-3 m in
    front of its western end hides it above 0.8 m for 4 m. Only returns 1 m up place a wall, so it came
    out in two pieces with the hidden stretch between them; its low returns there, whose rays above are
    stopped by the bush, carry it on (extend_hidden_m): one segment within 5 cm of the wall, end to end.
    A 1 m fence in line with it beyond its far end shows its top and is not joined."""
    bush = {"kind": "tree", "position": [12.0, -13.3], "trunk_height": 0.8, "trunk_radius": 0.1, "crown_radius": 1.4}
    fence = {"kind": "fence", "line": [[35, -15.0], [38, -15.0]], "height": 1.0}
    scan = cast_scan([building(10, -15.3, 35, -15.0, 2.2), fence, bush])
    result = extract_vertical_structure(scan)
    assert len(result) == 1
    seg = result.segments[0]
    assert on_line(seg, [10, -15], [35, -15], 0.05)
    assert sorted(seg[[0, 2]]) == pytest.approx([10, 35], abs=0.2)
    pieces = extract_vertical_structure(scan, VerticalStructureConfig(extend_hidden_m=0))
    assert len(pieces) == 2 and all(on_line(s, [10, -15], [35, -15], 0.05) for s in pieces.segments)
    assert pieces.segments[:, [0, 2]].max(1).min() < 12.5 and pieces.segments[:, [0, 2]].min(1).max() > 15


def _wall_with_low_returns(occluded: bool, fence_top: bool = False, gap_at: float | None = None):
    """A wall piece (5, 10)-(10, 10) and low returns on its line at x = 4.9 .. 2.0 every 0.1 m (0.5 m above
    a flat ground 1.73 m below the sensor); with ``occluded``, each has a return 1 m higher straight
    above its ray 20 % nearer (a bush in front); with ``fence_top``, a return 0.4 m higher on the line
    itself and one beyond it on the ray just above (a fence's top, seen: the next ray passes over it);
    ``gap_at``: no low return within 0.6 m of that x."""
    from featmap.extraction.base import ScanSegments

    x = np.round(np.arange(4.9, 1.95, -0.1), 2)
    if gap_at is not None:
        x = x[np.abs(x - gap_at) > 0.6]
    low = np.column_stack([x, np.full(len(x), 10.0), np.full(len(x), -1.23)])
    points, height = [low], [np.full(len(x), 0.5)]
    if occluded:
        points.append(np.column_stack([0.8 * low[:, :2], 0.8 * low[:, 2] + 1.0]))
        height.append(np.full(len(x), 1.5))
    if fence_top:
        points.append(low + [0, 0, 0.4])
        points.append(np.column_stack([1.5 * low[:, :2], 1.5 * (low[:, 2] + 0.6)]))   # seen over it, beyond
        height.append(np.full(len(x), 0.9))
        height.append(np.full(len(x), 1.5))
    wall = ScanSegments(segments=np.array([[5.0, 10.0, 10.0, 10.0]]), n_points=np.array([500]), rms=np.array([0.02]),
                        z_mean=np.array([0.0]), z_min=np.array([-1.5]), z_max=np.array([1.0]), max_gap=np.array([0.1]))
    return wall, np.concatenate(points), np.concatenate(height)


@pytest.mark.parametrize("occluded, fence_top, gap_at, start", [
    (True, False, None, 2.0),        # hidden above all along: 2.9 m (within extend_hidden_m = 3)
    (False, False, None, 5.0),       # nothing in front: its top is seen, no wall goes on
    (True, True, None, 5.0),         # a fence's top on the line is seen, the bush is higher up
    (True, False, 3.5, 4.2),         # a 1.4 m gap in the low returns (> max_gap_m) stops it
])
def test_walls_go_on_only_over_low_returns_hidden_above(occluded, fence_top, gap_at, start):
    from featmap.extraction.vertical_structure import extend_hidden_ends

    wall, xyz, height = _wall_with_low_returns(occluded, fence_top, gap_at)
    out = extend_hidden_ends(wall, xyz, height, VerticalStructureConfig())
    assert out.segments[0].tolist() == pytest.approx([start, 10.0, 10.0, 10.0], abs=1e-9)
    assert out.max_gap[0] == pytest.approx(0.1, abs=1e-9)    # no gap of the extension is longer
    assert extend_hidden_ends(wall, xyz, height, VerticalStructureConfig(extend_hidden_m=0)) is wall


def test_two_pieces_of_a_wall_whose_extensions_meet_become_one():
    """The second piece's end reaches the first one over hidden low returns: one wall on the line of the
    piece with more returns, over both; returns added, heights their extremes."""
    from featmap.extraction.base import ScanSegments
    from featmap.extraction.vertical_structure import extend_hidden_ends

    wall, xyz, height = _wall_with_low_returns(True)
    first = ScanSegments(segments=np.array([[-3.0, 10.02, 2.3, 10.0], [5.0, 10.0, 10.0, 10.0]]), n_points=np.array([100, 500]),
                         rms=np.array([0.03, 0.02]), z_mean=np.array([0.5, 0.0]), z_min=np.array([-1.6, -1.5]),
                         z_max=np.array([0.5, 1.0]), max_gap=np.array([0.2, 0.1]))
    out = extend_hidden_ends(first, xyz, height, VerticalStructureConfig())
    assert len(out) == 1
    assert out.segments[0].tolist() == pytest.approx([-3.0, 10.0, 10.0, 10.0], abs=1e-9)
    assert (out.n_points[0], out.z_min[0], out.z_max[0]) == (600, -1.6, 1.0)
    assert out.rms[0] == pytest.approx(np.sqrt((100 * 0.03 ** 2 + 500 * 0.02 ** 2) / 600))
    assert out.max_gap[0] == pytest.approx(0.2, abs=1e-9)    # the first piece's own (both went on and overlap)



def _hidden_low_returns(xs, y: float = 10.0):
    """Low returns at ``xs`` on the line y = ``y`` (0.5 m above a flat ground 1.73 m below the sensor),
    each hidden above by a return 1 m higher on its ray 20 % nearer: (N, 3) points and (N,) heights."""
    xs = np.asarray(xs, float)
    low = np.column_stack([xs, np.full(len(xs), y), np.full(len(xs), -1.23)])
    bush = np.column_stack([0.8 * low[:, :2], 0.8 * low[:, 2] + 1.0])
    return np.concatenate([low, bush]), np.concatenate([np.full(len(xs), 0.5), np.full(len(xs), 1.5)])


def _walls(segments, n_points=None):
    """ScanSegments of (K, 4) ``segments`` with 500 returns each (or ``n_points``) and max_gap 0.1 m."""
    from featmap.extraction.base import ScanSegments

    segments = np.asarray(segments, float)
    k = len(segments)
    return ScanSegments(segments=segments, n_points=np.asarray(n_points if n_points is not None else [500] * k),
                        rms=np.full(k, 0.02), z_mean=np.zeros(k), z_min=np.full(k, -1.5), z_max=np.ones(k),
                        max_gap=np.full(k, 0.1))


@pytest.mark.parametrize("xs, start, max_gap", [
    ([4.0, 3.0, 2.5], 2.5, 1.0),              # gaps of exactly max_gap_m, the first from the end, are crossed ...
    ([3.95, 3.5], 5.0, 0.1),                  # ... a longer one is not, even before the first return
    ([4.8, 4.3, 3.8], 3.8, 0.5),              # gaps of 0.5 m: max_gap grows to them
])
def test_an_end_goes_on_over_gaps_up_to_max_gap_m_and_records_them(xs, start, max_gap):
    from featmap.extraction.vertical_structure import extend_hidden_ends

    xyz, height = _hidden_low_returns(xs)
    out = extend_hidden_ends(_walls([[5.0, 10.0, 10.0, 10.0]]), xyz, height, VerticalStructureConfig())
    assert out.segments[0].tolist() == pytest.approx([start, 10.0, 10.0, 10.0], abs=1e-9)
    assert out.max_gap[0] == pytest.approx(max_gap, abs=1e-9)


def test_each_end_goes_on_by_itself_and_the_walls_stay_ordered_by_first_end():
    """Three walls, listed by first end: one that does not move (y = -20), one whose west end goes on
    from x = 4 to 2 (y = 30; it now comes first) and a short one (y = 20) whose east end goes on over
    three returns to 11.1 while its west end stops before a 1.2 m gap."""
    from featmap.extraction.vertical_structure import extend_hidden_ends

    xyz1, h1 = _hidden_low_returns([10.7, 10.9, 11.1, 8.8, 8.6], 20.0)
    xyz2, h2 = _hidden_low_returns(np.arange(3.8, 1.95, -0.2), 30.0)
    walls = _walls([[3.0, -20.0, 8.0, -20.0], [4.0, 30.0, 9.0, 30.0], [10.0, 20.0, 10.5, 20.0]])
    out = extend_hidden_ends(walls, np.concatenate([xyz1, xyz2]), np.concatenate([h1, h2]), VerticalStructureConfig())
    assert out.segments == pytest.approx(np.array([[2.0, 30.0, 9.0, 30.0], [3.0, -20.0, 8.0, -20.0],
                                                   [10.0, 20.0, 11.1, 20.0]]), abs=1e-9)


def test_three_walls_joined_over_overlaps_keep_the_gap_none_of_them_covers():
    """On y = 10: A 0-10 m (500 returns) goes on west to -0.5, B 5-12 m overlaps it, C 12.9-20 m goes on
    east to 21. A and B join (A moved), B and C join (0.9 m apart, C moved): one wall on A's line from
    -0.5 to 21 whose max_gap is the 0.9 m between B and C (covered neither by A nor B)."""
    from featmap.extraction.vertical_structure import extend_hidden_ends

    xyz, height = _hidden_low_returns([-0.5, 20.5, 21.0])
    walls = _walls([[0.0, 10.0, 10.0, 10.0], [5.0, 10.0, 12.0, 10.0], [12.9, 10.0, 20.0, 10.0]], [500, 100, 200])
    out = extend_hidden_ends(walls, xyz, height, VerticalStructureConfig())
    assert out.segments == pytest.approx(np.array([[-0.5, 10.0, 21.0, 10.0]]), abs=1e-9)
    assert (out.n_points.tolist(), out.max_gap[0]) == ([800], pytest.approx(0.9, abs=1e-9))


def test_a_short_wall_whose_bottom_is_hidden_by_a_fence_in_front_is_found_with_short_hidden_below():
    """A 2.5 m house front 40 m away behind a 3 m long, 1.7 m high fence at 15 m is seen from 1.7 m up (the
    ground beside it is seen, so it stands 1.3 m above it): a short piece that floats like a crown, so
    without ``short_hidden_below`` it is no wall. Its bottom is hidden (the returns just below it in
    its direction are the fence's, 25 m nearer); under a crown the rays pass. By default (the setting on)
    it is one segment within 5 cm; the crowns beside it, with nothing in front, still float."""
    trees = [{"kind": "tree", "position": [38.0, 8.0 + 4 * k], "trunk_height": 2.2, "crown_radius": 1.4}
             for k in range(3)]
    fence = {"kind": "fence", "line": [[15, -1.5], [15, 1.5]], "height": 1.7}
    objects = [building(40, -1.25, 46, 1.25, 6.0), fence, *trees]
    scan = cast_scan(objects, sensor="vls128", azimuth_step=0.2)
    house = (np.abs(scan[:, 0] - 40) < 0.1) & (np.abs(scan[:, 1]) < 1.2)
    assert scan[house, 2].min() + SENSORS["vls128"].height_m > 1.2     # its lower part is hidden by the fence
    off = extract_vertical_structure(scan, VerticalStructureConfig(short_hidden_below=False))
    assert not any(on_line(s, [40, -1.25], [40, 1.25], 0.1) for s in off.segments)
    result = extract_vertical_structure(scan)
    front = [s for s in result.segments if on_line(s, [40, -1.25], [40, 1.25], 0.05)]
    assert len(front) == 1 and abs(front[0][3] - front[0][1]) > 2.0
    for seg in result.segments:                                   # nothing on the crowns or the fence
        assert on_line(seg, [40, -1.25], [40, 1.25], 0.1), seg


def test_a_short_wall_whose_top_is_cut_by_a_crown_in_front_is_found_by_default_and_not_without_cut_above():
    """A 2.5 m house front 40 m away seen under the crown of a tree at 25 m: only its lowest 1.8 m are seen
    (lower than tall_m, and it does not reach the top beam). Its top is cut (the returns just above it in
    its direction are the crown's, 15 m nearer), so by default (``cut_above_counts_as_tall``) it is one
    segment within 5 cm, and without that setting it is no wall; a car behind the other tree's crown, whose
    top the rays just above pass over, is no wall either way."""
    trees = [{"kind": "tree", "position": [25.0, y], "trunk_height": 2.2, "crown_radius": 2.5} for y in (0.0, 8.0)]
    car = {"kind": "car", "position": [40.0, 16.0], "heading_deg": 90.0}
    scan = cast_scan([building(40, -1.25, 46, 1.25, 8.0), car, *trees], sensor="vls128", azimuth_step=0.2)
    house = (np.abs(scan[:, 0] - 40) < 0.1) & (np.abs(scan[:, 1]) < 1.2)
    assert 1.5 < scan[house, 2].max() + SENSORS["vls128"].height_m < 2.1         # seen up to ~1.8 m only
    assert len(extract_vertical_structure(scan, VerticalStructureConfig(cut_above_counts_as_tall=False))) == 0
    result = extract_vertical_structure(scan)
    assert len(result) == 1
    assert on_line(result.segments[0], [40, -1.25], [40, 1.25], 0.05)
    assert abs(result.segments[0][3] - result.segments[0][1]) > 2.0


def test_a_trunk_beside_the_underside_of_its_crown_is_no_wall_but_an_upper_storey_over_a_roof_is():
    """Street trees 7 m to each side, 12-66 m ahead (2.8 m trunks, 2.4 m crowns), seen by a vls128 at
    0.34 deg with 2.9 cm noise: at 39 m a trunk (one column from the ground) and the underside of its crown
    curving towards the sensor beside it (slivers 2.4-3.4 m up) line up as a 1.9 m piece that reaches
    down and is as tall as a van. Without ``floating_min_top_m`` it is a wall; by default it floats in half
    of its columns, in low thin slivers, and is none. A 5 m wide upper storey 30 m away, seen 3.5-9 m up
    over a 3 m roof in front, floats in every column too and is one segment within 5 cm, as is the roof's
    front wall."""
    trees = [{"kind": "tree", "position": [float(x), side * 7.0], "trunk_height": 2.8, "crown_radius": 2.4}
             for x in range(12, 70, 9) for side in (1, -1)]
    scan = cast_scan(trees, sensor="vls128", azimuth_step=0.34, noise=0.029)
    off = extract_vertical_structure(scan, VerticalStructureConfig(floating_min_top_m=0.0))
    assert len(off) == 1 and on_line(off.segments[0], [37.0, -6.4], [39.0, -7.0], 0.2)
    assert len(extract_vertical_structure(scan)) == 0

    scan = cast_scan([building(30, -2.5, 36, 2.5, 9.0), building(20, -6, 28, 6, 3.0)], sensor="vls128",
                     azimuth_step=0.34, noise=0.029)
    storey = (np.abs(scan[:, 0] - 30) < 0.1) & (np.abs(scan[:, 1]) < 2.4)
    assert scan[storey, 2].min() + SENSORS["vls128"].height_m > 3.0          # its lower part is hidden
    result = extract_vertical_structure(scan)
    assert len(result) == 2
    assert on_line(result.segments[1], [30, -2.5], [30, 2.5], 0.05) and abs(result.segments[1][3] - result.segments[1][1]) > 4.5
    assert on_line(result.segments[0], [20, -6], [20, 6], 0.05)


def test_a_trunk_straddling_two_of_three_columns_is_no_wall_and_short_walls_stay():
    """Street trees 7 m to each side, 12-52 m ahead (2.8 m trunks, 1.8 m crowns), seen by a vls128 at 0.4 deg
    with 2.6 cm noise: without ``trunk_max_share`` (0) three 1-1.7 m pieces of a trunk and the underside of
    its crown are walls (the trunk reaches down in two of their three 0.5 m columns, so
    ``floating_min_top_m`` keeps them); with the default 0.5 (their cells reach down over less than half of
    their length, beside low thin slivers) there are none. A 2 m house front and the 2 m side of a building,
    which reach down along all of their length, are the same segments with the setting as without it."""
    assert VerticalStructureConfig().trunk_max_share == 0.5
    trees = [{"kind": "tree", "position": [float(x), side * 7.0], "trunk_height": 2.8, "crown_radius": 1.8}
             for x in range(12, 60, 8) for side in (1, -1)]
    scan = cast_scan(trees, sensor="vls128", azimuth_step=0.4, noise=0.026)
    off = extract_vertical_structure(scan, VerticalStructureConfig(trunk_max_share=0.0))
    assert len(off) == 3
    assert all(1.0 < np.hypot(*(s[2:] - s[:2])) < 1.8 and 5.5 < min(abs(s[1]), abs(s[3])) and max(abs(s[1]), abs(s[3])) < 8.5
               for s in off.segments)                                      # at the trees
    assert len(extract_vertical_structure(scan)) == 0

    walls = [building(20, -1.0, 24, 1.0, 3.0), building(30, 6, 34, 8, 8.0)]
    for sensor, step in (("hdl64", 0.4), ("vls128", 0.2)):
        scan = cast_scan(walls, sensor=sensor, azimuth_step=step)
        plain = extract_vertical_structure(scan, VerticalStructureConfig(trunk_max_share=0.0))
        ruled = extract_vertical_structure(scan)
        assert any(on_line(s, [20, -1], [20, 1], 0.05) for s in ruled.segments)
        assert any(on_line(s, [30, 6], [30, 8], 0.05) for s in ruled.segments)
        assert ruled.segments == pytest.approx(plain.segments)


def test_a_far_wall_cut_by_a_single_beam_is_one_segment_within_5_cm_but_far_street_trees_stay_none():
    """A 32 m facade 95 m ahead, 5 m high, seen by a vlp16 at 0.13 deg: its beams lie 3.3 m apart in height
    there, so only the +1 deg beam hits it (3.4 m up; the -1 deg one meets its foot at the ground), and its
    returns span nothing in height. Longer than ``one_ring_min_length_m``, at a range where the beams lie
    farther apart than ``min_span_m``, and higher than ``tall_m``, it is one segment within 5 cm; without the
    rule it is none. A row of street trees 60-95 m away, cut by single beams at crown height, stays none."""
    scan = cast_scan([building(95, -16, 110, 16, 5.0)], sensor="vlp16", azimuth_step=0.13)
    facade = np.abs(scan[:, 0] - 95) < 0.3
    heights = scan[facade, 2] + SENSORS["vlp16"].height_m
    assert heights.max() == pytest.approx(3.4, abs=0.1) and (heights > 0.5).sum() > 140     # one beam, every step
    assert len(extract_vertical_structure(scan, VerticalStructureConfig(one_ring_min_length_m=0.0))) == 0
    result = extract_vertical_structure(scan)
    assert len(result) == 1
    assert on_line(result.segments[0], [95, -16], [95, 16], 0.05)
    assert abs(result.segments[0][3] - result.segments[0][1]) > 30
    assert result.z_max[0] - result.z_min[0] < 0.3

    for x in (60.0, 80.0, 95.0):
        trees = [{"kind": "tree", "position": [x, float(y)], "trunk_height": 2.8, "crown_radius": 2.4}
                 for y in np.arange(-24, 24, 4.5)]
        assert len(extract_vertical_structure(cast_scan(trees, sensor="vlp16", azimuth_step=0.13))) == 0
