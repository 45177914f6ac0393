"""Counting evaluation (MAE, RMSE, NAE, Acc10%) and dataset statistics for mixcount datasets.

Engine-free: reads COCO JSON files and prediction JSON files; plots with matplotlib's Agg backend.
"""

from mixcount.errors import EvaluationError, GroundTruthError, PredictionError

__all__ = ["EvaluationError", "GroundTruthError", "PredictionError"]
