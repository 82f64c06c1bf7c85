"""3D occupancy maps made from sweeps at known poses, the floor under the sensor's path, and OctoMap ``.bt`` files.

:func:`sweep_bounds` and :func:`carve_sweeps` turn posed sweeps into a :class:`hsmap.maps.maps3d.Map3D`: each point's
voxel is occupied and the voxels on its ray from the sensor are free (a 3D digital differential analyser,
Amanatides and Woo); a voxel hit by any sweep stays occupied. Rays longer than ``max_range`` are cut there and
only carve free space. The dense grid is bounded (:data:`hsmap.maps.maps3d.MAX_CELLS` and the memory available).

:func:`floor_under_path` finds the floor below each sensor pose: the horizontal surface of occupied voxels seen
most often around the pose within a range of depths below it, so that a building with several floor levels has
the floor each pose stands over, and a ceiling is never taken. :func:`level_map` shifts every voxel column by
the floor of the nearest pose, so that heights in the levelled map are heights above the local floor and the
bands of :mod:`hsmap.maps.maps3d` (``floor=0``) follow the floor from level to level.

:func:`write_octomap` encodes a map as OctoMap's binary tree (``.bt``: free and occupied leaves, uniform
octants merged), which octomap-python reads back and writes out, so that octovis and RViz open it.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterable
from pathlib import Path

import numba as nb
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import EmptyInputError, InputError, OutputError, ShapeError
from ..limits import check_allocation
from ._kernels import dda_start
from .maps3d import FREE, MAX_CELLS, OCCUPIED, UNKNOWN, Map3D

__all__ = [
    "sweep_bounds",
    "carve_sweeps",
    "floor_under_path",
    "floor_field",
    "level_map",
    "write_octomap",
]

#: OctoMap's tree depth: keys are 16-bit, the root covers 2**16 voxels per axis centred on the world origin.
_DEPTH = 16
_KEY_CENTRE = 1 << (_DEPTH - 1)


# --------------------------------------------------------------------------------------------------------------
# Carving
# --------------------------------------------------------------------------------------------------------------


def _clip(points: NDArray[np.float64], sensor: NDArray[np.float64], max_range: float):
    """Points cut to ``max_range`` from the sensor, and which of them are returns within it."""
    d = points - sensor
    r = np.sqrt((d * d).sum(axis=1))
    hit = r <= max_range
    scale = np.where(hit, 1.0, max_range / np.maximum(r, 1e-12))
    return sensor + d * scale[:, None], hit


def _check_sweep(points: ArrayLike, sensor: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    s = np.asarray(sensor, dtype=float).reshape(-1)
    if s.shape != (3,) or not np.isfinite(s).all():
        raise ShapeError(f"a sweep's sensor position must be 3 finite numbers, got {sensor!r}")
    return p[np.isfinite(p).all(axis=1)], s


def sweep_bounds(sweeps: Iterable[tuple[ArrayLike, ArrayLike]], max_range: float
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The box (low corner, high corner), world metres, holding every sensor position and every point of the
    sweeps cut to ``max_range`` from its sensor.

    Parameters
    ----------
    sweeps : iterable of (ndarray of shape (N, 3), ndarray of shape (3,))
        World points and the sensor's world position, per sweep.
    max_range : float
        Metres.
    """
    if not (np.isfinite(max_range) and max_range > 0):
        raise InputError(f"max_range must be a positive number of metres, got {max_range}")
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for points, sensor in sweeps:
        p, s = _check_sweep(points, sensor)
        c, _ = _clip(p, s, max_range)
        both = np.vstack([c, s[None]])
        lo, hi = np.minimum(lo, both.min(axis=0)), np.maximum(hi, both.max(axis=0))
    if not np.isfinite(lo).all():
        raise EmptyInputError("no sweep to bound")
    return lo, hi


