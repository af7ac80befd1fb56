"""Procedurally generated streets: a new, validated :class:`World` (and how to simulate it) per seed.

``generate_world(seed)`` builds a street scene the way real residential and urban streets look:

- a main street (carriageway 7-11 m, sidewalks 1.5-4 m) with one or two perpendicular side
  streets (crossings or T-junctions);
- blocks along every street edge, each filled in one style: rows of small houses (6-12 m wide,
  3-9 m high, rectangles and L-shapes, front setbacks of 2-9 m that vary house to house, gaps of
  2-3 m or wider), apartment blocks (20-45 m wide, 10-30 m high, some with a courtyard), or a
  mix; a second row of buildings behind the first, seen through the gaps;
- far walls: buildings closing the street's ends and the side streets 50-100 m from the route;
- clutter: parked cars along the curbs, fences and hedges along the front gardens, street lights
  and sign poles, trees on the sidewalks and in the gardens;
- a sloped ground (grade 0-5 % in any direction) with 10-15 cm curbs along every street;
- a route along the main street's right lane, turning into a side street in about half of the
  worlds, 20-26 s of driving at 6-10 m/s;
- the whole scene rotated by a random angle (walls are not axis-aligned).

``generate(seed)`` also chooses how to simulate it (:class:`DriveSettings`): the sensor cycles
through hdl64, vlp32, vls128 and vlp16 with the seed, with an azimuth step of 0.1-0.4 deg (0.2-0.4
for the 128-beam sensor, to keep scans below ~230k points), range noise 1-3 cm and dropout 0-10 %.

Which seeds are tuning, probe and held-out worlds is in :mod:`featmap.simulation.splits`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from featmap.simulation.sensors import SENSORS, SensorPreset
from featmap.simulation.worlds import World, world_from_dict

SENSOR_CYCLE = ("hdl64", "vlp32", "vls128", "vlp16")
AZIMUTH_STEP_RANGE_DEG = {"hdl64": (0.1, 0.4), "vlp32": (0.1, 0.4), "vls128": (0.2, 0.4), "vlp16": (0.1, 0.4)}


@dataclass(frozen=True)
class DriveSettings:
    """How to simulate a generated world (the arguments of ``simulate_drive``).

    Attributes:
        sensor: the sensor preset with this world's azimuth step.
        noise_m: standard deviation of the range noise (metres).
        dropout: probability that a return is lost.
        seed: seed of the simulation's random draws (noise, dropout).
    """

    sensor: SensorPreset
    noise_m: float
    dropout: float
    seed: int


@dataclass(frozen=True)
class GeneratedDrive:
    """A generated world and how to simulate it."""

    seed: int
    world: World
    settings: DriveSettings


def generate_world(seed: int) -> World:
    """The validated world of ``seed`` (the same seed always gives the same world)."""
    rng = np.random.default_rng([int(seed), 18])
    scene = _StreetScene(rng)
    scene.build()
    return world_from_dict(scene.to_dict(f"procedural_{seed}", seed), f"procedural world {seed}")


def drive_settings(seed: int) -> DriveSettings:
    """Sensor, azimuth step, noise and dropout of ``seed``'s world (drawn apart from its geometry)."""
    rng = np.random.default_rng([int(seed), 18, 1])
    name = SENSOR_CYCLE[int(seed) % len(SENSOR_CYCLE)]
    lo, hi = AZIMUTH_STEP_RANGE_DEG[name]
    sensor = SENSORS[name].with_azimuth_step(round(float(rng.uniform(lo, hi)), 3))
    return DriveSettings(sensor=sensor, noise_m=round(float(rng.uniform(0.01, 0.03)), 4),
                         dropout=round(float(rng.uniform(0.0, 0.10)), 3), seed=int(seed))


def generate(seed: int) -> GeneratedDrive:
    """World and simulation settings of ``seed``."""
    return GeneratedDrive(int(seed), generate_world(seed), drive_settings(seed))


