"""Simulator worlds: YAML or GeoJSON files describing buildings, clutter and the vehicle's route.

A world is data, not code. The YAML form (coordinates in metres, x east, y north)::

    name: prescan_case1
    geo_origin: {lat: 49.0110, lon: 8.4240}   # approximate WGS84 of (0, 0)
    route: {waypoints: [[-30, -15], [60, -15]], speed_mps: 8, turn_radius_m: 8}
    objects:
      - {id: A, kind: building, footprint: [[0, 0], [30, 0], [30, 20], [0, 20]], height: 12,
         vertex_labels: [a, b, c, d]}                                  # holes: [[...]] for courtyards
      - {id: f1, kind: fence, line: [[0, -5], [10, -5]], height: 1.2}
      - {id: c1, kind: car, position: [5, -9], heading_deg: 0}        # size: [4.5, 1.8, 1.5]
      - {id: p1, kind: pole, position: [12, -8], height: 6}
      - {id: t1, kind: tree, position: [20, -8]}                        # crown_porosity: 0.3, crown_depth_m: 0.4
      - {id: h1, kind: hedge, line: [[0, -4], [8, -4]], height: 1.1, width: 0.8}   # porosity, depth_m
    ground: {grade: [0.02, 0.0], curb_height: 0.12,                    # optional; flat z = 0 without it
             streets: [{line: [[-40, -15], [70, -15]], width: 8}]}

Another drive through the same streets is a world that ``extends`` one (a built-in name or a file
relative to it) with its own ``name`` and ``route``; it takes the base's ``geo_origin``, ``ground``
and ``objects`` (its own ``objects`` are added)::

    name: residential_east
    extends: residential
    route: {waypoints: [[80, -50], [80, 110], [170, 110]], speed_mps: 8, turn_radius_m: 9}

The ground is the plane ``z = grade_x * x + grade_y * y``; with ``streets`` and a ``curb_height``,
everything outside the streets' carriageways (sidewalks, gardens, building lots) lies
``curb_height`` higher, with a vertical curb face along every street edge. Buildings and clutter
stand on the ground beneath them, and the vehicle drives on the street surface (its pose follows
the slope).

The GeoJSON form (WGS84, e.g. OpenStreetMap building footprints exported as GeoJSON): Polygons are
buildings (``properties.height`` in metres, else ``building:levels`` x 3 m, else 10 m), a LineString
with ``properties.kind: route`` is the route, other LineStrings with ``kind: fence`` are fences,
Points with ``kind`` car, pole or tree are clutter.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Literal, Optional, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError, field_validator

from featmap.config import InvalidYamlError, load_yaml_text
from featmap.errors import FeatmapError, WorldError
from featmap.geo import open_ring

WORLDS_DIR = Path(__file__).resolve().parents[1] / "resources" / "worlds"
KINDS = ("building", "fence", "car", "pole", "tree", "hedge")


PositiveLength = Annotated[float, Field(gt=0)]
COORDINATE_LIMIT_M = 1e6
"""A world's coordinates lie within this many metres of its origin (1,000 km: a local frame, not UTM
eastings or degrees); beyond it routes take years and OXTS positions mean nothing."""
Coordinate = Annotated[float, Field(ge=-COORDINATE_LIMIT_M, le=COORDINATE_LIMIT_M)]
Point = tuple[Coordinate, Coordinate]


class _Obj(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    id: Optional[str] = None


class Building(_Obj):
    kind: Literal["building"]
    footprint: list[Point] = Field(min_length=3)
    holes: list[list[Point]] = []
    height: float = Field(10.0, gt=0)
    vertex_labels: Optional[list[str]] = None


class Fence(_Obj):
    kind: Literal["fence"]
    line: list[Point] = Field(min_length=2)
    height: float = Field(1.2, gt=0)
    thickness: float = Field(0.08, gt=0)


class Car(_Obj):
    kind: Literal["car"]
    position: Point
    heading_deg: float = 0.0
    size: tuple[PositiveLength, PositiveLength, PositiveLength] = (4.5, 1.8, 1.5)


class Pole(_Obj):
    kind: Literal["pole"]
    position: Point
    radius: float = Field(0.12, gt=0)
    height: float = Field(6.0, gt=0)


class Tree(_Obj):
    kind: Literal["tree"]
    position: Point
    trunk_radius: float = Field(0.2, gt=0)
    trunk_height: float = Field(2.5, gt=0)
    crown_radius: float = Field(2.0, gt=0)
    crown_porosity: float = Field(0.0, ge=0, lt=1, description="share of the rays reaching the crown that pass "
                                  "through it (foliage; 0 = a solid sphere)")
    crown_depth_m: float = Field(0.0, ge=0, description="mean depth (exponential) inside the crown at which a ray it "
                                 "stops returns (0 = at its surface)")


class Hedge(_Obj):
    """Low, irregular vegetation along a polyline: a row of boxes of jittered height, width and position."""

    kind: Literal["hedge"]
    line: list[Point] = Field(min_length=2)
    height: float = Field(1.2, gt=0)
    width: float = Field(0.8, gt=0)
    irregularity: float = Field(0.15, ge=0, description="metres: std of the jitter of each box's height, width and position")
    seed: int = Field(0, description="seeds the jitter (same seed, same hedge)")
    porosity: float = Field(0.0, ge=0, lt=1, description="share of the rays reaching the hedge that pass through it "
                            "(0 = solid boxes)")
    depth_m: float = Field(0.0, ge=0, description="mean depth (exponential) inside the hedge at which a ray it stops "
                           "returns (0 = at its surface)")


WorldObject = Annotated[Union[Building, Fence, Car, Pole, Tree, Hedge], Field(discriminator="kind")]
_OBJECT = TypeAdapter(WorldObject)


class Route(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    waypoints: list[Point] = Field(min_length=2)
    speed_mps: float = Field(8.0, gt=0)
    turn_radius_m: float = Field(8.0, ge=0)


class Street(BaseModel):
    """A street's carriageway: a polyline and its width (metres); the ground outside it is the curb's height higher."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    line: list[Point] = Field(min_length=2)
    width: float = Field(gt=0)