@nb.njit(cache=True, nogil=True)
def _carve_rays(state, origin, res, sensor, ends):  # pragma: no cover - JIT
    """Mark UNKNOWN voxels FREE along each ray from ``sensor`` to ``ends[i]`` (the end's voxel excluded): a 3D
    DDA, voxel by voxel."""
    nx, ny, nz = state.shape
    ox = (sensor[0] - origin[0]) / res
    oy = (sensor[1] - origin[1]) / res
    oz = (sensor[2] - origin[2]) / res
    for i in range(ends.shape[0]):
        px = (ends[i, 0] - origin[0]) / res
        py = (ends[i, 1] - origin[1]) / res
        pz = (ends[i, 2] - origin[2]) / res
        dx, dy, dz = px - ox, py - oy, pz - oz
        ix, iy, iz = int(np.floor(ox)), int(np.floor(oy)), int(np.floor(oz))
        ex, ey, ez = int(np.floor(px)), int(np.floor(py)), int(np.floor(pz))
        sx, sy, sz, tdx, tdy, tdz, tmx, tmy, tmz = dda_start(ix, iy, iz, ox, oy, oz, dx, dy, dz)
        steps = abs(ex - ix) + abs(ey - iy) + abs(ez - iz)
        for _ in range(steps + 1):
            if ix == ex and iy == ey and iz == ez:
                break
            if 0 <= ix < nx and 0 <= iy < ny and 0 <= iz < nz and state[ix, iy, iz] == 0:
                state[ix, iy, iz] = 1
            if tmx <= tmy and tmx <= tmz:
                ix += sx
                tmx += tdx
            elif tmy <= tmz:
                iy += sy
                tmy += tdy
            else:
                iz += sz
                tmz += tdz


def _grid_for(lower: ArrayLike, upper: ArrayLike, resolution: float, max_cells: int
              ) -> tuple[NDArray[np.float64], tuple[int, int, int]]:
    lo, hi = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    if not (np.isfinite(resolution) and resolution > 0):
        raise InputError(f"resolution must be a positive number of metres, got {resolution}")
    if lo.shape != (3,) or hi.shape != (3,) or not (np.isfinite(lo).all() and np.isfinite(hi).all()) or \
            np.any(hi < lo):
        raise InputError(f"the map's box must be two finite corners low <= high, got {lower!r}, {upper!r}")
    origin = np.floor(lo / resolution) * resolution
    shape = np.floor((hi - origin) / resolution).astype(np.int64) + 1
    cells = float(np.prod(shape.astype(float)))
    what = (f"a {shape[0]} x {shape[1]} x {shape[2]} voxel map at {resolution:g} m "
            f"({hi[0] - lo[0]:.1f} x {hi[1] - lo[1]:.1f} x {hi[2] - lo[2]:.1f} m)")
    if cells > max_cells:
        raise InputError(f"{what} exceeds the limit of {max_cells} cells (a coarser voxel or a shorter max_range)")
    check_allocation(cells, what)
    return origin, (int(shape[0]), int(shape[1]), int(shape[2]))


def carve_sweeps(sweeps: Iterable[tuple[ArrayLike, ArrayLike]], lower: ArrayLike, upper: ArrayLike, *,
                 resolution: float, max_range: float, max_cells: int = MAX_CELLS,
                 source: str = "sweeps") -> Map3D:
    """A voxel map of posed sweeps: each return's voxel occupied, the voxels on its ray free.

    Parameters
    ----------
    sweeps : iterable of (ndarray of shape (N, 3), ndarray of shape (3,))
        World points and the sensor's world position, per sweep (read once, one at a time).
    lower, upper : array_like of shape (3,)
        The map's box, world metres (:func:`sweep_bounds` of the same sweeps).
    resolution : float
        Voxel edge, metres.
    max_range : float
        Rays are cut at this many metres from the sensor; a point beyond it carves free space only.
    max_cells : int
        The largest grid accepted.
    source : str
        What the map is made of (:attr:`Map3D.source`).

    Returns
    -------
    Map3D
        Occupied where any sweep had a return, free where a ray passed and none had, unknown elsewhere.
    """
    origin, shape = _grid_for(lower, upper, resolution, max_cells)
    state = np.zeros(shape, dtype=np.uint8)
    top = np.asarray(shape) - 1
    for points, sensor in sweeps:
        p, s = _check_sweep(points, sensor)
        ends, hit = _clip(p, s, max_range)
        idx = np.floor((ends[hit] - origin) / resolution).astype(np.int64)
        inside = np.all((idx >= 0) & (idx <= top), axis=1)
        idx = idx[inside]
        state[idx[:, 0], idx[:, 1], idx[:, 2]] = OCCUPIED
        _carve_rays(state, origin, float(resolution), s, np.ascontiguousarray(ends))
    return Map3D(state, origin, float(resolution), source)


# --------------------------------------------------------------------------------------------------------------
# The floor under a path
# --------------------------------------------------------------------------------------------------------------


