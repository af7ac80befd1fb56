"""An interactive HTML map (folium / Leaflet): a toggleable layer per method, trajectory and ground truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from featmap.geo import GeoFrame
from featmap.io.atomic import atomic_write_text

_COLORS = {"proposed": "#d62728", "meanshift": "#1f77b4", "density": "#2ca02c", "segments": "#ff7f0e",
           "truth": "#555555"}


def write_html_map(path: str | Path, layers: dict[str, tuple[np.ndarray, np.ndarray | None]], frame: GeoFrame,
                   trajectory: np.ndarray | None = None, truth_walls: np.ndarray | None = None,
                   tiles: str = "OpenStreetMap") -> Path:
    """Write a self-contained Leaflet map; each fused feature has a popup with its support and length.

    Args:
        layers: name -> (segments (M, 4) local frame, support (M,) or None).
        trajectory: (F, 2) local vehicle positions.
        truth_walls: (W, 4) ground-truth walls, local frame.
    """
    import folium

    all_pts = [np.asarray(s, float).reshape(-1, 2) for s, _ in layers.values() if len(s)]
    if trajectory is not None:
        all_pts.append(np.asarray(trajectory, float))
    pts = np.concatenate(all_pts) if all_pts else np.zeros((1, 2))
    lat, lon = frame.to_wgs84(pts[:, 0], pts[:, 1])
    fmap = folium.Map(location=[float(np.mean(lat)), float(np.mean(lon))], zoom_start=17, tiles=tiles,
                      max_zoom=22, control_scale=True)
    fmap.fit_bounds([[float(lat.min()), float(lon.min())], [float(lat.max()), float(lon.max())]])

    def add_lines(name, segments, support, show=True):
        group = folium.FeatureGroup(name=name, show=show)
        segments = np.asarray(segments, float).reshape(-1, 4)
        la1, lo1 = frame.to_wgs84(segments[:, 0], segments[:, 1])
        la2, lo2 = frame.to_wgs84(segments[:, 2], segments[:, 3])
        for k in range(len(segments)):
            length = float(np.hypot(*(segments[k, 2:] - segments[k, :2])))
            text = f"<b>{name}</b> #{k}<br>length {length:.2f} m"
            if support is not None:
                text += f"<br>support {int(support[k])} segments"
            folium.PolyLine([[float(la1[k]), float(lo1[k])], [float(la2[k]), float(lo2[k])]],
                            color=_COLORS.get(name, "#9467bd"), weight=4 if support is not None else 2,
                            opacity=0.9, popup=folium.Popup(text, max_width=250)).add_to(group)
        group.add_to(fmap)

    if truth_walls is not None and len(truth_walls):
        add_lines("truth", truth_walls, None)
    for name, (segments, support) in layers.items():
        add_lines(name, segments, support, show=name != "segments")
    if trajectory is not None and len(trajectory) > 1:
        la, lo = frame.to_wgs84(trajectory[:, 0], trajectory[:, 1])
        group = folium.FeatureGroup(name="trajectory")
        folium.PolyLine(np.column_stack([la, lo]).tolist(), color="#e377c2", weight=2, dash_array="6",
                        popup="vehicle trajectory").add_to(group)
        group.add_to(fmap)
    folium.LayerControl(collapsed=False).add_to(fmap)
    return atomic_write_text(path, fmap.get_root().render())
