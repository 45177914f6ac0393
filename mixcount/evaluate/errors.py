"""Errors of the evaluation area; all are MixcountError, so the CLI reports them as messages.

EvaluationError      base of this module's errors
  GroundTruthError   the COCO file or dataset folder is missing or malformed
  PredictionError    the prediction file is missing or malformed
"""

from __future__ import annotations

from mixcount.errors import MixcountError


class EvaluationError(MixcountError):
    """Evaluation or statistics could not be computed from the given files."""


class GroundTruthError(EvaluationError):
    """The ground-truth COCO file (or dataset folder) is missing or malformed."""


class PredictionError(EvaluationError):
    """The prediction file is missing or malformed."""
