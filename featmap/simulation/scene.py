"""Triangle meshes of a world in an Open3D ``RaycastingScene`` (CPU).

The ground (flat z = 0, or a sloped plane with raised sidewalks and curb faces, see
:mod:`featmap.simulation.ground`); buildings as extruded footprints (one quad per wall, so every hit
on a wall maps back to its footprint edge), with roofs; fences as thin boxes; cars as boxes; poles as
cylinders; trees as a trunk cylinder and a spherical crown; hedges as rows of jittered boxes.

Foliage (a tree's crown, a hedge) may be porous (``crown_porosity`` / ``porosity``, ``crown_depth_m`` /
``depth_m`` of the world's objects): a ray that reaches it passes through with that probability, and
then returns from whatever the scene holds behind with every porous mesh taken away (a second crown or
hedge behind the first is passed too: an approximation); else it returns from an exponentially
distributed depth inside it (at most :data:`FOLIAGE_MAX_DEPTHS` mean depths), so its returns scatter in
depth and some rays reach the wall behind, as with real leaves. With no porous object in a world the
scene, the rays and the random draws are what they were without this (the drives stay byte for byte).

On sloped ground every object stands on the ground beneath it: a building's walls reach from
below its lowest footprint corner to ``height`` above its highest one; fences and hedges are cut
into pieces of at most :data:`SLOPE_PIECE_M` that each follow the ground, sunk
:data:`SLOPE_SINK_M` into it so that no gap opens underneath.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from featmap.geo import open_ring
from featmap.simulation.ground import GroundSurface
from featmap.simulation.worlds import World, building_edges

REFLECTANCE = {"ground": 0.12, "building": 0.32, "roof": 0.3, "fence": 0.4, "car": 0.65, "pole": 0.45, "tree": 0.2,
               "hedge": 0.18}
SLOPE_PIECE_M = 1.0
SLOPE_SINK_M = 0.15
HEDGE_BOX_M = 0.7           # longest box of a hedge (its segments are cut into equal boxes up to this long)
FOLIAGE_MAX_DEPTHS = 3.0    # a ray stopped by foliage returns from at most this many mean depths inside it
SOLID = (0.0, 0.0)          # the (porosity, mean depth) of a mesh that is not porous foliage


@dataclass
class SceneIndex:
    """What a ray hit, by Open3D geometry id.

    Attributes:
        kinds: geometry id -> kind name ("ground", "building", "roof", "fence", ...).
        wall_geometry_id: geometry id of the mesh holding every building wall.
        wall_edge_of_triangle: (T,) index into ``edges`` of each triangle of that mesh.
        edges: every building wall (see :func:`building_edges`).
        foliage: geometry id -> (T, 2) porosity and mean depth (m) of each triangle of that mesh, for the
            meshes holding porous foliage (empty: none).
    """

    kinds: dict[int, str]
    wall_geometry_id: int
    wall_edge_of_triangle: np.ndarray
    edges: list[dict]
    foliage: dict[int, np.ndarray] = field(default_factory=dict)


def building_levels(world: World, surface: GroundSurface | None = None) -> list[tuple[float, float]]:
    """(base z, roof z) of every building (world frame): (0, height) on flat ground.

    On sloped ground the walls start 0.3 m below the lowest ground point of the footprint's
    corners and the roof is ``height`` above the highest.
    """
    surface = surface or GroundSurface(world.ground)
    if surface.is_flat:
        return [(0.0, b.height) for b in world.buildings]
    out = []
    for b in world.buildings:
        z = surface.height(np.asarray(open_ring(b.footprint), float))
        out.append((float(z.min()) - 0.3, float(z.max()) + b.height))
    return out


def _wall_mesh(edges: list[dict], levels: list[tuple[float, float]] | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    verts, tris, owner = [], [], []
    for k, e in enumerate(edges):
        (px, py), (qx, qy) = e["p"], e["q"]
        z0, h = (0.0, e["height"]) if levels is None else levels[e["building_index"]]
        base = len(verts)
        verts += [(px, py, z0), (qx, qy, z0), (qx, qy, h), (px, py, h)]
        tris += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
        owner += [k, k]
    return np.asarray(verts, float).reshape(-1, 3), np.asarray(tris, np.int64).reshape(-1, 3), np.asarray(owner, np.int64)


def _roof_mesh(world: World, roof_z: list[float]) -> tuple[np.ndarray, np.ndarray]:
    import shapely
    from shapely.geometry import Polygon

    verts, tris = [], []
    for b, z in zip(world.buildings, roof_z):
        poly = Polygon(open_ring(b.footprint), [open_ring(h) for h in b.holes])
        for tri in shapely.constrained_delaunay_triangles(poly).geoms:
            base = len(verts)
            verts += [(x, y, z) for x, y in list(tri.exterior.coords)[:3]]
            tris.append((base, base + 1, base + 2))
    return np.asarray(verts, float).reshape(-1, 3), np.asarray(tris, np.int64).reshape(-1, 3)


def _merge(meshes) -> tuple[np.ndarray, np.ndarray]:
    verts, tris, offset = [], [], 0
    for m in meshes:
        v = np.asarray(m.vertices)
        t = np.asarray(m.triangles)
        verts.append(v)
        tris.append(t + offset)
        offset += len(v)
    if not verts:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    return np.concatenate(verts), np.concatenate(tris)


def _box_along(a: np.ndarray, b: np.ndarray, width: float, height: float, z0: float, lateral: float = 0.0):
    """A box from ``a`` to ``b`` (2,), ``width`` across (centred ``lateral`` to the left), from ``z0`` up ``height``."""
    import open3d as o3d

    length = float(np.linalg.norm(b - a))
    box = o3d.geometry.TriangleMesh.create_box(length, width, height)
    box.translate((0.0, -width / 2 + lateral, 0.0))
    ang = np.arctan2(*(b - a)[::-1])
    box.rotate(o3d.geometry.get_rotation_matrix_from_xyz((0, 0, ang)), center=(0, 0, 0))
    box.translate((a[0], a[1], z0))
    return box


def _pieces(a: np.ndarray, b: np.ndarray, piece_m: float) -> list[tuple[np.ndarray, np.ndarray]]:
    n = max(1, int(np.ceil(np.linalg.norm(b - a) / piece_m)))
    t = np.linspace(0.0, 1.0, n + 1)
    return [(a + (b - a) * t0, a + (b - a) * t1) for t0, t1 in zip(t[:-1], t[1:])]


def _hedge_boxes(hedge, surface: GroundSurface) -> list:
    """A hedge as boxes of ~HEDGE_BOX_M, each with jittered height, width and lateral position."""
    rng = np.random.default_rng(hedge.seed)
    line = np.asarray(hedge.line, float)
    out = []
    for a, b in zip(line[:-1], line[1:]):
        if np.linalg.norm(b - a) < 1e-6:
            continue
        for p, q in _pieces(a, b, HEDGE_BOX_M):
            jitter = rng.normal(0.0, hedge.irregularity, 3)
            height = max(0.2, hedge.height + jitter[0])
            width = max(0.2, hedge.width + jitter[1])
            mid = (p + q) / 2
            z0 = float(surface.height(mid)[0]) - SLOPE_SINK_M
            out.append(_box_along(p, q, width, height + SLOPE_SINK_M, z0, lateral=0.5 * jitter[2]))
    return out


def _clutter_meshes(world: World, surface: GroundSurface | None = None) -> tuple[dict[str, list], dict[str, list]]:
    """Meshes of every non-building object by kind, and each mesh's (porosity, mean depth) in the same
    order (see the module docstring; (0, 0) = solid); on flat ground everything stands on z = 0."""
    import open3d as o3d

    surface = surface or GroundSurface(world.ground)
    flat = surface.is_flat

    def ground_z(xy) -> float:
        return 0.0 if flat else float(surface.height(np.asarray(xy, float))[0])

    out: dict[str, list] = {"fence": [], "car": [], "pole": [], "tree": [], "hedge": []}
    foliage: dict[str, list] = {kind: [] for kind in out}
    for f in world.of_kind("fence"):
        line = np.asarray(f.line, float)
        for a, b in zip(line[:-1], line[1:]):
            length = float(np.linalg.norm(b - a))
            if length < 1e-6:
                continue
            if flat:
                out["fence"].append(_box_along(a, b, f.thickness, f.height, 0.0))
                continue
            for p, q in _pieces(a, b, SLOPE_PIECE_M):
                z0 = ground_z((p + q) / 2) - SLOPE_SINK_M
                out["fence"].append(_box_along(p, q, f.thickness, f.height + SLOPE_SINK_M, z0))
    for c in world.of_kind("car"):
        length, width, height = c.size
        z0 = 0.0 if flat else ground_z(c.position) - SLOPE_SINK_M
        box = o3d.geometry.TriangleMesh.create_box(length, width, height if flat else height + SLOPE_SINK_M)
        box.translate((-length / 2, -width / 2, 0.0))
        box.rotate(o3d.geometry.get_rotation_matrix_from_xyz((0, 0, np.deg2rad(c.heading_deg))), center=(0, 0, 0))
        box.translate((c.position[0], c.position[1], z0))
        out["car"].append(box)
    for p in world.of_kind("pole"):
        z0 = ground_z(p.position)
        cyl = o3d.geometry.TriangleMesh.create_cylinder(p.radius, p.height, resolution=12)
        cyl.translate((p.position[0], p.position[1], z0 + p.height / 2))
        out["pole"].append(cyl)
    for t in world.of_kind("tree"):
        z0 = ground_z(t.position)
        trunk = o3d.geometry.TriangleMesh.create_cylinder(t.trunk_radius, t.trunk_height, resolution=10)
        trunk.translate((t.position[0], t.position[1], z0 + t.trunk_height / 2))
        crown = o3d.geometry.TriangleMesh.create_sphere(t.crown_radius, resolution=10)
        crown.translate((t.position[0], t.position[1], z0 + t.trunk_height + 0.8 * t.crown_radius))
        out["tree"] += [trunk, crown]
        foliage["tree"] += [SOLID, (t.crown_porosity, t.crown_depth_m)]
    for h in world.of_kind("hedge"):
        boxes = _hedge_boxes(h, surface)
        out["hedge"] += boxes
        foliage["hedge"] += [(h.porosity, h.depth_m)] * len(boxes)
    for kind, meshes in out.items():
        foliage[kind] += [SOLID] * (len(meshes) - len(foliage[kind]))
    return out, foliage


def build_scene(world: World, ground_margin_m: float = 200.0, without_foliage: bool = False):
    """Return (``open3d.t.geometry.RaycastingScene``, :class:`SceneIndex`) for ``world``; with
    ``without_foliage``, every porous mesh is left out (what a ray passing through foliage reaches)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    kinds: dict[int, str] = {}

    def add(kind: str, verts: np.ndarray, tris: np.ndarray) -> int:
        gid = scene.add_triangles(o3d.core.Tensor(verts.astype(np.float32)), o3d.core.Tensor(tris.astype(np.uint32)))
        kinds[int(gid)] = kind
        return int(gid)

    pts = [np.asarray(world.route.waypoints, float)]
    pts += [np.asarray(b.footprint, float) for b in world.buildings]
    allpts = np.concatenate(pts)
    lo, hi = allpts.min(0) - ground_margin_m, allpts.max(0) + ground_margin_m
    surface = GroundSurface(world.ground)
    if surface.is_flat:
        add("ground", np.array([[lo[0], lo[1], 0], [hi[0], lo[1], 0], [hi[0], hi[1], 0], [lo[0], hi[1], 0]], float),
            np.array([[0, 1, 2], [0, 2, 3]]))
    else:
        add("ground", *surface.mesh(lo, hi))
    edges = building_edges(world)
    wall_gid = -1
    owner = np.zeros(0, np.int64)
    if edges:
        levels = building_levels(world, surface)
        verts, tris, owner = _wall_mesh(edges, levels)
        wall_gid = add("building", verts, tris)
        roof_v, roof_t = _roof_mesh(world, [top for _, top in levels])
        if len(roof_t):
            add("roof", roof_v, roof_t)
    meshes_by_kind, foliage_by_kind = _clutter_meshes(world, surface)
    foliage = {}
    for kind, meshes in meshes_by_kind.items():
        porous = [f != SOLID for f in foliage_by_kind[kind]]
        if without_foliage:
            meshes = [m for m, p in zip(meshes, porous) if not p]
        verts, tris = _merge(meshes)
        if len(tris):
            gid = add(kind, verts, tris)
            if any(porous) and not without_foliage:
                per_mesh = np.asarray(foliage_by_kind[kind], float)
                foliage[gid] = np.repeat(per_mesh, [len(m.triangles) for m in meshes], axis=0)
    return scene, SceneIndex(kinds=kinds, wall_geometry_id=wall_gid, wall_edge_of_triangle=owner, edges=edges,
                             foliage=foliage)


