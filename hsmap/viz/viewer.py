"""Open recordings in rerun's headless viewer and look at them: screenshots of every view, and a check.

The viewer (rerun 0.41) runs without a window when a graphics stack is present: a GPU, or Mesa's software
Vulkan renderer (``apt-get install mesa-vulkan-drivers``). It is driven over gRPC with
``rerun.experimental.ViewerClient``: the recording is opened, the time cursor moved to the start, middle and
end of its timeline, and every view saved as a PNG. :func:`check_recording` fails a recording whose views
report an error, or a view that should show something but is empty.

    from hsmap.viz.viewer import HeadlessViewer
    with HeadlessViewer() as v:
        shots = v.screenshots("reports/01-odometry-vs-hsslam-2d/slam.rrd", "shots/")
"""

from __future__ import annotations

import contextlib
import glob
import os
import socket
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DataFormatError, HsmapError

__all__ = ["viewer_unavailable", "HeadlessViewer", "ViewShot", "ViewerCheck", "check_recording", "image_content"]

_VULKAN_ICDS = ("/usr/share/vulkan/icd.d/*.json", "/etc/vulkan/icd.d/*.json", "/usr/local/share/vulkan/icd.d/*.json")

#: time cursor positions for the screenshots, as fractions of the active timeline
POSITIONS = {"start": 0.0, "middle": 0.5, "end": 1.0}


def viewer_unavailable() -> str | None:
    """Why the headless viewer cannot run here (None when it can): no ``rerun`` tool, or no Vulkan driver."""
    from .rerun import rerun_binary

    if rerun_binary() is None:
        return "the 'rerun' command-line tool is not installed (it comes with rerun-sdk)"
    if os.environ.get("VK_ICD_FILENAMES") or os.environ.get("VK_DRIVER_FILES"):
        return None
    if not any(glob.glob(p) for p in _VULKAN_ICDS):
        return "no Vulkan driver for the headless viewer (install Mesa's software renderer: mesa-vulkan-drivers)"
    return None


