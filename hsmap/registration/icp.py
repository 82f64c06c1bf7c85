"""Harmony-ICP: scan registration by Harmony Search (the paper's Algorithm 1), in 2D (3-DOF) and 3D (6-DOF).

:func:`harmony_icp` searches the pose vector (x, y, yaw) for (N, 2) clouds or (x, y, z, roll, pitch, yaw) for
(N, 3) clouds that minimises the two-term fitness of :mod:`hsmap.registration.fitness`, with the harmony memory seeded by
optional initial guesses and the rest drawn inside the bounds. No initial guess is needed: with none, the search
is centred on the identity. An optional local refinement (point-to-plane or point-to-point ICP, trimmed at the
fitness threshold) polishes the best harmony.

The global search truncates distances at ``search_threshold`` (0.5 m: a broad basin that finds the right
alignment from far away); an optional second Harmony Search stage narrows the box around the best harmony and
uses ``fine_threshold``. The refinement trims correspondences at ``threshold``, the inlier distance of the
reported fitness and inlier ratio.
"""

from __future__ import annotations

import enum
import time
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from .._blas import blas_limited
from .._threads import threads_limited
from ..errors import ConfigError, DegenerateInputError, EmptyInputError, InputError, ShapeError
from ..geometry import dof_of_dim, matrix_to_pose, pose_to_matrix, relative, transform_points, wrap_angle
from ..maps.mapping import voxel_downsample
from .fitness import DistanceField, FieldObjective, KDTreeLookup, field_bounds, score
from .harmony import HarmonyConfig, HarmonyResult, as_rng, harmony_search
from .information import adjoint, constrained_axes, drop_degenerate, safe_inverse
from .neighbours import NeighbourGrid, grid_fits, tree_query
from .normals import estimate_normals, orient_normals

__all__ = [
    "Backend",
    "Refinement",
    "RegistrationConfig",
    "RegistrationResult",
    "RegistrationTarget",
    "harmony_icp",
    "default_bounds",
    "refine_icp",
    "estimate_normals",
    "orient_normals",
    "alignment_cost",
    "alignment_information",
    "adjoint",
    "constrained_axes",
    "drop_degenerate",
    "spans_its_space",
]


class Backend(enum.StrEnum):
    """How nearest-neighbour distances are looked up."""

    FIELD = "field"  # precomputed distance field (fast)
    KDTREE = "kdtree"  # scipy cKDTree (exact)


class Refinement(enum.StrEnum):
    """Local refinement after the global search."""

    NONE = "none"
    POINT_TO_POINT = "point-to-point"
    POINT_TO_PLANE = "point-to-plane"  # point-to-line in 2D


def _default_harmony() -> HarmonyConfig:
    return HarmonyConfig(batch_size=16, max_iterations=500, patience=20, convergence_tol=1e-6, init="lhs")


