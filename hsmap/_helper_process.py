"""A helper process (:func:`helper_process`): a second Python that runs calls of module-level functions in the
order they were submitted, for work whose answer cannot depend on where it runs and which would hold the GIL in a
thread (many small NumPy calls).

The child is ``python -m hsmap._helper_process`` on two pipes of its own, not a :mod:`multiprocessing` start
method: a caller's script without a ``__main__`` guard is never run again in the child, and whatever the child
prints cannot garble the answers. It runs hsmap's kernels on one compute thread. A call's answer is
:meth:`Future.result() <concurrent.futures.Future.result>`; a call that raised, a child that died or could not
start, all raise :class:`HelperProcessError`, after which the caller computes the answer itself.
"""

from __future__ import annotations

import atexit
import importlib
import os
import pickle
import queue
import resource
import signal
import struct
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any, BinaryIO

__all__ = ["HelperProcess", "HelperProcessError", "helper_process", "helper_cpu_seconds", "cpu_seconds",
           "peak_memory_mb"]

_HEADER = struct.Struct("<Q")


class HelperProcessError(RuntimeError):
    """The helper process could not answer a call (it raised there, died, or never started)."""


def _read(stream: BinaryIO) -> Any:
    head = stream.read(_HEADER.size)
    if len(head) < _HEADER.size:
        raise EOFError("the other end closed its pipe")
    (size,) = _HEADER.unpack(head)
    data = stream.read(size)
    if len(data) < size:
        raise EOFError("the other end closed its pipe mid-message")
    return pickle.loads(data)


class HelperProcess:
    """One child Python answering calls in order (see the module's description)."""

    def __init__(self) -> None:
        to_child_r, to_child_w = os.pipe()
        from_child_r, from_child_w = os.pipe()
        # the child imports this very hsmap, wherever the caller found it
        here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        path = os.pathsep.join(p for p in (here, os.environ.get("PYTHONPATH", "")) if p)
        env = dict(os.environ, HSMAP_THREADS="1", NUMBA_NUM_THREADS="1", PYTHONPATH=path)
        try:
            self._proc = subprocess.Popen(
                [sys.executable, "-m", "hsmap._helper_process", str(to_child_r), str(from_child_w)],
                pass_fds=(to_child_r, from_child_w), stdin=subprocess.DEVNULL, env=env)
        finally:
            os.close(to_child_r)
            os.close(from_child_w)
        self._to_child = os.fdopen(to_child_w, "wb")
        self._from_child = os.fdopen(from_child_r, "rb")
        self._pending: deque[Future] = deque()
        self._lock = threading.Lock()
        self._broken: str | None = None
        # the pipes are written and read by threads of their own: a call larger than a pipe's buffer then waits
        # there, not in the caller, for the child to finish the one before
        self._calls: queue.SimpleQueue[bytes | None] = queue.SimpleQueue()
        self._writer = threading.Thread(target=self._write_calls, name="hsmap-helper-writer", daemon=True)
        self._reader = threading.Thread(target=self._read_answers, name="hsmap-helper-reader", daemon=True)
        self._writer.start()
        self._reader.start()

    @property
    def alive(self) -> bool:
        return self._broken is None and self._proc.poll() is None

    def submit(self, fn: Callable[..., Any], *args: Any) -> Future:
        """Run ``fn(*args)`` in the child after every call submitted before; ``fn`` is a module-level function."""
        future: Future = Future()
        with self._lock:
            if self._broken is not None:
                future.set_exception(HelperProcessError(self._broken))
                return future
            try:
                data = pickle.dumps((fn.__module__, fn.__qualname__, args), protocol=pickle.HIGHEST_PROTOCOL)
            except (pickle.PicklingError, TypeError, AttributeError) as exc:
                future.set_exception(HelperProcessError(f"a call the helper process cannot take: {exc}"))
                return future
            self._pending.append(future)
            self._calls.put(data)
        return future

    def _write_calls(self) -> None:
        try:
            while (data := self._calls.get()) is not None:
                self._to_child.write(_HEADER.pack(len(data)))
                self._to_child.write(data)
                self._to_child.flush()
        except (OSError, ValueError) as exc:
            with self._lock:
                self._fail(f"the helper process stopped taking calls: {exc}")
        finally:
            try:
                self._to_child.close()  # the child's end of the calls: it stops
            except OSError:
                pass

    def _fail(self, why: str) -> None:
        """Every pending call fails with ``why``, and the writer stops (the lock is held)."""
        if self._broken is None:
            self._broken = why
            self._calls.put(None)
        while self._pending:
            f = self._pending.popleft()
            if not f.done():
                f.set_exception(HelperProcessError(self._broken))

    def _read_answers(self) -> None:
        with self._from_child:
            self._answer_calls()

    def _answer_calls(self) -> None:
        while True:
            try:
                ok, value = _read(self._from_child)
            except (EOFError, OSError, pickle.UnpicklingError) as exc:
                with self._lock:
                    self._fail(f"the helper process stopped: {exc}")
                return
            with self._lock:
                future = self._pending.popleft() if self._pending else None
            if future is None:
                continue
            if ok:
                future.set_result(value)
            else:
                future.set_exception(HelperProcessError(value))

    def close(self) -> None:
        """Stop the child (pending calls fail)."""
        with self._lock:
            self._fail("the helper process was closed")  # the writer closes the child's pipe: the child ends
        try:
            self._proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        self._writer.join(timeout=5)
        self._reader.join(timeout=5)


