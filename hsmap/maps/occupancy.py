"""Occupancy grids (:class:`OccupancyGrid`) and THE conversion between world (x, y) in metres and image (row, col)
(:class:`GridGeometry`).

Convention (ROS map_server, used by the paper): an image of shape (H, W), row 0 at the top; ``origin`` is the
world (x, y) of the lower-left corner of the lower-left pixel (row H-1, col 0); ``resolution`` is metres per
pixel. The centre of pixel (row, col) is at::

    x = origin_x + (col + 0.5) * resolution
    y = origin_y + (H - 1 - row + 0.5) * resolution

Every other module converts through :class:`GridGeometry`; nothing else flips rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import InputError, ShapeError

__all__ = ["GridGeometry", "OccupancyGrid", "UNKNOWN", "FREE", "OCCUPIED", "PGM_FREE", "PGM_OCCUPIED", "PGM_UNKNOWN",
           "IMAGE_FREE_MIN"]


@dataclass(frozen=True)
class GridGeometry:
    """Where an (H, W) image lies in the world.

    Attributes
    ----------
    shape : tuple of int
        (H, W) = (rows, cols).
    resolution : float
        Metres per pixel, > 0.
    origin : tuple of float
        World (x, y) of the lower-left corner of pixel (H-1, 0).
    """

    shape: tuple[int, int]
    resolution: float
    origin: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        if not (np.isfinite(self.resolution) and self.resolution > 0):
            raise InputError(f"resolution must be a positive number of metres per pixel, got {self.resolution}")
        if len(self.shape) != 2 or min(self.shape) < 1:
            raise InputError(f"grid shape must be (rows, cols) with both >= 1, got {self.shape}")
        object.__setattr__(self, "shape", (int(self.shape[0]), int(self.shape[1])))
        object.__setattr__(self, "origin", (float(self.origin[0]), float(self.origin[1])))

    @classmethod
    def covering(cls, xy_min: ArrayLike, xy_max: ArrayLike, resolution: float, margin: float = 0.0) -> GridGeometry:
        """The smallest grid at ``resolution`` covering the box [xy_min, xy_max] plus ``margin`` metres."""
        lo = np.asarray(xy_min, dtype=float) - margin
        hi = np.asarray(xy_max, dtype=float) + margin
        if resolution <= 0:
            raise InputError(f"resolution must be > 0 metres per pixel, got {resolution}")
        w, h = np.maximum(np.ceil((hi - lo) / resolution).astype(int), 1)
        return cls((int(h), int(w)), float(resolution), (float(lo[0]), float(lo[1])))

    @property
    def height(self) -> int:
        return self.shape[0]

    @property
    def width(self) -> int:
        return self.shape[1]

    def world_to_pixel(self, xy: ArrayLike) -> NDArray[np.float64]:
        """Continuous (row, col) of world points (..., 2); pixel centres are at integer values."""
        xy = np.asarray(xy, dtype=float)
        col = (xy[..., 0] - self.origin[0]) / self.resolution - 0.5
        row = self.shape[0] - 1 - ((xy[..., 1] - self.origin[1]) / self.resolution - 0.5)
        return np.stack([row, col], -1)

    def world_to_index(self, xy: ArrayLike) -> NDArray[np.int64]:
        """Integer (row, col) of the pixels containing world points (..., 2) (may lie outside the image)."""
        return np.floor(self.world_to_pixel(xy) + 0.5).astype(np.int64)

    def pixel_to_world(self, rc: ArrayLike) -> NDArray[np.float64]:
        """World (x, y) of (row, col) pixel coordinates (..., 2); integers give pixel centres."""
        rc = np.asarray(rc, dtype=float)
        x = self.origin[0] + (rc[..., 1] + 0.5) * self.resolution
        y = self.origin[1] + (self.shape[0] - 1 - rc[..., 0] + 0.5) * self.resolution
        return np.stack([x, y], -1)

    def inside(self, rc: ArrayLike) -> NDArray[np.bool_]:
        """Whether integer (row, col) indices (..., 2) lie in the image."""
        rc = np.asarray(rc)
        return (rc[..., 0] >= 0) & (rc[..., 0] < self.shape[0]) & (rc[..., 1] >= 0) & (rc[..., 1] < self.shape[1])

    def extent(self) -> tuple[float, float, float, float]:
        """(left, right, bottom, top) in world metres, for matplotlib's ``imshow(extent=...)``."""
        x0, y0 = self.origin
        return (x0, x0 + self.shape[1] * self.resolution, y0, y0 + self.shape[0] * self.resolution)


