"""The slice of a 3D map at a height band as a 2D occupancy grid, from the 3D clouds placed at their poses.

For every cloud, the points between ``z_min`` and ``z_max`` are reduced to a *virtual 2D scan* at the slice
height (:func:`slice_scan`: the nearest such point in each azimuth bin, seen from the 3D sensor) and these scans
are rasterised like 2D LiDAR scans (:func:`slice_grid`, :func:`hsmap.maps.grid.grid_from_scans`): occupied at
the points, free along the way. (Free space from floor points does not work for a 3D LiDAR 1.6 m up with a
22.5 deg downward field of view: it sees no floor within 3.9 m of the robot.)

Coordinates: world (x, y[, z]) in metres, z up, the floor at z = 0.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import EmptyInputError, InputError, ShapeError
from ..geometry import matrix_to_pose, pose_to_matrix
from .grid import GridGeometry, OccupancyGrid, grid_from_scans


def slice_points(points: ArrayLike, z_min: float = 1.7, z_max: float = 1.8) -> NDArray[np.float64]:
    """The (x, y) of the points of a 3D map (N, 3) with ``z_min <= z < z_max``: (K, 2)."""
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ShapeError(f"points must have shape (N, 3) (a 3D map), got {pts.shape}")
    if not z_min < z_max:
        raise InputError(f"the slice needs z_min < z_max, got {z_min} >= {z_max}")
    m = (pts[:, 2] >= z_min) & (pts[:, 2] < z_max) & np.all(np.isfinite(pts), axis=1)
    return pts[m, :2].copy()


def _pose6(pose: ArrayLike, name: str) -> NDArray[np.float64]:
    p = np.asarray(pose, dtype=float).reshape(-1)
    if p.shape == (3,):
        return np.array([p[0], p[1], 0.0, 0.0, 0.0, p[2]])
    if p.shape == (6,):
        return p
    raise ShapeError(f"{name} must be a pose (x, y, yaw) or (x, y, z, roll, pitch, yaw), got shape {p.shape}")


def slice_scan(points: ArrayLike, sensor_pose: ArrayLike, *, z_min: float = 1.7, z_max: float = 1.8,
               bins: int = 720) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A 3D cloud's slice as a virtual 2D scan at the slice height.

    The points with world height in ``[z_min, z_max)`` are binned by their azimuth around the sensor; in each
    bin the nearest one (horizontally) is the scan's end point: the first obstacle at that height.

    Parameters
    ----------
    points : ndarray of shape (N, 3)
        The cloud in the 3D sensor's frame.
    sensor_pose : ndarray of shape (6,) or (3,)
        World pose of the 3D sensor (x, y, z, roll, pitch, yaw); (x, y, yaw) means a level sensor at z = 0.
    z_min, z_max : float
        The slice, world heights.
    bins : int
        Azimuth bins over 360 deg.

    Returns
    -------
    scan : ndarray of shape (K, 2)
        End points in the frame of a level virtual sensor at the 3D sensor's (x, y) and yaw, in azimuth order
        (bins without a point in the slice are left out), with a row of NaN where two consecutive end points
        are more than twice the scan's median spacing apart in azimuth: nothing was seen at the slice height
        between them (a 3D LiDAR with few channels crosses the slice only at some distances), and
        :func:`hsmap.maps.grid.grid_from_scans` then takes the free area back to the sensor there (a beam without a
        return) instead of across the unseen part.
    pose : ndarray of shape (3,)
        World (x, y, yaw) of that virtual sensor.
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ShapeError(f"points must have shape (N, 3), got {pts.shape}")
    if not z_min < z_max:
        raise InputError(f"the slice needs z_min < z_max, got {z_min} >= {z_max}")
    if bins < 1:
        raise InputError(f"bins must be >= 1, got {bins}")
    T = pose_to_matrix(_pose6(sensor_pose, "sensor_pose"))
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    z = pts @ T[2, :3] + T[2, 3]
    band = (z >= z_min) & (z < z_max)
    xy = pts[band] @ T[:2, :3].T + T[:2, 3]
    origin = T[:2, 3]
    yaw = float(np.arctan2(T[1, 0], T[0, 0]))
    pose2 = np.array([origin[0], origin[1], yaw])
    if not len(xy):
        return np.empty((0, 2)), pose2
    d = xy - origin
    r = np.hypot(d[:, 0], d[:, 1])
    az = np.arctan2(d[:, 1], d[:, 0])
    b = np.floor((az + np.pi) / (2 * np.pi) * bins).astype(np.int64) % bins
    order = np.lexsort((r, b))
    first = np.ones(len(order), dtype=bool)
    first[1:] = b[order][1:] != b[order][:-1]
    sel = order[first]  # nearest point of each bin, bins ascending = azimuth order
    c, s = np.cos(yaw), np.sin(yaw)
    local = d[sel] @ np.array([[c, -s], [s, c]])  # world offsets rotated into the virtual sensor frame
    if len(sel) > 2:
        gap = np.diff(b[sel])
        unseen = np.flatnonzero(gap > 2 * np.median(gap))
        if len(unseen):
            local = np.insert(local, unseen + 1, np.nan, axis=0)
    return local, pose2


def slice_scans(
    frames: Iterable,
    poses: ArrayLike,
    *,
    z_min: float = 1.7,
    z_max: float = 1.8,
    bins: int = 720,
) -> tuple[list[NDArray[np.float64]], NDArray[np.float64]]:
    """Every frame's 3D cloud as a virtual 2D scan at the slice height (:func:`slice_scan`).

    Parameters
    ----------
    frames : iterable of Frame
        Frames with ``cloud3d`` (in the 3D sensor frame) and ``extrinsic3d``; as many as ``poses``.
    poses : ndarray of shape (M, 6) or (M, 3)
        World poses of the robot base (6-DOF, or (x, y, yaw) on a flat floor).

    Returns
    -------
    scans : list of ndarray of shape (K_i, 2)
        The scans with at least two points, each in its virtual sensor's frame, in azimuth order (NaN rows:
        unseen gaps, see :func:`slice_scan`).
    sensor_poses : ndarray of shape (S, 3)
        World (x, y, yaw) of each scan's virtual sensor.

    Raises
    ------
    InputError
        A frame has no 3D cloud.
    ShapeError
        Frames and poses differ in number.
    """
    P = np.asarray(poses, dtype=float)
    if P.ndim != 2 or P.shape[1] not in (3, 6):
        raise ShapeError(f"poses must have shape (M, 6) or (M, 3), got {P.shape}")
    scans, spos = [], []
    n = 0
    for k, fr in enumerate(frames):
        if k >= len(P):
            raise ShapeError(f"more frames than the {len(P)} poses")
        if fr.cloud3d is None:
            raise InputError(f"frame {fr.index} (stamp {fr.stamp}) has no 3D cloud: the slice needs them")
        sensor = pose_to_matrix(_pose6(P[k], f"poses[{k}]")) @ pose_to_matrix(_pose6(fr.extrinsic3d, "extrinsic3d"))
        scan, p2 = slice_scan(fr.cloud3d, matrix_to_pose(sensor), z_min=z_min, z_max=z_max, bins=bins)
        n += 1
        if np.isfinite(scan[:, 0]).sum() >= 2:
            scans.append(scan)
            spos.append(p2)
    if n != len(P):
        raise ShapeError(f"{n} frames but {len(P)} poses")
    return scans, np.asarray(spos, dtype=float).reshape(-1, 3)


def slice_grid(
    frames: Iterable,
    poses: ArrayLike,
    *,
    z_min: float = 1.7,
    z_max: float = 1.8,
    resolution: float = 0.05,
    bins: int = 720,
    geometry: GridGeometry | None = None,
    margin: float = 0.5,
) -> OccupancyGrid:
    """Occupancy grid of the slice ``[z_min, z_max)`` of a 3D map made of clouds at known poses.

    Each frame's cloud becomes a virtual 2D scan at the slice height (:func:`slice_scans`) and the scans are
    rasterised by :func:`hsmap.maps.grid.grid_from_scans`: occupied where the slice has points, free along the
    sight lines at that height, unknown elsewhere.

    Parameters
    ----------
    frames : iterable of Frame
        Frames with ``cloud3d`` (in the 3D sensor frame) and ``extrinsic3d``; as many as ``poses``.
    poses : ndarray of shape (M, 6) or (M, 3)
        World poses of the robot base (6-DOF, or (x, y, yaw) on a flat floor).
    z_min, z_max, resolution, bins, geometry, margin
        The slice, the cell size, the azimuth bins, and the grid (default: covering all scans plus
        ``margin``).

    Raises
    ------
    InputError
        A frame has no 3D cloud.
    ShapeError
        Frames and poses differ in number.
    EmptyInputError
        No cloud has a point in the slice.
    """
    scans, spos = slice_scans(frames, poses, z_min=z_min, z_max=z_max, bins=bins)
    if not scans:
        raise EmptyInputError(f"no 3D cloud has points in the slice {z_min} <= z < {z_max} m")
    return grid_from_scans(scans, spos, resolution, geometry=geometry, margin=margin)
