"""A folder of point clouds (``.pcd``, ``.ply``, KITTI ``.bin``, ``.csv``) as a recording, optionally with a folder
of 2D scans beside it.

Layout
------
- The clouds: one file per 3D LiDAR sweep, in the 3D sensor's frame, in **natural order** of their names (digit
  runs compared as numbers: ``full2`` before ``full10``; KITTI's zero-padded ``000000.bin`` as they sort; names that
  are decimal numbers, such as stamps, by value). One kind of file per folder:

  - ``.pcd``: ``DATA ascii``, ``binary`` or ``binary_compressed`` (:mod:`hsmap.datasets.pcd`), any fields
    beside ``x y z``;
  - ``.ply``: read with Open3D (ASCII or binary);
  - ``.bin``: KITTI Velodyne, float32 ``x y z intensity`` per point (16 bytes);
  - ``.csv`` (or ``.txt``): one point per line, ``x y [z]`` separated by commas or spaces, ``#`` comments.

  Points at exactly (0, 0, 0) and non-finite ones are no returns and are dropped.
- Files that are not clouds are left out, with one note (:class:`~hsmap.errors.HsmapNote`) naming them and why:
  files of other endings (``README.md``), text files (``.csv``/``.txt``) beside ``.pcd``/``.ply``/``.bin`` clouds
  (poses, calibration), and, where most files are numbered alike (``full#.pcd``), the files not named so. Two
  kinds of cloud file (``.pcd`` and ``.ply``) are an error naming them.
- The stamps (seconds), one per cloud in natural order: a stamps file given as ``times`` (``--times FILE``), else
  a ``times.txt`` in the folder or beside it (KITTI's ``sequences/NN/times.txt`` next to ``velodyne/``). A stamps
  file holds one stamp a line, or is a TUM trajectory (``t x y z qx qy qz qw``, its first column taken). Or a fixed
  rate (``cloud_rate``, ``--cloud-rate HZ``: file *k* at *k* / rate), which wins over a ``times.txt``.
- Optionally the 2D scans (``scans``, ``--scans DIR``): a folder of the same kinds of files, each a 2D LiDAR
  scan as points in the 2D sensor's frame (z ignored), with its own ``times.txt`` or rate (``scan_rate``,
  ``--scan-rate HZ``).

With both sensors, frames are made by one of them (``drive``: the scans by default, the clouds for a 6-DOF run,
:meth:`CloudFolderDataset.driven_by`) and the other's nearest file within ``sync_tolerance`` is attached, as
for a bag (:mod:`hsmap.datasets.rosbag`). A folder has no transforms and no odometry. Clouds alone (no 2D scans)
are posed in their own frame: the robot base is the 3D sensor (a hand-held LiDAR), its offset zero without a
warning (source :data:`SOURCE_SENSOR`); ``extrinsic3d`` gives one where a base matters. With 2D scans too, the
offsets are zero unless given (``extrinsic2d``/``extrinsic3d``), with a warning.
"""

from __future__ import annotations

import math
import os
import re
import warnings
from collections import Counter
from collections.abc import Iterator
from decimal import Decimal
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..errors import DataFormatError, DatasetError, HsmapNote, InputError
from ..io import read_number_rows
from ..limits import check_allocation
from ..trajectory import nearest_index
from .frames import SOURCE_DEFAULT, Dataset, Frame, LaserScan2D, stamp_in_sweep

__all__ = ["CloudFolderDataset", "CLOUD_SUFFIXES", "SOURCE_SENSOR", "is_cloud_folder", "natural_key",
           "cloud_files", "read_stamps", "read_points", "read_points_timed"]

#: File endings read as point clouds (``.txt`` as ``.csv``).
CLOUD_SUFFIXES = (".pcd", ".ply", ".bin", ".csv", ".txt")
TIMES = "times.txt"
#: The offset source of clouds alone: posed in their own frame.
SOURCE_SENSOR = "sensor frame (clouds alone)"
_TEXT = (".csv", ".txt")
#: Names listed per reason in the note on files left out.
_NOTE_NAMES = 6

