"""Pose graphs in 2D (SE(2), 3-DOF) and 3D (SE(3), 6-DOF), optimised with GTSAM.

Nodes are keyframe poses (pose vectors: (x, y, yaw) or (x, y, z, roll, pitch, yaw)); edges are relative-pose
measurements ``z_ij`` (the pose of node j in the frame of node i) with an information matrix for a small motion
``xi = (translation, rotation)`` of node j in its own frame: ``T_i^-1 T_j = Z_ij exp(xi)``. That is the body-frame
convention of :attr:`hsmap.registration.icp.RegistrationResult.information`, so a registration's information goes
into an edge as it is.

Edges are of five kinds: ``odometry`` (consecutive keyframes, from tracking), ``wheel`` (consecutive keyframes,
the wheel odometry's motion between them), ``loop`` (loop closures: these
take a robust Cauchy kernel, and :meth:`PoseGraph.optimize` switches off those whose residual stays beyond a
chi-square gate after optimisation, so that a false closure cannot bend the map), ``pair`` (scan-to-scan
registrations between two overlapping keyframes, Lu and Milios 1997; robust and gated as loops are, but all those
beyond the gate are switched off in one round: a pair starts from the graph's own relative pose and cannot bend the
map as a false loop can, and one round for all of them keeps the re-optimisations few) and
``prior`` (absolute poses, unary).

GTSAM (``gtsam`` on PyPI) is used for the optimisation: it is the maintained, widely used factor-graph library
with Python wheels, SE(2) and SE(3) between-factors, robust noise models and Levenberg-Marquardt; g2o's Python
bindings are not maintained on PyPI.
"""

from __future__ import annotations

import enum
import functools
import warnings
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import sparse
from scipy.sparse import csgraph
from scipy.special import gammaincinv

from ..errors import HsmapError, InputError, ShapeError
from ..geometry import euler_to_matrix, matrix_to_euler, relative, wrap_angle

__all__ = ["EdgeKind", "Edge", "PoseGraph", "OptimizationResult", "OptimizationError", "information_with_floor",
           "SOLVERS", "chi2_quantile"]

def chi2_quantile(probability: float, dof: int) -> float:
    """The ``probability`` quantile of chi-square with ``dof`` degrees of freedom (scipy.stats' ``chi2.ppf``,
    without importing scipy.stats)."""
    return float(2.0 * gammaincinv(dof / 2.0, probability))


#: The ways :meth:`PoseGraph.optimize` solves the graph.
SOLVERS = ("batch", "incremental")


class OptimizationError(HsmapError):
    """The pose graph could not be optimised (non-finite values, an indeterminate system)."""


class EdgeKind(enum.StrEnum):
    ODOMETRY = "odometry"  # tracking: a keyframe registered against the map, relative to the previous keyframe
    WHEEL = "wheel"  # the wheel odometry's motion between two consecutive keyframes
    LOOP = "loop"
    PAIR = "pair"
    PRIOR = "prior"

    @property
    def matched(self) -> bool:
        """A place matched by registration (loop or pair): under the robust kernel and the chi-square gate."""
        return self in (EdgeKind.LOOP, EdgeKind.PAIR)


@dataclass
class Edge:
    """One measurement: the pose of node ``j`` in the frame of node ``i`` (``i == j`` and kind prior: absolute)."""

    i: int
    j: int
    measurement: NDArray[np.float64]
    information: NDArray[np.float64]
    kind: EdgeKind
    active: bool = True
    robust: bool = True  # loop edges: under the Cauchy kernel (off: a corroborated closure that must pull fully)
    # the graph's array of every edge's flag and this edge's index in it, kept in step with ``active``
    _flags: list | None = field(default=None, repr=False, compare=False)
    _index: int = field(default=-1, repr=False, compare=False)

    def __setattr__(self, name: str, value) -> None:
        object.__setattr__(self, name, value)
        if name == "active" and self._flags is not None:
            self._flags[0][self._index] = bool(value)


@dataclass
class OptimizationResult:
    """What :meth:`PoseGraph.optimize` did."""

    status: str  # "ok" or "failed"
    iterations: int = 0
    error_before: float = float("nan")
    error_after: float = float("nan")
    rejected: list[int] = field(default_factory=list)  # indices of loop edges switched off
    message: str = ""
    rounds: int = 0  # Levenberg-Marquardt runs, one per pruning round
    iterations_total: int = 0  # their iterations


