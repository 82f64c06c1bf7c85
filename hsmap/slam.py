"""HS-SLAM (the paper's Algorithm 3): scan-to-map Harmony-ICP in 2D (3-DOF) and 3D (6-DOF).

Each new scan is registered with :func:`hsmap.harmony_icp` against the previous scans for the first frames
(``warmup_frames``, all keyframes) and then against a bounded local map around the robot (a crop of a
voxel-hashed point map, :class:`hsmap.mapping.VoxelMap`, whose points carry normals computed when they were
inserted). The harmony memory is seeded with

- the previous pose,
- a constant-velocity prediction (the last motion repeated),
- the odometry prediction (the previous pose moved by the odometry increment), when the input has odometry and
  ``use_odometry`` is on,
- the mean of the recent poses,
- in 6-DOF, optionally, a prior pose from a 2D run at the same stamp (the paper seeds its 3D run with the 2D
  poses) with a narrower range,

and the search box spans the seeds plus a range around them. Scans are added to the map at keyframes (the robot
moved or turned enough since the last one); a keyframe's new points are splatted into the search distance field
(a window around the robot, rebuilt from the map only when the robot nears its edge) and the refinement's KD-tree
over the local map is rebuilt before the next registration.

:class:`HsSlam` processes frames one by one; :func:`run_slam` runs a whole dataset and returns a
:class:`SlamResult`; :func:`write_slam_outputs` writes ``trajectory.tum``, ``map.ply``, ``metrics.json`` and
``config.yaml`` atomically.
"""

from __future__ import annotations

import resource
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ._blas import blas_limited
from .config import dump_config, to_dict
from .datasets.frames import Dataset, Frame
from .errors import ConfigError, EmptyInputError, InputError
from .fitness import DistanceField
from .geometry import compose, pose_to_matrix, relative, transform_points, wrap_angle
from .harmony import HarmonyConfig, as_rng
from .io import atomic_path, write_json
from .mapping import VoxelMap, voxel_downsample
from .registration import (
    RegistrationConfig,
    RegistrationTarget,
    estimate_normals,
    harmony_icp,
)
from .trajectory import Trajectory, write_tum

__all__ = ["SlamConfig", "FrameResult", "SlamResult", "HsSlam", "run_slam", "write_slam_outputs",
           "frame_points"]


def _tracking_registration() -> RegistrationConfig:
    return RegistrationConfig(
        harmony=HarmonyConfig(batch_size=16, max_iterations=500, patience=15, convergence_tol=1e-6, init="lhs"),
        search_threshold=0.3,
        threshold=0.1,
        max_points=150,
        robust_kernel=0.07,
        translation_range=0.4,
        yaw_range=np.deg2rad(20.0),
        z_range=0.05,
        roll_pitch_range=np.deg2rad(2.0),
    )


