"""Per-scan wall extraction: one LiDAR scan (velodyne frame) -> 2D wall segments (numpy in, numpy out).

Two extractors, chosen by ``extraction.method``:

- ``vertical_structure`` (default, :mod:`featmap.extraction.vertical_structure`): thin, tall lines of
  the top view, from a grid of returns above a local ground;
- ``ransac_planes`` (:mod:`featmap.extraction.vertical_planes`): sequential Open3D RANSAC planes.

The extractor modules are imported when first used, so that ``featmap.config`` can compose their
config models without an import cycle.
"""

from __future__ import annotations

from featmap.extraction.segments import ScanSegments, segments_to_world

__all__ = ["METHODS", "ScanSegments", "extract_segments", "segments_to_world"]

METHODS = ("vertical_structure", "ransac_planes")


def extract_segments(points, config=None, timings: dict[str, float] | None = None) -> ScanSegments:
    """Wall segments of one scan by the extractor that ``config`` names.

    Args:
        points: (N, 3) or (N, 4) velodyne-frame points (x forward, y left, z up; metres).
        config: a ``featmap.config.ExtractionConfig`` (its ``method`` picks the extractor; default:
            the default config), or a ``VerticalStructureConfig`` to run that extractor directly.
        timings: if given, seconds spent per stage are added to it.
    Returns:
        ScanSegments in the velodyne frame (possibly empty).
    Raises:
        FeatmapError: points that are not an (N, >=3) numeric array, or with NaN/inf coordinates.
    """
    from featmap.extraction.vertical_structure import (VerticalStructureConfig, extract_vertical_structure,
                                                       validated_xyz)

    if isinstance(config, VerticalStructureConfig):
        return extract_vertical_structure(points, config, timings)
    if config is None:
        from featmap.config import ExtractionConfig

        config = ExtractionConfig()
    if config.method == "ransac_planes":
        from featmap.extraction.vertical_planes import extract_segments as extract_ransac_planes

        xyz = validated_xyz(points)
        return extract_ransac_planes(xyz, config, timings)
    return extract_vertical_structure(points, config.vertical_structure, timings)
