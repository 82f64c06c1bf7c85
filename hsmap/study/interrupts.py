"""Signals of a notebook batch: Ctrl-C marks the batch interrupted (the notebook machinery's last words are then
dropped), SIGTERM interrupts a busy worker so that it cleans up, and the workers are stopped together."""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import logging
import os
import threading
from collections.abc import Iterator

__all__ = ["busy"]

_busy = False  # a batch worker is running a notebook
class _QuietDashComm(logging.Filter):
    """Drop nbclient's "No handler found for comm target 'dash'": importing open3d imports plotly's
    ``dash``, whose Jupyter hook opens a comm that only a live front end answers. Harmless, but it was
    the only line the batch printed besides the results."""

    def filter(self, record: logging.LogRecord) -> bool:
        return "comm target 'dash'" not in record.getMessage()


class _QuietOnceInterrupted(logging.Filter):
    """Drop every record once the batch is interrupted: the kernel is shut down under a cell that is still
    waiting for its reply, and nbclient then logs "Kernel died while waiting for execute reply." and asyncio
    "Task exception was never retrieved ... DeadKernelError" (when the task is collected, later). An
    interrupted batch says one line, ``hsmap: interrupted``."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not _interrupted


def quiet_papermill_log() -> None:
    for name, quiet in (("papermill", (_QuietDashComm, _QuietOnceInterrupted)),
                        ("asyncio", (_QuietOnceInterrupted,))):
        log = logging.getLogger(name)
        for cls in quiet:
            if not any(isinstance(f, cls) for f in log.filters):
                log.addFilter(cls())


_interrupted = False  # this process's batch was interrupted: the notebook machinery's last words are dropped


def _interrupt(signum=None, frame=None) -> None:
    """Mark this process's batch interrupted, then raise KeyboardInterrupt (a signal handler)."""
    global _interrupted
    _interrupted = True
    raise KeyboardInterrupt


def _on_sigterm(signum, frame) -> None:
    if _busy:
        _interrupt()  # execute_notebook shuts the kernel down and removes its staging folder
    os._exit(128 + signum)  # idle: nothing to clean up, and no traceback from the pool's queue


@contextlib.contextmanager
def marking_interrupts():
    """Ctrl-C in a batch that runs its notebooks in this process marks the interruption before it raises, so
    that the notebook machinery's reports of the kernel it then shuts down are dropped (see
    :class:`_QuietOnceInterrupted`). Only the main thread can take signals, and only where Ctrl-C raises
    KeyboardInterrupt (Python's default) is it taken over; elsewhere this does nothing."""
    import signal

    global _interrupted
    _interrupted = False
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGINT) is not signal.default_int_handler):
        yield  # a process that handles or ignores Ctrl-C its own way keeps its way
        return

    previous = signal.signal(signal.SIGINT, _interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def worker_signals() -> None:
    """A batch worker: Ctrl-C in the terminal is the batch's to handle (the worker would print a traceback of
    its own); SIGTERM from the batch interrupts it so that it shuts its kernel down and removes its staging
    folder."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _on_sigterm)


def stop_workers(pool: cf.ProcessPoolExecutor) -> None:
    """Cancel what has not started and interrupt the workers (SIGTERM: they clean up), then wait for them."""
    import signal

    procs = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        try:
            if p.is_alive():
                os.kill(p.pid, signal.SIGTERM)
        except (OSError, ValueError, AttributeError):
            pass
    for p in procs:
        try:
            p.join(timeout=30)
            if p.is_alive():
                p.kill()
        except (OSError, ValueError, AssertionError, AttributeError):
            pass


@contextlib.contextmanager
def busy() -> Iterator[None]:
    """This batch worker runs a notebook for the ``with`` block: SIGTERM then interrupts it (:func:`_on_sigterm`)."""
    global _busy
    _busy = True
    try:
        yield
    finally:
        _busy = False
