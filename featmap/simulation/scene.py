"""Triangle meshes of a world in an Open3D ``RaycastingScene`` (CPU).

Flat ground at z = 0; buildings as extruded footprints (one quad per wall, so every hit on a wall
maps back to its footprint edge), with roofs; fences as thin boxes; cars as boxes; poles as
cylinders; trees as a trunk cylinder and a spherical crown.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from featmap.simulation.worlds import World, _open_ring, building_edges

REFLECTANCE = {"ground": 0.12, "building": 0.32, "roof": 0.3, "fence": 0.4, "car": 0.65, "pole": 0.45, "tree": 0.2}


@dataclass
class SceneIndex:
    """What a ray hit, by Open3D geometry id.

    Attributes:
        kinds: geometry id -> kind name ("ground", "building", "roof", "fence", ...).
        wall_geometry_id: geometry id of the mesh holding every building wall.
        wall_edge_of_triangle: (T,) index into ``edges`` of each triangle of that mesh.
        edges: every building wall (see :func:`building_edges`).
    """

    kinds: dict[int, str]
    wall_geometry_id: int
    wall_edge_of_triangle: np.ndarray
    edges: list[dict]


def _wall_mesh(edges: list[dict]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    verts, tris, owner = [], [], []
    for k, e in enumerate(edges):
        (px, py), (qx, qy), h = e["p"], e["q"], e["height"]
        base = len(verts)
        verts += [(px, py, 0.0), (qx, qy, 0.0), (qx, qy, h), (px, py, h)]
        tris += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
        owner += [k, k]
    return np.asarray(verts, float).reshape(-1, 3), np.asarray(tris, np.int64).reshape(-1, 3), np.asarray(owner, np.int64)


def _roof_mesh(world: World) -> tuple[np.ndarray, np.ndarray]:
    import shapely
    from shapely.geometry import Polygon

    verts, tris = [], []
    for b in world.buildings:
        poly = Polygon(_open_ring(b.footprint), [_open_ring(h) for h in b.holes])
        for tri in shapely.constrained_delaunay_triangles(poly).geoms:
            base = len(verts)
            verts += [(x, y, b.height) for x, y in list(tri.exterior.coords)[:3]]
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


def _clutter_meshes(world: World) -> dict[str, list]:
    import open3d as o3d

    out: dict[str, list] = {"fence": [], "car": [], "pole": [], "tree": []}
    for f in world.of_kind("fence"):
        line = np.asarray(f.line, float)
        for a, b in zip(line[:-1], line[1:]):
            length = float(np.linalg.norm(b - a))
            if length < 1e-6:
                continue
            box = o3d.geometry.TriangleMesh.create_box(length, f.thickness, f.height)
            box.translate((0.0, -f.thickness / 2, 0.0))
            ang = np.arctan2(*(b - a)[::-1])
            box.rotate(o3d.geometry.get_rotation_matrix_from_xyz((0, 0, ang)), center=(0, 0, 0))
            box.translate((a[0], a[1], 0.0))
            out["fence"].append(box)
    for c in world.of_kind("car"):
        length, width, height = c.size
        box = o3d.geometry.TriangleMesh.create_box(length, width, height)
        box.translate((-length / 2, -width / 2, 0.0))
        box.rotate(o3d.geometry.get_rotation_matrix_from_xyz((0, 0, np.deg2rad(c.heading_deg))), center=(0, 0, 0))
        box.translate((c.position[0], c.position[1], 0.0))
        out["car"].append(box)
    for p in world.of_kind("pole"):
        cyl = o3d.geometry.TriangleMesh.create_cylinder(p.radius, p.height, resolution=12)
        cyl.translate((p.position[0], p.position[1], p.height / 2))
        out["pole"].append(cyl)
    for t in world.of_kind("tree"):
        trunk = o3d.geometry.TriangleMesh.create_cylinder(t.trunk_radius, t.trunk_height, resolution=10)
        trunk.translate((t.position[0], t.position[1], t.trunk_height / 2))
        crown = o3d.geometry.TriangleMesh.create_sphere(t.crown_radius, resolution=10)
        crown.translate((t.position[0], t.position[1], t.trunk_height + 0.8 * t.crown_radius))
        out["tree"] += [trunk, crown]
    return out


def build_scene(world: World, ground_margin_m: float = 200.0):
    """Return (``open3d.t.geometry.RaycastingScene``, :class:`SceneIndex`) for ``world``."""
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
    add("ground", np.array([[lo[0], lo[1], 0], [hi[0], lo[1], 0], [hi[0], hi[1], 0], [lo[0], hi[1], 0]], float),
        np.array([[0, 1, 2], [0, 2, 3]]))
    edges = building_edges(world)
    wall_gid = -1
    owner = np.zeros(0, np.int64)
    if edges:
        verts, tris, owner = _wall_mesh(edges)
        wall_gid = add("building", verts, tris)
        roof_v, roof_t = _roof_mesh(world)
        if len(roof_t):
            add("roof", roof_v, roof_t)
    for kind, meshes in _clutter_meshes(world).items():
        verts, tris = _merge(meshes)
        if len(tris):
            add(kind, verts, tris)
    return scene, SceneIndex(kinds=kinds, wall_geometry_id=wall_gid, wall_edge_of_triangle=owner, edges=edges)


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
