"""Maps of the study: a dataset's scans or clouds placed at a trajectory's poses, and the 2D and 3D maps of one
simulated run shared by notebooks 04-07 (computed once, then cached).

:func:`point_maps` / :func:`point_map` / :func:`scan_grid` place a dataset's frames at the poses of any trajectory
(the SLAM map, the odometry-only map of the paper's Figures 2 and 8, the reference map at the true poses);
:func:`map_distances` measures how far one map lies from another.

:func:`two_lidar_maps` runs the paper's pipeline on a simulated run:

1. the simulated dataset and its HS-SLAM runs (:func:`hsmap.study.runs.simulated_slam_runs`: 2D, 3-DOF on the
   floor-level LiDAR, and 6-DOF on the 3D LiDAR seeded by the 2D poses, as in the paper; without odometry by
   default, the paper's claim; both started at the first ground-truth pose so that their maps share the world
   frame of the ground truth, its rooms, doors and labels);
2. the maps made from them: the 2D and 3D HS-SLAM point maps, the floor-level occupancy grid (every 2D scan at
   its 2D HS-SLAM pose, :func:`hsmap.maps.grid.grid_from_scans`) and the grid of the 3D map's slice at 1.7-1.8 m
   (every 3D cloud at its 6-DOF HS-SLAM pose, :func:`hsmap.maps.fusion.slice_scans`), with the points behind both.

The maps are a folder of :class:`hsmap.pipeline.cache.FolderCache` under ``data/generated/maps/`` (``maps.npz``),
keyed on the dataset, the SLAM runs' keys, the grid parameters and the code; the SLAM runs are the cached runs
every other notebook shares.

``two_lidar_maps(dataset=PATH)`` makes the same maps of a recording instead of a scenario: any input
:func:`hsmap.datasets.open.open_dataset` reads (a folder written by ``hsmap simulate``, a ROS1 or ROS2 bag, ...)
with 2D scans and 3D clouds. Its 2D and 6-DOF HS-SLAM runs (the 6-DOF one seeded by the 2D poses) use the
command line's default configuration (``hsmap slam``: the odometry when the recording has it) and start at its
first ground-truth pose when it has a ground truth (a simulator folder), else at the origin. A recording without
ground truth has no true rooms or doors (:meth:`TwoLidarMaps.true_doors` is None): the notebooks then show the
maps and their segmentation without scoring them.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from ..datasets.frames import Dataset, Frame
from ..datasets.open import open_dataset
from ..datasets.simulated import SimulatedDataset
from ..errors import InputError
from ..evaluation import segmentation_scores
from ..geometry import pose_to_matrix, transform_points
from ..io import write_json
from ..maps.fusion import resample_grid, slice_scans
from ..maps.grid import GridGeometry, OccupancyGrid, ScanGridConfig, grid_from_scans, scans_to_points
from ..maps.mapping import VoxelMap, first_per_voxel, voxel_downsample
from ..pipeline.cache import FolderCache, description_digest, slug
from ..rooms.segmentation import segment_rooms
from ..slam import SlamConfig, frame_points
from ..trajectory import Trajectory
from .datasets import simulated_dataset
from .paths import generated_dir
from .runs import SimulatedRuns, cached_slam, dataset_fingerprint, simulated_slam_runs

__all__ = ["point_maps", "point_map", "scan_grid", "map_distances", "TwoLidarMaps", "two_lidar_maps",
           "recording_maps", "default_maps_dir", "MapSegmentations", "segment_maps", "door_errors",
           "true_room_names"]


def default_maps_dir() -> Path:
    """``data/generated/maps`` of the repository (``$HSMAP_GENERATED/maps`` when that is set)."""
    return generated_dir() / "maps"


def _frames(dataset: Dataset | Iterable[Frame], clouds: bool, every: int, max_frames: int | None) -> Iterator[Frame]:
    it = dataset.frames(clouds=clouds) if isinstance(dataset, Dataset) else iter(dataset)
    for k, f in enumerate(it):
        if max_frames is not None and k >= max_frames:
            return
        if k % every == 0:
            yield f


def point_maps(
    dataset: Dataset | Iterable[Frame],
    trajectories: Mapping[str, Trajectory],
    *,
    dof: int | None = None,
    voxel: float | None = None,
    every: int = 1,
    max_frames: int | None = None,
    min_range: float = 0.1,
    max_range: float = 30.0,
    max_dt: float = 1e-3,
    block: int = 20,
) -> dict[str, NDArray[np.float64]]:
    """Point maps of ``dataset``'s scans (dof 3) or clouds (dof 6) placed at the poses of each trajectory.

    One pass over the data serves every trajectory (3D clouds are read once). With the SLAM trajectory this is
    the SLAM map; with the odometry (``dataset.odometry``) it is the map the odometry alone would make; with the
    ground truth, the reference map. Frames are matched to poses by stamp; frames without a pose in a trajectory
    are left out of that trajectory's map.

    Parameters
    ----------
    trajectories : mapping of name to Trajectory
        3-DOF trajectories place 3D clouds at z = roll = pitch = 0.
    dof : int, optional
        3 (2D scans) or 6 (3D clouds); default 6 when any trajectory is 6-DOF, else 3.
    voxel : float, optional
        One point per voxel of this size (default 0.05 m in 2D, 0.1 m in 3D, like the SLAM maps).
    every : int
        Use every n-th frame.
    block : int
        Frames whose (per-frame thinned) points are merged into the maps at once.

    Returns
    -------
    dict of name to ndarray of shape (M, 2) or (M, 3)
        World points of each map.
    """
    if not trajectories:
        raise InputError("point_maps needs at least one trajectory")
    if dof is None:
        dof = 6 if any(t.dof == 6 for t in trajectories.values()) else 3
    dof = int(dof)
    if dof not in (3, 6):
        raise InputError(f"dof must be 3 (2D scans) or 6 (3D clouds), got {dof}")
    if int(every) < 1 or int(block) < 1:
        raise InputError(f"every and block must be >= 1, got {every} and {block}")
    vox = voxel or (0.05 if dof == 3 else 0.1)
    trajs = {k: (t.as_6dof() if dof == 6 else t.as_3dof()) for k, t in trajectories.items()}
    maps = {k: VoxelMap(2 if dof == 3 else 3, vox) for k in trajs}
    pending: dict[str, list[NDArray[np.float64]]] = {k: [] for k in trajs}
    used = dict.fromkeys(trajs, 0)

    def flush() -> None:
        for k, parts in pending.items():
            if parts:
                maps[k].add(np.concatenate(parts))
                parts.clear()

    for n, f in enumerate(_frames(dataset, clouds=dof == 6, every=int(every), max_frames=max_frames)):
        if dof == 6 and f.cloud3d is not None and len(f.cloud3d) > 20000:
            # dense 3D clouds: thin in the sensor frame first (one point per half map voxel), then place
            f = dataclasses.replace(f, cloud3d=first_per_voxel(f.cloud3d, vox / 2))
        pts = frame_points(f, dof, min_range, max_range)
        for k, traj in trajs.items():
            pose, ok = traj.at([f.stamp], max_dt=max_dt)
            if not ok[0]:
                continue
            w = transform_points(pose_to_matrix(pose[0]), pts)
            pending[k].append(first_per_voxel(w, vox))  # thin per frame, same voxels as the map
            used[k] += 1
        if (n + 1) % int(block) == 0:
            flush()
    flush()
    empty = [k for k, c in used.items() if c == 0]
    if empty:
        raise InputError(f"no frame of the dataset has a pose in trajectory {empty[0]!r} (stamps differ?)")
    return {k: m.points for k, m in maps.items()}


def point_map(
    dataset: Dataset | Iterable[Frame],
    trajectory: Trajectory,
    **kwargs: Any,
) -> NDArray[np.float64]:
    """The point map of ``dataset``'s scans or clouds placed at ``trajectory``'s poses (see :func:`point_maps`).

    Returns
    -------
    ndarray of shape (M, 2) or (M, 3)
    """
    return point_maps(dataset, {"map": trajectory}, **kwargs)["map"]


def scan_grid(
    dataset: Dataset | Iterable[Frame],
    trajectory: Trajectory,
    resolution: float = 0.05,
    *,
    every: int = 1,
    max_frames: int | None = None,
    geometry: GridGeometry | None = None,
    config: ScanGridConfig | None = None,
    max_dt: float = 1e-3,
) -> OccupancyGrid:
    """Occupancy grid of ``dataset``'s 2D scans placed at ``trajectory``'s poses (:func:`hsmap.maps.grid.grid_from_scans`).

    Each scan is placed at its robot pose composed with its own 2D extrinsic. With the odometry this is the
    odometry-only map of the paper's Figures 2 and 8 (walls smeared thick by the drift).

    Returns
    -------
    hsmap.maps.grid.OccupancyGrid
    """
    if int(every) < 1:
        raise InputError(f"every must be >= 1, got {every}")
    traj = trajectory.as_3dof()
    scans, poses, extrinsics = [], [], []
    for f in _frames(dataset, clouds=False, every=int(every), max_frames=max_frames):
        if f.scan2d is None:
            raise InputError(f"frame {f.index} has no 2D scan")
        pose, ok = traj.at([f.stamp], max_dt=max_dt)
        if ok[0]:
            scans.append(f.scan2d)
            poses.append(pose[0])
            extrinsics.append(f.extrinsic2d)
    if not scans:
        raise InputError("no frame of the dataset has a pose in the trajectory (stamps differ?)")
    return grid_from_scans(scans, np.asarray(poses), resolution, extrinsic=np.asarray(extrinsics, dtype=float),
                           geometry=geometry, config=config)


def map_distances(points: ArrayLike, reference: ArrayLike) -> NDArray[np.float64]:
    """Distance (m) from each point of a map to the nearest point of a reference map (same dimension).

    With the reference built from the ground-truth poses this measures how far a map's walls lie from where
    they are: centimetres for a good SLAM map, metres for an odometry-only map with thick, doubled walls.

    Parameters
    ----------
    points : ndarray of shape (N, 2) or (N, 3)
    reference : ndarray of shape (M, 2) or (M, 3)

    Returns
    -------
    ndarray of shape (N,)
    """
    p = np.asarray(points, dtype=float)
    r = np.asarray(reference, dtype=float)
    if p.ndim != 2 or r.ndim != 2 or p.shape[1] != r.shape[1] or p.shape[1] not in (2, 3):
        raise InputError(f"points and reference must be (N, 2) or (N, 3) alike, got {p.shape} and {r.shape}")
    if len(r) == 0 or len(p) == 0:
        raise InputError("points and reference must not be empty")
    return cKDTree(r).query(p, k=1)[0]


@dataclass
class TwoLidarMaps:
    """The maps of one simulated run or recording (see the module docstring). World frame = the ground
    truth's, or the first 2D HS-SLAM pose's for a recording without ground truth.

    Attributes
    ----------
    dataset : Dataset
        A SimulatedDataset for a scenario; for a recording, what ``open_dataset`` returned.
    frames : int
        Frames used (the first ``frames`` of the dataset).
    groundtruth : Trajectory or None
        (K, 3) true robot poses (None for a recording without ground truth).
    slam2d : Trajectory
        (K, 3) 2D HS-SLAM poses of the robot base (the true poses with ``poses="groundtruth"``).
    slam3d : Trajectory
        (K, 6) 6-DOF HS-SLAM poses of the robot base (the true poses with ``poses="groundtruth"``).
    map2d : ndarray of shape (N, 2)
        The 2D HS-SLAM map (keyframe scans, one point per 5 cm cell); empty with ``poses="groundtruth"``.
    map3d : ndarray of shape (M, 3)
        The 6-DOF HS-SLAM map (keyframe clouds, one point per 10 cm voxel); empty with ``poses="groundtruth"``.
    floor : OccupancyGrid
        Floor-level grid: every 2D scan at its 2D HS-SLAM pose.
    slice : OccupancyGrid
        Grid of the 3D map's slice ``z_range``: every 3D cloud at its 6-DOF HS-SLAM pose.
    poses : str
        ``"slam"`` or ``"groundtruth"``: the poses the grids were built at.
    floor_points, slice_points : ndarray of shape (K, 2)
        The points behind the two grids (scan end points; virtual slice-scan end points), one per 2 cm cell.
    slice_scans : list of ndarray of shape (K_i, 2)
        The virtual slice scans (:func:`hsmap.maps.fusion.slice_scans`), each in its virtual sensor's frame.
    slice_poses : ndarray of shape (S, 3)
        World (x, y, yaw) of each slice scan's virtual sensor: ``grid_from_scans(slice_scans, poses)`` rebuilds
        the slice grid in any frame.
    z_range : (float, float)
    seconds : dict
        Wall time of each step when it was computed (``slam2d``, ``slam3d``, ``floor``, ``slice``).
    slam_metrics : dict
        Per run (``"2d"``, ``"3d"``): frames, keyframes, seconds, median inlier ratio.
    key : str
    folder : Path
    cached : bool
        True when this call read a stored result.
    """

    dataset: Dataset
    frames: int
    groundtruth: Trajectory | None
    slam2d: Trajectory
    slam3d: Trajectory
    map2d: NDArray[np.float64]
    map3d: NDArray[np.float64]
    floor: OccupancyGrid
    slice: OccupancyGrid
    floor_points: NDArray[np.float64]
    slice_points: NDArray[np.float64]
    slice_scans: list[NDArray[np.float64]]
    slice_poses: NDArray[np.float64]
    z_range: tuple[float, float]
    poses: str = "slam"
    seconds: dict = field(default_factory=dict)
    slam_metrics: dict = field(default_factory=dict)
    key: str = ""
    folder: Path | None = None
    cached: bool = False

    def true_doors(self) -> list[dict] | None:
        """The world's doors (``doors.json`` of a simulated dataset: name, center, width, ...); None when the
        dataset has none (a recording)."""
        return self.dataset.doors() if isinstance(self.dataset, SimulatedDataset) else None

    def true_rooms(self) -> tuple[NDArray[np.uint16], GridGeometry, dict[int, str]] | None:
        """The world's room labels (image, its geometry, label -> name) of a simulated dataset; None without."""
        return self.dataset.labels() if isinstance(self.dataset, SimulatedDataset) else None

    @property
    def sensor2d_height(self) -> float | None:
        """Mounting height (m) of the 2D LiDAR when the dataset says it (the simulator does), else None."""
        sensors = getattr(self.dataset, "sensors", None)
        try:
            return float(sensors["lidar2d"]["mount_height"])
        except (TypeError, KeyError, ValueError):
            return None