_OPTION_NAMES = {"cloud_rate": "cloud_rate", "scans": "scans", "scan_rate": "scan_rate",
                 "sync_tolerance": "sync_tolerance", "drive": "drive", "extrinsic2d": "extrinsic2d",
                 "extrinsic3d": "extrinsic3d", "times": "times"}


def natural_key(name: str) -> tuple:
    """Sort key of a file name in natural order: digit runs compared as numbers (``full2`` before ``full10``); a
    name whose stem is a decimal number (a stamp, ``1630577758.5690``) by its value, before other names."""
    stem = name[: -len(Path(name).suffix)] if Path(name).suffix else name
    if re.fullmatch(r"\d+(\.\d+)?", stem):
        return (0, (Decimal(stem),), name)
    parts = tuple((0, int(t), "") if t.isdigit() else (1, 0, t) for t in re.split(r"(\d+)", stem) if t)
    return (1, parts, name)


def _pattern(name: str) -> str:
    """A file name with its digit runs as ``#`` and its ending in lower case (``full#.pcd``)."""
    p = Path(name)
    return re.sub(r"\d+", "#", name[: len(name) - len(p.suffix)]) + p.suffix.lower()


def _candidates(folder: Path, skip: set[str]) -> tuple[list[Path], dict[str, list[str]]]:
    """The files of ``folder`` with a cloud ending (but ``skip``), and the others by why they are left out."""
    left: dict[str, list[str]] = {}
    found = []
    for f in folder.iterdir():
        if f.name.startswith(".") or f.name in skip or not f.is_file():
            continue
        if f.suffix.lower() in CLOUD_SUFFIXES:
            found.append(f)
        else:
            left.setdefault("not a cloud file", []).append(f.name)
    return found, left


def cloud_files(folder: str | os.PathLike, skip: tuple[str, ...] = (), what: str = "cloud"
                ) -> tuple[list[Path], dict[str, list[str]]]:
    """The cloud files of ``folder`` in natural order (:func:`natural_key`), and the files left out, by why.

    Left out: ``times.txt`` and ``skip`` (without a word), hidden files and folders, files of other endings, text
    files (``.csv``/``.txt``) beside binary clouds (``.pcd``/``.ply``/``.bin``) and, where more than half the files
    are numbered alike (``full#.pcd``), those named otherwise.

    Raises
    ------
    DatasetError
        The folder holds two kinds of cloud file (naming them).
    """
    folder = Path(folder)
    found, left = _candidates(folder, {TIMES, *skip})
    binary = sorted({f.suffix.lower() for f in found} - set(_TEXT))
    if binary:
        text = [f for f in found if f.suffix.lower() in _TEXT]
        if text:
            left.setdefault(f"text beside the {' and '.join(binary)} {what}s", []).extend(f.name for f in text)
            found = [f for f in found if f.suffix.lower() not in _TEXT]
    kinds = sorted({f.suffix.lower() for f in found})
    if len(kinds) > 1:
        raise DatasetError(f"{folder}: holds {' and '.join(kinds)} files; expected one kind of {what} file")
    if found:
        counts = Counter(_pattern(f.name) for f in found)
        top, n = max(counts.items(), key=lambda kv: (kv[1], kv[0]))
        if "#" in top and n > len(found) / 2 and n < len(found):
            others = [f for f in found if _pattern(f.name) != top]
            left.setdefault(f"not named like the numbered {what}s {top}", []).extend(f.name for f in others)
            found = [f for f in found if _pattern(f.name) == top]
    return sorted(found, key=lambda f: natural_key(f.name)), left


