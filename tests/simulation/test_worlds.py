import json

import pytest

from featmap.errors import WorldError
from featmap.simulation.worlds import builtin_worlds, building_edges, load_world

BASE = "name: t\nroute: {waypoints: [[0, 0], [10, 0]]}\nobjects:\n"


@pytest.mark.parametrize("obj,match", [
    ("  - {id: bow, kind: building, footprint: [[0, 0], [10, 10], [10, 0], [0, 10]]}",
     r"w.yaml: object 'bow' \(building\): invalid footprint \(Self-intersection"),
    ("  - {id: low, kind: building, footprint: [[0, 0], [10, 0], [10, 10]], height: -3}",
     r"w.yaml: object 'low' \(building\): 'height' input should be greater than 0"),
    ("  - {id: ufo, kind: spaceship, position: [1, 2]}",
     r"w.yaml: object 'ufo' \('?spaceship'?\): unknown kind 'spaceship'; allowed: building, fence, car, pole, tree"),
    ("  - {kind: car}", r"w.yaml: object #0 \(car\): 'position' field required"),
    ("  - {id: flat, kind: car, position: [5, 5], size: [-4, 0, 1.5]}",
     r"w.yaml: object 'flat' \(car\): 'size.0' input should be greater than 0"),
    ("  - {id: lost, kind: pole, position: [.nan, 5]}", r"w.yaml: object 'lost' \(pole\): 'position.0' input should be a finite number"),
])
def test_bad_world_files_name_the_file_and_the_object(tmp_path, obj, match):
    path = tmp_path / "w.yaml"
    path.write_text(BASE + obj + "\n")
    with pytest.raises(WorldError, match=match) as info:
        load_world(path)
    assert "\n" not in str(info.value)


def test_a_non_finite_route_is_one_line(tmp_path):
    path = tmp_path / "w.yaml"
    path.write_text("name: t\nroute: {waypoints: [[-10, .nan], [20, 0]], speed_mps: .inf}\n")
    with pytest.raises(WorldError, match=r"w.yaml: 'route.waypoints.0.1' input should be a finite number"):
        load_world(path)


@pytest.mark.parametrize("route,match", [
    ("{waypoints: [[0, 0], [1.0e300, 0]]}", r"w.yaml: 'route.waypoints.1.0' input should be less than or equal to 1000000"),
    ("{waypoints: [[0, 0], [0, -2.0e6]]}", r"w.yaml: 'route.waypoints.1.1' input should be greater than or equal to -1000000"),
])
def test_coordinates_beyond_1000_km_are_one_line(tmp_path, route, match):
    """1e300 used to pass and overflow inside the route's rounding (OverflowError: cannot convert float
    infinity to integer)."""
    path = tmp_path / "w.yaml"
    path.write_text(f"name: t\nroute: {route}\n")
    with pytest.raises(WorldError, match=match):
        load_world(path)
    path.write_text(BASE + "  - {id: far, kind: pole, position: [5, 1.0e7]}\n")
    with pytest.raises(WorldError, match=r"object 'far' \(pole\): 'position.1' input should be less than or equal"):
        load_world(path)


def test_a_key_given_twice_in_a_world_file_is_one_line_naming_the_line(tmp_path):
    """Read as strictly as a config file: PyYAML alone keeps the last 'height' without a word."""
    path = tmp_path / "w.yaml"
    path.write_text(BASE + "  - {id: A, kind: building, footprint: [[0, 0], [10, 0], [10, 10]],\n"
                           "     height: 12, height: 3}\n")
    with pytest.raises(WorldError, match=r"w.yaml:5: not valid YAML \('height' is given twice\)") as info:
        load_world(path)
    assert "\n" not in str(info.value)


def test_exponent_numbers_in_a_world_file_are_numbers(tmp_path):
    """1e3 and 5e-1 without a dot are numbers, as in a config file (YAML 1.1 reads them as strings, and an
    integer field such as a hedge's seed refused the string)."""
    path = tmp_path / "w.yaml"
    path.write_text(BASE + "  - {id: h, kind: hedge, line: [[0, -4], [1e1, -4]], height: 5e-1, seed: 1e3}\n")
    hedge = load_world(path).of_kind("hedge")[0]
    assert (hedge.line, hedge.height, hedge.seed) == ([(0.0, -4.0), (10.0, -4.0)], 0.5, 1000)


