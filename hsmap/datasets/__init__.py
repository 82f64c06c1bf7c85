"""Readers that turn recorded or simulated robot data into :class:`Frame` sequences; :func:`open_dataset` picks
the reader from what a path is."""

from .frames import Dataset, Frame, LaserScan2D
from .open import open_dataset

__all__ = ["Dataset", "Frame", "LaserScan2D", "open_dataset"]
