"""A 2D SLAM trajectory smoothed with the wheel odometry, by noise levels the run itself measures.

Every frame's SLAM pose carries a little noise of its own (the registration against the map, the point noise of
its scan): one frame to the next it jitters by millimetres to centimetres, more on sparse long-range scans. Wheel
odometry has the opposite character: from one frame to the next it is precise, and its error builds up over the
way. A fixed-interval smoother takes from each what it measures best: it solves for the poses that stay close to
the SLAM poses (white noise ``S``, per axis in the robot frame) and whose one-frame motions stay close to the
odometry's (``Q``), a sparse linear least-squares problem over every frame (Rauch, Tung and Striebel 1965 give the
same estimate recursively). Where the SLAM poses carry no noise of their own the smoother leaves them as they are:
on logs whose scans are dense and close, the odometry adds nothing.

The noise levels are measured in the run, not configured: the *three-cornered hat* (Gray and Allan 1974, for
clocks) compares three sources of each frame's motion, the SLAM trajectory, the odometry and the scan matched
against the previous frame's scan alone, no map. With independent errors, the variances of the three pairwise
differences give each source's own variance:
``var(a) = (var(a - b) + var(a - c) - var(b - c)) / 2``. Robust variances (the MAD as a Gaussian's sigma) keep a
wheel slip or a frame that jumped from setting them. The SLAM trajectory and the scan match share their scans,
so the hat gives the SLAM poses less noise than they have: it errs towards leaving them alone.

Outliers, told apart by the three sources (:func:`vote`). An odometry step slipped where its motion differs from
both the SLAM motion and the scan match beyond the chi-square 99.9 % quantile of their noise: it is left out (the
chain is cut there) and the wheel does not bend the trajectory (odometry messages that lag the scans and then catch
up give many such steps). A SLAM pose that no scan match into or out of it confirms, and that the smoothed estimate
puts beyond the same quantile of its white noise (one frame, or a few, that left the track where the odometry and
its neighbours say otherwise), is down-weighted (``gate / m^2``) in the passes after the first, plain least-squares
one (iteratively reweighted least squares), and put back where they say. A scan match that its scene does not
constrain (a featureless corridor) says nothing and confirms nothing.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numpy.typing import ArrayLike, NDArray

from ..errors import ShapeError
from ..geometry import compose, invert, pose_to_matrix, relative, wrap_angle
from ..registration.information import adjoint
from .posegraph import chi2_quantile

__all__ = ["SmoothingResult", "three_cornered_hat", "identify_noise", "vote", "smooth_with_odometry"]

#: a MAD-based variance of N Gaussian samples has a standard error of about this / sqrt(N) of itself (twice the
#: 1.1654 / sqrt(N) of the MAD's sigma: the median's asymptotic efficiency)
_MEDIAN_SE = 2.33
#: the whitened weight that holds an axis without white noise where the SLAM pose has it
_HELD = 1e6
#: fewer frames with all three motions than this: too few to measure the noise levels
MIN_FRAMES = 50
#: a white noise below this (m, m, rad) counts as none: the SLAM poses are kept as they are along that axis
_NEGLIGIBLE = np.array([1e-4, 1e-4, 1e-6])


@dataclass
class SmoothingResult:
    """What :func:`smooth_with_odometry` did.

    Attributes
    ----------
    poses : ndarray of shape (N, 3)
        The smoothed poses (the input poses where nothing was done).
    status : str
        ``ok``, or why nothing was done (``skipped: ...``).
    white_sigma, odometry_sigma, scan_sigma : ndarray of shape (3,)
        The three-cornered hat's one-frame noise (x, y in metres, yaw in radians, robot frame) of the SLAM poses
        (their white part, which the smoother takes out), of the odometry's one-frame motion (reported, not used)
        and of the scan-to-scan match.
    odometry_model_sigma : ndarray of shape (3,)
        The median of the odometry sigmas the smoother weighted the steps by.
    frames : int
        Frames whose three motions were compared.
    moved_median_m, moved_max_m, moved_max_rad : float
        How far the smoother moved the poses.
    odometry_slipped : int
        Odometry steps left out as slipped (:func:`vote`).
    poses_down_weighted : int
        SLAM poses down-weighted as outliers in the last pass.
    iterations : int
        Passes made.
    """

    poses: NDArray[np.float64]
    status: str = "ok"
    white_sigma: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    odometry_sigma: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    scan_sigma: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    odometry_model_sigma: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    frames: int = 0
    moved_median_m: float = 0.0
    moved_max_m: float = 0.0
    moved_max_rad: float = 0.0
    odometry_slipped: int = 0
    poses_down_weighted: int = 0
    iterations: int = 0

    def as_dict(self) -> dict:
        """JSON-ready (the metrics' ``smoothing``): sigmas as (x m, y m, yaw deg)."""
        def sig(v: NDArray[np.float64]) -> list[float]:
            return [float(v[0]), float(v[1]), float(np.rad2deg(v[2]))]

        return {"status": self.status, "frames": self.frames, "white_sigma": sig(self.white_sigma),
                "odometry_sigma": sig(self.odometry_sigma), "scan_sigma": sig(self.scan_sigma),
                "odometry_model_sigma": sig(self.odometry_model_sigma),
                "moved_median_m": self.moved_median_m, "moved_max_m": self.moved_max_m,
                "moved_max_deg": float(np.rad2deg(self.moved_max_rad)),
                "odometry_slipped": self.odometry_slipped,
                "poses_down_weighted": self.poses_down_weighted, "iterations": self.iterations}


def _difference(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Motion ``b`` in the frame of motion ``a`` (rows of (x, y, yaw)), the angle wrapped."""
    d = relative(a, b)
    d[..., 2] = wrap_angle(d[..., 2])
    return d


def _robust_variance(x: NDArray[np.float64]) -> NDArray[np.float64]:
    """Per column: the square of the MAD as a Gaussian's sigma."""
    mad = np.median(np.abs(x - np.median(x, axis=0)), axis=0)
    return (1.4826 * mad) ** 2


def three_cornered_hat(a: ArrayLike, b: ArrayLike, c: ArrayLike) -> tuple[NDArray[np.float64], ...]:
    """Each of three sources' own variance, per axis, from the robust variances of their pairwise differences.

    ``a``, ``b``, ``c``: arrays of shape (N, 3), three measurements of the same N motions (x, y, yaw). Returns the
    three variance vectors (3,), each less two standard errors of the estimate and clipped at 0: only the part the
    data tell from the estimate's own noise (a robust variance of N samples errs by some ``2.33 / sqrt(N)`` of
    itself, the median's efficiency; a negative difference says the errors are correlated, or that source's own
    noise is too small to tell).
    """
    a, b, c = (np.asarray(v, dtype=float) for v in (a, b, c))
    if not (a.shape == b.shape == c.shape) or a.ndim != 2 or a.shape[1] != 3:
        raise ShapeError(f"the three motions must be arrays of one shape (N, 3), got {a.shape}, {b.shape}, {c.shape}")
    ab, ac, bc = (_robust_variance(_difference(x, y)) for x, y in ((a, b), (a, c), (b, c)))
    se = 0.5 * np.sqrt(ab**2 + ac**2 + bc**2) * _MEDIAN_SE / np.sqrt(max(len(a), 1))
    return tuple(np.clip(v - 2 * se, 0.0, None) for v in ((ab + ac - bc) / 2, (ab + bc - ac) / 2, (ac + bc - ab) / 2))


def identify_noise(poses: NDArray[np.float64], odometry_motion: NDArray[np.float64],
                   scan_motion: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                                               NDArray[np.float64], int]:
    """The one-frame noise variances (3,) of the SLAM poses' white part, of the odometry and of the scan matches.

    ``poses``: (N, 3); ``odometry_motion`` and ``scan_motion``: (N, 3), row k the motion from frame k-1 to frame k
    that the odometry and frame k's scan matched against frame k-1's give (NaN where none; row 0 is unused). Frames
    whose odometry or scan motion is missing are left out. A white noise of variance ``w`` on each pose adds ``2 w``
    to a one-frame motion. Returns ``(white, odometry, scan, frames compared)``.
    """
    slam = relative(poses[:-1], poses[1:])
    odo = odometry_motion[1:]
    scan = scan_motion[1:]
    ok = np.isfinite(slam).all(1) & np.isfinite(odo).all(1) & np.isfinite(scan).all(1)
    n = int(ok.sum())
    if n < MIN_FRAMES:
        return np.zeros(3), np.zeros(3), np.zeros(3), n
    v_slam, v_odo, v_scan = three_cornered_hat(slam[ok], odo[ok], scan[ok])
    return v_slam / 2, v_odo, v_scan, n


def _down_weight(m2: NDArray[np.float64], gate: float) -> NDArray[np.float64]:
    """1 within the chi-square gate, ``gate / m^2`` beyond it (as :func:`hsmap.slam.odometry.slip_weight`)."""
    return np.where(m2 > gate, gate / np.maximum(m2, 1e-300), 1.0)


def _mahalanobis2(a: NDArray[np.float64], b: NDArray[np.float64], var: NDArray[np.float64]) -> NDArray[np.float64]:
    d = _difference(a, b)
    return (d * d / np.maximum(var, 1e-300)).sum(1)


def vote(slam: NDArray[np.float64], odometry: NDArray[np.float64], scan: NDArray[np.float64],
         white: NDArray[np.float64], odometry_var: NDArray[np.float64], scan_var: NDArray[np.float64]
         ) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """Which of N steps the three sources outvote: ``(slipped, scan_agrees)``, two boolean arrays (N,).

    ``slam``, ``odometry``, ``scan``: (N, 3), each step's motion as the three sources have it (the scan's NaN where
    it said nothing); ``white`` (3,), ``odometry_var`` (N, 3) or (3,), ``scan_var`` (3,): their variances. Two
    motions agree within the chi-square 99.9 % quantile of their summed variances (the SLAM motion's: ``2
    white``). ``slipped``: the odometry agrees with neither the SLAM motion nor a scan match that said something
    (the wheels against the two laser sources; where those two disagree with each other too, the wheels are the
    furthest off: odometry messages that lag the scans and catch up lie there).
    ``scan_agrees``: the scan match agrees with the SLAM motion.
    """
    gate = chi2_quantile(0.999, 3)
    m_so = _mahalanobis2(odometry, slam, 2 * white + odometry_var)
    m_oi = _mahalanobis2(odometry, scan, odometry_var + scan_var)
    m_si = _mahalanobis2(slam, scan, 2 * white + scan_var)
    scan_agrees = m_si <= gate  # NaN compares False: a scan that said nothing agrees with no one
    return (m_so > gate) & (m_oi > gate), scan_agrees  # NaN: not slipped


@dataclass
class _Chain:
    """What every pass of :func:`smooth_with_odometry` solves against: the SLAM poses and their weights on the
    free axes, the odometry steps (``k1``: each step's later frame) with their weights, and the poses that a scan
    match confirms."""

    P: NDArray[np.float64]
    free: NDArray[np.bool_]
    w_pose: NDArray[np.float64]
    k1: NDArray[np.int64]
    z_odo: NDArray[np.float64]
    w_odo: NDArray[np.float64]
    a_odo: NDArray[np.float64]
    confirmed: NDArray[np.bool_]
    gate_pose: float


def _chain(P: NDArray[np.float64], odo: NDArray[np.float64], Os: NDArray[np.float64], M: NDArray[np.float64],
           white: NDArray[np.float64], v_scan: NDArray[np.float64]) -> tuple[_Chain, NDArray[np.bool_]]:
    """The chain of poses and odometry steps, and which steps slipped (:func:`vote`)."""
    free = np.sqrt(white) > _NEGLIGIBLE
    # the white noise's inverse sigmas; an axis without any is held (its pose component stays)
    w_pose = 1.0 / np.sqrt(np.maximum(white, _NEGLIGIBLE**2))
    n = len(P)
    k1 = np.flatnonzero(np.isfinite(odo[1:]).all(1) & np.isfinite(Os[1:]).all(1) & (Os[1:] > 0).all(1)) + 1
    z_odo = odo[k1]  # each step's motion, k1 its later frame
    w_odo = 1.0 / Os[k1]
    gate_pose = chi2_quantile(0.999, int(free.sum()))
    slipped, scan_agrees = vote(relative(P[k1 - 1], P[k1]), z_odo, M[k1], white, Os[k1] ** 2, v_scan)
    a_odo = np.where(slipped, 0.0, 1.0)  # a slipped step cuts the chain
    # a pose that the scan match into it or out of it confirms is never overruled by the odometry
    confirmed = np.zeros(n, dtype=bool)
    confirmed[k1[scan_agrees]] = True
    confirmed[k1[scan_agrees] - 1] = True
    return _Chain(P, free, w_pose, k1, z_odo, w_odo, a_odo, confirmed, gate_pose), slipped


def _correction(ch: _Chain, cur: NDArray[np.float64], a_pose: NDArray[np.float64],
                r_pose: NDArray[np.float64]) -> NDArray[np.float64]:
    """One pass's correction of every pose (N, 3), in its current frame: the whitened, weighted least-squares
    system linearised at ``cur`` (``r_pose``: its whitened offsets from the SLAM poses), solved."""
    n, k1, free, w_pose, w_odo = len(ch.P), ch.k1, ch.free, ch.w_pose, ch.w_odo
    frames = np.arange(n)
    z = relative(cur[k1 - 1], cur[k1])
    e = _difference(ch.z_odo, z) * w_odo  # the estimate's motion against the odometry's, whitened
    blocks: list[tuple] = []  # (rows, columns, values, right-hand sides) of the whitened, weighted system
    row = 0
    # a pose's correction d_k (in its current frame): r_pose + d_k on the free axes; 0 on the held ones
    for c in range(3):
        if free[c]:
            s = np.sqrt(a_pose)
            blocks.append((row + frames, 3 * frames + c, w_pose[c] * s, -r_pose[:, int(free[:c].sum())] * s))
        else:
            blocks.append((row + frames, 3 * frames + c, np.full(n, _HELD), np.zeros(n)))
        row += n
    # a step's residual: log(o^-1 z) + d_k - Ad(z^-1) d_{k-1}
    A = adjoint(pose_to_matrix(invert(z)))  # Ad(z^-1), one a step
    s = np.sqrt(ch.a_odo)
    for c in range(3):
        r = row + np.arange(len(k1))
        blocks.append((r, 3 * k1 + c, w_odo[:, c] * s, -e[:, c] * s))
        for cc in range(3):
            blocks.append((r, 3 * (k1 - 1) + cc, -w_odo[:, c] * A[:, c, cc] * s, None))
        row += len(k1)
    rows = np.concatenate([b[0] for b in blocks])
    J = sp.csr_matrix((np.concatenate([b[2] for b in blocks]), (rows, np.concatenate([b[1] for b in blocks]))),
                      shape=(row, 3 * n))
    rhs = np.zeros(row)
    for b in blocks:
        if b[3] is not None:
            rhs[b[0]] = b[3]
    return spla.spsolve((J.T @ J).tocsc(), J.T @ rhs).reshape(n, 3)


def smooth_with_odometry(poses: ArrayLike, odometry_motion: ArrayLike, odometry_sigma: ArrayLike,
                         scan_motion: ArrayLike, *, iterations: int = 50) -> SmoothingResult:
    """Smooth 2D SLAM poses with the wheel odometry: the poses' white noise as :func:`identify_noise` measures it,
    the odometry's by its own model.

    Parameters
    ----------
    poses : array_like of shape (N, 3)
        The SLAM trajectory (x, y, yaw), one pose a frame, in time order.
    odometry_motion : array_like of shape (N, 3)
        Row k: the wheel odometry's motion from frame k-1 to frame k, in frame k-1's robot frame (NaN where there
        is none: the chain is cut there; row 0 is unused).
    odometry_sigma : array_like of shape (N, 3)
        Row k: the sigmas (x, y, yaw) of that motion. They must not claim the odometry better than it is: an
        odometry taken for exact holds the trajectory to its drift. The model a SLAM run learns
        (:meth:`hsmap.slam.OdometryModel.sigma`) errs on the loose side (it holds some of the registrations' noise),
        which is the safe side; the three-cornered hat's own estimate of the odometry (reported in the result) is a
        small difference of large variances where the odometry is the best of the three sources, and can be 0.
    scan_motion : array_like of shape (N, 3)
        Row k: frame k's scan matched against frame k-1's, the motion between them (NaN where none).
    iterations : int
        Passes at most: least squares, then reweighted passes (each a linearisation at the current estimate and one
        sparse solve) until no pose moves by more than 0.1 mm and 1e-6 rad. A stretch of frames that left the track
        is brought back over several passes.

    Returns
    -------
    SmoothingResult
    """
    P = np.asarray(poses, dtype=float)
    odo = np.asarray(odometry_motion, dtype=float)
    Os = np.asarray(odometry_sigma, dtype=float)
    M = np.asarray(scan_motion, dtype=float)
    if P.ndim != 2 or P.shape[1] != 3 or odo.shape != P.shape or Os.shape != P.shape or M.shape != P.shape:
        raise ShapeError(f"poses, odometry_motion, odometry_sigma and scan_motion must be arrays of one shape "
                         f"(N, 3), got {P.shape}, {odo.shape}, {Os.shape}, {M.shape}")
    white, v_odo, v_scan, n_compared = identify_noise(P, odo, M)
    result = SmoothingResult(P.copy(), white_sigma=np.sqrt(white), odometry_sigma=np.sqrt(v_odo),
                             scan_sigma=np.sqrt(v_scan), frames=n_compared)
    if n_compared < MIN_FRAMES:
        result.status = f"skipped: {n_compared} frames with odometry and a scan match, fewer than {MIN_FRAMES}"
        return result
    if not (np.sqrt(white) > _NEGLIGIBLE).any():
        return result  # the SLAM poses carry no white noise of their own that the data can tell: status ok
    ch, slipped = _chain(P, odo, Os, M, white, v_scan)
    result.odometry_model_sigma = np.median(Os[ch.k1], axis=0) if len(ch.k1) else np.zeros(3)
    cur = P.copy()
    a_pose = np.ones(len(P))
    for it in range(max(1, iterations)):
        r_pose = _difference(P, cur)[:, ch.free] * ch.w_pose[ch.free]  # the offset from the SLAM pose, whitened
        if it > 0:  # least squares first, then the poses that the current estimate puts far from theirs
            a_pose = np.where(ch.confirmed, 1.0, _down_weight((r_pose**2).sum(1), ch.gate_pose))
        d = _correction(ch, cur, a_pose, r_pose)
        if not np.all(np.isfinite(d)):
            result.status = "skipped: the smoothing system could not be solved"
            return result
        cur = compose(cur, d)
        cur[:, 2] = P[:, 2] + wrap_angle(cur[:, 2] - P[:, 2])
        result.iterations = it + 1
        if it > 0 and np.abs(d[:, :2]).max() < 1e-4 and np.abs(d[:, 2]).max() < 1e-6:
            break
    moved = _difference(P, cur)
    result.poses = cur
    result.moved_median_m = float(np.median(np.hypot(moved[:, 0], moved[:, 1])))
    result.moved_max_m = float(np.hypot(moved[:, 0], moved[:, 1]).max())
    result.moved_max_rad = float(np.abs(moved[:, 2]).max())
    result.odometry_slipped = int(slipped.sum())
    result.poses_down_weighted = int((a_pose < 1).sum())
    return result
