"""Motion compensation of rolling 3D sweeps: every point moved to its cloud's reference time.

A spinning LiDAR takes its cloud over a sweep (about 0.1 s) while the robot moves; each point carries its own
time (:attr:`hsmap.datasets.frames.Frame.point_times`, seconds relative to the frame's stamp). With the robot
base's motion over the sweep, ``M(t) = B(stamp)^-1 B(stamp + t)``, a point ``p`` measured in the sensor frame at
time ``t`` lies at ``E^-1 M(t) E p`` in the sensor frame at the stamp (``E``: the sensor's pose in the base
frame). The motion comes from, in this order: a prior trajectory (a 2D run's poses) interpolated at the points'
times, the wheel odometry's increment into the frame as a constant velocity, or the constant velocity of the
last two tracked poses; with none of them the cloud is left as it is.

A motion interpolated between poses a frame apart misses what changed within the sweep (a turn starting, the
mast swaying). :func:`refine_sweep` estimates that remainder from the cloud itself: the pose at the stamp and a
constant velocity over the sweep, fitted together to the map (point-to-plane).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from .datasets.frames import Frame
from .errors import ShapeError
from .geometry import interpolate_poses, invert_matrix, matrix_to_pose, pose_to_matrix, relative

__all__ = ["TIME_QUANTUM", "PRIOR_MAX_GAP", "VELOCITY_SIGMA", "constant_velocity_motion", "trajectory_motion",
           "deskew_points", "sweep_motion", "deskew_frame", "SweepRefinement", "refine_sweep"]

#: Seconds: point times are grouped to this step before the motion is evaluated (one motion per group).
TIME_QUANTUM = 1e-5
#: Seconds: a prior trajectory gives a sweep's motion where its poses lie at most this far from every point time
#: (a 2D run's poses come one per frame, several sweep lengths apart).
PRIOR_MAX_GAP = 1.0
#: (m/s, rad/s): the prior's sigma of the velocity :func:`refine_sweep` adds to a sweep's motion, in translation
#: and in rotation: a ground robot's speed and turn rate are of this order, so only a direction the cloud does not
#: constrain is held by it.
VELOCITY_SIGMA = (1.0, 1.0)


def constant_velocity_motion(step: ArrayLike, dt: float, times: ArrayLike) -> NDArray[np.float64]:
    """Base motions (U, dof) from the reference pose to ``times`` (U,) seconds after it, at the constant
    velocity that makes ``step`` (dof,) (a relative pose, (x, y, yaw) or (x, y, z, roll, pitch, yaw)) in ``dt``
    seconds (along the SE(2)/SE(3) geodesic, :func:`hsmap.geometry.interpolate_poses`)."""
    step = np.asarray(step, dtype=float)
    t = np.asarray(times, dtype=float).reshape(-1)
    if not (np.isfinite(dt) and dt > 0):
        raise ShapeError(f"dt must be a positive number of seconds, got {dt}")
    if len(step) == 3:
        zero = np.zeros((len(t), 3))
        return interpolate_poses(zero, np.broadcast_to(step, zero.shape), t / dt)
    # SE(3): exp(s log(step)), the screw motion (a planar step moves along the same arc as in SE(2))
    T = pose_to_matrix(step)
    w = Rotation.from_matrix(T[:3, :3]).as_rotvec()
    u = np.linalg.solve(_se3_v(w), T[:3, 3])
    s = t / dt
    out = np.zeros((len(s), 4, 4))
    out[:, :3, :3] = Rotation.from_rotvec(s[:, None] * w).as_matrix()
    out[:, :3, 3] = np.einsum("nij,j->ni", np.stack([_se3_v(k * w) for k in s]), u) * s[:, None]
    out[:, 3, 3] = 1.0
    return matrix_to_pose(out)


def _se3_v(w: NDArray[np.float64]) -> NDArray[np.float64]:
    """The SE(3) exponential's V (3, 3) for the rotation vector ``w`` (3,)."""
    th = float(np.linalg.norm(w))
    K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if th < 1e-8:
        return np.eye(3) + K / 2.0
    return np.eye(3) + (1 - np.cos(th)) / th**2 * K + (th - np.sin(th)) / th**3 * K @ K


