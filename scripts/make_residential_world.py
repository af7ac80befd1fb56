"""Generate ``featmap/resources/worlds/residential.yaml``, the embedded default world.

A residential street network in the spirit of KITTI's 2011_09_30_drive_0018: houses (rectangles and
L-shapes, 6-15 m high) and a few longer apartment blocks (one with a courtyard) on both sides of the
streets, garden fences, parked cars, street lights and trees, and a ~420 m route with three turns.
The world is data: this script only wrote it once (seeded); edit the YAML or write your own.

    .venv/bin/python scripts/make_residential_world.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml
from shapely.geometry import LineString, Polygon

OUT = Path(__file__).resolve().parents[1] / "featmap" / "resources" / "worlds" / "residential.yaml"
ROUTE = [[-10.0, 0.0], [170.0, 0.0], [170.0, 110.0], [80.0, 110.0], [80.0, 190.0]]
STREETS = [[[-60, 0], [260, 0]], [[170, -60], [170, 250]], [[-60, 110], [260, 110]], [[80, -60], [80, 250]]]


def main(seed: int = 18) -> None:
    rng = np.random.default_rng(seed)
    streets = [LineString(s).buffer(9.0) for s in STREETS]
    taken: list[Polygon] = []
    objects: list[dict] = []

    def free(poly: Polygon) -> bool:
        if any(poly.intersects(s) for s in streets):
            return False
        return not any(poly.buffer(2.0).intersects(t) for t in taken)

    def place(local: np.ndarray, origin: np.ndarray, along: np.ndarray, side: float) -> np.ndarray:
        normal = np.array([-along[1], along[0]]) * side
        return origin + local[:, :1] * along + local[:, 1:] * normal

    n_house = 0
    for street in STREETS:
        a, b = np.asarray(street, float)
        along = (b - a) / np.linalg.norm(b - a)
        length = np.linalg.norm(b - a)
        for side in (1.0, -1.0):
            s = rng.uniform(2, 8)
            while s < length - 10:
                width = rng.uniform(9, 20) if rng.random() > 0.2 else rng.uniform(28, 45)
                depth = rng.uniform(9, 15)
                setback = rng.uniform(11, 15)
                shape = "L" if (width < 25 and rng.random() < 0.3) else "rect"
                if width >= 28:
                    local = np.array([[0, 0], [width, 0], [width, depth + 4], [0, depth + 4]])
                elif shape == "L":
                    cut_w, cut_d = width * rng.uniform(0.35, 0.55), depth * rng.uniform(0.35, 0.5)
                    local = np.array([[0, 0], [width, 0], [width, depth - cut_d], [width - cut_w, depth - cut_d],
                                      [width - cut_w, depth], [0, depth]])
                else:
                    local = np.array([[0, 0], [width, 0], [width, depth], [0, depth]])
                local = local + np.array([0.0, setback])
                fp = place(local, a + along * s, along, side)
                poly = Polygon(fp)
                if not poly.exterior.is_ccw:
                    fp = fp[::-1]
                    poly = Polygon(fp)
                if free(poly):
                    n_house += 1
                    obj = {"id": f"house{n_house:03d}", "kind": "building",
                           "footprint": np.round(fp, 2).tolist(),
                           "height": float(round(rng.uniform(6, 15) if width < 28 else rng.uniform(12, 22), 1))}
                    if width >= 40 and not any("holes" in o for o in objects):
                        inner = place(np.array([[8, setback + 6], [width - 8, setback + 6],
                                                [width - 8, setback + depth - 2], [8, setback + depth - 2]]),
                                      a + along * s, along, side)
                        if not Polygon(inner).exterior.is_ccw:
                            inner = inner[::-1]
                        obj["holes"] = [np.round(inner, 2).tolist()]
                    objects.append(obj)
                    taken.append(poly)
                    if rng.random() < 0.35 and width < 25:   # a garden fence in front of the house
                        f0 = a + along * (s + 1) + np.array([-along[1], along[0]]) * side * rng.uniform(7.5, 8.5)
                        f1 = f0 + along * (width - 2)
                        fence = LineString([f0, f1])
                        if not any(fence.intersects(t) for t in taken):
                            objects.append({"id": f"fence{len(objects):03d}", "kind": "fence",
                                            "line": np.round([f0, f1], 2).tolist(),
                                            "height": float(round(rng.uniform(0.9, 1.6), 2))})
                s += width + rng.uniform(4, 12)
    # Parked cars, street lights and trees along the driven route only (what the sensor sees up close).
    route = LineString(ROUTE)
    for dist in np.arange(15.0, route.length - 10, 1.0):
        p = np.asarray(route.interpolate(dist).coords[0])
        q = np.asarray(route.interpolate(dist + 0.5).coords[0])
        along = (q - p) / max(np.linalg.norm(q - p), 1e-9)
        normal = np.array([-along[1], along[0]])
        side = 1.0 if rng.random() < 0.5 else -1.0
        near_corner = min(np.linalg.norm(p - np.asarray(c)) for c in ROUTE[1:-1]) < 16
        if near_corner:
            continue
        r = rng.random()
        if r < 0.035:
            pos = p + normal * side * 3.6
            if all(LineString([pos, pos]).distance(t) > 3 for t in taken):
                objects.append({"id": f"car{len(objects):03d}", "kind": "car", "position": np.round(pos, 2).tolist(),
                                "heading_deg": float(round(np.degrees(np.arctan2(along[1], along[0])) + rng.normal(0, 2), 1))})
        elif r < 0.055:
            pos = p + normal * side * 5.8
            objects.append({"id": f"pole{len(objects):03d}", "kind": "pole", "position": np.round(pos, 2).tolist(),
                            "height": 6.0})
        elif r < 0.08:
            pos = p + normal * side * 7.0
            if all(LineString([pos, pos]).distance(t) > 3 for t in taken):
                objects.append({"id": f"tree{len(objects):03d}", "kind": "tree", "position": np.round(pos, 2).tolist(),
                                "crown_radius": float(round(rng.uniform(1.5, 2.8), 1))})
    world = {
        "name": "residential",
        "description": "Residential streets like KITTI 2011_09_30_drive_0018: houses on both sides, fences, "
                       "parked cars, street lights, trees; a ~420 m drive with three turns (generated by "
                       "scripts/make_residential_world.py).",
        "geo_origin": {"lat": 49.0385, "lon": 8.4590},
        "route": {"waypoints": ROUTE, "speed_mps": 8.0, "turn_radius_m": 9.0},
        "objects": objects,
    }
    header = ("# The embedded default world of `featmap run` (generated once by scripts/make_residential_world.py;\n"
              "# edit freely). Coordinates in metres, x east, y north.\n")
    OUT.write_text(header + yaml.safe_dump(world, sort_keys=False, default_flow_style=None, width=120))
    kinds = {}
    for o in objects:
        kinds[o["kind"]] = kinds.get(o["kind"], 0) + 1
    print(f"wrote {OUT} with {kinds}, route {route.length:.0f} m")


if __name__ == "__main__":
    main()
