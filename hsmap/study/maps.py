"""Maps of the study: the 2D and 3D maps of one simulated run shared by notebooks 04-07 (computed once, then
cached), and their rooms. The point maps (a dataset's frames at a trajectory's poses, :func:`point_maps`,
:func:`point_map`, :func:`scan_grid`, :func:`map_distances`) live in :mod:`hsmap.study.point_maps` and are
importable from here.

:func:`two_lidar_maps` runs the paper's pipeline on a simulated run:

1. the simulated dataset and its HS-SLAM runs (:func:`hsmap.study.runs.simulated_slam_runs`: 2D, 3-DOF on the
   floor-level LiDAR, and 6-DOF on the 3D LiDAR seeded by the 2D poses, as in the paper; without odometry by
   default, the paper's claim; both started at the first ground-truth pose so that their maps share the world
   frame of the ground truth, its rooms, doors and labels);
2. the maps made from them: the 2D and 3D HS-SLAM point maps, and the chain's grids
   (:func:`hsmap.pipeline.stages.chain_grids`): the floor-level occupancy grid (every 2D scan at its 2D HS-SLAM
   pose) and the grid of the 3D map's slice at 1.7-1.8 m (every 3D cloud at its 6-DOF HS-SLAM pose), with the
   points behind both.

The maps are a folder of :class:`hsmap.pipeline.cache.FolderCache` under ``data/generated/maps/`` (``maps.npz``),
keyed on the dataset, the SLAM runs' keys, the grid parameters and the code; the SLAM runs are the cached runs
every other notebook shares.

``two_lidar_maps(dataset=PATH)`` makes the same maps of a recording instead of a scenario, as ``hsmap map`` makes
them: any input :func:`hsmap.datasets.open.open_dataset` reads (a folder written by ``hsmap simulate``, a ROS1 or
ROS2 bag, ...) with 2D scans and 3D clouds goes through the chain's stages (:func:`hsmap.pipeline.stages.slam_runs`
at ``hsmap map``'s defaults, :func:`hsmap.pipeline.stages.chain_grids` with deskewing), so its grids are those of
``hsmap map`` of the recording. A recording without ground truth has no true rooms or doors
(:meth:`TwoLidarMaps.true_doors` is None): the notebooks then show the maps and their segmentation without scoring
them.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..config import to_dict
from ..datasets.frames import Dataset
from ..datasets.open import open_dataset
from ..datasets.simulated import SimulatedDataset
from ..errors import InputError
from ..evaluation import segmentation_scores
from ..io import write_json
from ..maps.fusion import resample_grid
from ..maps.grid import GridGeometry, OccupancyGrid
from ..pipeline.cache import FolderCache, description_digest, slug
from ..pipeline.config import ChainConfig, GridsConfig
from ..pipeline.stages import ChainGrids, chain_grids, slam_runs, slam_summary
from ..rooms.segmentation import segment_rooms
from ..trajectory import Trajectory
from .datasets import simulated_dataset
from .paths import generated_dir
from .point_maps import map_distances, point_map, point_maps, scan_grid
from .runs import SimulatedRuns, dataset_fingerprint, default_slam_dir, simulated_slam_runs

__all__ = ["point_maps", "point_map", "scan_grid", "map_distances", "TwoLidarMaps", "two_lidar_maps",
           "recording_maps", "default_maps_dir", "MapSegmentations", "segment_maps", "door_errors",
           "true_room_names"]


def default_maps_dir() -> Path:
    """``data/generated/maps`` of the repository (``$HSMAP_GENERATED/maps`` when that is set)."""
    return generated_dir() / "maps"


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
        Wall time of each step when it was computed (``slam2d``, ``slam3d``, ``grids``).
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


def _save_maps(folder: Path, grids: ChainGrids, trajectories: dict[str, tuple], point_maps: dict,
               meta: dict) -> None:
    """``maps.npz`` (the grids, the trajectories (stamps, poses) as ``NAME_stamps`` and ``NAME``, the point maps)
    and ``meta.json``."""
    arrays = {f"{k}{suffix}": v for k, (stamps, poses) in trajectories.items()
              for suffix, v in (("", poses), ("_stamps", stamps))}
    np.savez(folder / "maps.npz", **grids.arrays(), **arrays, **point_maps)
    write_json(folder / "meta.json", meta)


def _maps_loader(ds: Dataset, z_range: tuple[float, float], poses: str):
    def load(folder: Path) -> TwoLidarMaps:
        meta = json.loads((folder / "meta.json").read_text(encoding="utf-8"))
        with np.load(folder / "maps.npz") as z:
            g = ChainGrids.from_arrays(z)
            gt = Trajectory(z["groundtruth_stamps"], z["groundtruth"]) if len(z["groundtruth_stamps"]) else None
            return TwoLidarMaps(
                dataset=ds, frames=int(meta["frames"]), groundtruth=gt,
                slam2d=Trajectory(z["slam2d_stamps"], z["slam2d"]), slam3d=Trajectory(z["slam3d_stamps"], z["slam3d"]),
                map2d=z["map2d"], map3d=z["map3d"], floor=g.floor, slice=g.slice, floor_points=g.floor_points,
                slice_points=g.slice_points, slice_scans=g.slice_scans, slice_poses=g.slice_poses, z_range=z_range,
                poses=poses, seconds=meta["seconds"], slam_metrics=meta["slam_metrics"], folder=folder)

    return load


def _compute_maps(ds: SimulatedDataset, n: int, runs: SimulatedRuns | None, grids_cfg: GridsConfig, every: int):
    """The maps' folder writer of a simulated run: the chain's grids (:func:`hsmap.pipeline.stages.chain_grids`)
    at the SLAM poses or the true ones."""

    def compute(folder: Path) -> None:
        stamps, gt = ds.stamps[:n], ds.groundtruth.poses[:n]
        if runs is not None:
            p2, p3 = runs.run3.trajectory.poses, runs.run6.trajectory.poses
            point_maps = {"map2d": runs.run3.map_points, "map3d": runs.run6.map_points}
            seconds = {"slam2d": runs.run3.seconds, "slam3d": runs.run6.seconds}
            slam_metrics = {"2d": slam_summary(runs.run3), "3d": slam_summary(runs.run6)}
        else:
            p2, p3 = gt, np.column_stack([gt[:, :2], np.zeros((n, 3)), gt[:, 2]])
            point_maps, seconds, slam_metrics = {"map2d": np.empty((0, 2)), "map3d": np.empty((0, 3))}, {}, {}
        t = time.perf_counter()
        traj2, traj3 = Trajectory(stamps, p2), Trajectory(stamps, p3)
        grids = chain_grids(ds, ds, traj2, traj3, grids_cfg, every=every, max_frames=n)
        seconds["grids"] = time.perf_counter() - t
        _save_maps(folder, grids, {"groundtruth": (stamps, gt), "slam2d": (stamps, p2), "slam3d": (stamps, p3)},
                   point_maps, {"seconds": seconds, "frames": int(n), "slam_metrics": slam_metrics})

    return compute


def _compute_recording_maps(ds: Dataset, n: int, runs: tuple, grids_cfg: GridsConfig, deskew: bool, every: int,
                            max_frames: int | None):
    """The maps' folder writer of a recording: the chain's grids (:func:`hsmap.pipeline.stages.chain_grids`) of
    its frames at the chain's runs' poses, as ``hsmap map`` makes them."""

    def compute(folder: Path) -> None:
        run2, run3 = runs
        seconds = {"slam2d": run2.seconds, "slam3d": run3.seconds}
        t = time.perf_counter()
        grids = chain_grids(ds.driven_by("scan"), ds.driven_by("cloud"), run2.trajectory, run3.trajectory,
                            grids_cfg, deskew=deskew, every=every, max_frames=max_frames)
        seconds["grids"] = time.perf_counter() - t
        gt = getattr(ds, "groundtruth", None)
        stamps = run2.trajectory.stamps
        truth = (np.empty(0), np.empty((0, 3)))
        if gt is not None:
            gt_poses, ok = gt.as_3dof().at(stamps)
            truth = (stamps[ok], gt_poses)
        _save_maps(folder, grids, {"groundtruth": truth, "slam2d": (stamps, run2.trajectory.poses),
                                   "slam3d": (run3.trajectory.stamps, run3.trajectory.poses)},
                   {"map2d": run2.map_points, "map3d": run3.map_points},
                   {"seconds": seconds, "frames": int(n), "dataset": ds.name,
                    "slam_metrics": {"2d": slam_summary(run2), "3d": slam_summary(run3)}})

    return compute


def recording_maps(
    dataset: str | os.PathLike | Dataset,
    seed: int = 1,
    *,
    config: ChainConfig | None = None,
    max_frames: int | None = None,
    every: int = 1,
    open_kwargs: Mapping[str, Any] | None = None,
    cache_dir: str | os.PathLike | None = None,
) -> TwoLidarMaps:
    """The maps of :func:`two_lidar_maps` made from a recording as ``hsmap map`` makes them (see the module
    docstring).

    Parameters
    ----------
    dataset : path or Dataset
        Anything :func:`hsmap.datasets.open.open_dataset` opens (``open_kwargs`` are its keywords) that has 2D
        scans and 3D clouds.
    config : ChainConfig, optional
        The chain's settings (both runs, the grids); default ``hsmap map``'s.

    Other parameters are those of :func:`two_lidar_maps`.
    """

    if isinstance(dataset, (str, os.PathLike)) and not str(dataset).strip():
        raise InputError("dataset: empty path")
    if int(every) < 1:
        raise InputError(f"every must be >= 1, got {every}")
    if max_frames is not None and int(max_frames) < 1:
        raise InputError(f"max_frames must be >= 1, got {max_frames}")
    config = ChainConfig() if config is None else config
    ds = dataset if isinstance(dataset, Dataset) else open_dataset(dataset, **dict(open_kwargs or {}))
    n = len(ds) if max_frames is None else min(int(max_frames), len(ds))
    if n < 1:
        raise InputError(f"{ds.name}: the recording has no frames")
    runs = slam_runs(ds.driven_by("scan"), ds.driven_by("cloud"), config, int(seed), cache_dir=default_slam_dir(),
                     max_frames=max_frames)
    # the key names the input as given (a path: its contents and options), the runs and maps share it
    src = ds if isinstance(dataset, Dataset) else dataset
    params = {"grids": to_dict(config.grids), "every": int(every), "frames": int(n), "seed": int(seed)}
    desc = {"dataset": dataset_fingerprint(src, None if isinstance(dataset, Dataset) else open_kwargs),
            "params": params, "slam": [r.key for r in runs]}
    slot = f"{slug(ds.name.split('.')[0])}-rec-seed{int(seed)}-{n}f-{description_digest(desc)[:16]}"
    cache = FolderCache(cache_dir if cache_dir is not None else default_maps_dir())
    compute = _compute_recording_maps(ds, n, runs, config.grids, config.slam3d.deskew, int(every), max_frames)
    got = cache.get(slot, desc, compute, _maps_loader(ds, config.grids.slice, "slam"))
    return dataclasses.replace(got.value, key=got.key, cached=got.cached)


def two_lidar_maps(
    scenario: str = "two-rooms",
    seed: int = 1,
    *,
    max_frames: int | None = None,
    grids: GridsConfig | None = None,
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
    grids : GridsConfig, optional
        The grids: ``resolution`` (metres per cell of both), ``slice`` (the slice of the 3D map; the paper's
        1.7-1.8 m), ``slice_bins`` (azimuth bins of the virtual slice scans); default ``hsmap map``'s.
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

    grids = GridsConfig() if grids is None else grids
    if poses not in ("slam", "groundtruth"):
        raise InputError(f"poses must be 'slam' or 'groundtruth', got {poses!r}")
    if dataset is not None and (isinstance(dataset, Dataset) or str(dataset).strip()):
        if poses != "slam":
            raise InputError("a recording's maps are made at its HS-SLAM poses: poses must be 'slam'")
        return recording_maps(dataset, seed, config=ChainConfig(grids=grids), max_frames=max_frames, every=every,
                              cache_dir=cache_dir)
    if int(every) < 1:
        raise InputError(f"every must be >= 1, got {every}")
    z = grids.slice
    if poses == "slam":
        runs = simulated_slam_runs(scenario, seed, max_frames=max_frames, use_odometry=use_odometry)
        ds, n = runs.dataset, runs.frames
    else:
        runs = None
        ds = simulated_dataset(scenario, seed, max_frames=max_frames)
        n = len(ds) if max_frames is None else min(int(max_frames), len(ds))
    params = {"z_range": list(z), "resolution": float(grids.resolution), "slice_bins": int(grids.slice_bins), "poses": poses,
              "every": int(every), "use_odometry": bool(use_odometry), "frames": int(n), "seed": int(seed)}
    desc = {"dataset": dataset_fingerprint(ds), "params": params,
            "slam": None if runs is None else [runs.run3.key, runs.run6.key]}
    slot = f"{slug(ds.name)}-seed{int(seed)}-{n}f-{'gt-' if runs is None else ''}{description_digest(params)[:16]}"
    cache = FolderCache(cache_dir if cache_dir is not None else default_maps_dir())
    got = cache.get(slot, desc, _compute_maps(ds, n, runs, grids, int(every)),
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