def _grid_arrays(prefix: str, g: OccupancyGrid) -> dict[str, np.ndarray]:
    geo = g.geometry
    return {f"{prefix}_data": g.data, f"{prefix}_geometry": np.array([geo.resolution, *geo.origin])}


def _grid_from(z, prefix: str) -> OccupancyGrid:
    data = z[f"{prefix}_data"]
    res, ox, oy = (float(v) for v in z[f"{prefix}_geometry"])
    return OccupancyGrid(data, GridGeometry(data.shape, res, (ox, oy)))


def _thin(points: NDArray[np.float64], voxel: float) -> NDArray[np.float64]:

    return voxel_downsample(np.asarray(points, dtype=float), voxel)


def _slam_summary(run) -> dict:
    m = run.metrics
    return {k: m[k] for k in ("frames", "keyframes", "map_points", "seconds_total", "inlier_ratio_median",
                              "real_time_factor")}


def _compute_maps(ds: SimulatedDataset, n: int, runs: SimulatedRuns | None, z_range: tuple[float, float],
                  resolution: float, bins: int, every: int):
    """The maps' folder writer: ``maps.npz`` (poses, point maps, grids, slice scans) and ``meta.json``."""

    def compute(folder: Path) -> None:

        gt = ds.groundtruth.poses[:n]
        seconds: dict[str, float] = {}
        if runs is not None:
            p2, p3 = runs.run3.trajectory.poses, runs.run6.trajectory.poses
            map2d, map3d = runs.run3.map_points, runs.run6.map_points
            seconds.update(slam2d=runs.run3.seconds, slam3d=runs.run6.seconds)
            slam_metrics = {"2d": _slam_summary(runs.run3), "3d": _slam_summary(runs.run6)}
        else:
            p2 = gt
            p3 = np.column_stack([gt[:, :2], np.zeros((n, 3)), gt[:, 2]])
            map2d, map3d = np.empty((0, 2)), np.empty((0, 3))
            slam_metrics = {}

        t = time.perf_counter()
        idx = np.arange(0, n, every)
        scans = [ds.scan2d(int(i)) for i in idx]
        floor = grid_from_scans(scans, p2[idx], resolution, extrinsic=ds.extrinsic2d)
        floor_pts = _thin(scans_to_points(scans, p2[idx], ds.extrinsic2d), 0.02)
        seconds["floor"] = time.perf_counter() - t
        t = time.perf_counter()
        sscans, spos = slice_scans(ds.frames(stop=n, step=every), p3[idx], z_min=z_range[0], z_max=z_range[1],
                                   bins=bins)
        slice_ = grid_from_scans(sscans, spos, resolution)
        slice_pts = _thin(scans_to_points(sscans, spos), 0.02)
        seconds["slice"] = time.perf_counter() - t
        np.savez(folder / "maps.npz", stamps=ds.stamps[:n], groundtruth=gt, slam2d=p2, slam3d=p3, map2d=map2d,
                 map3d=map3d, floor_points=floor_pts, slice_points=slice_pts,
                 slice_scan_points=np.vstack(sscans) if sscans else np.empty((0, 2)),
                 slice_scan_sizes=np.array([len(a) for a in sscans], dtype=np.int64), slice_poses=spos,
                 **_grid_arrays("floor", floor), **_grid_arrays("slice", slice_))
        write_json(folder / "meta.json", {"seconds": seconds, "slam_metrics": slam_metrics})

    return compute