def floor_under_path(m: Map3D, positions: ArrayLike, *, radius: float, depth: tuple[float, float]
                     ) -> NDArray[np.float64]:
    """The floor's height below each sensor position.

    Around each position (columns within ``radius`` metres) and between ``depth[0]`` and ``depth[1]`` metres
    below it, the voxel layer with the most upward-facing occupied surfaces (an occupied voxel under one that is
    not) is the floor there; its centre is the floor's height. Positions where no surface is found take the
    floor of the nearest position along the path that has one.

    Parameters
    ----------
    m : Map3D
    positions : array_like of shape (P, 3)
        World sensor positions along the path.
    radius : float
        Metres around each position.
    depth : (float, float)
        Metres below the sensor the floor may lie, nearest first.

    Returns
    -------
    ndarray of shape (P,)

    Raises
    ------
    EmptyInputError
        No position has a surface below it in that range.
    """
    pos = np.asarray(positions, dtype=float).reshape(-1, 3)
    lo_d, hi_d = (float(v) for v in depth)
    if not (np.isfinite(radius) and radius > 0 and np.isfinite(lo_d) and np.isfinite(hi_d) and 0 <= lo_d < hi_d):
        raise InputError(f"floor search: radius must be > 0 and depth two metres 0 <= near < far, got {radius}, "
                         f"{depth}")
    res, o = m.resolution, m.origin
    r = int(np.ceil(radius / res))
    off = np.arange(-r, r + 1)
    disc = (off[:, None] ** 2 + off[None, :] ** 2) * res * res <= radius * radius
    floors = np.full(len(pos), np.nan)
    nx, ny, nz = m.shape
    for k, p in enumerate(pos):
        c = np.floor((p - o) / res).astype(np.int64)
        k0 = int(np.floor((p[2] - hi_d - o[2]) / res))
        k1 = int(np.floor((p[2] - lo_d - o[2]) / res))
        i0, i1, j0, j1 = c[0] - r, c[0] + r + 1, c[1] - r, c[1] + r + 1
        a0, a1, b0, b1 = max(i0, 0), min(i1, nx), max(j0, 0), min(j1, ny)
        z0, z1 = max(k0, 0), min(k1, nz - 1) + 1
        if a0 >= a1 or b0 >= b1 or z0 >= z1:
            continue
        d = disc[a0 - i0:a1 - i0, b0 - j0:b1 - j0]
        occ = m.state[a0:a1, b0:b1, z0:z1 + 1][d] == OCCUPIED  # (columns, layers + the one above)
        above = occ[:, 1:] if occ.shape[1] > z1 - z0 else np.pad(occ[:, 1:], ((0, 0), (0, 1)))
        counts = (occ[:, :z1 - z0] & ~above).sum(axis=0)
        if counts.max(initial=0) > 0:
            floors[k] = o[2] + (z0 + int(np.argmax(counts)) + 0.5) * res
    found = np.flatnonzero(np.isfinite(floors))
    if len(found) == 0:
        raise EmptyInputError(f"{m.source}: no floor found {lo_d:g}-{hi_d:g} m below any of the {len(pos)} sensor "
                              f"positions (within {radius:g} m around them)")
    nearest = found[np.abs(np.arange(len(pos))[:, None] - found[None, :]).argmin(axis=1)]
    return floors[nearest]


def floor_field(m: Map3D, positions: ArrayLike, floors: ArrayLike, *, reach: float = 0.0) -> NDArray[np.float64]:
    """The floor's height under every voxel column: that of the position nearest to it in (x, y), or, with
    ``reach`` > 0, the column's own upward-facing occupied surface nearest to that height within ``reach`` metres
    above or below it (a step or a ramp between floor levels, which the nearest position's floor misses).

    Returns
    -------
    ndarray of shape (nx, ny)
    """
    from scipy.spatial import cKDTree

    pos = np.asarray(positions, dtype=float).reshape(-1, 3)
    f = np.asarray(floors, dtype=float).reshape(-1)
    if len(pos) != len(f) or len(pos) == 0:
        raise ShapeError(f"positions and floors must be as many and not none, got {len(pos)} and {len(f)}")
    if not (np.isfinite(reach) and reach >= 0):
        raise InputError(f"reach must be a number of metres >= 0, got {reach}")
    nx, ny, _ = m.shape
    xs = m.origin[0] + (np.arange(nx) + 0.5) * m.resolution
    ys = m.origin[1] + (np.arange(ny) + 0.5) * m.resolution
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    _, near = cKDTree(pos[:, :2]).query(np.column_stack([gx.ravel(), gy.ravel()]))
    field = f[near].reshape(nx, ny)
    return _nearest_surface(m, field, reach) if reach > 0 else field