def test_builtin_worlds_load_and_label_vertices():
    assert {"residential", "prescan_case1", "prescan_case2"} <= set(builtin_worlds())
    case1 = load_world("prescan_case1")
    edges = building_edges(case1)
    assert [(e["label_p"], e["label_q"]) for e in edges] == [("a", "b"), ("b", "c"), ("c", "d"), ("d", "a")]
    res = load_world("residential")
    assert len(res.buildings) > 30 and res.of_kind("fence") and res.of_kind("car")


def test_geojson_world_like_an_openstreetmap_export(tmp_path):
    lat, lon = 49.0, 8.4
    d = 1e-4
    fc = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"kind": "route"},
         "geometry": {"type": "LineString", "coordinates": [[lon, lat], [lon + 4 * d, lat]]}},
        {"type": "Feature", "properties": {"building": "yes", "building:levels": 3},
         "geometry": {"type": "Polygon", "coordinates": [[[lon, lat + d], [lon + d, lat + d], [lon + d, lat + 2 * d],
                                                          [lon, lat + 2 * d], [lon, lat + d]]]}},
    ]}
    path = tmp_path / "osm.geojson"
    path.write_text(json.dumps(fc))
    world = load_world(path)
    assert len(world.buildings) == 1 and world.buildings[0].height == 9.0
    xs = [p[0] for p in world.buildings[0].footprint]
    assert max(xs) - min(xs) == pytest.approx(d * 3.14159265 / 180 * 6378137 * 0.656, rel=0.01)


def test_unknown_world_name_lists_builtins():
    with pytest.raises(WorldError, match="built-in worlds: .*residential"):
        load_world("atlantis")


def test_malformed_geojson_world_is_one_line(tmp_path):
    path = tmp_path / "bad.geojson"
    path.write_text('{"type": "FeatureCollection", "features": [{"properties": {"kind": "route"}, "geometry": {}}]}')
    with pytest.raises(WorldError, match="bad.geojson: malformed GeoJSON feature"):
        load_world(path)
    path.write_text('{"type": "FeatureCollection", "features": [')
    with pytest.raises(WorldError, match=r"bad.geojson:1: not valid JSON"):
        load_world(path)
    route = '{"type": "FeatureCollection", "features": [{"properties": {"kind": "route"}, "geometry": {"coordinates": [%s]}}]}'
    path.write_text(route % "[8.4, NaN], [8.5, 49.0]")
    with pytest.raises(WorldError, match=r"bad.geojson: malformed GeoJSON feature \(ValueError: NaN is not a finite number\)"):
        load_world(path)
    path.write_text(route % "[8.4, 91.0], [8.5, 49.0]")
    with pytest.raises(WorldError, match=r"bad.geojson: the route's first position: geo origin latitude 91 is outside"):
        load_world(path)


def test_a_world_extends_another_with_its_own_route(tmp_path):
    base = load_world("residential")
    cross = load_world("residential_cross")
    assert cross.objects == base.objects and cross.geo_origin == base.geo_origin
    assert cross.route.waypoints[0] == (80.0, -50.0) and cross.name == "residential_cross"
    (tmp_path / "base.yaml").write_text("name: base\nroute: {waypoints: [[0, 0], [10, 0]]}\ngeo_origin: {lat: 48, lon: 9}\n"
                                        "objects:\n  - {kind: pole, position: [1, 2]}\n")
    (tmp_path / "more.yaml").write_text("extends: base.yaml\nroute: {waypoints: [[10, 0], [0, 0]]}\n"
                                        "objects:\n  - {kind: tree, position: [3, 4]}\n")
    more = load_world(tmp_path / "more.yaml")
    assert [o.kind for o in more.objects] == ["pole", "tree"] and more.geo_origin.lat == 48 and more.name == "more"


@pytest.mark.parametrize("text,match", [
    ("extends: base.yaml\n", r"needs its own 'route'"),
    ("extends: nowhere\nroute: {waypoints: [[0, 0], [1, 0]]}\n", r"unknown world 'nowhere'"),
    ("extends: loop.yaml\nroute: {waypoints: [[0, 0], [1, 0]]}\n", r"makes a cycle"),
    ("extends: 3\nroute: {waypoints: [[0, 0], [1, 0]]}\n", r"'extends' must be a built-in world name or a world file"),
])
def test_bad_extends_is_one_line(tmp_path, text, match):
    (tmp_path / "base.yaml").write_text("name: base\nroute: {waypoints: [[0, 0], [10, 0]]}\n")
    (tmp_path / "loop.yaml").write_text(text)
    with pytest.raises(WorldError, match=match):
        load_world(tmp_path / "loop.yaml")


