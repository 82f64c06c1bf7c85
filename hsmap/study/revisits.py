"""A check of 6-DOF trajectories that needs no reference: sweeps far apart in time but near in space (revisits)
registered directly to each other by an independent GICP (small_gicp, the ``peers`` extra), and each trajectory's
relative poses between them compared with those registrations.

A reference trajectory that drifts (a lidar-inertial estimate, as BALM's) and an estimate that does not disagree
with each other by the drift; the direct registrations side with the one whose sweeps line up. Each pair is
registered from the relative pose of every trajectory given; a pair whose registrations from those starts end
further apart than ``settle`` is unsettled (the registration, not the trajectories, decides nothing there) and left
out of the agreement.

- :func:`revisit_pairs`: the pairs, from one trajectory's positions;
- :func:`register_revisits`: their direct registrations (:class:`Revisits`);
- :func:`revisit_agreement`: how far a trajectory's relative poses lie from them;
- :func:`corrected_reference`: a reference with its drift between the revisits taken out (a pose graph of its
  sweep-to-sweep motions and the registrations).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..geometry import matrix_to_pose, pose_to_matrix
from ..trajectory import Trajectory

__all__ = ["revisit_pairs", "register_revisits", "revisit_agreement", "corrected_reference", "Revisits",
           "as_matrices", "STEP_SIGMA", "REVISIT_SIGMA"]

#: (m, rad): the sigmas of a reference's sweep-to-sweep motion in :func:`corrected_reference` (a lidar-inertial
#: estimate's steps line adjacent sweeps up to millimetres; its error is the drift they add up to)
STEP_SIGMA = (0.005, float(np.deg2rad(0.05)))
#: (m, rad): the sigmas of a settled revisit registration (settled: within 1 cm from every start)
REVISIT_SIGMA = (0.01, float(np.deg2rad(0.1)))


def as_matrices(trajectory: Trajectory | NDArray[np.float64]) -> NDArray[np.float64]:
    """A 6-DOF trajectory's poses as 4x4 matrices (N, 4, 4), from a :class:`Trajectory`, pose vectors (N, 6) or
    matrices (N, 4, 4)."""
    if isinstance(trajectory, Trajectory):
        return pose_to_matrix(trajectory.as_6dof().poses).reshape(-1, 4, 4)
    M = np.asarray(trajectory, dtype=float)
    if M.ndim == 2 and M.shape[1] == 6:
        return pose_to_matrix(M).reshape(-1, 4, 4)
    if M.ndim != 3 or M.shape[1:] != (4, 4):
        raise InputError(f"expected a 6-DOF trajectory, (N, 6) pose vectors or (N, 4, 4) poses, got shape "
                         f"{M.shape}")
    return M


def revisit_pairs(trajectory: Trajectory | NDArray[np.float64], *, min_gap: int = 30, max_distance: float = 8.0,
                  every: int = 6) -> NDArray[np.intp]:
    """Pairs (P, 2) of sweeps ``i < j`` (every ``every``-th sweep) at least ``min_gap`` sweeps apart whose positions
    lie at most ``max_distance`` apart, in ``trajectory``."""
    if min_gap < 1 or every < 1 or not max_distance > 0:
        raise InputError(f"revisit pairs: min_gap and every must be >= 1 and max_distance > 0, got {min_gap}, "
                         f"{every}, {max_distance}")
    pos = as_matrices(trajectory)[:, :3, 3]
    idx = np.arange(0, len(pos), every)
    i, j = np.meshgrid(idx, idx, indexing="ij")
    keep = (j - i >= min_gap) & (np.linalg.norm(pos[i] - pos[j], axis=-1) <= max_distance)
    return np.column_stack([i[keep], j[keep]]).astype(np.intp)


def _angle_deg(R: NDArray[np.float64]) -> NDArray[np.float64]:
    """The rotation angles (deg) of rotation matrices (..., 3, 3)."""
    c = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def _apart(A: NDArray[np.float64], B: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Translation (m) and rotation angle (deg) of ``A^-1 B`` for 4x4 poses (..., 4, 4)."""
    D = np.linalg.inv(A) @ B
    return np.linalg.norm(D[..., :3, 3], axis=-1), _angle_deg(D[..., :3, :3])


@dataclass
class Revisits:
    """Direct registrations of revisit pairs.

    Attributes
    ----------
    pairs : ndarray of shape (P, 2)
    relative : ndarray of shape (P, 4, 4)
        Sweep ``j``'s pose in sweep ``i``'s frame, as registered from the first start.
    spread : ndarray of shape (P,)
        The largest distance (m) between the registrations from the different starts.
    settled : ndarray of shape (P,)
        Whether the registrations from every start ended within ``settle`` of each other and converged.
    """

    pairs: NDArray[np.intp]
    relative: NDArray[np.float64]
    spread: NDArray[np.float64]
    settled: NDArray[np.bool_]