def information_with_floor(information: ArrayLike, sigma_translation: float, sigma_rotation: float
                           ) -> NDArray[np.float64]:
    """Information matrix whose covariance is at least ``diag(sigma_t^2, ..., sigma_r^2, ...)``.

    Adds the floor to the covariance (inf-safe): a registration's Gauss-Newton information treats every point as an
    independent measurement and is overconfident; the floor bounds it by the map's resolution.
    """
    info = np.asarray(information, dtype=float)
    ss = _floor_scales(info.shape[0], float(sigma_translation), float(sigma_rotation))
    # (I^-1 + F)^-1 = F^-1/2 (F^-1/2 I^-1 F^-1/2 + 1)^-1 F^-1/2, computed from I without inverting it
    M = info / ss  # F^1/2 I F^1/2
    w, V = np.linalg.eigh(0.5 * (M + M.T))
    w = np.clip(w, 0.0, None)
    inner = (V * (w / (1.0 + w))) @ V.T  # (F^1/2 I F^1/2)(1 + F^1/2 I F^1/2)^-1 = (F^-1/2 I^-1 F^-1/2 + 1)^-1
    return inner * ss


@functools.lru_cache(maxsize=16)
def _floor_scales(dof: int, sigma_translation: float, sigma_rotation: float) -> NDArray[np.float64]:
    """``outer(s, s)`` of ``s = F^-1/2``, the floor's scales (:func:`information_with_floor`), read-only."""
    dim = 2 if dof == 3 else 3
    floor = np.r_[np.full(dim, sigma_translation**2), np.full(dof - dim, sigma_rotation**2)]
    s = 1.0 / np.sqrt(floor)
    out = np.outer(s, s)
    out.flags.writeable = False
    return out


