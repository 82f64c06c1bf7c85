"""The local refinement after the harmony search (:func:`refine_icp`: point-to-plane or point-to-point ICP,
trimmed at a threshold) and a pose's alignment cost and information against a target."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..geometry import dof_of_dim, matrix_to_pose, pose_to_matrix, transform_points
from .config import Refinement
from .information import adjoint
from .neighbours import TrackedQuery
from .target import RegistrationTarget


def _trim_schedule(start: float, end: float) -> list[float]:
    """Correspondence distances halving from ``start`` down to ``end`` (multi-scale ICP)."""
    out = [end]
    while out[-1] * 2 < start:
        out.append(out[-1] * 2)
    return out[::-1]


def refine_icp(
    source: NDArray[np.float64],
    target: RegistrationTarget,
    pose: NDArray[np.float64],
    *,
    max_distance: float,
    start_distance: float | None = None,
    iterations: int = 30,
    method: Refinement | str = Refinement.POINT_TO_PLANE,
    tolerance: float = 1e-5,
    robust_kernel: float = 0.0,
    hint: NDArray[np.intp] | None = None,
) -> NDArray[np.float64]:
    """Local ICP refinement of ``pose`` (a pose vector), in 2D or 3D.

    Correspondences (nearest target points, from the target's KD-tree) farther apart than the current trimming
    distance are ignored; the trimming distance halves from ``start_distance`` (default ``max_distance``) down to
    ``max_distance``, ``iterations`` at most in all. Point-to-plane (point-to-line in 2D) takes Gauss-Newton steps
    on the target normals, weighted by a Geman-McClure kernel of scale ``robust_kernel`` (metres; 0: none);
    point-to-point takes the closed-form SVD (Kabsch) step. ``hint`` (N,): target rows near the source points at
    a pose close to ``pose`` (:meth:`RegistrationTarget.nearest`), which speed the first search.
    """
    from . import _kernels  # numba: compiled on first use

    dim = source.shape[1]
    schedule = _trim_schedule(start_distance or max_distance, max_distance)
    per_stage = max(1, iterations // len(schedule))
    T = pose_to_matrix(pose)
    try:
        method = Refinement(method)
    except ValueError:
        raise InputError(f"method must be one of {[r.value for r in Refinement]}, got {method!r}") from None
    normals = target.normals if method is Refinement.POINT_TO_PLANE else None
    field = target.nearest_field(schedule[0]) if normals is not None else None
    if field is not None:
        # correspondences from the field's nearest points (one look-up each, compiled); then a few iterations
        # with exact nearest neighbours at the final distance polish what the field's cells rounded
        src = np.ascontiguousarray(source, dtype=float)
        sched = np.asarray(schedule, dtype=float)
        if dim == 2:
            T = _kernels.refine_on_field_2d(src, T, field.nearest, field.origin, field.resolution, sched,
                                            per_stage, tolerance, robust_kernel)
        else:
            T = _kernels.refine_on_field_3d(src, T, field.nearest_index, field.nearest_points,
                                            field.nearest_normals, field.origin, field.resolution, sched,
                                            per_stage, tolerance, robust_kernel)
        # 2D: a few exact iterations polish what the 2-3 cm cells rounded; 3D (10 cm cells): the final stage
        # with exact correspondences until it converges, as without the field (three left the 6-DOF route's
        # roll and pitch errors at 0.095 / 0.062 deg, against 0.055 / 0.045 without the field)
        schedule, per_stage = schedule[-1:], (min(per_stage, 3) if dim == 2 else per_stage)
        grid = target.grid_for(schedule[0]) if dim == 2 else None
        if grid is not None:  # the exact iterations compiled whole
            T = grid.polish_2d(src, T, schedule[0], per_stage, tolerance, robust_kernel, normals, hint)
            return matrix_to_pose(T)
    grid = target.grid_for(max(schedule)) if normals is not None and dim == 3 else None
    if grid is not None:  # the exact iterations compiled whole
        src = np.ascontiguousarray(source, dtype=float)
        return matrix_to_pose(grid.icp_3d(src, T, np.asarray(schedule), per_stage, tolerance, robust_kernel,
                                          normals, hint))
    idx = hint  # the previous iteration's correspondences: the next search starts from them
    # where the KD-tree answers, a point is searched again only once it may have a new nearest neighbour
    tracked = TrackedQuery(target.tree, _kernels.CERTIFY_MARGIN) if target.grid_for(max(schedule)) is None else None
    for dist in schedule:
        for _ in range(per_stage):
            moved = transform_points(T, source)
            d, idx = tracked(moved, dist) if tracked is not None else target.nearest(moved, dist, idx)
            if normals is not None:
                dT, step, found = _kernels.point_to_plane_step(moved, d, idx, target.points, normals, robust_kernel)
                if found < 2 * dim:
                    break
            else:
                ok = np.isfinite(d)
                if ok.sum() < 2 * dim:
                    break
                p, q = moved[ok], target.points[idx[ok]]
                dT = np.eye(dim + 1)
                mp, mq = p.mean(0), q.mean(0)
                U, _, Vt = np.linalg.svd((p - mp).T @ (q - mq))
                S = np.eye(dim)
                S[-1, -1] = np.sign(np.linalg.det(Vt.T @ U.T))
                dT[:dim, :dim] = Vt.T @ S @ U.T
                dT[:dim, dim] = mq - dT[:dim, :dim] @ mp
                step = max(np.abs(dT[:dim, dim]).max(), np.abs(dT[:dim, :dim] - np.eye(dim)).max())
            T = dT @ T
            if step < tolerance:
                break
    return matrix_to_pose(T)


def _match(pose: NDArray[np.float64], source: NDArray[np.float64], target: RegistrationTarget,
           threshold: float, hint: NDArray[np.intp] | None = None) -> tuple:
    """Nearest target points of ``source`` moved by ``pose`` within ``threshold``: (T, moved, d, idx), d inf
    where none (one KD-tree query, shared by the cost, the information and the fitness at a pose; ``hint``: the
    rows at a pose nearby, :meth:`RegistrationTarget.nearest`)."""
    T = pose_to_matrix(pose)
    moved = transform_points(T, source)
    d, idx = target.nearest(moved, threshold, hint)
    return T, moved, d, idx


def _cost_of(match: tuple, target: RegistrationTarget, threshold: float, plane: bool) -> float:
    """:func:`_alignment_cost` from the correspondences ``match`` (:func:`_match`)."""
    from . import _kernels  # numba: compiled on first use

    _, moved, d, idx = match
    normals = target.normals if plane else target.points
    return float(_kernels.truncated_cost(moved, d, idx, target.points, normals, float(threshold), bool(plane)))


def _alignment_cost(pose: NDArray[np.float64], source: NDArray[np.float64], target: RegistrationTarget,
                    threshold: float, plane: bool) -> float:
    """Mean truncated residual / threshold: point-to-plane (point-to-line) distances of the correspondences within
    ``threshold``, or point distances; a point with no correspondence costs 1."""
    return _cost_of(_match(pose, source, target, threshold), target, threshold, plane)


def alignment_cost(source: NDArray[np.float64], target: RegistrationTarget, pose: NDArray[np.float64],
                   threshold: float, plane: bool = True) -> float:
    """Mean truncated residual of ``source`` moved by ``pose`` against ``target``, as a fraction of ``threshold``.

    Point-to-plane (point-to-line in 2D) distances of the nearest-neighbour correspondences within ``threshold``
    (``plane=True``) or point distances; a point with no correspondence costs 1. 0 is a perfect alignment.
    """
    return _alignment_cost(pose, source, target, threshold, plane)


def alignment_information(source: NDArray[np.float64], target: RegistrationTarget, pose: NDArray[np.float64],
                          threshold: float, robust_kernel: float = 0.0,
                          min_sigma: float = 1e-3) -> tuple[NDArray[np.float64], float, int]:
    """Information matrix of ``pose`` from the point-to-plane residuals of ``source`` against ``target``.

    Returns ``(information, sigma, n)``: the Gauss-Newton matrix J^T W J of the correspondences within
    ``threshold`` (robust weights of scale ``robust_kernel``), expressed for a perturbation in the source's own
    frame (``T @ exp(xi)``, xi = (translation, rotation)) and divided by the weighted residual variance sigma^2
    (at least ``min_sigma``^2); and the number n of correspondences. With too few correspondences the matrix is
    zero (nothing is known).
    """
    info, sigma, n, _ = _information_and_cost(source, target, pose, threshold, robust_kernel, min_sigma)
    return info, sigma, n


def _information_and_cost(source, target, pose, threshold, robust_kernel=0.0, min_sigma=1e-3, match=None):
    """:func:`alignment_information` and :func:`alignment_cost` (point-to-plane) from one correspondence search
    (``match``: :func:`_match`'s at ``pose``, when already made)."""
    from . import _kernels  # numba: compiled on first use

    dim = source.shape[1]
    dof = dof_of_dim(dim)
    T, moved, d, idx = match if match is not None else _match(pose, source, target, threshold)
    A, n, cost_sum, wr2, wsum = _kernels.plane_information_terms(moved, d, idx, target.points, target.normals,
                                                                  float(robust_kernel), float(threshold))
    if n < 2 * dim:
        return np.zeros((dof, dof)), float("nan"), n, 1.0 - n / max(len(source), 1)
    cost = float((cost_sum + threshold * (len(source) - n)) / (threshold * len(source)))
    sigma = max(float(np.sqrt(wr2 / wsum)), min_sigma)
    Ad = adjoint(T)
    return Ad.T @ (A / sigma**2) @ Ad, sigma, n, cost
