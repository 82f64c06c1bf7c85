"""The chain's stages as functions: ``hsmap map`` (:mod:`hsmap.pipeline.chain`), the 3D-only chain
(:mod:`hsmap.pipeline.chain3d`) and the study's maps (:mod:`hsmap.study.maps`) call these, so that a notebook's
grids of a recording and ``hsmap map``'s are the same.

- :func:`slam_runs`: 3-DOF HS-SLAM on the 2D scans, started at the first odometry pose (:func:`start_pose`), then
  6-DOF HS-SLAM on the 3D clouds seeded by the 2D poses and started at the 2D pose of the first cloud;
- :func:`chain_grids`: the floor-level grid (every deskewed 2D scan at its 2D pose) and the grid of the 3D map's
  slice (every deskewed cloud at its 6-DOF pose), with the points behind both and the slice's virtual scans
  (:class:`ChainGrids`, stored and read back through :func:`hsmap.maps.grid.grid_arrays`);
- :func:`fuse_grids`: the floor grid registered to the slice;
- :func:`segment_grids`: doors and rooms of each grid, one configuration;
- :class:`StageLog`: the stages' progress lines, bars and timings.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from itertools import islice
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .. import progress as _progress
from ..datasets.frames import Dataset, Frame
from ..deskew import deskew_frame
from ..deskew2d import deskew_scan_frame
from ..errors import InputError
from ..io import write_json
from ..maps.fusion import MapAlignment, align_maps, slice_scans
from ..maps.grid import OccupancyGrid, grid_arrays, grid_from_arrays, grid_from_scans, scans_to_points
from ..maps.mapping import voxel_downsample
from ..rooms.segmentation import Door, Segmentation, SegmentationConfig, segment_rooms
from ..trajectory import Trajectory
from .cache import FolderCache
from .config import ChainConfig, GridsConfig
from .runs import SlamRun, cached_slam

__all__ = ["StageLog", "start_pose", "slam_runs", "slam_summary", "ChainGrids", "chain_grids", "fuse_grids",
           "segment_grids", "rooms_stage", "cached_stage", "thin"]

#: The cell (m) the points behind a grid are thinned to.
POINTS_VOXEL = 0.02


class StageLog:
    """Progress bars and timings of the stages; a stage read back from its folder says "unchanged"."""

    def __init__(self, progress: bool | None) -> None:
        self.progress = progress
        self.info: dict[str, dict] = {}

    def start(self, name: str, detail: str = "") -> None:
        _progress.stage(name, detail)  # a line for a caller that reports progress, else nothing

    def bar(self, name: str, total: int | None = None, unit: str = "step"):
        return _progress.bar(total, unit=unit, desc=f"{name:<7s}", progress=self.progress, leave=True)

    def done(self, name: str, cached: bool, seconds: float, bar=None) -> None:
        self.info[name] = {"unchanged": bool(cached), "seconds": round(float(seconds), 3)}
        _progress.say(f"{name}: " + ("unchanged, read back" if cached else f"done in {seconds:.1f} s"))
        if bar is not None:
            if cached:
                bar.set_postfix_str("unchanged, skipped")
            if bar.total is not None and bar.n < bar.total:
                bar.update(bar.total - bar.n)
            bar.close()


def counted(items: Iterable, bar) -> Iterator:
    """``items``, each counted on ``bar`` once the caller took it."""
    for item in items:
        yield item
        if bar is not None:
            bar.update(1)


def thin(points: NDArray[np.float64], voxel: float = POINTS_VOXEL) -> NDArray[np.float64]:
    """One point per ``voxel`` cell (:func:`hsmap.maps.mapping.voxel_downsample`)."""
    return voxel_downsample(np.asarray(points, dtype=float), voxel)


def slam_summary(run) -> dict:
    """The numbers of a SLAM run that the chain's ``metrics.json`` and the study's maps record."""
    m = run.metrics
    keys = ("frames", "keyframes", "map_points", "seconds_total", "cpu_seconds_total", "real_time_factor",
            "inlier_ratio_median", "frames_retried", "frames_unverified", "loop_closure", "loops_closed", "pair_edges",
            "prior")
    return {k: m.get(k) for k in keys}


# --- SLAM -------------------------------------------------------------------------------------------------------

def start_pose(dataset: Dataset) -> np.ndarray | None:
    """The first frame's odometry pose (x, y, yaw), when the input has odometry there."""
    odo = getattr(dataset, "odometry", None)
    if odo is None or not len(dataset):
        return None
    pose, found = odo.at([float(np.asarray(dataset.stamps)[0])], max_dt=1e-3)
    return pose[0] if found[0] else None


