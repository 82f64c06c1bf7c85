"""rerun recordings of hsmap runs: time, poses, points and paths, over the recording and its layout of
:mod:`~hsmap.viz.rerun_recording` (re-exported here) (rerun-sdk 0.41, pinned: its API moves between releases).

One recording per run, written to one ``.rrd`` file through a file sink (no viewer, no network; analytics
off); hsmap writes the bytes into the file itself (see :class:`Recording`). Open one with ``.venv/bin/rerun FILE.rrd``. Entity layout::

    world/                      ViewCoordinates RIGHT_HAND_Z_UP (x forward/east, y left/north, z up), metres
      robot                     Transform3D: the robot base pose, on the timelines
        lidar2d                 static Transform3D: the 2D LiDAR's extrinsic in the robot frame
          scan                  Points3D, the current 2D scan in the sensor frame (z = 0)
        lidar3d                 static Transform3D: the 3D LiDAR's extrinsic
          cloud                 Points3D, the current 3D cloud in the sensor frame
      trajectory/NAME           LineStrips3D, a whole path (static)
      map/points/NNNN           Points3D, the growing point map in blocks of scans (PointMapLogger)
      map/occupancy             GridMap (RViz "map" colours), placed by the grid's GridGeometry
      map/rooms                 GridMap RGBA of the room labels, just above the occupancy grid
      map/graph                 Points3D + LineStrips3D: the room/door graph at its world positions
    map/                        the 2D map view, in the grid's pixel frame (x = column, y = row, as images)
      occupancy                 Image (map_server grey levels)
      rooms                     SegmentationImage + AnnotationContext (one colour and name per room)
      graph, paths/NAME         Points2D / LineStrips2D converted from world (x, y) by GridGeometry
    graph                       GraphNodes + GraphEdges (GraphView), node positions = world (x, -y) * scale

Timelines: ``scan`` (sequence: the frame index) and ``time`` (seconds: a duration, or a timestamp when the
stamps are Unix times).

Every ``log_*`` function takes a :class:`Recording` (or a plain ``rerun.RecordingStream``) first and logs
with ``strict=True``, so bad data raises instead of being dropped with a warning.
"""

from __future__ import annotations

import os
from typing import Any

os.environ["RERUN_ANALYTICS"] = "0"  # before rerun is imported: never phone home from our runs

import numpy as np  # noqa: E402
import rerun as rr  # noqa: E402
from numpy.typing import ArrayLike, NDArray  # noqa: E402

from ..errors import InputError, ShapeError  # noqa: E402
from ..geometry import euler_to_matrix, matrix_to_quaternion  # noqa: E402
from ..maps.mapping import first_per_voxel  # noqa: E402
from .colors import VIEWER_SERIES_COLORS, height_colors  # noqa: E402
from .rerun_recording import (  # noqa: E402, F401  (the recording and its layout, re-exported)
    _UNIX_TIME_THRESHOLD,
    GRAPH,
    LEGEND,
    LIDAR2D,
    LIDAR3D,
    MAP2D,
    RERUN_VERSION,
    ROBOT,
    ROBOT_COLOR,
    WORLD,
    WORLD_MAP,
    Recording,
    _FileFeed,
    _stream,
    default_blueprint,
    eye_for_bounds,
    grid_bounds,
    log_legend,
    open_recording,
    series_legend,
)

__all__ = ["RERUN_VERSION", "Recording", "open_recording", "default_blueprint", "eye_for_bounds", "grid_bounds", "log_legend", "series_legend", "set_frame_time", "pose_transform", "log_robot_pose", "log_sensor_rig", "log_scan2d", "log_cloud", "log_frame", "log_points", "log_path", "log_trajectory"]


# --- time and poses ------------------------------------------------------------------------------------


def set_frame_time(rec: Any, index: int, stamp: float | None = None) -> None:
    """Set the ``scan`` timeline to ``index`` and, when given, ``time`` to ``stamp`` seconds.

    Stamps above 1e8 s are taken as Unix times (a timestamp timeline), smaller ones as durations.
    """
    s = _stream(rec)
    s.set_time("scan", sequence=int(index))
    if stamp is not None:
        stamp = float(stamp)
        if not np.isfinite(stamp):
            raise InputError(f"frame stamp must be finite seconds, got {stamp}")
        if stamp > _UNIX_TIME_THRESHOLD:
            s.set_time("time", timestamp=stamp)
        else:
            s.set_time("time", duration=stamp)


