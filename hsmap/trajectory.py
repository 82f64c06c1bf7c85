"""Timestamped poses: the :class:`Trajectory` type, its one look-up of poses at stamps, and TUM files.

A trajectory is ``stamps (N,)`` in seconds and ``poses (N, 3)`` (x, y, yaw) or ``(N, 6)``
(x, y, z, roll, pitch, yaw), see :mod:`hsmap.geometry`. :func:`nearest_index` is the one nearest-stamp search of
the package: :meth:`Trajectory.at` (a trajectory's poses at given stamps), the association of an estimate with
its reference (:mod:`hsmap.evaluation.trajectory`) and the pairing of a recording's clouds with its scans
(:mod:`hsmap.datasets.rosbag`) all go through it. :meth:`Trajectory.interpolate` gives poses between stamps
(SE(2)/SE(3) interpolation within a tolerance): the 2D prior of a 6-DOF HS-SLAM run (:mod:`hsmap.slam`), whose
clouds come between the 2D scans.

TUM files (``t x y z qx qy qz qw``, one pose per line) are read and written here (:func:`read_tum`,
:func:`write_tum`); they are readable by evo.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import DataFormatError, DatasetError, InputError, ShapeError
from .geometry import (
    euler_to_matrix,
    interpolate_poses,
    matrix_to_euler,
    matrix_to_quaternion,
    quaternion_to_matrix,
)
from .io import atomic_open, read_number_rows

__all__ = ["Trajectory", "nearest_index", "read_tum", "write_tum"]


def nearest_index(stamps: ArrayLike, query: ArrayLike, max_dt: float = np.inf) -> NDArray[np.intp]:
    """Index into ``stamps`` of the stamp nearest to each query stamp, -1 where none lies within ``max_dt``.

    Parameters
    ----------
    stamps : array_like of shape (N,)
        Seconds, in any order.
    query : array_like of shape (M,)
        Seconds.
    max_dt : float
        The largest accepted difference, in seconds (inclusive).

    Returns
    -------
    ndarray of int of shape (M,)
        Of two equally near stamps the earlier one; of equal stamps the first listed.
    """
    s = np.asarray(stamps, dtype=float).reshape(-1)
    q = np.asarray(query, dtype=float).reshape(-1)
    if len(s) == 0:
        return np.full(len(q), -1, dtype=np.intp)
    order = np.argsort(s, kind="stable")
    ss = s[order]
    hi = np.clip(np.searchsorted(ss, q), 0, len(ss) - 1)
    lo = np.clip(hi - 1, 0, len(ss) - 1)
    pick = np.where(np.abs(ss[lo] - q) <= np.abs(ss[hi] - q), lo, hi)
    out = order[pick].astype(np.intp)
    out[~(np.abs(ss[pick] - q) <= max_dt)] = -1
    return out


@dataclass
class Trajectory:
    """Timestamped poses.

    Attributes
    ----------
    stamps : ndarray of shape (N,)
        Seconds.
    poses : ndarray of shape (N, 3) or (N, 6)
        (x, y, yaw) or (x, y, z, roll, pitch, yaw), see :mod:`hsmap.geometry`.
    """

    stamps: NDArray[np.float64]
    poses: NDArray[np.float64]

    def __post_init__(self) -> None:
        self.stamps = np.asarray(self.stamps, dtype=float).reshape(-1)
        self.poses = np.asarray(self.poses, dtype=float)
        if self.poses.ndim != 2 or self.poses.shape[1] not in (3, 6):
            raise ShapeError(f"Trajectory.poses must have shape (N, 3) or (N, 6), got {self.poses.shape}")
        if len(self.stamps) != len(self.poses):
            raise ShapeError(f"Trajectory has {len(self.stamps)} stamps but {len(self.poses)} poses")

    def __len__(self) -> int:
        return len(self.stamps)

    @property
    def dof(self) -> int:
        return self.poses.shape[1]

    def at(self, stamps: ArrayLike, max_dt: float = 1e-3) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        """The poses at ``stamps``: for each, the pose with the nearest stamp, when it lies within ``max_dt``.

        Parameters
        ----------
        stamps : array_like of shape (M,)
            Seconds.
        max_dt : float
            Seconds; a stamp farther than this from every pose has none.

        Returns
        -------
        poses : ndarray of shape (K, dof)
            The poses of the K stamps that have one, in the order of ``stamps``.
        found : ndarray of bool of shape (M,)
            Which stamps have a pose.

        Raises
        ------
        InputError
            The trajectory is empty.
        """
        if len(self) == 0:
            raise InputError("the trajectory is empty")
        idx = nearest_index(self.stamps, stamps, max_dt)
        found = idx >= 0
        return self.poses[idx[found]], found

    def interpolate(self, stamps: ArrayLike, max_dt: float) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        """The poses at ``stamps``, interpolated between the two poses around each stamp.

        A stamp within 1 ms of a pose's stamp takes that pose (as :meth:`at`); any other stamp takes the
        geodesic interpolation (:func:`hsmap.geometry.interpolate_poses`: SE(2) for (x, y, yaw), SE(3) for
        6-DOF poses) of the poses just before and just after it, when both lie within ``max_dt`` seconds of
        it, or when the gap between them is no longer than 1.5 times the trajectory's median spacing (two
        consecutive poses of its regular cadence, however slow: a 2 Hz 2D LiDAR's). Stamps outside the
        trajectory's time span, or in a longer gap (a pose missing there), have no pose. This is how the 3D
        clouds of a recording, stamped between the 2D scans, get the 2D run's poses.

        Parameters
        ----------
        stamps : array_like of shape (M,)
            Seconds.
        max_dt : float
            Seconds (>= 0).

        Returns
        -------
        poses : ndarray of shape (K, dof)
            The poses of the K stamps that have one, in the order of ``stamps``.
        found : ndarray of bool of shape (M,)

        Raises
        ------
        InputError
            The trajectory is empty, or ``max_dt`` is negative or not a number.
        """
        if len(self) == 0:
            raise InputError("the trajectory is empty")
        if not (np.isfinite(max_dt) and max_dt >= 0):
            raise InputError(f"max_dt must be a number of seconds >= 0, got {max_dt}")
        q = np.asarray(stamps, dtype=float).reshape(-1)
        exact = nearest_index(self.stamps, q, 1e-3)
        order = np.argsort(self.stamps, kind="stable")
        ts, ps = self.stamps[order], self.poses[order]
        hi = np.clip(np.searchsorted(ts, q, side="right"), 1, max(len(ts) - 1, 1))
        lo = hi - 1
        steps = np.diff(ts)
        steps = steps[steps > 0]
        cadence = 1.5 * float(np.median(steps)) if len(steps) else 0.0
        inside = (len(ts) > 1) & (ts[lo] <= q) & (q <= ts[hi]) & (
            ((q - ts[lo] <= max_dt) & (ts[hi] - q <= max_dt)) | (ts[hi] - ts[lo] <= cadence))
        found = (exact >= 0) | inside
        out = np.empty((len(q), self.dof))
        out[exact >= 0] = self.poses[exact[exact >= 0]]
        between = inside & (exact < 0)
        if between.any():
            t0, t1 = ts[lo[between]], ts[hi[between]]
            frac = np.where(t1 > t0, (q[between] - t0) / np.where(t1 > t0, t1 - t0, 1.0), 0.0)
            out[between] = interpolate_poses(ps[lo[between]], ps[hi[between]], frac)
        return out[found], found

    def as_6dof(self) -> Trajectory:
        """The same trajectory as (x, y, z, roll, pitch, yaw), z = roll = pitch = 0 for 2D input."""
        if self.dof == 6:
            return self
        p = np.zeros((len(self), 6))
        p[:, :2] = self.poses[:, :2]
        p[:, 5] = self.poses[:, 2]
        return Trajectory(self.stamps.copy(), p)

    def as_3dof(self) -> Trajectory:
        """The planar part (x, y, yaw)."""
        if self.dof == 3:
            return self
        return Trajectory(self.stamps.copy(), self.poses[:, [0, 1, 5]].copy())

    def head(self, n: int) -> Trajectory:
        """The first ``n`` poses (all of them when there are fewer)."""
        return Trajectory(self.stamps[:n].copy(), self.poses[:n].copy())

    def path_length(self) -> float:
        """Length of the path through the positions, in metres."""
        d = 2 if self.dof == 3 else 3
        return float(np.linalg.norm(np.diff(self.poses[:, :d], axis=0), axis=1).sum())


def write_tum(path: str | os.PathLike, traj: Trajectory) -> None:
    """Write a TUM trajectory (``t x y z qx qy qz qw``, readable by evo), atomically."""
    p = traj.as_6dof().poses
    q = matrix_to_quaternion(euler_to_matrix(p[:, 3], p[:, 4], p[:, 5]))
    rows = np.column_stack([traj.stamps, p[:, :3], q])
    with atomic_open(path, "w", encoding="utf-8") as fh:
        fh.write("# timestamp x y z qx qy qz qw\n")
        np.savetxt(fh, rows, fmt=["%.9f"] + ["%.9g"] * 7)


def read_tum(path: str | os.PathLike, dof: int = 6) -> Trajectory:
    """Read a TUM trajectory file; ``dof=3`` returns (x, y, yaw)."""
    if not Path(path).is_file():
        raise DatasetError(f"{path}: no such trajectory file")
    arr = read_number_rows(path, "t x y z qx qy qz qw", "poses")
    try:
        rpy = matrix_to_euler(quaternion_to_matrix(arr[:, 4:]))
    except InputError as exc:
        raise DataFormatError(f"{path}: {exc}") from None
    traj = Trajectory(arr[:, 0], np.column_stack([arr[:, 1:4], rpy]))
    return traj.as_3dof() if dof == 3 else traj