def _timed_run(log: StageLog | None, name: str, detail: str, run_it) -> SlamRun:
    t = time.perf_counter()
    if log is not None:
        log.start(name, detail)
    run = run_it()
    if log is not None:
        log.done(name, run.cached, time.perf_counter() - t, log.bar(name, 1) if run.cached else None)
    return run


def slam_runs(ds2: Dataset, ds3: Dataset, config: ChainConfig, seed: int, *, cache_dir: str | Path,
              max_frames: int | None = None, progress: bool | None = None,
              log: StageLog | None = None) -> tuple[SlamRun, SlamRun]:
    """The chain's two HS-SLAM runs, each a :func:`hsmap.pipeline.runs.cached_slam` folder in ``cache_dir``.

    ``ds2`` and ``ds3`` are the recording's frames made by its scans and by its clouds
    (:meth:`~hsmap.datasets.frames.Dataset.driven_by`). The 3-DOF run starts at the first odometry pose
    (:func:`start_pose`; the origin without odometry), so that the maps share the odometry's frame; the 6-DOF
    run is seeded by its poses and starts at its pose of the first cloud.
    """
    init2 = start_pose(ds2)
    run2 = _timed_run(log, "slam2d", f"3-DOF HS-SLAM on {len(ds2)} scans", lambda: cached_slam(
        ds2, config.slam2d, seed, initial_pose=init2, max_frames=max_frames, cache_dir=cache_dir, progress=progress))
    prior = run2.trajectory
    first = float(np.asarray(ds3.stamps)[0])
    p0, ok = prior.interpolate([first], config.slam3d.sync_tolerance)
    p0 = p0[0] if ok[0] else prior.at([first], max_dt=np.inf)[0][0]
    init3 = np.array([p0[0], p0[1], 0.0, 0.0, 0.0, p0[2]])
    run3 = _timed_run(log, "slam3d", f"6-DOF HS-SLAM on {len(ds3)} clouds", lambda: cached_slam(
        ds3, config.slam3d, seed, prior=prior, initial_pose=init3, max_frames=max_frames, cache_dir=cache_dir,
        progress=progress))
    return run2, run3


# --- grids ------------------------------------------------------------------------------------------------------

@dataclass
class ChainGrids:
    """The chain's two grids and what they are made of.

    Attributes
    ----------
    floor, slice : OccupancyGrid
        The floor-level grid and the grid of the 3D map's slice.
    floor_points, slice_points : ndarray of shape (K, 2)
        The points behind each grid (scan end points; virtual slice-scan end points), one per 2 cm cell.
    slice_scans : list of ndarray of shape (K_i, 2)
        The virtual slice scans (:func:`hsmap.maps.fusion.slice_scans`), each in its virtual sensor's frame.
    slice_poses : ndarray of shape (S, 3)
        World (x, y, yaw) of each slice scan's virtual sensor.
    """

    floor: OccupancyGrid
    slice: OccupancyGrid
    floor_points: NDArray[np.float64]
    slice_points: NDArray[np.float64]
    slice_scans: list
    slice_poses: NDArray[np.float64]

    def arrays(self) -> dict[str, NDArray]:
        """Everything as arrays for an ``.npz`` (:meth:`from_arrays` reads them back)."""
        return {"floor_points": self.floor_points, "slice_points": self.slice_points,
                "slice_scan_points": np.vstack(self.slice_scans) if self.slice_scans else np.empty((0, 2)),
                "slice_scan_sizes": np.array([len(a) for a in self.slice_scans], dtype=np.int64),
                "slice_poses": self.slice_poses, **grid_arrays("floor", self.floor), **grid_arrays("slice", self.slice)}

    @classmethod
    def from_arrays(cls, z) -> ChainGrids:
        return cls(grid_from_arrays(z, "floor"), grid_from_arrays(z, "slice"), z["floor_points"], z["slice_points"],
                   np.split(z["slice_scan_points"], np.cumsum(z["slice_scan_sizes"])[:-1]), z["slice_poses"])

    def save(self, path: str | Path) -> None:
        np.savez(path, **self.arrays())

    @classmethod
    def load(cls, path: str | Path) -> ChainGrids:
        with np.load(path) as z:
            return cls.from_arrays(z)