def _left_out_note(folder: Path, left: dict[str, list[str]], what: str) -> str:
    """One line naming the files left out of ``folder`` and why."""
    parts = []
    for why, names in left.items():
        names = sorted(names, key=natural_key)
        shown = ", ".join(names[:_NOTE_NAMES]) + (f" and {len(names) - _NOTE_NAMES} more" if len(names) >
                                                  _NOTE_NAMES else "")
        parts.append(f"{shown} ({why})")
    n = sum(len(v) for v in left.values())
    return f"{folder}: {n} file{'s' if n > 1 else ''} not read as {what}s: {'; '.join(parts)}"


def _listed(names: list[str], most: int = 20) -> list[str]:
    """``names`` in natural order, at most ``most`` of them and a last ``"... and N more"``."""
    names = sorted(names, key=natural_key)
    return names if len(names) <= most else names[:most] + [f"... and {len(names) - most} more"]


def is_cloud_folder(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a folder holding point-cloud files (and no bag or simulator description)."""
    p = Path(path)
    return p.is_dir() and bool(_candidates(p, {TIMES})[0])


def read_stamps(path: str | os.PathLike) -> tuple[NDArray[np.float64], str]:
    """The stamps (seconds) of a stamps file: one a line, or a TUM trajectory (``t x y z qx qy qz qw``; its first
    column); ``#`` lines and blank lines skipped. Also what the file is (``"stamps"`` or ``"TUM trajectory"``).

    Raises
    ------
    DatasetError
        No such file.
    DataFormatError
        A line holds neither one number nor a TUM line's eight (naming the file and line), or no line holds any.
    """
    p = Path(path)
    if not p.is_file():
        raise DatasetError(f"{p}: no such file; expected a stamps file (one a line, or a TUM trajectory)")
    check_allocation(float(p.stat().st_size) * 16, f"{p}: a stamps file of {p.stat().st_size} bytes",
                     DataFormatError)
    width, at = None, 0
    with open(p, encoding="utf-8", errors="replace") as fh:
        for line in fh:
            at += 1
            text = line.strip()
            if text and not text.startswith("#"):
                width = len(text.replace(",", " ").split())
                break
    if width not in (None, 1, 8):
        raise DataFormatError(f"{p}:{at}: expected one stamp a line or a TUM trajectory line (t x y z qx qy "
                              f"qz qw), got {width} values")
    tum = width == 8
    rows = read_number_rows(p, "t x y z qx qy qz qw" if tum else "t", "stamps")
    return rows[:, 0].astype(float), "TUM trajectory" if tum else "stamps"


def read_points(path: str | os.PathLike) -> NDArray[np.float64]:
    """The points (N, 3) of one ``.pcd``/``.ply``/``.bin``/``.csv`` file; no-return points (zeros, NaN) dropped.

    Raises
    ------
    DataFormatError
        The file is not what its ending says (naming the file and what was expected).
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix == ".bin":
        size = p.stat().st_size
        if size % 16:
            raise DataFormatError(f"{p}: {size} bytes is not a whole number of KITTI points (16 bytes: float32 x, y, "
                                  "z, intensity)")
        pts = np.fromfile(p, dtype="<f4").reshape(-1, 4)[:, :3].astype(float)
    elif suffix == ".pcd":
        from .pcd import read_pcd

        rec = read_pcd(p)
        pts = _xyz(p, rec)
    elif suffix == ".ply":
        with open(p, "rb") as fh:
            head = fh.read(256)
        if not head.startswith(b"ply"):
            raise DataFormatError(f"{p}: not a PLY point cloud (expected a ply header)")
        declared = _declared_points(p)
        import open3d as o3d

        pts = np.asarray(o3d.io.read_point_cloud(str(p)).points, dtype=float)
        if declared is not None and len(pts) != declared:
            raise DataFormatError(f"{p}: damaged: its header declares {declared} points, {len(pts)} could be read "
                                  "(the file is cut short or its data do not match the header)")
    else:
        rows = []
        with open(p, encoding="utf-8", errors="replace") as fh:
            for lineno, line in enumerate(fh, 1):
                text = line.split("#", 1)[0].replace(",", " ").split()
                if not text:
                    continue
                try:
                    values = [float(v) for v in text]
                except ValueError:
                    raise DataFormatError(f"{p}:{lineno}: expected numbers x y [z], got {line.strip()!r}") from None
                if len(values) not in (2, 3):
                    raise DataFormatError(f"{p}:{lineno}: expected 2 or 3 numbers (x y [z]), got {len(values)}")
                rows.append(values + [0.0] * (3 - len(values)))
        pts = np.asarray(rows, dtype=float).reshape(-1, 3)
    return pts[np.isfinite(pts).all(axis=1) & (pts != 0.0).any(axis=1)]


def _xyz(p: Path, rec: np.ndarray) -> NDArray[np.float64]:
    """The (N, 3) positions of a PCD's records."""
    names = rec.dtype.names or ()
    missing = [c for c in "xyz" if c not in names]
    if missing:
        raise DataFormatError(f"{p}: its PCD FIELDS are {' '.join(names) or 'empty'}: no {', '.join(missing)} "
                              "field (a point cloud needs x, y and z)")
    if any(rec.dtype[k].shape for k in "xyz"):
        raise DataFormatError(f"{p}: no x, y, z fields of one value each (FIELDS {' '.join(names)})")
    return np.column_stack([rec["x"], rec["y"], rec["z"]]).astype(float)


_PLY_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2, "uint16": 2,
              "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}


def _declared_points(p: Path) -> int | None:
    """The number of points the header of PLY file ``p`` declares, after checking that the file is long enough to
    hold them (binary data: their bytes; text: two characters a value) and that they fit in the memory; None where
    the header cannot tell (vertices with list properties).

    Raises
    ------
    DataFormatError
        The file is shorter than its header says, or its points would not fit in the memory available.
    """

    size = p.stat().st_size
    with open(p, "rb") as fh:
        head = fh.read(65536)
    end = head.find(b"end_header\n")
    if end < 0:
        raise DataFormatError(f"{p}: damaged PLY header (no end_header line in its first 64 KiB)")
    lines = head[:end].decode("latin-1").splitlines()
    count, width, binary, variable, values = None, 0, False, False, 0
    elements: list[str] = []  # a PLY's elements in order: with the vertices alone, the data are theirs exactly
    data_start, element = end + len(b"end_header\n"), None
    for line in lines:
        w = line.split()
        if w[:1] == ["format"] and len(w) > 1:
            binary = w[1].startswith("binary")
        elif w[:1] == ["element"] and len(w) == 3:
            element = w[1]
            elements.append(element)
            if element == "vertex":
                try:
                    count = int(w[2])
                except ValueError:
                    raise DataFormatError(f"{p}: damaged PLY header: 'element vertex {w[2]}'") from None
        elif w[:1] == ["property"] and element == "vertex":
            if len(w) > 1 and w[1] == "list":
                variable = True
            width += _PLY_SIZES.get(w[1], 0) if binary and len(w) > 1 else 2
            values += 1
    if count is None or variable:
        return None
    if count < 0:
        raise DataFormatError(f"{p}: damaged header: {count} points")
    check_allocation(float(count) * 64, f"{p}: {count} points declared in its header",
                     DataFormatError)
    need = float(count) * width
    if size - data_start < need:
        raise DataFormatError(f"{p}: damaged: its header declares {count} points ({need:.0f} bytes of "
                              f"{'binary' if binary else 'text'} data at least), the file holds "
                              f"{size - data_start} bytes after its header (cut short?)")
    alone = elements == ["vertex"]
    if binary and alone and size - data_start > need:
        raise DataFormatError(f"{p}: damaged: its header declares {count} vertices ({need:.0f} bytes), the file "
                              f"holds {size - data_start} bytes after its header (more data than declared)")
    if not binary and values:
        with open(p, "rb") as fh:
            fh.seek(data_start)
            found = len(fh.read().split())
        if found < count * values:
            raise DataFormatError(f"{p}: damaged: its header declares {count} points of {values} values, the file "
                                  f"holds {found} values after its header (cut short?)")
        if alone and found > count * values:
            raise DataFormatError(f"{p}: damaged: its header declares {count} vertices of {values} values, the file "
                                  f"holds {found} values after its header (more data than declared)")
    return count


_PCD_TYPES = {("F", 4): "f4", ("F", 8): "f8", ("U", 1): "u1", ("U", 2): "u2", ("U", 4): "u4", ("U", 8): "u8",
              ("I", 1): "i1", ("I", 2): "i2", ("I", 4): "i4", ("I", 8): "i8"}
_PLY_TYPES = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4", "uint": "u4", "float": "f4",
              "double": "f8", "int8": "i1", "uint8": "u1", "int16": "i2", "uint16": "u2", "int32": "i4",
              "uint32": "u4", "float32": "f4", "float64": "f8"}


