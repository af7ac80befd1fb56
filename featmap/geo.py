"""KITTI's local metric frame <-> WGS84, exactly as pykitti builds it from OXTS.

pykitti projects every OXTS packet with a Mercator projection whose scale is ``cos(lat0)`` of the
*first* packet, and puts the origin at the first packet's position (x east, y north, metres).
:class:`GeoFrame` holds that first packet's latitude/longitude and converts both ways.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from numbers import Real

import numpy as np

from featmap.errors import ConfigError

EARTH_RADIUS_M = 6378137.0
"""The earth radius pykitti uses in its Mercator projection."""


def latlon_to_mercator(lat_deg, lon_deg, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """pykitti's Mercator projection of WGS84 degrees to metres (``scale = cos(lat0)``)."""
    lat = np.asarray(lat_deg, float)
    lon = np.asarray(lon_deg, float)
    mx = scale * lon * np.pi * EARTH_RADIUS_M / 180.0
    my = scale * EARTH_RADIUS_M * np.log(np.tan((90.0 + lat) * np.pi / 360.0))
    return mx, my


def mercator_to_latlon(mx, my, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`latlon_to_mercator`: metres to WGS84 degrees."""
    mx = np.asarray(mx, float)
    my = np.asarray(my, float)
    lon = mx * 180.0 / (np.pi * EARTH_RADIUS_M * scale)
    lat = 360.0 / np.pi * np.arctan(np.exp(my / (scale * EARTH_RADIUS_M))) - 90.0
    return lat, lon


@dataclass(frozen=True)
class GeoFrame:
    """The local metric frame of one drive: origin and Mercator scale from its first OXTS packet.

    Attributes:
        lat0_deg, lon0_deg: WGS84 position of the first OXTS packet (the local origin), -90 < lat < 90
            (the Mercator projection has no poles) and -180 <= lon <= 180.
        alt0_m: its altitude (the local z origin).

    Raises:
        ConfigError: a value that is not a finite number or out of range (one line naming it); callers that
            read it from a file catch it to name the file.
    """

    lat0_deg: float
    lon0_deg: float
    alt0_m: float = 0.0

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, Real):
                raise ConfigError(f"geo origin {f.name} {value!r} is not a number")
            if not math.isfinite(value):
                raise ConfigError(f"geo origin {f.name} {value!r} is not a finite number")
        if not -90 < self.lat0_deg < 90:
            raise ConfigError(f"geo origin latitude {self.lat0_deg:.10g} is outside -90 < lat < 90 degrees")
        if not -180 <= self.lon0_deg <= 180:
            raise ConfigError(f"geo origin longitude {self.lon0_deg:.10g} is outside -180 <= lon <= 180 degrees")

    @property
    def scale(self) -> float:
        return float(np.cos(np.deg2rad(self.lat0_deg)))

    def _origin(self) -> tuple[float, float]:
        mx, my = latlon_to_mercator(self.lat0_deg, self.lon0_deg, self.scale)
        return float(mx), float(my)

    def to_local(self, lat_deg, lon_deg) -> tuple[np.ndarray, np.ndarray]:
        """WGS84 degrees -> local x east, y north (metres)."""
        mx, my = latlon_to_mercator(lat_deg, lon_deg, self.scale)
        ox, oy = self._origin()
        return mx - ox, my - oy

    def to_wgs84(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """Local x east, y north (metres) -> WGS84 (lat, lon) degrees."""
        ox, oy = self._origin()
        return mercator_to_latlon(np.asarray(x, float) + ox, np.asarray(y, float) + oy, self.scale)

    def to_dict(self) -> dict:
        return {"lat0_deg": self.lat0_deg, "lon0_deg": self.lon0_deg, "alt0_m": self.alt0_m}


def reproject(points: np.ndarray, src: GeoFrame, dst: GeoFrame) -> np.ndarray:
    """(K, 2) points of the local frame of ``src`` in the local frame of ``dst`` (through WGS84).

    Both frames are pykitti's Mercator frames; the round trip is analytic, so a point of one drive lands
    where the other drive's frame puts the same place on earth. Lengths change by the ratio of the two
    frames' scales, cos(lat0 of dst) / cos(lat0 of src) (2e-5 for origins 100 m apart in latitude at
    49 deg): each frame is metric only near its own origin. The same origin returns a copy.
    """
    points = np.asarray(points, float).reshape(-1, 2)
    if (src.lat0_deg, src.lon0_deg) == (dst.lat0_deg, dst.lon0_deg):
        return points.copy()
    lat, lon = src.to_wgs84(points[:, 0], points[:, 1])
    x, y = dst.to_local(lat, lon)
    return np.column_stack([x, y])


def reproject_segments(segments: np.ndarray, src: GeoFrame, dst: GeoFrame) -> np.ndarray:
    """(M, 4) segments ``x1, y1, x2, y2`` of the frame of ``src`` in the frame of ``dst``."""
    segments = np.asarray(segments, float).reshape(-1, 4)
    return np.column_stack([reproject(segments[:, :2], src, dst), reproject(segments[:, 2:], src, dst)])


def open_ring(points) -> list[tuple]:
    """A polygon ring's vertices once each, as tuples: a vertex repeated in a row (OSM exports have them)
    counts once, and the closing vertex (GeoJSON rings end where they start) is dropped."""
    points = [tuple(p) for p in points]
    points = [p for k, p in enumerate(points) if k == 0 or p != points[k - 1]]
    return points[:-1] if len(points) > 1 and points[0] == points[-1] else points
