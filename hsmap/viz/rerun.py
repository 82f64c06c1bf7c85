"""rerun recordings of hsmap runs (rerun-sdk 0.41, pinned: its API moves between releases).

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

import atexit
import os
import re
import shutil
import subprocess
import sys
import threading
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

os.environ["RERUN_ANALYTICS"] = "0"  # before rerun is imported: never phone home from our runs

import numpy as np  # noqa: E402
import rerun as rr  # noqa: E402
import rerun.blueprint as rrb  # noqa: E402
from numpy.typing import ArrayLike, NDArray  # noqa: E402

from ..errors import DataFormatError, HsmapError, InputError, OutputError, ShapeError  # noqa: E402
from ..geometry import euler_to_matrix, matrix_to_quaternion  # noqa: E402
from ..grid import GridGeometry  # noqa: E402
from ..io import locked_temporary, publish_file, write_failure_reason  # noqa: E402
from ..mapping import first_per_voxel  # noqa: E402
from .colors import ROOM_PALETTE, VIEWER_SERIES_COLORS, height_colors, label_color, label_colors  # noqa: E402
from .occupancy import _ros_to_image, occupancy_to_image, occupancy_to_ros  # noqa: E402

__all__ = [
    "RERUN_VERSION",
    "FrameLogger",
    "Recording",
    "open_recording",
    "default_blueprint",
    "eye_for_bounds",
    "grid_bounds",
    "log_legend",
    "series_legend",
    "log_rgba_grid",
    "log_map2d_robot",
    "log_map2d_robots",
    "log_map2d_points",
    "set_frame_time",
    "pose_transform",
    "log_robot_pose",
    "log_sensor_rig",
    "log_scan2d",
    "log_cloud",
    "log_frame",
    "log_points",
    "log_path",
    "log_trajectory",
    "PointMapLogger",
    "occupancy_to_ros",
    "occupancy_to_image",
    "log_occupancy_grid",
    "room_annotation_context",
    "log_room_labels",
    "world_to_map2d",
    "log_map2d_path",
    "log_room_graph",
    "rerun_binary",
    "verify_rrd",
    "recording_contents",
]

RERUN_VERSION = rr.__version__

WORLD = "world"
ROBOT = "world/robot"
LIDAR2D = "world/robot/lidar2d"
LIDAR3D = "world/robot/lidar3d"
WORLD_MAP = "world/map"
MAP2D = "map"
GRAPH = "graph"
LEGEND = "legend"
ROBOT_COLOR = (255, 140, 0)

_UNIX_TIME_THRESHOLD = 1e8  # seconds: stamps above this (after 1973) are taken as Unix times




def _stream(rec: Any) -> rr.RecordingStream:
    if isinstance(rec, Recording):
        if rec.closed:
            raise HsmapError(f"the recording {rec.path} is closed")
        return rec.stream
    if isinstance(rec, rr.RecordingStream):
        return rec
    raise InputError(f"expected an hsmap Recording or a rerun.RecordingStream, got {type(rec).__name__}")


class _FileFeed:
    """The bytes of a rerun file sink, written into an open file descriptor by a thread of ours.

    rerun's file sink writes from a background thread of its own and, when the write fails (a full disk), only
    logs it, and sometimes (rerun-sdk 0.41) never wakes the ``flush`` or ``disconnect`` that waits for it: the
    run, and then the interpreter's exit, hang. So the sink writes into a pipe (``/dev/fd/N``), which cannot fail;
    this thread copies the pipe into the file, remembers the first ``OSError`` and keeps draining the pipe after
    it, so rerun always finishes. :meth:`close` returns the error, if any.
    """

    def __init__(self, fd: int):
        self._out = fd
        self.error: Exception | None = None
        self._read, self._write = os.pipe()
        try:
            import fcntl

            fcntl.fcntl(self._write, fcntl.F_SETPIPE_SZ, 1 << 20)  # fewer wake-ups; the default 64 KiB works too
        except (ImportError, AttributeError, OSError):
            pass
        self.sink_path = f"/dev/fd/{self._write}"
        self._thread = threading.Thread(target=self._copy, name="hsmap-rrd-writer", daemon=True)
        self._thread.start()

    @staticmethod
    def available() -> bool:
        return sys.platform.startswith("linux") and os.path.isdir("/dev/fd")

    def _copy(self) -> None:
        while True:
            data = os.read(self._read, 1 << 20)
            if not data:
                return
            if self.error is None:
                try:
                    self._put(data)
                except Exception as exc:  # OSError (a full disk); whatever it is, keep draining the pipe
                    self.error = exc

    def _put(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            view = view[os.write(self._out, view):]

    def close(self) -> Exception | None:
        """After rerun has closed its end (``disconnect``): wait for the last bytes; the write error, if any."""
        os.close(self._write)
        self._thread.join()
        os.close(self._read)
        return self.error


class Recording:
    """A rerun recording written to one ``.rrd`` file, atomically.

    The data goes to a temporary file beside ``path`` and is renamed to ``path`` by :meth:`close` (or on
    leaving a ``with`` block without an error; with an error, the temporary file is deleted). A recording
    still open when the interpreter exits is closed then.

    Parameters
    ----------
    path : str or path-like
        The ``.rrd`` to write.
    application_id : str
        rerun's application id (recordings of one application share blueprints in the viewer).
    recording_id : str, optional
        rerun's recording id (random by default).
    blueprint : rerun.blueprint.Blueprint, optional
        The layout the viewer opens with (see :func:`default_blueprint`).

    Attributes
    ----------
    path : pathlib.Path
    stream : rerun.RecordingStream
        Use it for anything the ``log_*`` helpers do not cover; the recording also forwards attribute
        access to it (``rec.log(...)``, ``rec.set_time(...)``).
    """

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        application_id: str = "hsmap",
        recording_id: str | None = None,
        blueprint: Any = None,
    ):
        self.path = Path(path)
        if self.path.suffix != ".rrd":
            raise InputError(f"a rerun recording file must end in .rrd, got {self.path}")
        self._fd, self._tmp = locked_temporary(self.path, ".tmp.rrd")  # locked: a rerun can tell it from a leftover
        self.closed = False
        self.rig_logged = False
        # rerun wants application ids that are entry names: letters, digits, '-' and '_'
        self.application_id = re.sub(r"[^A-Za-z0-9_-]+", "_", application_id).strip("_") or "hsmap"
        self.stream = rr.RecordingStream(self.application_id, recording_id=recording_id)
        self.stream.set_log_time_enabled(False)  # only our timelines: scan and time
        self.stream.set_log_tick_enabled(False)
        self._feed = _FileFeed(self._fd) if _FileFeed.available() else None
        sink = self._feed.sink_path if self._feed is not None else str(self._tmp)
        self.stream.set_sinks(rr.FileSink(sink), default_blueprint=blueprint)
        self.stream.log(WORLD, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True, strict=True)
        atexit.register(self.close)

    def __getattr__(self, item: str) -> Any:
        if item in ("stream", "__setstate__") or item.startswith("__"):
            raise AttributeError(item)
        return getattr(self.stream, item)

    def __repr__(self) -> str:
        return f"Recording({str(self.path)!r}{', closed' if self.closed else ''})"

    def __enter__(self) -> Recording:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def close(self) -> Path:
        """Flush, close the file and move it to :attr:`path` once it checks out complete (synced, rerun's footer
        present: :func:`hsmap.io.verify_output`); returns the path. Idempotent.

        Raises
        ------
        OutputError
            The recording could not be written completely (e.g. no space left); the temporary file is deleted
            and :attr:`path` is left as it was.
        """
        if not self.closed:
            self.closed = True
            atexit.unregister(self.close)
            try:
                try:
                    try:
                        self.stream.flush()
                    finally:
                        self.stream.disconnect()
                except RuntimeError as exc:  # rerun's own file writer stopped (no feed): it only logs why
                    why = write_failure_reason(self.path.parent, f"rerun: {exc}")
                    raise OutputError(f"{self.path}: cannot write it ({why})") from None
                finally:
                    error = self._feed.close() if self._feed is not None else None
                if error is not None:
                    raise OutputError(f"{self.path}: cannot write it ({getattr(error, 'strerror', None) or error})")
                publish_file(self._tmp, self.path)
            except BaseException:
                self._tmp.unlink(missing_ok=True)
                raise
            finally:
                os.close(self._fd)
        return self.path

    def abort(self) -> None:
        """Close without publishing: the temporary file is deleted, :attr:`path` is left as it was."""
        if not self.closed:
            self.closed = True
            atexit.unregister(self.close)
            try:
                self.stream.disconnect()
            finally:
                if self._feed is not None:
                    self._feed.close()
                self._tmp.unlink(missing_ok=True)
                os.close(self._fd)


def open_recording(path: str | os.PathLike, **kwargs: Any) -> Recording:
    """A :class:`Recording` on ``path`` with :func:`default_blueprint` unless ``blueprint=`` is given."""
    kwargs.setdefault("blueprint", default_blueprint())
    return Recording(path, **kwargs)


def grid_bounds(geometry: Any, z: tuple[float, float] = (0.0, 2.8)) -> tuple[np.ndarray, np.ndarray]:
    """The box (lo, hi corners, world x, y, z) over a grid's extent between the heights ``z``."""
    h, w = geometry.shape
    x0, y0 = float(geometry.origin[0]), float(geometry.origin[1])
    return (np.array([x0, y0, z[0]]), np.array([x0 + w * geometry.resolution, y0 + h * geometry.resolution, z[1]]))