@dataclass
class RegistrationConfig:
    """Parameters of :func:`harmony_icp`.

    Attributes
    ----------
    harmony : HarmonyConfig
        Optimiser parameters (paper defaults HMS 30, HMCR 0.7, PAR 0.3, BW 0.05, 500 iterations; here improvised
        16 at a time with a no-improvement rule of 20 rounds, the memory drawn by Latin hypercube sampling).
    threshold : float
        Metres. Inlier distance: of the reported fitness and inlier ratio, and the refinement's trimming.
    search_threshold : float
        Metres. Truncation (and inlier distance) of the fitness in the global search.
    fine_threshold : float or None
        Metres. If set, a second Harmony Search stage around the best harmony uses this truncation.
    inlier_weight : float
        Weight ``w`` of the inlier-count term (see :mod:`hsmap.registration.fitness`).
    backend : Backend
        ``Backend.FIELD`` (distance field, fast) or ``Backend.KDTREE`` (exact); the strings ``"field"`` and
        ``"kdtree"`` are accepted.
    field_resolution : float or None
        Cell size of the distance fields in metres; None picks a tenth of the truncation (at least 0.02 m) in 2D
        and a quarter of it in 3D.
    max_points : int
        Source points used by the global search (a random subset, drawn from ``rng``, after voxel downsampling).
    voxel_size : float or None
        Voxel size for downsampling the source before sampling ``max_points``; None picks 0.05 m in 2D and
        0.1 m in 3D.
    translation_range, z_range : float
        Metres. Half-width of the default search box around the initial guesses (or the identity) in x, y and z.
    yaw_range, roll_pitch_range : float
        Radians. Half-width of the default search box in yaw and in roll/pitch.
    fine_range_factor : float
        The fine stage searches +/- this many search thresholds (translation) around the first stage's best, and
        the matching angle at the source's radius of gyration.
    refinement : Refinement
        ``Refinement.POINT_TO_PLANE`` (point-to-line in 2D), ``POINT_TO_POINT`` or ``NONE``; the strings
        ``"point-to-plane"``, ``"point-to-point"`` and ``"none"`` are accepted.
    refine_iterations : int
        Maximum refinement iterations.
    refine_points : int
        Source points used by the refinement.
    refine_reach : float or None
        Metres: a refinement that moves the search's pose by at most this much is kept even where its truncated
        cost is a little higher (the search cannot tell poses within a field cell apart). None: the search
        field's cell in 2D, 0 in 3D; 0: the cost alone decides.
    refine_seeds : int
        Also refine from this many of the initial guesses (in the order given) and keep, of all refined
        candidates, the one with the lowest point-to-plane cost. Guards against a global search that settles in
        a flat, sampling-biased valley of the point-to-point fitness (a long corridor).
    robust_kernel : float
        Metres. Scale of the Geman-McClure kernel weighting the point-to-plane residuals (0: plain least squares):
        correspondences much farther than it (new, unmapped surfaces matched to old ones) lose their pull.
    polish_voxel : float or None
        Metres. 3D: a final point-to-plane refinement after the search and its refinement, against the target
        averaged in voxels of this size (normals estimated there, where a neighbourhood spans a surface rather
        than a scan line) with the source averaged in voxels of twice it; kept where it lowers the truncated
        point-to-plane cost on that target. None: 0.1 m; 0: none. 2D scans have none.
    polish_distance : float
        Metres. The final refinement's correspondences farther apart than this are ignored.
    polish_kernel : float
        Metres. Scale of the Geman-McClure kernel of the final refinement (0: plain least squares).
    polish_iterations : int
        The final refinement's iterations at most (0: none).
    stop_within_cell : bool
        2D: count, for the Harmony Search's ``patience``, only the improvements that move its best pose by more
        than one cell of the search's distance field (translation; rotation: the angle that moves the sample's
        typical point by a cell): the fitness cannot tell poses within a cell apart, and the refinement polishes
        the best. 3D searches, whose field cells are several times coarser, count every improvement.
    """

    harmony: HarmonyConfig = field(default_factory=_default_harmony)
    threshold: float = 0.10
    search_threshold: float = 0.5
    fine_threshold: float | None = None
    inlier_weight: float = 1.0
    backend: Backend = Backend.FIELD
    field_resolution: float | None = None
    max_points: int = 150
    voxel_size: float | None = None
    translation_range: float = 1.5
    z_range: float = 0.3
    yaw_range: float = np.deg2rad(60.0)
    roll_pitch_range: float = np.deg2rad(8.0)
    fine_range_factor: float = 1.0
    refinement: Refinement = Refinement.POINT_TO_PLANE
    refine_iterations: int = 30
    refine_points: int = 2000
    refine_reach: float | None = 0.0
    refine_seeds: int = 0
    robust_kernel: float = 0.0
    polish_voxel: float | None = None
    polish_distance: float = 0.3
    polish_kernel: float = 0.1
    polish_iterations: int = 30
    stop_within_cell: bool = True

    def __post_init__(self) -> None:
        for name in ("threshold", "search_threshold", "inlier_weight", "translation_range", "z_range", "yaw_range",
                     "roll_pitch_range", "fine_range_factor", "polish_distance", "polish_kernel"):
            v = getattr(self, name)
            positive = name in ("threshold", "search_threshold", "polish_distance")
            if not (np.isfinite(v) and (v > 0 if positive else v >= 0)):
                need = "> 0" if positive else ">= 0"
                raise ConfigError(f"registration.{name} must be a finite number {need}, got {v!r}")
        if not (np.isfinite(self.robust_kernel) and self.robust_kernel >= 0):
            raise ConfigError(f"registration.robust_kernel must be a finite number >= 0, got {self.robust_kernel!r}")
        for name in ("field_resolution", "voxel_size", "fine_threshold"):
            v = getattr(self, name)
            if v is not None and not (np.isfinite(v) and v > 0):
                raise ConfigError(f"registration.{name} must be None or > 0, got {v!r}")
        if self.polish_voxel is not None and not (np.isfinite(self.polish_voxel) and self.polish_voxel >= 0):
            raise ConfigError(f"registration.polish_voxel must be None or a finite number >= 0, got "
                              f"{self.polish_voxel!r}")
        if self.refine_reach is not None and not (np.isfinite(self.refine_reach) and self.refine_reach >= 0):
            raise ConfigError(f"registration.refine_reach must be None or a finite number >= 0, got "
                              f"{self.refine_reach!r}")
        for name in ("max_points", "refine_iterations", "refine_points", "refine_seeds", "polish_iterations"):
            v = getattr(self, name)
            zero_ok = name in ("refine_iterations", "refine_seeds", "polish_iterations")
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < (0 if zero_ok else 1):
                raise ConfigError(f"registration.{name} must be a positive integer, got {v!r}")
        try:
            self.backend = Backend(self.backend)
        except ValueError:
            raise ConfigError(f"registration.backend must be one of {[b.value for b in Backend]}, "
                              f"got {self.backend!r}") from None
        try:
            self.refinement = Refinement(self.refinement)
        except ValueError:
            raise ConfigError(f"registration.refinement must be one of {[r.value for r in Refinement]}, "
                              f"got {self.refinement!r}") from None
        if isinstance(self.harmony, dict):
            from ..config import from_dict

            self.harmony = from_dict(HarmonyConfig, self.harmony, "registration.harmony")

    def effective_polish_voxel(self) -> float:
        """``polish_voxel`` or its default, 0.1 m (0: no final refinement)."""
        return 0.1 if self.polish_voxel is None else float(self.polish_voxel)


