"""Evaluation: pose errors, ATE/RPE, the Freiburg relations metric, Bormann room-segmentation precision/recall.

Pure functions on arrays and small dataclasses; file reading lives in :mod:`hsmap.io`, :mod:`hsmap.trajectory` and the readers.
"""

from .segmentation import SegmentationScores, ground_truth_rooms, segmentation_scores
from .trajectory import (
    DEFAULT_MAX_DT,
    Alignment,
    DeltaUnit,
    ErrorResult,
    PoseErrors,
    PoseRelation,
    RelationsResult,
    Statistics,
    align,
    associate,
    ate,
    evaluate_trajectory,
    pose_errors,
    relation_errors,
    relations_error,
    rpe,
    umeyama,
)

__all__ = [
    "DEFAULT_MAX_DT",
    "Alignment",
    "DeltaUnit",
    "ErrorResult",
    "PoseErrors",
    "PoseRelation",
    "RelationsResult",
    "Statistics",
    "align",
    "associate",
    "ate",
    "evaluate_trajectory",
    "pose_errors",
    "relation_errors",
    "relations_error",
    "rpe",
    "umeyama",
    "SegmentationScores",
    "ground_truth_rooms",
    "segmentation_scores",
]