class PoseGraph:
    """A pose graph of 3-DOF or 6-DOF pose vectors.

    Parameters
    ----------
    dof : int
        3 (SE(2)) or 6 (SE(3)).
    loop_kernel : float
        Scale of the Cauchy kernel on loop edges, in whitened units (standard deviations).
    gate_probability : float
        A loop edge whose chi-square residual after optimisation exceeds this quantile (of the chi-square
        distribution with ``dof`` degrees of freedom) is switched off and the graph re-optimised.
    solver : {"batch", "incremental"}
        ``batch``: every :meth:`optimize` runs Levenberg-Marquardt on the whole graph. ``incremental``: GTSAM's
        iSAM2 keeps the graph factorised between calls and updates only what the new edges and nodes touch
        (Kaess et al. 2012); node poses must then change through :meth:`optimize` alone.
    """

    def __init__(self, dof: int, *, loop_kernel: float = 3.0, gate_probability: float = 0.9999,
                 solver: str = "batch") -> None:
        if dof not in (3, 6):
            raise ShapeError(f"pose graph dof must be 3 or 6, got {dof!r}")
        if solver not in SOLVERS:
            raise InputError(f"pose graph solver must be one of {', '.join(SOLVERS)}, got {solver!r}")
        self.solver = solver
        self._incremental = _Incremental()  # incremental: iSAM2 kept between calls
        self.dof = dof
        self.dim = 2 if dof == 3 else 3
        self.loop_kernel = float(loop_kernel)
        self.gate = chi2_quantile(gate_probability, dof)
        self._P = np.zeros((64, dof))
        self._n = 0
        self.edges: list[Edge] = []
        self._factors: list = []  # one gtsam factor per edge, built on first use
        # the edges as arrays (ends, kind, measurement, information; grown by doubling), for the distances and the
        # gate, which run on graphs of thousands of edges where reading each Edge's attributes cost more than the work
        self._ij = np.zeros((64, 2), np.int64)
        self._kind = np.zeros(64, "U8")
        self._Z = np.zeros((64, dof))
        self._info = np.zeros((64, dof, dof))
        self._act = [np.zeros(64, bool)]  # every edge's ``active`` (a list: edges keep it across growth)
        self._chi2 = np.zeros(64)

    # ------------------------------------------------------------------------------------------ building
    def __len__(self) -> int:
        return self._n

    @property
    def poses(self) -> NDArray[np.float64]:
        """Current node poses, (n, dof) (a view: index it, do not keep it across :meth:`add_node`)."""
        return self._P[: self._n]

    @poses.setter
    def poses(self, value: ArrayLike) -> None:
        P = np.asarray(value, dtype=float).reshape(-1, self.dof)
        if len(P) != self._n:
            raise ShapeError(f"the graph has {self._n} nodes, got {len(P)} poses")
        self._P[: self._n] = P

    def add_node(self, pose: ArrayLike) -> int:
        """Add a node at ``pose`` (its initial estimate); returns its index."""
        p = np.asarray(pose, dtype=float)
        if p.shape != (self.dof,) or not np.all(np.isfinite(p)):
            raise InputError(f"a node pose must be {self.dof} finite values, got {np.asarray(pose).tolist()}")
        if self._n == len(self._P):
            self._P = np.concatenate([self._P, np.zeros_like(self._P)])
        self._P[self._n] = p
        self._n += 1
        return self._n - 1

    def add_edge(self, i: int, j: int, measurement: ArrayLike, information: ArrayLike,
                 kind: EdgeKind | str = EdgeKind.ODOMETRY, *, robust: bool = True) -> int:
        """Add a measurement of node j's pose in node i's frame; returns the edge index."""
        kind = EdgeKind(kind)
        n = self._n
        if not (0 <= i < n and 0 <= j < n):
            raise InputError(f"edge ({i}, {j}) names a node that does not exist (the graph has {n})")
        if (i == j) != (kind == EdgeKind.PRIOR):
            raise InputError(f"edge ({i}, {j}) of kind {kind.value}: only priors (i == j) are unary")
        z = np.asarray(measurement, dtype=float).copy()
        info = np.asarray(information, dtype=float)
        if z.shape != (self.dof,) or info.shape != (self.dof, self.dof):
            raise ShapeError(f"edge ({i}, {j}): measurement must be ({self.dof},) and information "
                             f"({self.dof}, {self.dof}), got {z.shape} and {info.shape}")
        if not (np.all(np.isfinite(z)) and np.all(np.isfinite(info))):
            raise InputError(f"edge ({i}, {j}): measurement and information must be finite")
        k = len(self.edges)
        if k == len(self._ij):
            self._ij, self._kind, self._Z, self._info, self._act[0], self._chi2 = (
                np.concatenate([a, np.zeros_like(a)])
                for a in (self._ij, self._kind, self._Z, self._info, self._act[0], self._chi2))
        e = Edge(int(i), int(j), z, 0.5 * (info + info.T), kind, robust=bool(robust), _flags=self._act, _index=k)
        self._act[0][k] = True
        self._chi2[k] = np.nan
        self._ij[k] = e.i, e.j
        self._kind[k] = kind.value
        self._Z[k] = e.measurement
        self._info[k] = e.information
        self.edges.append(e)
        self._factors.append(None)
        return k

    def loop_edges(self, active_only: bool = True) -> list[Edge]:
        return [e for e in self.edges if e.kind == EdgeKind.LOOP and (e.active or not active_only)]

    # ------------------------------------------------------------------------------------------ distances
    def path_distances(self, source: int, *, rotation_weight: float = 1.0, limit: float = np.inf
                       ) -> NDArray[np.float64]:
        """Shortest-path length from node ``source`` to every node (inf where beyond ``limit``).

        An edge's length is the distance it spans plus ``rotation_weight`` metres per radian it turns, measured
        on the current estimates; an active loop edge has length 0 (its two ends are the same place, known to
        the registration's precision). The length bounds how uncertain the two ends' relative pose is.
        """
        n = self._n
        m = len(self.edges)
        keep = self._active() & (self._kind[:m] != EdgeKind.PRIOR.value)
        ei, ej = self._ij[:m][keep].T
        loop = self._kind[:m][keep] == EdgeKind.LOOP.value
        if len(ei) == 0:
            out = np.full(n, np.inf)
            out[source] = 0.0
            return out
        P = self.poses
        d = P[ej] - P[ei]
        turn = np.abs(wrap_angle(d[:, self.dim:]))
        # 2D: np.linalg.norm's and max's arithmetic, without their overhead on two columns and one
        length = (np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) if self.dim == 2
                  else np.linalg.norm(d[:, : self.dim], axis=1))
        length += rotation_weight * (turn[:, 0] if self.dim == 2 else turn.max(axis=1))
        length[loop] = 0.0
        # one entry per pair of nodes, the shortest edge's: a sparse matrix sums duplicate entries, and two places
        # tied by several edges (tracking and wheel odometry, a loop and a pair) are no further apart for it
        pair = np.minimum(ei, ej) * n + np.maximum(ei, ej)
        order = np.argsort(pair, kind="stable")
        pair = pair[order]
        first = np.flatnonzero(np.r_[True, pair[1:] != pair[:-1]])
        shortest = np.minimum.reduceat(length[order], first)
        G = sparse.csr_matrix((shortest + 1e-9, np.divmod(pair[first], n)), shape=(n, n))
        return csgraph.dijkstra(G, directed=False, indices=source, limit=limit)

    # ------------------------------------------------------------------------------------------ optimising
    def optimize(self, *, max_iterations: int = 50, prune_rounds: int = 3, fixed: int = 0) -> OptimizationResult:
        """Optimise all node poses (Levenberg-Marquardt), switching off matched edges that fail the gate.

        Each round switches off the worst loop edge beyond the gate (a false closure distorts the others'
        residuals, so one at a time) and every pair edge beyond it, then optimises again, up to ``prune_rounds``.

        Node ``fixed`` is held at its current pose (the gauge). On failure (non-finite result, an indeterminate
        system, a solver exception) the poses are left unchanged and the result's status is ``"failed"``.
        """
        if self._n < 2:
            return OptimizationResult("ok")
        import gtsam

        if self.solver == "incremental":
            return self._incremental.optimize(self, gtsam, max_iterations, prune_rounds, fixed)
        rejected: list[int] = []
        result = OptimizationResult("ok")
        rounds = iterations = 0
        for _ in range(max(1, prune_rounds)):
            try:
                graph, values = self._build(gtsam, fixed)
                params = gtsam.LevenbergMarquardtParams()
                params.setMaxIterations(max_iterations)
                params.setRelativeErrorTol(1e-6)
                params.setAbsoluteErrorTol(1e-9)
                opt = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
                before = graph.error(values)
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    out = opt.optimize()
                after = graph.error(out)
                poses = _from_gtsam(gtsam, self.dof, out, self._n)
            except RuntimeError as exc:  # gtsam raises RuntimeError (IndeterminantLinearSystem, ...)
                return OptimizationResult("failed", message=f"{type(exc).__name__}: {exc}".splitlines()[0],
                                          rounds=rounds + 1, iterations_total=iterations)
            rounds, iterations = rounds + 1, iterations + opt.iterations()
            if not (np.isfinite(after) and np.all(np.isfinite(poses))):
                return OptimizationResult("failed", message="the optimisation gave non-finite poses",
                                          rounds=rounds, iterations_total=iterations)
            result = OptimizationResult("ok", opt.iterations(), float(before), float(after), rejected,
                                        rounds=rounds, iterations_total=iterations)
            off = self._take(poses, fixed)
            if not off:
                break
            rejected.extend(off)
        result.rejected = rejected
        return result

    def _take(self, poses: NDArray[np.float64], fixed: int) -> list[int]:
        """Take a solver's ``poses`` (n, dof) as the graph's, node ``fixed`` kept exactly (its prior lets the
        solver move it by rounding noise), and switch off the edges the gate rejects there (returned)."""
        poses[fixed] = self._P[fixed]
        self._P[: self._n] = poses
        off = self._update_chi2() or []
        for k in off:
            self.edges[k].active = False
        return off

    def _active(self) -> NDArray[np.bool_]:
        return self._act[0][: len(self.edges)]

    @property
    def chi2(self) -> NDArray[np.float64]:
        """Every edge's whitened squared residual after the last optimisation (NaN before one), (m,)."""
        return self._chi2[: len(self.edges)].copy()

    def _update_chi2(self) -> list[int] | None:
        """Whitened residuals of every edge at the current poses; the edges to switch off (None: none).

        Those are the worst active loop edge beyond the gate and every active pair edge beyond it.
        """
        m = len(self.edges)
        if not m:
            return None
        kind = self._kind[:m]
        r = self._residuals(self._ij[:m, 0], self._ij[:m, 1], self._Z[:m], kind == EdgeKind.PRIOR.value)
        c2 = np.einsum("ei,eij,ej->e", r, self._info[:m], r)
        self._chi2[:m] = c2
        act = self._active()
        over = np.where((kind == EdgeKind.LOOP.value) & act & (c2 > self.gate), c2, -np.inf)
        worst = int(np.argmax(over))
        pairs = np.flatnonzero((kind == EdgeKind.PAIR.value) & act & (c2 > self.gate)).tolist()
        out = ([worst] if np.isfinite(over[worst]) else []) + pairs
        return out or None

    def _residuals(self, ei, ej, Z, prior) -> NDArray[np.float64]:
        P = self.poses
        actual = relative(P[ei], P[ej])
        if prior.any():
            actual[prior] = P[ei[prior]]
        err = relative(Z, actual)  # Z^-1 (T_i^-1 T_j), as pose vectors
        if self.dof == 6:
            from scipy.spatial.transform import Rotation

            R = euler_to_matrix(err[:, 3], err[:, 4], err[:, 5])
            return np.concatenate([err[:, :3], Rotation.from_matrix(R).as_rotvec()], axis=1)
        err[:, 2] = wrap_angle(err[:, 2])
        return err

    def residual(self, e: Edge) -> NDArray[np.float64]:
        """Residual (translation, rotation) of an edge at the current poses, in the measurement's frame."""
        return self._residuals(np.array([e.i]), np.array([e.j]), e.measurement[None],
                               np.array([e.kind == EdgeKind.PRIOR]))[0]

    # ------------------------------------------------------------------------------------------ gtsam glue
    def _factor(self, gtsam, k: int):
        f = self._factors[k]
        if f is None:
            e = self.edges[k]
            noise = _noise(gtsam, self.dof, e.information, e.kind.matched and e.robust, self.loop_kernel)
            z = _to_gtsam(gtsam, self.dof, e.measurement)
            if e.kind == EdgeKind.PRIOR:
                f = (gtsam.PriorFactorPose2 if self.dof == 3 else gtsam.PriorFactorPose3)(e.i, z, noise)
            else:
                f = (gtsam.BetweenFactorPose2 if self.dof == 3 else gtsam.BetweenFactorPose3)(e.i, e.j, z, noise)
            self._factors[k] = f
        return f

    def _build(self, gtsam, fixed: int):
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        for k in range(self._n):
            values.insert(k, _to_gtsam(gtsam, self.dof, self._P[k]))
        Prior = gtsam.PriorFactorPose2 if self.dof == 3 else gtsam.PriorFactorPose3
        tight = gtsam.noiseModel.Isotropic.Sigma(self.dof, 1e-6)
        graph.add(Prior(fixed, _to_gtsam(gtsam, self.dof, self._P[fixed]), tight))
        for k, e in enumerate(self.edges):
            if e.active:
                graph.add(self._factor(gtsam, k))
        return graph, values