# --------------------------------------------------------------------------------------------------------------
# Occupancy grids
# --------------------------------------------------------------------------------------------------------------

#: Cell values of :class:`OccupancyGrid` (those of ROS ``nav_msgs/OccupancyGrid``).
UNKNOWN, FREE, OCCUPIED = -1, 0, 100

#: Gray values map_server's ``trinary`` mode writes (and the benchmark's ``*_scan`` maps use).
PGM_FREE, PGM_OCCUPIED, PGM_UNKNOWN = 254, 0, 205

#: Default free-space rule for plain images (no YAML): gray value >= 250 is free (the IPA benchmark's rule).
IMAGE_FREE_MIN = 250

@dataclass
class OccupancyGrid:
    """A 2D occupancy grid: cell states plus where the image lies in the world.

    Attributes
    ----------
    data : ndarray of shape (H, W), int8
        ``FREE`` (0), ``OCCUPIED`` (100) or ``UNKNOWN`` (-1); row 0 is the top of the image (largest y).
    geometry : GridGeometry
        Resolution and origin; convert with ``geometry.world_to_index`` / ``pixel_to_world``.
    """

    data: NDArray[np.int8]
    geometry: GridGeometry

    def __post_init__(self) -> None:
        self.data = np.asarray(self.data, dtype=np.int8)
        if self.data.ndim != 2:
            raise ShapeError(f"OccupancyGrid.data must be 2D (H, W), got shape {self.data.shape}")
        if self.data.shape != self.geometry.shape:
            raise ShapeError(f"OccupancyGrid.data {self.data.shape} differs from geometry {self.geometry.shape}")

    @property
    def free(self) -> NDArray[np.bool_]:
        """(H, W) bool, True on free cells."""
        return self.data == FREE

    @property
    def occupied(self) -> NDArray[np.bool_]:
        """(H, W) bool, True on occupied cells."""
        return self.data == OCCUPIED

    @property
    def resolution(self) -> float:
        return self.geometry.resolution

    def to_image(self) -> NDArray[np.uint8]:
        """(H, W) uint8 gray image as map_server writes it: 254 free, 0 occupied, 205 unknown."""
        img = np.full(self.data.shape, PGM_UNKNOWN, dtype=np.uint8)
        img[self.data == FREE] = PGM_FREE
        img[self.data == OCCUPIED] = PGM_OCCUPIED
        return img

    @classmethod
    def from_image(
        cls,
        image: ArrayLike,
        resolution: float,
        origin: tuple[float, float] = (0.0, 0.0),
        *,
        free_min: int = IMAGE_FREE_MIN,
        occupied_max: int = 89,
    ) -> OccupancyGrid:
        """Cell states from a gray image: ``>= free_min`` free, ``<= occupied_max`` occupied, else unknown.

        The defaults are the benchmark's rule (>= 250 free) and map_server's occupied threshold (0.65).
        """
        img = np.asarray(image)
        if img.ndim != 2:
            raise ShapeError(f"map image must be a 2D gray image (H, W), got shape {img.shape}")
        data = np.full(img.shape, UNKNOWN, dtype=np.int8)
        data[img >= free_min] = FREE
        data[img <= occupied_max] = OCCUPIED
        return cls(data, GridGeometry(img.shape, resolution, origin))