def _pose6(pose: ArrayLike, name: str = "pose") -> NDArray[np.float64]:
    p = np.asarray(pose, dtype=float)
    if p.shape[-1:] == (3,):
        q = np.zeros(p.shape[:-1] + (6,))
        q[..., :2] = p[..., :2]
        q[..., 5] = p[..., 2]
        p = q
    if p.shape[-1:] != (6,):
        raise ShapeError(f"{name} must be (x, y, yaw) or (x, y, z, roll, pitch, yaw), got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise InputError(f"{name} has NaN or inf values")
    return p


def _translation_quaternion(pose: ArrayLike, name: str = "pose") -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    p = _pose6(pose, name)
    q = matrix_to_quaternion(euler_to_matrix(p[..., 3], p[..., 4], p[..., 5]))
    return p[..., :3], q


def pose_transform(pose: ArrayLike) -> rr.Transform3D:
    """``rr.Transform3D`` of a pose (x, y, yaw) or (x, y, z, roll, pitch, yaw) (child -> parent)."""
    t, q = _translation_quaternion(pose)
    return rr.Transform3D(translation=t, quaternion=rr.Quaternion(xyzw=q))


def log_robot_pose(rec: Any, pose: ArrayLike, *, entity: str = ROBOT) -> None:
    """Log the robot base pose (3- or 6-DOF) at the current time."""
    _stream(rec).log(entity, pose_transform(pose), strict=True)


def log_sensor_rig(
    rec: Any,
    *,
    extrinsic2d: ArrayLike | None = None,
    extrinsic3d: ArrayLike | None = None,
    lidar2d_height: float = 0.0,
    robot: str = ROBOT,
    axis_length: float = 0.3,
) -> None:
    """Log the fixed sensor extrinsics beneath the robot (static) and axes on the robot.

    Parameters
    ----------
    extrinsic2d : array of shape (3,), optional
        (x, y, yaw) of the 2D LiDAR in the robot frame; it sits ``lidar2d_height`` metres above the base.
    extrinsic3d : array of shape (6,), optional
        (x, y, z, roll, pitch, yaw) of the 3D LiDAR in the robot frame.
    """
    s = _stream(rec)
    s.log(robot, rr.TransformAxes3D(axis_length), static=True, strict=True)
    # a body to find the robot by (orange, a 0.6 x 0.44 x 0.3 m box on the floor, its front marked by the axes)
    s.log(f"{robot}/body", rr.Boxes3D(centers=[[0.0, 0.0, 0.15]], half_sizes=[[0.3, 0.22, 0.15]],
                                      colors=ROBOT_COLOR, fill_mode="solid"), static=True, strict=True)
    if extrinsic2d is not None:
        e = np.asarray(extrinsic2d, dtype=float)
        if e.shape != (3,):
            raise ShapeError(f"extrinsic2d must be (x, y, yaw), got shape {e.shape}")
        s.log(f"{robot}/lidar2d", pose_transform([e[0], e[1], lidar2d_height, 0.0, 0.0, e[2]]),
              rr.TransformAxes3D(axis_length / 2), static=True, strict=True)
    if extrinsic3d is not None:
        e = np.asarray(extrinsic3d, dtype=float)
        if e.shape != (6,):
            raise ShapeError(f"extrinsic3d must be (x, y, z, roll, pitch, yaw), got shape {e.shape}")
        s.log(f"{robot}/lidar3d", pose_transform(e), rr.TransformAxes3D(axis_length / 2), static=True, strict=True)


# --- points --------------------------------------------------------------------------------------------


def _points(points: ArrayLike, dims: tuple[int, ...], name: str) -> NDArray[np.float64]:
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] not in dims:
        raise ShapeError(f"{name} must have shape (N, {' or '.join(map(str, dims))}), got {p.shape}")
    return p[np.all(np.isfinite(p), axis=1)]


def log_points(
    rec: Any,
    entity: str,
    points: ArrayLike,
    *,
    colors: ArrayLike | None = None,
    color_by_height: bool = False,
    z_range: tuple[float, float] | None = None,
    radius: float = 0.02,
    voxel: float | None = None,
    static: bool = False,
) -> int:
    """Log (N, 2) or (N, 3) points as ``Points3D`` (z = 0 for 2D points); returns the number logged.

    Parameters
    ----------
    colors : array of shape (3,) or (N, 3), optional
        RGB 0-255 (ignored when ``voxel`` drops points and colours are per point).
    color_by_height : bool
        Colour by z over ``z_range`` (see :func:`hsmap.viz.colors.height_colors`).
    radius : float
        Point radius in metres.
    voxel : float, optional
        Keep one point per voxel of this side (metres) before logging.
    """
    p = _points(points, (2, 3), "points")
    if p.shape[1] == 2:
        p = np.column_stack([p, np.zeros(len(p))])
    if voxel is not None:
        p = first_per_voxel(p, voxel)
        if colors is not None and np.ndim(colors) == 2:
            colors = None
    if color_by_height:
        colors = height_colors(p[:, 2], z_range)
    _stream(rec).log(entity, rr.Points3D(p, colors=colors, radii=radius), static=static, strict=True)
    return len(p)


def log_scan2d(
    rec: Any, points: ArrayLike, *, entity: str = f"{LIDAR2D}/scan", color: ArrayLike = (230, 90, 30),
    radius: float = 0.025,
) -> None:
    """Log a 2D scan's (K, 2) points, in the 2D LiDAR frame, at the current time."""
    log_points(rec, entity, points, colors=color, radius=radius)


