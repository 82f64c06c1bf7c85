"""Readers that turn recorded or simulated robot data into :class:`Frame` sequences."""

from .frames import Dataset, Frame, LaserScan2D

__all__ = ["Dataset", "Frame", "LaserScan2D"]
