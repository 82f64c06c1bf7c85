"""BLAS threads for hsmap's hot loops, set where the loops run and given back afterwards.

hsmap's linear algebra is small (N x 3 by 3 x 3 products, 6 x 6 solves): it gains nothing from BLAS threads, and
when other processes keep the cores busy (notebooks run in parallel, CI) OpenBLAS's spinning threads make such
products many times slower. So :func:`harmony_icp <hsmap.registration.icp.harmony_icp>`,
:func:`~hsmap.registration.icp.estimate_normals` and :func:`~hsmap.slam.run_slam` run under :func:`limited_blas`:
BLAS on ``$HSMAP_BLAS_THREADS`` threads (default 1) for the call, the host's own setting restored when the
outermost limited call returns. Importing hsmap changes nothing in the host process; the ``hsmap`` command and
the notebook kernels of ``hsmap reproduce`` (hsmap's own processes) run wholly under the limit.

The limit goes through threadpoolctl's :class:`~threadpoolctl.ThreadpoolController`, kept between calls (finding
the loaded BLAS libraries takes milliseconds; setting a limit microseconds) and rebuilt when modules have been
imported since, in case one brought its own BLAS.
"""

from __future__ import annotations

import contextlib
import functools
import os
import sys
import threading
from collections.abc import Callable, Iterator
from typing import Any, TypeVar

from .errors import ConfigError

__all__ = ["BLAS_THREADS_ENV", "blas_threads", "limited_blas", "blas_limited"]

#: Environment variable naming the BLAS threads of hsmap's hot loops.
BLAS_THREADS_ENV = "HSMAP_BLAS_THREADS"

F = TypeVar("F", bound=Callable[..., Any])

_lock = threading.Lock()
_depth = 0
_limiter: Any = None
_controller: Any = None
_modules_seen = -1


def blas_threads() -> int:
    """The BLAS threads of hsmap's hot loops: ``$HSMAP_BLAS_THREADS``, default 1."""
    text = os.environ.get(BLAS_THREADS_ENV, "1")
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise ConfigError(f"${BLAS_THREADS_ENV} must be a whole number >= 1, got {text!r}")
    return n


def _controller_now() -> Any:
    global _controller, _modules_seen
    if _controller is None or len(sys.modules) != _modules_seen:
        from threadpoolctl import ThreadpoolController

        _controller = ThreadpoolController()
        _modules_seen = len(sys.modules)
    return _controller


@contextlib.contextmanager
def limited_blas() -> Iterator[None]:
    """Run the block with BLAS on :func:`blas_threads` threads; the outermost block restores the host's setting.

    Nested and concurrent blocks (threads) share one limit, taken by the first to enter and given back by the
    last to leave.
    """
    global _depth, _limiter
    with _lock:
        if _depth == 0:
            _limiter = _controller_now().limit(limits=blas_threads(), user_api="blas")
        _depth += 1
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0:
                _limiter.restore_original_limits()
                _limiter = None


def blas_limited(fn: F) -> F:
    """Decorator: ``fn`` runs under :func:`limited_blas`."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with limited_blas():
            return fn(*args, **kwargs)

    return wrapper  # type: ignore[return-value]
