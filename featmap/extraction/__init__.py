"""Per-scan extraction of wall segments (numpy in, numpy out), chosen by the scan's dimension.

>>> from featmap.extraction import ExtractionConfig, extract_scan
>>> segments = extract_scan(points, 3, ExtractionConfig())   # doctest: +SKIP
"""

from featmap.extraction.base import Extractor, ScanSegments, segments_to_world, world_fields
from featmap.extraction.registry import EXTRACTORS, ExtractionConfig, extract_scan, extractor_for

__all__ = ["EXTRACTORS", "ExtractionConfig", "Extractor", "ScanSegments", "extract_scan", "extractor_for",
           "segments_to_world", "world_fields"]
