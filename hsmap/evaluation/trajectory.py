"""Trajectory metrics: per-DOF pose errors (the paper's Table 1), ATE and RPE (evo's definitions) and the
Freiburg relations metric (Kümmerle et al. 2009).

Every function takes :class:`hsmap.trajectory.Trajectory` objects (3-DOF ``(x, y, yaw)`` or 6-DOF
``(x, y, z, roll, pitch, yaw)``) and returns a small result object with an ``as_dict()`` for JSON. Poses are
handled as SE(3) matrices internally (a 3-DOF trajectory is the planar special case), so 2D and 3D share one
code path.

Definitions (P = estimate, Q = reference, both 4x4 poses of the robot in their world frames):

- **Association.** Each estimated stamp is paired with the nearest reference stamp; a pair more than
  ``max_dt`` seconds apart is an :class:`~hsmap.errors.InputError` (estimated stamps must all exist in the
  reference; reference stamps without an estimate are ignored).
- **Per-DOF errors** (:func:`pose_errors`). Each trajectory is taken relative to its own first pose
  (``P_0⁻¹ P_k`` and ``Q_0⁻¹ Q_k``), no alignment; the error of each degree of freedom is the difference of
  the pose-vector components, estimate minus reference, angles wrapped to [-pi, pi). Reported: the maximum
  absolute error per DOF over the route, and the final pose's error (per DOF, as a translation distance and
  as a rotation angle).
- **ATE** (:func:`ate`, evo's APE). ``E_k = Q_k⁻¹ P_k`` after an optional :class:`Alignment` of the estimate
  onto the reference (Umeyama on the positions: SE(2) about z on x, y; SE(3); Sim(3)); the error is
  ``|t(E_k)|`` (m) or ``|angle(E_k)|`` (degrees) per :class:`PoseRelation`. Statistics as in evo: RMSE, mean,
  median, population standard deviation, min, max, SSE.
- **RPE** (:func:`rpe`, evo's RPE). ``E_ij = (Q_i⁻¹ Q_j)⁻¹ (P_i⁻¹ P_j)`` over pairs ``(i, j)`` ``delta``
  frames apart, or ``delta`` metres of path apart (:class:`DeltaUnit`; the estimate's path unless
  ``pairs_from_reference``, evo's default), with evo's pair selection (consecutive pairs unless ``all_pairs``).
  Checked against evo 1.38 on a random 6-DOF trajectory: APE and RPE statistics agree to 1e-12.
- **Relations** (:func:`relations_error`). For each relation (t_i, t_j, R): the estimated poses at t_i and
  t_j (the pose at that stamp when one is within ``max_dt``, else linearly interpolated: translation lerp,
  rotation slerp), ``E = (P_i⁻¹ P_j) R⁻¹``; translational error ``|t(E)|`` (m), rotational ``|angle(E)|``.
  Reported as mean and sample standard deviation, absolute and squared (m², deg²), as Kümmerle et al.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..datasets.relations import Relations
from ..errors import EmptyInputError, InputError, ShapeError
from ..geometry import invert_matrix, matrix_to_pose, pose_to_matrix, wrap_angle
from ..trajectory import Trajectory, nearest_index
from .trajectory_results import (
    _ANGULAR,
    DEFAULT_MAX_DT,
    DOF_NAMES,
    Alignment,
    DeltaUnit,
    ErrorResult,
    PoseErrors,
    PoseRelation,
    RelationsResult,
    Statistics,
)

__all__ = [
    "DEFAULT_MAX_DT",
    "Alignment",
    "PoseRelation",
    "DeltaUnit",
    "Statistics",
    "ErrorResult",
    "PoseErrors",
    "RelationsResult",
    "associate",
    "umeyama",
    "align",
    "pose_errors",
    "ate",
    "rpe",
    "relations_error",
    "relation_errors",
    "evaluate_trajectory",
]


# -- helpers -------------------------------------------------------------------------------------------
def _angle(R: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation angle (rad) of (..., 3, 3) matrices, accurate near 0 (atan2 of sine and cosine parts)."""
    s = 0.5 * np.linalg.norm(
        np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1), axis=-1
    )
    c = 0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0)
    return np.arctan2(s, c)


def _matrices(traj: Trajectory) -> NDArray[np.float64]:
    return pose_to_matrix(traj.as_6dof().poses)


