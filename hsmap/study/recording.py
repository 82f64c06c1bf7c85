"""A cached HS-SLAM run replayed into a rerun recording, frame by frame, as ``hsmap slam`` logs it live."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from typing import Any

import numpy as np

from ..datasets.frames import Dataset, Frame
from ..errors import InputError
from ..geometry import pose_to_matrix, transform_points
from ..mapping import first_per_voxel
from ..slam import frame_points
from ..trajectory import Trajectory
from .runs import SlamRun

__all__ = ["record_slam_run"]


def record_slam_run(
    rec: Any,
    dataset: Dataset | Iterable[Frame],
    run: SlamRun,
    *,
    every: int = 1,
    map_block: int = 10,
    map_voxel: float | None = None,
    cloud_voxel: float = 0.25,
    groundtruth: Trajectory | None = None,
    odometry: Trajectory | None = None,
) -> dict:
    """Log a (cached) SLAM run to a rerun recording, frame by frame on the ``scan`` timeline.

    Replays the run from its stored poses, as ``hsmap slam`` logs it live: the robot pose (``world/robot``),
    the current 2D scan and 3D cloud under their sensors, the growing map (the keyframes' points, in blocks of
    ``map_block`` keyframes under ``world/map/points``) and, as static lines, the estimated path and the
    optional ground truth and odometry.

    Parameters
    ----------
    every : int
        Log every n-th frame's pose and scan (the map still gets every keyframe).

    Returns
    -------
    dict
        ``frames`` logged, ``map_blocks``, ``map_points`` logged.
    """
    from ..viz import rerun as hv

    if int(every) < 1:
        raise InputError(f"every must be >= 1, got {every}")
    dof = run.dof
    cfg = run.config
    index_of = {int(i): k for k, i in enumerate(run.frame_indices)}
    key = run.keyframes
    poses = run.trajectory.poses
    logger = hv.PointMapLogger(rec, block=int(map_block),
                               voxel=map_voxel or (0.05 if dof == 3 else 0.15),
                               z_range=(-0.2, 3.0) if dof == 6 else None)
    logged = 0
    n_frames = len(run.trajectory)
    map_vox = map_voxel or (0.05 if dof == 3 else 0.15)

    thin = first_per_voxel  # one point per voxel; the viewer-side thinning then has little left to do

    for f in (dataset.frames(clouds=dof == 6) if isinstance(dataset, Dataset) else iter(dataset)):
        k = index_of.get(int(f.index))
        if k is None:
            if f.index > run.frame_indices.max():
                break
            continue
        show = k % int(every) == 0 or k == n_frames - 1
        if not (show or key[k]):
            continue
        if dof == 6 and f.cloud3d is not None:
            f = dataclasses.replace(f, cloud3d=thin(np.asarray(f.cloud3d, dtype=float), min(cloud_voxel, map_vox)))
        if show:
            shown = f if dof == 6 else dataclasses.replace(f, cloud3d=None)
            hv.log_frame(rec, shown, poses[k], index=k, cloud_voxel=cloud_voxel)
            logged += 1
        if key[k]:
            if not show:
                hv.set_frame_time(rec, k, f.stamp)
            pts = frame_points(f, dof, cfg.min_range, cfg.max_range)
            logger.add(thin(transform_points(pose_to_matrix(poses[k]), pts), map_vox))
    logger.flush()
    hv.log_path(rec, "estimate", run.trajectory.poses)
    if groundtruth is not None:
        hv.log_path(rec, "groundtruth", groundtruth.poses)
    if odometry is not None:
        hv.log_path(rec, "odometry", odometry.poses)
    return {"frames": logged, "map_blocks": logger.blocks, "map_points": logger.points_logged}
