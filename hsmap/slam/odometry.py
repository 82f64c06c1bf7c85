"""The wheel odometry as HS-SLAM uses it (:class:`OdometryModel`): increments, their sigma model, the bias and
scale learned from the registrations, and the motion accumulated between keyframes (the graph's wheel edges)."""

from __future__ import annotations

import math
import warnings
from bisect import bisect_left, insort
from collections import deque

import numpy as np
from numpy.typing import NDArray

from ..datasets.frames import Frame
from ..errors import HsmapWarning
from ..geometry import (
    body_covariance_2d,
    compose,
    compose_2d,
    compose_with_covariance_2d,
    relative,
    relative_2d,
    single_2d,
    wrap_angle,
    wrap_angle_1,
)
from ..registration.icp import RegistrationResult
from ..registration.information import constrained_axes
from .config import SlamConfig

__all__ = ["OdometryModel", "constrains_xy", "slip_weight", "CHI2_999", "INFO_JITTER"]

#: 99.9 % quantiles of chi-square with 3 and 6 degrees of freedom, to 3 decimals: the gate on a prediction
CHI2_999 = {3: 16.266, 6: 22.458}
#: 1e-12 on the diagonal of an (n, n) information sum, keeping its solve regular
INFO_JITTER = {n: 1e-12 * np.eye(n) for n in (3, 6)}


def constrains_xy(info: NDArray[np.float64] | None, degenerate_ratio: float) -> bool:
    """Whether a registration's information (dof, dof) constrains its translation along both x and y (6-DOF: z
    may see walls only)."""
    if info is None or not all(map(math.isfinite, np.asarray(info, dtype=float).ravel().tolist())):
        return False
    # the block's eigenvalues in closed form (eigh reads its lower triangle); eigh itself decides where they lie
    # too near zero or the ratio for the closed form's rounding to tell
    a, b, c = float(info[0, 0]), float(info[1, 0]), float(info[1, 1])
    mid, r = 0.5 * (a + c), math.hypot(0.5 * (a - c), b)
    hi, lo = mid + r, mid - r
    tol = 1e-9 * (abs(a) + abs(b) + abs(c))
    if hi > tol and abs(lo - degenerate_ratio * hi) > tol:
        return lo > degenerate_ratio * hi
    return constrained_axes(info[:2, :2], degenerate_ratio).shape[1] == 2


def slip_weight(d: NDArray[np.float64], info_a: NDArray[np.float64], info_b: NDArray[np.float64]) -> float:
    """The weight (<= 1) of measurement b where it lies ``d`` (n,) from measurement a: 1 within their joint
    uncertainty, ``gate / m2`` beyond the chi-square 99.9 % quantile, ``m2`` being d's squared Mahalanobis length
    under the information of their difference, I_a (I_a + I_b)^-1 I_b."""
    n = len(d)
    gate = CHI2_999[n]
    # the information of the difference is at most I_b (both positive semi-definite): d within half the gate under
    # I_b lies within the gate, without the solve
    if float(d @ info_b @ d) <= 0.5 * gate:
        return 1.0
    m2 = float(d @ (info_a @ np.linalg.solve(info_a + info_b + INFO_JITTER[n], info_b)) @ d)
    return gate / m2 if m2 > gate else 1.0