def _maps_loader(ds: SimulatedDataset, z_range: tuple[float, float], poses: str):
    def load(folder: Path) -> TwoLidarMaps:
        meta = json.loads((folder / "meta.json").read_text(encoding="utf-8"))
        with np.load(folder / "maps.npz") as z:
            stamps = z["stamps"]
            return TwoLidarMaps(
                dataset=ds, frames=len(stamps), groundtruth=Trajectory(stamps, z["groundtruth"]),
                slam2d=Trajectory(stamps, z["slam2d"]), slam3d=Trajectory(stamps, z["slam3d"]),
                map2d=z["map2d"], map3d=z["map3d"], floor=_grid_from(z, "floor"), slice=_grid_from(z, "slice"),
                floor_points=z["floor_points"], slice_points=z["slice_points"],
                slice_scans=np.split(z["slice_scan_points"], np.cumsum(z["slice_scan_sizes"])[:-1]),
                slice_poses=z["slice_poses"], z_range=z_range, poses=poses, seconds=meta["seconds"],
                slam_metrics=meta["slam_metrics"], folder=folder)

    return load


def _compute_recording_maps(dataset, open_kwargs: Mapping[str, Any] | None, n: int, runs: tuple,
                            z_range: tuple[float, float], resolution: float, bins: int, every: int):
    """The maps' folder writer for a recording (any Dataset, matched to the SLAM poses by stamp)."""

    def compute(folder: Path) -> None:

        ds = dataset if isinstance(dataset, Dataset) else open_dataset(dataset, **dict(open_kwargs or {}))
        run3, run6 = runs
        seconds = {"slam2d": run3.seconds, "slam3d": run6.seconds}
        t = time.perf_counter()
        stamps, scans, ext2, idx = [], [], [], []
        for k, f in enumerate(_frames(ds, clouds=False, every=1, max_frames=n)):
            if k % every == 0 and f.scan2d is not None:
                stamps.append(f.stamp)
                scans.append(f.scan2d)
                ext2.append(f.extrinsic2d)
                idx.append(k)
        if not scans:
            raise InputError(f"{ds.name}: no frame with a 2D scan among the first {n}: the floor map needs them")
        stamps_a = np.asarray(stamps, dtype=float)
        p2, ok2 = run3.trajectory.at(stamps_a)
        if not ok2.any():
            raise InputError(f"{ds.name}: no 2D scan has a 2D HS-SLAM pose (stamps differ?)")
        keep2 = np.flatnonzero(ok2)
        floor_scans = [scans[i] for i in keep2]
        ext = np.asarray([ext2[i] for i in keep2], dtype=float)
        floor = grid_from_scans(floor_scans, p2, resolution, extrinsic=ext)
        floor_pts = _thin(scans_to_points(floor_scans, p2, ext), 0.02)
        seconds["floor"] = time.perf_counter() - t

        t = time.perf_counter()
        p3, ok3 = run6.trajectory.at(stamps_a)
        if not ok3.any():
            raise InputError(f"{ds.name}: no frame has a 6-DOF HS-SLAM pose (stamps differ?)")
        wanted = {idx[i] for i in np.flatnonzero(ok3)}
        sliced = (f for k, f in enumerate(_frames(ds, clouds=True, every=1, max_frames=n)) if k in wanted)
        sscans, spos = slice_scans(sliced, p3, z_min=z_range[0], z_max=z_range[1], bins=bins)
        slice_ = grid_from_scans(sscans, spos, resolution)
        slice_pts = _thin(scans_to_points(sscans, spos), 0.02)
        seconds["slice"] = time.perf_counter() - t

        gt = getattr(ds, "groundtruth", None)
        gt_poses, gt_stamps = np.empty((0, 3)), np.empty(0)
        if gt is not None:
            gt_poses, ok = gt.as_3dof().at(stamps_a)
            gt_stamps = stamps_a[ok]
        np.savez(folder / "maps.npz", slam2d_stamps=stamps_a[ok2], slam2d=p2, slam3d_stamps=stamps_a[ok3],
                 slam3d=p3, groundtruth_stamps=gt_stamps, groundtruth=gt_poses, map2d=run3.map_points,
                 map3d=run6.map_points, floor_points=floor_pts, slice_points=slice_pts,
                 slice_scan_points=np.vstack(sscans) if sscans else np.empty((0, 2)),
                 slice_scan_sizes=np.array([len(a) for a in sscans], dtype=np.int64), slice_poses=spos,
                 **_grid_arrays("floor", floor), **_grid_arrays("slice", slice_))
        write_json(folder / "meta.json", {"seconds": seconds, "frames": int(n), "dataset": ds.name,
                                          "slam_metrics": {"2d": _slam_summary(run3), "3d": _slam_summary(run6)}})

    return compute