class Ground(BaseModel):
    """The ground surface: a plane with a grade, and raised sidewalks (a curb step) outside the streets."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    grade: tuple[float, float] = Field((0.0, 0.0), description="dz/dx, dz/dy of the ground plane (0.03 = 3 % slope)")
    curb_height: float = Field(0.0, ge=0, le=0.5, description="metres the ground outside the streets lies above them")
    streets: list[Street] = []

    @field_validator("grade")
    @classmethod
    def _moderate_grade(cls, grade: tuple[float, float]) -> tuple[float, float]:
        if max(abs(grade[0]), abs(grade[1])) > 0.2:
            raise ValueError("a grade above 0.2 (20 %) is not a street")
        return grade

    @property
    def is_flat(self) -> bool:
        """True for the flat z = 0 plane every world had before grades and curbs existed."""
        return self.grade == (0.0, 0.0) and (self.curb_height == 0.0 or not self.streets)


class GeoOrigin(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    lat: float = Field(49.0110, ge=-85, le=85)
    lon: float = Field(8.4240, ge=-180, le=180)


class World(BaseModel):
    """A validated world: objects in a local metric frame (x east, y north, metres)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    name: str
    description: str = ""
    geo_origin: GeoOrigin = GeoOrigin()
    route: Route
    objects: list[WorldObject] = []
    ground: Ground = Ground()
    source: Optional[str] = None

    def of_kind(self, kind: str) -> list:
        return [o for o in self.objects if o.kind == kind]

    @property
    def buildings(self) -> list[Building]:
        return self.of_kind("building")


def _label(index: int, raw) -> str:
    if isinstance(raw, dict):
        name = raw.get("id")
        kind = raw.get("kind", "?")
        return f"object {name!r} ({kind})" if name is not None else f"object #{index} ({kind})"
    return f"object #{index}"