@dataclass(frozen=True)
class _Frames:
    """Which frames make the grids: every n-th of the first ``first`` (None: of all)."""

    every: int = 1
    first: int | None = None

    def take(self, frames: Iterable[Frame], bar) -> Iterator[Frame]:
        return (f for k, f in enumerate(counted(islice(frames, self.first), bar)) if k % self.every == 0)

    def mask(self, n: int) -> NDArray[np.bool_]:
        k = np.arange(n if self.first is None else min(n, self.first))
        return k % self.every == 0


def _floor_scans(ds2: Dataset, traj2: Trajectory, deskew: bool, use: _Frames, bar):
    """The 2D scans that have a 2D pose (deskewed by it), their poses and their 2D LiDAR offsets."""
    scans, poses, ext = [], [], []
    t2 = traj2.as_3dof()
    for f in use.take(ds2.frames(clouds=False), bar):
        pose, ok = t2.at([f.stamp], max_dt=1e-3)
        if ok[0] and f.scan2d is not None:
            scans.append(deskew_scan_frame(f, prior=t2)[0].scan2d if deskew else f.scan2d)
            poses.append(pose[0])
            ext.append(f.extrinsic2d)
    if not scans:
        raise InputError("no 2D scan has a 2D HS-SLAM pose: nothing to make the floor grid of")
    return scans, np.asarray(poses), np.asarray(ext, dtype=float)


def _slice(ds3: Dataset, traj3: Trajectory, grids: GridsConfig, deskew: bool, use: _Frames, bar):
    """The virtual slice scans of the clouds that have a 6-DOF pose (deskewed by it) and their poses."""
    z_min, z_max = grids.slice
    stamps = np.asarray(ds3.stamps, dtype=float)
    keep = use.mask(len(stamps))
    p3, found = traj3.as_6dof().at(stamps[:len(keep)][keep], max_dt=1e-3)
    wanted = (deskew_frame(f, prior=traj3)[0] if deskew else f
              for f, ok in zip(use.take(ds3.frames(), bar), found, strict=True)
              if ok and f.cloud3d is not None)
    sscans, spos = slice_scans(wanted, p3, z_min=z_min, z_max=z_max, bins=grids.slice_bins)
    if not sscans:
        raise InputError(f"no 3D cloud has points between {z_min} and {z_max} m above the base frame: "
                         "no slice to map (is the base frame on the floor, and the 3D offset right?)")
    return sscans, spos


