"""Harmony-ICP's settings (:class:`RegistrationConfig`, the look-up :class:`Backend` and the :class:`Refinement`)
and what a registration returns (:class:`RegistrationResult`)."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from ..errors import ConfigError
from .harmony import HarmonyConfig
from .information import safe_inverse


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