# --- the scene, built in a street frame (x along the main street, y to its left), then rotated ------

class _StreetScene:
    def __init__(self, rng: np.random.Generator):
        self.rng = rng
        self.buildings: list[dict] = []
        self.clutter: list[dict] = []
        self.streets: list[dict] = []          # {"line": [(x, y), ...], "width": w, "sidewalk": s}
        self.route: list[tuple[float, float]] = []
        self._footprints: list = []            # shapely polygons of accepted buildings
        self._clutter_shapes: list = []

    # -- layout -----------------------------------------------------------------------------------
    def build(self) -> None:
        rng = self.rng
        self.road_w = float(rng.uniform(7.0, 11.0))
        self.sidewalk = float(rng.uniform(1.5, 4.0))
        self.speed = float(rng.uniform(6.0, 10.0))
        drive_len = float(rng.uniform(20.0, 26.0)) * self.speed
        # one or two side streets, at least 45 m apart, along the drive
        n_side = int(rng.integers(1, 3))
        xs: list[float] = []
        for _ in range(50):
            if len(xs) == n_side:
                break
            x = float(rng.uniform(45.0, max(50.0, drive_len - 25.0)))
            if all(abs(x - other) > 45.0 for other in xs):
                xs.append(x)
        self.side_streets = [{"x": x, "kind": str(rng.choice(["cross", "left", "right"])),
                              "width": float(rng.uniform(6.0, 9.0)), "length": float(rng.uniform(70.0, 110.0))}
                             for x in sorted(xs)]

        # the route: the main street's right lane (driving +x), perhaps turning into a side street
        lane_y = -self._lane_offset(self.road_w)
        self.route = [(0.0, lane_y)]
        turn = rng.random() < 0.5
        candidates = [st for st in self.side_streets if st["x"] + 20.0 < drive_len]
        if turn and candidates:
            st = candidates[int(rng.integers(len(candidates)))]
            go_left = st["kind"] == "left" or (st["kind"] == "cross" and rng.random() < 0.5)
            sign = 1.0 if go_left else -1.0
            x_lane = st["x"] + sign * self._lane_offset(st["width"])      # the right lane of the side street
            along = min(max(30.0, drive_len - st["x"]), st["length"] - 25.0)
            self.route += [(x_lane, lane_y), (x_lane, lane_y + sign * along)]
            self.main_end = st["x"] + float(rng.uniform(40.0, 90.0))
        else:
            self.route.append((drive_len, lane_y))
            self.main_end = drive_len + float(rng.uniform(50.0, 90.0))
        self.turn_radius = float(rng.uniform(6.0, 10.0))
        self.main_start = -float(rng.uniform(50.0, 80.0))

        # carriageways: the main street, and the side streets from its centre line to near their ends
        self._add_street([(self.main_start + 2.0, 0.0), (self.main_end - 2.0, 0.0)], self.road_w)
        for st in self.side_streets:
            end = st["length"] - 2.0
            y0 = -end if st["kind"] in ("cross", "right") else 0.0
            y1 = end if st["kind"] in ("cross", "left") else 0.0
            self._add_street([(st["x"], y0), (st["x"], y1)], st["width"])
        self._street_union()

        # far walls first: buildings closing the main street's two ends and every side street
        self._closing_building(self.main_end, 0.0, "-x", float(rng.uniform(30, 60)))
        self._closing_building(self.main_start, 0.0, "+x", float(rng.uniform(30, 60)))
        for st in self.side_streets:
            if st["kind"] in ("cross", "left"):
                self._closing_building(st["x"], st["length"], "-y", float(rng.uniform(25, 50)))
            if st["kind"] in ("cross", "right"):
                self._closing_building(st["x"], -st["length"], "+y", float(rng.uniform(25, 50)))

        # blocks along both sides of the main street, cut where a side street leaves on that side
        for side in (+1, -1):
            cuts = sorted((st["x"], st["width"]) for st in self.side_streets
                          if st["kind"] == "cross" or (st["kind"] == "left") == (side > 0))
            x_from = self.main_start + 2.0
            for x, w in cuts + [(self.main_end - 2.0, None)]:
                x_to = x if w is None else x - (w / 2 + self.sidewalk + 1.0)
                if x_to - x_from > 8.0:
                    self._fill_block("x", x_from, x_to, side * (self.road_w / 2 + self.sidewalk), side)
                if w is not None:
                    x_from = x + w / 2 + self.sidewalk + 1.0
        # blocks along both sides of every side street
        for st in self.side_streets:
            for direction in (+1, -1):
                if (direction > 0 and st["kind"] == "right") or (direction < 0 and st["kind"] == "left"):
                    continue
                for face in (+1, -1):
                    self._fill_block("y", self.road_w / 2 + self.sidewalk + 1.0, st["length"] - 4.0,
                                     st["x"] + face * (st["width"] / 2 + self.sidewalk), face, direction)
        self._street_clutter()
        self.grade = self._grade()
        self.curb = float(rng.uniform(0.10, 0.15))
        self.angle = float(rng.uniform(0.0, 2 * np.pi))

    @staticmethod
    def _lane_offset(width: float) -> float:
        """Distance from a street's centre line to the middle of its right lane, beside a parking lane."""
        return max(0.0, width / 2 - 3.3)

    def _grade(self) -> tuple[float, float]:
        rng = self.rng
        if rng.random() < 0.2:
            return (0.0, 0.0)
        g = float(rng.uniform(0.005, 0.05))
        a = float(rng.uniform(0.0, 2 * np.pi))
        return (g * np.cos(a), g * np.sin(a))

    def _add_street(self, line, width) -> None:
        self.streets.append({"line": [tuple(map(float, p)) for p in line], "width": float(width)})

    def _street_union(self) -> None:
        from shapely import union_all
        from shapely.geometry import LineString

        self.street_area = union_all([LineString(s["line"]).buffer(s["width"] / 2 + self.sidewalk, cap_style="flat",
                                                                   join_style="mitre") for s in self.streets])
        self.carriageway = union_all([LineString(s["line"]).buffer(s["width"] / 2, cap_style="flat", join_style="mitre")
                                      for s in self.streets])

    # -- buildings ----------------------------------------------------------------------------------
    def _try_building(self, poly, height: float, kind: str, min_gap: float = 1.95) -> bool:
        """Accept a footprint if it leaves the streets and sidewalks free and keeps ``min_gap`` to others."""
        if not poly.is_valid or poly.area < 12.0:
            return False
        if poly.intersects(self.street_area):
            return False
        if any(poly.distance(other) < min_gap for other in self._footprints):
            return False
        self._footprints.append(poly)
        self.buildings.append({"poly": poly, "height": round(float(height), 2), "kind": kind})
        return True

    def _closing_building(self, cx: float, cy: float, facing: str, width: float) -> None:
        """A wide building across a street's end whose front faces the street (a far wall)."""
        from shapely.geometry import box

        rng = self.rng
        depth = float(rng.uniform(10.0, 18.0))
        height = float(rng.uniform(8.0, 25.0))
        gap = self.sidewalk + 2.5
        if facing == "-x":
            poly = box(cx + gap, cy - width / 2, cx + gap + depth, cy + width / 2)
        elif facing == "+x":
            poly = box(cx - gap - depth, cy - width / 2, cx - gap, cy + width / 2)
        elif facing == "-y":
            poly = box(cx - width / 2, cy + gap, cx + width / 2, cy + gap + depth)
        else:
            poly = box(cx - width / 2, cy - gap - depth, cx + width / 2, cy - gap)
        self._try_building(poly, height, "far", min_gap=1.0)

    def _frame(self, axis: str, side: int, direction: int, front: float):
        """Map block coordinates (u along the street from the block's start, v away from the street) to the street frame."""
        def to_xy(u, v):
            if axis == "x":
                return (u, front + side * v)
            return (front + side * v, direction * u)
        return to_xy

    @staticmethod
    def _to_street(poly_uv, to_xy):
        """Map a (u, v) polygon to the street frame, counter-clockwise."""
        from shapely.geometry import Polygon
        from shapely.geometry.polygon import orient

        ring = lambda r: [to_xy(u, v) for u, v in list(r.coords)[:-1]]  # noqa: E731
        return orient(Polygon(ring(poly_uv.exterior), [ring(r) for r in poly_uv.interiors]), 1.0)

    def _fill_block(self, axis: str, start: float, stop: float, front: float, side: int, direction: int = 1) -> None:
        """Buildings along one street edge, u from ``start`` to ``stop`` along the street, set back from ``front``."""
        rng = self.rng
        style = str(rng.choice(["houses", "houses", "apartments", "mixed"]))
        to_xy = self._frame(axis, side, direction, front)
        u = start + float(rng.uniform(0.0, 4.0))
        while u < stop - 6.0:
            pick = style if style != "mixed" else str(rng.choice(["houses", "apartments"]))
            if pick == "houses":
                width = float(rng.uniform(6.0, 12.0))
                depth = float(rng.uniform(7.0, 12.0))
                setback = float(rng.uniform(2.0, 9.0))
                height = float(rng.uniform(3.0, 9.0))
            else:
                width = float(rng.uniform(20.0, 45.0))
                depth = float(rng.uniform(12.0, 22.0))
                setback = float(rng.uniform(0.5, 4.0))
                height = float(rng.uniform(10.0, 30.0))
            width = min(width, stop - u)
            if width < 5.0:
                break
            poly = self._footprint(to_xy, u, u + width, setback, setback + depth, pick)
            if self._try_building(poly, height, pick):
                self._front_garden(to_xy, u, u + width, setback, pick)
                if rng.random() < 0.6:
                    self._second_row(to_xy, u, width, setback + depth)
            gap = float(rng.uniform(2.0, 3.0)) if rng.random() < 0.5 else float(rng.uniform(4.0, 10.0))
            if rng.random() < 0.08:
                gap = float(rng.uniform(18.0, 30.0))           # an open lot: a view to the second row
            u += width + gap

    def _footprint(self, to_xy, u0, u1, v0, v1, kind: str):
        """A house or block footprint on [u0, u1] x [v0, v1]: a rectangle, an L-shape or a courtyard block."""
        from shapely.geometry import box

        rng = self.rng
        rect = box(u0, v0, u1, v1)
        r = rng.random()
        w, d = u1 - u0, v1 - v0
        shape = rect
        if kind == "houses" and r < 0.4 and w > 7 and d > 7:           # L-shape: a notch at one corner
            nu, nv = float(rng.uniform(0.3, 0.5)) * w, float(rng.uniform(0.3, 0.5)) * d
            cu0, cu1 = (u0 - 1.0, u0 + nu) if rng.random() < 0.5 else (u1 - nu, u1 + 1.0)   # the notch box pokes out,
            cv0, cv1 = (v0 - 1.0, v0 + nv) if rng.random() < 0.5 else (v1 - nv, v1 + 1.0)   # so no sliver is left
            shape = rect.difference(box(cu0, cv0, cu1, cv1))
        elif kind == "apartments" and w >= 25 and d >= 18 and r < 0.45:  # courtyard
            inset = float(rng.uniform(5.0, 7.0))
            shape = rect.difference(box(u0 + inset, v0 + inset, u1 - inset, v1 - inset))
        elif kind == "apartments" and r > 0.75 and w > 20:               # L-shaped block: a wing to the back
            wing, extra = float(rng.uniform(0.3, 0.5)) * w, float(rng.uniform(6.0, 12.0))
            wu = u0 if rng.random() < 0.5 else u1 - wing
            shape = rect.union(box(wu, v1, wu + wing, v1 + extra))
        shape = shape.simplify(1e-6)                                     # no collinear vertices
        return self._to_street(shape, to_xy)

    def _second_row(self, to_xy, u: float, width: float, behind: float) -> None:
        rng = self.rng
        v0 = behind + float(rng.uniform(6.0, 18.0))
        w = float(rng.uniform(8.0, max(9.0, width + 6.0)))
        u0 = u + float(rng.uniform(-4.0, 4.0))
        d = float(rng.uniform(8.0, 14.0))
        poly = self._footprint(to_xy, u0, u0 + w, v0, v0 + d, "houses")
        self._try_building(poly, float(rng.uniform(4.0, 20.0)), "second_row")

    # -- clutter ------------------------------------------------------------------------------------
    def _try_clutter(self, obj: dict, shape, corridor: bool = True) -> None:
        if any(shape.intersects(b.buffer(0.3)) for b in self._footprints):
            return
        if corridor and shape.intersects(self.drive_corridor):
            return
        if obj["kind"] == "car" and any(shape.intersects(c) for c in self._clutter_shapes):
            return
        self.clutter.append(obj)
        self._clutter_shapes.append(shape)

    @property
    def drive_corridor(self):
        from shapely.geometry import LineString

        if not hasattr(self, "_corridor"):
            self._corridor = LineString(self.route).buffer(1.3)
        return self._corridor

    def _front_garden(self, to_xy, u0: float, u1: float, setback: float, kind: str) -> None:
        """Fence or hedge along the lot's front, a tree in the garden, sometimes."""
        from shapely.geometry import LineString, Point

        rng = self.rng
        if kind != "houses" or setback < 1.5:
            return
        v = float(rng.uniform(0.2, 0.6))
        a, b = to_xy(u0 - 0.5, v), to_xy(u1 + 0.5, v)
        r = rng.random()
        if r < 0.35:
            self._try_clutter({"kind": "fence", "line": [a, b], "height": round(float(rng.uniform(0.8, 1.6)), 2)},
                              LineString([a, b]).buffer(0.05), corridor=False)
        elif r < 0.7:
            self._try_clutter({"kind": "hedge", "line": [a, b], "height": round(float(rng.uniform(0.6, 1.5)), 2),
                               "width": round(float(rng.uniform(0.5, 1.2)), 2), "seed": int(rng.integers(1 << 30))},
                              LineString([a, b]).buffer(0.6), corridor=False)
        if setback > 4.0 and rng.random() < 0.4:
            p = to_xy(float(rng.uniform(u0, u1)), float(rng.uniform(1.5, setback - 1.5)))
            crown = float(rng.uniform(1.0, min(2.5, setback / 2)))
            self._try_clutter({"kind": "tree", "position": p, "crown_radius": round(crown, 2),
                               "trunk_height": round(float(rng.uniform(1.5, 3.0)), 2)}, Point(p).buffer(0.3),
                              corridor=False)

    def _street_clutter(self) -> None:
        from shapely.geometry import Point, box
        from shapely.affinity import rotate

        rng = self.rng
        for s in self.streets:
            (x0, y0), (x1, y1) = s["line"][0], s["line"][-1]
            length = float(np.hypot(x1 - x0, y1 - y0))
            ux, uy = (x1 - x0) / length, (y1 - y0) / length
            nx, ny = -uy, ux
            heading = float(np.degrees(np.arctan2(uy, ux)))
            for side in (+1, -1):
                # parked cars in the parking lane
                t = float(rng.uniform(0.0, 8.0))
                density = float(rng.uniform(0.2, 0.8))
                while t < length - 3.0:
                    if rng.random() < density:
                        off = side * (s["width"] / 2 - 1.0)
                        cx, cy = x0 + ux * t + nx * off, y0 + uy * t + ny * off
                        size = (round(float(rng.uniform(3.8, 5.0)), 2), round(float(rng.uniform(1.7, 1.95)), 2),
                                round(float(rng.uniform(1.4, 1.9)), 2))
                        h = heading + float(rng.normal(0.0, 2.0)) + (180.0 if rng.random() < 0.5 else 0.0)
                        shape = rotate(box(cx - size[0] / 2, cy - size[1] / 2, cx + size[0] / 2, cy + size[1] / 2), h,
                                       origin=(cx, cy))
                        if shape.within(self.carriageway):
                            self._try_clutter({"kind": "car", "position": (cx, cy), "heading_deg": round(h, 2),
                                               "size": size}, shape)
                    t += float(rng.uniform(5.5, 9.0))
                # street lights and sign poles on the sidewalk near the curb
                t = float(rng.uniform(0.0, 20.0))
                while t < length:
                    off = side * (s["width"] / 2 + 0.6)
                    p = (x0 + ux * t + nx * off, y0 + uy * t + ny * off)
                    light = rng.random() < 0.6
                    obj = {"kind": "pole", "position": p, "height": round(float(rng.uniform(5.0, 8.0)), 2) if light else 2.6,
                           "radius": 0.12 if light else 0.05}
                    if not Point(p).within(self.carriageway):
                        self._try_clutter(obj, Point(p).buffer(0.2))
                    t += float(rng.uniform(18.0, 40.0))
                # trees on the sidewalk, where it is wide enough
                if self.sidewalk > 2.2 and rng.random() < 0.6:
                    t = float(rng.uniform(0.0, 12.0))
                    while t < length:
                        off = side * (s["width"] / 2 + self.sidewalk * 0.6)
                        p = (x0 + ux * t + nx * off, y0 + uy * t + ny * off)
                        if not Point(p).within(self.carriageway):
                            self._try_clutter({"kind": "tree", "position": p,
                                               "crown_radius": round(float(rng.uniform(1.2, 3.0)), 2),
                                               "trunk_height": round(float(rng.uniform(2.0, 3.5)), 2)},
                                              Point(p).buffer(0.3))
                        t += float(rng.uniform(9.0, 25.0))

    # -- output -------------------------------------------------------------------------------------
    def to_dict(self, name: str, seed: int) -> dict:
        c, s = np.cos(self.angle), np.sin(self.angle)

        def rot(p) -> list[float]:
            x, y = float(p[0]), float(p[1])
            return [round(float(c * x - s * y), 3), round(float(s * x + c * y), 3)]

        objects = []
        for k, b in enumerate(self.buildings):
            poly = b["poly"]
            obj = {"id": f"{b['kind']}{k:03d}", "kind": "building", "height": b["height"],
                   "footprint": [rot(p) for p in list(poly.exterior.coords)[:-1]]}
            if poly.interiors:
                obj["holes"] = [[rot(p) for p in list(r.coords)[:-1]] for r in poly.interiors]
            objects.append(obj)
        for k, o in enumerate(self.clutter):
            obj = {key: value for key, value in o.items()}
            obj["id"] = f"{o['kind']}{k:03d}"
            if "position" in obj:
                obj["position"] = rot(obj["position"])
            if "line" in obj:
                obj["line"] = [rot(p) for p in obj["line"]]
            if "heading_deg" in obj:
                obj["heading_deg"] = round(obj["heading_deg"] + float(np.degrees(self.angle)), 2)
            objects.append(obj)
        return {
            "name": name,
            "description": f"procedurally generated street (featmap.simulation.procedural, seed {seed})",
            "route": {"waypoints": [rot(p) for p in self.route], "speed_mps": round(self.speed, 2),
                      "turn_radius_m": round(self.turn_radius, 2)},
            "ground": {"grade": [round(g, 5) for g in self._rotated_grade()], "curb_height": round(self.curb, 3),
                       "streets": [{"line": [rot(p) for p in st["line"]], "width": round(st["width"], 3)}
                                   for st in self.streets]},
            "objects": objects,
        }

    def _rotated_grade(self) -> tuple[float, float]:
        gx, gy = self.grade
        c, s = np.cos(self.angle), np.sin(self.angle)
        return (c * gx - s * gy, s * gx + c * gy)