def eye_for_bounds(lo: ArrayLike, hi: ArrayLike, *, elevation_deg: float = 55.0) -> rrb.EyeControls3D:
    """A 3D camera that frames the box ``lo``..``hi`` (world x, y, z) whole: looking at its centre from the
    south (-y), ``elevation_deg`` above the horizon, far enough back for the box's larger side."""
    lo_a, hi_a = np.asarray(lo, dtype=float).reshape(-1), np.asarray(hi, dtype=float).reshape(-1)
    if lo_a.shape != (3,) or hi_a.shape != (3,) or not np.all(np.isfinite(lo_a)) or not np.all(np.isfinite(hi_a)):
        raise InputError(f"bounds must be two finite (x, y, z) corners, got {lo!r} and {hi!r}")
    centre = 0.5 * (lo_a + hi_a)
    size = max(float(np.max(hi_a[:2] - lo_a[:2])), 1.0)
    dist = 1.1 * size  # a ~60 deg field of view sees about 1.15 x its distance across
    el = np.radians(elevation_deg)
    eye = centre + dist * np.array([0.0, -np.cos(el), np.sin(el)])
    return rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, position=eye, look_target=centre, eye_up=(0.0, 0.0, 1.0))


def default_blueprint(
    *,
    view3d: bool = True,
    map2d: bool = True,
    graph: bool = True,
    names: Mapping[str, str] | None = None,
    legend: bool = False,
    eye: rrb.EyeControls3D | None = None,
    hidden: Iterable[str] = (),
) -> rrb.Blueprint:
    """The layout a recording opens on: the 3D world on the left; the 2D map, the room graph and the legend on
    the right.

    Views whose data a recording lacks can be left out (``map2d=False`` for a SLAM run without a grid).

    Parameters
    ----------
    names : mapping, optional
        View titles by view ("3D world", "2D map", "Room graph", "Legend"), e.g. the paper's figure names.
    legend : bool
        Add a text view of ``legend`` (see :func:`log_legend`): what each colour and entity is.
    eye : rerun.blueprint.EyeControls3D, optional
        The 3D view's camera (see :func:`eye_for_bounds`); rerun's default otherwise.
    hidden : entity paths
        Entities the 3D view has but hides at first (slabs, ceilings): the user can show them in the viewer.
    """
    title = {"3D world": "3D world", "2D map": "2D map", "Room graph": "Room graph", "Legend": "Legend"}
    title.update(names or {})
    right: list[Any] = []
    if map2d:
        right.append(rrb.Spatial2DView(name=title["2D map"], origin=MAP2D))
    if graph:
        right.append(
            rrb.GraphView(
                name=title["Room graph"],
                origin=GRAPH,
                # positions are given (world x, -y): keep them, do not let the force layout move the nodes
                force_link=rrb.archetypes.ForceLink(enabled=False),
                force_many_body=rrb.archetypes.ForceManyBody(enabled=False),
                force_center=rrb.archetypes.ForceCenter(enabled=False),
            )
        )
    overrides = {f"/{e.strip('/')}": rrb.EntityBehavior(visible=False) for e in hidden}
    left = [rrb.Spatial3DView(name=title["3D world"], origin=WORLD, eye_controls=eye, overrides=overrides or None)
            ] if view3d else []
    if not left and not right:
        raise InputError("default_blueprint needs at least one view")
    if legend:
        right.append(rrb.TextDocumentView(name=title["Legend"], origin=LEGEND))
    if left and right:
        shares = [3, 1, 1][: len(right)] if len(right) > 1 else None
        root: Any = rrb.Horizontal(
            left[0], right[0] if len(right) == 1 else rrb.Vertical(*right, row_shares=shares), column_shares=[3, 2]
        )
    else:
        views = left + right
        root = views[0] if len(views) == 1 else rrb.Vertical(*views)
    return rrb.Blueprint(root, collapse_panels=False)


