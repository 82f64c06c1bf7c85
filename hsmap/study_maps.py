"""The 2D and 3D maps of one simulated run, shared by the study notebooks 04-07 (computed once, then cached).

Notebooks 04 (2D/3D overlap), 05 (Voronoi steps), 06 (topology and doors) and 07 (occluded vs non-occluded)
all start from the same products of one simulated run through the paper's pipeline:

1. the simulated dataset (:func:`simulated_dataset`: ``data/generated/<scenario>-seed<seed>``, or the prefix
   folder ``...-first<N>`` for quick runs; generated once, under a lock);
2. HS-SLAM in 2D (3-DOF, the floor-level LiDAR) and in 3D (6-DOF, the 3D LiDAR, seeded by the 2D poses as in the
   paper), without odometry by default (the paper's claim), both started at the first ground-truth pose so that their maps share the world frame of the ground
   truth (the rooms, doors and labels to compare with);
3. the maps made from them: the 2D and 3D HS-SLAM point maps, the floor-level occupancy grid (every 2D scan
   at its 2D HS-SLAM pose, :func:`hsmap.grid.grid_from_scans`) and the grid of the 3D map's slice at
   1.7-1.8 m (every 3D cloud at its 6-DOF HS-SLAM pose, :func:`hsmap.fusion.slice_grid`), with the points
   behind both grids.

:func:`two_lidar_maps` returns them all. It computes them once per *key* and stores them in
``data/generated/maps/<dataset>-<key>/``; the key is a SHA-256 of the dataset's ``dataset.yaml``, the frame
count, the SLAM configurations and seed, the grid parameters, the hsmap version and the source of every module
that decides the result, so a change to the SLAM or grid code never reuses a stale result. Parallel callers
(``hsmap reproduce --jobs 2``) serialise on a file lock: the second waits and reads what the first wrote. A
folder is published atomically (written beside, then renamed) with ``meta.json`` last.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from . import __version__
from .config import to_dict
from .errors import DatasetError, InputError
from .grid import GridGeometry, OccupancyGrid
from .io import write_json
from .trajectory import Trajectory
from .study import _sha, _source_digest, simulated_dataset

__all__ = ["TwoLidarMaps", "two_lidar_maps", "simulated_dataset", "MAP_SOURCES", "default_maps_dir"]

#: Package files (relative to ``hsmap/``) whose contents decide the maps; their digest is part of the key.
MAP_SOURCES = (
    "slam.py", "registration.py", "harmony.py", "fitness.py", "mapping.py", "_kernels.py", "geometry.py",
    "grid.py", "fusion.py", "io.py", "config.py", "datasets/frames.py", "datasets/simulated.py", "study_maps.py",
)


def default_maps_dir() -> Path:
    """``data/generated/maps`` of the repository (``$HSMAP_GENERATED/maps`` when that is set)."""
    from .sim.catalog import generated_dir

    return generated_dir() / "maps"


@dataclass
class TwoLidarMaps:
    """The maps of one simulated run (see the module docstring). World frame = the ground truth's.

    Attributes
    ----------
    dataset : SimulatedDataset
    frames : int
        Frames used (the first ``frames`` of the dataset).
    groundtruth : Trajectory
        (frames, 3) true robot poses.
    slam2d : Trajectory
        (frames, 3) 2D HS-SLAM poses of the robot base (the true poses with ``poses="groundtruth"``).
    slam3d : Trajectory
        (frames, 6) 6-DOF HS-SLAM poses of the robot base (the true poses with ``poses="groundtruth"``).
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
        The virtual slice scans (:func:`hsmap.fusion.slice_scans`), each in its virtual sensor's frame.
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

    dataset: Any
    frames: int
    groundtruth: Trajectory
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


def _slam_configs(use_odometry: bool = False):
    from .slam import SlamConfig

    return SlamConfig(dof=3, use_odometry=use_odometry), SlamConfig(dof=6, use_odometry=use_odometry)


def _key(dataset, frames: int, seed: int, params: dict) -> tuple[str, dict]:
    c2, c3 = _slam_configs(params["use_odometry"])
    desc = {
        "dataset": _sha((Path(dataset.path) / "dataset.yaml").read_bytes()),
        "frames": int(frames),
        "seed": int(seed),
        "slam2d": to_dict(c2),
        "slam3d": to_dict(c3),
        "params": params,
        "hsmap_version": __version__,
        "sources": _source_digest(MAP_SOURCES),
    }
    return _sha(json.dumps(desc, sort_keys=True).encode()), desc


def _grid_arrays(prefix: str, g: OccupancyGrid) -> dict[str, np.ndarray]:
    geo = g.geometry
    return {f"{prefix}_data": g.data, f"{prefix}_geometry": np.array([geo.resolution, *geo.origin])}


def _grid_from(z, prefix: str) -> OccupancyGrid:
    data = z[f"{prefix}_data"]
    res, ox, oy = (float(v) for v in z[f"{prefix}_geometry"])
    return OccupancyGrid(data, GridGeometry(data.shape, res, (ox, oy)))


def _thin(points: NDArray[np.float64], voxel: float) -> NDArray[np.float64]:
    from .mapping import voxel_downsample

    return voxel_downsample(np.asarray(points, dtype=float), voxel)


