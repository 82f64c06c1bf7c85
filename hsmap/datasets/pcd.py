"""PCD files (PCL's point cloud format, v0.6/v0.7): ``DATA ascii``, ``binary`` and ``binary_compressed``.

A header of ``KEY values`` lines (``FIELDS``, ``SIZE``, ``TYPE``, ``COUNT``, ``WIDTH``, ``HEIGHT``, ``VIEWPOINT``,
``POINTS``) ends with the ``DATA`` line; the points follow: text lines, little-endian records of the fields in
order, or (compressed) two little-endian uint32 (the compressed and the decompressed size) and an LZF block
(:mod:`hsmap.datasets._lzf`) that decompresses to the fields one after the other, each for every point.

:func:`read_pcd` checks what the header declares against the bytes there are (a file cut short, a block that does
not decompress to the declared points) and against the memory before allocating; each problem is one
:class:`~hsmap.errors.DataFormatError` naming the file. :func:`write_pcd` writes the three forms.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np

from ..errors import DataFormatError, InputError
from ..limits import check_allocation

__all__ = ["read_pcd", "write_pcd", "PCD_DATA"]

#: The data forms :func:`read_pcd` reads and :func:`write_pcd` writes.
PCD_DATA = ("ascii", "binary", "binary_compressed")

_TYPES = {("F", 4): "f4", ("F", 8): "f8", ("U", 1): "u1", ("U", 2): "u2", ("U", 4): "u4", ("U", 8): "u8",
          ("I", 1): "i1", ("I", 2): "i2", ("I", 4): "i4", ("I", 8): "i8"}
_KEYS = ("VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT", "POINTS", "DATA")
_MAX_HEADER = 65536


def _header(path: Path, head: bytes) -> tuple[dict[str, list[str]], int]:
    """The header's keys and values and the byte offset where the data start."""
    keys: dict[str, list[str]] = {}
    offset = 0
    for raw in head.split(b"\n"):
        end = offset + len(raw) + 1
        if end > len(head) and not head.endswith(b"\n"):
            break  # a line cut by the 64 KiB read
        line = raw.decode("latin-1").strip()
        offset = end
        if not line or line.startswith("#"):
            continue
        words = line.split()
        key = words[0].upper()
        if key not in _KEYS:
            if not keys:
                raise DataFormatError(f"{path}: not a PCD point cloud (expected a PCD VERSION/FIELDS header, got "
                                      f"{line[:40]!r})")
            raise DataFormatError(f"{path}: damaged PCD header: unknown line {line[:40]!r}")
        keys[key] = words[1:]
        if key == "DATA":
            return keys, offset
    if not keys:
        raise DataFormatError(f"{path}: not a PCD point cloud (expected a PCD VERSION/FIELDS header)")
    raise DataFormatError(f"{path}: damaged PCD header (no DATA line in its first {_MAX_HEADER // 1024} KiB)")


def _int(path: Path, keys: dict, key: str, default: int | None = None) -> int:
    words = keys.get(key)
    if words is None and default is not None:
        return default
    try:
        (value,) = words
        n = int(value)
    except (TypeError, ValueError):
        raise DataFormatError(f"{path}: damaged PCD header: {key} {' '.join(words or ['(missing)'])!r}; expected "
                              "one whole number") from None
    if n < 0:
        raise DataFormatError(f"{path}: damaged PCD header: {key} {n} < 0")
    return n


def _dtype(path: Path, keys: dict) -> np.dtype:
    """The points' record type from FIELDS, SIZE, TYPE and COUNT (padding fields ``_`` renamed apart)."""
    names = keys.get("FIELDS")
    if not names:
        raise DataFormatError(f"{path}: damaged PCD header: no FIELDS")
    sizes, types = keys.get("SIZE", []), keys.get("TYPE", [])
    counts = keys.get("COUNT") or ["1"] * len(names)
    if not (len(sizes) == len(types) == len(counts) == len(names)):
        raise DataFormatError(f"{path}: damaged PCD header: {len(names)} FIELDS, {len(sizes)} SIZE, {len(types)} "
                              f"TYPE, {len(counts)} COUNT values; expected one of each per field")
    formats, unique = [], []
    for k, (name, size, kind, count) in enumerate(zip(names, sizes, types, counts, strict=True)):
        try:
            code = _TYPES[(kind.upper(), int(size))]
            c = int(count)
        except (KeyError, ValueError):
            raise DataFormatError(f"{path}: damaged PCD header: field {name!r} has TYPE {kind} SIZE {size} COUNT "
                                  f"{count}; expected F 4/8, U or I 1/2/4/8, a count >= 1") from None
        if c < 1 or c > 4096:
            raise DataFormatError(f"{path}: damaged PCD header: field {name!r} has COUNT {c}; expected 1 to 4096")
        if name == "_" or name in unique:
            if name != "_":
                raise DataFormatError(f"{path}: damaged PCD header: field {name!r} appears twice in FIELDS")
            name = f"_{k}"
        unique.append(name)
        formats.append(("<" + code) if c == 1 else (f"<{code}", (c,)))
    return np.dtype({"names": unique, "formats": formats})


