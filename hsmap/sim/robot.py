"""A differential-drive robot that follows waypoints, and its drifting wheel odometry.

The robot drives like a simple waypoint follower: to reach the next waypoint it first turns on the spot to
face it (or to face away from it when the leg is driven in reverse), then drives straight; both motions
follow trapezoidal velocity profiles limited by the maximum speed, turn rate and accelerations. The motion
is sampled at an internal rate (100 Hz by default), where the wheel odometry is integrated with

- a systematic scale error on the distance travelled (wheel radius error),
- a systematic scale error on rotations (wheel base error),
- a heading bias proportional to the signed distance driven (unequal wheel radii: the robot believes it
  drives straight while it curves, which bends corridors in an odometry-only map), and
- random slip: zero-mean Gaussian increments whose variance grows linearly with the distance and the angle
  travelled, several times stronger when turning on the spot.

Odometry starts at the first ground-truth pose. All randomness comes from the ``rng`` passed in.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import ConfigError
from ..geometry import matrix_to_pose, pose_to_matrix, wrap_angle
from ..limits import check_allocation

__all__ = ["RobotConfig", "OdometryConfig", "RouteStep", "Leg", "Motion", "plan_legs", "simulate_motion",
           "integrate_odometry", "mast_sway", "mast_poses", "mast_matrices"]


def _positive(name: str, value: float, allow_zero: bool = False) -> None:
    ok = value >= 0 if allow_zero else value > 0
    if not (isinstance(value, (int, float)) and np.isfinite(value) and ok):
        raise ConfigError(f"{name} must be a number {'>= 0' if allow_zero else '> 0'}, got {value!r}")


@dataclass
class RobotConfig:
    """Kinematic limits of the differential-drive base.

    Attributes
    ----------
    radius : float
        Footprint radius, metres (routes must keep this clearance from walls and furniture).
    wheel_base : float
        Distance between the wheels, metres (used to weigh turning slip).
    max_speed : float
        Metres per second (0.5: at most 0.25 m between frames at 2 Hz).
    max_turn_rate_deg : float
        Degrees per second (30: at most 15 deg between frames at 2 Hz).
    acceleration : float
        Metres per second squared.
    turn_acceleration_deg : float
        Degrees per second squared.
    internal_rate : float
        Hz at which motion is sampled and odometry is integrated.
    """

    radius: float = 0.22
    wheel_base: float = 0.40
    max_speed: float = 0.5
    max_turn_rate_deg: float = 30.0
    acceleration: float = 0.5
    turn_acceleration_deg: float = 60.0
    internal_rate: float = 100.0

    def __post_init__(self) -> None:
        for name in ("radius", "wheel_base", "max_speed", "max_turn_rate_deg", "acceleration",
                     "turn_acceleration_deg", "internal_rate"):
            _positive(f"robot.{name}", getattr(self, name))


@dataclass
class OdometryConfig:
    """Wheel-odometry error model (see the module docstring).

    Attributes
    ----------
    scale_error : float
        Relative error of measured distances (0.02: 2 % too long).
    turn_scale_error : float
        Relative error of measured rotations.
    heading_bias_deg_per_m : float
        Unnoticed heading change per metre driven forward (backwards: the opposite), degrees per metre.
    slip_translation : float
        Standard deviation of the distance error after 1 m, metres (grows with the square root of distance).
    slip_rotation_deg : float
        Standard deviation of the heading error after turning 1 rad, degrees (grows with the square root).
    slip_heading_deg_per_m : float
        Standard deviation of the heading error after driving 1 m, degrees.
    turn_slip_factor : float
        Multiplier on the rotational slip standard deviation while turning on the spot.
    """

    scale_error: float = 0.015
    turn_scale_error: float = 0.01
    heading_bias_deg_per_m: float = 0.12
    slip_translation: float = 0.005
    slip_rotation_deg: float = 0.3
    slip_heading_deg_per_m: float = 0.15
    turn_slip_factor: float = 3.0

    def __post_init__(self) -> None:
        for name in ("scale_error", "turn_scale_error", "heading_bias_deg_per_m"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v)):
                raise ConfigError(f"odometry.{name} must be a finite number, got {v!r}")
        if self.scale_error <= -1 or self.turn_scale_error <= -1:
            raise ConfigError("odometry.scale_error and turn_scale_error must be > -1")
        for name in ("slip_translation", "slip_rotation_deg", "slip_heading_deg_per_m"):
            _positive(f"odometry.{name}", getattr(self, name), allow_zero=True)
        if not (isinstance(self.turn_slip_factor, (int, float)) and self.turn_slip_factor >= 1):
            raise ConfigError(f"odometry.turn_slip_factor must be >= 1, got {self.turn_slip_factor!r}")

    @classmethod
    def perfect(cls) -> OdometryConfig:
        """An error-free odometry (for tests and comparisons)."""
        return cls(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)


@dataclass
class RouteStep:
    """One instruction of a route.

    ``kind`` is ``"goto"`` (drive to ``xy``; backwards when ``reverse``), ``"turn"`` (turn on the spot by
    ``angle`` radians, counter-clockwise positive, may exceed a full turn), ``"face"`` (turn on the spot to
    the absolute heading ``angle``) or ``"wait"`` (stand still ``seconds``). ``speed`` caps the leg's speed.
    ``where`` names the step in its scenario file for error messages.
    """

    kind: str
    xy: tuple[float, float] | None = None
    reverse: bool = False
    angle: float = 0.0
    seconds: float = 0.0
    speed: float | None = None
    where: str = ""


@dataclass
class Leg:
    """One elementary motion: a straight drive, a turn on the spot or a wait, with a trapezoidal profile."""

    kind: str  # "drive" | "turn" | "wait"
    t0: float
    duration: float
    start: NDArray[np.float64]  # (x, y, yaw)
    amount: float  # signed metres (drive) or radians (turn); 0 for wait
    peak: float  # peak speed of the profile (m/s or rad/s)
    accel: float
    where: str = ""

    @property
    def end(self) -> NDArray[np.float64]:
        return self.pose_at(np.array([self.duration]))[0]

    def _progress(self, tau: NDArray[np.float64]) -> NDArray[np.float64]:
        """Unsigned distance (or angle) covered after ``tau`` seconds."""
        total = abs(self.amount)
        if self.kind == "wait" or total == 0.0:
            return np.zeros_like(tau)
        tau = np.clip(tau, 0.0, self.duration)
        ta = self.peak / self.accel
        tc = self.duration - 2 * ta
        s_acc = 0.5 * self.accel * ta**2
        s = np.where(
            tau < ta,
            0.5 * self.accel * tau**2,
            np.where(
                tau < ta + tc,
                s_acc + self.peak * (tau - ta),
                total - 0.5 * self.accel * np.maximum(self.duration - tau, 0.0) ** 2,
            ),
        )
        return np.clip(s, 0.0, total)

    def pose_at(self, tau: NDArray[np.float64]) -> NDArray[np.float64]:
        """Poses (T, 3) at times ``tau`` (T,) since the leg's start."""
        s = np.sign(self.amount) * self._progress(np.asarray(tau, dtype=float))
        out = np.repeat(self.start[None, :], len(s), 0).astype(float)
        if self.kind == "drive":
            out[:, 0] += s * np.cos(self.start[2])
            out[:, 1] += s * np.sin(self.start[2])
        elif self.kind == "turn":
            out[:, 2] = wrap_angle(self.start[2] + s)
        return out


