"""Scoring fused maps: the metrics (pure functions of arrays) and the plug-ins that find references.

- :mod:`truth_metrics`: the metrics of ``shared/EVALUATION.md`` against ground-truth walls;
- :mod:`references`: ground truth from a simulated drive's ``truth/`` folder or building footprints;
- :mod:`clutter`: what segments lie on where they lie on no building wall (the simulator's objects, by kind);
- :mod:`plugins`: the evaluators a run calls when it has their reference.
"""

from featmap.evaluation.plugins import EVALUATORS, EvaluationConfig, EvaluationContext, Evaluator, Reference
from featmap.evaluation.references import load_simulator_truth, truth_from_footprints
from featmap.evaluation.truth_metrics import GroundTruth, truth_metrics

__all__ = ["EVALUATORS", "EvaluationConfig", "EvaluationContext", "Evaluator", "GroundTruth", "Reference",
           "load_simulator_truth", "truth_from_footprints", "truth_metrics"]
