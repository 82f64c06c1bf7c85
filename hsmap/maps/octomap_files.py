"""OctoMap ``.bt`` and ``.ot`` files read as leaves without trusting them: the header checked, the binary tree walked by
compiled loops that stop at the first inconsistency (a damaged file is refused with its byte offset before
OctoMap's own reader could crash on it), the leaves returned as centres, sizes and occupancy.
"""

from __future__ import annotations

import os
from pathlib import Path

import numba as nb
import numpy as np
from numpy.typing import NDArray

from ..errors import DataFormatError, DatasetError, EmptyInputError

#: The depth of OctoMap's trees (16 levels below the root; leaves at depth 16 have the finest resolution).
_OCTREE_DEPTH = 16

#: The most header lines an OctoMap file may have before its ``data`` line.
_MAX_HEADER_LINES = 64


@nb.njit(cache=True, nogil=True)
def _walk_bt(buf, start, max_depth):  # pragma: no cover - JIT
    """Walk a ``.bt`` node stream (2 bytes per inner node, 2 bits per child: 01 occupied leaf, 10 free leaf,
    11 inner node) from ``start``. Returns (end offset, nodes, error): error 0 ok, 1 truncated, 2 too deep."""
    stack = np.empty(8 * max_depth + 8, np.int64)
    stack[0] = 0
    top = 1
    pos = start
    nodes = 1
    n = buf.shape[0]
    while top > 0:
        top -= 1
        depth = stack[top]
        if pos + 2 > n:
            return pos, nodes, 1
        for b in range(2):
            byte = buf[pos + b]
            for i in range(4):
                code = (byte >> (2 * i)) & 3
                if code != 0:
                    nodes += 1
                if code == 3:
                    if depth + 1 >= max_depth:
                        return pos, nodes, 2
                    stack[top] = depth + 1
                    top += 1
        pos += 2
    return pos, nodes, 0


@nb.njit(cache=True, nogil=True)
def _walk_ot(buf, start, max_depth):  # pragma: no cover - JIT
    """Walk a ``.ot`` node stream (per node a float32 log-odds and a child bit mask, children depth first) from
    ``start``. Returns (end offset, nodes, error): error 0 ok, 1 truncated, 2 too deep."""
    stack = np.empty(8 * max_depth + 8, np.int64)
    stack[0] = 0
    top = 1
    pos = start
    nodes = 0
    n = buf.shape[0]
    while top > 0:
        top -= 1
        depth = stack[top]
        if pos + 5 > n:
            return pos, nodes, 1
        nodes += 1
        mask = buf[pos + 4]
        if mask != 0 and depth >= max_depth:
            return pos, nodes, 2
        for i in range(8):
            if (mask >> i) & 1:
                stack[top] = depth + 1
                top += 1
        pos += 5
    return pos, nodes, 0


def _octomap_header(path: Path, raw: bytes) -> tuple[bool, dict[str, str], int]:
    """Whether the file is binary (``.bt``), its header keys (id, size, res) and the offset of its node data."""
    first, sep, _ = raw[:256].partition(b"\n")
    if first.startswith(b"# Octomap OcTree binary file"):
        binary = True
    elif first.startswith(b"# Octomap OcTree file"):
        binary = False
    else:
        raise DataFormatError(f"{path}: not an OctoMap file (expected a first line '# Octomap OcTree binary file' "
                              f"or '# Octomap OcTree file', got {first[:40]!r})")
    pos = len(first) + 1
    keys: dict[str, str] = {}
    for _ in range(_MAX_HEADER_LINES):
        end = raw.find(b"\n", pos)
        if end < 0:
            raise DataFormatError(f"{path}: OctoMap header ends before its 'data' line (truncated file?)")
        line = raw[pos:end].decode("ascii", errors="replace").strip()
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        if line == "data":
            break
        key, _, value = line.partition(" ")
        keys[key] = value.strip()
    else:
        raise DataFormatError(f"{path}: no 'data' line in the first {_MAX_HEADER_LINES} header lines")
    for key in ("id", "size", "res"):
        if key not in keys:
            raise DataFormatError(f"{path}: OctoMap header lacks '{key}' (expected id, size, res before 'data')")
    if keys["id"] != "OcTree":
        raise DataFormatError(f"{path}: OctoMap tree type '{keys['id']}' is not supported (expected OcTree)")
    try:
        size = int(keys["size"])
        res = float(keys["res"])
    except ValueError:
        raise DataFormatError(f"{path}: OctoMap header 'size {keys['size']}' / 'res {keys['res']}' are not "
                              "numbers") from None
    if size < 0 or not (np.isfinite(res) and res > 0):
        raise DataFormatError(f"{path}: OctoMap header needs size >= 0 and res > 0, got size {size}, res {res}")
    return binary, keys, pos