def _header(path: Path, end: bytes) -> tuple[list[str], int]:
    """The header lines of a .pcd/.ply file up to the line starting with ``end``, and the data's byte offset."""
    lines, pos = [], 0
    with open(path, "rb") as fh:
        for raw in iter(fh.readline, b""):
            pos += len(raw)
            lines.append(raw.decode("ascii", errors="replace").strip())
            if raw.startswith(end) or len(lines) > 200:
                break
    return lines, pos


def _records(path: Path) -> tuple[np.ndarray, str] | None:
    """The vertex records of a .pcd (:func:`hsmap.datasets.pcd.read_pcd`) or .ply (ascii or binary, vertices first) file with a
    per-point time field (:data:`hsmap.datasets.rosbag.POINT_TIME_FIELDS`) and that field's name; None for
    any other file."""
    from .rosbag import POINT_TIME_FIELDS

    if path.suffix.lower() == ".pcd":
        from .pcd import read_pcd

        rec = read_pcd(path)
        names = rec.dtype.names
        tname = next((n for n in POINT_TIME_FIELDS if n in names), None)
        if tname is None or rec.dtype[tname].shape:
            return None
        _xyz(path, rec)  # x, y, z there
        return rec, tname
    lines, pos = _header(path, b"end_header")
    fmt = next((ln.split()[1] for ln in lines if ln.startswith("format ")), "")
    names, codes, n, in_vertex = [], [], 0, False
    for ln in lines:
        w = ln.split()
        if w[:1] == ["element"]:
            if names:  # vertices must come first
                break
            in_vertex = w[1:2] == ["vertex"]
            n = int(w[2]) if in_vertex and len(w) > 2 and w[2].isdigit() else 0
            if not in_vertex:
                return None
        elif w[:1] == ["property"] and in_vertex:
            if w[1] == "list" or w[1] not in _PLY_TYPES:
                return None
            codes.append(_PLY_TYPES[w[1]])
            names.append(w[2])
    tname = next((nm for nm in POINT_TIME_FIELDS if nm in names), None)
    if tname is None or fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        return None
    ascii_ = fmt == "ascii"
    endian = ">" if fmt == "binary_big_endian" else "<"
    if not {"x", "y", "z"} <= set(names) or len(set(names)) != len(names):
        return None
    dtype = np.dtype({"names": names, "formats": [endian + c for c in codes]})
    if ascii_:
        with open(path, "rb") as fh:
            fh.seek(pos)
            try:
                rows = np.loadtxt(fh, dtype=float, ndmin=2, max_rows=n)
            except ValueError as exc:
                raise DataFormatError(f"{path}: unreadable ascii points ({exc})") from None
        if rows.shape != (n, len(names)):
            raise DataFormatError(f"{path}: expected {n} points of {len(names)} values, got {rows.shape}")
        rec = np.zeros(n, dtype=[(nm, "f8") for nm in names])
        for k, nm in enumerate(names):
            rec[nm] = rows[:, k]
        return rec, tname
    size = path.stat().st_size
    if size - pos < n * dtype.itemsize:
        raise DataFormatError(f"{path}: {size - pos} bytes of points, expected {n} of {dtype.itemsize} bytes")
    return np.fromfile(path, dtype=dtype, count=n, offset=pos), tname