def _check(traj: Trajectory, name: str) -> None:
    if not isinstance(traj, Trajectory):
        raise InputError(f"{name} must be a hsmap.trajectory.Trajectory, got {type(traj).__name__}")
    if len(traj) == 0:
        raise EmptyInputError(f"{name} has no poses")
    if not (np.all(np.isfinite(traj.stamps)) and np.all(np.isfinite(traj.poses))):
        raise InputError(f"{name} has NaN or infinite stamps or poses")


def associate(
    est: Trajectory, ref: Trajectory, *, max_dt: float = DEFAULT_MAX_DT
) -> tuple[Trajectory, Trajectory]:
    """Pair each estimated pose with the reference pose at the same stamp (within ``max_dt`` s).

    Returns
    -------
    est, ref : Trajectory
        The estimate (in its own order) and the matching reference poses, same length.

    Raises
    ------
    InputError
        An estimated stamp has no reference stamp within ``max_dt`` (the message says how many and gives
        both stamp ranges), or two estimated poses match the same reference pose.
    """
    _check(est, "estimate")
    _check(ref, "reference")
    idx = nearest_index(ref.stamps, est.stamps, max_dt)
    bad = idx < 0
    if bad.any():
        first = est.stamps[np.argmax(bad)]
        raise InputError(
            f"{int(bad.sum())} of {len(est)} estimated stamps have no reference stamp within {max_dt} s "
            f"(first: {first:.6f}); estimate spans [{est.stamps.min():.6f}, {est.stamps.max():.6f}], "
            f"reference spans [{ref.stamps.min():.6f}, {ref.stamps.max():.6f}]"
        )
    if len(np.unique(idx)) != len(idx):
        raise InputError("several estimated poses match the same reference stamp: the estimate has duplicate stamps")
    return est, Trajectory(ref.stamps[idx], ref.poses[idx])


