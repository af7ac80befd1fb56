"""Fusion of redundant segments: the paper's method and its two competitors, by name.

>>> from featmap.fusion import METHODS, FusionConfig, fuse
>>> result = fuse("proposed", segments_world, scan, FusionConfig())   # doctest: +SKIP
"""

from featmap.fusion.base import FusionMethod, FusionResult
from featmap.fusion.registry import (FUSION_METHODS, METHODS, FusionConfig, fuse, get_method, prepare_method,
                                    resolve_methods)

__all__ = ["FUSION_METHODS", "METHODS", "FusionConfig", "FusionMethod", "FusionResult", "fuse", "get_method",
           "prepare_method", "resolve_methods"]