def trajectory_motion(trajectory, stamp: float, times: ArrayLike, max_dt: float) -> NDArray[np.float64] | None:
    """Base motions (U, dof) from the trajectory's pose at ``stamp`` to its poses at ``stamp + times`` (U,).

    The three poses of the trajectory nearest to the sweep's middle, each at most ``max_dt`` seconds from every
    time of the sweep, are joined by a quadratic in time (per coordinate, in the frame of the first of them,
    angles unwrapped): a motion that speeds up or slows down within the sweep keeps its shape. With two such
    poses the motion is interpolated along the geodesic between them (constant velocity). None where the
    trajectory has fewer than two.
    """
    t = np.asarray(times, dtype=float).reshape(-1)
    st = np.asarray(trajectory.stamps, dtype=float)
    poses = np.asarray(trajectory.poses, dtype=float)
    if len(t) == 0:
        return np.zeros((0, poses.shape[1]))
    lo, hi = float(stamp) + min(0.0, t.min()), float(stamp) + max(0.0, t.max())
    near = np.flatnonzero((st >= hi - max_dt) & (st <= lo + max_dt))
    if len(near) < 2:
        return None
    near = near[np.argsort(np.abs(st[near] - (lo + hi) / 2), kind="stable")[:3]]
    near = np.sort(near)
    rel = relative(np.broadcast_to(poses[near[0]], poses[near].shape), poses[near])
    ang = slice(3, 6) if rel.shape[1] == 6 else slice(2, 3)
    rel[:, ang] = np.unwrap(rel[:, ang], axis=0)
    tq = np.concatenate([[float(stamp)], float(stamp) + t]) - st[near[0]]
    ts = st[near] - st[near[0]]
    if len(near) == 2:
        at = interpolate_poses(np.broadcast_to(rel[0], (len(tq), rel.shape[1])),
                               np.broadcast_to(rel[1], (len(tq), rel.shape[1])), tq / ts[1])
    else:
        at = np.column_stack([np.polyval(np.polyfit(ts, rel[:, c], 2), tq) for c in range(rel.shape[1])])
    return relative(np.broadcast_to(at[0], at[1:].shape), at[1:])