def _profile(total: float, vmax: float, acc: float) -> tuple[float, float]:
    """(duration, peak speed) of a trapezoidal profile covering ``total`` (> 0)."""
    if total >= vmax**2 / acc:
        return 2 * vmax / acc + (total - vmax**2 / acc) / vmax, vmax
    peak = float(np.sqrt(total * acc))
    return 2 * peak / acc, peak


def plan_legs(start: ArrayLike, steps: list[RouteStep], robot: RobotConfig, t0: float = 0.0) -> list[Leg]:
    """Turn a route (start pose (x, y, yaw) and steps) into timed legs.

    Returns
    -------
    list of Leg
        Consecutive legs; each starts when and where the previous one ends.
    """
    pose = np.asarray(start, dtype=float).copy()
    t = float(t0)
    legs: list[Leg] = []
    wmax = np.deg2rad(robot.max_turn_rate_deg)
    wacc = np.deg2rad(robot.turn_acceleration_deg)

    def add_turn(angle: float, where: str) -> None:
        nonlocal pose, t
        if abs(angle) < 1e-9:
            return
        dur, peak = _profile(abs(angle), wmax, wacc)
        leg = Leg("turn", t, dur, pose.copy(), float(angle), peak, wacc, where)
        legs.append(leg)
        pose = leg.end
        pose[2] = wrap_angle(legs[-1].start[2] + angle)
        t += dur

    for step in steps:
        if step.kind == "goto":
            d = np.asarray(step.xy, dtype=float) - pose[:2]
            dist = float(np.hypot(*d))
            if dist < 1e-9:
                continue
            heading = np.arctan2(d[1], d[0]) + (np.pi if step.reverse else 0.0)
            add_turn(float(wrap_angle(heading - pose[2])), step.where)
            vmax = min(robot.max_speed, step.speed) if step.speed else robot.max_speed
            dur, peak = _profile(dist, vmax, robot.acceleration)
            leg = Leg("drive", t, dur, pose.copy(), -dist if step.reverse else dist, peak, robot.acceleration,
                      step.where)
            legs.append(leg)
            pose = leg.end
            pose[:2] = step.xy  # exactly on the waypoint
            t += dur
        elif step.kind == "turn":
            add_turn(step.angle, step.where)
        elif step.kind == "face":
            add_turn(float(wrap_angle(step.angle - pose[2])), step.where)
        elif step.kind == "wait":
            if step.seconds > 0:
                legs.append(Leg("wait", t, float(step.seconds), pose.copy(), 0.0, 0.0, 1.0, step.where))
                t += step.seconds
        else:  # pragma: no cover - parser only makes the kinds above
            raise ValueError(f"unknown route step kind {step.kind!r}")
    return legs