def log_legend(rec: Any, markdown: str) -> None:
    """The recording's legend (Markdown), shown by the blueprint's text view (``default_blueprint(legend=True)``)."""
    _stream(rec).log(LEGEND, rr.TextDocument(str(markdown), media_type=rr.MediaType.MARKDOWN), static=True,
                     strict=True)


def series_legend(names: Iterable[str]) -> str:
    """Markdown lines naming the colour of each path (``VIEWER_SERIES_COLORS``)."""
    what = {"groundtruth": "ground truth", "estimate": "estimate (HS-SLAM)", "slam": "estimate (HS-SLAM)",
            "odometry": "wheel odometry"}
    lines = []
    for n in names:
        c = VIEWER_SERIES_COLORS.get(n, VIEWER_SERIES_COLORS["other"])
        lines.append(f"- **{_colour_name(c)}** line: {what.get(n, n)}")
    return "\n".join(lines)


def _colour_name(c: Any) -> str:
    names = {(60, 210, 90): "green", (40, 150, 255): "blue", (245, 70, 50): "red", (250, 200, 40): "yellow"}
    rgb = tuple(int(v) for v in c[:3])
    return names.get(rgb, "#" + "".join(f"{v:02x}" for v in rgb))


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
        scan = None if frame.scan2d is None else _points(frame.scan2d.points(), (2, 3), "points")
        cloud = None
        if frame.cloud3d is not None:
            cloud = _points(frame.cloud3d, (2, 3), "points")
            if self.cloud_voxel is not None:
                cloud = first_per_voxel(cloud, self.cloud_voxel)
        self._rows.append((int(index), stamp, _pose6(pose).copy(), scan, cloud))
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
        t, q = _translation_quaternion(np.stack([r[2] for r in rows]))
        s.send_columns(ROBOT, indexes=times(everyone), columns=rr.Transform3D.columns(translation=t, quaternion=q),
                       strict=True)
        for k, entity in ((3, f"{LIDAR2D}/scan"), (4, f"{LIDAR3D}/cloud")):
            sel = [i for i in everyone if rows[i][k] is not None]
            if not sel:
                continue
            pts = [rows[i][k] for i in sel]
            pts = [np.column_stack([p, np.zeros(len(p))]) if p.shape[1] == 2 else p for p in pts]
            lengths = np.array([len(p) for p in pts])
            allp = np.concatenate(pts) if len(pts) else np.empty((0, 3))
            if k == 3:  # log_scan2d's colour and radius
                cols = rr.Points3D.columns(positions=allp).partition(lengths)
                style = rr.Points3D.columns(colors=np.tile(np.array([230, 90, 30], dtype=np.uint8), (len(sel), 1)),
                                            radii=np.full(len(sel), 0.025, dtype=np.float32))
            else:  # log_cloud's height colours and radius
                cols = rr.Points3D.columns(positions=allp, colors=height_colors(allp[:, 2], (-2.0, 2.0))
                                           ).partition(lengths)
                style = rr.Points3D.columns(radii=np.full(len(sel), 0.02, dtype=np.float32))
            s.send_columns(entity, indexes=times(sel), columns=[*cols, *style], strict=True)


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