#: iSAM2 relinearises a variable whose linear step exceeds this (its tangent's largest entry).
_RELINEARIZE = 1e-3


class _Incremental:
    """GTSAM's iSAM2 kept factorised between a pose graph's optimisations (Kaess et al. 2012): the solver, how many
    of the graph's nodes are in it, each edge's factor slot (-1 where it is not in) and the gauge node."""

    def __init__(self) -> None:
        self.isam = None
        self.nodes = 0
        self.slot: list[int] = []
        self.fixed = -1

    def optimize(self, pg: PoseGraph, gtsam, max_iterations: int, prune_rounds: int, fixed: int
                 ) -> OptimizationResult:
        """:meth:`PoseGraph.optimize` of ``pg`` by iSAM2: the nodes and edges added since the last call go in,
        switched-off edges out, then iSAM2 steps (each relinearising what moved) until no variable's step would be
        relinearised, no pose moves by more than 1e-6, or ``max_iterations`` steps; the gate's rounds as in the
        batch solver."""
        if self.isam is not None and fixed != self.fixed:
            self.isam = None  # another gauge: start over
        rejected: list[int] = []
        rounds = iterations = 0
        try:
            if self.isam is None:
                params = gtsam.ISAM2Params()
                params.setRelinearizeThreshold(_RELINEARIZE)
                params.relinearizeSkip = 1
                self.isam = gtsam.ISAM2(params)
                self.nodes, self.slot, self.fixed = 0, [], fixed
            for _ in range(max(1, prune_rounds)):
                graph, values, added = gtsam.NonlinearFactorGraph(), gtsam.Values(), []
                if self.nodes == 0:
                    Prior = gtsam.PriorFactorPose2 if pg.dof == 3 else gtsam.PriorFactorPose3
                    graph.add(Prior(fixed, _to_gtsam(gtsam, pg.dof, pg._P[fixed]),
                                    gtsam.noiseModel.Isotropic.Sigma(pg.dof, 1e-6)))
                    added.append(-1)
                for k in range(self.nodes, pg._n):
                    values.insert(k, _to_gtsam(gtsam, pg.dof, pg._P[k]))
                m, seen = len(pg.edges), len(self.slot)
                act = pg._active()
                for k in np.flatnonzero(act[seen:]) + seen:
                    graph.add(pg._factor(gtsam, int(k)))
                    added.append(int(k))
                self.slot.extend([-1] * (m - seen))  # -1: not in iSAM2 (switched off before it went in)
                slots = np.asarray(self.slot[:seen], dtype=np.int64)
                gone = np.flatnonzero((slots >= 0) & ~act[:seen])
                remove = slots[gone].tolist()
                for k in gone:
                    self.slot[k] = -1
                out = self.isam.update(graph, values, remove)
                for k, slot in zip(added, out.getNewFactorsIndices(), strict=True):
                    if k >= 0:
                        self.slot[k] = int(slot)
                self.nodes = pg._n
                estimate = self.isam.calculateEstimate()
                poses = _from_gtsam(gtsam, pg.dof, estimate, pg._n)
                steps = 1
                while steps < max_iterations:
                    delta = self.isam.getDelta().vector()
                    if not len(delta) or np.abs(delta).max() < _RELINEARIZE:
                        break  # an update would relinearise nothing: the estimate stays as it is
                    self.isam.update()
                    estimate = self.isam.calculateEstimate()
                    nxt = _from_gtsam(gtsam, pg.dof, estimate, pg._n)
                    steps += 1
                    moved = nxt - poses
                    moved[:, pg.dim:] = wrap_angle(moved[:, pg.dim:])
                    poses = nxt
                    if np.abs(moved).max() < 1e-6:
                        break
                rounds, iterations = rounds + 1, iterations + steps
                if not np.all(np.isfinite(poses)):
                    return OptimizationResult("failed", message="the optimisation gave non-finite poses",
                                              rounds=rounds, iterations_total=iterations)
                off = pg._take(poses, fixed)
                if not off:
                    break
                rejected.extend(off)
        except RuntimeError as exc:  # gtsam raises RuntimeError (IndeterminantLinearSystem, ...)
            self.isam = None
            return OptimizationResult("failed", message=f"{type(exc).__name__}: {exc}".splitlines()[0],
                                      rounds=rounds + 1, iterations_total=iterations)
        return OptimizationResult("ok", steps, rejected=rejected, rounds=rounds, iterations_total=iterations)