def deskew_points(points: ArrayLike, times: ArrayLike, motions: ArrayLike, extrinsic: ArrayLike,
                  inverse: ArrayLike | None = None) -> NDArray[np.float64]:
    """Points (N, 3) of a sweep, in the sensor frame, moved to the sweep's reference time.

    Parameters
    ----------
    points : array_like of shape (N, 3)
        The sensor-frame points as measured.
    times : array_like of shape (U,)
        The distinct point times (seconds from the reference); with ``inverse`` None, one per point (U = N).
    motions : array_like of shape (U, 3) or (U, 6)
        The robot base's pose at each time relative to its pose at the reference time.
    extrinsic : array_like of shape (6,)
        The sensor's pose (x, y, z, roll, pitch, yaw) in the base frame.
    inverse : array_like of int of shape (N,), optional
        Index into ``times``/``motions`` of each point.

    Returns
    -------
    ndarray of shape (N, 3)
        ``E^-1 M(t) E p`` for each point.
    """
    p = np.asarray(points, dtype=float)
    m = np.asarray(motions, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ShapeError(f"points must be (N, 3), got {p.shape}")
    if m.ndim != 2 or m.shape[1] not in (3, 6) or len(m) != len(np.asarray(times).reshape(-1)):
        raise ShapeError(f"motions must be (U, 3) or (U, 6), one per time, got {m.shape}")
    if m.shape[1] == 3:
        m6 = np.zeros((len(m), 6))
        m6[:, :2], m6[:, 5] = m[:, :2], m[:, 2]
        m = m6
    idx = np.arange(len(p)) if inverse is None else np.asarray(inverse, dtype=np.intp)
    if len(idx) != len(p):
        raise ShapeError(f"inverse must have one index per point ({len(p)}), got {len(idx)}")
    E = pose_to_matrix(np.asarray(extrinsic, dtype=float))
    S = invert_matrix(E) @ pose_to_matrix(m) @ E  # (U, 4, 4) sensor motion
    return np.einsum("nij,nj->ni", S[idx, :3, :3], p) + S[idx, :3, 3]


def sweep_motion(frame: Frame, times: NDArray[np.float64], *, prior=None, max_dt: float = PRIOR_MAX_GAP,
                 previous_stamps: Sequence[float] = (), previous_poses: Sequence[NDArray[np.float64]] = (),
                 previous_odometry: NDArray[np.float64] | None = None
                 ) -> tuple[NDArray[np.float64] | None, str]:
    """The robot base's motion over a frame's sweep at ``times`` (U,) seconds from its stamp, and its source.

    Parameters
    ----------
    frame : Frame
    times : ndarray of shape (U,)
    prior : Trajectory, optional
        Poses (x, y, yaw) of a previous run, interpolated at the times (within ``max_dt`` of its poses).
    previous_stamps, previous_poses : sequence
        The stamps and poses (dof,) of the frames tracked before this one (the last two are used).
    previous_odometry : ndarray of shape (3,), optional
        The wheel odometry at ``previous_stamps[-1]``.

    Returns
    -------
    motions : ndarray of shape (U, 3) or (U, 6), or None
        None where nothing gives the motion.
    source : str
        ``"prior"``, ``"odometry"``, ``"constant_velocity"`` or ``"none"``.
    """
    if prior is not None and len(prior):
        m = trajectory_motion(prior, frame.stamp, times, max_dt)
        if m is not None:
            return m, "prior"
    if previous_stamps:
        dt = float(frame.stamp) - float(previous_stamps[-1])
        if frame.odometry is not None and previous_odometry is not None and dt > 0:
            return constant_velocity_motion(relative(previous_odometry, frame.odometry), dt, times), "odometry"
        if len(previous_poses) >= 2 and len(previous_stamps) >= 2:
            dt = float(previous_stamps[-1]) - float(previous_stamps[-2])
            if dt > 0:
                step = relative(previous_poses[-2], previous_poses[-1])
                return constant_velocity_motion(step, dt, times), "constant_velocity"
    return None, "none"


def deskew_frame(frame: Frame, **motion_sources) -> tuple[Frame, str]:
    """The frame with its cloud moved to its stamp (:func:`deskew_points`) and its point times cleared, and
    where the motion came from (:func:`sweep_motion`, whose keyword arguments ``motion_sources`` are).

    A frame without point times or cloud is returned as it is (source ``"static"``); one whose motion nothing
    gives keeps its points, its times cleared (source ``"none"``).
    """
    if frame.point_times is None or frame.cloud3d is None:
        return frame, "static"
    pts = np.asarray(frame.cloud3d, dtype=float)
    t = np.asarray(frame.point_times, dtype=float).reshape(-1)
    if len(t) != len(pts):
        raise ShapeError(f"frame {frame.index}: {len(t)} point times for {len(pts)} points")
    q = np.rint(t / TIME_QUANTUM)
    uq, inverse = np.unique(q, return_inverse=True)
    motions, source = sweep_motion(frame, uq * TIME_QUANTUM, **motion_sources)
    if motions is not None:
        pts = deskew_points(pts, uq * TIME_QUANTUM, motions, frame.extrinsic3d, inverse.reshape(-1))
    return dataclasses.replace(frame, cloud3d=pts, point_times=None), source


@dataclasses.dataclass
class SweepRefinement:
    """What :func:`refine_sweep` found.

    Attributes
    ----------
    pose : ndarray of shape (6,)
        The pose at the stamp.
    velocity : ndarray of shape (3,)
        The velocity added to the sweep's motion, (vx, vy, wz) in the base frame at the stamp (m/s, rad/s).
    points : ndarray of shape (N, 3)
        The points in the base frame at the stamp, moved by that velocity.
    cost_before, cost_after : float
        Mean truncated point-to-plane residual over the threshold (an unmatched point counts 1) at the start and
        at the end.
    iterations : int
    """

    pose: NDArray[np.float64]
    velocity: NDArray[np.float64]
    points: NDArray[np.float64]
    cost_before: float
    cost_after: float
    iterations: int

    @property
    def improved(self) -> bool:
        """Whether the refined pose and motion align the cloud better than the starting ones."""
        return self.cost_after < self.cost_before


def _cross_rows(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.column_stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                            a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]])


def _sweep_cost(target, moved: NDArray[np.float64], threshold: float, hint=None) -> tuple:
    d, idx = target.nearest(moved, threshold, hint)
    ok = np.isfinite(d)
    r = np.einsum("ij,ij->i", target.normals[idx[ok]], moved[ok] - target.points[idx[ok]])
    cost = float((np.minimum(np.abs(r), threshold).sum() + threshold * (len(moved) - ok.sum()))
                 / (threshold * max(len(moved), 1)))
    return cost, ok, idx, r