@dataclass
class RegistrationResult:
    """Outcome of :func:`harmony_icp`.

    Attributes
    ----------
    transformation : ndarray of shape (3, 3) or (4, 4)
        Homogeneous transform mapping ``source`` into the frame of ``target``.
    pose : ndarray of shape (3,) or (6,)
        The same as a pose vector (x, y, yaw) or (x, y, z, roll, pitch, yaw).
    fitness : float
        Two-term fitness at ``pose`` over all valid source points, with the fine threshold (lower is better).
    inlier_ratio : float
        Fraction of valid source points within ``threshold`` of the target at ``pose``.
    rmse : float
        Root mean square distance of the inliers (metres).
    evaluations : int
        Poses scored by the global search.
    iterations : int
        Harmony Search rounds (both stages).
    dropped : int
        Source and target points dropped because they were NaN or infinite.
    global_pose : ndarray
        Best pose of the global search, before refinement.
    refined : bool
        Whether the refinement was applied (it is kept only if it does not worsen the fitness).
    stop_reason : str
        Why the (last) Harmony Search stage stopped.
    seconds : float
        Wall time of the call.
    information : ndarray of shape (dof, dof)
        Information matrix (inverse covariance) of the pose: of a small motion xi = (translation, rotation)
        applied in the source's own frame, ``transformation @ exp(xi)``, from the point-to-plane (point-to-line)
        Gauss-Newton matrix of the inlier correspondences at ``pose`` divided by their residual variance
        (:func:`alignment_information`). Small eigenvalues mark directions the scene does not constrain (a
        corridor's axis).
    cost : float
        Mean truncated point-to-plane residual over all valid source points, as a fraction of ``threshold``
        (:func:`alignment_cost`; 0 perfect, 1 nothing matched): the measure by which candidate poses are compared.
    """

    transformation: NDArray[np.float64]
    pose: NDArray[np.float64]
    fitness: float
    inlier_ratio: float
    rmse: float
    evaluations: int
    iterations: int
    dropped: int
    global_pose: NDArray[np.float64]
    refined: bool
    stop_reason: str
    seconds: float
    information: NDArray[np.float64] | None = None
    cost: float = float("nan")

    @property
    def covariance(self) -> NDArray[np.float64]:
        """Covariance of the body-frame perturbation (see ``information``); inf where unconstrained."""
        return safe_inverse(self.information)


