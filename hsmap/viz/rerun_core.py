"""rerun recordings of hsmap runs: the recording, its layout, time, poses, points and paths (rerun-sdk 0.41, pinned: its API moves between releases).

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

from ..errors import HsmapError, InputError, OutputError, ShapeError  # noqa: E402
from ..geometry import euler_to_matrix, matrix_to_quaternion  # noqa: E402
from ..io import locked_temporary, publish_file, write_failure_reason  # noqa: E402
from ..maps.mapping import first_per_voxel  # noqa: E402
from .colors import VIEWER_SERIES_COLORS, height_colors  # noqa: E402

__all__ = ["RERUN_VERSION", "Recording", "open_recording", "default_blueprint", "eye_for_bounds", "grid_bounds", "log_legend", "series_legend", "set_frame_time", "pose_transform", "log_robot_pose", "log_sensor_rig", "log_scan2d", "log_cloud", "log_frame", "log_points", "log_path", "log_trajectory"]


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