def sample_legs(legs: list[Leg], times: ArrayLike) -> NDArray[np.float64]:
    """Ground-truth poses (T, 3) at absolute ``times`` (T,) along ``legs`` (held at the end afterwards)."""
    times = np.asarray(times, dtype=float)
    out = np.empty((len(times), 3))
    starts = np.array([leg.t0 for leg in legs])
    idx = np.clip(np.searchsorted(starts, times, side="right") - 1, 0, len(legs) - 1)
    for k in np.unique(idx):
        sel = idx == k
        out[sel] = legs[k].pose_at(times[sel] - legs[k].t0)
    return out


def integrate_odometry(poses: ArrayLike, config: OdometryConfig, wheel_base: float,
                       rng: np.random.Generator) -> NDArray[np.float64]:
    """Wheel odometry (T, 3) from densely sampled true poses (T, 3), starting at ``poses[0]``.

    The true increments between consecutive samples are expressed in the robot frame (distance ``ds``
    along the heading, rotation ``dth``), corrupted by the error model of :class:`OdometryConfig`, and
    integrated with the midpoint rule.
    """
    p = np.asarray(poses, dtype=float)
    c, s = np.cos(p[:-1, 2]), np.sin(p[:-1, 2])
    d = np.diff(p[:, :2], axis=0)
    ds = d[:, 0] * c + d[:, 1] * s
    dth = wrap_angle(np.diff(p[:, 2]))
    ads, adth = np.abs(ds), np.abs(dth)
    # fraction of the wheel travel that comes from turning: 1 when turning on the spot, 0 when driving straight
    spin = adth * wheel_base / 2 / np.maximum(adth * wheel_base / 2 + ads, 1e-12)
    rot_sigma = np.deg2rad(config.slip_rotation_deg) * (1.0 + (config.turn_slip_factor - 1.0) * spin)
    n_s = rng.standard_normal(len(ds)) * config.slip_translation * np.sqrt(ads)
    n_th = rng.standard_normal(len(ds)) * np.sqrt(
        rot_sigma**2 * adth + np.deg2rad(config.slip_heading_deg_per_m) ** 2 * ads
    )
    ds_m = ds * (1.0 + config.scale_error) + n_s
    dth_m = dth * (1.0 + config.turn_scale_error) + np.deg2rad(config.heading_bias_deg_per_m) * ds + n_th
    th = p[0, 2] + np.concatenate([[0.0], np.cumsum(dth_m)])
    mid = th[:-1] + dth_m / 2
    x = p[0, 0] + np.concatenate([[0.0], np.cumsum(ds_m * np.cos(mid))])
    y = p[0, 1] + np.concatenate([[0.0], np.cumsum(ds_m * np.sin(mid))])
    return np.column_stack([x, y, wrap_angle(th)])