def _compute(ds, n: int, seed: int, z_range: tuple[float, float], resolution: float, bins: int, poses: str,
             every: int, use_odometry: bool) -> dict:
    from .fusion import slice_scans
    from .grid import scans_to_points
    from .grid import grid_from_scans
    from .slam import run_slam

    gt = ds.groundtruth.poses[:n]
    start = gt[0]
    seconds: dict[str, float] = {}
    if poses == "slam":
        c2, c3 = _slam_configs(use_odometry)
        t = time.perf_counter()
        r2 = run_slam(ds, c2, rng=seed, max_frames=n, initial_pose=start, progress=False)
        seconds["slam2d"] = time.perf_counter() - t
        t = time.perf_counter()
        start6 = np.array([start[0], start[1], 0.0, 0.0, 0.0, start[2]])
        r3 = run_slam(ds, c3, rng=seed, max_frames=n, initial_pose=start6, prior=r2.trajectory, progress=False)
        seconds["slam3d"] = time.perf_counter() - t
        p2, p3 = r2.trajectory.poses, r3.trajectory.poses
        map2d, map3d = r2.map.points, r3.map.points
        runs = {"2d": r2, "3d": r3}
    else:
        p2 = gt
        p3 = np.column_stack([gt[:, :2], np.zeros((n, 3)), gt[:, 2]])
        map2d, map3d = np.empty((0, 2)), np.empty((0, 3))
        runs = {}

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

    def summary(r) -> dict:
        m = r.metrics()
        return {k: m[k] for k in ("frames", "keyframes", "map_points", "seconds_total", "inlier_ratio_median",
                                  "real_time_factor")}

    return {
        "arrays": {
            "stamps": ds.stamps[:n], "groundtruth": gt, "slam2d": p2, "slam3d": p3,
            "map2d": map2d, "map3d": map3d, "floor_points": floor_pts, "slice_points": slice_pts,
            "slice_scan_points": np.vstack(sscans) if sscans else np.empty((0, 2)),
            "slice_scan_sizes": np.array([len(a) for a in sscans], dtype=np.int64), "slice_poses": spos,
            **_grid_arrays("floor", floor), **_grid_arrays("slice", slice_),
        },
        "seconds": seconds,
        "slam_metrics": {k: summary(r) for k, r in runs.items()},
    }


def _load(folder: Path, ds, key: str, z_range, cached: bool) -> TwoLidarMaps:
    meta_path = folder / "meta.json"
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
        if meta.get("key") != key:
            raise ValueError("key differs")
        with np.load(folder / "maps.npz") as z:
            stamps = z["stamps"]
            out = TwoLidarMaps(
                dataset=ds, frames=len(stamps), groundtruth=Trajectory(stamps, z["groundtruth"]),
                slam2d=Trajectory(stamps, z["slam2d"]), slam3d=Trajectory(stamps, z["slam3d"]),
                map2d=z["map2d"], map3d=z["map3d"], floor=_grid_from(z, "floor"), slice=_grid_from(z, "slice"),
                floor_points=z["floor_points"], slice_points=z["slice_points"],
                slice_scans=np.split(z["slice_scan_points"], np.cumsum(z["slice_scan_sizes"])[:-1]),
                slice_poses=z["slice_poses"], z_range=tuple(z_range), poses=meta["description"]["params"]["poses"],
                seconds=meta.get("seconds", {}), slam_metrics=meta.get("slam_metrics", {}), key=key,
                folder=folder, cached=cached)
    except (OSError, ValueError, KeyError) as exc:
        raise DatasetError(f"{folder}: incomplete or damaged maps folder ({exc})") from None
    return out


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
) -> TwoLidarMaps:
    """The 2D and 3D HS-SLAM maps of a simulated run and the grids made from them (see the module docstring).

    Parameters
    ----------
    scenario : str
        A shipped scenario (``two-rooms``, ``slam-office``) or a scenario file.
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
        Default :func:`default_maps_dir`.

    Returns
    -------
    TwoLidarMaps
    """
    from .sim.writer import folder_lock

    ds = simulated_dataset(scenario, seed, max_frames=max_frames)
    n = len(ds) if max_frames is None else min(int(max_frames), len(ds))
    if poses not in ("slam", "groundtruth"):
        raise InputError(f"poses must be 'slam' or 'groundtruth', got {poses!r}")
    if int(every) < 1:
        raise InputError(f"every must be >= 1, got {every}")
    params = {"z_range": [float(z_range[0]), float(z_range[1])], "resolution": float(resolution),
              "slice_bins": int(slice_bins), "poses": poses, "every": int(every),
              "use_odometry": bool(use_odometry)}
    key, desc = _key(ds, n, seed, params)
    cache = Path(cache_dir) if cache_dir is not None else default_maps_dir()
    folder = cache / f"{Path(ds.path).name}-{n}f-{'gt-' if poses == 'groundtruth' else ''}{key[:16]}"
    with folder_lock(folder):
        if folder.exists():
            try:
                return _load(folder, ds, key, z_range, cached=True)
            except DatasetError:
                shutil.rmtree(folder)
        res = _compute(ds, n, int(seed), (float(z_range[0]), float(z_range[1])), float(resolution), int(slice_bins),
                       poses, int(every), bool(use_odometry))
        tmp = folder.with_name(f".{folder.name}.tmp-{os.getpid()}")
        shutil.rmtree(tmp, ignore_errors=True)
        try:
            tmp.mkdir(parents=True)
            np.savez(tmp / "maps.npz", **res["arrays"])
            write_json(tmp / "meta.json", {"key": key, "description": desc, "seconds": res["seconds"],
                                           "slam_metrics": res["slam_metrics"]})
            os.rename(tmp, folder)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        return _load(folder, ds, key, z_range, cached=False)
