"""The common currency of every reader: one :class:`Frame` per scan."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

__all__ = ["LaserScan2D", "Frame", "Dataset"]


@dataclass
class LaserScan2D:
    """A planar laser scan in the sensor frame.

    Attributes
    ----------
    ranges : ndarray of shape (M,)
        Metres; NaN where there is no return (readings at or beyond ``range_max`` are masked by readers).
    angles : ndarray of shape (M,)
        Beam angles in radians, counter-clockwise from the sensor's x axis.
    range_min, range_max : float
        Valid range interval of the sensor.
    """

    ranges: NDArray[np.float64]
    angles: NDArray[np.float64]
    range_min: float = 0.0
    range_max: float = np.inf

    def points(self) -> NDArray[np.float64]:
        """Valid returns as (K, 2) points in the sensor frame."""
        r = np.asarray(self.ranges, dtype=float)
        ok = np.isfinite(r) & (r >= self.range_min) & (r < self.range_max)
        return np.column_stack([r[ok] * np.cos(self.angles[ok]), r[ok] * np.sin(self.angles[ok])])


@dataclass
class Frame:
    """One time step of robot data.

    Attributes
    ----------
    stamp : float
        Seconds; the scan's own timestamp (this is what trajectories are written with).
    scan2d : LaserScan2D or None
        Floor-level 2D scan, in the 2D sensor frame.
    cloud3d : ndarray of shape (N, 3) or None
        3D LiDAR points, in the 3D sensor frame.
    odometry : ndarray of shape (3,) or None
        Wheel-odometry pose (x, y, yaw) of the robot base in the odometry frame, at ``stamp``.
    index : int
        Position of the frame in its sequence.
    extrinsic2d : ndarray of shape (3,)
        Pose (x, y, yaw) of the 2D sensor in the robot base frame.
    extrinsic3d : ndarray of shape (6,)
        Pose (x, y, z, roll, pitch, yaw) of the 3D sensor in the robot base frame.
    """

    stamp: float
    scan2d: LaserScan2D | None = None
    cloud3d: NDArray[np.float64] | None = None
    odometry: NDArray[np.float64] | None = None
    index: int = 0
    extrinsic2d: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    extrinsic3d: NDArray[np.float64] = field(default_factory=lambda: np.zeros(6))


class Dataset:
    """What every reader returns: a sequence of :class:`Frame` plus what the source knows about itself.

    Attributes
    ----------
    name : str
        Short name for reports (file or folder stem).
    path : str
        Where it was read from.
    odometry : Trajectory or None
        Wheel odometry of the robot base at the scan stamps, when the source has it.
    groundtruth : Trajectory or None
        Ground-truth poses of the robot base at the scan stamps (simulator only).
    """

    name: str = ""
    path: str = ""
    odometry = None
    groundtruth = None

    def __len__(self) -> int:
        raise NotImplementedError

    def override_extrinsics(self, extrinsic2d=None, extrinsic3d=None) -> None:
        """Replace the sensor extrinsics the source declares (e.g. a TF known to be wrong).

        Parameters
        ----------
        extrinsic2d : array_like of shape (3,), optional
            (x, y, yaw) of the 2D LiDAR in the robot base frame.
        extrinsic3d : array_like of shape (6,), optional
            (x, y, z, roll, pitch, yaw) of the 3D LiDAR in the robot base frame.
        """
        from ..errors import ShapeError

        for name, value, n in (("extrinsic2d", extrinsic2d, 3), ("extrinsic3d", extrinsic3d, 6)):
            if value is None:
                continue
            arr = np.asarray(value, dtype=float)
            if arr.shape != (n,) or not np.all(np.isfinite(arr)):
                raise ShapeError(f"{name} must be {n} finite numbers, got {np.asarray(value).tolist()}")
            setattr(self, name, arr)

    def frames(self, clouds: bool = True):  # -> Iterator[Frame]
        """Yield the frames in recording order; ``clouds=False`` may skip reading 3D clouds (faster 2D runs)."""
        raise NotImplementedError
