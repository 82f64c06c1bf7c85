"""The settings of the whole chain (``hsmap map --config FILE``): one YAML with the sections ``slam2d``,
``slam3d``, ``grids`` and ``segmentation``."""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from ..config import from_dict, read_yaml
from ..errors import ConfigError
from ..rooms.segmentation import SegmentationConfig
from ..slam import SlamConfig

__all__ = ["ChainConfig", "GridsConfig", "load_chain_config"]


@dataclass
class GridsConfig:
    """The chain's occupancy grids and the doors' points (lengths in metres).

    Attributes
    ----------
    resolution : float
        Metres per cell of the floor-level grid and of the slice's grid.
    slice : tuple of 2 floats
        Heights (above the base frame's z = 0) of the 3D map's slice; the paper's is 1.7-1.8 m.
    slice_bins : int
        Azimuth bins of the virtual scans the slice is made of.
    door_depth, door_margin : float
        The box around each door whose map points are the door's (:func:`hsmap.rooms.segmentation.points_in_doors`).
    voxel : float
        3D-only recordings: the edge of the 3D occupancy map's voxels (``map3d.bt``), which is also the cell of
        its band grids.
    max_range : float
        3D-only recordings: rays are cut this far from the sensor; a farther return only carves free space.
    floor_band : tuple of 2 floats
        3D-only recordings: heights above the floor of the floor-level band (``floor.pgm``), where a robot's 2D
        LiDAR would scan; ``slice`` is then in heights above the floor, too.
    floor_radius : float
        3D-only recordings: metres around each sensor pose in which the floor below it is looked for.
    floor_depth : tuple of 2 floats
        3D-only recordings: metres below the sensor (nearest, farthest) where the floor may lie.
    floor_reach : float
        3D-only recordings: metres above or below the nearest pose's floor in which a map column's own floor
        surface is taken instead (steps and ramps between floor levels; under a table top's height).
    """

    resolution: float = 0.05
    slice: tuple[float, float] = (1.7, 1.8)
    slice_bins: int = 720
    door_depth: float = 0.3
    door_margin: float = 0.15
    voxel: float = 0.1
    max_range: float = 30.0
    floor_band: tuple[float, float] = (0.3, 0.4)
    floor_radius: float = 4.0
    floor_depth: tuple[float, float] = (0.2, 3.0)
    floor_reach: float = 0.5

    def __post_init__(self) -> None:
        if not (np.isfinite(self.resolution) and self.resolution > 0):
            raise ConfigError(f"grids.resolution must be > 0 metres per cell, got {self.resolution!r}")
        z = np.asarray(self.slice, dtype=float)
        if z.shape != (2,) or not np.all(np.isfinite(z)) or not z[0] < z[1]:
            raise ConfigError(f"grids.slice must be two heights low < high (metres), got {self.slice!r}")
        self.slice = (float(z[0]), float(z[1]))
        for name in ("voxel", "max_range", "floor_radius", "floor_reach"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and (v > 0 or name == "floor_reach" and v == 0)):
                raise ConfigError(f"grids.{name} must be a number of metres > 0, got {v!r}")
        for name, low in (("floor_band", -np.inf), ("floor_depth", 0.0)):
            z = np.asarray(getattr(self, name), dtype=float)
            if z.shape != (2,) or not np.all(np.isfinite(z)) or not low <= z[0] < z[1]:
                raise ConfigError(f"grids.{name} must be two heights low < high (metres"
                                  f"{', low >= 0' if low == 0 else ''}), got {getattr(self, name)!r}")
            setattr(self, name, (float(z[0]), float(z[1])))
        if not isinstance(self.slice_bins, (int, np.integer)) or self.slice_bins < 1:
            raise ConfigError(f"grids.slice_bins must be an integer >= 1, got {self.slice_bins!r}")
        for name in ("door_depth", "door_margin"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ConfigError(f"grids.{name} must be a finite number >= 0, got {v!r}")


@dataclass
class ChainConfig:
    """Every setting of the chain on one recording.

    Attributes
    ----------
    slam2d : SlamConfig
        The 3-DOF run on the 2D scans.
    slam3d : SlamConfig
        The 6-DOF run on the 3D clouds, seeded by the 2D poses.
    grids : GridsConfig
        The grids, the slice and the doors' points.
    segmentation : SegmentationConfig
        Doors and rooms of both grids.
    """

    slam2d: SlamConfig = field(default_factory=lambda: SlamConfig(dof=3))
    slam3d: SlamConfig = field(default_factory=lambda: SlamConfig(dof=6))
    grids: GridsConfig = field(default_factory=GridsConfig)
    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)

    def __post_init__(self) -> None:
        if self.slam2d.dof != 3:
            raise ConfigError(f"slam2d.dof must be 3, got {self.slam2d.dof}")
        if self.slam3d.dof != 6:
            raise ConfigError(f"slam3d.dof must be 6, got {self.slam3d.dof}")


def load_chain_config(path: str | os.PathLike | None) -> ChainConfig:
    """The chain's settings from a YAML file (None: the defaults); ``slam3d.dof`` is 6 unless the file says."""
    data = read_yaml(path) if path is not None else None
    if data is None:
        return ChainConfig()
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping with the sections slam2d, slam3d, grids, segmentation, "
                          f"got {type(data).__name__}")
    data = dict(data)
    if isinstance(data.get("slam3d"), dict):
        data["slam3d"] = {"dof": 6, **data["slam3d"]}
    elif "slam3d" not in data or data["slam3d"] is None:
        data["slam3d"] = {"dof": 6}
    return from_dict(ChainConfig, data, str(path))