def read_points_timed(path: str | os.PathLike, stamp: float = 0.0
                      ) -> tuple[NDArray[np.float64], NDArray[np.float64] | None, str | None]:
    """The points (N, 3) of one cloud file (as :func:`read_points`) and, for a .pcd/.ply with a per-point time
    field (the names and units of :data:`hsmap.datasets.rosbag.POINT_TIME_FIELDS`), each point's seconds
    relative to ``stamp`` (the file's stamp), and the field's name; (points, None, None) otherwise."""
    from .ros_messages import POINT_TIME_FIELDS, point_time_unit

    p = Path(path)
    got = _records(p) if p.suffix.lower() in (".pcd", ".ply") else None
    if got is None:
        return read_points(p), None, None
    rec, tname = got
    pts = np.column_stack([rec["x"], rec["y"], rec["z"]]).astype(float)
    ok = np.isfinite(pts).all(axis=1) & (pts != 0.0).any(axis=1)
    scale, label = point_time_unit(tname, rec[tname][ok])
    t = rec[tname][ok].astype(float) * scale - (float(stamp) if POINT_TIME_FIELDS[tname][2] else 0.0)
    if not np.all(np.isfinite(t)):
        raise DataFormatError(f"{p}: field {tname!r} holds non-finite (NaN or infinite) times")
    return pts[ok], t, label