#: Helper processes one process may start: after that many died, its callers compute everything themselves.
MAX_STARTS = 3

_helper: HelperProcess | None = None
_helper_pid = 0
_starts = 0
_helper_lock = threading.Lock()


def helper_process() -> HelperProcess | None:
    """The helper process, started on first use and kept until exit (a new one after it died, at most
    :data:`MAX_STARTS` in all, or in a forked child); None where none can run (not POSIX, it failed to start, or
    too many died)."""
    global _helper, _helper_pid, _starts
    if os.name != "posix":
        return None
    with _helper_lock:
        if _helper_pid != os.getpid():
            _helper, _helper_pid, _starts = None, os.getpid(), 0
        if _helper is not None and not _helper.alive:
            _helper.close()
            _helper = None
        if _helper is None and _starts < MAX_STARTS:
            _starts += 1
            try:
                _helper = HelperProcess()
            except OSError:
                _helper = None
        return _helper


def _ask_helper(fn: Callable[[], float]) -> float | None:
    """``fn()`` as the running helper process answers it, or None where none runs or it cannot answer."""
    helper = _helper
    if helper is None or not helper.alive or _helper_pid != os.getpid():
        return None
    try:
        return float(helper.submit(fn).result())
    except HelperProcessError:
        return None


def helper_cpu_seconds() -> float:
    """The CPU seconds the running helper process has used (after the calls submitted so far), or 0 where none
    runs: a caller adds the difference over its work to its own ``time.process_time()``."""
    return _ask_helper(time.process_time) or 0.0


def cpu_seconds() -> float:
    """``time.process_time()`` plus :func:`helper_cpu_seconds`: a difference of two readings is the CPU a piece
    of work used in this process and in the helper process."""
    return time.process_time() + helper_cpu_seconds()


def _own_peak_memory_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def peak_memory_mb() -> float:
    """This process's peak resident memory (MiB) plus the running helper process's, each at its own peak: a bound
    on what the two held at once."""
    return _own_peak_memory_mb() + (_ask_helper(_own_peak_memory_mb) or 0.0)


@atexit.register
def _close_helper() -> None:
    if _helper is not None and _helper_pid == os.getpid():
        _helper.close()


def _serve(read_fd: int, write_fd: int) -> None:
    """The child's loop: read a call, run it, write ``(True, answer)`` or ``(False, why)``, until the pipe closes.
    Ctrl-C reaches the caller's whole process group: the child leaves it to the caller, whose exit closes the pipe."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    with os.fdopen(read_fd, "rb") as calls, os.fdopen(write_fd, "wb") as answers:
        while True:
            try:
                module, name, args = _read(calls)
            except EOFError:
                return
            try:
                fn: Any = importlib.import_module(module)
                for part in name.split("."):
                    fn = getattr(fn, part)
                answer = (True, fn(*args))
            except Exception as exc:  # the caller computes it itself; it needs only the reason
                answer = (False, f"{module}.{name} raised {type(exc).__name__}: {exc}")
            try:
                data = pickle.dumps(answer, protocol=pickle.HIGHEST_PROTOCOL)
            except Exception as exc:
                data = pickle.dumps((False, f"{module}.{name} gave an answer that cannot be sent back: {exc}"))
            answers.write(_HEADER.pack(len(data)))
            answers.write(data)
            answers.flush()


if __name__ == "__main__":
    _serve(int(sys.argv[1]), int(sys.argv[2]))
