"""Progress of long runs, told as lines of text: a line when a stage starts and a heartbeat while it runs.

The library only marks what it is doing: :func:`stage` when a stage starts, :func:`bar` for a counted loop (a tqdm
bar on a terminal, as before), :func:`describing` for a status it alone can tell. Nothing is said unless a caller
(a command) wraps the work in :func:`reporting`: then each stage start is a line at once, and while the work runs a
background thread writes a heartbeat line whenever ``interval`` seconds have passed without one, saying what is
being done and how far (``slam3d: HS-SLAM 6-DOF: cloud 812/1777, 45 s``), on any output, terminal or not.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

__all__ = ["Heartbeat", "reporting", "stage", "say", "bar", "describing", "format_seconds"]

#: Seconds between heartbeat lines (half of the minute a reader should never wait for a line).
DEFAULT_INTERVAL = 30.0

_active: list[Heartbeat] = []
_active_lock = threading.Lock()


def format_seconds(seconds: float) -> str:
    """``"45 s"``, ``"3 min 05 s"``, ``"1 h 02 min"``."""
    s = int(round(max(0.0, seconds)))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {s % 3600 // 60:02d} min"


class Heartbeat:
    """What a run is doing (its stage, its open counted loops, a caller's status) and the lines that say so.

    Parameters
    ----------
    log : callable
        Receives each line (without a newline).
    interval : float
        Seconds without a line after which :meth:`tick` writes a heartbeat.
    clock : callable
        Monotonic seconds (a fake in tests).
    """

    def __init__(self, log: Callable[[str], None], *, interval: float = DEFAULT_INTERVAL,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if not interval > 0:
            raise ValueError(f"interval must be > 0 seconds, got {interval}")
        self.log = log
        self.interval = float(interval)
        self.clock = clock
        self._lock = threading.RLock()
        self._started = self._last = clock()
        self._stage: str | None = None
        self._stage_started = self._started
        self._bars: list[_Bar] = []
        self._describers: list[Callable[[], str]] = []

    def say(self, line: str) -> None:
        """Write ``line`` now; the next heartbeat is due ``interval`` seconds later."""
        with self._lock:
            self._last = self.clock()
            self.log(line)

    def stage(self, name: str, detail: str = "", *, announce: bool = True) -> None:
        """A stage starts: say so (``NAME: started``, with ``detail`` after a comma; ``announce=False``: only the
        heartbeats name it) and time it."""
        with self._lock:
            self._stage, self._stage_started = name, self.clock()
            if announce:
                self.say(f"{name}: started" + (f", {detail}" if detail else ""))

    def status(self) -> str:
        """What is being done and how far: the stage and its time, the innermost open loop or the caller's status,
        and the time since the run started."""
        with self._lock:
            now = self.clock()
            what = ""
            if self._describers:
                what = _safe(self._describers[-1])
            elif self._bars:
                what = self._bars[-1].describe()
            line = f"{self._stage or 'working'}: {what or 'still running'}, {format_seconds(now - self._stage_started)}"
            if self._stage is not None:
                line += f" (in all {format_seconds(now - self._started)})"
            return line

    def tick(self) -> bool:
        """Write a heartbeat when ``interval`` seconds have passed since the last line; True when it did."""
        with self._lock:
            if self.clock() - self._last < self.interval:
                return False
            self.say(self.status())
            return True

    # the library's marks, through the module's functions
    def _open(self, b: _Bar) -> None:
        with self._lock:
            self._bars.append(b)

    def _close(self, b: _Bar) -> None:
        with self._lock:
            if b in self._bars:
                self._bars.remove(b)

    @contextlib.contextmanager
    def _describing(self, describe: Callable[[], str]) -> Iterator[None]:
        with self._lock:
            self._describers.append(describe)
        try:
            yield
        finally:
            with self._lock:
                self._describers.remove(describe)


def _safe(describe: Callable[[], str]) -> str:
    try:
        return str(describe())
    except Exception as exc:  # a status that cannot be read now must not stop the run it describes
        return f"(status unavailable: {type(exc).__name__})"


def _current() -> Heartbeat | None:
    with _active_lock:
        return _active[-1] if _active else None


@contextlib.contextmanager
def reporting(log: Callable[[str], None], *, interval: float = DEFAULT_INTERVAL,
              clock: Callable[[], float] = time.monotonic, beat: bool = True) -> Iterator[Heartbeat]:
    """Within the block, stage starts are told to ``log`` and a background thread writes a heartbeat line whenever
    ``interval`` seconds pass without a line (``beat=False``: no thread, the caller calls
    :meth:`Heartbeat.tick`). Yields the :class:`Heartbeat`."""
    hb = Heartbeat(log, interval=interval, clock=clock)
    stop = threading.Event()

    def beating() -> None:
        while not stop.wait(min(1.0, interval / 4)):
            hb.tick()

    with _active_lock:
        _active.append(hb)
    thread = threading.Thread(target=beating, name="hsmap-heartbeat", daemon=True) if beat else None
    if thread is not None:
        thread.start()
    try:
        yield hb
    finally:
        stop.set()
        if thread is not None:
            thread.join()
        with _active_lock:
            _active.remove(hb)


def stage(name: str, detail: str = "", *, announce: bool = True) -> None:
    """Mark the start of a stage (a line when a caller is :func:`reporting` and ``announce``, else nothing)."""
    hb = _current()
    if hb is not None:
        hb.stage(name, detail, announce=announce)


def say(line: str) -> None:
    """A line for the caller that is :func:`reporting` (nothing otherwise)."""
    hb = _current()
    if hb is not None:
        hb.say(line)


@contextlib.contextmanager
def describing(describe: Callable[[], str]) -> Iterator[None]:
    """Within the block, heartbeats say ``describe()`` for how far the work is (e.g. the notebooks running)."""
    hb = _current()
    if hb is None:
        yield
        return
    with hb._describing(describe):
        yield


class _Bar:
    """A counted loop: a tqdm bar (shown as ``progress`` says) whose count the heartbeat also reads."""

    def __init__(self, total: int | None, unit: str, desc: str, progress: bool | None, **tqdm_kwargs: Any) -> None:
        from tqdm.auto import tqdm

        self._bar = tqdm(total=total, unit=unit, desc=desc, disable=None if progress is None else not progress,
                         **tqdm_kwargs)
        self.total, self.n, self.unit, self.desc = total, 0, unit, desc.strip()
        self._hb = _current()
        if self._hb is not None:
            self._hb._open(self)

    def describe(self) -> str:
        count = f"{self.n}/{self.total}" if self.total is not None else f"{self.n}"
        return f"{self.desc}: {self.unit} {count}" if self.desc else f"{self.unit} {count}"

    def update(self, n: int = 1) -> None:
        self.n += n
        self._bar.update(n)

    def set_postfix_str(self, text: str) -> None:
        self._bar.set_postfix_str(text)

    def close(self) -> None:
        if self._hb is not None:
            self._hb._close(self)
        self._bar.close()

    def __enter__(self) -> _Bar:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def bar(total: int | None = None, *, unit: str = "step", desc: str = "", progress: bool | None = None,
        **tqdm_kwargs: Any) -> _Bar:
    """A counted loop's progress: a tqdm bar (``progress`` None: on a terminal only; False: never) whose count the
    heartbeat of a :func:`reporting` caller reads. ``update``, ``set_postfix_str``, ``close``, ``n``, ``total``."""
    return _Bar(total, unit, desc, progress, **tqdm_kwargs)