@dataclass
class SlamConfig:
    """HS-SLAM parameters (lengths in metres, angles in radians).

    Attributes
    ----------
    dof : int
        3 (x, y, yaw from the 2D scans) or 6 (x, y, z, roll, pitch, yaw from the 3D clouds).
    registration : RegistrationConfig
        Harmony-ICP parameters for tracking; its ``translation_range``, ``yaw_range``, ``z_range`` and
        ``roll_pitch_range`` are the half-widths of the search box around the seeds.
    use_odometry : bool
        Seed the memory with the odometry prediction when the input has odometry.
    prior_translation_range, prior_yaw_range : float
        Half-widths used instead when a 6-DOF run is seeded by prior (2D) poses.
    recent_poses : int
        How many recent poses the "mean of recent poses" seed averages.
    warmup_frames : int
        The first frames are all keyframes: each is registered against all the previous scans.
    map_voxel : float or None
        Voxel size of the point map; None: 0.05 m (2D), 0.1 m (3D).
    scan_voxel : float or None
        Voxel size the scans are downsampled to before registration; None: 0.03 m (2D), 0.15 m (3D).
    local_map_radius : float
        Radius of the local map (the registration target) around the robot.
    keyframe_distance, keyframe_angle : float
        A scan becomes a keyframe (added to the map) when the robot moved or turned this much since the last one.
    min_range, max_range : float
        Points of the scans outside [min_range, max_range] from the sensor are ignored.
    """

    dof: int = 3
    registration: RegistrationConfig = field(default_factory=_tracking_registration)
    use_odometry: bool = True
    prior_translation_range: float = 0.15
    prior_yaw_range: float = np.deg2rad(4.0)
    recent_poses: int = 5
    warmup_frames: int = 3
    map_voxel: float | None = None
    scan_voxel: float | None = None
    local_map_radius: float = 20.0
    keyframe_distance: float = 0.5
    keyframe_angle: float = np.deg2rad(15.0)
    min_range: float = 0.1
    max_range: float = 30.0

    def __post_init__(self) -> None:
        if self.dof not in (3, 6):
            raise ConfigError(f"slam.dof must be 3 (2D scans) or 6 (3D clouds), got {self.dof!r}")
        if isinstance(self.registration, dict):
            from .config import from_dict

            self.registration = from_dict(RegistrationConfig, self.registration, "slam.registration")
        for name in ("prior_translation_range", "prior_yaw_range", "local_map_radius", "keyframe_distance",
                     "keyframe_angle", "min_range", "max_range"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ConfigError(f"slam.{name} must be a finite number >= 0, got {v!r}")
        if self.max_range <= self.min_range:
            raise ConfigError(f"slam.max_range ({self.max_range}) must exceed slam.min_range ({self.min_range})")
        for name in ("recent_poses", "warmup_frames"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or v < 1:
                raise ConfigError(f"slam.{name} must be an integer >= 1, got {v!r}")
        for name in ("map_voxel", "scan_voxel"):
            v = getattr(self, name)
            if v is not None and not (np.isfinite(v) and v > 0):
                raise ConfigError(f"slam.{name} must be None or > 0, got {v!r}")

    @property
    def dim(self) -> int:
        return 2 if self.dof == 3 else 3

    def effective_map_voxel(self) -> float:
        return self.map_voxel or (0.05 if self.dof == 3 else 0.1)

    def effective_scan_voxel(self) -> float:
        return self.scan_voxel or (0.03 if self.dof == 3 else 0.15)


@dataclass
class FrameResult:
    """What HS-SLAM did with one frame."""

    index: int
    stamp: float
    pose: NDArray[np.float64]
    fitness: float
    inlier_ratio: float
    rmse: float
    evaluations: int
    seconds: float
    keyframe: bool
    points: int
    map_points: int


@dataclass
class SlamResult:
    """A whole run: the trajectory, the map, per-frame results and totals."""

    trajectory: Trajectory
    map: VoxelMap
    frames: list[FrameResult]
    config: SlamConfig
    seconds: float
    peak_memory_mb: float
    input_name: str = ""
    cpu_seconds: float = float("nan")

    def metrics(self) -> dict:
        """Per-frame and total metrics, JSON-ready."""
        secs = np.array([f.seconds for f in self.frames])
        duration = float(self.trajectory.stamps.max() - self.trajectory.stamps.min()) if len(self.frames) else 0.0
        return {
            "input": self.input_name,
            "dof": self.config.dof,
            "frames": len(self.frames),
            "keyframes": int(sum(f.keyframe for f in self.frames)),
            "map_points": len(self.map),
            "seconds_total": self.seconds,
            "cpu_seconds_total": self.cpu_seconds,
            "seconds_per_frame_median": float(np.median(secs)) if len(secs) else None,
            "seconds_per_frame_p95": float(np.percentile(secs, 95)) if len(secs) else None,
            "input_duration_s": duration,
            "real_time_factor": duration / self.seconds if self.seconds > 0 else None,
            "peak_memory_mb": self.peak_memory_mb,
            "inlier_ratio_median": float(np.median([f.inlier_ratio for f in self.frames])) if self.frames else None,
            "per_frame": {
                "index": [f.index for f in self.frames],
                "stamp": [f.stamp for f in self.frames],
                "seconds": secs.tolist(),
                "fitness": [f.fitness for f in self.frames],
                "inlier_ratio": [f.inlier_ratio for f in self.frames],
                "rmse": [f.rmse for f in self.frames],
                "evaluations": [f.evaluations for f in self.frames],
                "keyframe": [f.keyframe for f in self.frames],
                "points": [f.points for f in self.frames],
            },
        }


def frame_points(frame: Frame, dof: int, min_range: float = 0.0, max_range: float = np.inf,
                 voxel: float | None = None) -> NDArray[np.float64]:
    """The frame's scan (dof 3) or cloud (dof 6) as points in the robot base frame, range-filtered.

    With ``voxel``, the points are downsampled (voxel centroids, in the sensor frame) in the same pass, before
    they are moved to the base frame.
    """
    if dof == 3:
        if frame.scan2d is None:
            raise InputError(f"frame {frame.index} (stamp {frame.stamp}) has no 2D scan: a 3-DOF run needs them")
        pts = frame.scan2d.points()
        ext = np.asarray(frame.extrinsic2d, dtype=float)
    else:
        if frame.cloud3d is None:
            raise InputError(f"frame {frame.index} (stamp {frame.stamp}) has no 3D cloud: a 6-DOF run needs them")
        pts = np.asarray(frame.cloud3d, dtype=float)
        ext = np.asarray(frame.extrinsic3d, dtype=float)
    if voxel is not None:
        pts = voxel_downsample(pts, voxel, min_range, max_range)
    else:
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        r = np.linalg.norm(pts, axis=1)
        pts = pts[(r >= min_range) & (r <= max_range)]
    if np.any(ext != 0):
        pts = transform_points(pose_to_matrix(ext), pts)
    return pts


def _mean_pose(poses: NDArray[np.float64]) -> NDArray[np.float64]:
    dim = 2 if poses.shape[1] == 3 else 3
    out = poses.mean(axis=0)
    ang = poses[:, dim:]
    out[dim:] = np.arctan2(np.sin(ang).mean(0), np.cos(ang).mean(0))
    return out


class HsSlam:
    """Incremental HS-SLAM: call :meth:`process` with each frame in order.

    Parameters
    ----------
    config : SlamConfig, optional
    rng : int or numpy.random.Generator, optional
        Seed for every random choice (default 0).
    initial_pose : array_like of shape (dof,), optional
        Pose of the first frame (default: the origin).
    prior : Trajectory, optional
        6-DOF only: (x, y, yaw) poses from a 2D run, looked up by stamp, used as seeds with a narrower range.
    """

    def __init__(self, config: SlamConfig | None = None, *, rng: int | np.random.Generator | None = None,
                 initial_pose: NDArray[np.float64] | None = None, prior: Trajectory | None = None) -> None:
        self.config = config or SlamConfig()
        cfg = self.config
        self.rng = as_rng(rng)
        self.dim = cfg.dim
        self.map = VoxelMap(self.dim, cfg.effective_map_voxel())
        self.poses: list[NDArray[np.float64]] = []
        self.stamps: list[float] = []
        self.results: list[FrameResult] = []
        self._initial = None if initial_pose is None else np.asarray(initial_pose, dtype=float)
        if self._initial is not None and self._initial.shape != (cfg.dof,):
            raise InputError(f"initial_pose must have {cfg.dof} values, got shape {self._initial.shape}")
        self._prior = None
        if prior is not None:
            if cfg.dof != 6:
                raise InputError("a prior trajectory seeds 6-DOF runs only (dof=6)")
            self._prior = prior.as_3dof()
        self._target: RegistrationTarget | None = None
        self._field: DistanceField | None = None
        self._field_centre = np.zeros(self.dim)
        self._last_key: NDArray[np.float64] | None = None
        self._prev_odom: NDArray[np.float64] | None = None

    # --------------------------------------------------------------------------------------------- seeds
    def _prior_pose(self, stamp: float) -> NDArray[np.float64] | None:
        if self._prior is None:
            return None
        poses, found = self._prior.at([stamp], max_dt=1e-3)
        if not found[0]:
            return None
        (x, y, yaw), prev = poses[0], self.poses[-1]
        return np.array([x, y, prev[2], prev[3], prev[4], yaw])

    def seeds(self, frame: Frame) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Initial guesses (K, dof) for ``frame`` and the half-widths (dof,) of the box around them."""
        cfg = self.config
        prev = self.poses[-1]
        seeds = [prev]
        if len(self.poses) >= 2:
            seeds.append(compose(prev, relative(self.poses[-2], prev)))
        odom = None if frame.odometry is None else np.asarray(frame.odometry, dtype=float)
        if cfg.use_odometry and odom is not None and self._prev_odom is not None:
            delta = relative(self._prev_odom, odom)  # (x, y, yaw) increment in the robot frame
            if cfg.dof == 3:
                seeds.append(compose(prev, delta))
            else:
                seeds.append(compose(prev, np.array([delta[0], delta[1], 0.0, 0.0, 0.0, delta[2]])))
        if len(self.poses) >= 2:
            seeds.append(_mean_pose(np.asarray(self.poses[-cfg.recent_poses:])))
        half = self._ranges(prior=False)
        prior = self._prior_pose(frame.stamp)
        if prior is not None:
            seeds = [prior, *seeds]
            half = self._ranges(prior=True)
        s = np.asarray(seeds)
        # unwrap angles next to the previous pose so that the box is continuous across +/- pi
        s[:, self.dim:] = prev[self.dim:] + wrap_angle(s[:, self.dim:] - prev[self.dim:])
        return s, half

    def _ranges(self, prior: bool) -> NDArray[np.float64]:
        cfg, reg = self.config, self.config.registration
        t = cfg.prior_translation_range if prior else reg.translation_range
        y = cfg.prior_yaw_range if prior else reg.yaw_range
        if cfg.dof == 3:
            return np.array([t, t, y])
        return np.array([t, t, reg.z_range, reg.roll_pitch_range, reg.roll_pitch_range, y])

    # ---------------------------------------------------------------------------------------------- loop
    def process(self, frame: Frame) -> FrameResult:
        """Register one frame and update the map; returns what was done."""
        t0 = time.perf_counter()
        cfg = self.config
        scan = frame_points(frame, cfg.dof, cfg.min_range, cfg.max_range, voxel=cfg.effective_scan_voxel())
        if len(scan) < 3 * cfg.dim:
            raise EmptyInputError(f"frame {frame.index} (stamp {frame.stamp}) has {len(scan)} usable points "
                                  f"within {cfg.min_range}..{cfg.max_range} m; at least {3 * cfg.dim} needed")
        first = not self.poses
        fitness = inlier = rmse = 0.0
        evaluations = 0
        if first:
            pose = self._initial if self._initial is not None else np.zeros(cfg.dof)
            fitness, inlier, rmse = 0.0, 1.0, 0.0
        else:
            if self._target is None:
                self._rebuild_target()
            guesses, half = self.seeds(frame)
            bounds = np.column_stack([guesses.min(0) - half, guesses.max(0) + half])
            res = harmony_icp(scan, self._target, bounds=bounds, initial_guesses=guesses,
                              config=cfg.registration, rng=self.rng)
            pose = res.pose
            fitness, inlier, rmse, evaluations = res.fitness, res.inlier_ratio, res.rmse, res.evaluations
        keyframe = first or len(self.poses) < cfg.warmup_frames or self._is_keyframe(pose)
        if keyframe:
            self._insert(frame, scan, pose)
        self.poses.append(pose)
        self.stamps.append(float(frame.stamp))
        if frame.odometry is not None:
            self._prev_odom = np.asarray(frame.odometry, dtype=float)
        result = FrameResult(frame.index, float(frame.stamp), pose, float(fitness), float(inlier), float(rmse),
                             int(evaluations), time.perf_counter() - t0, bool(keyframe), len(scan), len(self.map))
        self.results.append(result)
        return result

    def _is_keyframe(self, pose: NDArray[np.float64]) -> bool:
        cfg = self.config
        d = relative(self._last_key, pose)
        return bool(np.linalg.norm(d[: self.dim]) >= cfg.keyframe_distance
                    or np.abs(wrap_angle(d[self.dim:])).max() >= cfg.keyframe_angle)

    def _insert(self, frame: Frame, scan: NDArray[np.float64], pose: NDArray[np.float64]) -> None:
        """Add a keyframe to the map (with normals from its own neighbourhoods) and to the search field."""
        cfg = self.config
        T = pose_to_matrix(pose)
        dense = scan if cfg.dof == 3 else frame_points(frame, cfg.dof, cfg.min_range, cfg.max_range,
                                                       voxel=cfg.effective_map_voxel())
        world = transform_points(T, dense)
        added = self.map.add(world, estimate_normals(world))
        if self._field is not None and len(added):
            self._field.add(added)
        self._last_key = pose
        self._target = None  # the refinement target (KD-tree) is rebuilt before the next registration

    def _rebuild_target(self) -> None:
        """The registration target: the local map crop (points, normals) and the search field around the robot."""
        cfg = self.config
        reg = cfg.registration
        centre = self.poses[-1][: self.dim]
        pts, normals = self.map.crop_with_normals(centre, cfg.local_map_radius)
        if self._field is None or np.linalg.norm(centre[:2] - self._field_centre[:2]) > cfg.local_map_radius / 2:
            half = cfg.local_map_radius + reg.search_threshold
            lo = np.r_[centre[:2] - half, pts[:, 2].min() - 1.0] if self.dim == 3 else centre[:2] - half
            hi = np.r_[centre[:2] + half, pts[:, 2].max() + 1.0] if self.dim == 3 else centre[:2] + half
            res = reg.field_resolution or (max(0.02, reg.search_threshold / 10) if self.dim == 2
                                           else reg.search_threshold / 3)
            self._field = DistanceField(pts, res, reg.search_threshold, bounds=[lo, hi])
            self._field_centre = centre.copy()
        self._target = RegistrationTarget(pts, reg, normals=normals, fields={reg.search_threshold: self._field})

    @property
    def trajectory(self) -> Trajectory:
        return Trajectory(np.asarray(self.stamps), np.asarray(self.poses).reshape(-1, self.config.dof))


@blas_limited
def run_slam(
    dataset: Dataset | Iterable[Frame],
    config: SlamConfig | None = None,
    *,
    rng: int | np.random.Generator | None = None,
    initial_pose: NDArray[np.float64] | None = None,
    prior: Trajectory | None = None,
    max_frames: int | None = None,
    progress: bool | None = None,
    on_frame: Callable[[Frame, FrameResult, HsSlam], None] | None = None,
) -> SlamResult:
    """Run HS-SLAM over a dataset (or any iterable of frames).

    Parameters
    ----------
    dataset : Dataset or iterable of Frame
    config : SlamConfig, optional
    rng : int or Generator, optional
    initial_pose : array_like, optional
        Pose of the first frame (default: origin).
    prior : Trajectory, optional
        6-DOF: 2D poses used as seeds.
    max_frames : int, optional
        Stop after this many frames.
    progress : bool or None
        Show a progress bar; None shows it only on a terminal.
    on_frame : callable, optional
        Called after each frame with (frame, result, slam), e.g. to log to rerun.
    """
    from tqdm.auto import tqdm

    slam = HsSlam(config, rng=rng, initial_pose=initial_pose, prior=prior)
    dof = slam.config.dof
    frames = dataset.frames(clouds=dof == 6) if isinstance(dataset, Dataset) else iter(dataset)
    total = len(dataset) if isinstance(dataset, Dataset) else None
    if max_frames is not None:
        total = min(total, max_frames) if total is not None else max_frames
    t0, c0 = time.perf_counter(), time.process_time()
    bar = tqdm(total=total, unit="scan", disable=None if progress is None else not progress,
               desc=f"HS-SLAM {slam.config.dof}-DOF")
    try:
        for k, frame in enumerate(frames):
            if max_frames is not None and k >= max_frames:
                break
            res = slam.process(frame)
            if on_frame is not None:
                on_frame(frame, res, slam)
            bar.update(1)
    finally:
        bar.close()
    if not slam.poses:
        raise EmptyInputError("the input has no frames")
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return SlamResult(slam.trajectory, slam.map, slam.results, slam.config, time.perf_counter() - t0, peak,
                      getattr(dataset, "name", ""), time.process_time() - c0)


def write_slam_outputs(result: SlamResult, out_dir: str | Path) -> dict[str, Path]:
    """Write ``trajectory.tum``, ``map.ply``, ``metrics.json`` and ``config.yaml`` into ``out_dir`` atomically.

    ``metrics.json`` is written last: a folder without it is incomplete.
    """
    import open3d as o3d

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"trajectory": out / "trajectory.tum", "map": out / "map.ply", "config": out / "config.yaml",
             "metrics": out / "metrics.json"}
    write_tum(paths["trajectory"], result.trajectory)
    pts = result.map.points
    if pts.shape[1] == 2:
        pts = np.column_stack([pts, np.zeros(len(pts))])
    with atomic_path(paths["map"]) as tmp:
        if not o3d.io.write_point_cloud(str(tmp), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))):
            raise OSError(f"open3d could not write {paths['map']}")
    dump_config(result.config, paths["config"])
    metrics = result.metrics()
    metrics["config"] = to_dict(result.config)
    write_json(paths["metrics"], metrics)
    return paths
