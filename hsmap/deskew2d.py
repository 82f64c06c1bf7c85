"""Motion compensation of 2D scans taken over a scanner's turn: every beam moved to its scan's stamp.

A planar LiDAR measures its beams one after the other while its mirror turns (ROS ``LaserScan.time_increment``);
each beam carries its time (:attr:`hsmap.datasets.frames.LaserScan2D.times`, seconds relative to the frame's
stamp). With the robot base's motion ``M(t) = B(stamp)^-1 B(stamp + t)``, a beam's point ``p`` measured in the
sensor frame at time ``t`` lies at ``E^-1 M(t) E p`` in the sensor frame at the stamp (``E``: the sensor's pose
(x, y, yaw) in the base frame). The motion comes from the same sources as a 3D sweep's
(:func:`hsmap.deskew.sweep_motion`): a trajectory interpolated at the beams' times (HS-SLAM 3-DOF gives it the
input's wheel odometry at the frame stamps, the map's floor grid the 2D run's poses), else the wheel odometry's
last increment or the last tracked poses' constant velocity; with none of them the scan is left as it is.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import ArrayLike

from .datasets.frames import Frame, LaserScan2D
from .deskew import sweep_motion
from .errors import ShapeError
from .geometry import invert_matrix, pose_to_matrix

__all__ = ["deskew_scan", "deskew_scan_frame"]


def deskew_scan(scan: LaserScan2D, extrinsic: ArrayLike, motions: ArrayLike) -> LaserScan2D:
    """The scan with each beam's return moved to the scan's reference time, its beam times cleared.

    Parameters
    ----------
    scan : LaserScan2D
        M beams, ranges (NaN = no return) and angles in the sensor frame as measured.
    extrinsic : array_like of shape (3,)
        The sensor's pose (x, y, yaw) in the base frame.
    motions : array_like of shape (M, 3)
        The robot base's pose at each beam's time relative to its pose at the reference time.

    Returns
    -------
    LaserScan2D
        Ranges and angles (M,) of ``E^-1 M(t) E p`` per beam; a beam without a return keeps its angle and NaN.
    """
    r = np.asarray(scan.ranges, dtype=float)
    a = np.asarray(scan.angles, dtype=float)
    m = np.asarray(motions, dtype=float)
    if m.shape != (len(r), 3) or a.shape != r.shape:
        raise ShapeError(f"a scan of {len(r)} ranges and {a.shape} angles needs motions ({len(r)}, 3), got {m.shape}")
    E = pose_to_matrix(np.asarray(extrinsic, dtype=float).reshape(3))
    S = invert_matrix(E) @ pose_to_matrix(m) @ E  # (M, 3, 3) sensor motion
    ok = np.isfinite(r)
    x, y = r * np.cos(a), r * np.sin(a)
    qx = S[:, 0, 0] * x + S[:, 0, 1] * y + S[:, 0, 2]
    qy = S[:, 1, 0] * x + S[:, 1, 1] * y + S[:, 1, 2]
    ranges = np.where(ok, np.hypot(qx, qy), np.nan)
    angles = np.where(ok, np.arctan2(qy, qx), a)
    return dataclasses.replace(scan, ranges=ranges, angles=angles, times=None)


def deskew_scan_frame(frame: Frame, **motion_sources) -> tuple[Frame, str]:
    """The frame with its 2D scan moved to its stamp (:func:`deskew_scan`) and its beam times cleared, and where
    the motion came from (:func:`hsmap.deskew.sweep_motion`, whose keyword arguments ``motion_sources`` are:
    ``prior``, ``previous_stamps``, ``previous_poses`` (x, y, yaw), ``previous_odometry``).

    A frame without a scan or beam times is returned as it is (source ``"static"``); one whose motion nothing
    gives keeps its ranges, its times cleared (source ``"none"``).
    """
    scan = frame.scan2d
    if scan is None or scan.times is None:
        return frame, "static"
    t = np.asarray(scan.times, dtype=float).reshape(-1)
    if len(t) != len(scan.ranges):
        raise ShapeError(f"frame {frame.index}: {len(t)} beam times for {len(scan.ranges)} beams")
    motions, source = sweep_motion(frame, t, **motion_sources)
    if motions is None:
        return dataclasses.replace(frame, scan2d=dataclasses.replace(scan, times=None)), source
    if motions.shape[1] == 6:  # a 6-DOF prior: its planar part
        motions = motions[:, [0, 1, 5]]
    return dataclasses.replace(frame, scan2d=deskew_scan(scan, frame.extrinsic2d, motions)), source
