"""Compute threads of hsmap's hot loops: the Harmony Search fitness kernels (numba) and the KD-tree queries.

Every parallel loop of hsmap gives the same result whatever the number of threads: each harmony's fitness is
summed by one thread (the batch is split between the threads, never one harmony's points), and each KD-tree
query point is answered on its own. So the thread count is a speed setting only, not part of any configuration.

The count is ``$HSMAP_THREADS`` (default: every core numba sees, ``NUMBA_NUM_THREADS``), or the ``threads``
argument of :func:`hsmap.slam.run_slam` (``hsmap slam --threads N``). :func:`threads_limited` sets it for the
calling thread while a hot loop runs and gives the previous numba setting back afterwards (numba's setting is
per calling thread); importing hsmap changes nothing.
"""

from __future__ import annotations

import contextlib
import functools
import inspect
import os
import threading
import warnings
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import Any, TypeVar

from .errors import ConfigError

__all__ = ["THREADS_ENV", "compute_threads", "current_threads", "using_threads", "threads_limited",
           "start_threading_layer", "helper_pool"]

#: Environment variable naming the compute threads of hsmap's hot loops.
THREADS_ENV = "HSMAP_THREADS"

F = TypeVar("F", bound=Callable[..., Any])

_local = threading.local()
_pool: ThreadPoolExecutor | None = None
_pool_size = 0
_pool_pid = 0
_pool_lock = threading.Lock()


def _max_threads() -> int:
    import numba

    return int(numba.config.NUMBA_NUM_THREADS)


def compute_threads(threads: int | None = None) -> int:
    """The compute threads to use: ``threads`` if given, else ``$HSMAP_THREADS``, else every core (numba's count);
    at most numba's count."""
    if threads is None:
        text = os.environ.get(THREADS_ENV, "")
        if text.strip() == "":
            return _max_threads()
        try:
            threads = int(text)
        except ValueError:
            threads = 0
        if threads < 1:
            raise ConfigError(f"${THREADS_ENV} must be a whole number >= 1, got {text!r}")
    if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
        raise ConfigError(f"threads must be a whole number >= 1, got {threads!r}")
    return min(threads, _max_threads())


def current_threads() -> int:
    """The threads of the innermost :func:`using_threads` block of this thread (1 outside any)."""
    return getattr(_local, "threads", 1)


def _get_num_threads() -> int:
    """numba's thread count; the first call starts numba's threading layer, whose choice may warn (an old TBB
    loaded by another library, e.g. Open3D's, is passed over for OpenMP): that is no concern of the caller's."""
    import numba

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", numba.NumbaWarning)
        return numba.get_num_threads()


def start_threading_layer() -> None:
    """Start numba's threading layer quietly (see :func:`_get_num_threads`) before a parallel kernel runs."""
    global _started
    if not _started:
        _get_num_threads()
        _started = True


_started = False


@contextlib.contextmanager
def using_threads(threads: int | None = None) -> Iterator[int]:
    """Run the block with ``threads`` compute threads (see :func:`compute_threads`); an inner block without an
    explicit count keeps the outer block's. Yields the count."""
    outer = getattr(_local, "threads", None)
    if threads is None and outer is not None:  # numba runs on the outer block's count already (only these set it)
        yield outer
        return
    import numba

    n = compute_threads(threads)
    before = _get_num_threads()
    _local.threads = n
    numba.set_num_threads(n)
    try:
        yield n
    finally:
        numba.set_num_threads(before)
        if outer is None:
            del _local.threads
        else:
            _local.threads = outer


def threads_limited(fn: F) -> F:
    """Decorator: ``fn`` runs under :func:`using_threads`; it takes one more keyword, ``threads`` (default None:
    the enclosing block's count, else ``$HSMAP_THREADS``, else every core)."""

    @functools.wraps(fn)
    def wrapper(*args: Any, threads: int | None = None, **kwargs: Any) -> Any:
        with using_threads(threads):
            return fn(*args, **kwargs)

    wrapper.__signature__ = _with_threads_keyword(inspect.signature(fn))  # type: ignore[attr-defined]
    return wrapper  # type: ignore[return-value]


def _with_threads_keyword(signature: inspect.Signature) -> inspect.Signature:
    """``signature`` with the keyword-only ``threads`` that :func:`threads_limited` adds (before any ``**kwargs``)."""
    params = list(signature.parameters.values())
    threads = inspect.Parameter("threads", inspect.Parameter.KEYWORD_ONLY, default=None, annotation="int | None")
    at = next((i for i, p in enumerate(params) if p.kind is inspect.Parameter.VAR_KEYWORD), len(params))
    return signature.replace(parameters=[*params[:at], threads, *params[at:]])


def helper_pool(workers: int) -> ThreadPoolExecutor:
    """A pool of at least ``workers`` threads, started once and kept (rebuilt in a forked child).

    For work that releases the GIL, split by the caller, which takes a share itself: scipy's own ``workers=`` starts
    new threads on every call, which on 2 cores cost 0.1-0.5 ms a query (4,000 points against a 60,000-point tree:
    1.7 ms with ``workers=2``, 1.0 ms through this pool, 2.0 ms on one thread).
    """
    global _pool, _pool_size, _pool_pid
    with _pool_lock:
        if _pool is None or _pool_size < workers or _pool_pid != os.getpid():
            _pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="hsmap")
            _pool_size, _pool_pid = workers, os.getpid()
        return _pool