def _recording_loader(ds: Dataset, z_range: tuple[float, float]):
    def load(folder: Path) -> TwoLidarMaps:
        meta = json.loads((folder / "meta.json").read_text(encoding="utf-8"))
        with np.load(folder / "maps.npz") as z:
            gt = (Trajectory(z["groundtruth_stamps"], z["groundtruth"]) if len(z["groundtruth_stamps"]) else None)
            return TwoLidarMaps(
                dataset=ds, frames=int(meta["frames"]), groundtruth=gt,
                slam2d=Trajectory(z["slam2d_stamps"], z["slam2d"]), slam3d=Trajectory(z["slam3d_stamps"], z["slam3d"]),
                map2d=z["map2d"], map3d=z["map3d"], floor=_grid_from(z, "floor"), slice=_grid_from(z, "slice"),
                floor_points=z["floor_points"], slice_points=z["slice_points"],
                slice_scans=np.split(z["slice_scan_points"], np.cumsum(z["slice_scan_sizes"])[:-1]),
                slice_poses=z["slice_poses"], z_range=z_range, poses="slam", seconds=meta["seconds"],
                slam_metrics=meta["slam_metrics"], folder=folder)

    return load


def recording_maps(
    dataset: str | os.PathLike | Dataset,
    seed: int = 1,
    *,
    max_frames: int | None = None,
    z_range: tuple[float, float] = (1.7, 1.8),
    resolution: float = 0.05,
    slice_bins: int = 720,
    every: int = 1,
    use_odometry: bool | None = None,
    open_kwargs: Mapping[str, Any] | None = None,
    cache_dir: str | os.PathLike | None = None,
) -> TwoLidarMaps:
    """The maps of :func:`two_lidar_maps` made from a recording (see the module docstring).

    Parameters
    ----------
    dataset : path or Dataset
        Anything :func:`hsmap.datasets.open.open_dataset` opens (``open_kwargs`` are its keywords) that has 2D
        scans and 3D clouds.
    use_odometry : bool, optional
        Default: the command line's (:class:`hsmap.slam.SlamConfig`), which uses the odometry when there is one.

    Other parameters are those of :func:`two_lidar_maps`.
    """

    if isinstance(dataset, (str, os.PathLike)) and not str(dataset).strip():
        raise InputError("dataset: empty path")
    if int(every) < 1:
        raise InputError(f"every must be >= 1, got {every}")
    if max_frames is not None and int(max_frames) < 1:
        raise InputError(f"max_frames must be >= 1, got {max_frames}")
    ds = dataset if isinstance(dataset, Dataset) else open_dataset(dataset, **dict(open_kwargs or {}))
    n = len(ds) if max_frames is None else min(int(max_frames), len(ds))
    if n < 1:
        raise InputError(f"{ds.name}: the recording has no frames")
    # the key names the input as given (a path: its contents and options), the runs and maps share it
    src = ds if isinstance(dataset, Dataset) else dataset
    kw = None if isinstance(dataset, Dataset) else open_kwargs
    base = SlamConfig()
    odo = base.use_odometry if use_odometry is None else bool(use_odometry)
    gt = getattr(ds, "groundtruth", None)
    start = None if gt is None else gt.as_3dof().poses[0]
    run3 = cached_slam(src, SlamConfig(dof=3, use_odometry=odo), seed, max_frames=n, initial_pose=start,
                       open_kwargs=kw)
    start6 = None if gt is None else gt.as_6dof().poses[0]
    run6 = cached_slam(src, SlamConfig(dof=6, use_odometry=odo), seed, max_frames=n, initial_pose=start6,
                       prior=run3.trajectory, open_kwargs=kw)
    z = (float(z_range[0]), float(z_range[1]))
    params = {"z_range": list(z), "resolution": float(resolution), "slice_bins": int(slice_bins),
              "every": int(every), "use_odometry": odo, "frames": int(n), "seed": int(seed)}
    desc = {"dataset": dataset_fingerprint(src, kw), "params": params, "slam": [run3.key, run6.key]}
    slot = f"{slug(ds.name.split('.')[0])}-rec-seed{int(seed)}-{n}f-{description_digest(desc)[:16]}"
    cache = FolderCache(cache_dir if cache_dir is not None else default_maps_dir())
    got = cache.get(slot, desc, _compute_recording_maps(src, kw, n, (run3, run6), z, float(resolution),
                                                        int(slice_bins), int(every)),
                    _recording_loader(ds, z))
    return dataclasses.replace(got.value, key=got.key, cached=got.cached)


