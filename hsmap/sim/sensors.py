"""LiDAR models: a floor-level planar scanner and a mast-mounted spinning 3D scanner.

Both are configured by dataclasses (YAML-loadable through :mod:`hsmap.config`) whose defaults are the study's
sensors: a 270 deg, 0.25 deg, 10 m planar LiDAR 0.20 m above the floor, and a 128 x 1024, 45 deg vertical
field-of-view, 50 m LiDAR on a 1.6 m mast. Ranges get Gaussian noise; a return beyond ``range_max`` or closer
than ``range_min`` is no return.

The 3D scanner's range image has shape (channels, columns): row ``i`` looks at elevation
``vertical_angles[i]`` (listed from the top beam down, as in an image), column ``j`` at azimuth
``-pi + j * 2 pi / columns`` (counter-clockwise from the sensor's x axis). Datasets store it as uint16
millimetres with 0 = no return; the codec (:func:`encode_range_image`, :func:`range_image_to_points`) belongs to
the dataset format and lives with its reader, :mod:`hsmap.datasets.simulated`.

This module is numpy-only; ray casting lives in :mod:`hsmap.sim.world`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from ..datasets.simulated import (  # the stored format is the reader's; the simulator writes it
    RANGE_UNIT,
    beam_directions,
    decode_range_image,
    encode_range_image,
    range_image_to_points,
)
from ..errors import ConfigError

__all__ = [
    "Lidar2DConfig",
    "Lidar3DConfig",
    "RANGE_UNIT",
    "beam_directions",
    "range_image_to_points",
    "encode_range_image",
    "decode_range_image",
]


def _check_positive(name: str, value: float, allow_zero: bool = False) -> None:
    ok = value >= 0 if allow_zero else value > 0
    if not (np.isfinite(value) and ok):
        raise ConfigError(f"{name} must be {'>= 0' if allow_zero else '> 0'}, got {value}")


def _check_vector(name: str, value, n: int) -> list[float]:
    try:
        arr = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ConfigError(f"{name} must be a list of {n} numbers, got {value!r}") from None
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise ConfigError(f"{name} must be a list of {n} finite numbers, got {value!r}")
    return [float(v) for v in arr]


@dataclass
class Lidar2DConfig:
    """A planar LiDAR scanning a horizontal plane at ``height`` metres above the floor.

    Attributes
    ----------
    angle_min_deg, angle_max_deg, angle_increment_deg : float
        First and last beam angle and the step, degrees, counter-clockwise from the sensor's x axis.
    range_min, range_max : float
        Metres; returns outside [range_min, range_max] are "no return" (NaN).
    noise_sigma : float
        Standard deviation of the Gaussian range noise, metres.
    dropout : float
        Probability that a beam with a hit returns nothing anyway.
    position : list of 2 float
        (x, y) of the sensor in the robot base frame, metres.
    yaw_deg : float
        Heading of the sensor in the robot base frame, degrees.
    height : float
        Mounting height above the floor (the base frame's z = 0 is the floor), metres.
    scan_time : float
        Seconds of one turn of the scanner (ROS ``LaserScan.scan_time``): beam i is measured
        ``i * angle_increment_deg / 360 * scan_time`` after the scan's stamp (its first beam), from the pose the
        robot has then; 0 takes the whole scan at the stamp.
    """

    angle_min_deg: float = -135.0
    angle_max_deg: float = 135.0
    angle_increment_deg: float = 0.25
    range_min: float = 0.05
    range_max: float = 10.0
    noise_sigma: float = 0.01
    dropout: float = 0.0
    position: list[float] = field(default_factory=lambda: [0.15, 0.0])
    yaw_deg: float = 0.0
    height: float = 0.20
    scan_time: float = 0.0

    def __post_init__(self) -> None:
        if isinstance(self.scan_time, bool) or not isinstance(self.scan_time, (int, float)):
            raise ConfigError(f"lidar2d.scan_time must be a number, got {self.scan_time!r}")
        if not (np.isfinite(self.scan_time) and 0.0 <= self.scan_time <= 1.0):
            raise ConfigError(f"lidar2d.scan_time must be in [0, 1] s, got {self.scan_time}")
        self.position = _check_vector("lidar2d.position", self.position, 2)
        _check_positive("lidar2d.angle_increment_deg", self.angle_increment_deg)
        if not self.angle_max_deg > self.angle_min_deg:
            raise ConfigError(
                f"lidar2d.angle_max_deg ({self.angle_max_deg}) must exceed angle_min_deg ({self.angle_min_deg})"
            )
        if self.angle_max_deg - self.angle_min_deg > 360.0 + 1e-9:
            raise ConfigError("lidar2d: the field of view angle_max_deg - angle_min_deg must be at most 360")
        _check_positive("lidar2d.range_max", self.range_max)
        _check_positive("lidar2d.range_min", self.range_min, allow_zero=True)
        if self.range_min >= self.range_max:
            raise ConfigError(f"lidar2d.range_min ({self.range_min}) must be below range_max ({self.range_max})")
        _check_positive("lidar2d.noise_sigma", self.noise_sigma, allow_zero=True)
        if not 0.0 <= self.dropout < 1.0:
            raise ConfigError(f"lidar2d.dropout must be in [0, 1), got {self.dropout}")
        _check_positive("lidar2d.height", self.height)

    @property
    def beams(self) -> int:
        """Number of beams, M."""
        return int(round((self.angle_max_deg - self.angle_min_deg) / self.angle_increment_deg)) + 1

    def angles(self) -> NDArray[np.float64]:
        """Beam angles (M,) in radians."""
        return np.deg2rad(self.angle_min_deg + self.angle_increment_deg * np.arange(self.beams))

    def extrinsic(self) -> NDArray[np.float64]:
        """Pose (x, y, yaw) of the sensor in the robot base frame."""
        return np.array([self.position[0], self.position[1], np.deg2rad(self.yaw_deg)])

    @property
    def time_increment(self) -> float:
        """Seconds between two beams (ROS ``LaserScan.time_increment``): ``scan_time * angle_increment_deg / 360``."""
        return float(self.scan_time) * float(self.angle_increment_deg) / 360.0

    def beam_times(self) -> NDArray[np.float64]:
        """Seconds (M,) from the scan's stamp (its first beam) at which each beam is measured."""
        return self.time_increment * np.arange(self.beams)

    def describe(self) -> dict:
        """The sensor as written to ``dataset.yaml`` (radians, metres)."""
        a = self.angles()
        return {
            "type": "planar-lidar",
            "frame": "lidar2d",
            "beams": self.beams,
            "angle_min": float(a[0]),
            "angle_max": float(a[-1]),
            "angle_increment": float(np.deg2rad(self.angle_increment_deg)),
            "range_min": float(self.range_min),
            "range_max": float(self.range_max),
            "noise_sigma": float(self.noise_sigma),
            "dropout": float(self.dropout),
            "extrinsic": [float(v) for v in self.extrinsic()],
            "extrinsic_convention": "x y yaw (m, m, rad) of the sensor in the robot base frame",
            "mount_height": float(self.height),
            **({} if self.scan_time == 0 else {
                "scan_time": float(self.scan_time),
                "time_increment": self.time_increment,
                "scan_convention": "beam i is measured beam_time[i] = i * time_increment s after the scan's stamp "
                "(its first beam) from the pose the robot has then; time_increment = scan_time * angle_increment "
                "/ (2 pi)"}),
        }


@dataclass
class Lidar3DConfig:
    """A spinning multi-beam LiDAR.

    Attributes
    ----------
    channels, columns : int
        Rows (beams) and columns (azimuth steps) of the range image.
    vertical_fov_deg : list of 2 float
        Lowest and highest elevation, degrees; the channels are spread evenly between them unless
        ``vertical_angles_deg`` lists them.
    vertical_angles_deg : list of float or None
        Explicit elevations, one per channel, degrees.
    range_min, range_max : float
        Metres.
    noise_sigma : float
        Standard deviation of the Gaussian range noise, metres.
    dropout : float
        Probability that a beam with a hit returns nothing anyway.
    position : list of 3 float
        (x, y, z) of the sensor in the robot base frame (z = 0 is the floor), metres.
    rpy_deg : list of 3 float
        (roll, pitch, yaw) of the sensor in the robot base frame, degrees.
    sweep_time : float
        Seconds one sweep takes: column j is measured ``j / columns * sweep_time`` after the cloud's stamp (the
        sweep's start), from the pose the robot has then; 0 takes the whole cloud at the stamp.
    sway_frequency : float
        Hz of the mast's own pitch and roll oscillation, driven by the base's acceleration at the mast's foot
        (:func:`hsmap.sim.robot.mast_sway`); 0 is a rigid mast.
    sway_damping : float
        Damping ratio of that oscillation (0 < ratio).
    """

    channels: int = 128
    columns: int = 1024
    vertical_fov_deg: list[float] = field(default_factory=lambda: [-22.5, 22.5])
    vertical_angles_deg: list[float] | None = None
    range_min: float = 0.3
    range_max: float = 50.0
    noise_sigma: float = 0.01
    dropout: float = 0.0
    position: list[float] = field(default_factory=lambda: [-0.10, 0.0, 1.6])
    rpy_deg: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    sweep_time: float = 0.0
    sway_frequency: float = 0.0
    sway_damping: float = 0.2

    def __post_init__(self) -> None:
        for name in ("sweep_time", "sway_frequency", "sway_damping"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise ConfigError(f"lidar3d.{name} must be a number, got {v!r}")
        if not (np.isfinite(self.sweep_time) and 0.0 <= self.sweep_time <= 1.0):
            raise ConfigError(f"lidar3d.sweep_time must be in [0, 1] s, got {self.sweep_time}")
        if not (np.isfinite(self.sway_frequency) and 0.0 <= self.sway_frequency <= 100.0):
            raise ConfigError(f"lidar3d.sway_frequency must be in [0, 100] Hz, got {self.sway_frequency}")
        if not (np.isfinite(self.sway_damping) and 0.0 < self.sway_damping <= 10.0):
            raise ConfigError(f"lidar3d.sway_damping must be in (0, 10], got {self.sway_damping}")
        if not (isinstance(self.channels, int) and self.channels >= 1):
            raise ConfigError(f"lidar3d.channels must be a positive integer, got {self.channels!r}")
        if not (isinstance(self.columns, int) and self.columns >= 1):
            raise ConfigError(f"lidar3d.columns must be a positive integer, got {self.columns!r}")
        self.vertical_fov_deg = _check_vector("lidar3d.vertical_fov_deg", self.vertical_fov_deg, 2)
        lo, hi = self.vertical_fov_deg
        if not (-90 <= lo < hi <= 90) and not (self.channels == 1 and lo == hi):
            raise ConfigError(f"lidar3d.vertical_fov_deg must be [low, high] within [-90, 90], got {[lo, hi]}")
        if self.vertical_angles_deg is not None:
            self.vertical_angles_deg = _check_vector(
                "lidar3d.vertical_angles_deg", self.vertical_angles_deg, self.channels
            )
        _check_positive("lidar3d.range_max", self.range_max)
        _check_positive("lidar3d.range_min", self.range_min, allow_zero=True)
        if self.range_min >= self.range_max:
            raise ConfigError(f"lidar3d.range_min ({self.range_min}) must be below range_max ({self.range_max})")
        if self.range_max / RANGE_UNIT > np.iinfo(np.uint16).max:
            raise ConfigError(f"lidar3d.range_max must be at most {np.iinfo(np.uint16).max * RANGE_UNIT} m")
        _check_positive("lidar3d.noise_sigma", self.noise_sigma, allow_zero=True)
        if not 0.0 <= self.dropout < 1.0:
            raise ConfigError(f"lidar3d.dropout must be in [0, 1), got {self.dropout}")
        self.position = _check_vector("lidar3d.position", self.position, 3)
        self.rpy_deg = _check_vector("lidar3d.rpy_deg", self.rpy_deg, 3)

    def vertical_angles(self) -> NDArray[np.float64]:
        """Elevation of each channel (channels,), radians, from the top beam down."""
        if self.vertical_angles_deg is not None:
            return np.deg2rad(np.asarray(self.vertical_angles_deg, dtype=float))
        lo, hi = self.vertical_fov_deg
        return np.deg2rad(np.linspace(hi, lo, self.channels))

    def azimuths(self) -> NDArray[np.float64]:
        """Azimuth of each column (columns,), radians: -pi + j * 2 pi / columns."""
        return -np.pi + 2.0 * np.pi * np.arange(self.columns) / self.columns

    def directions(self) -> NDArray[np.float64]:
        """Unit beam directions (channels, columns, 3) in the sensor frame."""
        return beam_directions(self.vertical_angles(), self.azimuths())

    @property
    def static(self) -> bool:
        """Whether every cloud is taken at one instant from the rigid mount (no rolling sweep, no sway)."""
        return self.sweep_time == 0.0 and self.sway_frequency == 0.0

    def column_times(self) -> NDArray[np.float64]:
        """Seconds (columns,) from the cloud's stamp (the sweep's start) at which each column is measured."""
        return float(self.sweep_time) * np.arange(self.columns) / self.columns

    def extrinsic(self) -> NDArray[np.float64]:
        """Pose (x, y, z, roll, pitch, yaw) of the sensor in the robot base frame."""
        return np.array([*self.position, *np.deg2rad(self.rpy_deg)])

    def describe(self) -> dict:
        """The sensor as written to ``dataset.yaml``."""
        return {
            "type": "spinning-lidar",
            "frame": "lidar3d",
            "channels": int(self.channels),
            "columns": int(self.columns),
            "vertical_angles_deg": [round(float(v), 6) for v in np.rad2deg(self.vertical_angles())],
            "vertical_angles_order": "row 0 of the range image first (top beam first by default)",
            "azimuth_min": float(-np.pi),
            "azimuth_increment": float(2.0 * np.pi / self.columns),
            "azimuth_convention": "column j looks at azimuth azimuth_min + j * azimuth_increment, "
            "counter-clockwise from the sensor x axis",
            "range_min": float(self.range_min),
            "range_max": float(self.range_max),
            "range_unit": RANGE_UNIT,
            "noise_sigma": float(self.noise_sigma),
            "dropout": float(self.dropout),
            "extrinsic": [float(v) for v in self.extrinsic()],
            "extrinsic_convention": "x y z roll pitch yaw (m, rad; R = Rz(yaw) Ry(pitch) Rx(roll)) of the sensor "
            "in the robot base frame (z = 0 is the floor)",
            **({} if self.static else {
                "sweep_time": float(self.sweep_time),
                "sweep_convention": "column j is measured column_time[j] = j / columns * sweep_time s after the "
                "cloud's stamp (the sweep's start) from the pose the robot has then",
                "sway_frequency": float(self.sway_frequency), "sway_damping": float(self.sway_damping)}),
        }
