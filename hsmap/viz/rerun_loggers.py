"""Frames and the growing point map logged in blocks, as columns (:class:`FrameLogger`, :class:`PointMapLogger`)."""

from __future__ import annotations

import math
import os
from typing import Any

os.environ["RERUN_ANALYTICS"] = "0"  # before rerun is imported: never phone home from our runs

import numpy as np  # noqa: E402
import rerun as rr  # noqa: E402
from numpy.typing import ArrayLike, NDArray  # noqa: E402

from ..errors import InputError  # noqa: E402
from ..maps.mapping import first_per_voxel  # noqa: E402
from .colors import height_colors  # noqa: E402
from .rerun_core import (  # noqa: E402
    _UNIX_TIME_THRESHOLD,
    LIDAR2D,
    LIDAR3D,
    ROBOT,
    WORLD_MAP,
    Recording,
    _points,
    _pose6,
    _stream,
    _translation_quaternion,
    log_points,
    log_sensor_rig,
)

__all__ = ["FrameLogger", "PointMapLogger"]

class FrameLogger:
    """The frames of a run logged as :func:`log_frame` logs them (robot pose, 2D scan, 3D cloud, on the ``scan``
    and ``time`` timelines), ``block`` frames at a time as columns (``rr.send_columns``): one call per entity
    per block instead of three or four per frame, which keeps the recording off the hot path of a long run.

    Call :meth:`add` for each frame, :meth:`flush` after the last. The viewer shows the same entities at the
    same times as with :func:`log_frame` (row-logged data also carries rerun's ``log_tick``/``log_time``
    timelines, which these columns do not).

    Parameters
    ----------
    rec : Recording
    block : int
        Frames per block.
    cloud_voxel : float, optional
        Voxel side (metres) the 3D clouds are thinned to (as :func:`log_frame`'s ``cloud_voxel``).
    lidar2d_height : float
        Height of the 2D LiDAR above the base (the sensor rig, logged once).
    """

    def __init__(self, rec: Any, *, block: int = 64, cloud_voxel: float | None = 0.1,
                 lidar2d_height: float = 0.0) -> None:
        if int(block) < 1:
            raise InputError(f"block must be >= 1 frames, got {block}")
        self.rec, self.block, self.cloud_voxel, self.lidar2d_height = rec, int(block), cloud_voxel, lidar2d_height
        self._rows: list[tuple[int, float, NDArray[np.float64], Any, Any]] = []
        self.frames_logged = 0

    def add(self, frame: Any, pose: ArrayLike, *, index: int | None = None) -> None:
        """Queue one :class:`hsmap.datasets.Frame` with the robot's estimated pose (logged at the next block)."""
        index = frame.index if index is None else index
        stamp = float(frame.stamp)
        if not np.isfinite(stamp):
            raise InputError(f"frame stamp must be finite seconds, got {stamp}")
        if not getattr(self.rec, "rig_logged", False):
            log_sensor_rig(self.rec, extrinsic2d=frame.extrinsic2d if frame.scan2d is not None else None,
                           extrinsic3d=frame.extrinsic3d if frame.cloud3d is not None else None,
                           lidar2d_height=self.lidar2d_height)
            if isinstance(self.rec, Recording):
                self.rec.rig_logged = True
        cloud = None
        if frame.cloud3d is not None:
            cloud = _points(frame.cloud3d, (2, 3), "points")
            if self.cloud_voxel is not None:
                cloud = first_per_voxel(cloud, self.cloud_voxel)
        p = np.array(pose, dtype=float)  # a copy: the caller's array may change before the block is sent
        if p.shape not in ((3,), (6,)) or not all(map(math.isfinite, p.tolist())):
            _pose6(p)  # raises, naming what is wrong
        # the 2D scan's points are computed for the whole block at once (:func:`_scan_points`)
        self._rows.append((int(index), stamp, p, frame.scan2d, cloud))
        if len(self._rows) >= self.block:
            self.flush()

    def flush(self) -> None:
        """Log the queued frames."""
        rows, self._rows = self._rows, []
        if not rows:
            return
        stamps = np.array([r[1] for r in rows])
        unix = stamps > _UNIX_TIME_THRESHOLD
        for part in (np.flatnonzero(unix), np.flatnonzero(~unix)):  # one kind of time column per call
            if len(part):
                self._send([rows[i] for i in part], bool(unix[part[0]]))
        self.frames_logged += len(rows)

    def _send(self, rows: list, unix: bool) -> None:
        s = _stream(self.rec)

        def times(sel: list[int]) -> list[rr.TimeColumn]:
            idx = np.array([rows[i][0] for i in sel], dtype=np.int64)
            st = np.array([rows[i][1] for i in sel])
            when = rr.TimeColumn("time", timestamp=st) if unix else rr.TimeColumn("time", duration=st)
            return [rr.TimeColumn("scan", sequence=idx), when]

        everyone = list(range(len(rows)))
        poses = [r[2] for r in rows]
        same = len({p.shape for p in poses}) == 1  # (x, y, yaw) or 6-DOF poses, converted in one call
        t, q = _translation_quaternion(np.stack(poses) if same else np.stack([_pose6(p) for p in poses]))
        s.send_columns(ROBOT, indexes=times(everyone), columns=rr.Transform3D.columns(translation=t, quaternion=q),
                       strict=True)
        for k, entity in ((3, f"{LIDAR2D}/scan"), (4, f"{LIDAR3D}/cloud")):
            sel = [i for i in everyone if rows[i][k] is not None]
            if not sel:
                continue
            if k == 3:
                allp, lengths = _scan_points([rows[i][k] for i in sel])
            else:
                pts = [rows[i][k] for i in sel]
                pts = [np.column_stack([p, np.zeros(len(p))]) if p.shape[1] == 2 else p for p in pts]
                lengths = np.array([len(p) for p in pts])
                allp = np.concatenate(pts)
            if k == 3:  # log_scan2d's colour and radius
                cols = rr.Points3D.columns(positions=allp).partition(lengths)
                style = rr.Points3D.columns(colors=np.tile(np.array([230, 90, 30], dtype=np.uint8), (len(sel), 1)),
                                            radii=np.full(len(sel), 0.025, dtype=np.float32))
            else:  # log_cloud's height colours and radius
                cols = rr.Points3D.columns(positions=allp, colors=height_colors(allp[:, 2], (-2.0, 2.0))
                                           ).partition(lengths)
                style = rr.Points3D.columns(radii=np.full(len(sel), 0.02, dtype=np.float32))
            s.send_columns(entity, indexes=times(sel), columns=[*cols, *style], strict=True)


