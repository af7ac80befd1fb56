"""The ground of a world: a sloped plane with raised sidewalks (curbs) outside the streets.

Heights are in the world frame (metres, z up). A flat world (:attr:`Ground.is_flat`) is the plane
z = 0 everywhere, exactly as before grades and curbs existed.
"""

from __future__ import annotations

import numpy as np

from featmap.simulation.worlds import Ground


class GroundSurface:
    """Heights of a :class:`Ground`: the street surface, and the sidewalk ``curb_height`` above it.

    Args:
        ground: the world's ground model.
    """

    def __init__(self, ground: Ground):
        self.ground = ground
        self.grade = np.asarray(ground.grade, float)
        self.streets = street_area(ground)

    @property
    def is_flat(self) -> bool:
        return self.ground.is_flat

    def plane_height(self, xy: np.ndarray) -> np.ndarray:
        """(N,) height of the street surface (the sloped plane) at (N, 2) points."""
        xy = np.asarray(xy, float).reshape(-1, 2)
        return xy @ self.grade

    def on_street(self, xy: np.ndarray) -> np.ndarray:
        """(N,) True where the (N, 2) points lie on a street's carriageway (edges included)."""
        import shapely

        xy = np.asarray(xy, float).reshape(-1, 2)
        if self.streets is None:
            return np.zeros(len(xy), bool)
        return shapely.intersects_xy(self.streets, xy[:, 0], xy[:, 1])

    def height(self, xy: np.ndarray) -> np.ndarray:
        """(N,) ground height at (N, 2) points: the plane, plus the curb height off the streets."""
        z = self.plane_height(xy)
        if self.streets is not None and self.ground.curb_height > 0:
            z = z + np.where(self.on_street(xy), 0.0, self.ground.curb_height)
        return z

    def mesh(self, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Triangles of the ground over the box ``lo``-``hi`` (2,): (vertices (V, 3), triangles (T, 3)).

        Streets at the plane's height, the rest ``curb_height`` higher, and a vertical curb face
        along every street edge inside the box.
        """
        from shapely.geometry import box

        area = box(lo[0], lo[1], hi[0], hi[1])
        if self.streets is None or self.ground.curb_height == 0:
            return _triangulate(area, self.grade, 0.0)
        streets = self.streets.intersection(area)
        sidewalks = area.difference(self.streets)
        curb = self.ground.curb_height
        v1, t1 = _triangulate(streets, self.grade, 0.0)
        v2, t2 = _triangulate(sidewalks, self.grade, curb)
        v3, t3 = _curb_faces(self.streets.boundary.intersection(area), self.grade, curb)
        verts, tris, offset = [], [], 0
        for v, t in ((v1, t1), (v2, t2), (v3, t3)):
            verts.append(v)
            tris.append(t + offset)
            offset += len(v)
        return np.concatenate(verts), np.concatenate(tris)


def street_area(ground: Ground):
    """The union of the streets' carriageways (a shapely geometry; flat-capped, mitred), or None."""
    if not ground.streets:
        return None
    from shapely import union_all
    from shapely.geometry import LineString

    parts = [LineString(s.line).buffer(s.width / 2, cap_style="flat", join_style="mitre") for s in ground.streets]
    return union_all(parts)


def _polygons(geom) -> list:
    if geom.is_empty:
        return []
    if geom.geom_type == "Polygon":
        return [geom]
    return [g for g in getattr(geom, "geoms", []) if g.geom_type == "Polygon" and not g.is_empty]


def _triangulate(geom, grade: np.ndarray, lift: float) -> tuple[np.ndarray, np.ndarray]:
    import shapely

    verts = []
    for poly in _polygons(geom):
        for tri in shapely.constrained_delaunay_triangles(poly).geoms:
            verts += list(tri.exterior.coords)[:3]
    if not verts:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    xy = np.asarray(verts, float)
    z = xy @ grade + lift
    return np.column_stack([xy, z]), np.arange(len(xy)).reshape(-1, 3)


def _curb_faces(edges, grade: np.ndarray, curb: float) -> tuple[np.ndarray, np.ndarray]:
    """Vertical quads from the street surface up to the sidewalk along the street edges (a shapely line geometry)."""
    verts, tris = [], []
    lines = [edges] if edges.geom_type in ("LineString", "LinearRing") else list(getattr(edges, "geoms", []))
    for line in lines:
        if line.is_empty or line.geom_type not in ("LineString", "LinearRing"):
            continue
        xy = np.asarray(line.coords, float)
        for a, b in zip(xy[:-1], xy[1:]):
            za, zb = float(a @ grade), float(b @ grade)
            base = len(verts)
            verts += [(a[0], a[1], za), (b[0], b[1], zb), (b[0], b[1], zb + curb), (a[0], a[1], za + curb)]
            tris += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
    return np.asarray(verts, float).reshape(-1, 3), np.asarray(tris, np.int64).reshape(-1, 3)
