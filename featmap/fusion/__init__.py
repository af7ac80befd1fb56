"""Fusion of redundant segments: the paper's method and its two competitors, by name.

>>> from featmap.fusion import FUSION_METHODS, fuse
>>> result = fuse("proposed", segments_world, scan, config)   # doctest: +SKIP
"""

from featmap.fusion.base import FusionResult
from featmap.fusion.registry import FUSION_METHODS, FusionMethod, fuse, get_method

__all__ = ["FUSION_METHODS", "FusionMethod", "FusionResult", "fuse", "get_method"]