def two_lidar_maps(
    scenario: str = "two-rooms",
    seed: int = 1,
    *,
    max_frames: int | None = None,
    z_range: tuple[float, float] = (1.7, 1.8),
    resolution: float = 0.05,
    slice_bins: int = 720,
    poses: str = "slam",
    every: int = 1,
    use_odometry: bool = False,
    cache_dir: str | os.PathLike | None = None,
    dataset: str | os.PathLike | Dataset | None = None,
) -> TwoLidarMaps:
    """The 2D and 3D HS-SLAM maps of a simulated run and the grids made from them (see the module docstring).

    Parameters
    ----------
    scenario : str
        A shipped scenario (``two-rooms``, ``slam-office``) or a scenario file.
    dataset : path or Dataset, optional
        A recording to map instead of the scenario (:func:`recording_maps`; empty or None: the scenario). It is
        mapped with HS-SLAM at the command line's defaults (``use_odometry`` does not apply; ``poses`` must be
        ``"slam"``).
    seed : int
        Simulator seed and HS-SLAM seed.
    max_frames : int, optional
        Use only the first frames (quick runs).
    z_range : (float, float)
        The slice of the 3D map (the paper: 1.7-1.8 m).
    resolution : float
        Metres per cell of both grids.
    slice_bins : int
        Azimuth bins of the virtual slice scans.
    poses : str
        ``"slam"`` (the paper's pipeline: HS-SLAM in 2D and 6-DOF) or ``"groundtruth"`` (no SLAM: the grids
        at the true poses; ``slam2d``/``slam3d`` then hold the true poses and ``map2d``/``map3d`` are empty).
    every : int
        Build the grids from every n-th frame (SLAM still runs on all frames).
    use_odometry : bool
        Seed HS-SLAM with the wheel odometry (default no: the paper's claim is that it needs none; notebooks
        01-03 run it without too).
    cache_dir : path, optional
        Default :func:`default_maps_dir`; the SLAM runs stay in the shared run cache.

    Returns
    -------
    TwoLidarMaps
    """

    if poses not in ("slam", "groundtruth"):
        raise InputError(f"poses must be 'slam' or 'groundtruth', got {poses!r}")
    if dataset is not None and (isinstance(dataset, Dataset) or str(dataset).strip()):
        if poses != "slam":
            raise InputError("a recording's maps are made at its HS-SLAM poses: poses must be 'slam'")
        return recording_maps(dataset, seed, max_frames=max_frames, z_range=z_range, resolution=resolution,
                              slice_bins=slice_bins, every=every, cache_dir=cache_dir)
    if int(every) < 1:
        raise InputError(f"every must be >= 1, got {every}")
    z = (float(z_range[0]), float(z_range[1]))
    if poses == "slam":
        runs = simulated_slam_runs(scenario, seed, max_frames=max_frames, use_odometry=use_odometry)
        ds, n = runs.dataset, runs.frames
    else:
        runs = None
        ds = simulated_dataset(scenario, seed, max_frames=max_frames)
        n = len(ds) if max_frames is None else min(int(max_frames), len(ds))
    params = {"z_range": list(z), "resolution": float(resolution), "slice_bins": int(slice_bins), "poses": poses,
              "every": int(every), "use_odometry": bool(use_odometry), "frames": int(n), "seed": int(seed)}
    desc = {"dataset": dataset_fingerprint(ds), "params": params,
            "slam": None if runs is None else [runs.run3.key, runs.run6.key]}
    slot = f"{slug(ds.name)}-seed{int(seed)}-{n}f-{'gt-' if runs is None else ''}{description_digest(params)[:16]}"
    cache = FolderCache(cache_dir if cache_dir is not None else default_maps_dir())
    got = cache.get(slot, desc, _compute_maps(ds, n, runs, z, float(resolution), int(slice_bins), int(every)),
                    _maps_loader(ds, z, poses))
    return dataclasses.replace(got.value, key=got.key, cached=got.cached)