def register_revisits(load: Callable[[int], NDArray[np.float64]], pairs: NDArray[np.intp],
                      starts: Sequence[Trajectory | NDArray[np.float64]], *, voxel: float = 0.1,
                      max_correspondence: float = 0.5, iterations: int = 100, settle: float = 0.01) -> Revisits:
    """Register sweep ``j`` to sweep ``i`` for each pair with small_gicp's GICP (clouds thinned to ``voxel``,
    correspondences within ``max_correspondence``), once from each trajectory's relative pose in ``starts``.

    ``load(i)`` gives sweep ``i``'s points (M, 3) in the sensor's frame.

    Raises
    ------
    InputError
        No start, or a start without pose for a pair's sweep.
    ModuleNotFoundError
        small_gicp is not installed (the ``peers`` extra).
    """
    import small_gicp

    if not len(starts):
        raise InputError("register_revisits: expected at least one trajectory to start from")
    P = np.asarray(pairs, dtype=np.intp).reshape(-1, 2)
    mats = [as_matrices(s) for s in starts]
    if len(P) and (P.min() < 0 or P.max() >= min(len(m) for m in mats)):
        raise InputError(f"register_revisits: pairs name sweeps {int(P.min())}..{int(P.max())}; expected 0..{min(map(len, mats)) - 1} (the "
                         f"poses of every start)")
    clouds: dict[int, tuple] = {}

    def cloud(k: int):
        if k not in clouds:
            pts = np.asarray(load(k), dtype=np.float64)
            clouds[k] = small_gicp.preprocess_points(pts[np.isfinite(pts).all(axis=1)], voxel)
        return clouds[k]

    rel = np.zeros((len(P), 4, 4))
    spread = np.zeros(len(P))
    settled = np.zeros(len(P), dtype=bool)
    for n, (i, j) in enumerate(P):
        (ti, tree), (tj, _) = cloud(int(i)), cloud(int(j))
        ends, converged = [], True
        for M in mats:
            r = small_gicp.align(ti, tj, tree, np.linalg.inv(M[i]) @ M[j], registration_type="GICP",
                                 max_correspondence_distance=max_correspondence, max_iterations=iterations)
            ends.append(np.asarray(r.T_target_source))
            converged &= bool(r.converged)
        E = np.asarray(ends)
        rel[n] = E[0]
        spread[n] = max(float(_apart(E[a], E[b])[0]) for a in range(len(E)) for b in range(len(E)))
        settled[n] = converged and spread[n] <= settle
    return Revisits(P, rel, spread, settled)


def revisit_agreement(trajectory: Trajectory | NDArray[np.float64], revisits: Revisits) -> dict:
    """How far ``trajectory``'s relative poses between the settled revisit pairs lie from their direct
    registrations: translation (m) mean, median and maximum, rotation angle (deg) mean and maximum (JSON-ready)."""
    M = as_matrices(trajectory)
    P = revisits.pairs[revisits.settled]
    out: dict = {"pairs": int(len(P)), "unsettled": int((~revisits.settled).sum())}
    if not len(P):
        return out
    own = np.linalg.inv(M[P[:, 0]]) @ M[P[:, 1]]
    t, r = _apart(own, revisits.relative[revisits.settled])
    out.update(translation_mean_m=float(t.mean()), translation_median_m=float(np.median(t)),
               translation_max_m=float(t.max()), rotation_mean_deg=float(r.mean()), rotation_max_deg=float(r.max()))
    return out


def corrected_reference(reference: Trajectory, revisits: Revisits, *, step_sigma: tuple[float, float] = STEP_SIGMA,
                        revisit_sigma: tuple[float, float] = REVISIT_SIGMA) -> Trajectory:
    """``reference`` with its drift between the settled revisit pairs taken out: a pose graph of its
    sweep-to-sweep motions (sigmas ``step_sigma``) and the revisits' direct registrations (``revisit_sigma``),
    optimised from the reference with its first sweep held. An independent check of a reference, not a survey:
    it is as good as the registrations and their sigmas."""
    from ..slam.posegraph import EdgeKind, PoseGraph

    M = as_matrices(reference)
    traj = reference.as_6dof()

    def info(sig: tuple[float, float]) -> NDArray[np.float64]:
        return np.diag([1.0 / sig[0] ** 2] * 3 + [1.0 / sig[1] ** 2] * 3)

    graph = PoseGraph(6)
    for p in traj.poses:
        graph.add_node(p)
    steps = matrix_to_pose(np.linalg.inv(M[:-1]) @ M[1:]).reshape(-1, 6)
    for k, z in enumerate(steps):
        graph.add_edge(k, k + 1, z, info(step_sigma), EdgeKind.ODOMETRY)
    for (i, j), rel in zip(revisits.pairs[revisits.settled], revisits.relative[revisits.settled], strict=True):
        graph.add_edge(int(i), int(j), matrix_to_pose(rel[None])[0], info(revisit_sigma), EdgeKind.LOOP)
    out = graph.optimize(fixed=0)
    if out.status != "ok":
        raise InputError(f"the corrected reference's pose graph failed: {out.message}")
    return Trajectory(traj.stamps.copy(), np.asarray(graph.poses).copy())