def _distance(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    """How far apart two planar steps (x, y, yaw) end, a radian of turn counted as a metre."""
    d = relative(a, b)
    return float(np.hypot(d[0], d[1]) + abs(wrap_angle(d[2])))


def _middle_apart(s: list[float], m: float) -> float:
    """The median of ``abs(v - m)`` over the sorted values ``s`` (at least one), as ``np.median`` gives it: the
    distances below ``m`` and those from it up are each sorted, and the middle of the two runs together is found
    by bisection."""
    n = len(s)
    k = n // 2  # the k-th smallest (from 0), averaged with the (k - 1)-th for an even count
    p = bisect_left(s, m)  # s[p - 1 - i] - m for i = 0.. and s[p + j] - m for j = 0.. grow apart from m
    lo, hi = max(0, k + 1 - (n - p)), min(k + 1, p)
    while lo < hi:  # the fewest taken below m such that the next one below is no nearer than the last one above
        i = (lo + hi) // 2
        if abs(s[p - 1 - i] - m) < abs(s[p + k - i] - m):
            lo = i + 1
        else:
            hi = i
    # the k + 1 nearest: lo below m (the last of them at s[p - lo]), k + 1 - lo from it up (the last at s[p + k - lo])
    below = [abs(s[p - lo + t] - m) for t in range(min(lo, 2))]  # the farthest one or two of those below
    above = [abs(s[p + k - lo - t] - m) for t in range(min(k + 1 - lo, 2))]  # and of those above
    last = sorted(below + above)
    return last[-1] if n % 2 else (last[-2] + last[-1]) / 2


class _Window:
    """The last ``size`` rows of three values, each column's finite values also kept sorted: the medians and the
    median absolute deviations of the window without sorting it again (the values of ``np.median``'s)."""

    def __init__(self, size: int) -> None:
        self._rows: deque[tuple[float, float, float]] = deque(maxlen=size)
        self._sorted: tuple[list[float], ...] = ([], [], [])

    def __len__(self) -> int:
        return len(self._rows)

    def append(self, row: tuple[float, float, float]) -> None:
        if len(self._rows) == self._rows.maxlen:
            for col, v in zip(self._sorted, self._rows[0], strict=True):
                if math.isfinite(v):
                    del col[bisect_left(col, v)]
        self._rows.append(row)
        for col, v in zip(self._sorted, row, strict=True):
            if math.isfinite(v):
                insort(col, v)

    def finite(self, c: int) -> int:
        """How many of column ``c``'s values are finite."""
        return len(self._sorted[c])

    def median(self, c: int) -> float:
        """The median of column ``c``'s finite values (at least one)."""
        s = self._sorted[c]
        k = len(s) // 2
        return s[k] if len(s) % 2 else (s[k - 1] + s[k]) / 2

    def deviation(self, c: int) -> float:
        """The median absolute deviation of column ``c``'s finite values (at least one) from their median."""
        return _middle_apart(self._sorted[c], self.median(c))


class OdometryModel:
    """The odometry of one run: what it predicts and how far to trust it.

    Parameters
    ----------
    config : SlamConfig
        ``use_odometry``, ``odometry_sigma`` and the ``odometry_*`` learning settings.
    learn : bool
        Learn the bias and the scale of the sigma model from the registrations.
    wheel_edges : bool
        Accumulate the motion (and its covariance) since the newest keyframe for the graph's wheel edges.
    prior : bool
        The run is seeded by a prior trajectory (no odometry step is then set aside, :meth:`set_aside`).

    Attributes
    ----------
    scale : ndarray of shape (2,)
        The learned scale of the sigma model (translation, rotation).
    bias : ndarray of shape (3,)
        The learned systematic error (x, y, yaw) in sigmas of the configured model.
    outliers : list of int
        Frames whose odometry step was set aside (:meth:`set_aside`).
    """

    def __init__(self, config: SlamConfig, *, learn: bool, wheel_edges: bool, prior: bool = False) -> None:
        self.config = config
        self.dim = config.dim
        self.learn = learn
        self.wheel_edges = wheel_edges
        self.prior = prior
        self.previous: NDArray[np.float64] | None = None  # the last frame's odometry reading
        # the last step: both readings' bytes, the two readings (objects) and their increment
        self._last_step: tuple | None = None
        # the last frame's odometry step, where it was used (the wheels' own previous motion, for set_aside)
        self._wheel_step: NDArray[np.float64] | None = None
        self._spike: NDArray[np.float64] | None = None  # the reading of a frame whose step was set aside
        self.outliers: list[int] = []
        self.scale = np.ones(2)
        self.bias = np.zeros(3)
        self._corrected: tuple | None = None  # the last step corrected: (the bias, the step's bytes, the result)
        # the one-frame disagreements with the registrations (bias) and the lagged ones (scale), in model sigmas
        self._disagreement = _Window(config.odometry_window)
        self._lagged = _Window(config.odometry_window)
        # per frame, for the scale: the registration's pose, whether its translation was constrained, the raw
        # odometry, and the configured model's variances summed from the first frame (translation, rotation)
        self._history: deque[tuple] = deque(maxlen=config.odometry_lag + 1)
        self._variance = (0.0, 0.0)
        # the motion since the newest keyframe and its covariance, in that keyframe's frame (None: a frame
        # without odometry came between)
        self.wheel_motion: NDArray[np.float64] | None = np.zeros(3)
        self.wheel_covariance = np.zeros((3, 3))
        self.wheel_gated = 0  # wheel edges down-weighted (slipped)

    def step(self, frame: Frame) -> NDArray[np.float64] | None:
        """The odometry increment since the previous frame, as a pose vector of the run's dof, or None.

        After a frame whose step was set aside, the increment starts at whichever of two readings continues the
        wheels' steady motion (their last used step): the odometry as it would have read there (a spike that
        returns) or the reading it sent (a jump that stays)."""
        if not (self.config.use_odometry and frame.odometry is not None and self.previous is not None):
            return None
        if self.outliers and self.outliers[-1] == frame.index:
            return None
        # a frame asks for its step several times (seeds, predictions, learning, wheel edges): the increment
        # between the same two readings (the same objects, else the same bits) is computed once
        last = self._last_step
        if last is not None and last[1] is frame.odometry and last[2] is self.previous:
            return last[3].copy()
        odom = np.asarray(frame.odometry, dtype=float)
        key = np.asarray(self.previous, dtype=float).tobytes() + odom.tobytes()  # the readings, bit for bit
        if last is not None and last[0] == key:
            self._last_step = (key, frame.odometry, self.previous, last[3])
            return last[3].copy()
        delta = relative(self.previous, odom)  # (x, y, yaw) increment in the robot frame
        if self._spike is not None and self._wheel_step is not None:
            stays = relative(self._spike, odom)
            if _distance(stays, self._wheel_step[[0, 1, -1]]) < _distance(delta, self._wheel_step[[0, 1, -1]]):
                delta = stays
        if self.config.dof != 3:
            delta = np.array([delta[0], delta[1], 0.0, 0.0, 0.0, delta[2]])
        self._last_step = (key, frame.odometry, self.previous, delta)
        return delta.copy()

    def advance(self, frame: Frame, motion: NDArray[np.float64] | None = None) -> None:
        """The frame is done: the next increment starts at its odometry (where it has one), or, where its step was
        set aside, at the odometry as it would read had it moved by ``motion`` (the tracked motion, (dof,)) or at
        the reading it sent, whichever the next step finds steadier (:meth:`step`)."""
        if frame.odometry is None:
            self._wheel_step = self._spike = None
            return
        if self.outliers[-1:] == [frame.index] and motion is not None:
            self._spike = np.asarray(frame.odometry, dtype=float)
            self.previous = compose(self.previous, motion if self.config.dof == 3 else motion[[0, 1, 5]])
            return
        self._wheel_step = self.step(frame)
        self._spike = None
        self.previous = np.asarray(frame.odometry, dtype=float)

    def set_aside(self, frame: Frame, res: RegistrationResult, poses: list[NDArray[np.float64]]) -> bool:
        """Whether the frame's odometry step is a spike to be set aside (with a warning); the frame is then tracked
        without it. The registration ``res`` lies outside the odometry's gate (the caller checked).

        Only evidence the matches cannot have made themselves counts: the wheels' own step jumps, ending further
        than ``verify_sigmas`` of ``motion_sigma`` from where their previous step (the last frame's, used) would
        put it, while the registration and the previous tracked motion (from ``poses``) agree; the registration
        constrains its translation in every direction (``degenerate_ratio``); and the previous frame's step was
        not set aside. A scan match that slides is a run of matches drifting while the wheels stay steady: the
        wheels win there, as they do wherever the match is poorly constrained."""
        cfg = self.config
        if self.prior or len(poses) < 2 or frame.index is None or self._wheel_step is None:
            return False
        if self.outliers and self.outliers[-1] == frame.index - 1:
            return False
        if not constrains_xy(res.information, cfg.degenerate_ratio):
            return False
        odo = self.step(frame)
        if odo is None:
            return False
        prev = poses[-1]
        motion = relative(poses[-2], prev)
        st, sr = self.model_sigmas(motion, cfg.motion_sigma)

        def apart(a: NDArray[np.float64], b: NDArray[np.float64]) -> bool:
            d = relative(a, b)
            return bool(np.linalg.norm(d[:2]) > cfg.verify_sigmas * st or
                        abs(wrap_angle(d[-1])) > cfg.verify_sigmas * sr)

        by_motion, by_odometry = compose(prev, motion), compose(prev, self.corrected(odo))
        by_wheels = compose(prev, self.corrected(self._wheel_step))
        if not apart(by_wheels, by_odometry) or not apart(by_motion, by_odometry) or apart(by_motion, res.pose):
            return False
        self.outliers.append(int(frame.index))
        d = relative(by_odometry, res.pose)
        warnings.warn(f"frame {frame.index} (stamp {frame.stamp:.6f}): its odometry puts it "
                      f"{float(np.linalg.norm(d[:2])):.2f} m and {float(np.rad2deg(abs(wrap_angle(d[-1])))):.1f} deg "
                      "from where the scan match and the previous motion agree it is, a jump the wheels' previous "
                      "step does not make; that odometry step is not used", HsmapWarning, stacklevel=3)
        return True

    def confirms(self, frame: Frame, previous_pose: NDArray[np.float64], pose: NDArray[np.float64]) -> bool:
        """Whether the frame's odometry step from ``previous_pose`` ends within ``verify_sigmas`` of the gate's
        sigmas (:meth:`sigma` with ``gate``) of ``pose``; True for a frame without an odometry step."""
        step = self.step(frame)
        if step is None:
            return True
        step = self.corrected(step)
        st, sr = self.model_sigmas(step, self.sigma(gate=True))
        d = relative(compose(previous_pose, step), pose)
        k = self.config.verify_sigmas
        return bool(np.linalg.norm(d[:2]) <= k * st and np.abs(wrap_angle(d[self.dim:])).max() <= k * sr)

    def sigma(self, gate: bool = False) -> tuple[float, ...]:
        """The sigma model (``SlamConfig.odometry_sigma``) scaled by what was learned (``gate``: never below the
        configured model)."""
        a, b, c, d, e = self.config.odometry_sigma
        st, sr = self.scale.tolist()
        if gate:
            st, sr = max(st, 1.0), max(sr, 1.0)
        return a * st, b * st, c * sr, d * sr, e * sr

    def model_sigmas(self, step: NDArray[np.float64], model: tuple[float, ...] | None = None
                     ) -> tuple[float, float]:
        """A sigma model's (translation, rotation) sigmas for one step: ``model`` (a, b, c, d, e as
        ``SlamConfig.odometry_sigma``), by default the configured odometry model."""
        a, b, c, d, e = self.config.odometry_sigma if model is None else model
        if self.dim == 2:  # np.linalg.norm's and wrap_angle's arithmetic on three floats
            x, y, yaw = step.tolist() if isinstance(step, np.ndarray) else step
            dist, turn = math.sqrt(x * x + y * y), abs(wrap_angle_1(yaw))
        else:
            dist = float(np.linalg.norm(step[: self.dim]))
            turn = float(np.abs(wrap_angle(step[self.dim:])).max())
        return a + b * dist, c + d * turn + e * dist

    def corrected(self, step: NDArray[np.float64]) -> NDArray[np.float64]:
        """The step with the learned bias taken out (in the model's sigmas: it grows with distance and turn)."""
        if not self.bias.any():
            return step
        # a frame corrects its step several times (predictions, the wheel motion): the step, bit for bit, under
        # the same bias (replaced when learned, never changed in place) is corrected once
        key = np.asarray(step, dtype=float).tobytes()
        kept = self._corrected
        if kept is not None and kept[0] is self.bias and kept[1] == key:
            return kept[2].copy()
        st, sr = self.model_sigmas(step)
        bx, by, byaw = self.bias.tolist()
        if self.config.dof == 3 and single_2d(step):
            out = np.array(compose_2d(step.tolist(), (bx * st, by * st, byaw * sr)))
        else:
            fix = np.zeros(self.config.dof)
            fix[0], fix[1], fix[-1] = bx * st, by * st, byaw * sr
            out = compose(step, fix)
        self._corrected = (self.bias, key, out)
        return out.copy()

    def learn_bias(self, frame: Frame, res: RegistrationResult, previous_pose: NDArray[np.float64]) -> None:
        """Record how far the frame's first registration lies from the raw odometry's prediction (from
        ``previous_pose``); the bias is the median of these disagreements, x and y only where the scene constrains
        the registration's translation."""
        cfg = self.config
        if not self.learn:
            return
        step = self.step(frame)
        if step is None:
            return
        st0, sr0 = self.model_sigmas(step)
        # the registration in the raw prediction's frame
        if self.config.dof == 3 and single_2d(previous_pose, step, res.pose):
            off = relative_2d(compose_2d(previous_pose.tolist(), step.tolist()), res.pose.tolist())
        else:
            off = relative(compose(previous_pose, step), res.pose).tolist()
        constrained = constrains_xy(res.information, cfg.degenerate_ratio)
        xy = (off[0] / st0, off[1] / st0) if constrained else (math.nan, math.nan)
        window = self._disagreement
        window.append((*xy, wrap_angle_1(off[-1]) / sr0))
        need = max(cfg.odometry_window // 10, 1)
        enough = [window.finite(c) >= need for c in range(3)]
        if any(enough):
            self.bias = np.array([window.median(c) if enough[c] else 0.0 for c in range(3)])

    def learn_scale(self, frame: Frame, res: RegistrationResult) -> None:
        """Learn the model's scale from how the registrations' and the odometry's motions disagree over
        ``odometry_lag`` frames, between two frames whose registrations the scene constrained in translation: the
        robust spread (MAD, as a Gaussian's sigma) of the last ``odometry_window`` disagreements, normalised by
        the configured model summed over the lag."""
        cfg = self.config
        if not self.learn or not cfg.use_odometry or frame.odometry is None:
            self._history.clear()
            return
        step = self.step(frame)
        if step is None:
            self._history.clear()  # the first frame with odometry: nothing to compare with yet
        else:
            st, sr = self.model_sigmas(step)
            vt, vr = self._variance
            self._variance = (vt + st * st, vr + sr * sr)
        constrained = constrains_xy(res.information, cfg.degenerate_ratio)
        pose = (res.pose if cfg.dof == 3 else res.pose[[0, 1, 5]]).tolist()
        odom = np.asarray(frame.odometry, dtype=float).tolist()
        self._history.append((pose, constrained, odom, self._variance))
        if len(self._history) <= cfg.odometry_lag or not constrained:
            return
        p0, c0, o0, v0 = self._history[0]
        if not c0:
            return
        dvt, dvr = self._variance[0] - v0[0], self._variance[1] - v0[1]
        if not (dvt > 0.0 and dvr > 0.0):  # no spread to normalise by
            return
        # the registrations' motion in the odometry's frame
        e = relative_2d(relative_2d(o0, odom), relative_2d(p0, pose))
        st, sr = math.sqrt(dvt), math.sqrt(dvr)
        z = (e[0] / st, e[1] / st, wrap_angle_1(e[2]) / sr)
        if not all(math.isfinite(v) for v in z):
            return
        self._lagged.append(z)
        if len(self._lagged) < max(cfg.odometry_window // 10, 1):
            return
        spread = [1.4826 * self._lagged.deviation(c) for c in range(3)]  # MAD as a Gaussian's sigma
        lo, hi = cfg.odometry_scale_bounds
        self.scale = np.array([min(max(max(spread[0], spread[1]), lo), hi), min(max(spread[2], lo), hi)])

    def accumulate_wheel(self, frame: Frame) -> None:
        """Add the frame's step (bias out) to the wheel motion since the newest keyframe, its covariance
        propagated to first order from the learned sigma model."""
        step = self.step(frame)
        if self.wheel_motion is None or step is None or not self.wheel_edges:
            self.wheel_motion = None
            return
        step = self.corrected(step)
        # the sigma model as model_sigmas evaluates it, with hypot for the distance
        a, b, c, d, e = self.sigma()
        dist = float(np.hypot(step[0], step[1]))
        st, sr = a + b * dist, c + d * abs(wrap_angle_1(float(step[2]))) + e * dist
        self.wheel_motion, self.wheel_covariance = compose_with_covariance_2d(
            self.wheel_motion, self.wheel_covariance, step, np.diag([st ** 2, st ** 2, sr ** 2]))

    def restart_wheel(self, frame: Frame) -> None:
        """A keyframe at ``frame``: the next wheel edge measures from its odometry (none without one)."""
        self.wheel_motion = np.zeros(3) if frame.odometry is not None else None
        self.wheel_covariance = np.zeros((3, 3))

    def wheel_edge(self, z_tracking: NDArray[np.float64], info_tracking: NDArray[np.float64]
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        """The wheel edge from the previous keyframe to the new one (measurement (3,), information (3, 3)), or None.

        Its information is the inverse of the propagated covariance in the edge's end frame; an edge further from
        the tracking edge ``z_tracking`` than their joint uncertainty allows (a wheel slipped) is down-weighted.
        """
        z, cov = self.wheel_motion, self.wheel_covariance
        if z is None or not (np.all(np.isfinite(z)) and np.all(np.isfinite(cov))) or cov[2, 2] <= 0.0:
            return None
        info = np.linalg.inv(body_covariance_2d(z, cov))
        d = relative(z_tracking, z)
        d[2] = wrap_angle(d[2])
        info_t = np.linalg.inv(body_covariance_2d(z_tracking, cov))
        w = slip_weight(d, info_tracking, info_t)
        if w < 1.0:
            info = info * w
            self.wheel_gated += 1
        return z.copy(), 0.5 * (info + info.T)

    def summary(self) -> dict:
        """The learned scale and bias and how many frames taught them (JSON-ready)."""
        return {"learned": bool(self.config.learn_odometry and len(self._disagreement) > 0),
                "frames": len(self._disagreement),  # the bias's one-frame disagreements
                "lagged_frames": len(self._lagged),  # the scale's
                "scale_translation": float(self.scale[0]),
                "scale_rotation": float(self.scale[1]),
                "bias": [float(v) for v in self.bias],  # x, y, yaw in sigmas of the configured model
                "set_aside": len(self.outliers),  # frames whose odometry step was set aside
                "sigma": [float(v) for v in self.sigma()]}
