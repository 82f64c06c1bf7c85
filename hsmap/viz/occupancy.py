"""Occupancy grids in the conventions hsmap meets, converted for display (rerun and matplotlib)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import InputError, ShapeError

__all__ = ["occupancy_to_ros", "occupancy_to_image"]


def occupancy_to_ros(grid: ArrayLike, convention: str = "auto") -> NDArray[np.uint8]:
    """Occupancy in ROS ``OccupancyGrid`` values as uint8: 0 free ... 100 occupied, 255 (= -1) unknown.

    Parameters
    ----------
    grid : ndarray of shape (H, W)
    convention : {"auto", "occupied", "probability", "image", "ros"}
        ``occupied``: bool, True = occupied. ``probability``: float in [0, 1], NaN = unknown.
        ``image``: uint8 map_server image (0 = occupied/black, 254-255 = free, 205 = unknown).
        ``ros``: int8, -1 = unknown, 0..100. ``auto`` picks by dtype in that order.
    """
    g = np.asarray(grid)
    if g.ndim != 2 or min(g.shape) < 1:
        raise ShapeError(f"occupancy grid must be a non-empty (H, W) array, got shape {g.shape}")
    if convention == "auto":
        if g.dtype == bool:
            convention = "occupied"
        elif np.issubdtype(g.dtype, np.floating):
            convention = "probability"
        elif g.dtype == np.uint8:
            convention = "image"
        elif g.dtype == np.int8:
            convention = "ros"
        else:
            raise InputError(
                f"cannot tell the occupancy convention of a {g.dtype} grid: pass convention="
                "'occupied', 'probability', 'image' or 'ros'"
            )
    if convention == "occupied":
        return np.where(g.astype(bool), 100, 0).astype(np.uint8)
    if convention == "probability":
        p = g.astype(float)
        known = np.isfinite(p)
        if np.any((p[known] < 0) | (p[known] > 1)):
            raise InputError("occupancy probabilities must lie in [0, 1] (NaN = unknown)")
        out = np.full(g.shape, 255, np.uint8)
        out[known] = np.round(p[known] * 100).astype(np.uint8)
        return out
    if convention == "image":
        v = g.astype(np.int64)
        if np.any((v < 0) | (v > 255)):
            raise InputError("map image values must lie in 0..255")
        out = np.round((255 - v) * 100 / 255).astype(np.uint8)
        out[v == 205] = 255
        return out
    if convention == "ros":
        if int(g.min()) < -1 or int(g.max()) > 100:
            raise InputError("ROS occupancy values must lie in -1..100")
        if g.dtype == np.int8:
            return g.view(np.uint8).copy()  # -1 is 255 in the same byte; a large map, no int64 copies
        v = g.astype(np.int64)
        return np.where(v < 0, 255, v).astype(np.uint8)
    raise InputError(f"unknown occupancy convention {convention!r}; use auto, occupied, probability, image, ros")


_GREY = np.round(254 - np.minimum(np.arange(256), 100) * 254 / 100).astype(np.uint8)  # ROS value -> grey level
_GREY[255] = 205  # unknown


def _ros_to_image(ros: NDArray[np.uint8]) -> NDArray[np.uint8]:
    return _GREY[ros]  # one table look-up per cell: a hospital-sized map has millions


def occupancy_to_image(grid: ArrayLike, convention: str = "auto") -> NDArray[np.uint8]:
    """map_server grey levels (H, W) uint8: free 254, occupied 0 (darker = more occupied), unknown 205."""
    return _ros_to_image(occupancy_to_ros(grid, convention))