def _scan_from_points(pts: NDArray[np.float64]) -> LaserScan2D:
    xy = pts[:, :2]
    r = np.hypot(xy[:, 0], xy[:, 1])
    a = np.arctan2(xy[:, 1], xy[:, 0])
    order = np.argsort(a, kind="stable")
    return LaserScan2D(ranges=r[order], angles=a[order])


class _Stream:
    """One sensor's files and stamps; ``left_out``: the folder's files that are not its data, by why."""

    def __init__(self, folder: Path, rate: float | None, what: str, folder_flag: str, rate_flag: str,
                 times: str | os.PathLike | None = None, times_flag: str | None = None) -> None:
        if not folder.is_dir():
            raise DatasetError(f"{folder_flag} {folder}: no such folder; expected a folder of {what} files "
                               f"({', '.join(CLOUD_SUFFIXES)})")
        self.folder = folder
        if times is not None and rate is not None:
            raise InputError(f"{times_flag} and {rate_flag} both give the {what}s' stamps; give one of them")
        times = None if times is None else Path(times)
        skip = (times.name,) if times is not None and times.parent.resolve() == folder.resolve() else ()
        self.files, self.left_out = cloud_files(folder, skip, what)
        if self.left_out:  # before the stamps are counted against the files
            warnings.warn(_left_out_note(folder, self.left_out, what), HsmapNote, stacklevel=3)
        if not self.files:
            raise DatasetError(f"{folder_flag} {folder}: no {what} files ({', '.join(CLOUD_SUFFIXES)})")
        self.kind = self.files[0].suffix.lower()
        n = len(self.files)
        if rate is not None:
            if not (math.isfinite(rate) and rate > 0):
                raise InputError(f"{rate_flag} must be a rate in Hz > 0, got {rate!r}")
            self.stamps = np.arange(n) / float(rate)
            self.stamp_source = f"{rate_flag} {rate:g}"
            return
        if times is None:
            times = next((t for t in (folder / TIMES, folder.parent / TIMES) if t.is_file()), None)
        elif not times.is_file():
            raise DatasetError(f"{times_flag} {times}: no such file; expected the {what}s' stamps, one a line or a "
                               "TUM trajectory")
        if times is None:
            give = f"stamps with {times_flag} FILE (one a line, or a TUM trajectory) or their " if times_flag else ""
            raise DatasetError(f"{folder}: no {TIMES} in the folder or beside it; give the {what}s' {give}rate "
                               f"with {rate_flag} HZ")
        stamps, kind = read_stamps(times)
        if len(stamps) != n:
            raise DataFormatError(f"{times}: {len(stamps)} stamps{' (a TUM trajectory)' if kind != 'stamps' else ''} "
                                  f"for the {n} {what} files of {folder}; expected one per file, in natural order")
        self.stamps = stamps
        if not np.all(np.isfinite(self.stamps)) or np.any(np.diff(self.stamps) <= 0):
            raise DataFormatError(f"{times}: stamps must be finite and increase from line to line (the files' "
                                  "natural order)")
        self.stamp_source = str(times)

    def describe(self) -> dict:
        st = self.stamps
        return {"folder": str(self.folder), "files": len(self.files), "kind": self.kind,
                "first": self.files[0].name, "last": self.files[-1].name,
                "left_out": {why: _listed(names) for why, names in self.left_out.items()},
                "stamps": self.stamp_source,
                "rate_hz": (len(st) - 1) / float(st[-1] - st[0]) if len(st) > 1 else None}