# --- grids and labels ----------------------------------------------------------------------------------


def _check_geometry(geometry: GridGeometry, shape: tuple[int, ...], what: str) -> None:
    if not isinstance(geometry, GridGeometry):
        raise InputError(f"geometry must be an hsmap.grid.GridGeometry, got {type(geometry).__name__}")
    if tuple(shape[:2]) != geometry.shape:
        raise ShapeError(f"{what} has shape {tuple(shape[:2])} but its GridGeometry says {geometry.shape}")


def log_occupancy_grid(
    rec: Any,
    grid: ArrayLike,
    geometry: GridGeometry,
    *,
    convention: str = "auto",
    entity: str = f"{WORLD_MAP}/occupancy",
    map_entity: str | None = f"{MAP2D}/occupancy",
    z: float = 0.0,
    opacity: float | None = None,
    static: bool = True,
) -> None:
    """Log an occupancy grid: a ``GridMap`` in the 3D world where ``geometry`` places it, and an ``Image``
    in the 2D map view (``map_entity``; None to skip). See :func:`occupancy_to_ros` for ``convention``."""
    ros = occupancy_to_ros(grid, convention)
    _check_geometry(geometry, ros.shape, "occupancy grid")
    h, w = ros.shape
    s = _stream(rec)
    s.log(
        entity,
        rr.GridMap(
            data=np.ascontiguousarray(ros).tobytes(),
            format=rr.components.ImageFormat(width=w, height=h, color_model="L", channel_datatype="U8"),
            cell_size=geometry.resolution,
            translation=[geometry.origin[0], geometry.origin[1], z],
            colormap=rr.components.Colormap.RvizMap,
            opacity=opacity,
        ),
        static=static,
        strict=True,
    )
    if map_entity is not None:
        img = _ros_to_image(ros)
        s.log(map_entity, rr.Image(img, color_model="L", draw_order=-10.0), static=static, strict=True)