@dataclass
class Motion:
    """Ground truth and odometry of a simulated run.

    Attributes
    ----------
    stamps : ndarray of shape (N,)
        Frame times, seconds.
    groundtruth, odometry : ndarray of shape (N, 3)
        Robot base poses (x, y, yaw) at the frame times, in the world and in the odometry frame.
    legs : list of Leg
        The planned motion.
    sample_times : ndarray of shape (S,)
        The internal sampling times (``stamps`` is a subset).
    sample_groundtruth, sample_odometry : ndarray of shape (S, 3)
        Poses at the internal rate.
    """

    stamps: NDArray[np.float64]
    groundtruth: NDArray[np.float64]
    odometry: NDArray[np.float64]
    legs: list[Leg]
    sample_times: NDArray[np.float64]
    sample_groundtruth: NDArray[np.float64]
    sample_odometry: NDArray[np.float64]

    def __len__(self) -> int:
        return len(self.stamps)

    def path_length(self) -> float:
        """Length of the ground-truth path, metres (from the internal samples)."""
        return float(np.linalg.norm(np.diff(self.sample_groundtruth[:, :2], axis=0), axis=1).sum())


def simulate_motion(start: ArrayLike, steps: list[RouteStep], robot: RobotConfig, odometry: OdometryConfig,
                    frame_rate: float, rng: np.random.Generator, start_time: float = 0.0) -> Motion:
    """Drive the route and return ground truth and odometry at ``frame_rate`` Hz.

    The internal rate is rounded up to a whole multiple of ``frame_rate`` so that every frame coincides with
    an internal sample. Frames run from ``start_time`` until the route is finished (the last frame at or
    just after its end).
    """
    if not (frame_rate > 0 and np.isfinite(frame_rate)):
        raise ConfigError(f"frame_rate must be > 0 Hz, got {frame_rate}")
    legs = plan_legs(start, steps, robot, start_time)
    if not legs:
        raise ConfigError("the route does not move the robot")
    end = legs[-1].t0 + legs[-1].duration
    per_frame = max(1, int(np.ceil(robot.internal_rate / frame_rate - 1e-9)))
    n_frames = int(np.ceil((end - start_time) * frame_rate - 1e-9)) + 1  # the last frame sees the route's end
    n_samples = (n_frames - 1) * per_frame + 1

    check_allocation(float(n_samples) * 8 * 12, f"frame_rate {frame_rate} Hz: {n_samples} motion samples",
                     ConfigError)
    times = start_time + np.arange(n_samples) / (frame_rate * per_frame)
    gt = sample_legs(legs, times)
    odo = integrate_odometry(gt, odometry, robot.wheel_base, rng)
    sel = np.arange(0, n_samples, per_frame)
    return Motion(times[sel], gt[sel], odo[sel], legs, times, gt, odo)


