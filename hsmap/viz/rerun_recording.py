"""The rerun recording of an hsmap run and its layout: the entity paths, the recording written to one ``.rrd``
file through hsmap's own file feed (a failed write ends the run on one line), the default blueprint (3D view,
map view, graph, legend) and the legend of series colours. See :mod:`hsmap.viz.rerun_core` for the entity tree."""

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
from numpy.typing import ArrayLike  # noqa: E402

from ..errors import HsmapError, InputError, OutputError  # noqa: E402
from ..io import locked_temporary, publish_file, write_failure_reason  # noqa: E402
from .colors import VIEWER_SERIES_COLORS  # noqa: E402

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