def read_pcd(path: str | os.PathLike) -> np.ndarray:
    """The points of a PCD file as a structured array, one field per ``FIELDS`` name (a field of ``COUNT`` > 1 a
    sub-array; padding fields ``_`` named ``_K``), in the types the header declares.

    Raises
    ------
    DataFormatError
        Not a PCD file; a damaged header (``POINTS`` other than ``WIDTH`` x ``HEIGHT``, unknown types); fewer bytes
        or values than the header declares; a compressed block that does not decompress to the declared points;
        points that would not fit in the memory available. The message names the file.
    """
    p = Path(path)
    size = p.stat().st_size
    with open(p, "rb") as fh:
        head = fh.read(_MAX_HEADER)
    keys, start = _header(p, head)
    dtype = _dtype(p, keys)
    width, height = _int(p, keys, "WIDTH"), _int(p, keys, "HEIGHT", 1)
    n = _int(p, keys, "POINTS", width * height)
    if n != width * height:
        raise DataFormatError(f"{p}: damaged PCD header: POINTS {n}, but WIDTH {width} x HEIGHT {height} = "
                              f"{width * height}")
    mode = (keys.get("DATA") or [""])[0].lower()
    if mode not in PCD_DATA:
        raise DataFormatError(f"{p}: DATA {mode or '(missing)'!r}; expected one of {', '.join(PCD_DATA)}")
    check_allocation(float(n) * (dtype.itemsize + 48), f"{p}: {n} points declared in its header", DataFormatError)
    have = size - start
    need = n * dtype.itemsize
    if mode == "binary":
        if have < need:
            raise DataFormatError(f"{p}: damaged: its header declares {n} points ({need} bytes of binary data), the "
                                  f"file holds {have} bytes after its header (cut short?)")
        return np.fromfile(p, dtype=dtype, count=n, offset=start)
    with open(p, "rb") as fh:
        fh.seek(start)
        data = fh.read()
    if mode == "ascii":
        return _ascii(p, data, dtype, n)
    return _compressed(p, data, dtype, n)


def _ascii(p: Path, data: bytes, dtype: np.dtype, n: int) -> np.ndarray:
    per = sum(int(np.prod(dtype[k].shape)) for k in range(len(dtype.names)))
    # each word of text becomes a bytes object (about 40 bytes) and a float before the records are filled
    check_allocation(float(len(data)) * 8, f"{p}: {len(data)} bytes of ascii points", DataFormatError)
    words = data.split()
    if len(words) < n * per:
        raise DataFormatError(f"{p}: damaged: its header declares {n} points of {per} values, the file holds "
                              f"{len(words)} values after its header (cut short?)")
    try:
        values = np.array(words[: n * per], dtype=np.float64).reshape(n, per)
    except ValueError as exc:
        raise DataFormatError(f"{p}: unreadable ascii points ({exc})") from None
    out = np.zeros(n, dtype=dtype)
    col = 0
    for name in dtype.names:
        c = int(np.prod(dtype[name].shape))
        block = values[:, col: col + c]
        out[name] = block[:, 0] if dtype[name].shape == () else block
        col += c
    return out