def mast_sway(legs: list[Leg], times: ArrayLike, foot: ArrayLike, height: float, frequency: float,
              damping: float, rate: float = 200.0) -> NDArray[np.float64]:
    """Roll and pitch (T, 2) of a mast at ``times`` (T,), swaying as a damped oscillator driven by the base.

    The mast stands at ``foot`` (x, y) in the base frame and is ``height`` metres tall; the base's acceleration
    ``a`` at the foot (in the base frame, from ``legs``) drives its tilt from rest at the first leg's start:
    ``pitch'' + 2 z w pitch' + w^2 pitch = -a_x / height`` and ``roll'' + 2 z w roll' + w^2 roll = a_y / height``
    (``w = 2 pi frequency``, ``z = damping``: the top lags behind the base), integrated exactly for an
    acceleration held over each ``1 / rate`` step.
    """
    from scipy.signal import cont2discrete, lfilter

    t = np.asarray(times, dtype=float).reshape(-1)
    if frequency <= 0 or len(t) == 0 or not legs:
        return np.zeros((len(t), 2))
    t0 = legs[0].t0
    t1 = max(float(t.max()), t0)
    n = min(int(np.ceil((t1 - t0) * rate)) + 3, 50_000_000)
    grid = t0 + np.arange(n) / rate
    pose = sample_legs(legs, grid)
    c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
    fx, fy = float(foot[0]), float(foot[1])
    world = np.column_stack([pose[:, 0] + c * fx - s * fy, pose[:, 1] + s * fx + c * fy])
    acc = np.gradient(np.gradient(world, 1.0 / rate, axis=0), 1.0 / rate, axis=0)
    a_x, a_y = c * acc[:, 0] + s * acc[:, 1], -s * acc[:, 0] + c * acc[:, 1]
    w = 2.0 * np.pi * frequency
    num, den, _ = cont2discrete(([1.0 / height], [1.0, 2.0 * damping * w, w * w]), 1.0 / rate, method="zoh")
    num = np.asarray(num).reshape(-1)
    pitch = lfilter(num, den, -a_x)
    roll = lfilter(num, den, a_y)
    return np.column_stack([np.interp(t, grid, roll), np.interp(t, grid, pitch)])


def mast_poses(legs: list[Leg], times: ArrayLike, foot: ArrayLike, height: float, frequency: float,
               damping: float) -> NDArray[np.float64]:
    """The mast's true 6-DOF poses (T, 6) at ``times`` (T,): the base's pose along ``legs`` tilted by the mast's
    sway (:func:`mast_sway`) about its foot at ``foot`` (x, y) in the base frame. A sensor on the mast at
    extrinsic E has the pose ``mast_pose @ E``; a rigid mast (``frequency`` 0) gives the base's poses."""
    t = np.asarray(times, dtype=float).reshape(-1)
    return matrix_to_pose(mast_matrices(legs, t, foot, mast_sway(legs, t, foot, height, frequency, damping)))


def mast_matrices(legs: list[Leg], times: ArrayLike, foot: ArrayLike, sway: ArrayLike | None) -> NDArray[np.float64]:
    """(T, 4, 4) poses of the base along ``legs`` at ``times`` (T,), tilted by ``sway`` (T, 2) roll and pitch
    about the mast's foot at ``foot`` (x, y) in the base frame (None: not tilted)."""
    t = np.asarray(times, dtype=float).reshape(-1)
    base = sample_legs(legs, t)
    b6 = np.zeros((len(t), 6))
    b6[:, :2], b6[:, 5] = base[:, :2], base[:, 2]
    B = pose_to_matrix(b6)
    if sway is None:
        return B
    tilt = np.zeros((len(t), 6))
    tilt[:, 3:5] = np.asarray(sway, dtype=float).reshape(len(t), 2)
    S = pose_to_matrix(tilt)
    f = np.array([float(foot[0]), float(foot[1]), 0.0])
    S[:, :3, 3] = f - S[:, :3, :3] @ f
    return B @ S