def room_annotation_context(
    ids: Iterable[int], names: Mapping[int, str] | None = None, *, background: str = "no room"
) -> rr.AnnotationContext:
    """One class per room id (its palette colour and name; "room k" by default); 0 is transparent."""
    infos = [rr.AnnotationInfo(0, background, (0, 0, 0, 0))]
    for k in sorted({int(i) for i in ids if int(i) > 0}):
        name = (names or {}).get(k, f"room {k}")
        infos.append(rr.AnnotationInfo(k, str(name), label_color(k)))
    return rr.AnnotationContext(infos)


def log_room_labels(
    rec: Any,
    labels: ArrayLike,
    geometry: GridGeometry,
    *,
    names: Mapping[int, str] | None = None,
    entity: str = f"{WORLD_MAP}/rooms",
    map_entity: str | None = f"{MAP2D}/rooms",
    z: float = 0.02,
    opacity: float = 0.6,
    static: bool = True,
) -> None:
    """Log a room label image (H, W) (0 = no room): in the 2D map view as ``SegmentationImage`` with an
    ``AnnotationContext`` (room names and colours), and in the 3D world as a coloured quad
    (:func:`log_rgba_grid`) placed by ``geometry`` just above the occupancy grid."""
    lab = np.asarray(labels)
    if lab.ndim != 2:
        raise ShapeError(f"labels must be an (H, W) image, got shape {lab.shape}")
    _check_geometry(geometry, lab.shape, "label image")
    if lab.size and (lab.min() < 0 or lab.max() > np.iinfo(np.uint16).max):
        raise InputError("labels must lie in 0..65535 (0 = no room)")
    lab16 = lab.astype(np.uint16)
    ids = np.unique(lab16)
    s = _stream(rec)
    rgba = label_colors(lab16)
    rgba[..., 3] = np.where(rgba[..., 3] > 0, int(round(255 * float(opacity))), 0).astype(np.uint8)
    log_rgba_grid(rec, entity, rgba, geometry, z=z, static=static)
    if map_entity is not None:
        s.log(map_entity, room_annotation_context(ids, names), static=True, strict=True)
        s.log(map_entity, rr.SegmentationImage(lab16, opacity=opacity, draw_order=0.0), static=static,
              strict=True)


def world_to_map2d(geometry: GridGeometry, xy: ArrayLike) -> NDArray[np.float64]:
    """World (x, y) (N, 2) -> positions in the 2D map view (x = column, y = row, pixel corners at integers)."""
    rc = geometry.world_to_pixel(np.asarray(xy, dtype=float)[..., :2])
    return np.stack([rc[..., 1] + 0.5, rc[..., 0] + 0.5], -1)


def log_map2d_path(
    rec: Any, name: str, poses: Any, geometry: GridGeometry, *, color: ArrayLike | None = None,
    radius: float = 1.0, static: bool = True,
) -> None:
    """A path drawn over the 2D map view at ``map/paths/NAME`` (radius in pixels; ``static=False`` logs it at
    the current time, for a path that grows)."""
    xy = _path_positions(poses, None)[:, :2]
    color = VIEWER_SERIES_COLORS.get(name, VIEWER_SERIES_COLORS["other"]) if color is None else color
    _stream(rec).log(f"{MAP2D}/paths/{name}",
                     rr.LineStrips2D([world_to_map2d(geometry, xy)], colors=color, radii=radius,
                                     draw_order=10.0), static=static, strict=True)


def log_map2d_robot(rec: Any, pose: ArrayLike, geometry: GridGeometry, *, entity: str = f"{MAP2D}/robot",
                    length: float = 0.6, color: ArrayLike = ROBOT_COLOR) -> None:
    """The robot in the 2D map view at the current time: a dot and an arrow ``length`` metres along its heading."""
    p = _pose6(pose)
    x, y, yaw = p[0], p[1], p[5]
    a, b = world_to_map2d(geometry, np.array([[x, y], [x + length * np.cos(yaw), y + length * np.sin(yaw)]]))
    s = _stream(rec)
    s.log(entity, rr.Arrows2D(origins=[a], vectors=[b - a], colors=color, radii=1.5, draw_order=40.0),
          rr.Points2D([a], colors=color, radii=4.0, draw_order=40.0), strict=True)


