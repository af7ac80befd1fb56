"""An interactive HTML map (folium / Leaflet): a toggleable layer per method, trajectory and ground truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from featmap.geo import GeoFrame
from featmap.io.atomic import atomic_write_text
from featmap.io.layers import MapLayer


def write_html_map(path: str | Path, layers: list[MapLayer], frame: GeoFrame, trajectory: np.ndarray | None = None,
                   trajectory_color: str = "#e377c2", tiles: str = "OpenStreetMap") -> Path:
    """Write a self-contained Leaflet map, a toggleable layer each. A layer with support (fused features)
    draws each feature with a popup of its support and length; a layer without (raw segments, ground
    truth) is one GeoJSON object.

    Args:
        layers: local-frame segments to draw, in order (the first drawn below the others).
        trajectory: (F, 2) local vehicle positions.
    """
    import folium

    all_pts = [np.asarray(layer.segments, float).reshape(-1, 2) for layer in layers if len(layer.segments)]
    if trajectory is not None:
        all_pts.append(np.asarray(trajectory, float))
    pts = np.concatenate(all_pts) if all_pts else np.zeros((1, 2))
    lat, lon = frame.to_wgs84(pts[:, 0], pts[:, 1])
    fmap = folium.Map(location=[float(np.mean(lat)), float(np.mean(lon))], zoom_start=17, tiles=tiles,
                      max_zoom=22, control_scale=True)
    fmap.fit_bounds([[float(lat.min()), float(lon.min())], [float(lat.max()), float(lon.max())]])

    def add_lines(layer: MapLayer):
        name, support = layer.name, layer.support
        group = folium.FeatureGroup(name=name, show=layer.show)
        segments = np.asarray(layer.segments, float).reshape(-1, 4)
        la1, lo1 = frame.to_wgs84(segments[:, 0], segments[:, 1])
        la2, lo2 = frame.to_wgs84(segments[:, 2], segments[:, 3])
        if support is None:
            # Context layers (raw segments, ground truth) can hold tens of thousands of lines: one GeoJSON
            # object without popups instead of a polyline each keeps the page small and fast to write.
            lines = [[[float(lo1[k]), float(la1[k])], [float(lo2[k]), float(la2[k])]] for k in range(len(segments))]
            style = {"color": layer.color, "weight": layer.width, "opacity": 0.9}
            folium.GeoJson({"type": "Feature", "properties": {},
                            "geometry": {"type": "MultiLineString", "coordinates": lines}},
                           style_function=lambda _feature, style=style: style).add_to(group)
        for k in range(len(segments) if support is not None else 0):
            length = float(np.hypot(*(segments[k, 2:] - segments[k, :2])))
            text = f"<b>{name}</b> #{k}<br>length {length:.2f} m<br>support {int(support[k])} segments"
            folium.PolyLine([[float(la1[k]), float(lo1[k])], [float(la2[k]), float(lo2[k])]],
                            color=layer.color, weight=layer.width,
                            opacity=0.9, popup=folium.Popup(text, max_width=250)).add_to(group)
        group.add_to(fmap)

    for layer in layers:
        add_lines(layer)
    if trajectory is not None and len(trajectory) > 1:
        la, lo = frame.to_wgs84(trajectory[:, 0], trajectory[:, 1])
        group = folium.FeatureGroup(name="trajectory")
        folium.PolyLine(np.column_stack([la, lo]).tolist(), color=trajectory_color, weight=2, dash_array="6",
                        popup="vehicle trajectory").add_to(group)
        group.add_to(fmap)
    folium.LayerControl(collapsed=False).add_to(fmap)
    return atomic_write_text(path, fmap.get_root().render())