def log_cloud(
    rec: Any, points: ArrayLike, *, entity: str = f"{LIDAR3D}/cloud", voxel: float | None = 0.1,
    z_range: tuple[float, float] | None = (-2.0, 2.0), radius: float = 0.02,
) -> int:
    """Log a 3D cloud (N, 3), in the 3D LiDAR frame, coloured by height, voxel-downsampled (``voxel`` m)."""
    return log_points(rec, entity, points, color_by_height=True, z_range=z_range, radius=radius, voxel=voxel)


def log_frame(
    rec: Any,
    frame: Any,
    pose: ArrayLike,
    *,
    index: int | None = None,
    lidar2d_height: float = 0.0,
    cloud_voxel: float | None = 0.1,
) -> None:
    """Log one :class:`hsmap.datasets.Frame` with the robot's estimated pose: time, pose, 2D scan, 3D cloud.

    The sensor extrinsics (from the frame) are logged once per :class:`Recording`.
    """
    index = frame.index if index is None else index
    set_frame_time(rec, index, frame.stamp)
    if not getattr(rec, "rig_logged", False):
        log_sensor_rig(rec, extrinsic2d=frame.extrinsic2d if frame.scan2d is not None else None,
                       extrinsic3d=frame.extrinsic3d if frame.cloud3d is not None else None,
                       lidar2d_height=lidar2d_height)
        if isinstance(rec, Recording):
            rec.rig_logged = True
    log_robot_pose(rec, pose)
    if frame.scan2d is not None:
        log_scan2d(rec, frame.scan2d.points())
    if frame.cloud3d is not None:
        log_cloud(rec, frame.cloud3d, voxel=cloud_voxel)


def _path_positions(poses: Any, z: float | None) -> NDArray[np.float64]:
    poses = getattr(poses, "poses", poses)  # a Trajectory
    p = np.asarray(poses, dtype=float)
    if p.ndim != 2 or p.shape[1] not in (2, 3, 6):
        raise ShapeError(f"poses must be (N, 2) positions or (N, 3)/(N, 6) poses, got shape {p.shape}")
    if p.shape[1] == 6:
        xyz = p[:, :3].copy()
    else:
        xyz = np.column_stack([p[:, :2], np.zeros(len(p))])
    if z is not None:
        xyz[:, 2] = z
    return xyz


def log_path(
    rec: Any,
    name: str,
    poses: Any,
    *,
    color: ArrayLike | None = None,
    radius: float = 0.03,
    z: float | None = None,
    entity: str | None = None,
    static: bool = True,
    label: str | None = None,
) -> None:
    """Log a whole path as one line strip at ``world/trajectory/NAME`` (static by default).

    Parameters
    ----------
    name : str
        "groundtruth", "odometry", "estimate", ... (sets the default colour, see ``VIEWER_SERIES_COLORS``;
        :func:`series_legend` says which is which).
    poses : Trajectory or array of shape (N, 2), (N, 3) or (N, 6)
    z : float, optional
        Height of the line for planar paths (default 0; 6-DOF paths keep their own z).
    static : bool
        False logs the path at the current time (a path drawn up to now, logged again as it grows).
    label : str, optional
        A text label on the line (none by default: rerun draws every label of a strip on one spot).
    """
    xyz = _path_positions(poses, z)
    color = VIEWER_SERIES_COLORS.get(name, VIEWER_SERIES_COLORS["other"]) if color is None else color
    _stream(rec).log(entity or f"{WORLD}/trajectory/{name}",
                     rr.LineStrips3D([xyz], colors=color, radii=radius, labels=None if label is None else [label]),
                     static=static, strict=True)


def log_trajectory(
    rec: Any,
    trajectory: Any,
    *,
    name: str = "estimate",
    robot_entity: str | None = ROBOT,
    indices: ArrayLike | None = None,
    color: ArrayLike | None = None,
) -> None:
    """A trajectory at once: its path (static line) and, on the timelines, the robot pose at every stamp.

    Parameters
    ----------
    trajectory : hsmap.trajectory.Trajectory
        Stamps and (N, 3) or (N, 6) poses.
    robot_entity : str or None
        Where the moving pose goes (``world/robot``); None logs the path only.
    indices : array of int, optional
        ``scan`` values for the poses (default 0..N-1).
    """
    stamps = np.asarray(trajectory.stamps, dtype=float)
    poses = np.asarray(trajectory.poses, dtype=float)
    log_path(rec, name, poses, color=color)
    if robot_entity is None:
        return
    n = len(poses)
    idx = np.arange(n) if indices is None else np.asarray(indices, dtype=np.int64)
    if idx.shape != (n,):
        raise ShapeError(f"indices must have shape ({n},), got {idx.shape}")
    t, q = _translation_quaternion(poses, "trajectory.poses")
    time_col = (rr.TimeColumn("time", timestamp=stamps) if n and stamps.max() > _UNIX_TIME_THRESHOLD
                else rr.TimeColumn("time", duration=stamps))
    _stream(rec).send_columns(
        robot_entity,
        indexes=[rr.TimeColumn("scan", sequence=idx), time_col],
        columns=rr.Transform3D.columns(translation=t, quaternion=q),
        strict=True,
    )