def _check_octomap_stream(path: Path) -> tuple[bool, int, float]:
    """Check an OctoMap file's header and node stream before a reader sees it: (binary, nodes, resolution)."""
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise DatasetError(f"{path}: cannot read it ({exc.strerror})") from None
    if not raw:
        raise DataFormatError(f"{path}: empty file (expected an OctoMap .bt/.ot tree)")
    binary, keys, start = _octomap_header(path, raw)
    size, res = int(keys["size"]), float(keys["res"])
    if size == 0:
        raise EmptyInputError(f"{path}: the OctoMap tree is empty (size 0)")
    buf = np.frombuffer(raw, dtype=np.uint8)
    walk = _walk_bt if binary else _walk_ot
    end, nodes, err = walk(buf, start, _OCTREE_DEPTH)
    kind = ".bt" if binary else ".ot"
    if err == 1:
        raise DataFormatError(f"{path}: truncated OctoMap {kind} file (node data ends at byte {len(raw)} inside "
                              f"node {nodes} of {size})")
    if err == 2:
        raise DataFormatError(f"{path}: damaged OctoMap {kind} file (nodes below depth {_OCTREE_DEPTH} at byte "
                              f"{end})")
    if nodes != size:
        raise DataFormatError(f"{path}: damaged OctoMap {kind} file (header says {size} nodes, data holds {nodes})")
    if end != len(raw):
        raise DataFormatError(f"{path}: damaged OctoMap {kind} file ({len(raw) - end} bytes after the tree)")
    return binary, size, res


def _octomap_leaves(path: Path) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.bool_], float]:
    """Leaf centres (N, 3), depths (N,), occupied flags (N,) and the finest resolution of an OctoMap file."""
    binary, size, res = _check_octomap_stream(path)
    try:
        import octomap
    except ImportError:  # pragma: no cover - a dependency
        from ..errors import DependencyError

        raise DependencyError(f"{path}: reading OctoMap files needs octomap-python (pip install "
                              "octomap-python)") from None
    name = os.fsencode(path)
    try:
        tree = octomap.OcTree(name) if binary else octomap.OcTree.read(name)
    except Exception as exc:  # noqa: BLE001 - the binding raises plain exceptions
        raise DataFormatError(f"{path}: OctoMap could not read it ({exc})") from None
    if tree is None or tree.size() != size:
        raise DataFormatError(f"{path}: OctoMap read {0 if tree is None else tree.size()} nodes, the header says "
                              f"{size}")
    thres = tree.getOccupancyThresLog()
    rows = [(it.getCoordinate(), it.getDepth(), it.getValue()) for it in tree.begin_leafs()]
    if not rows:
        raise EmptyInputError(f"{path}: the OctoMap tree has no leaves")
    centres = np.array([r[0] for r in rows], dtype=float)
    depth = np.array([r[1] for r in rows], dtype=np.int64)
    value = np.array([r[2] for r in rows], dtype=float)
    nan = int(np.isnan(value).sum())
    if nan:  # neither occupied nor free: a NaN compares false with the threshold and would read as free
        raise DataFormatError(f"{path}: {nan} of its {len(value)} OctoMap leaves have a NaN log-odds occupancy; "
                              "expected numbers")
    occupied = value >= thres
    return centres, depth, occupied, float(tree.getResolution())