# --- the maps' rooms, scored against the world's where it is known ----------------------------------------

def door_errors(doors: Iterable[Any], true_doors: Iterable[Mapping[str, Any]] | None) -> list[float] | None:
    """Distance (m) from each found door's centre to the nearest true door centre (``doors.json``'s
    ``center``); None when there are no true doors to compare with (a recording without ground truth).

    Parameters
    ----------
    doors : iterable of hsmap.rooms.segmentation.Door
    true_doors : iterable of mapping, or None
    """
    if true_doors is None:
        return None
    centres = np.array([d["center"] for d in true_doors], dtype=float).reshape(-1, 2)
    if len(centres) == 0:
        return None
    return [float(np.hypot(*(centres - np.asarray(d.centre, dtype=float)).T).min()) for d in doors]


@dataclass
class MapSegmentations:
    """Both maps of a :class:`TwoLidarMaps` segmented with one configuration (:func:`segment_maps`).

    Attributes
    ----------
    segmentations : dict
        ``"floor"`` and ``"slice"``: :class:`hsmap.rooms.segmentation.Segmentation`.
    scores : dict or None
        The same keys: :class:`hsmap.evaluation.segmentation.SegmentationScores` against the world's rooms;
        None without ground truth.
    coverage : dict or None
        The same keys: the share of the true rooms' floor each map sees free; None without ground truth.
    truth : tuple or None
        The world's room labels (image, geometry, label -> name), as :meth:`TwoLidarMaps.true_rooms`.
    """

    segmentations: dict
    scores: dict | None
    coverage: dict | None
    truth: tuple | None

    def title(self, key: str) -> str:
        """``"precision P, recall R"`` of a map, or its room and door count without ground truth."""
        if self.scores is not None:
            s = self.scores[key]
            return f"precision {s.precision:.3f}, recall {s.recall:.3f}"
        seg = self.segmentations[key]
        return f"{seg.n_rooms} rooms, {len(seg.doors)} doors (no ground truth)"


