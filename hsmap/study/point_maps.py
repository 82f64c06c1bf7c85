"""Point maps of the study: a dataset's scans or clouds placed at a trajectory's poses, and how far one map lies
from another.

:func:`point_maps` / :func:`point_map` / :func:`scan_grid` place a dataset's frames at the poses of any trajectory
(the SLAM map, the odometry-only map of the paper's Figures 2 and 8, the reference map at the true poses);
:func:`map_distances` measures how far one map lies from another.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Iterator, Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from ..datasets.frames import Dataset, Frame
from ..errors import InputError
from ..geometry import pose_to_matrix, transform_points
from ..maps.grid import GridGeometry, OccupancyGrid, ScanGridConfig, grid_from_scans
from ..maps.mapping import VoxelMap, first_per_voxel
from ..slam import frame_points
from ..trajectory import Trajectory

__all__ = ["point_maps", "point_map", "scan_grid", "map_distances"]


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