def _clean_cloud(points: ArrayLike, name: str, dim: int | None = None) -> tuple[NDArray[np.float64], int]:
    try:
        arr = np.asarray(points, dtype=float)
    except (TypeError, ValueError):
        raise ShapeError(f"{name} must be a numeric array of shape (N, 2) or (N, 3)") from None
    if arr.ndim != 2 or arr.shape[1] not in (2, 3):
        raise ShapeError(f"{name} must have shape (N, 2) or (N, 3), got {arr.shape}")
    if dim is not None and arr.shape[1] != dim:
        raise ShapeError(f"{name} has {arr.shape[1]} columns but the other cloud has {dim}: "
                         f"both must be 2D (N, 2) or both 3D (N, 3)")
    if arr.shape[0] == 0:
        raise EmptyInputError(f"{name} is empty: expected at least one point")
    ok = np.all(np.isfinite(arr), axis=1)
    dropped = int((~ok).sum())
    if dropped:
        arr = arr[ok]
        if arr.shape[0] == 0:
            raise EmptyInputError(f"{name} has no finite points: all {dropped} contain NaN or inf")
    return arr, dropped


def _check_spread(arr: NDArray[np.float64], name: str) -> None:
    """DegenerateInputError naming ``name`` when its (finite) points do not span the plane (2D) or space (3D)."""
    if not spans_its_space(arr):
        d = arr.shape[1]
        where = "on one line" if d == 2 else "on one plane"
        raise DegenerateInputError(
            f"{name} cannot be registered: its {len(arr)} finite points "
            f"{'coincide' if not spans_its_space(arr, 1) else 'all lie ' + where}; a {d}D registration needs points "
            f"that span the {'plane' if d == 2 else 'space'} (at least {d + 1} not {where})")


def spans_its_space(points: NDArray[np.float64], rank: int | None = None) -> bool:
    """Whether finite points (N, d) span ``rank`` dimensions (default d): not all equal, not all on one line
    (2D), not all on one plane (3D), up to rounding (the smallest spread is below 1e-9 of the largest).

    A cloud that does not span its space has no unique registration: it can slide or turn without changing its
    fit (:func:`harmony_icp` raises :class:`~hsmap.errors.DegenerateInputError` for one).
    """
    from . import _kernels  # numba: compiled on first use
    pts = np.ascontiguousarray(points, dtype=float)
    d = pts.shape[1]
    rank = d if rank is None else rank
    if len(pts) < rank + 1:
        return False
    scale, scatter = _kernels.centred_scatter(pts)
    if not scale > 0 or not np.isfinite(scale):
        return rank == 0
    ev = np.linalg.eigvalsh(scatter)  # ascending; spreads squared
    return bool(ev[d - rank] > 1e-18 * ev[-1])


