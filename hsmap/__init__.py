"""hsmap: multi-LiDAR indoor mapping with Harmony Search.

The public API: :func:`harmony_icp` (scan registration), the error family in :mod:`hsmap.errors`, and the
modules ``geometry``, ``harmony``, ``fitness``, ``registration``, ``grid``, ``io``, ``datasets``, ``evaluation``.
"""

import os as _os

_os.environ.setdefault("RERUN_ANALYTICS", "0")  # rerun's analytics off in everything we run


def _limit_blas_threads() -> None:
    """Run BLAS on one thread (set HSMAP_BLAS_THREADS to change it).

    hsmap's linear algebra is small (N x 3 by 3 x 3 products, 6 x 6 solves): it gains nothing from BLAS threads,
    and when other processes keep the cores busy (notebooks run in parallel, CI) OpenBLAS's spinning threads make
    such products 50x slower. The variables also reach child processes (papermill kernels).
    """
    n = _os.environ.get("HSMAP_BLAS_THREADS", "1")
    for var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        _os.environ.setdefault(var, n)
    try:
        from threadpoolctl import threadpool_limits

        threadpool_limits(int(n), user_api="blas")
    except (ImportError, ValueError):  # pragma: no cover - threadpoolctl is a dependency
        pass


_limit_blas_threads()

__version__ = "0.1.0"

from . import errors, geometry  # noqa: E402
from .errors import HsmapError  # noqa: E402
from .harmony import HarmonyConfig, harmony_search  # noqa: E402
from .registration import RegistrationConfig, RegistrationResult, RegistrationTarget, harmony_icp  # noqa: E402

__all__ = [
    "__version__",
    "errors",
    "geometry",
    "HsmapError",
    "HarmonyConfig",
    "harmony_search",
    "RegistrationConfig",
    "RegistrationResult",
    "RegistrationTarget",
    "harmony_icp",
]
