"""The evaluation area's errors, defined in the one exception tree (:mod:`mixcount.errors`):

EvaluationError      base of the evaluation errors
  GroundTruthError   the COCO file or dataset folder is missing or malformed
  PredictionError    the prediction file is missing or malformed
"""

from __future__ import annotations

from mixcount.errors import EvaluationError, GroundTruthError, PredictionError

__all__ = ["EvaluationError", "GroundTruthError", "PredictionError"]