def log_map2d_robots(rec: Any, poses: ArrayLike, geometry: GridGeometry, indexes: ArrayLike, stamps: ArrayLike, *,
                     entity: str = f"{MAP2D}/robot", length: float = 0.6, color: ArrayLike = ROBOT_COLOR) -> None:
    """:func:`log_map2d_robot` at many times in one call (columns): the robot at ``poses[i]`` at frame
    ``indexes[i]`` (the ``scan`` timeline) and ``stamps[i]`` seconds (``time``)."""
    p = _pose6(poses)
    if p.ndim != 2:
        raise ShapeError(f"poses must be (K, 3) or (K, 6), got shape {np.shape(poses)}")
    idx = np.asarray(indexes, dtype=np.int64)
    st = np.asarray(stamps, dtype=float)
    if not (len(idx) == len(st) == len(p)):
        raise ShapeError(f"{len(p)} poses, {len(idx)} indexes and {len(st)} stamps: expected as many of each")
    if len(p) == 0:
        return
    x, y, yaw = p[:, 0], p[:, 1], p[:, 5]
    a = world_to_map2d(geometry, np.column_stack([x, y]))
    b = world_to_map2d(geometry, np.column_stack([x + length * np.cos(yaw), y + length * np.sin(yaw)]))
    unix = st > _UNIX_TIME_THRESHOLD
    for part in (np.flatnonzero(unix), np.flatnonzero(~unix)):
        if not len(part):
            continue
        when = (rr.TimeColumn("time", timestamp=st[part]) if unix[part[0]]
                else rr.TimeColumn("time", duration=st[part]))
        k = len(part)
        cols = [*rr.Arrows2D.columns(origins=a[part], vectors=(b - a)[part],
                                     colors=np.tile(np.asarray(color, dtype=np.uint8), (k, 1)),
                                     radii=np.full(k, 1.5, dtype=np.float32), draw_order=np.full(k, 40.0)),
                *rr.Points2D.columns(positions=a[part], colors=np.tile(np.asarray(color, dtype=np.uint8), (k, 1)),
                                     radii=np.full(k, 4.0, dtype=np.float32), draw_order=np.full(k, 40.0))]
        _stream(rec).send_columns(entity, indexes=[rr.TimeColumn("scan", sequence=idx[part]), when], columns=cols,
                                  strict=True)


def log_map2d_points(rec: Any, name: str, points_world: ArrayLike, geometry: GridGeometry, *,
                     color: ArrayLike = (230, 90, 30), radius: float = 1.2, static: bool = False) -> None:
    """World points (N, 2+) in the 2D map view at ``map/NAME`` (radius in pixels), at the current time."""
    p = _points(points_world, (2, 3), "points_world")
    _stream(rec).log(f"{MAP2D}/{name}", rr.Points2D(world_to_map2d(geometry, p[:, :2]), colors=color, radii=radius,
                                                  draw_order=35.0), static=static, strict=True)


def log_rgba_grid(
    rec: Any, entity: str, image: ArrayLike, geometry: GridGeometry, *, z: float = 0.0, static: bool = True,
) -> None:
    """An (H, W, 3) or (H, W, 4) uint8 picture over a grid, in the 3D world, placed by ``geometry``: a textured
    quad (``Mesh3D``). Rows as an image's and a ``GridMap``'s: row 0 on the side of largest y, so it lies on
    the occupancy grid. (rerun 0.41 flags a colour ``GridMap`` as an error in the view, so colour pictures go this way.)"""
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] not in (3, 4) or img.dtype != np.uint8:
        raise ShapeError(f"{entity}: a picture must be (H, W, 3|4) uint8, got {img.shape} {img.dtype}")
    _check_geometry(geometry, img.shape, entity)
    h, w = img.shape[:2]
    x0, y0 = float(geometry.origin[0]), float(geometry.origin[1])
    x1, y1 = x0 + w * geometry.resolution, y0 + h * geometry.resolution
    # nearest-neighbour look: a texture is filtered linearly, so each cell is drawn as a 4 x 4 block
    big = np.ascontiguousarray(np.repeat(np.repeat(img, 4, axis=0), 4, axis=1)) if max(h, w) <= 1024 else img
    _stream(rec).log(entity, rr.Mesh3D(
        vertex_positions=[[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]],
        triangle_indices=[[0, 1, 2], [0, 2, 3]],
        vertex_texcoords=[[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]],  # row 0 (v = 0) on the far side
        albedo_texture=big,
    ), static=static, strict=True)


# --- room graph ----------------------------------------------------------------------------------------


def _node_kind(data: Mapping[str, Any]) -> str:
    kind = data.get("kind", data.get("type"))
    if kind is not None:
        return str(kind)
    return "room" if "area" in data else "door"


def _centroid(node: Any, data: Mapping[str, Any]) -> NDArray[np.float64]:
    c = data.get("centroid")
    if c is None:
        raise InputError(f"graph node {node!r} has no 'centroid' (x, y) attribute")
    c = np.asarray(c, dtype=float).reshape(-1)
    if c.shape[0] < 2 or not np.all(np.isfinite(c[:2])):
        raise InputError(f"graph node {node!r}: centroid must be finite (x, y), got {data.get('centroid')!r}")
    return c[:2]


