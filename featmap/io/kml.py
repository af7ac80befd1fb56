"""KML for Google Earth (simplekml): one folder per layer, styled lines, descriptions with support and length.

This is how a user puts a featmap map on Google's imagery: open ``map.kml`` in Google Earth.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from featmap.errors import InputFileError
from featmap.geo import GeoFrame
from featmap.io.atomic import atomic_write_text
from featmap.io.layers import MapLayer


def kml_color(hex_rgb: str) -> str:
    """``#rrggbb`` -> KML's opaque ``aabbggrr``."""
    rr, gg, bb = hex_rgb[1:3], hex_rgb[3:5], hex_rgb[5:7]
    return f"ff{bb}{gg}{rr}".lower()


def write_kml(path: str | Path, layers: list[MapLayer], frame: GeoFrame, trajectory: np.ndarray | None = None,
              trajectory_color: str = "#ff00ff") -> Path:
    """Write ``layers`` (local-frame segments) as KML folders, one per layer, in WGS84.

    ``trajectory`` (F, 2) local positions becomes a path in its own folder.
    """
    import simplekml
    from simplekml.base import Kmlable

    # simplekml numbers its elements with a class-wide counter; start it afresh so that the same map
    # gives the same file however many maps this process wrote before (batch workers write many).
    Kmlable._globalid = 0
    kml = simplekml.Kml(name="featmap")
    for layer in layers:
        name, support = layer.name, layer.support
        folder = kml.newfolder(name=name)
        segments = np.asarray(layer.segments, float).reshape(-1, 4)
        lat1, lon1 = frame.to_wgs84(segments[:, 0], segments[:, 1])
        lat2, lon2 = frame.to_wgs84(segments[:, 2], segments[:, 3])
        for k in range(len(segments)):
            line = folder.newlinestring(name=f"{name} {k}",
                                        coords=[(float(lon1[k]), float(lat1[k])), (float(lon2[k]), float(lat2[k]))])
            length = float(np.hypot(*(segments[k, 2:] - segments[k, :2])))
            line.description = f"length {length:.2f} m" + (f", support {int(support[k])}" if support is not None else "")
            line.style.linestyle.color = kml_color(layer.color)
            line.style.linestyle.width = layer.width
    if trajectory is not None and len(trajectory) > 1:
        folder = kml.newfolder(name="trajectory")
        lat, lon = frame.to_wgs84(trajectory[:, 0], trajectory[:, 1])
        path_line = folder.newlinestring(name="trajectory", coords=list(zip(lon.tolist(), lat.tolist())))
        path_line.style.linestyle.color = kml_color(trajectory_color)
        path_line.style.linestyle.width = 2
    return atomic_write_text(path, kml.kml())


def read_kml(path: str | Path, frame: GeoFrame) -> dict[str, np.ndarray]:
    """Read a featmap KML back: folder name -> local-frame segments (M, 4) (two-point lines only)."""
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, FileNotFoundError) as exc:
        raise InputFileError(path, f"not a readable KML file ({exc})") from None
    ns = {"k": root.tag.split("}")[0].strip("{")} if root.tag.startswith("{") else {"k": ""}
    out: dict[str, np.ndarray] = {}
    for folder in root.iter(f"{{{ns['k']}}}Folder"):
        name = folder.find("k:name", ns).text
        segs = []
        for coords in folder.iter(f"{{{ns['k']}}}coordinates"):
            pts = [tuple(map(float, c.split(",")[:2])) for c in coords.text.split()]
            if len(pts) == 2:
                (lon1, lat1), (lon2, lat2) = pts
                x, y = frame.to_local(np.array([lat1, lat2]), np.array([lon1, lon2]))
                segs.append([x[0], y[0], x[1], y[1]])
        out[name] = np.asarray(segs, float).reshape(-1, 4)
    return out