def test_a_repeated_footprint_vertex_makes_no_zero_length_wall():
    """OSM exports repeat vertices: each wall is still one edge, none of zero length."""
    import numpy as np

    from featmap.simulation.worlds import world_from_dict

    def world(footprint):
        return world_from_dict({"name": "w", "route": {"waypoints": [[-20, -5], [40, -5]]},
                                "objects": [{"kind": "building", "footprint": footprint, "height": 8}]}, "w.yaml")

    plain = building_edges(world([[0, 0], [20, 0], [20, 10], [0, 10]]))
    repeated = building_edges(world([[0, 0], [20, 0], [20, 0], [20, 10], [0, 10], [0, 10], [0, 0]]))
    assert len(repeated) == len(plain) == 4
    assert all(np.hypot(*(np.asarray(e["q"]) - e["p"])) > 1 for e in repeated)


def test_with_porous_foliage_changes_the_crowns_and_hedges_only():
    from featmap.simulation.worlds import with_porous_foliage, world_from_dict

    world = world_from_dict({
        "name": "w", "route": {"waypoints": [[0, 0], [40, 0]]},
        "objects": [{"id": "A", "kind": "building", "height": 8, "footprint": [[0, 5], [10, 5], [10, 9], [0, 9]]},
                    {"id": "t", "kind": "tree", "position": [5, -5]},
                    {"id": "h", "kind": "hedge", "line": [[0, -3], [8, -3]]},
                    {"id": "f", "kind": "fence", "line": [[0, -4], [8, -4]]}]}, "w.yaml")
    porous = with_porous_foliage(world, 0.3, 0.4, 0.1, 0.2)
    by_id = {o.id: o for o in porous.objects}
    assert (by_id["t"].crown_porosity, by_id["t"].crown_depth_m) == (0.3, 0.4)
    assert (by_id["h"].porosity, by_id["h"].depth_m) == (0.1, 0.2)
    assert by_id["A"] == world.objects[0] and by_id["f"] == world.objects[3]
    assert world.objects[1].crown_porosity == 0.0          # the original is left as it was


def test_with_drawn_foliage_draws_each_crown_and_hedge_in_its_range_and_repeats_per_seed():
    from featmap.simulation.worlds import DRAWN_FOLIAGE, with_drawn_foliage, world_from_dict

    world = world_from_dict({
        "name": "w", "route": {"waypoints": [[0, 0], [40, 0]]},
        "objects": [{"id": "A", "kind": "building", "height": 8, "footprint": [[0, 5], [10, 5], [10, 9], [0, 9]]},
                    *({"id": f"t{k}", "kind": "tree", "position": [4 * k, -5]} for k in range(20)),
                    {"id": "h", "kind": "hedge", "line": [[0, -3], [8, -3]]},
                    {"id": "f", "kind": "fence", "line": [[0, -4], [8, -4]]}]}, "w.yaml")
    drawn = with_drawn_foliage(world, 7)
    assert drawn == with_drawn_foliage(world, 7) and drawn != with_drawn_foliage(world, 8)
    trees = [o for o in drawn.objects if o.kind == "tree"]
    for key, (low, high) in DRAWN_FOLIAGE["tree"].items():
        values = [getattr(t, key) for t in trees]
        assert all(low <= v <= high for v in values)
        assert len(set(values)) > len(trees) // 2            # each crown its own
    hedge = next(o for o in drawn.objects if o.kind == "hedge")
    assert all(low <= getattr(hedge, key) <= high for key, (low, high) in DRAWN_FOLIAGE["hedge"].items())
    assert drawn.objects[0] == world.objects[0] and drawn.objects[-1] == world.objects[-1]   # building, fence
    assert world.objects[1].crown_porosity == 0.0            # the original is left as it was


def test_the_world_files_in_configs_load():
    from pathlib import Path

    folder = Path(__file__).resolve().parents[2] / "configs" / "worlds"
    for path in sorted(folder.glob("*.yaml")):
        world = load_world(str(path))
        assert world.name == path.stem and world.buildings and len(world.route.waypoints) >= 2
