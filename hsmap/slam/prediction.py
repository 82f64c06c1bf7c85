"""The motion prediction of HS-SLAM (:class:`MotionPrediction`): where each frame should be and how sure that is,
from a prior trajectory, the wheel odometry or the last motion repeated; the seeds of the frame's registration
and the box around them."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..datasets.frames import Frame
from ..geometry import compose, compose_2d, relative, single_2d, wrap_angle, wrap_angle_1
from ..registration.icp import RegistrationResult
from ..trajectory import Trajectory
from .config import SlamConfig
from .odometry import OdometryModel
from .search import SearchBox

__all__ = ["MotionPrediction", "Prediction", "mean_pose"]

#: A prediction: the predicted pose (dof,) and its sigmas (translation, rotation), or None
Prediction = tuple[NDArray[np.float64], NDArray[np.float64]] | None


def mean_pose(poses: NDArray[np.float64]) -> NDArray[np.float64]:
    """The mean of poses (K, dof), angles averaged on the circle."""
    dim = 2 if poses.shape[1] == 3 else 3
    out = poses.mean(axis=0)
    ang = poses[:, dim:]
    out[dim:] = np.arctan2(np.sin(ang).mean(0), np.cos(ang).mean(0))
    return out


class MotionPrediction:
    """The prediction of the frame being tracked, from the poses tracked before it.

    The previous pose moved by: (6-DOF, :attr:`use_prior`) the prior trajectory's motion (``prior_sigma``); else
    the wheel odometry's step (its learned bias taken out, ``odometry_sigma`` scaled by what was learned); else the
    last motion repeated (``motion_sigma``). Call :meth:`start` with each frame, :meth:`first_registration` and
    :meth:`kept_registration` with its registrations, and :meth:`advance` once it is tracked.

    Parameters
    ----------
    config : SlamConfig
    odometry : OdometryModel
        The wheels' steps, their sigma model and what it learns.
    search : SearchBox
        The half-widths of the box around the seeds.
    prior : Trajectory, optional
        (x, y, yaw) poses of a 2D run (6-DOF runs only), interpolated at each frame's stamp.

    Attributes
    ----------
    poses, stamps : list
        The tracked poses (dof,) and their stamps, in order.
    frame : Frame or None
        The frame being predicted.
    use_prior : bool
        Whether the prior predicts :attr:`frame` (not where the wheels contradict it, :meth:`prior_contradicted`).
    """

    def __init__(self, config: SlamConfig, odometry: OdometryModel, search: SearchBox,
                 prior: Trajectory | None = None) -> None:
        self.config = config
        self.dim = config.dim
        self.odometry = odometry
        self.search = search
        self.prior = prior
        self.poses: list[NDArray[np.float64]] = []
        self.stamps: list[float] = []
        self.frame: Frame | None = None
        self.use_prior = True
        self._prior_at: dict[float, NDArray[np.float64] | None] = {}  # the prior's (x, y, yaw) at recent stamps

    def start(self, frame: Frame) -> None:
        """Predict ``frame`` next (the prior first, :attr:`use_prior`)."""
        self.frame, self.use_prior = frame, True

    def prior_pose(self, stamp: float) -> NDArray[np.float64] | None:
        """The prior's (x, y, yaw) at ``stamp`` with the previous pose's height, roll and pitch, or None."""
        if self.prior is None:
            return None
        planar = self._prior_at.get(stamp, False)
        if planar is False:  # a frame asks for its own stamp and the previous frame's several times
            poses, found = self.prior.interpolate([stamp], self.config.sync_tolerance)
            planar = poses[0] if found[0] else None
            self._prior_at = {k: v for k, v in self._prior_at.items() if k in self.stamps[-1:]} | {stamp: planar}
        if planar is None:
            return None
        (x, y, yaw), prev = planar, self.poses[-1]
        return np.array([x, y, prev[2], prev[3], prev[4], yaw])

    def tracking_box(self) -> NDArray[np.float64]:
        """The half-widths (dof,) of the tracking's search box without a prior (:meth:`SearchBox.ranges`)."""
        return self.search.ranges(self.poses, False)

    def seeds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Initial guesses (K, dof) for the frame and the half-widths (dof,) of the box around them: the previous
        pose, the last motion repeated (with :attr:`SearchBox.follows_motion`, also its translation alone, in the
        world, at the previous orientation), the odometry's prediction, the recent poses' mean, a prior's pose."""
        prev = self.poses[-1]
        seeds = [prev]
        if len(self.poses) >= 2:
            seeds.append(compose(prev, relative(self.poses[-2], prev)))
            if self.search.follows_motion:
                # a sensor carried by hand: the carrier walks on while the hand turns it at will, so the last
                # step's translation in the world with the orientation held is a motion of its own
                walk = prev.copy()
                walk[: self.dim] += prev[: self.dim] - self.poses[-2][: self.dim]
                seeds.append(walk)
        step = self.odometry.step(self.frame)
        if step is not None:
            seeds.append(compose(prev, step))
        if len(self.poses) >= 2:
            seeds.append(mean_pose(np.asarray(self.poses[-self.config.recent_poses:])))
        half = self.tracking_box()
        prior = self.prior_pose(self.frame.stamp)
        if prior is not None:
            seeds = [prior, *seeds]
            half = self.search.ranges(self.poses, True)
        s = np.asarray(seeds)
        # unwrap angles next to the previous pose so that the box is continuous across +/- pi
        s[:, self.dim:] = prev[self.dim:] + wrap_angle(s[:, self.dim:] - prev[self.dim:])
        return s, half

    def predict(self, gate: bool = False) -> Prediction:
        """The frame's predicted pose and the sigmas (translation, yaw) of its x/y and yaw, or None for the first
        two frames with neither a prior's pose nor an odometry step (``gate``: the odometry's sigmas never tighter
        than configured)."""
        return self._predict(gate, self.use_prior)

    def _predict(self, gate: bool, use_prior: bool) -> Prediction:
        cfg = self.config
        prev = self.poses[-1]
        step, model = None, None
        prior_now = self.prior_pose(self.frame.stamp) if use_prior else None
        prior_prev = self.prior_pose(self.stamps[-1]) if prior_now is not None else None
        if prior_now is not None and prior_prev is not None:
            step, model = relative(prior_prev, prior_now), cfg.prior_sigma
            step[2:5] = 0.0  # the prior knows x, y and yaw only
        elif (odo := self.odometry.step(self.frame)) is not None:
            step, model = self.odometry.corrected(odo), self.odometry.sigma(gate)
        elif len(self.poses) >= 2:
            step, model = relative(self.poses[-2], prev), cfg.motion_sigma
        if step is None:
            return None
        sig = np.array(self.odometry.model_sigmas(step, model))
        if self.dim == 2 and single_2d(prev, step):  # compose's and wrap_angle's arithmetic on floats
            x, y, yaw = compose_2d(prev.tolist(), step.tolist())
            yaw0 = float(prev[2])
            return np.array([x, y, yaw0 + wrap_angle_1(yaw - yaw0)]), sig
        pred = compose(prev, step).copy()
        pred[self.dim:] = prev[self.dim:] + wrap_angle(pred[self.dim:] - prev[self.dim:])
        return pred, sig

    def prior_contradicted(self, res: RegistrationResult) -> bool:
        """A run seeded by a prior: whether the frame's odometry step contradicts the prior's prediction and
        confirms the registration ``res`` instead (the prior's own step jumped, as a 2D run's may along a
        corridor)."""
        if self.prior is None:
            return False
        pred = self._predict(False, True)
        if pred is None:
            return False
        prev = self.poses[-1]
        return (not self.odometry.confirms(self.frame, prev, pred[0])
                and self.odometry.confirms(self.frame, prev, res.pose))

    def first_registration(self, res: RegistrationResult) -> None:
        """The frame's first registration ``res``: the odometry's bias learned from it; the odometry, not the
        prior, predicts the frame where :meth:`prior_contradicted`."""
        self.odometry.learn_bias(self.frame, res, self.poses[-1])
        self.use_prior = not self.prior_contradicted(res)

    def set_aside(self, res: RegistrationResult) -> bool:
        """Whether the frame's odometry step is a spike that the registration ``res`` beyond its gate sets aside
        (:meth:`OdometryModel.set_aside`)."""
        return self.odometry.set_aside(self.frame, res, self.poses)

    def consents(self, res: RegistrationResult) -> bool:
        """Whether a registration beyond a prior's gate may overrule it: where the wheels confirm it (two agreeing
        sources outweigh a scan that aligns better by aliasing, while a prior whose own step jumped is overruled);
        always in a run without a prior."""
        return self.prior is None or self.odometry.confirms(self.frame, self.poses[-1], res.pose)

    def kept_registration(self, res: RegistrationResult) -> None:
        """The registration kept for the frame: the odometry's scale learned from it, and the frame's step added to
        the wheel motion since the newest keyframe (with the bias and scale that :meth:`predict` then uses)."""
        self.odometry.learn_scale(self.frame, res)
        self.odometry.accumulate_wheel(self.frame)

    def advance(self, pose: NDArray[np.float64]) -> None:
        """The frame is tracked at ``pose`` (the last of :attr:`poses`): the next odometry step starts at it."""
        self.odometry.advance(self.frame, relative(self.poses[-2], pose) if len(self.poses) >= 2 else None)