class CloudFolderDataset(Dataset):
    """Frames from a folder of point clouds, optionally with a folder of 2D scans (see the module docstring).

    Parameters
    ----------
    path : str or Path
        The clouds folder.
    cloud_rate : float, optional
        Hz: file *k* is stamped *k* / rate (instead of a ``times.txt``).
    scans : str or Path, optional
        A folder of 2D scans.
    scan_rate : float, optional
        Hz, for the scans (instead of their ``times.txt``).
    sync_tolerance : float
        Largest stamp difference (s) for attaching the other sensor's file to a frame.
    drive : str, optional
        ``"scan"`` or ``"cloud"``: the sensor whose files make the frames (default the scans when given).
    extrinsic2d, extrinsic3d : array_like of shape (3,) / (6,), optional
        The sensors' poses in the robot base frame. Not given: zero; with 2D scans, with a warning; for clouds
        alone without one (the base is the 3D sensor, source :data:`SOURCE_SENSOR`).
    times : str or Path, optional
        The clouds' stamps file (one a line, or a TUM trajectory), instead of a ``times.txt``.
    option_names : mapping, optional
        The caller's names of the options, for messages (``{"cloud_rate": "--cloud-rate", ...}``).
    """

    def __init__(self, path: str | os.PathLike, *, cloud_rate: float | None = None, scans: str | os.PathLike | None = None,
                 scan_rate: float | None = None, sync_tolerance: float = 0.1, drive: str | None = None,
                 extrinsic2d=None, extrinsic3d=None, times: str | os.PathLike | None = None,
                 option_names: dict | None = None) -> None:
        names = {**_OPTION_NAMES, **(option_names or {})}
        self._names = names
        p = Path(path)
        self.path = str(p)
        self.name = p.name
        if not (math.isfinite(float(sync_tolerance)) and float(sync_tolerance) >= 0):
            raise InputError(f"{names['sync_tolerance']} must be a number of seconds >= 0, got {sync_tolerance!r}")
        self.sync_tolerance = float(sync_tolerance)
        if drive not in (None, "scan", "cloud"):
            raise InputError(f"{names['drive']} must be 'scan' or 'cloud', got {drive!r}")
        if scan_rate is not None and scans is None:
            raise InputError(f"{names['scan_rate']} needs a folder of 2D scans ({names['scans']} DIR)")
        self.cloud_rate, self.scan_rate = cloud_rate, scan_rate
        # read too: part of the input's identity
        self.extra_paths = ([] if scans is None else [str(scans)]) + ([] if times is None else [str(times)])
        self._clouds = _Stream(p, cloud_rate, "cloud", "input", names["cloud_rate"], times, names["times"])
        self._scans = None if scans is None else _Stream(Path(scans), scan_rate, "scan", names["scans"],
                                                        names["scan_rate"])
        self.extrinsic2d = np.zeros(3) if self._scans is not None else None
        self.extrinsic3d = np.zeros(6)
        self.extrinsic_sources.clear()
        self.extrinsic_sources["3d"] = SOURCE_DEFAULT if self._scans is not None else SOURCE_SENSOR
        if self._scans is not None:
            self.extrinsic_sources["2d"] = SOURCE_DEFAULT
        if extrinsic3d is not None:
            self.override_extrinsics(extrinsic3d=extrinsic3d, source=names["extrinsic3d"])
        if extrinsic2d is not None:
            if self._scans is None:
                raise InputError(f"{names['extrinsic2d']} is the 2D LiDAR's offset, and there are no 2D scans "
                                 f"({names['scans']} DIR)")
            self.override_extrinsics(extrinsic2d=extrinsic2d, source=names["extrinsic2d"])
        for key, sig in (("2d", "X,Y,YAW"), ("3d", "X,Y,Z,ROLL,PITCH,YAW")):
            if self.extrinsic_sources.get(key) == SOURCE_DEFAULT:
                what = "2D scans" if key == "2d" else "3D clouds"
                self._warn(f"{self.path}: a folder has no transforms: the offset of the {what} in the robot base "
                           f"frame is taken as zero; give it with {names['extrinsic' + key]} {sig}")
        self._build_frames(drive or ("scan" if self._scans is not None else "cloud"))

    def _build_frames(self, driver: str) -> None:
        if driver == "scan" and self._scans is None:
            raise DatasetError(f"{self.path}: frames made by 2D scans need a folder of them ({self._names['scans']} DIR)")
        self.driver = driver
        if driver == "cloud":
            self.stamps = self._clouds.stamps.copy()
            self._cloud_index = np.arange(len(self.stamps))
            self._scan_index = (None if self._scans is None else
                                nearest_index(self._scans.stamps, self.stamps, self.sync_tolerance))
        else:
            self.stamps = self._scans.stamps.copy()
            self._scan_index = np.arange(len(self.stamps))
            self._cloud_index = nearest_index(self._clouds.stamps, self.stamps, self.sync_tolerance)

    def __len__(self) -> int:
        return len(self.stamps)

    def _describe(self) -> dict:
        out = {"clouds": self._clouds.describe(), "sync_tolerance": self.sync_tolerance}
        if self._scans is not None:
            out["scans"] = self._scans.describe()
        return out

    def frames(self, clouds: bool = True) -> Iterator[Frame]:
        for i, t in enumerate(self.stamps):
            k = -1 if self._scan_index is None else int(self._scan_index[i])
            c = int(self._cloud_index[i])
            cloud = times = None
            if clouds and c >= 0:
                cstamp = float(self._clouds.stamps[c])
                cloud, times, field = read_points_timed(self._clouds.files[c], cstamp)
                if times is not None:
                    if self.point_time is None:
                        from .ros_messages import point_time_convention

                        self.point_time = {"field": field, "convention": point_time_convention(field)}
                    times = times + (cstamp - float(t))  # relative to the frame's stamp
                    if not np.any(times):
                        times = None
            yield Frame(
                stamp=float(t),
                scan2d=_scan_from_points(read_points(self._scans.files[k])) if k >= 0 else None,
                cloud3d=cloud,
                point_times=times,
                stamp_in_sweep=None if times is None else stamp_in_sweep(times),
                index=i,
                extrinsic2d=np.zeros(3) if self.extrinsic2d is None else self.extrinsic2d.copy(),
                extrinsic3d=self.extrinsic3d.copy(),
            )