def _nearest_surface(m: Map3D, field: NDArray[np.float64], reach: float) -> NDArray[np.float64]:
    """Per column, the centre of the upward-facing occupied voxel nearest to ``field`` within ``reach`` metres
    (ties: the lower); ``field`` where the column has none."""
    nz = m.shape[2]
    res = m.resolution
    at = np.floor((field - m.origin[2]) / res).astype(np.int64)
    best = np.full(field.shape, np.iinfo(np.int64).max)
    out = field.copy()
    r = int(np.floor(reach / res))
    for off in sorted(range(-r, r + 1), key=lambda k: (abs(k), k)):
        k = at + off
        ok = (k >= 0) & (k < nz)
        here = np.take_along_axis(m.state, np.clip(k, 0, nz - 1)[:, :, None], axis=2)[:, :, 0] == OCCUPIED
        up = np.take_along_axis(m.state, np.clip(k + 1, 0, nz - 1)[:, :, None], axis=2)[:, :, 0] == OCCUPIED
        surface = ok & here & ((k + 1 >= nz) | ~up) & (best == np.iinfo(np.int64).max)
        best[surface] = abs(off)
        out[surface] = m.origin[2] + (k[surface] + 0.5) * res
    return out


def level_map(m: Map3D, floor: NDArray[np.float64], *, below: float = 0.5) -> Map3D:
    """The map with every column shifted by its floor: height z of the result is z above the column's floor.

    Parameters
    ----------
    m : Map3D
    floor : ndarray of shape (nx, ny)
        The floor's world height per column (:func:`floor_field`).
    below : float
        Metres below the floor the levelled map keeps.

    Returns
    -------
    Map3D
        Of the same (nx, ny), each column's floor voxel centred on z = 0; the layers from ``below`` under it to
        the top of the map over its lowest floor; voxels that fall outside ``m`` are unknown.
    """
    nx, ny, nz = m.shape
    fl = np.asarray(floor, dtype=float)
    if fl.shape != (nx, ny) or not np.isfinite(fl).all():
        raise ShapeError(f"floor must be finite heights of shape {(nx, ny)}, got {fl.shape}")
    res = m.resolution
    kb = int(np.ceil(below / res))
    at = np.floor((fl - m.origin[2]) / res).astype(np.int64)  # each column's floor voxel: layer kb of the result
    nzr = kb + max(nz - int(at.min()), 1)
    out = np.zeros((nx, ny, nzr), dtype=np.uint8)
    for k in range(nzr):
        src = at + (k - kb)
        ok = (src >= 0) & (src < nz)
        layer = np.take_along_axis(m.state, np.clip(src, 0, nz - 1)[:, :, None], axis=2)[:, :, 0]
        out[:, :, k] = np.where(ok, layer, UNKNOWN)
    origin = np.array([m.origin[0], m.origin[1], -(kb + 0.5) * res])
    return Map3D(out, origin, res, m.source)


# --------------------------------------------------------------------------------------------------------------
# OctoMap's binary tree
# --------------------------------------------------------------------------------------------------------------


def _parent_codes(codes: NDArray[np.uint8], start: NDArray[np.int64]) -> tuple[NDArray[np.uint8], NDArray[np.int64]]:
    """One tree level up: 0 unknown, 1 free leaf, 2 occupied leaf, 3 inner node (children that differ)."""
    pad_lo = start % 2
    end = start + np.asarray(codes.shape)
    pad_hi = end % 2
    c = np.pad(codes, [(int(a), int(b)) for a, b in zip(pad_lo, pad_hi, strict=True)])
    n = np.asarray(c.shape) // 2
    blocks = c.reshape(n[0], 2, n[1], 2, n[2], 2).transpose(0, 2, 4, 1, 3, 5).reshape(*n, 8)
    first = blocks[..., 0]
    same = (blocks == first[..., None]).all(axis=-1)
    parent = np.where(same & (first != 3), first, 3).astype(np.uint8)
    return parent, (start - pad_lo) // 2


