"""Readers that turn recorded or simulated robot data into :class:`Frame` sequences."""

from .frames import Frame, LaserScan2D

__all__ = ["Frame", "LaserScan2D"]