def _free_port() -> int:
    with contextlib.closing(socket.socket(socket.AF_INET, socket.SOCK_STREAM)) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def image_content(png: bytes | str | os.PathLike) -> float:
    """How much a screenshot shows: the fraction of its pixels that differ from its most common colour by more
    than a little (an empty 2D view is one colour; an empty 3D view shows only its thin ground grid)."""
    import io

    from PIL import Image

    src = io.BytesIO(png) if isinstance(png, bytes | bytearray) else png
    img = np.asarray(Image.open(src).convert("RGB"), dtype=np.int16)
    flat = img.reshape(-1, 3)
    q = (flat // 8).astype(np.int32)
    keys = (q[:, 0] << 10) | (q[:, 1] << 5) | q[:, 2]
    mode = np.bincount(keys).argmax()
    ref = np.array([(mode >> 10) & 31, (mode >> 5) & 31, mode & 31]) * 8 + 4
    differs = np.abs(flat - ref).max(axis=1) > 24
    return float(differs.mean())


@dataclass
class ViewShot:
    """One view's screenshot at one time position."""

    view: str
    view_class: str
    position: str
    path: Path | None
    content: float
    reports: list[str] = field(default_factory=list)


@dataclass
class ViewerCheck:
    """What the viewer showed of one recording."""

    recording: Path
    views: list[str]
    shots: list[ViewShot]
    errors: list[str]

    @property
    def ok(self) -> bool:
        return not self.errors


class HeadlessViewer:
    """A headless rerun viewer process, for one or more recordings (a context manager: quits on exit)."""

    def __init__(self, *, startup_timeout: float = 60.0):
        reason = viewer_unavailable()
        if reason is not None:
            raise HsmapError(f"the headless viewer cannot run here: {reason}")
        from rerun.experimental import ViewerClient

        from .rerun import rerun_binary

        self.port = _free_port()
        # the viewer inherits the environment: quiet (its INFO log would fill the batch's terminal) and with a
        # runtime folder; the host's environment is given back at once
        saved = {k: os.environ.get(k) for k in ("RUST_LOG", "XDG_RUNTIME_DIR")}
        os.environ["RUST_LOG"] = saved["RUST_LOG"] or "error"
        os.environ["XDG_RUNTIME_DIR"] = saved["XDG_RUNTIME_DIR"] or tempfile.gettempdir()
        try:
            self.client = ViewerClient.spawn(headless=True, port=self.port, hide_welcome_screen=True,
                                             executable_path=str(rerun_binary()))
        finally:
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
        deadline = time.monotonic() + startup_timeout
        while True:
            try:
                self.client.get_state()
                break
            except Exception as e:  # noqa: BLE001 - the server is still starting
                if time.monotonic() > deadline:
                    self.close()
                    raise HsmapError(f"the headless viewer did not answer in {startup_timeout:.0f} s: {e}") from None
                time.sleep(0.5)

    def __enter__(self) -> HeadlessViewer:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.client.quit(timeout=5.0)

    def open(self, path: str | os.PathLike, *, settle: float = 1.0) -> Any:
        """Open one recording (closing the others) and return the viewer's state once it has loaded."""
        path = Path(path).resolve()
        if not path.is_file():
            raise DataFormatError(f"{path}: no such recording")
        with contextlib.suppress(Exception):
            self.client.close("all")
        self.client.open(str(path))
        deadline = time.monotonic() + 60.0
        state = self.client.get_state()
        while state.loading and time.monotonic() < deadline:
            time.sleep(0.5)
            state = self.client.get_state()
        time.sleep(settle)
        state = self.client.get_state()
        if state.active_recording is None:
            raise DataFormatError(f"{path}: the viewer opened no recording from it")
        return state

    def _seek(self, state: Any, fraction: float) -> None:
        rec = next((r for r in state.recordings if r.store_id == state.active_recording), None)
        if rec is None or not rec.timelines:
            return
        tl = next((t for t in rec.timelines if t.name == rec.current_timeline), rec.timelines[0])
        value = tl.start + fraction * (tl.end - tl.start)
        if tl.time_type == "sequence":
            self.client.set_time(tl.name, sequence=int(round(value)), play_state="paused")
        elif tl.time_type == "duration":
            self.client.set_time(tl.name, duration=np.timedelta64(int(round(value)), "ns"), play_state="paused")
        else:
            self.client.set_time(tl.name, timestamp=np.datetime64(int(round(value)), "ns"), play_state="paused")

    def _settled(self, view_id: Any, *, timeout: float = 20.0) -> bytes:
        """A screenshot once the picture stops changing (the viewer fetches a recording's chunks as the time
        cursor needs them, so the first pictures after a seek can be incomplete)."""
        deadline = time.monotonic() + timeout
        last = self.client.take_screenshot(view_id)
        while time.monotonic() < deadline:
            time.sleep(0.4)
            png = self.client.take_screenshot(view_id)
            if png == last:
                return png
            last = png
        return last

    def screenshots(
        self,
        path: str | os.PathLike,
        out_dir: str | os.PathLike | None = None,
        *,
        positions: Sequence[str] = ("start", "middle", "end"),
        whole: bool = True,
    ) -> ViewerCheck:
        """Screenshots of every view of ``path`` at the start, middle and end of its active timeline.

        PNGs go to ``out_dir`` (``<stem>-<position>-<view>.png``, and ``<stem>-<position>.png`` of the whole
        viewer when ``whole``); with ``out_dir`` None, nothing is written and only the check is made.
        """
        path = Path(path)
        state = self.open(path)
        views = [v for v in state.views if v.visible]
        timed = any(r.timelines for r in state.recordings if r.store_id == state.active_recording)
        shots: list[ViewShot] = []
        out = Path(out_dir) if out_dir is not None else None
        if out is not None:
            out.mkdir(parents=True, exist_ok=True)
        for pos in positions if timed else ("end",):
            self._seek(state, POSITIONS[pos])
            time.sleep(0.3)
            if out is not None and whole:
                (out / f"{path.stem}-{pos}.png").write_bytes(self._settled(None))
            current = {v.view_id: v for v in self.client.get_state().views}
            for v in views:
                png = self._settled(v.view_id)
                target = None
                if out is not None:
                    slug = "".join(c if c.isalnum() else "-" for c in v.name.lower()).strip("-")
                    target = out / f"{path.stem}-{pos}-{slug}.png"
                    target.write_bytes(png)
                reports = [f"{r.severity}: {r.summary}" for r in getattr(current.get(v.view_id, v), "reports", [])]
                shots.append(ViewShot(v.name, v.view_class, pos, target, image_content(png), reports))
        errors = []
        for s in shots:
            errors += [f"view '{s.view}' at the {s.position}: {r}" for r in s.reports if r.startswith("error")]
        for name in {s.view for s in shots}:
            mine = [s for s in shots if s.view == name]
            if mine[0].view_class in ("TextDocument", "TextLog"):
                continue
            if max(s.content for s in mine) < _MIN_CONTENT.get(mine[0].view_class, 0.01):
                errors.append(f"view '{name}' ({mine[0].view_class}) is empty at every time")
        return ViewerCheck(path, [v.name for v in views], shots, errors)


#: the least fraction of non-background pixels a view with content shows (an empty 3D view's grid is < 1 %)
_MIN_CONTENT = {"2D": 0.01, "3D": 0.03, "Graph": 0.005}


def check_recording(path: str | os.PathLike, out_dir: str | os.PathLike | None = None) -> ViewerCheck:
    """Open one recording in a fresh headless viewer; see :meth:`HeadlessViewer.screenshots`."""
    with HeadlessViewer() as v:
        return v.screenshots(path, out_dir)
