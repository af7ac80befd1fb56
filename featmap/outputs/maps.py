"""Map outputs: GeoJSON (WGS84), KML for Google Earth, an interactive HTML map, an overview PNG."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from featmap.fusion import FusionResult
from featmap.io.geojson import write_fused_geojson, write_segments_geojson
from featmap.io.layers import MapLayer
from featmap.outputs.base import OutputConfig, RunProducts
from featmap.plotting.basemap import Tiles
from featmap.plotting.style import SEGMENT_COLOR, TRAJECTORY_COLOR, TRUTH_COLOR, method_color


def distinct_scans(labels: np.ndarray, scan: np.ndarray, n_features: int) -> np.ndarray:
    """(M,) number of different scans among the members of each fused feature (labels (N,), scan (N,))."""
    keep = labels >= 0
    pairs = np.unique(np.stack([labels[keep], scan[keep]]), axis=1)
    return np.bincount(pairs[0], minlength=n_features) if pairs.size else np.zeros(n_features, np.int64)


def method_layers(results: dict[str, FusionResult]) -> list[MapLayer]:
    return [MapLayer(name, r.segments, r.support, method_color(name), width=3) for name, r in results.items()]


class FusedGeojson:
    name = "fused_<method>.geojson"
    needs_geo = True

    def enabled(self, config: OutputConfig) -> bool:
        return config.geojson

    def write(self, products: RunProducts, folder: Path) -> list[str]:
        names = []
        for method, r in products.results.items():
            scans = distinct_scans(r.labels, products.table.scan, len(r))
            write_fused_geojson(folder / f"fused_{method}.geojson", r.segments, r.support, products.geo_frame,
                                method, scans)
            names.append(f"fused_{method}.geojson")
        return names


class LayersGeojson:
    """The extracted segments, the trajectory and (when known) the ground truth as GeoJSON."""

    name = "segments/trajectory/truth.geojson"
    needs_geo = True

    def enabled(self, config: OutputConfig) -> bool:
        return config.geojson

    def write(self, products: RunProducts, folder: Path) -> list[str]:
        frame, table, traj = products.geo_frame, products.table, products.trajectory
        write_segments_geojson(folder / "segments.geojson", table.segments, frame,
                               [{"scan": int(s)} for s in table.scan], {"layer": "extracted"})
        write_segments_geojson(folder / "trajectory.geojson", np.column_stack([traj[:-1], traj[1:]]), frame,
                               common={"layer": "trajectory"})
        names = ["segments.geojson", "trajectory.geojson"]
        if products.truth is not None:
            write_segments_geojson(folder / "truth.geojson", products.truth.walls, frame,
                                   [{"building": str(b)} for b in products.truth.building], {"layer": "truth"})
            names.append("truth.geojson")
        return names


class RefinedTrajectoryGeojson:
    """The refined trajectory as GeoJSON (WGS84), when pose refinement ran."""

    name = "trajectory_refined.geojson"
    needs_geo = True

    def enabled(self, config: OutputConfig) -> bool:
        return config.geojson

    def write(self, products: RunProducts, folder: Path) -> list[str]:
        if products.corrections is None:
            return []
        traj = products.trajectory
        props = [{"frame": int(f), "dx_m": round(float(c[0]), 4), "dy_m": round(float(c[1]), 4),
                  "dyaw_deg": round(float(np.rad2deg(c[2])), 5)} for f, c in zip(products.frames[1:], products.corrections[1:])]
        write_segments_geojson(folder / "trajectory_refined.geojson", np.column_stack([traj[:-1], traj[1:]]),
                               products.geo_frame, props, {"layer": "trajectory_refined"})
        return ["trajectory_refined.geojson"]


class Kml:
    name = "map.kml"
    needs_geo = True

    def enabled(self, config: OutputConfig) -> bool:
        return config.kml

    def write(self, products: RunProducts, folder: Path) -> list[str]:
        from featmap.io.kml import write_kml

        write_kml(folder / "map.kml", method_layers(products.results), products.geo_frame,
                  trajectory=products.trajectory, trajectory_color=TRAJECTORY_COLOR)
        return ["map.kml"]


class HtmlMap:
    name = "map.html"
    needs_geo = True

    def enabled(self, config: OutputConfig) -> bool:
        return config.html

    def write(self, products: RunProducts, folder: Path) -> list[str]:
        from featmap.io.html_map import write_html_map

        layers = []
        if products.truth is not None:
            layers.append(MapLayer("truth", products.truth.walls, None, TRUTH_COLOR))
        layers.append(MapLayer("segments", products.table.segments, None, SEGMENT_COLOR, show=False))
        layers += [MapLayer(name, r.segments, r.support, method_color(name), width=4)
                   for name, r in products.results.items()]
        write_html_map(folder / "map.html", layers, products.geo_frame, products.trajectory, TRAJECTORY_COLOR)
        return ["map.html"]


def tiles_of(config: OutputConfig) -> Tiles:
    return Tiles(config.tile_source, config.tile_cache_dir, config.tile_timeout_s)


class OverviewPng:
    """Every method's fused features over map tiles (over the ground truth without a geo origin or tiles)."""

    name = "map_overview.png"
    needs_geo = False

    def enabled(self, config: OutputConfig) -> bool:
        return config.plots

    def write(self, products: RunProducts, folder: Path) -> list[str]:
        from featmap.plotting.overview import overview_plot

        if not products.results:
            return []
        overview_plot(folder / "map_overview.png", {n: r.segments for n, r in products.results.items()},
                      products.geo_frame, products.trajectory, products.truth, tiles_of(products.output))
        return ["map_overview.png"]