def _check_object(path: str, index: int, raw) -> object:
    where = f"{path}: {_label(index, raw)}"
    if not isinstance(raw, dict):
        raise WorldError(f"{where}: expected a mapping with a 'kind'")
    kind = raw.get("kind")
    if kind not in KINDS:
        raise WorldError(f"{where}: unknown kind {kind!r}; allowed: {', '.join(KINDS)}")
    try:
        obj = _OBJECT.validate_python(raw)
    except ValidationError as exc:
        err = exc.errors()[0]
        key = ".".join(str(p) for p in err["loc"][1:]) or "value"
        raise WorldError(f"{where}: '{key}' {err['msg'][0].lower() + err['msg'][1:]} (got {err.get('input')!r})") from None
    if isinstance(obj, Building):
        from shapely.geometry import Polygon
        from shapely.validation import explain_validity

        poly = Polygon(obj.footprint, obj.holes)
        if not poly.is_valid:
            raise WorldError(f"{where}: invalid footprint ({explain_validity(poly)}); "
                             "footprints must be simple polygons (no self-intersection)")
        if poly.area <= 0:
            raise WorldError(f"{where}: footprint has no area")
        if obj.vertex_labels is not None and len(obj.vertex_labels) != len(open_ring(obj.footprint)):
            raise WorldError(f"{where}: {len(obj.vertex_labels)} vertex_labels for {len(open_ring(obj.footprint))} vertices")
    return obj


def world_from_dict(data: dict, path: str) -> World:
    """Validate a world mapping; every problem is a one-line WorldError naming ``path`` and the object."""
    if not isinstance(data, dict):
        raise WorldError(f"{path}: expected a mapping with name, route and objects")
    raw_objects = data.get("objects") or []
    if not isinstance(raw_objects, list):
        raise WorldError(f"{path}: 'objects' must be a list")
    objects = [_check_object(path, i, raw) for i, raw in enumerate(raw_objects)]
    rest = {k: v for k, v in data.items() if k != "objects"}
    rest.setdefault("name", Path(path).stem)
    if "route" not in rest:
        raise WorldError(f"{path}: no 'route' (the vehicle's waypoints)")
    try:
        return World.model_validate({**rest, "objects": [o.model_dump() for o in objects], "source": str(path)})
    except ValidationError as exc:
        err = exc.errors()[0]
        key = ".".join(str(p) for p in err["loc"])
        if err["type"] == "extra_forbidden":
            raise WorldError(f"{path}: unknown key '{key}'") from None
        raise WorldError(f"{path}: '{key}' {err['msg'][0].lower() + err['msg'][1:]} (got {err.get('input')!r})") from None


def _world_from_geojson(data: dict, path: str) -> dict:
    from featmap.geo import GeoFrame

    features = data.get("features")
    if data.get("type") != "FeatureCollection" or not isinstance(features, list):
        raise WorldError(f"{path}: expected a GeoJSON FeatureCollection")
    route_feats = [f for f in features if (f.get("properties") or {}).get("kind") == "route"]
    if not route_feats:
        raise WorldError(f"{path}: no LineString feature with properties.kind = 'route'")
    lon0, lat0 = route_feats[0]["geometry"]["coordinates"][0][:2]
    try:
        frame = GeoFrame(lat0, lon0)
    except FeatmapError as exc:     # not a number, or off the earth
        raise WorldError(f"{path}: the route's first position: {exc}") from None

    def local(coords):
        arr = np.asarray(coords, float)[:, :2]
        x, y = frame.to_local(arr[:, 1], arr[:, 0])
        return [[float(a), float(b)] for a, b in zip(x, y)]

    objects = []
    for n, feat in enumerate(features):
        props = dict(feat.get("properties") or {})
        geom = feat.get("geometry") or {}
        kind = props.pop("kind", None)
        gtype = geom.get("type")
        ident = props.pop("id", None) or feat.get("id") or f"feature{n}"
        if kind == "route":
            continue
        if gtype in ("Polygon", "MultiPolygon"):
            polys = [geom["coordinates"]] if gtype == "Polygon" else geom["coordinates"]
            height = props.get("height")
            if height is None and props.get("building:levels") is not None:
                height = float(props["building:levels"]) * 3.0
            for k, rings in enumerate(polys):
                obj = {"id": str(ident) if len(polys) == 1 else f"{ident}.{k}", "kind": kind or "building",
                       "footprint": local(rings[0]), "holes": [local(r) for r in rings[1:]]}
                if height is not None:
                    obj["height"] = float(height)
                objects.append(obj)
        elif gtype == "LineString":
            objects.append({"id": str(ident), "kind": kind or "fence", "line": local(geom["coordinates"]),
                            **({"height": float(props["height"])} if "height" in props else {})})
        elif gtype == "Point":
            objects.append({"id": str(ident), "kind": kind, "position": local([geom["coordinates"]])[0]})
        else:
            raise WorldError(f"{path}: feature {ident!r}: unsupported geometry type {gtype!r}")
    rp = route_feats[0].get("properties") or {}
    route = {"waypoints": local(route_feats[0]["geometry"]["coordinates"])}
    for key in ("speed_mps", "turn_radius_m"):
        if key in rp:
            route[key] = rp[key]
    return {"name": data.get("name") or Path(path).stem, "geo_origin": {"lat": lat0, "lon": lon0},
            "route": route, "objects": objects}