@nb.njit(cache=True, nogil=True)
def _serialise(levels, starts, out):  # pragma: no cover - JIT
    """OctoMap's binary node stream, depth first from the root: per inner node 2 bytes, 2 bits per child
    (bit 2i: free leaf, bit 2i + 1: occupied leaf, both: inner). Returns (bytes written, nodes)."""
    top = len(levels) - 1
    stack = np.empty((8 * (top + 2), 4), np.int64)
    stack[0, 0] = top
    stack[0, 1] = starts[top, 0]
    stack[0, 2] = starts[top, 1]
    stack[0, 3] = starts[top, 2]
    n = 1
    pos = 0
    nodes = 1
    while n > 0:
        n -= 1
        lev, a, b, c = stack[n, 0], stack[n, 1], stack[n, 2], stack[n, 3]
        child = levels[lev - 1]
        s = starts[lev - 1]
        b0 = 0
        b1 = 0
        inner = np.zeros(8, np.int64)
        for i in range(8):
            x = 2 * a + (i & 1) - s[0]
            y = 2 * b + ((i >> 1) & 1) - s[1]
            z = 2 * c + ((i >> 2) & 1) - s[2]
            code = 0
            if 0 <= x < child.shape[0] and 0 <= y < child.shape[1] and 0 <= z < child.shape[2]:
                code = child[x, y, z]
            if code != 0:
                nodes += 1
            if i < 4:
                b0 |= code << (2 * i)
            else:
                b1 |= code << (2 * (i - 4))
            inner[i] = code == 3
        out[pos] = b0
        out[pos + 1] = b1
        pos += 2
        for i in range(7, -1, -1):
            if inner[i]:
                stack[n, 0] = lev - 1
                stack[n, 1] = 2 * a + (i & 1)
                stack[n, 2] = 2 * b + ((i >> 1) & 1)
                stack[n, 3] = 2 * c + ((i >> 2) & 1)
                n += 1
    return pos, nodes


def _octomap_bytes(m: Map3D) -> bytes:
    """The map as the bytes of an OctoMap ``.bt`` file (keys: voxel index + the origin's key)."""
    key0 = np.rint(m.origin / m.resolution).astype(np.int64) + _KEY_CENTRE
    if not np.allclose(key0 - _KEY_CENTRE, m.origin / m.resolution, atol=1e-6):
        raise InputError(f"{m.source}: the map's origin {m.origin.tolist()} is not on its {m.resolution:g} m grid")
    if np.any(key0 < 0) or np.any(key0 + np.asarray(m.shape) > (1 << _DEPTH)):
        raise InputError(f"{m.source}: the map reaches beyond OctoMap's {(1 << _DEPTH)} voxels per axis")
    codes = np.zeros(m.shape, dtype=np.uint8)
    codes[m.state == FREE] = 1
    codes[m.state == OCCUPIED] = 2
    levels, starts = [codes], [key0]
    for _ in range(_DEPTH):
        c, s = _parent_codes(levels[-1], starts[-1])
        levels.append(c)
        starts.append(s)
    if levels[-1][0, 0, 0] != 3:
        raise EmptyInputError(f"{m.source}: the map has no observed voxel to write")
    inner = sum(int((lev == 3).sum()) for lev in levels)
    out = np.zeros(2 * inner, dtype=np.uint8)
    typed = nb.typed.List(levels)
    used, nodes = _serialise(typed, np.asarray(starts, dtype=np.int64), out)
    header = ("# Octomap OcTree binary file\n# (feel free to add / change comments, but leave the first line as it "
              f"is!)\n#\nid OcTree\nsize {nodes}\nres {m.resolution!r}\ndata\n").encode("ascii")
    return header + out[:used].tobytes()


def write_octomap(m: Map3D, path: str | os.PathLike) -> int:
    """Write the map as an OctoMap ``.bt`` file (octomap-python reads the encoded tree and writes the file).

    Occupied voxels become occupied leaves, free voxels free leaves, unknown voxels nothing; eight equal leaves
    are one leaf of their parent. Returns the tree's node count.

    Raises
    ------
    EmptyInputError
        The map has no occupied or free voxel.
    OutputError
        octomap-python could not read the encoded tree back, or could not write the file.
    """
    import octomap

    from ..io import atomic_path

    path = Path(path)
    data = _octomap_bytes(m)
    expected = int(data.split(b"\nsize ", 1)[1].split(b"\n", 1)[0])
    fd, name = tempfile.mkstemp(suffix=".bt", prefix=f".{path.stem}.encoded-", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        tree = octomap.OcTree(os.fsencode(name))
        nodes = int(tree.size())
        if nodes != expected:
            raise OutputError(f"{path}: OctoMap read {nodes} nodes of the {expected} encoded")
        with atomic_path(path) as tmp:
            if not tree.writeBinary(os.fsencode(tmp)):
                raise OutputError(f"{path}: octomap-python could not write it")
    finally:
        Path(name).unlink(missing_ok=True)
    return nodes