def cast(scene, origin: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cast rays from ``origin`` (3,) along world-frame unit ``directions`` (R, 3).

    Returns (distance (R,) with inf for misses, geometry id (R,), primitive id (R,)).
    """
    import open3d as o3d

    rays = np.empty((len(directions), 6), np.float32)
    rays[:, :3] = origin
    rays[:, 3:] = directions
    hit = scene.cast_rays(o3d.core.Tensor(rays))
    return (hit["t_hit"].numpy(), hit["geometry_ids"].numpy().astype(np.int64),
            hit["primitive_ids"].numpy().astype(np.int64))


def through_foliage(t_hit: np.ndarray, gid: np.ndarray, prim: np.ndarray, index: SceneIndex,
                    rng: np.random.Generator, cast_without_foliage) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The hits of :func:`cast` ((R,) distance, geometry id, primitive id; ``index``'s ids) with porous
    foliage applied (module docstring): rays that pass are cast again by ``cast_without_foliage(rows)``,
    which returns their (distance, geometry id in ``index``, primitive id) in a scene without the porous
    meshes; the others that foliage stopped return from inside it. ``rng`` draws R uniforms and one
    exponential per stopped ray, in that order. Returns new arrays; the inputs are not changed."""
    t_hit, gid, prim = t_hit.copy(), gid.copy(), prim.copy()
    porosity = np.zeros(len(t_hit))
    depth = np.zeros(len(t_hit))
    for g, per_triangle in index.foliage.items():
        on = gid == g
        porosity[on] = per_triangle[prim[on], 0]
        depth[on] = per_triangle[prim[on], 1]
    through = rng.random(len(t_hit)) < porosity
    if through.any():
        rows = np.flatnonzero(through)
        t_hit[rows], gid[rows], prim[rows] = cast_without_foliage(rows)
    stopped = np.flatnonzero(~through & (depth > 0) & np.isfinite(t_hit))
    extra = rng.exponential(1.0, len(stopped)) * depth[stopped]
    t_hit[stopped] += np.minimum(extra, FOLIAGE_MAX_DEPTHS * depth[stopped])
    return t_hit, gid, prim