def log_room_graph(
    rec: Any,
    graph: Any,
    *,
    entity: str = GRAPH,
    world_entity: str | None = f"{WORLD_MAP}/graph",
    geometry: GridGeometry | None = None,
    z: float = 0.3,
    scale: float = 40.0,
    static: bool = True,
) -> None:
    """Log a room/door graph (networkx): rooms have ``centroid`` (x, y) and ``area`` (m^2), doors a
    ``centroid``; edges may carry ``distance`` (m). A node's ``kind`` ("room"/"door") wins over the guess
    from ``area``; a room's ``label`` attribute (its id in the label image) picks its colour.

    Logs ``GraphNodes``/``GraphEdges`` at ``entity`` (positions world (x, -y) * ``scale``, so the graph view
    looks like the map from above; a door lying on the line between its two rooms is drawn a little aside,
    so that its label does not cover theirs), the same graph in the 3D world at height ``z`` (``world_entity``:
    light edges and each edge's length at its middle), and, with ``geometry``, over the 2D map view
    (``map/graph``: labels in white, not in the room's own colour, which is the fill under them; doors by
    their short name).
    """
    if not hasattr(graph, "nodes") or not hasattr(graph, "edges"):
        raise InputError(f"expected a networkx graph, got {type(graph).__name__}")
    ids, pos, labels, short, colors, radii, kinds = [], [], [], [], [], [], []
    for i, (n, data) in enumerate(graph.nodes(data=True)):
        kind = _node_kind(data)
        c = _centroid(n, data)
        ids.append(str(n))
        pos.append(c)
        kinds.append(kind)
        if kind == "room":
            area = data.get("area")
            name = data.get("name") or f"room {n}"
            labels.append(f"{name} ({float(area):.1f} m²)" if area is not None else str(name))
            short.append(str(name))
            lab = data.get("label", n if isinstance(n, (int, np.integer)) else i + 1)
            colors.append(label_color(int(lab)) if isinstance(lab, (int, np.integer)) else tuple(ROOM_PALETTE[0]))
            radii.append(1.0)
        else:
            name = str(data.get("name") or f"door {n}")
            labels.append(name)
            short.append(name)
            colors.append(_DOOR_COLOR)
            radii.append(0.5)
    if not ids:
        raise InputError("the room graph has no nodes")
    pos_a = np.array(pos)
    index = {str(n): k for k, n in enumerate(graph.nodes)}
    edges, edge_lines, edge_labels = [], [], []
    for u, v, data in graph.edges(data=True):
        edges.append((str(u), str(v)))
        edge_lines.append([pos_a[index[str(u)]], pos_a[index[str(v)]]])
        d = data.get("distance")
        edge_labels.append(f"{float(d):.2f} m" if d is not None else "")
    s = _stream(rec)
    gpos = _graph_positions(graph, pos_a, kinds, index) * np.array([1.0, -1.0]) * scale
    s.log(entity, rr.GraphNodes(ids, positions=gpos, labels=labels, colors=colors,
                                radii=np.array(radii) * 0.15 * scale, show_labels=True),
          static=static, strict=True)
    s.log(entity, rr.GraphEdges(edges, graph_type="undirected"), static=static, strict=True)
    if world_entity is not None:
        p3 = np.column_stack([pos_a, np.full(len(pos_a), z)])
        # labels in white: a room's label in its own colour would vanish on its floor's fill
        s.log(f"{world_entity}/nodes", rr.Points3D(p3, colors=colors, radii=np.array(radii) * 0.2),
              static=static, strict=True)
        # rooms only: door labels would crowd a corridor's (the door clouds and the edges show the doors)
        rooms = np.array([k == "room" for k in kinds])
        s.log(f"{world_entity}/labels", rr.Points3D(p3[rooms] + [0.0, 0.0, 0.25], colors=(255, 255, 255),
                                                    radii=0.01, labels=[t for t, r in zip(labels, rooms, strict=True)
                                                                        if r], show_labels=True),
              static=static, strict=True)
        if edges:
            lines = [np.column_stack([np.array(e), np.full(2, z)]) for e in edge_lines]
            s.log(f"{world_entity}/edges", rr.LineStrips3D(lines, colors=(235, 235, 235), radii=0.06),
                  static=static, strict=True)
            mids = np.array([ln.mean(axis=0) for ln in lines])
            s.log(f"{world_entity}/lengths", rr.Points3D(mids, colors=(235, 235, 235), radii=0.08,
                                                         labels=edge_labels, show_labels=True),
                  static=static, strict=True)
    if geometry is not None:
        tags = [lab if kinds[k] == "room" else lab.removeprefix("door ") for k, lab in enumerate(short)]
        s.log(f"{MAP2D}/graph/nodes", rr.Points2D(world_to_map2d(geometry, pos_a), colors=(255, 255, 255),
                                                 radii=np.array(radii) * 4.0, labels=tags, draw_order=30.0),
              static=static, strict=True)
        if edges:
            s.log(f"{MAP2D}/graph/edges",
                  rr.LineStrips2D([world_to_map2d(geometry, np.array(e)) for e in edge_lines],
                                  colors=(40, 40, 40), radii=1.0, draw_order=25.0), static=static, strict=True)