class RegistrationTarget:
    """A target cloud prepared for repeated registrations (distance fields, KD-tree, normals built once).

    Parameters
    ----------
    points : array_like of shape (M, 2) or (M, 3)
    config : RegistrationConfig, optional
    normals : array_like of shape (M, 2) or (M, 3), optional
        Unit normals of the points, when known (otherwise estimated on first use by PCA of neighbourhoods).
    fields : dict of float to DistanceField, optional
        Distance fields already built for given truncations (e.g. a map's field grown scan by scan).
    field_within : array_like of shape (2, d), optional
        [lower, upper] corners of the box that the registrations' transformed source points stay in: the fields
        built here cover only that box (:func:`hsmap.registration.fitness.field_bounds`), and answer as whole ones there.
    """

    def __init__(self, points: ArrayLike, config: RegistrationConfig | None = None, *,
                 normals: ArrayLike | None = None, fields: dict[float, DistanceField] | None = None,
                 field_within: ArrayLike | None = None) -> None:
        self.config = config or RegistrationConfig()
        self.points, self.dropped = _clean_cloud(points, "target")
        _check_spread(self.points, "target")
        self.dim = self.points.shape[1]
        self._lookups: dict[float, DistanceField | KDTreeLookup] = dict(fields or {})
        self._field_within = None if field_within is None else np.asarray(field_within, dtype=float)
        self._tree: cKDTree | None = None
        self._grid: NeighbourGrid | None | bool = None  # False: the points do not fit a grid
        self._normals: NDArray[np.float64] | None = None
        self._voxelised: dict[float, RegistrationTarget] = {}
        if normals is not None:
            n = np.asarray(normals, dtype=float)
            if n.shape != self.points.shape or self.dropped:
                raise ShapeError(f"target normals must have the shape of the (finite) points {self.points.shape}, "
                                 f"got {n.shape}")
            self._normals = n

    def voxelised(self, voxel: float) -> RegistrationTarget:
        """This target averaged in voxels of side ``voxel`` (:func:`hsmap.maps.mapping.voxel_downsample`), as a target
        of its own with its own normals; built on first use, then cached."""
        cached = self._voxelised.get(voxel)
        if cached is None:
            pts = voxel_downsample(self.points, voxel)
            cached = self if len(pts) == len(self.points) or not spans_its_space(pts) else \
                RegistrationTarget(pts, self.config)
            self._voxelised[voxel] = cached
        return cached

    def lookup(self, truncation: float) -> DistanceField | KDTreeLookup:
        """The distance look-up for a truncation distance (built on first use, then cached)."""
        lk = self._lookups.get(truncation)
        if lk is None:
            if self.config.backend is Backend.FIELD:
                res = self.config.field_resolution
                if res is None:
                    res = max(0.02, truncation / 10.0) if self.dim == 2 else truncation / 4.0
                # 2D: keep nearest points too, for the point-to-line refinement's correspondences
                plane = self.dim == 2 and self.config.refinement is Refinement.POINT_TO_PLANE
                bounds = (None if self._field_within is None
                          else field_bounds(self.points, res, truncation, self._field_within))
                lk = DistanceField(self.points, res, truncation, bounds=bounds,
                                   normals=self.normals if plane else None)
            else:
                lk = KDTreeLookup(self.points, truncation)
            self._lookups[truncation] = lk
        return lk

    def nearest_field(self, reach: float) -> DistanceField | None:
        """A field of this target that keeps nearest points and reaches at least ``reach`` metres, if any."""
        best = None
        for lk in self._lookups.values():
            if (isinstance(lk, DistanceField) and lk.keeps_nearest and lk.truncation >= reach
                    and (best is None or lk.resolution < best.resolution)):
                best = lk
        return best

    def prepare(self) -> NeighbourGrid | bool:
        """Build the neighbour grid of :meth:`nearest` now rather than on the first query (False: the target
        does not fit one, :func:`hsmap.registration.neighbours.grid_fits`)."""
        if self._grid is None:
            cell = 2.0 * self.config.threshold
            self._grid = NeighbourGrid(self.points, cell) if grid_fits(self.points, cell) else False
        return self._grid

    def nearest(self, points: NDArray[np.float64], bound: float, hint: NDArray[np.intp] | None = None
                ) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
        """Nearest target point of each point (N, d) closer than ``bound``: (distance, row), ``inf`` and
        ``len(self.points)`` where none is; cKDTree's answer, bit for bit, except that of points at exactly the
        same distance the lowest row is the answer wherever it comes from.

        Answered by a :class:`hsmap.registration.neighbours.NeighbourGrid` of cells twice the configured ``threshold`` (the
        refinement's trimming distances) where the target fits one and ``bound`` is at most two cells, else by
        the KD-tree; large queries are split between the compute threads either way. ``hint`` (N,): rows near
        the points (a previous answer), which speed the grid's search and change no answer.
        """
        grid = self.prepare()
        if grid is not False and bound <= 2.0 * grid.cell:
            return grid.query(points, bound, hint)
        return tree_query(self.tree, points, distance_upper_bound=bound)

    @property
    def tree(self) -> cKDTree:
        if self._tree is None:
            # sliding-midpoint splits: half the build time of a balanced tree, the same exact answers
            self._tree = cKDTree(self.points, balanced_tree=False, compact_nodes=False)
        return self._tree

    @property
    def normals(self) -> NDArray[np.float64]:
        """Unit normals of the target points (lines in 2D, planes in 3D), estimated once when not given."""
        if self._normals is None:
            self._normals = estimate_normals(self.points, tree=self.tree)
        return self._normals


def default_bounds(centres: NDArray[np.float64], cfg: RegistrationConfig) -> NDArray[np.float64]:
    """The box (dof, 2) that :func:`harmony_icp` searches without ``bounds``: the initial guesses ``centres``
    (K, dof) widened by the configured ranges (``translation_range``, ``z_range``, ``roll_pitch_range``,
    ``yaw_range``)."""
    dof = centres.shape[1]
    if dof == 3:
        half = np.array([cfg.translation_range, cfg.translation_range, cfg.yaw_range])
    else:
        half = np.array([cfg.translation_range, cfg.translation_range, cfg.z_range,
                         cfg.roll_pitch_range, cfg.roll_pitch_range, cfg.yaw_range])
    return np.column_stack([centres.min(axis=0) - half, centres.max(axis=0) + half])


_default_bounds = default_bounds  # its private name, for the callers that import that