def segment_maps(maps: TwoLidarMaps, config: Any = None, *,
                 log: Any = print) -> MapSegmentations:
    """Segment the floor-level map and the slice with one configuration and, where the world's rooms are known,
    score both (Bormann et al.'s precision and recall, :func:`hsmap.evaluation.segmentation_scores`, on the
    ground truth's grid) and measure how much of the true rooms' floor each map sees free.

    Parameters
    ----------
    maps : TwoLidarMaps
    config : hsmap.rooms.segmentation.SegmentationConfig, optional
    log : callable or None
        Receives one line per map.
    """

    truth = maps.true_rooms()
    segs, scores, coverage = {}, {}, {}
    name = getattr(maps.dataset, "name", "")
    for key, grid in (("floor", maps.floor), ("slice", maps.slice)):
        seg = segment_rooms(grid, config=config)
        segs[key] = seg
        line = f"{name} {key:5s}: {seg.n_rooms} rooms, {len(seg.doors)} doors"
        if truth is not None:
            gt, gt_geo, _ = truth
            gt = gt.astype(np.int32)
            labels = resample_grid(seg.labels.astype(np.int32), seg.geometry, gt_geo, fill=0)
            sc = scores[key] = segmentation_scores(labels, gt, gt_is_labels=True)
            free = resample_grid(grid.free.astype(np.uint8), grid.geometry, gt_geo, fill=0).astype(bool)
            coverage[key] = float(free[gt > 0].mean()) if (gt > 0).any() else 0.0
            line += (f"; precision {sc.precision:.4f}, recall {sc.recall:.4f} (area-weighted "
                     f"{sc.precision_area:.4f} / {sc.recall_area:.4f}); free {100 * coverage[key]:.1f}% of the "
                     "true rooms' floor")
        else:
            line += " (no ground truth: not scored)"
        if log is not None:
            log(line)
    if truth is None:
        return MapSegmentations(segs, None, None, None)
    return MapSegmentations(segs, scores, coverage, truth)


def true_room_names(segmentation: Any, truth: tuple | None) -> dict[int, str]:
    """Our rooms named after the world's: for each label of ``segmentation``, the name of the true room it
    overlaps most (``"outside"`` when it overlaps none); empty without ground truth (``truth`` None).

    Parameters
    ----------
    segmentation : hsmap.rooms.segmentation.Segmentation
    truth : tuple or None
        (label image, its GridGeometry, label -> name), as :meth:`TwoLidarMaps.true_rooms`.
    """
    if truth is None:
        return {}

    gt, gt_geo, gt_names = truth
    ours = resample_grid(segmentation.labels.astype(np.int32), segmentation.geometry, gt_geo, fill=0)
    names = {}
    for lab in range(1, segmentation.n_rooms + 1):
        hit = gt[ours == lab]
        hit = hit[hit > 0]
        names[lab] = gt_names.get(int(np.bincount(hit).argmax()), "?") if hit.size else "outside"
    return names
