"""Pose refinement: correct the scans' poses from their own segments before fusion.

Numpy in, numpy out (:class:`RefinementInput` -> :class:`RefinementResult`): planar corrections
``dx, dy, dyaw`` per scan in the world frame (:mod:`featmap.refinement.base`). Methods are registered in
:mod:`featmap.refinement.registry` (``none``, ``pose_graph``, ``scan_to_map``) and configured under
``refinement.<name>``.
"""

from featmap.refinement.base import (RefinementInput, RefinementMethod, RefinementResult, apply_corrections,
                                     planar_difference)
from featmap.refinement.registry import METHODS, REFINEMENT_METHODS, RefinementConfig, get_refinement, refine

__all__ = ["METHODS", "REFINEMENT_METHODS", "RefinementConfig", "RefinementInput", "RefinementMethod",
           "RefinementResult", "apply_corrections", "get_refinement", "planar_difference", "refine"]