def chain_grids(ds2: Dataset, ds3: Dataset, traj2: Trajectory, traj3: Trajectory, grids: GridsConfig, *,
                deskew: bool = True, every: int = 1, max_frames: int | None = None, bar=None) -> ChainGrids:
    """The floor-level grid and the slice's grid (see the module docstring).

    Parameters
    ----------
    ds2, ds3 : Dataset
        The frames made by the scans and by the clouds (``ds3`` may be ``ds2`` when every frame has both).
    traj2, traj3 : Trajectory
        The 2D and the 6-DOF poses; a frame without a pose within 1 ms of its stamp is left out.
    grids : GridsConfig
        ``resolution``, ``slice``, ``slice_bins``.
    deskew : bool
        Move each scan's beams and each cloud's points to their frame's stamp by the poses' motion.
    every : int
        Use every n-th frame.
    max_frames : int, optional
        Use only the first frames of each.
    bar : progress bar, optional
        Counts the frames read.
    """
    if int(every) < 1 or (max_frames is not None and int(max_frames) < 1):
        raise InputError(f"every and max_frames must be >= 1, got {every} and {max_frames}")
    use = _Frames(int(every), None if max_frames is None else int(max_frames))
    scans, poses, ext = _floor_scans(ds2, traj2, deskew, use, bar)
    floor = grid_from_scans(scans, poses, grids.resolution, extrinsic=ext)
    floor_pts = thin(scans_to_points(scans, poses, ext))
    sscans, spos = _slice(ds3, traj3, grids, deskew, use, bar)
    slice_ = grid_from_scans(sscans, spos, grids.resolution)
    return ChainGrids(floor, slice_, floor_pts, thin(scans_to_points(sscans, spos)), sscans, spos)


# --- overlay and rooms ----------------------------------------------------------------------------------------------

def fuse_grids(grids: ChainGrids, seed: int) -> MapAlignment:
    """The floor grid registered to the slice (:func:`hsmap.maps.fusion.align_maps`), seeded by ``seed``."""
    return align_maps(grids.floor, grids.slice, floor_points=grids.floor_points, slice_points=grids.slice_points,
                      rng=seed)


def segment_grids(grids: dict[str, OccupancyGrid], config: SegmentationConfig) -> dict[str, Segmentation]:
    """Doors and rooms of each grid, one configuration (:func:`hsmap.rooms.segmentation.segment_rooms`)."""
    return {name: segment_rooms(g, config=config) for name, g in grids.items()}


# --- the stages' folders -----------------------------------------------------------------------------------------

def _door_from(d: dict) -> Door:
    return Door(centre=np.asarray(d["centre"], dtype=float), end_points=np.asarray(d["end_points"], dtype=float),
                width=float(d["width"]), rooms=tuple(int(r) for r in d["rooms"]),
                pixel=tuple(int(v) for v in d["pixel"]), kind=str(d["kind"]))


def rooms_stage(grids: dict[str, OccupancyGrid], config: SegmentationConfig) -> tuple[Callable, Callable]:
    """The rooms stage's folder (``rooms.npz`` of labels, ``doors.json``): compute and load."""
    def compute(folder: Path) -> None:
        segs = segment_grids(grids, config)
        np.savez(folder / "rooms.npz", **{name: s.labels.astype(np.int32) for name, s in segs.items()})
        write_json(folder / "doors.json", {name: [d.as_dict() for d in s.doors] for name, s in segs.items()})

    def load(folder: Path) -> dict[str, Segmentation]:
        doors = json.loads((folder / "doors.json").read_text(encoding="utf-8"))
        with np.load(folder / "rooms.npz") as z:
            return {name: Segmentation(z[name], [_door_from(d) for d in doors[name]], grids[name].geometry, config)
                    for name in grids}

    return compute, load


def cached_stage(cache: FolderCache, log: StageLog, name: str, description: dict,
                 compute_load: tuple[Callable, Callable], *, detail: str = "", own_bar: bool = False) -> tuple[Any, str]:
    """One stage as a :class:`FolderCache` slot ``name``: computed, or read back when its description and the
    code are unchanged; its progress on ``log`` (``own_bar``: the stage's compute shows its own bar)."""
    t = time.perf_counter()
    log.start(name, detail)
    bar = None if own_bar else log.bar(name, 1)
    got = cache.get(name, description, *compute_load)
    if own_bar and got.cached:
        bar = log.bar(name, 1)
    log.done(name, got.cached, time.perf_counter() - t, bar)
    return got.value, got.key