def _check_bounds(bounds: ArrayLike, dof: int) -> NDArray[np.float64]:
    try:
        b = np.asarray(bounds, dtype=float)
    except (TypeError, ValueError):
        raise ShapeError(f"bounds must be a numeric array of shape ({dof}, 2)") from None
    if b.shape != (dof, 2):
        raise ShapeError(f"bounds must have shape ({dof}, 2) [lower, upper] for a {dof}-DOF pose, got {b.shape}")
    if not np.all(np.isfinite(b)):
        raise InputError(f"bounds must be finite, got {b.tolist()}")
    bad = np.flatnonzero(b[:, 1] < b[:, 0])
    if bad.size:
        i = int(bad[0])
        raise InputError(f"bounds[{i}] is inverted: lower {b[i, 0]} > upper {b[i, 1]}")
    with np.errstate(over="ignore"):
        wide = np.flatnonzero(~np.isfinite(b[:, 1] - b[:, 0]))
    if wide.size:
        i = int(wide[0])
        raise InputError(f"bounds[{i}] spans {b[i, 0]:g}..{b[i, 1]:g}, wider than a float can hold; expected a "
                         "search box of finite width")
    return b


def _subsample(points: NDArray[np.float64], voxel: float, n: int, gen: np.random.Generator) -> NDArray[np.float64]:
    pts = voxel_downsample(points, voxel)
    if len(pts) > n:
        pts = pts[np.sort(gen.choice(len(pts), n, replace=False))]
    return pts


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
    idx = hint  # the previous iteration's correspondences: the next search starts from them
    for dist in schedule:
        for _ in range(per_stage):
            moved = transform_points(T, source)
            d, idx = target.nearest(moved, dist, idx)
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
    _, moved, d, idx = match
    ok = np.isfinite(d)
    r = d.copy()
    if plane:
        r[ok] = np.abs(np.einsum("ij,ij->i", target.normals[idx[ok]], moved[ok] - target.points[idx[ok]]))
    return float(np.where(ok, np.minimum(r, threshold), threshold).mean() / threshold)


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
    ok = np.isfinite(d)
    n = int(ok.sum())
    if n < 2 * dim:
        return np.zeros((dof, dof)), float("nan"), n, 1.0 - n / max(len(source), 1)
    p, q, nq = moved[ok], target.points[idx[ok]], target.normals[idx[ok]]
    A, _ = _kernels.point_to_plane_normal_equations(p, q, nq, robust_kernel)
    r = np.einsum("ij,ij->i", nq, p - q)
    cost = float((np.minimum(np.abs(r), threshold).sum() + threshold * (len(source) - n)) / (threshold * len(source)))
    if robust_kernel > 0:
        k2 = robust_kernel * robust_kernel
        w = k2 * k2 / (k2 + r * r) ** 2
    else:
        w = np.ones_like(r)
    sigma = max(float(np.sqrt((w * r * r).sum() / w.sum())), min_sigma)
    Ad = adjoint(T)
    return Ad.T @ (A / sigma**2) @ Ad, sigma, n, cost


def _refine_reach(cfg: RegistrationConfig, lookup, dim: int) -> float:
    """``cfg.refine_reach``, or its default: the 2D search field's cell, 0 in 3D."""
    if cfg.refine_reach is not None:
        return cfg.refine_reach
    if dim != 2:
        return 0.0
    return lookup.resolution if isinstance(lookup, DistanceField) else max(0.02, cfg.search_threshold / 10)


def _within(a: NDArray[np.float64], b: NDArray[np.float64], reach: NDArray[np.float64], dim: int) -> bool:
    """Whether pose ``b`` lies within ``reach`` (per pose component) of pose ``a``, in ``a``'s frame."""
    moved = np.abs(relative(a, b))
    moved[dim:] = np.abs(wrap_angle(moved[dim:]))
    return bool(np.all(moved <= reach))


def _polish(source: NDArray[np.float64], target: RegistrationTarget, pose: NDArray[np.float64],
            cfg: RegistrationConfig) -> NDArray[np.float64] | None:
    """The final point-to-plane refinement of a 3D ``pose`` (``RegistrationConfig.polish_*``) against the target
    averaged in voxels: the refined pose where it lowers the truncated point-to-plane cost there, else None."""
    voxel = cfg.effective_polish_voxel()
    if voxel <= 0 or cfg.polish_iterations <= 0:
        return None
    fine = target.voxelised(voxel)
    src = voxel_downsample(source, 2 * voxel)
    if len(src) < 6:
        return None
    cand = refine_icp(src, fine, pose, max_distance=cfg.polish_distance, iterations=cfg.polish_iterations,
                      robust_kernel=cfg.polish_kernel)
    before = _alignment_cost(pose, src, fine, cfg.threshold, plane=True)
    after = _alignment_cost(cand, src, fine, cfg.threshold, plane=True)
    return cand if after < before else None