def _to_gtsam(gtsam, dof: int, pose: NDArray[np.float64]):
    """A pose vector as GTSAM's Pose2 (``dof`` 3) or Pose3 (``dof`` 6)."""
    if dof == 3:
        return gtsam.Pose2(float(pose[0]), float(pose[1]), float(pose[2]))
    return gtsam.Pose3(gtsam.Rot3(euler_to_matrix(pose[3], pose[4], pose[5])), gtsam.Point3(*pose[:3]))


def _from_gtsam(gtsam, dof: int, values, n: int) -> NDArray[np.float64]:
    """The poses of nodes 0..n-1 in GTSAM's ``values``, as (n, dof) pose vectors."""
    if dof == 3:
        return gtsam.utilities.extractPose2(values)[:, [0, 1, 2]]
    out = np.empty((n, 6))
    for k in range(n):
        p = values.atPose3(k)
        out[k, :3] = np.asarray(p.translation())
        out[k, 3:] = matrix_to_euler(np.asarray(p.rotation().matrix()))
    return out


def _noise(gtsam, dof: int, info: NDArray[np.float64], robust: bool, loop_kernel: float):
    """GTSAM's noise model of an information matrix (made positive definite), Cauchy-robust if ``robust``."""
    if dof == 6:  # gtsam's Pose3 tangent is (rotation, translation)
        perm = np.r_[3, 4, 5, 0, 1, 2]
        info = info[np.ix_(perm, perm)]
    w, V = np.linalg.eigh(info)
    info = (V * np.maximum(w, 1e-9 * max(w.max(), 1e-9))) @ V.T  # positive definite
    base = gtsam.noiseModel.Gaussian.Information(info)
    if robust:
        return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(loop_kernel), base)
    return base
