"""Each frame's points as HS-SLAM tracks them (:class:`Deskewing`): the cloud or the 2D scan moved to the frame's
stamp by the motion over its sweep (``SlamConfig.deskew``), and a 6-DOF registration refined with that motion."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from ..datasets.frames import Frame
from ..deskew import deskew_frame, refine_sweep
from ..deskew2d import deskew_scan_frame
from ..errors import UnusableFrameError
from ..geometry import pose_to_matrix, wrap_angle
from ..registration.icp import RegistrationResult, RegistrationTarget, spans_its_space
from ..trajectory import Trajectory
from .config import SlamConfig
from .costs import Costs
from .frames import frame_points, timed_cloud_points, unusable_reason
from .prediction import MotionPrediction

__all__ = ["Deskewing"]


class Deskewing:
    """The frames' points, moved by the motion over each sweep: the prior's (6-DOF), the input's odometry track
    (3-DOF, with ``use_odometry``), else the last odometry reading or the last poses' constant velocity (from the
    :class:`MotionPrediction`'s history).

    Parameters
    ----------
    config : SlamConfig
    costs : Costs
        Counts the sweep refinements.
    prediction : MotionPrediction
        The tracked poses, their stamps, the prior and the odometry.
    odometry : Trajectory, optional
        3-DOF: the input's wheel odometry (x, y, yaw) at its frame stamps, interpolated at the beams' times.
    """

    def __init__(self, config: SlamConfig, costs: Costs, prediction: MotionPrediction,
                 odometry: Trajectory | None = None) -> None:
        self.config = config
        self.costs = costs
        self.prediction = prediction
        self.track = odometry if config.dof == 3 and config.use_odometry and odometry is not None else None

    def points(self, frame: Frame) -> tuple[Frame, NDArray[np.float64], NDArray[np.float64] | None]:
        """The frame as tracked (:meth:`deskewed`), its points (N, dim) at the scan voxel and, for a 6-DOF cloud
        with point times (``deskew``), each point's time (N,) for :meth:`refined`, else None. A frame with too few
        points, or points that do not span their space, raises :class:`~hsmap.errors.UnusableFrameError`."""
        cfg = self.config
        times = frame.point_times if cfg.deskew and cfg.dof == 6 and frame.point_times is not None else None
        frame = self.deskewed(frame)
        if times is None:
            scan = frame_points(frame, cfg.dof, cfg.min_range, cfg.max_range, voxel=cfg.effective_scan_voxel())
        else:
            scan, times = timed_cloud_points(frame, np.asarray(times, dtype=float).reshape(-1), cfg.min_range,
                                             cfg.max_range, cfg.effective_scan_voxel())
        if len(scan) < 3 * cfg.dim or not spans_its_space(scan):
            raise UnusableFrameError(unusable_reason(frame, cfg.dof, cfg.min_range, cfg.max_range, scan),
                                     frame.index, frame.stamp)
        return frame, scan, times

    def deskewed(self, frame: Frame) -> Frame:
        """The frame with its cloud (6-DOF) or its 2D scan (3-DOF) moved to its stamp, with ``deskew``
        (:func:`hsmap.deskew.deskew_frame`, :func:`hsmap.deskew2d.deskew_scan_frame`); frames without point or
        beam times are returned as they are."""
        if not self.config.deskew:
            return frame
        motion = self.prediction
        odom = motion.odometry.previous if self.config.use_odometry else None
        if self.config.dof == 3:
            if frame.scan2d is None or frame.scan2d.times is None:
                return frame
            return deskew_scan_frame(frame, prior=self.track, previous_stamps=motion.stamps[-2:],
                                     previous_poses=motion.poses[-2:], previous_odometry=odom)[0]
        if frame.point_times is None:
            return frame
        return deskew_frame(frame, prior=motion.prior, previous_stamps=motion.stamps[-2:],
                            previous_poses=motion.poses[-2:], previous_odometry=odom)[0]

    def refined(self, scan: NDArray[np.float64], times: NDArray[np.float64], target: RegistrationTarget,
                res: RegistrationResult) -> tuple[RegistrationResult, NDArray[np.float64]]:
        """The registration and the scan (N, 3) refined with the motion over the sweep
        (:func:`hsmap.deskew.refine_sweep`) where that aligns the scan better; else both as they are."""
        reg = self.config.registration
        ref = refine_sweep(scan, times, target, res.pose, threshold=reg.threshold, robust_kernel=reg.robust_kernel)
        self.costs.add(refinements=1)
        if not ref.improved:
            return res, scan
        pose = ref.pose.copy()
        pose[3:] = res.pose[3:] + wrap_angle(pose[3:] - res.pose[3:])
        return replace(res, pose=pose, transformation=pose_to_matrix(pose)), ref.points