@blas_limited
@threads_limited
def harmony_icp(
    source: ArrayLike,
    target: ArrayLike | RegistrationTarget,
    *,
    bounds: ArrayLike | None = None,
    initial_guesses: ArrayLike | None = None,
    config: RegistrationConfig | None = None,
    rng: int | np.random.Generator | None = None,
) -> RegistrationResult:
    """Register ``source`` to ``target`` with Harmony Search (Harmony-ICP).

    Parameters
    ----------
    source : array_like of shape (N, 2) or (N, 3)
        Points to move. NaN/inf rows are dropped (counted in ``result.dropped``).
    target : array_like of shape (M, 2) or (M, 3), or RegistrationTarget
        Reference points (same dimension as ``source``), or a target prepared once for many registrations.
    bounds : array_like of shape (dof, 2), optional
        Absolute [lower, upper] limits of the pose vector (x, y, yaw) or (x, y, z, roll, pitch, yaw). Default: a
        box of the configured ranges around the initial guesses, or around the identity.
    initial_guesses : array_like of shape (K, dof) or (dof,), optional
        Pose vectors seeded into the harmony memory (odometry, previous pose, ...). None needed.
    config : RegistrationConfig, optional
    rng : int or numpy.random.Generator, optional
        Seed or generator for every random choice (default seed 0).
    threads : int, optional
        Compute threads (keyword only; default: the enclosing run's, else ``$HSMAP_THREADS``, else every core):
        a speed setting only, the result is the same for any count (:mod:`hsmap._threads`).

    Returns
    -------
    RegistrationResult
        ``.transformation`` maps ``source`` into the frame of ``target``.
    """
    t0 = time.perf_counter()
    cfg = config or (target.config if isinstance(target, RegistrationTarget) else RegistrationConfig())
    if not isinstance(cfg, RegistrationConfig):
        raise ConfigError(f"config must be a RegistrationConfig, got {type(cfg).__name__}")
    gen = as_rng(rng)
    if isinstance(target, RegistrationTarget):
        tgt = target
        src, dropped = _clean_cloud(source, "source", tgt.dim)
    else:
        src, dropped = _clean_cloud(source, "source")
        _clean_cloud(target, "target", src.shape[1])  # shape check with names before building anything
    _check_spread(src, "source")
    if not isinstance(target, RegistrationTarget):
        tgt = RegistrationTarget(target, cfg)
    dropped += tgt.dropped
    dim = src.shape[1]
    dof = dof_of_dim(dim)

    guesses = None
    if initial_guesses is not None:
        try:
            guesses = np.atleast_2d(np.asarray(initial_guesses, dtype=float))
        except (TypeError, ValueError):
            raise ShapeError(f"initial_guesses must be numeric pose vectors of shape (K, {dof})") from None
        if guesses.ndim != 2 or guesses.shape[1] != dof:
            raise ShapeError(f"initial_guesses must have shape (K, {dof}) for {dim}D clouds, "
                             f"got {np.asarray(initial_guesses).shape}")
        if not np.all(np.isfinite(guesses)):
            raise InputError("initial_guesses must be finite (no NaN or inf)")
    if bounds is None:
        centres = guesses if guesses is not None else np.zeros((1, dof))
        b = default_bounds(centres, cfg)
    else:
        b = _check_bounds(bounds, dof)

    voxel = cfg.voxel_size or (0.05 if dim == 2 else 0.1)
    try:
        sample = _subsample(src, voxel, cfg.max_points, gen)
    except InputError as exc:
        raise type(exc)(f"source: {exc}") from None
    radius = float(np.sqrt(((sample - sample.mean(0)) ** 2).sum(1).mean())) + 1e-9
    iterations = evaluations = 0
    hs: HarmonyResult | None = None
    seeds = guesses

    stages = [cfg.search_threshold] + ([cfg.fine_threshold] if cfg.fine_threshold else [])
    for k, tau in enumerate(stages):
        box = b
        if k > 0 and hs is not None:
            # narrow the box around the first stage's best: +/- a few search thresholds in translation, and the
            # angle that moves the source's typical point by as much
            half_t = cfg.fine_range_factor * cfg.search_threshold
            half = np.full(dof, min(half_t / radius, np.pi))
            half[:dim] = half_t
            box = np.column_stack([np.maximum(hs.x - half, b[:, 0]), np.minimum(hs.x + half, b[:, 1])])
            seeds = hs.memory[: max(1, cfg.harmony.memory_size // 3)]
        lookup = tgt.lookup(tau)
        if isinstance(lookup, DistanceField):
            objective = FieldObjective(sample, lookup, cfg.inlier_weight)  # compiled Harmony Search rounds
        else:
            def objective(X: NDArray[np.float64], lookup=lookup) -> NDArray[np.float64]:
                return score(X, sample, lookup, cfg.inlier_weight).value

        spread = None
        if cfg.stop_within_cell and dim == 2:
            cell = lookup.resolution if isinstance(lookup, DistanceField) else max(0.02, tau / 10.0)
            spread = np.full(dof, cell / radius)
            spread[:dim] = cell
        hs = harmony_search(objective, box, initial=seeds, config=cfg.harmony, rng=gen, spread=spread)
        iterations += hs.iterations
        evaluations += hs.evaluations
    assert hs is not None
    global_pose = hs.x.copy()
    pose = global_pose.copy()

    full = src if len(src) <= cfg.refine_points else src[np.sort(gen.choice(len(src), cfg.refine_points,
                                                                            replace=False))]
    refined = False
    match = None  # the correspondences at `pose` (one KD-tree query serves the cost, information and fitness)
    if cfg.refinement is not Refinement.NONE and cfg.refine_iterations > 0:
        # Keep a refinement unless it made the alignment worse, judged by its own (point-to-plane) metric: the
        # point-to-point fitness is biased towards poses where the scan's sampling pattern (a LiDAR's rings on
        # the floor) repeats the map's, i.e. towards no motion.
        plane = cfg.refinement is Refinement.POINT_TO_PLANE
        match = _match(pose, full, tgt, cfg.threshold)
        best_cost = _cost_of(match, tgt, cfg.threshold, plane)
        reach = np.full(dof, _refine_reach(cfg, lookup, dim))
        reach[dim:] /= radius
        starts = [pose] + ([] if guesses is None else list(guesses[: cfg.refine_seeds]))
        near = match[3]  # the correspondences at the search's pose, near every start and result
        for start in starts:
            cand = refine_icp(full, tgt, start, max_distance=cfg.threshold, start_distance=cfg.search_threshold,
                              iterations=cfg.refine_iterations, method=cfg.refinement,
                              robust_kernel=cfg.robust_kernel, hint=near)
            cand_match = _match(cand, full, tgt, cfg.threshold, near)
            cost = _cost_of(cand_match, tgt, cfg.threshold, plane)
            if cost <= best_cost + 1e-12 or (not refined and reach.any() and _within(global_pose, cand, reach, dim)):
                pose, best_cost, refined, match = cand, cost, True, cand_match
    polished = _polish(src, tgt, pose, cfg) if dim == 3 else None
    if polished is not None:
        pose, refined, match = polished, True, None
    pose = pose.copy()
    pose[dim:] = wrap_angle(pose[dim:])  # the same transform: `match` still holds
    if match is None:
        match = _match(pose, full, tgt, cfg.threshold)
    if full is src:
        d = np.minimum(match[2], cfg.threshold)
    else:
        d = np.minimum(tgt.nearest(transform_points(pose_to_matrix(pose), src), cfg.threshold)[0], cfg.threshold)
    inl = d < cfg.threshold * (1 - 1e-6)
    inlier_ratio = float(inl.mean())
    fitness = float(d.mean() / cfg.threshold + cfg.inlier_weight * (1.0 - inlier_ratio))
    rmse = float(np.sqrt(np.mean(d[inl] ** 2))) if inl.any() else float("nan")
    information, _, _, cost = _information_and_cost(full, tgt, pose, cfg.threshold, cfg.robust_kernel, match=match)
    return RegistrationResult(
        transformation=pose_to_matrix(pose),
        pose=pose,
        fitness=fitness,
        inlier_ratio=inlier_ratio,
        rmse=rmse,
        evaluations=evaluations,
        iterations=iterations,
        dropped=dropped,
        global_pose=global_pose,
        refined=refined,
        stop_reason=hs.stop_reason.value,
        seconds=time.perf_counter() - t0,
        information=information,
        cost=cost,
    )
