"""Evaluation: pose errors, ATE/RPE, the Freiburg relations metric, Bormann room-segmentation precision/recall.

Pure functions on arrays and small dataclasses; file reading lives in :mod:`hsmap.io` and the readers.
"""

from .segmentation import SegmentationScores, ground_truth_rooms, segmentation_scores

__all__ = ["SegmentationScores", "ground_truth_rooms", "segmentation_scores"]