def _scan_points(scans: list) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """The finite points of 2D scans (:meth:`hsmap.datasets.LaserScan2D.points`, at z = 0) computed in one pass:
    all their points (N, 3), scan after scan, and each scan's count."""
    r = np.concatenate([np.asarray(s.ranges, dtype=float).reshape(-1) for s in scans])
    a = np.concatenate([np.asarray(s.angles, dtype=float).reshape(-1) for s in scans])
    sizes = [np.asarray(s.ranges).size for s in scans]
    which = np.repeat(np.arange(len(scans)), sizes)
    lo = np.repeat([float(s.range_min) for s in scans], sizes)
    hi = np.repeat([float(s.range_max) for s in scans], sizes)
    ok = np.isfinite(r) & (r >= lo) & (r < hi)
    r, a, which = r[ok], a[ok], which[ok]
    pts = np.column_stack([r * np.cos(a), r * np.sin(a), np.zeros(len(r))])
    finite = np.all(np.isfinite(pts), axis=1)
    return pts[finite], np.bincount(which[finite], minlength=len(scans))


class PointMapLogger:
    """A growing point map on the timelines: world-frame points added scan by scan, logged in blocks.

    Each block of ``block`` scans becomes one entity ``entity/NNNN`` logged at the time of its last scan, so
    the viewer shows the map as it was built (latest-at every block) without re-sending old points; the
    current scan itself is what :func:`log_frame` shows. Call :meth:`flush` after the last scan.

    Parameters
    ----------
    rec : Recording
    entity : str
    block : int
        Scans per block.
    voxel : float, optional
        Voxel side (metres) to thin each block.
    z_range : (float, float)
        Height range of the colour ramp (fixed, so blocks are coloured alike); None for one colour.
    color : (3,) RGB, optional
        Used when ``z_range`` is None.
    """

    def __init__(
        self,
        rec: Any,
        *,
        entity: str = f"{WORLD_MAP}/points",
        block: int = 10,
        voxel: float | None = 0.05,
        z_range: tuple[float, float] | None = (-0.2, 3.0),
        color: ArrayLike = (90, 90, 90),
        radius: float = 0.02,
    ):
        if int(block) < 1:
            raise InputError(f"block must be >= 1 scans, got {block}")
        self.rec, self.entity, self.block = rec, entity, int(block)
        self.voxel, self.z_range, self.color, self.radius = voxel, z_range, color, radius
        self._pending: list[NDArray[np.float64]] = []
        self._scans = 0
        self.blocks = 0
        self.points_logged = 0

    def add(self, points_world: ArrayLike) -> None:
        """Add one scan's points (N, 2) or (N, 3), already in the world frame."""
        p = _points(points_world, (2, 3), "points_world")
        if p.shape[1] == 2:
            p = np.column_stack([p, np.zeros(len(p))])
        self._pending.append(p)
        self._scans += 1
        if self._scans >= self.block:
            self.flush()

    def flush(self) -> None:
        """Log the pending scans as one block (at the current time)."""
        if not self._pending:
            return
        p = np.concatenate(self._pending)
        self._pending, self._scans = [], 0
        self.points_logged += log_points(
            self.rec, f"{self.entity}/{self.blocks:04d}", p,
            colors=None if self.z_range is not None else self.color,
            color_by_height=self.z_range is not None, z_range=self.z_range, radius=self.radius, voxel=self.voxel,
        )
        self.blocks += 1
