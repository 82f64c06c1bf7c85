"""The hsmap exception family.

Every error raised on purpose by hsmap derives from :class:`HsmapError`, so that callers (and the
``hsmap`` command, which turns them into a one-line message and a non-zero exit) can catch them apart
from programming errors. Messages name the argument, file, key or field at fault and what was expected.
"""

from __future__ import annotations

__all__ = [
    "HsmapError",
    "InputError",
    "ShapeError",
    "EmptyInputError",
    "DegenerateInputError",
    "UnusableFrameError",
    "ConfigError",
    "DataFormatError",
    "DatasetError",
    "ScenarioError",
    "HsmapWarning",
    "HsmapNote",
    "CacheError",
    "DependencyError",
    "OutputError",
]


class HsmapError(Exception):
    """Base class of every error hsmap raises on purpose."""


class InputError(HsmapError, ValueError):
    """An argument has a value hsmap cannot work with (wrong range, NaN, inverted bounds, ...)."""


class ShapeError(InputError):
    """An array argument has the wrong shape or dimensionality."""


class EmptyInputError(InputError):
    """An input that must hold data is empty (or nothing is left after dropping invalid values)."""


class DegenerateInputError(InputError):
    """An input holds data, but not enough to determine what is asked: a point cloud whose points all coincide or
    lie on one line (2D) or one plane (3D) has no unique registration."""


class UnusableFrameError(EmptyInputError):
    """A frame (one time step of a recording) cannot be used: its scan or cloud is missing or has too few usable
    points. :func:`hsmap.slam.run_slam` skips such frames with a warning unless ``strict``.

    Attributes
    ----------
    index : int or None
        The frame's position in its sequence.
    stamp : float or None
        The frame's stamp, seconds.
    """

    def __init__(self, message: str, index: int | None = None, stamp: float | None = None) -> None:
        super().__init__(message)
        self.index = index
        self.stamp = stamp


class ConfigError(HsmapError, ValueError):
    """A configuration value or file is invalid (unknown key, out of range, wrong type)."""


class DataFormatError(HsmapError, ValueError):
    """A file does not have the expected format; the message names the file and, where known, the line."""


class DatasetError(HsmapError):
    """A dataset cannot be found or read (missing file, missing topic, ...)."""


class ScenarioError(ConfigError):
    """A simulator scenario file is malformed; the message names the file, the key and the problem."""


class HsmapWarning(UserWarning):
    """Something hsmap worked around (a failed optimisation, a skipped input): the result is usable but the user
    should know."""


class HsmapNote(HsmapWarning):
    """Something hsmap did that the user may not expect but that needs no action (files of an input folder left
    out as not being its data); the command line prints it as ``hsmap: note: ...``."""


class OutputError(HsmapError, OSError):
    """An output could not be written completely (no space left, a read-only or missing folder, a file a library
    wrote that does not read back): the message names the output and the cause. Nothing was published under its
    name; a file of an earlier run there is left as it was. Also an :class:`OSError`, so callers that catch I/O
    errors catch it too."""


class CacheError(HsmapError):
    """A cached result cannot be looked up or published: its lock is not free in time, or the code digest that
    keys it cannot be computed (a file it expects is missing)."""


class DependencyError(HsmapError):
    """An optional part of hsmap is used without the packages it needs; the message says what to install
    (e.g. ``pip install 'hsmap[study]'`` for the notebooks)."""