def builtin_worlds() -> list[str]:
    return sorted(p.stem for p in WORLDS_DIR.glob("*.yaml"))


def resolve_world_path(name_or_file: str | Path) -> Path:
    """A built-in world name (``residential``) or a path to a YAML/GeoJSON file."""
    path = Path(name_or_file)
    if path.suffix.lower() in (".yaml", ".yml", ".geojson", ".json") or path.exists():
        if not path.exists():
            raise WorldError(f"{path}: world file not found")
        return path
    builtin = WORLDS_DIR / f"{name_or_file}.yaml"
    if builtin.exists():
        return builtin
    raise WorldError(f"unknown world {str(name_or_file)!r}; built-in worlds: {', '.join(builtin_worlds())}, "
                     "or give a .yaml/.geojson file")


MAX_EXTENDS_DEPTH = 4


def _not_finite(constant: str):
    raise ValueError(f"{constant} is not a finite number")


def _read_world_mapping(path: Path) -> dict:
    """The raw mapping of a YAML or GeoJSON world file (GeoJSON converted to the YAML form)."""
    try:
        text = path.read_text()
    except OSError as exc:
        raise WorldError(f"{path}: cannot read ({exc.strerror})") from None
    if path.suffix.lower() in (".geojson", ".json"):
        try:
            return _world_from_geojson(json.loads(text, parse_constant=_not_finite), str(path))
        except json.JSONDecodeError as exc:
            raise WorldError(f"{path}:{exc.lineno}: not valid JSON ({exc.msg})") from None
        except (KeyError, TypeError, IndexError, ValueError, AttributeError) as exc:
            raise WorldError(f"{path}: malformed GeoJSON feature ({type(exc).__name__}: {exc}); every feature needs "
                             "a geometry with coordinates") from None
    try:
        return load_yaml_text(text, str(path))      # as strict as a config: a key given twice is an error
    except InvalidYamlError as exc:
        raise WorldError(str(exc)) from None


def _resolve_extends(data, path: Path, seen: tuple[Path, ...] = ()) -> dict:
    """A world mapping with its ``extends: BASE`` resolved.

    ``BASE`` is a built-in world name or a world file (relative to this file's folder). The world takes
    the base's ``geo_origin``, ``ground`` and ``objects``; its own ``objects`` are added to the base's,
    its own ``geo_origin``/``ground`` replace the base's, and it must give its own ``route`` (another
    drive through the same streets).
    """
    if not isinstance(data, dict) or "extends" not in data:
        return data
    ref = data["extends"]
    if not isinstance(ref, str) or not ref:
        raise WorldError(f"{path}: 'extends' must be a built-in world name or a world file, got {ref!r}")
    if "route" not in data:
        raise WorldError(f"{path}: a world that extends {ref!r} needs its own 'route' (the vehicle's waypoints)")
    local = path.parent / ref
    base_path = local if local.suffix.lower() in (".yaml", ".yml", ".geojson", ".json") and local.exists() \
        else resolve_world_path(ref)
    base_path = base_path.resolve()
    if base_path in seen or len(seen) >= MAX_EXTENDS_DEPTH:
        raise WorldError(f"{path}: 'extends: {ref}' makes a cycle or a chain longer than {MAX_EXTENDS_DEPTH}")
    base = _resolve_extends(_read_world_mapping(base_path), base_path, (*seen, path.resolve()))
    if not isinstance(base, dict):
        raise WorldError(f"{base_path}: expected a mapping with name, route and objects (extended by {path})")
    merged = {k: v for k, v in base.items() if k in ("geo_origin", "ground")}
    merged.update({k: v for k, v in data.items() if k not in ("extends", "objects")})
    if not isinstance(data.get("objects") or [], list) or not isinstance(base.get("objects") or [], list):
        raise WorldError(f"{path}: 'objects' must be a list")
    merged["objects"] = list(base.get("objects") or []) + list(data.get("objects") or [])
    return merged


