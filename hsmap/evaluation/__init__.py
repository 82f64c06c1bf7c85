"""Evaluation: pose errors, ATE/RPE, the Freiburg relations metric, Bormann room-segmentation precision/recall.

Pure functions on arrays and small dataclasses; file reading lives in :mod:`hsmap.io` and the readers.
"""