def umeyama(
    x: NDArray[np.float64], y: NDArray[np.float64], *, with_scale: bool = False
) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """Least-squares similarity ``y ≈ s R x + t`` (Umeyama 1991), as evo's ``umeyama_alignment``.

    Parameters
    ----------
    x, y : ndarray of shape (N, d)
        Corresponding points (estimate, reference).

    Returns
    -------
    R : ndarray of shape (d, d)
    t : ndarray of shape (d,)
    s : float
        1 unless ``with_scale``.
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    if x.shape != y.shape or x.ndim != 2:
        raise InputError(f"umeyama needs two (N, d) arrays of the same shape, got {x.shape} and {y.shape}")
    n, d = x.shape
    if n < d:
        raise InputError(f"umeyama alignment in {d}D needs at least {d} poses, got {n}")
    mx, my = x.mean(0), y.mean(0)
    xc, yc = x - mx, y - my
    sigma_x = np.sum(xc**2) / n
    cov = yc.T @ xc / n
    u, dvals, vt = np.linalg.svd(cov)
    S = np.eye(d)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        S[-1, -1] = -1.0
    R = u @ S @ vt
    if with_scale:
        if sigma_x <= 0:
            raise InputError("Sim(3) alignment needs an estimate whose positions are not all equal")
        s = float(np.trace(np.diag(dvals) @ S) / sigma_x)
    else:
        s = 1.0
    t = my - s * R @ mx
    return R, t, s


def align(est: Trajectory, ref: Trajectory, alignment: Alignment) -> tuple[NDArray[np.float64], NDArray, float]:
    """Alignment of associated trajectories: returns (aligned estimate poses (N, 4, 4), T (4, 4), scale).

    The transform ``T`` (and ``scale``) maps the estimate's world frame onto the reference's:
    ``P' = T P`` with the translation scaled by ``scale`` first.
    """
    alignment = Alignment(alignment)
    P, Q = _matrices(est), _matrices(ref)
    T, s = np.eye(4), 1.0
    if alignment is Alignment.ORIGIN:
        T = Q[0] @ invert_matrix(P[0])
    elif alignment is Alignment.SE2:
        R2, t2, _ = umeyama(P[:, :2, 3], Q[:, :2, 3])
        T[:2, :2], T[:2, 3] = R2, t2
    elif alignment in (Alignment.SE3, Alignment.SIM3):
        R3, t3, s = umeyama(P[:, :3, 3], Q[:, :3, 3], with_scale=alignment is Alignment.SIM3)
        T[:3, :3], T[:3, 3] = R3, t3
    Ps = P.copy()
    Ps[:, :3, 3] *= s
    return T @ Ps, T, s


def _error_of(E: NDArray[np.float64], relation: PoseRelation) -> tuple[NDArray[np.float64], str]:
    if relation is PoseRelation.TRANSLATION:
        return np.linalg.norm(E[:, :3, 3], axis=1), "m"
    return np.degrees(_angle(E[:, :3, :3])), "deg"


# -- metrics ---------------------------------------------------------------------------------------------
def pose_errors(est: Trajectory, ref: Trajectory, *, max_dt: float = DEFAULT_MAX_DT) -> PoseErrors:
    """Per-DOF errors relative to the first pose, no alignment (the paper's Table 1).

    3-DOF when either trajectory is 3-DOF (x, y, yaw), else 6-DOF.
    """
    est, ref = associate(est, ref, max_dt=max_dt)
    dof = 3 if 3 in (est.dof, ref.dof) else 6
    P, Q = _matrices(est), _matrices(ref)
    Pr = invert_matrix(P[0]) @ P
    Qr = invert_matrix(Q[0]) @ Q
    pv, qv = matrix_to_pose(Pr), matrix_to_pose(Qr)
    if dof == 3:
        pv, qv = pv[:, [0, 1, 5]], qv[:, [0, 1, 5]]
    err = pv - qv
    ang = np.array([n in _ANGULAR for n in DOF_NAMES[dof]])
    err[:, ang] = wrap_angle(err[:, ang])
    Ef = invert_matrix(Qr[-1]) @ Pr[-1]
    return PoseErrors(
        names=DOF_NAMES[dof],
        stamps=est.stamps.copy(),
        errors=err,
        max_abs=np.abs(err).max(axis=0),
        final=np.abs(err[-1]),
        final_translation=float(np.linalg.norm(Pr[-1, :3, 3] - Qr[-1, :3, 3])),
        final_rotation=float(_angle(Ef[:3, :3])),
    )


def ate(
    est: Trajectory,
    ref: Trajectory,
    *,
    alignment: Alignment = Alignment.NONE,
    relation: PoseRelation = PoseRelation.TRANSLATION,
    max_dt: float = DEFAULT_MAX_DT,
) -> ErrorResult:
    """Absolute trajectory error (evo's APE) after an optional alignment."""
    alignment, relation = Alignment(alignment), PoseRelation(relation)
    est, ref = associate(est, ref, max_dt=max_dt)
    P, T, s = align(est, ref, alignment)
    E = invert_matrix(_matrices(ref)) @ P
    e, unit = _error_of(E, relation)
    return ErrorResult(
        name=f"ATE {relation.value} ({alignment.value})",
        unit=unit,
        errors=e,
        stamps=est.stamps.copy(),
        statistics=Statistics.of(e),
        alignment=T,
        scale=s,
    )


def _pairs(Q: NDArray[np.float64], delta: float, unit: DeltaUnit, all_pairs: bool, tol: float) -> NDArray[np.intp]:
    n = len(Q)
    if unit is DeltaUnit.FRAMES:
        k = int(delta)
        if k < 1 or k != delta:
            raise InputError(f"RPE delta in frames must be a positive integer, got {delta}")
        if all_pairs:
            i = np.arange(max(n - k, 0))
            return np.column_stack([i, i + k])
        ids = np.arange(0, n, k)
        return np.column_stack([ids[:-1], ids[1:]])
    if not delta > 0:
        raise InputError(f"RPE delta in metres must be positive, got {delta}")
    steps = np.linalg.norm(np.diff(Q[:, :3, 3], axis=0), axis=1)
    dist = np.concatenate([[0.0], np.cumsum(steps)])
    if all_pairs:
        pairs = []
        for i in range(n - 1):
            rest = dist[i + 1 :] - dist[i]
            j = int(np.argmin(np.abs(rest - delta)))
            if abs(rest[j] - delta) <= tol:
                pairs.append((i, i + 1 + j))
        return np.asarray(pairs, dtype=np.intp).reshape(-1, 2)
    # evo: the first pose, then each pose where the path since the last mark reaches delta
    ids, base = [0], 0.0
    while True:
        j = int(np.searchsorted(dist, base + delta, side="left"))
        if j >= n:
            break
        ids.append(j)
        base = dist[j]
    ids = np.asarray(ids, dtype=np.intp)
    return np.column_stack([ids[:-1], ids[1:]]) if len(ids) > 1 else np.zeros((0, 2), np.intp)


def rpe(
    est: Trajectory,
    ref: Trajectory,
    *,
    delta: float = 1,
    unit: DeltaUnit = DeltaUnit.FRAMES,
    relation: PoseRelation = PoseRelation.TRANSLATION,
    all_pairs: bool = False,
    rel_delta_tol: float = 0.1,
    pairs_from_reference: bool = False,
    max_dt: float = DEFAULT_MAX_DT,
) -> ErrorResult:
    """Relative pose error (evo's RPE) over pose pairs ``delta`` frames or metres of path apart.

    As in evo (1.38), the pairs are chosen on the estimate's path unless ``pairs_from_reference``; with
    ``unit=METERS`` and ``all_pairs``, a pair is kept when its path length is within
    ``rel_delta_tol * delta`` of ``delta``.
    """
    unit, relation = DeltaUnit(unit), PoseRelation(relation)
    est, ref = associate(est, ref, max_dt=max_dt)
    P, Q = _matrices(est), _matrices(ref)
    on = Q if pairs_from_reference else P
    ij = _pairs(on, delta, unit, all_pairs, rel_delta_tol * delta)
    if len(ij) == 0:
        raise EmptyInputError(
            f"no pose pairs {delta:g} {unit.value} apart in {'a reference' if pairs_from_reference else 'an estimate'} "
            f"of {len(on)} poses ({float(np.linalg.norm(np.diff(on[:, :3, 3], axis=0), axis=1).sum()):.3f} m of path)"
        )
    i, j = ij[:, 0], ij[:, 1]
    dQ = invert_matrix(Q[i]) @ Q[j]
    dP = invert_matrix(P[i]) @ P[j]
    e, u = _error_of(invert_matrix(dQ) @ dP, relation)
    return ErrorResult(
        name=f"RPE {relation.value} (delta {delta:g} {unit.value}{', all pairs' if all_pairs else ''})",
        unit=u,
        errors=e,
        stamps=est.stamps[i],
        statistics=Statistics.of(e),
    )


def _interpolate(
    stamps: NDArray[np.float64], M: NDArray[np.float64], t: NDArray[np.float64], max_dt: float
) -> tuple[NDArray[np.float64], NDArray[np.bool_], NDArray[np.bool_]]:
    """Poses (K, 4, 4) at ``t`` from sorted ``stamps``; returns (poses, matched, interpolated)."""
    from scipy.spatial.transform import Rotation

    pick = nearest_index(stamps, t, max_dt)
    exact = pick >= 0
    inside = (t > stamps[0]) & (t < stamps[-1]) & ~exact
    out = np.full((len(t), 4, 4), np.nan)
    out[exact] = M[pick[exact]]
    if inside.any():
        tq = t[inside]
        j = np.searchsorted(stamps, tq, side="right")
        i = j - 1
        a = (tq - stamps[i]) / (stamps[j] - stamps[i])
        A, B = M[i], M[j]
        rel = Rotation.from_matrix(np.swapaxes(A[:, :3, :3], 1, 2) @ B[:, :3, :3]).as_rotvec()
        R = A[:, :3, :3] @ Rotation.from_rotvec(a[:, None] * rel).as_matrix()
        T = np.zeros((len(tq), 4, 4))
        T[:, :3, :3] = R
        T[:, :3, 3] = (1 - a)[:, None] * A[:, :3, 3] + a[:, None] * B[:, :3, 3]
        T[:, 3, 3] = 1.0
        out[inside] = T
    return out, exact | inside, inside


def relations_error(
    traj: Trajectory,
    relations: Relations,
    *,
    max_dt: float = DEFAULT_MAX_DT,
    skip_unmatched: bool = False,
) -> RelationsResult:
    """The Freiburg relations metric of an estimated trajectory (see the module docstring).

    Parameters
    ----------
    traj : Trajectory
        Estimated poses of the robot; any order (it is sorted by stamp), no duplicate stamps.
    relations : Relations
    max_dt : float
        A relation stamp within this many seconds of a trajectory stamp takes that pose; others inside
        the trajectory's time span are interpolated.
    skip_unmatched : bool
        Score only the relations whose both stamps lie within the trajectory's time span, instead of
        raising.

    Raises
    ------
    InputError
        Relations with a stamp outside the trajectory's time span (unless ``skip_unmatched``; the message
        says how many, and both stamp ranges), duplicate trajectory stamps, or no relation left to score.
    """
    _check(traj, "trajectory")
    if not isinstance(relations, Relations) or len(relations) == 0:
        raise EmptyInputError("relations must be a non-empty hsmap.datasets.relations.Relations")
    o = np.argsort(traj.stamps, kind="stable")
    ts = traj.stamps[o]
    M = _matrices(traj)[o]
    dup = np.diff(ts) <= 0
    if dup.any():
        k = int(np.argmax(dup))
        raise InputError(f"trajectory has {int(dup.sum())} duplicate stamps (first: {ts[k]:.6f})")
    Pi, ok_i, int_i = _interpolate(ts, M, relations.t_i, max_dt)
    Pj, ok_j, int_j = _interpolate(ts, M, relations.t_j, max_dt)
    used = ok_i & ok_j
    if not used.all() and not skip_unmatched or not used.any():
        bad_stamps = np.concatenate([relations.t_i[~ok_i], relations.t_j[~ok_j]])
        rel_all = np.concatenate([relations.t_i, relations.t_j])
        raise InputError(
            f"{int((~used).sum())} of {len(relations)} relations could not be matched to the trajectory: "
            f"{len(bad_stamps)} relation stamps lie outside its stamp range [{ts[0]:.6f}, {ts[-1]:.6f}] "
            f"(relations span [{rel_all.min():.6f}, {rel_all.max():.6f}])"
            + ("" if skip_unmatched or not used.any() else "; skip_unmatched=True (hsmap evaluate relations "
               "--skip-unmatched) scores the others")
        )
    R = pose_to_matrix(relations.poses[used])
    rel_est = invert_matrix(Pi[used]) @ Pj[used]
    translation, rotation = relation_errors(rel_est, R)
    return RelationsResult(
        translation=translation,
        rotation=rotation,
        used=used,
        n_interpolated=int(int_i[used].sum() + int_j[used].sum()),
        estimated=rel_est[:, :3, 3].copy(),
        reference=R[:, :3, 3].copy(),
    )


def relation_errors(estimated: ArrayLike, reference: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Translational (m) and rotational (rad) errors of estimated relative poses against reference ones, as the
    Freiburg relations metric takes them (Kümmerle et al. 2009): the translation and the rotation angle of
    ``estimated @ reference^-1``. Both are rigid homogeneous matrices of one shape, (..., 3, 3) in 2D or
    (..., 4, 4) in 3D (:func:`hsmap.geometry.pose_to_matrix` makes them from pose vectors)."""
    est, ref = np.asarray(estimated, dtype=float), np.asarray(reference, dtype=float)
    if est.shape != ref.shape or est.shape[-2:] not in ((3, 3), (4, 4)):
        raise ShapeError(f"estimated and reference must be homogeneous matrices of one shape (..., 3, 3) or "
                         f"(..., 4, 4), got {est.shape} and {ref.shape}")
    E = est @ invert_matrix(ref)
    d = E.shape[-1] - 1
    if d == 2:
        return np.linalg.norm(E[..., :2, 2], axis=-1), np.abs(np.arctan2(E[..., 1, 0], E[..., 0, 0]))
    return np.linalg.norm(E[..., :3, 3], axis=-1), _angle(E[..., :3, :3])


def evaluate_trajectory(est: Trajectory, ref: Trajectory, *, max_dt: float = DEFAULT_MAX_DT) -> dict:
    """Everything ``hsmap evaluate trajectory`` prints: per-DOF errors, ATE (none / SE(3)) and RPE.

    RPE per frame (delta 1) and per metre of reference path (delta 1 m, when the path is long enough).
    """
    out: dict = {"pose_errors": pose_errors(est, ref, max_dt=max_dt).as_dict(), "ate": {}, "rpe": {}}
    planar = 3 in (est.dof, ref.dof)
    for al in (Alignment.NONE, Alignment.SE2 if planar else Alignment.SE3):
        for rel in PoseRelation:
            r = ate(est, ref, alignment=al, relation=rel, max_dt=max_dt)
            out["ate"][f"{rel.value}/{al.value}"] = r.as_dict()
    for delta, unit in ((1, DeltaUnit.FRAMES), (1.0, DeltaUnit.METERS)):
        for rel in PoseRelation:
            try:
                r = rpe(est, ref, delta=delta, unit=unit, relation=rel, max_dt=max_dt)
            except EmptyInputError as exc:
                out["rpe"][f"{rel.value}/{delta:g}{unit.value[0]}"] = {"skipped": str(exc)}
                continue
            out["rpe"][f"{rel.value}/{delta:g}{unit.value[0]}"] = r.as_dict()
    return out
