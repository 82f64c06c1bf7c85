"""File I/O shared by every stage: atomic writes, JSON, rows of numbers.

Outputs are written atomically: to a temporary file in the same folder, then renamed over the target,
so an interrupted run never leaves a half-written file that looks complete.
"""

from __future__ import annotations

import contextlib
import enum
import json
import os
import tempfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import IO, Any

import numpy as np
from numpy.typing import NDArray

from .errors import DataFormatError, DatasetError

__all__ = [
    "atomic_path",
    "atomic_open",
    "write_json",
    "to_plain",
    "write_text",
    "read_number_rows",
]


def _default_file_mode() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


_FILE_MODE = _default_file_mode()  # what open() would give a new file (mkstemp makes it private)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it over ``path``, on error delete it.

    Use for writers that want a file name (open3d, PIL, rerun): ``with atomic_path(p) as tmp: write(tmp)``.
    The temporary file keeps ``path``'s suffix (or ``suffix``) so that format-sniffing writers work.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix if suffix is not None else path.suffix,
                               dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        if tmp_path.exists():
            os.chmod(tmp_path, _FILE_MODE)
        os.replace(tmp_path, path)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "w", **kwargs: Any) -> Iterator[IO[Any]]:
    """Open ``path`` for writing atomically (see :func:`atomic_path`)."""
    with atomic_path(path) as tmp, open(tmp, mode, **kwargs) as fh:
        yield fh


def to_plain(value: Any) -> Any:
    """``value`` as plain Python data for JSON and YAML: mappings become dicts with string keys, lists and tuples
    lists, numpy arrays nested lists, numpy scalars Python numbers, enums their value, paths strings; anything
    else is returned as it is."""
    if isinstance(value, Mapping):
        return {str(k): to_plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, enum.Enum):
        return value.value
    if isinstance(value, Path):
        return str(value)
    return value


def _json_default(o: Any) -> Any:
    plain = to_plain(o)
    if plain is o:
        raise TypeError(f"cannot serialise {type(o).__name__} to JSON")
    return plain


def write_json(path: str | os.PathLike, obj: Any) -> None:
    """Write ``obj`` as indented JSON, atomically (numpy scalars and arrays allowed)."""
    with atomic_open(path, "w", encoding="utf-8") as fh:
        json.dump(obj, fh, indent=2, default=_json_default)
        fh.write("\n")


def write_text(path: str | os.PathLike, text: str) -> None:
    """Write text atomically."""
    with atomic_open(path, "w", encoding="utf-8") as fh:
        fh.write(text)


def read_number_rows(path: str | os.PathLike, fields: str, what: str) -> NDArray[np.float64]:
    """Rows of whitespace- (or comma-) separated finite numbers, one per line; ``#`` lines and blank lines skipped.

    Parameters
    ----------
    fields : str
        The expected fields, e.g. ``"t x y z qx qy qz qw"``: their count is the row width, their names go into
        the error messages.
    what : str
        What the rows are (``"poses"``), for the message of an empty file.

    Raises
    ------
    DatasetError
        The file does not exist.
    DataFormatError
        A line does not hold that many finite numbers (the message gives the file and line), or no line does.
    """
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: no such file")
    n = len(fields.split())
    rows = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for lineno, line in enumerate(fh, 1):
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            parts = line.replace(",", " ").split()
            if len(parts) != n:
                raise DataFormatError(f"{path}:{lineno}: expected {n} values '{fields}', got {len(parts)}")
            try:
                vals = [float(v) for v in parts]
            except ValueError:
                raise DataFormatError(f"{path}:{lineno}: not a number in {line!r}") from None
            if not np.all(np.isfinite(vals)):
                raise DataFormatError(f"{path}:{lineno}: NaN or inf in {line!r}")
            rows.append(vals)
    if not rows:
        raise DataFormatError(f"{path}: no {what} in file")
    return np.asarray(rows)