def _compressed(p: Path, data: bytes, dtype: np.dtype, n: int) -> np.ndarray:
    from ._lzf import lzf_decompress

    need = n * dtype.itemsize
    if len(data) < 8:
        raise DataFormatError(f"{p}: damaged: a binary_compressed file without its 8-byte block sizes (cut short?)")
    packed, raw = struct.unpack("<II", data[:8])
    if raw != need:
        raise DataFormatError(f"{p}: damaged: its header declares {n} points ({need} bytes), its compressed block "
                              f"says {raw} bytes")
    if len(data) - 8 < packed:
        raise DataFormatError(f"{p}: damaged: its compressed block of {packed} bytes is cut short ({len(data) - 8} "
                              "bytes in the file)")
    out = np.empty(need, dtype=np.uint8)
    got = lzf_decompress(np.frombuffer(data, dtype=np.uint8, count=packed, offset=8), out) if packed else 0
    if got != need:
        why = {-1: "ends inside a run", -2: "decodes to more bytes", -3: "refers before its start"}.get(int(got),
                                                                                                      f"decodes to {got} bytes")
        raise DataFormatError(f"{p}: damaged: its compressed block {why}; expected {need} bytes for {n} points")
    rec = np.empty(n, dtype=dtype)
    offset = 0
    for name in dtype.names:  # field by field, each for every point
        field = dtype[name]
        nbytes = n * field.itemsize
        rec[name] = out[offset: offset + nbytes].view(field.base).reshape((n, *field.shape))
        offset += nbytes
    return rec


def write_pcd(path: str | os.PathLike, points: np.ndarray, data: str = "binary") -> None:
    """Write ``points`` as a PCD v0.7 file (atomically): a structured array of numeric fields (sub-arrays for
    ``COUNT`` > 1), or an (N, 3) array written as float32 ``x y z``. ``data``: one of :data:`PCD_DATA`.

    Raises
    ------
    InputError
        ``data`` is not one of :data:`PCD_DATA`, or ``points`` is neither form.
    """
    from ..io import atomic_path

    if data not in PCD_DATA:
        raise InputError(f"data must be one of {', '.join(PCD_DATA)}, got {data!r}")
    rec = np.asarray(points)
    if rec.dtype.names is None:
        if rec.ndim != 2 or rec.shape[1] != 3:
            raise InputError(f"points must be a structured array or (N, 3), got shape {rec.shape}")
        xyz = rec.astype("<f4")
        rec = np.zeros(len(xyz), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
        rec["x"], rec["y"], rec["z"] = xyz.T
    rec = rec.reshape(-1)
    kinds = {"f": "F", "u": "U", "i": "I"}
    sizes, types, counts = [], [], []
    for name in rec.dtype.names:
        base = rec.dtype[name].base
        if base.kind not in kinds:
            raise InputError(f"points field {name!r} has type {base}; expected a number")
        sizes.append(str(base.itemsize))
        types.append(kinds[base.kind])
        counts.append(str(int(np.prod(rec.dtype[name].shape))))
    little = np.dtype({"names": list(rec.dtype.names),
                       "formats": [(rec.dtype[k].base.newbyteorder("<"), rec.dtype[k].shape) if rec.dtype[k].shape
                                   else rec.dtype[k].base.newbyteorder("<") for k in rec.dtype.names]})
    rec = rec.astype(little)
    n = len(rec)
    head = (f"# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS {' '.join(rec.dtype.names)}\n"
            f"SIZE {' '.join(sizes)}\nTYPE {' '.join(types)}\nCOUNT {' '.join(counts)}\nWIDTH {n}\nHEIGHT 1\n"
            f"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {data}\n").encode("ascii")
    if data == "binary":
        body = rec.tobytes()
    elif data == "ascii":
        rows = []
        for name in rec.dtype.names:
            column = rec[name].reshape(n, -1)
            base = rec.dtype[name].base  # floats with the digits that read back exactly
            fmt = ("%.9g" if base.itemsize == 4 else "%.17g") if base.kind == "f" else "%d"
            rows.append([[fmt % v for v in row] for row in column.tolist()])
        body = "".join(" ".join(v for field in point for v in field) + "\n"
                       for point in zip(*rows, strict=True)).encode("ascii")
    else:
        from ._lzf import compressed_bound, lzf_compress

        raw = np.concatenate([np.ascontiguousarray(rec[name]).view(np.uint8).reshape(-1)
                              for name in rec.dtype.names]) if n else np.zeros(0, np.uint8)
        out = np.empty(compressed_bound(raw.size), dtype=np.uint8)
        packed = int(lzf_compress(raw, out)) if raw.size else 0
        body = struct.pack("<II", packed, raw.size) + out[:packed].tobytes()
    with atomic_path(path, verify=lambda _: None) as tmp:
        Path(tmp).write_bytes(head + body)
