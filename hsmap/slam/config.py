"""HS-SLAM's settings: the tracker's (:class:`SlamConfig`) and the keyframe graph's policy
(:class:`KeyframeGraphConfig`); lengths in metres, angles in radians."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from ..config import from_dict
from ..errors import ConfigError
from ..registration.harmony import HarmonyConfig
from ..registration.icp import RegistrationConfig
from .loopclosure import LoopClosureConfig
from .posegraph import SOLVERS

__all__ = ["SlamConfig", "KeyframeGraphConfig"]


def _tracking_registration() -> RegistrationConfig:
    return RegistrationConfig(
        harmony=HarmonyConfig(batch_size=16, max_iterations=500, patience=15, convergence_tol=1e-6, init="lhs"),
        search_threshold=0.3,
        threshold=0.1,
        max_points=150,
        refine_points=4000,  # 3D: every point of a 0.15 m-voxel cloud
        robust_kernel=0.07,
        translation_range=0.4,
        yaw_range=np.deg2rad(20.0),
        z_range=0.05,
        roll_pitch_range=np.deg2rad(2.0),
        # 3D: the final refinement stops where its step falls below the tolerance; the cap only bounds the work.
        # A search whose best lies a few decimetres off leaves it that far to go, and a cap met on the way leaves
        # the frame centimetres and tenths of a degree short of the alignment it was converging to
        polish_iterations=100,
    )


@dataclass
class KeyframeGraphConfig:
    """When the keyframe graph gains edges, searches for loops and is optimised.

    Attributes
    ----------
    pair_edges : int
        Scan-to-scan edges per new keyframe (0: none), to the nearest earlier keyframes within
        ``pair_distance``; each is a refinement from the graph's relative pose.
    pair_distance : float
        Metres between the two keyframes' positions, at most, for a pair edge.
    pair_iterations : int
        Refinement iterations of a pair edge at most (it starts a few millimetres off).
    odometry_edges : bool
        2D runs with wheel odometry: the odometry's motion between consecutive keyframes is an edge of its own,
        with the learned model's covariance, down-weighted where a wheel slipped.
    tracking_path_distance : float
        The tracking map holds the keyframes within this graph distance of the newest keyframe.
    optimize_threshold_translation, optimize_threshold_rotation : float
        A closure that corrects the graph's estimate by more than these optimises the graph at once.
    optimize_every : int
        Otherwise the graph is optimised at least this often (keyframes) while edges are pending, and at the end.
    solver : str
        How the graph is optimised: ``incremental`` (iSAM2, updating what the new edges touch) or ``batch``
        (Levenberg-Marquardt on the whole graph each time); :class:`hsmap.slam.posegraph.PoseGraph`.
    """

    pair_edges: int = 4
    pair_distance: float = 2.0
    pair_iterations: int = 10
    odometry_edges: bool = True
    tracking_path_distance: float = 20.0
    optimize_threshold_translation: float = 0.02
    optimize_threshold_rotation: float = float(np.deg2rad(0.3))
    optimize_every: int = 25
    solver: str = "incremental"

    def __post_init__(self) -> None:
        for name in ("pair_distance", "tracking_path_distance", "optimize_threshold_translation",
                     "optimize_threshold_rotation"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float, np.floating)) and np.isfinite(v) and v >= 0):
                raise ConfigError(f"slam.graph.{name} must be a finite number >= 0, got {v!r}")
        for name in ("pair_edges", "pair_iterations", "optimize_every"):
            v, low = getattr(self, name), 0 if name == "pair_edges" else 1
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < low:
                raise ConfigError(f"slam.graph.{name} must be an integer >= {low}, got {v!r}")
        if self.solver not in SOLVERS:
            raise ConfigError(f"slam.graph.solver must be one of {', '.join(SOLVERS)}, got {self.solver!r}")


@dataclass
class SlamConfig:
    """HS-SLAM parameters (lengths in metres, angles in radians).

    Attributes
    ----------
    dof : int
        3 (x, y, yaw from the 2D scans) or 6 (x, y, z, roll, pitch, yaw from the 3D clouds).
    registration : RegistrationConfig
        Harmony-ICP parameters of the tracking; its ranges are the half-widths of the search box around the seeds.
    use_odometry : bool
        Seed the search with the odometry prediction when the input has odometry.
    prior_translation_range, prior_yaw_range : float
        Half-widths of the search box instead when a 6-DOF run is seeded by a prior (2D) trajectory.
    sync_tolerance : float
        Seconds: a frame takes the prior's pose interpolated between the poses just before and after its stamp
        when both lie within this time of it.
    recent_poses : int
        How many recent poses the "mean of recent poses" seed averages.
    warmup_frames : int
        The first frames are all keyframes.
    map_voxel : float or None
        Voxel size of the point map; None: 0.05 m (2D), 0.1 m (3D).
    map_average : bool
        Each voxel of the map holds the mean of the keyframe points in it (else the first keyframe's point).
    scan_voxel : float or None
        Voxel size the scans are downsampled to before registration; None: 0.03 m (2D), 0.15 m (3D).
    local_map_radius : float
        Radius of the local map (the registration target) around the robot.
    keyframe_distance, keyframe_angle : float or None
        A frame becomes a keyframe (added to the map) when the robot moved or turned this much since the last one;
        None: 0.5 m and 15 deg (2D), 1 m and 30 deg (3D, whose sweeps overlap over more of a move or a turn).
    min_range, max_range : float
        Points of the scans outside [min_range, max_range] from the sensor are ignored.
    odometry_sigma : tuple of 5 floats
        Wheel odometry's uncertainty over one frame, (a [m], b, c [rad], d, e [rad/m]): translation sigma
        a + b * distance, rotation sigma c + d * |turn| + e * distance.
    learn_odometry : bool
        Learn the odometry's bias and the scale of its sigma model as the run goes (``odometry_model`` of the
        metrics); the fusion down-weights a prediction beyond the chi-square 99.9 % gate (a wheel slip).
    odometry_window : int
        Disagreements with the registrations that set the scale (1 until a tenth of them are in) and the bias.
    odometry_lag : int
        Frames between the two registrations whose motion is compared with the odometry's for the scale.
    odometry_scale_bounds : tuple of 2 floats
        The learned scale stays within these bounds.
    motion_sigma : tuple of 5 floats
        As ``odometry_sigma``, for the constant-velocity prediction (no odometry).
    prior_sigma : tuple of 5 floats
        As ``odometry_sigma``, for the motion of a prior trajectory (a 6-DOF run seeded by a 2D run).
    degenerate_ratio : float
        Translation directions with less than this fraction of the best constrained one's information count as
        unconstrained (:func:`hsmap.registration.icp.drop_degenerate`): the prediction carries the pose along them.
    verify_sigmas : float
        A registration further than this many sigmas from the prediction is retried around the prediction.
    motion_window : int
        6-DOF runs without a prior: the last this many frames' motions set the search box, which is widened per
        axis to ``verify_sigmas`` times the RMS change between consecutive motions (the error of the
        constant-velocity prediction) where that exceeds the configured ranges (a sensor carried by hand).
    min_inlier_share : float
        6-DOF runs without a prior: a registration whose inlier ratio is below this share of the median of the
        recent confirmed frames', or below that median by more than ``verify_sigmas`` times their spread, is
        searched again in wider boxes (``widen_factors``); of every candidate of the frame, the one that aligns
        the scan best is kept, and is not a keyframe unless it passes this check or two searches agree on it.
    widen_factors : tuple of floats
        The search box's half-widths are multiplied by these in turn (1: the same box searched again, longer;
        each search is refined) for a registration that fails the inlier check, until one passes (or, above
        ``min_inlier_share`` of the median, two searches agree).
    global_search : bool
        6-DOF runs without a prior: a registration below ``min_inlier_share`` of the median in every widened box
        is searched over the rest of the yaw circle (:meth:`hsmap.slam.search.SearchBox.widened`), in sectors as
        wide as the widest box, before it is given up (a turn faster than the motion predicts).
    loop_closure : LoopClosureConfig
        Loop-closure candidates, matching and verification.
    graph : KeyframeGraphConfig
        When the keyframe graph gains edges, searches for loops and is optimised.
    smoothing : bool
        2D runs with wheel odometry: the final trajectory is smoothed with the odometry
        (:func:`hsmap.slam.smoothing.smooth_with_odometry`); the map stays the graph's.
    deskew : bool
        Clouds with per-point times (6-DOF, :mod:`hsmap.deskew`) and 2D scans with beam times (3-DOF,
        :mod:`hsmap.deskew2d`) are moved to their stamps before use.
    level_floor : bool
        6-DOF runs seeded by a 2D run: every keyframe's height, roll and pitch are held to the first pose's by a
        unary edge of the pose graph (sigmas ``hsmap.slam.tracker.FLOOR_SIGMA``), as for a robot on one level
        floor; off for ramps and runs across floors.
    """

    dof: int = 3
    registration: RegistrationConfig = field(default_factory=_tracking_registration)
    use_odometry: bool = True
    prior_translation_range: float = 0.15
    prior_yaw_range: float = np.deg2rad(4.0)
    sync_tolerance: float = 0.1
    recent_poses: int = 5
    warmup_frames: int = 3
    map_voxel: float | None = None
    map_average: bool = True
    scan_voxel: float | None = None
    local_map_radius: float = 20.0
    keyframe_distance: float | None = None
    keyframe_angle: float | None = None
    min_range: float = 0.1
    max_range: float = 30.0
    odometry_sigma: tuple[float, ...] = (0.02, 0.05, float(np.deg2rad(1.0)), 0.05, float(np.deg2rad(1.0)))
    learn_odometry: bool = True
    odometry_window: int = 400
    odometry_lag: int = 16
    odometry_scale_bounds: tuple[float, float] = (0.1, 5.0)
    motion_sigma: tuple[float, ...] = (0.1, 0.5, float(np.deg2rad(5.0)), 0.5, float(np.deg2rad(5.0)))
    prior_sigma: tuple[float, ...] = (0.01, 0.02, float(np.deg2rad(0.2)), 0.02, float(np.deg2rad(0.5)))
    verify_sigmas: float = 3.0
    motion_window: int = 10
    min_inlier_share: float = 0.85
    widen_factors: tuple[float, ...] = (1.0, 2.0, 4.0)
    global_search: bool = True
    degenerate_ratio: float = 0.05
    loop_closure: LoopClosureConfig = field(default_factory=LoopClosureConfig)
    graph: KeyframeGraphConfig = field(default_factory=KeyframeGraphConfig)

    #: Keys a configuration file may still give at their earlier place (that place -> the key), read with a warning.
    MOVED_KEYS: ClassVar[dict[str, str]] = {
        f"graph.{name}": f"loop_closure.{name}" for name in ("attempts_per_keyframe", "search_every", "far_every")}
    smoothing: bool = True
    deskew: bool = True
    level_floor: bool = True

    def __post_init__(self) -> None:
        if self.dof not in (3, 6):
            raise ConfigError(f"slam.dof must be 3 (2D scans) or 6 (3D clouds), got {self.dof!r}")
        if isinstance(self.registration, dict):
            self.registration = from_dict(RegistrationConfig, self.registration, "slam.registration")
        if isinstance(self.loop_closure, dict):
            self.loop_closure = from_dict(LoopClosureConfig, self.loop_closure, "slam.loop_closure")
        if isinstance(self.graph, dict):
            self.graph = from_dict(KeyframeGraphConfig, self.graph, "slam.graph")
        for name in ("odometry_sigma", "motion_sigma", "prior_sigma"):
            v = getattr(self, name)
            try:
                arr = np.asarray(v, dtype=float)
            except (TypeError, ValueError):
                arr = np.array([])
            if arr.shape != (5,) or not np.all(np.isfinite(arr)) or np.any(arr < 0) or arr[0] <= 0 or arr[2] <= 0:
                # a and c > 0: a robot standing still has a finite information
                raise ConfigError(f"slam.{name} must be 5 finite numbers >= 0, the first and third > 0 (a [m], "
                                  f"b, c [rad], d, e [rad/m]), got {v!r}")
            setattr(self, name, tuple(float(x) for x in arr))
        for name in ("verify_sigmas", "degenerate_ratio"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ConfigError(f"slam.{name} must be a finite number > 0, got {v!r}")
        for name in ("prior_translation_range", "prior_yaw_range", "sync_tolerance", "local_map_radius",
                     "keyframe_distance", "keyframe_angle", "min_range", "max_range"):
            v = getattr(self, name)
            if v is None and name.startswith("keyframe_"):
                continue
            if not (np.isfinite(v) and v >= 0):
                raise ConfigError(f"slam.{name} must be a finite number >= 0, got {v!r}")
        if self.max_range <= self.min_range:
            raise ConfigError(f"slam.max_range ({self.max_range}) must exceed slam.min_range ({self.min_range})")
        lo_hi = np.asarray(self.odometry_scale_bounds, dtype=float)
        if lo_hi.shape != (2,) or not np.all(np.isfinite(lo_hi)) or not 0 < lo_hi[0] <= lo_hi[1]:
            raise ConfigError(f"slam.odometry_scale_bounds must be two numbers 0 < low <= high, got "
                              f"{self.odometry_scale_bounds!r}")
        self.odometry_scale_bounds = (float(lo_hi[0]), float(lo_hi[1]))
        if not (np.isfinite(self.min_inlier_share) and 0 <= self.min_inlier_share <= 1):
            raise ConfigError(f"slam.min_inlier_share must be a number in [0, 1], got {self.min_inlier_share!r}")
        try:
            widen = np.asarray(self.widen_factors, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            widen = np.array([np.nan])
        if not np.all(np.isfinite(widen)) or np.any(widen < 1) or len(widen) > 8:
            raise ConfigError(f"slam.widen_factors must be at most 8 finite numbers >= 1, got {self.widen_factors!r}")
        self.widen_factors = tuple(float(x) for x in widen)
        for name in ("recent_poses", "warmup_frames", "odometry_window", "odometry_lag", "motion_window"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or v < 1:
                raise ConfigError(f"slam.{name} must be an integer >= 1, got {v!r}")
        for name in ("map_voxel", "scan_voxel"):
            v = getattr(self, name)
            if v is not None and not (np.isfinite(v) and v > 0):
                raise ConfigError(f"slam.{name} must be None or > 0, got {v!r}")

    @property
    def dim(self) -> int:
        """2 (3-DOF) or 3 (6-DOF): the dimension of the points."""
        return 2 if self.dof == 3 else 3

    def effective_map_voxel(self) -> float:
        """``map_voxel`` or its default for the dof."""
        return self.map_voxel or (0.05 if self.dof == 3 else 0.1)

    def effective_keyframe_distance(self) -> float:
        """``keyframe_distance`` or its default for the dof."""
        return self.keyframe_distance if self.keyframe_distance is not None else (0.5 if self.dof == 3 else 1.0)

    def effective_keyframe_angle(self) -> float:
        """``keyframe_angle`` or its default for the dof."""
        return (self.keyframe_angle if self.keyframe_angle is not None
                else float(np.deg2rad(15.0 if self.dof == 3 else 30.0)))

    def effective_scan_voxel(self) -> float:
        """``scan_voxel`` or its default for the dof."""
        return self.scan_voxel or (0.03 if self.dof == 3 else 0.15)
