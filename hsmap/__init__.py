"""hsmap: multi-LiDAR indoor mapping with Harmony Search.

The public API: :func:`harmony_icp` (scan registration), the error family in :mod:`hsmap.errors`, and the
modules ``geometry``, ``harmony``, ``fitness``, ``registration``, ``grid``, ``io``, ``datasets``, ``evaluation``.

Importing hsmap changes nothing in the host process (no environment variable, no thread pool setting): the
BLAS thread limit of the hot loops is taken and given back where they run (:mod:`hsmap._blas`).
"""

__version__ = "0.1.0"

from . import errors, geometry  # noqa: E402  (after __version__, which submodules import)
from .errors import HsmapError  # noqa: E402
from .registration.harmony import HarmonyConfig, harmony_search  # noqa: E402
from .registration.icp import RegistrationConfig, RegistrationResult, RegistrationTarget, harmony_icp  # noqa: E402

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
