"""Checks that a written file is complete where the library that wrote it cannot be trusted to report a failure.

:func:`verify_output` picks the check by suffix: a ``.ply`` whose header promises more vertices than the file
holds, a rerun ``.rrd`` cut short (no footer) raise :class:`~hsmap.errors.OutputError`; other files pass.
:func:`hsmap.io.publish_file` runs it before renaming a temporary file over its target.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Callable
from pathlib import Path

from .errors import OutputError

_PLY_TYPES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2, "uint16": 2,
              "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}


def _verify_ply(path: Path, name: Path) -> None:
    """A PLY file is complete: its header ends, and its body holds what the header announces."""
    size = path.stat().st_size
    with open(path, "rb") as fh:
        head = fh.read(1 << 20)
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        raise OutputError(f"{name}: incomplete PLY file ({size} bytes, no complete header)")
    nl = head.find(b"\n", end)
    if nl < 0:
        raise OutputError(f"{name}: incomplete PLY file ({size} bytes, no complete header)")
    body_start = nl + 1
    fmt, elements = None, []  # (count, stride or None)
    for line in head[:end].decode("ascii", "replace").splitlines():
        w = line.split()
        if not w:
            continue
        if w[0] == "format" and len(w) > 1:
            fmt = w[1]
        elif w[0] == "element" and len(w) == 3:
            elements.append([int(w[2]), 0])
        elif w[0] == "property" and elements:
            if len(w) >= 2 and w[1] == "list" or elements[-1][1] is None:
                elements[-1][1] = None
            elif len(w) >= 3 and w[1] in _PLY_TYPES:
                elements[-1][1] += _PLY_TYPES[w[1]]
    if fmt is None:
        raise OutputError(f"{name}: incomplete PLY file (no format line)")
    if fmt == "ascii":
        with open(path, "rb") as fh:
            fh.seek(body_start)
            rows = sum(1 for line in fh if line.strip())
        expected = sum(c for c, _ in elements)
        if rows < expected or not _ends_with_newline(path):
            raise OutputError(f"{name}: incomplete PLY file ({rows} of {expected} rows)")
        return
    if any(stride is None for _, stride in elements):
        return  # list properties: the size cannot be told from the header
    expected = body_start + sum(c * stride for c, stride in elements)
    if size != expected:
        raise OutputError(f"{name}: incomplete PLY file ({size} bytes, its header announces {expected})")


def _ends_with_newline(path: Path) -> bool:
    with open(path, "rb") as fh:
        fh.seek(-1, os.SEEK_END)
        return fh.read(1) == b"\n"


_RRD_MAGIC = b"RRF2"


_RRD_FOOTER_MAGIC = b"RRF2FOOT"


def _verify_rrd(path: Path, name: Path) -> None:
    """A rerun ``.rrd`` file is complete: its messages run up to the end-of-stream message, and the footer that
    rerun writes when the recording is closed is there and points back at it."""
    size = path.stat().st_size
    with open(path, "rb") as fh:
        if fh.read(4) != _RRD_MAGIC:
            raise OutputError(f"{name}: incomplete rerun recording ({size} bytes, no RRF2 header)")
        if size < 12 + 16 + 32:
            raise OutputError(f"{name}: incomplete rerun recording ({size} bytes)")
        fh.seek(size - 32)
        tail = fh.read(32)
        if tail[20:28] != _RRD_FOOTER_MAGIC:
            raise OutputError(f"{name}: incomplete rerun recording ({size} bytes, no footer: it was not closed or "
                              "not written completely)")
        footer_at, footer_len = struct.unpack("<QQ", tail[:16])
        if footer_at + footer_len + 32 != size:
            raise OutputError(f"{name}: incomplete rerun recording (its footer does not match its {size} bytes)")
        offset = 12
        while True:
            fh.seek(offset)
            hdr = fh.read(16)
            if len(hdr) < 16:
                raise OutputError(f"{name}: incomplete rerun recording (message at byte {offset} cut off)")
            kind, length = struct.unpack("<QQ", hdr)
            if kind == 0:  # end of stream: the footer follows
                if offset + 16 != footer_at or length != footer_len:
                    raise OutputError(f"{name}: incomplete rerun recording (end of stream at byte {offset} does "
                                      "not match its footer)")
                return
            offset += 16 + length
            if offset > footer_at:
                raise OutputError(f"{name}: incomplete rerun recording (message at byte {offset} runs past the "
                                  "footer)")


_VERIFIERS: dict[str, Callable[[Path, Path], None]] = {".ply": _verify_ply, ".rrd": _verify_rrd}


def verify_output(path: str | os.PathLike, *, name: str | os.PathLike | None = None) -> None:
    """Check that a file a library wrote is complete, for the formats whose writers do not report failures.

    ``.ply`` (Open3D's ``write_point_cloud`` returns True even when the disk is full): the header is whole and
    the file holds as many bytes (or rows) as the header announces. ``.rrd`` (rerun writes from a background
    thread and logs, rather than raises, its errors): the messages run up to the end-of-stream message and the
    footer rerun adds on closing is there. Other suffixes: nothing to check (Python's own writers raise).

    Parameters
    ----------
    path : path-like
        The file to check.
    name : path-like, optional
        The name to give in the message (the final name of a temporary file).

    Raises
    ------
    OutputError
        The file is incomplete.
    """
    path = Path(path)
    check = _VERIFIERS.get(Path(name if name is not None else path).suffix.lower())
    if check is not None:
        try:
            check(path, Path(name) if name is not None else path)
        except OutputError:
            raise
        except (OSError, ValueError) as exc:
            raise OutputError(f"{name or path}: cannot check it ({exc})") from None
