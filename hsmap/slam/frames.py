"""A frame's points for HS-SLAM: range-filtered, downsampled, in the robot base frame; the 2D scans' sampling
check on normals."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from ..datasets.frames import Frame
from ..errors import UnusableFrameError
from ..geometry import pose_to_matrix, transform_points
from ..maps.mapping import voxel_downsample, voxel_downsample_with

__all__ = ["frame_points", "timed_cloud_points", "unusable_reason", "sampled_as_its_normal_says", "grazing_where_sparse",
           "SAMPLING_SLACK"]

#: How much further than its normal and the beams' spacing say a point's nearest neighbour may lie
SAMPLING_SLACK = 3.0


def frame_points(frame: Frame, dof: int, min_range: float = 0.0, max_range: float = np.inf,
                 voxel: float | None = None) -> NDArray[np.float64]:
    """The frame's scan (dof 3) or cloud (dof 6) as points of shape (N, 2) or (N, 3) in the robot base frame,
    range-filtered.

    With ``voxel``, the points are downsampled (voxel centroids, in the sensor frame) in the same pass, before
    they are moved to the base frame.
    """
    if dof == 3:
        if frame.scan2d is None:
            raise UnusableFrameError(f"frame {frame.index} (stamp {frame.stamp}) has no 2D scan: a 3-DOF run needs "
                                     "them", frame.index, frame.stamp)
        pts = frame.scan2d.points()
        ext = np.asarray(frame.extrinsic2d, dtype=float)
    else:
        if frame.cloud3d is None:
            raise UnusableFrameError(f"frame {frame.index} (stamp {frame.stamp}) has no 3D cloud: a 6-DOF run needs "
                                     "them", frame.index, frame.stamp)
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


def timed_cloud_points(frame: Frame, times: NDArray[np.float64], min_range: float, max_range: float,
                       voxel: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """:func:`frame_points` of a 6-DOF frame's cloud with ``voxel`` (the same points), and each point's time (M,),
    the mean of ``times`` (N,), one per cloud point, over its voxel."""
    pts, t = voxel_downsample_with(np.asarray(frame.cloud3d, dtype=float), times, voxel, min_range, max_range)
    ext = np.asarray(frame.extrinsic3d, dtype=float)
    if np.any(ext != 0):
        pts = transform_points(pose_to_matrix(ext), pts)
    return pts, t


def unusable_reason(frame: Frame, dof: int, min_range: float, max_range: float, scan: NDArray[np.float64]) -> str:
    """Why a frame's scan (or cloud), ``scan`` after filtering, cannot be registered, counted from its readings."""
    dim = 2 if dof == 3 else 3
    raw = frame.scan2d.ranges if dof == 3 else frame.cloud3d
    n = len(raw)
    valid = len(frame.scan2d.points()) if dof == 3 else int(np.isfinite(raw).all(axis=1).sum())
    near = len(frame_points(frame, dof, min_range, max_range))
    what = "readings" if dof == 3 else "points"
    head = f"frame {frame.index} (stamp {frame.stamp}) has {len(scan)} usable points"
    why = (f"of its {n} {what}, {n - valid} are NaN, inf or no return and {valid - near} lie outside "
           f"{min_range}..{max_range} m")
    if len(scan) < 3 * dim:
        return f"{head} ({why}); at least {3 * dim} needed"
    return f"{head}, all on one {'line' if dim == 2 else 'plane'} ({why}): nothing to register"


def sampled_as_its_normal_says(points: NDArray[np.float64], normals: NDArray[np.float64], frame: Frame,
                               voxel: float, tree: cKDTree | None = None) -> NDArray[np.bool_]:
    """Which points (N, 2) of a 2D scan (``frame``'s, in the base frame) lie as densely as their normals say.

    A surface at range r whose normal makes the angle a with the beam is sampled every r * dtheta / cos(a) by a
    laser with the increment dtheta (never closer than ``voxel``). A point whose nearest neighbour lies more than
    ``SAMPLING_SLACK`` times further has the normal of no surface it lies on (a sparse point far down a corridor,
    its neighbours on both walls). ``tree``: a k-d tree of ``points`` already built.
    """
    if len(points) < 3:
        return np.ones(len(points), dtype=bool)
    ang = np.sort(np.asarray(frame.scan2d.angles, dtype=float))
    step = np.diff(ang)
    dtheta = float(np.median(step[step > 0])) if np.any(step > 0) else 0.0
    if dtheta <= 0.0:
        return np.ones(len(points), dtype=bool)
    ray = points - np.asarray(frame.extrinsic2d, dtype=float)[:2]
    r = np.linalg.norm(ray, axis=1)
    cos_a = np.abs(np.einsum("ij,ij->i", normals, ray)) / np.maximum(r, 1e-9)
    expected = np.maximum(r * dtheta / np.maximum(cos_a, 1e-3), voxel)
    nn = (tree if tree is not None else cKDTree(points)).query(points, k=2)[0][:, 1]
    return nn <= SAMPLING_SLACK * expected


def grazing_where_sparse(points: NDArray[np.float64], normals: NDArray[np.float64], frame: Frame,
                         voxel: float, tree: cKDTree | None = None) -> NDArray[np.float64]:
    """``normals`` (N, 2) with those :func:`sampled_as_its_normal_says` rejects turned across their beams.

    A point sampled that sparsely lies on a surface the beam grazes, whose normal is nearly square to the beam.
    """
    keep = sampled_as_its_normal_says(points, normals, frame, voxel, tree)
    if keep.all():
        return normals
    ray = points[~keep] - np.asarray(frame.extrinsic2d, dtype=float)[:2]
    ray /= np.maximum(np.linalg.norm(ray, axis=1, keepdims=True), 1e-12)
    out = normals.copy()
    out[~keep] = np.column_stack([-ray[:, 1], ray[:, 0]])
    return out