def refine_sweep(points: ArrayLike, times: ArrayLike, target, pose: ArrayLike, *, threshold: float,
                 robust_kernel: float = 0.0, iterations: int = 3, tolerance: float = 1e-5,
                 velocity_sigma: tuple[float, float] = VELOCITY_SIGMA) -> SweepRefinement:
    """Refine a deskewed sweep's pose together with the planar motion over the sweep that its deskewing missed.

    Each point ``p`` (base frame at the stamp, measured ``t`` seconds after it) moves to ``p + t (w x p + v)``
    for a velocity v = (vx, vy, 0), w = (0, 0, wz) constant over the sweep: what the motion interpolated between
    poses a frame apart misses is the base's motion in its plane (a turn or a stop starting within the frame).
    Gauss-Newton on the point-to-plane residuals against ``target`` (correspondences within ``threshold``,
    Geman-McClure weights of scale ``robust_kernel``, weighted by their spread) finds the pose and the velocity
    together, the velocity held by a zero-mean prior of ``velocity_sigma``.

    Parameters
    ----------
    points : array_like of shape (N, 3)
        The deskewed points in the base frame.
    times : array_like of shape (N,)
        Each point's time in seconds from the stamp.
    target : hsmap.registration.icp.RegistrationTarget
        The map (3D, with normals).
    pose : array_like of shape (6,)
        The registered pose at the stamp.

    Returns
    -------
    SweepRefinement
    """
    P = np.array(points, dtype=float)
    tau = np.asarray(times, dtype=float).reshape(-1)
    if P.ndim != 2 or P.shape[1] != 3 or len(tau) != len(P):
        raise ShapeError(f"points must be (N, 3) with one time each, got {P.shape} and {tau.shape}")
    T = pose_to_matrix(np.asarray(pose, dtype=float))
    prior = np.zeros(9)
    prior[6:8] = 1.0 / velocity_sigma[0] ** 2
    prior[8] = 1.0 / velocity_sigma[1] ** 2
    vel = np.zeros(3)
    cost0, ok, idx, r = _sweep_cost(target, P @ T[:3, :3].T + T[:3, 3], threshold)
    cost, it = cost0, 0
    while it < iterations:
        it += 1
        if ok.sum() < 9:
            break
        R, t = T[:3, :3], T[:3, 3]
        moved = P[ok] @ R.T + t
        n = target.normals[idx[ok]]
        tk = tau[ok]
        # d(residual)/d(pose) (a perturbation on the left, in the map frame) and d/d(vx, vy, wz) (base frame)
        J = np.column_stack([n, _cross_rows(moved, n), tk * (n @ R[:, 0]), tk * (n @ R[:, 1]),
                             tk * np.einsum("ij,j->i", _cross_rows(moved - t, n), R[:, 2])])
        w = np.ones(len(r))
        if robust_kernel > 0:
            k2 = robust_kernel * robust_kernel
            w = k2 * k2 / (k2 + r * r) ** 2
        # the residuals' spread (weighted, at least 1 mm) puts the data and the velocity's prior in one unit
        s2 = max(float((w * r * r).sum() / w.sum()), 1e-6)
        Jw = J * (w / s2)[:, None]
        A = Jw.T @ J + np.diag(prior)
        g = Jw.T @ r
        g[6:] += prior[6:] * vel
        delta = -np.linalg.solve(A + 1e-9 * np.eye(9), g)
        dv = delta[6:]
        x, y = P[:, 0].copy(), P[:, 1]
        P[:, 0] += tau * (dv[0] - dv[2] * y)
        P[:, 1] += tau * (dv[1] + dv[2] * x)
        vel += dv
        dT = np.eye(4)
        dT[:3, :3] = Rotation.from_rotvec(delta[3:6]).as_matrix()
        dT[:3, 3] = delta[:3]
        T = dT @ T
        cost, ok, idx, r = _sweep_cost(target, P @ T[:3, :3].T + T[:3, 3], threshold, idx)
        if np.abs(delta).max() < tolerance:
            break
    return SweepRefinement(matrix_to_pose(T), vel, P, cost0, cost, it)
