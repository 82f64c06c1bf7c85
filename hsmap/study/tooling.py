"""The study tooling (papermill, nbformat, nbconvert, ipykernel: the ``study`` extra), checked for and made
lighter to import."""

from __future__ import annotations

import importlib.util
import sys

from ..errors import DependencyError

__all__ = ["STUDY_TOOLING", "require_study_tooling"]

#: The study tooling the batch imports, and the distribution each comes from.
STUDY_TOOLING = {"papermill": "papermill", "nbformat": "nbformat", "nbconvert": "nbconvert",
                 "ipykernel": "ipykernel"}


def require_study_tooling() -> None:
    """Raise :class:`~hsmap.errors.DependencyError` (one line: what to install) when the study tooling is
    missing: ``pip install hsmap`` gives the library and the commands without Jupyter."""
    missing = [dist for mod, dist in STUDY_TOOLING.items() if importlib.util.find_spec(mod) is None]
    if missing:
        raise DependencyError(
            f"running the study notebooks needs the study tooling, and {', '.join(missing)} "
            f"{'is' if len(missing) == 1 else 'are'} not installed: pip install 'hsmap[study]' "
            "(a checkout's 'make setup' installs it)")


def lighten_jupyter_imports() -> None:
    """Skip jsonschema's optional RFC 3987 checker (``rfc3987_syntax`` compiles ~40 grammars on import,
    seconds of CPU in every process that imports nbformat); notebooks never use IRI formats."""
    if "jsonschema" not in sys.modules:
        sys.modules.setdefault("rfc3987_syntax", None)  # type: ignore[arg-type]
