"""One point-cloud file read, checked against what its header declares: ``.pcd`` (through :mod:`hsmap.datasets.pcd`),
``.ply`` (ascii and binary), KITTI ``.bin`` and ``.csv``/``.txt`` rows, as (N, 3) points, or with each point's
time where the file has a per-point time field (:func:`read_points_timed`)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..errors import DataFormatError
from ..limits import check_allocation


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
