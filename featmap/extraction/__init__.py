"""Per-scan extraction of vertical planes as 2D ground segments (numpy in, numpy out)."""

from featmap.extraction.vertical_planes import ScanSegments, extract_segments, segments_to_world

__all__ = ["ScanSegments", "extract_segments", "segments_to_world"]