def load_world(name_or_file: str | Path) -> World:
    """Load and validate a world by built-in name or file path (with its ``extends:`` base, if any)."""
    path = resolve_world_path(name_or_file)
    data = _resolve_extends(_read_world_mapping(path), path)
    return world_from_dict(data, str(path))


def with_porous_foliage(world: World, crown_porosity: float, crown_depth_m: float, hedge_porosity: float,
                        hedge_depth_m: float) -> World:
    """``world`` with every tree's crown and every hedge porous (see :mod:`featmap.simulation.scene`): the
    share of rays that pass through each and the mean depth inside it at which the others return."""
    update = {"tree": {"crown_porosity": crown_porosity, "crown_depth_m": crown_depth_m},
              "hedge": {"porosity": hedge_porosity, "depth_m": hedge_depth_m}}
    data = world.model_dump()
    data["objects"] = [{**obj, **update.get(obj["kind"], {})} for obj in data["objects"]]
    return World.model_validate(data)


DRAWN_FOLIAGE: dict[str, dict[str, tuple[float, float]]] = {
    "tree": {"crown_porosity": (0.0, 0.6), "crown_depth_m": (0.1, 0.6)},
    "hedge": {"porosity": (0.0, 0.3), "depth_m": (0.05, 0.3)},
}
"""Ranges (low, high) from which :func:`with_drawn_foliage` draws each crown's and hedge's porosity and
mean depth, uniformly. Chosen by hand to span the real scans' kinds (from sparse crowns most rays pass to
trimmed hedges that stop nearly all near their surface) and to contain the fixed stress setting of
``bench_generalization.py --foliage 0.3,0.3,0.15,0.2``; not measured on real foliage, and nothing was tuned
on them."""
FOLIAGE_DRAW_STREAM = 0xF011A6E
"""Tags the random stream of :func:`with_drawn_foliage` (with the world's seed)."""


def with_drawn_foliage(world: World, seed: int) -> World:
    """``world`` with every tree's crown and every hedge porous, each by its own porosity and mean depth
    drawn from :data:`DRAWN_FOLIAGE` (the same ``seed``, the same draws; objects are drawn in order)."""
    rng = np.random.default_rng([seed, FOLIAGE_DRAW_STREAM])
    data = world.model_dump()
    for obj in data["objects"]:
        for key, (low, high) in DRAWN_FOLIAGE.get(obj["kind"], {}).items():
            obj[key] = round(float(rng.uniform(low, high)), 3)
    return World.model_validate(data)


def building_edges(world: World) -> list[dict]:
    """Every wall of every building: dicts with building id and index, edge index, endpoints (2,)+(2,), labels.

    Rings are walked counter-clockwise for exteriors and clockwise for holes, so the outward normal of
    every wall is on its right-hand side.
    """
    from shapely.geometry import Polygon
    from shapely.geometry.polygon import orient

    edges = []
    for b_index, b in enumerate(world.buildings):
        bid = b.id or f"building{b_index}"
        poly = orient(Polygon(open_ring(b.footprint), [open_ring(h) for h in b.holes]), sign=1.0)
        rings = [np.asarray(poly.exterior.coords)[:-1]] + [np.asarray(r.coords)[:-1] for r in poly.interiors]
        ext_raw = open_ring(b.footprint)
        for r_index, ring in enumerate(rings):
            for k in range(len(ring)):
                p, q = ring[k], ring[(k + 1) % len(ring)]
                label_p = label_q = ""
                if r_index == 0 and b.vertex_labels:
                    lookup = {tuple(map(float, v)): lab for v, lab in zip(ext_raw, b.vertex_labels)}
                    label_p = lookup.get(tuple(map(float, p)), "")
                    label_q = lookup.get(tuple(map(float, q)), "")
                edges.append({"building": bid, "building_index": b_index, "ring": r_index, "edge": k, "height": b.height,
                              "p": p.astype(float), "q": q.astype(float), "label_p": label_p, "label_q": label_q})
    return edges