_DOOR_COLOR = (230, 230, 230)


def _graph_positions(graph: Any, pos: NDArray[np.float64], kinds: list[str], index: Mapping[str, int]
                     ) -> NDArray[np.float64]:
    """Node positions for the graph view: the map's, except that a door lying (nearly) on the line between
    its two rooms moves aside, perpendicular to that line, by a third of the rooms' distance (else the door's
    label and the rooms' overlap when rooms follow each other along a corridor)."""
    out = pos.copy()
    for n in graph.nodes:
        k = index[str(n)]
        if kinds[k] != "door":
            continue
        rooms = [index[str(m)] for m in graph.neighbors(n) if kinds[index[str(m)]] == "room"]
        if len(rooms) != 2:
            continue
        a, b = pos[rooms[0]], pos[rooms[1]]
        ab = b - a
        length = float(np.hypot(*ab))
        if length < 1e-9:
            continue
        normal = np.array([-ab[1], ab[0]]) / length
        off = float(np.dot(pos[k] - a, normal))
        if abs(off) < 0.15 * length:
            out[k] = pos[k] + normal * (np.sign(off) if off else 1.0) * (length / 3.0 - abs(off))
    return out


# --- verification --------------------------------------------------------------------------------------


def rerun_binary() -> Path | None:
    """The ``rerun`` command-line tool of this environment (beside the interpreter), or on PATH."""
    beside = Path(sys.executable).with_name("rerun")
    if beside.is_file() and os.access(beside, os.X_OK):
        return beside
    found = shutil.which("rerun")
    return Path(found) if found else None


def verify_rrd(path: str | os.PathLike, *, timeout: float = 300.0) -> str:
    """Run ``rerun rrd verify PATH``; returns its report, raises :class:`DataFormatError` when it fails.

    Raises :class:`HsmapError` when no ``rerun`` binary is installed.
    """
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(f"{path}: no such recording")
    exe = rerun_binary()
    if exe is None:
        raise HsmapError("the 'rerun' command-line tool is not installed (it comes with rerun-sdk)")
    env = dict(os.environ, RERUN_ANALYTICS="0", NO_COLOR="1", RUST_LOG_STYLE="never")
    try:
        r = subprocess.run([str(exe), "rrd", "verify", str(path)], capture_output=True, text=True,
                           timeout=timeout, env=env)
    except subprocess.TimeoutExpired:
        raise DataFormatError(f"{path}: 'rerun rrd verify' did not finish in {timeout:.0f} s") from None
    out = _ANSI.sub("", (r.stdout + r.stderr)).strip()
    if r.returncode != 0:
        lines = [line.strip() for line in out.splitlines() if line.strip()]
        errors = [line for line in lines if line.startswith("Error")] or lines[-3:]
        raise DataFormatError(f"{path}: 'rerun rrd verify' failed (exit {r.returncode}): {' | '.join(errors)}")
    return out


_ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")


_CHUNK_LINE = re.compile(r"with (\d+) rows .* - (/\S*) - data columns: \[(.*)\]")


def recording_contents(path: str | os.PathLike, *, timeout: float = 300.0) -> dict[str, dict[str, Any]]:
    """What a recording holds, per entity, from ``rerun rrd print``: ``{"/world/robot": {"columns":
    {"Transform3D:translation", ...}, "rows": 177}, ...}`` (blueprint entities included)."""
    exe = rerun_binary()
    if exe is None:
        raise HsmapError("the 'rerun' command-line tool is not installed (it comes with rerun-sdk)")
    env = dict(os.environ, RERUN_ANALYTICS="0", NO_COLOR="1", RUST_LOG_STYLE="never")
    r = subprocess.run([str(exe), "rrd", "print", str(path)], capture_output=True, text=True, timeout=timeout,
                       env=env)
    if r.returncode != 0:
        raise DataFormatError(f"{path}: 'rerun rrd print' failed: {_ANSI.sub('', r.stderr).strip()[-500:]}")
    out: dict[str, dict[str, Any]] = {}
    for line in r.stdout.splitlines():
        m = _CHUNK_LINE.search(line)
        if m:
            e = out.setdefault(m.group(2), {"columns": set(), "rows": 0})
            e["rows"] += int(m.group(1))
            e["columns"].update(m.group(3).split())
    return out
