"""Voxels: the voxel-hashed point map (2D or 3D) that keeps one point per voxel, and the two ways of thinning a
cloud by voxels.

Like KISS-ICP's voxel map, :class:`VoxelMap` stores raw points (not voxel centres), at most one per voxel, so
the map keeps the sensor's precision while its size is bounded by the explored volume. The local map used for
registration is a crop around the robot.

Thinning: :func:`voxel_downsample` keeps the centroid of each voxel (the scans before registration; numba);
:func:`first_per_voxel` keeps the first point of each voxel, a raw point (maps to draw and to log).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import InputError, ShapeError

__all__ = ["VoxelMap", "voxel_keys", "first_per_voxel", "voxel_downsample", "voxel_downsample_with"]

_BIAS = 1 << 20  # voxel indices in [-2^20, 2^20) per axis fit in 21 bits; 3 axes fit in an int64


def voxel_keys(points: NDArray[np.floating], voxel: float) -> NDArray[np.int64]:
    """One int64 key per point naming its voxel (square in 2D, cube in 3D) of side ``voxel``."""
    idx = np.floor(points / voxel).astype(np.int64) + _BIAS
    if np.any(idx < 0) or np.any(idx >= 2 * _BIAS):
        raise InputError(f"points beyond +/-{_BIAS * voxel:.0f} m cannot be stored at voxel size {voxel} m")
    key = idx[:, 0]
    for k in range(1, points.shape[1]):
        key = (key << 21) | idx[:, k]
    return key


def first_per_voxel(points: NDArray[np.floating], voxel: float) -> NDArray[np.float64]:
    """Thin points (N, d) to one per voxel of side ``voxel``: the first, in input order; non-finite rows dropped.

    Keeps raw points (unlike voxel centroids), fast (one 1-D key per point); for maps to draw and to log.
    """
    if not voxel > 0:
        raise InputError(f"voxel must be > 0 metres, got {voxel}")
    p = np.asarray(points, dtype=float)
    p = p[np.all(np.isfinite(p), axis=1)]
    if len(p) == 0:
        return p
    return p[np.sort(np.unique(voxel_keys(p, voxel), return_index=True)[1])]


def voxel_downsample(points: NDArray[np.floating], voxel: float, min_range: float = 0.0,
                     max_range: float = np.inf) -> NDArray[np.float64]:
    """Centroid of the points in each occupied voxel (cube or square of side ``voxel``), ordered by voxel.

    Points that are not finite, or whose distance from the origin is outside [min_range, max_range], are dropped
    first. The points kept must lie within +/- 2^20 voxels of the origin (about +/- 100 km at 0.1 m).
    """
    from . import _kernels  # numba: compiled on first use
    pts = np.asarray(points, dtype=float)
    if voxel <= 0 or len(pts) == 0:
        return pts
    pts = np.ascontiguousarray(pts)
    out, bad = _kernels.voxel_centroids(pts, float(voxel), float(min_range), float(max_range))
    _check_voxel_reach(pts, bad, voxel)
    return out


def _check_voxel_reach(pts: NDArray[np.float64], bad: int, voxel: float) -> None:
    """The downsampling's voxel keys hold +/- 2^20 voxels: refuse a kept point (row ``bad``, -1: none) beyond."""
    if bad >= 0:
        raise InputError(f"points beyond +/-{(1 << 20) * voxel:.0f} m cannot be downsampled at {voxel} m voxels "
                         f"(e.g. {pts[bad].tolist()})")


def voxel_downsample_with(points: NDArray[np.floating], values: NDArray[np.floating], voxel: float,
                          min_range: float = 0.0, max_range: float = np.inf
                          ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """:func:`voxel_downsample` of points (N, d) that also averages ``values`` (N,) per voxel (a point's time).

    Returns the centroids (M, d), the same as :func:`voxel_downsample`'s, and each voxel's mean value (M,).
    """
    from . import _kernels  # numba: compiled on first use
    pts = np.asarray(points, dtype=float)
    vals = np.asarray(values, dtype=float).reshape(-1)
    if len(vals) != len(pts):
        raise ShapeError(f"values must have one entry per point ({len(pts)}), got {len(vals)}")
    if voxel <= 0 or len(pts) == 0:
        return pts, vals
    pts = np.ascontiguousarray(pts)
    out, means, bad = _kernels.voxel_centroids_with(pts, np.ascontiguousarray(vals), float(voxel), float(min_range),
                                                    float(max_range))
    _check_voxel_reach(pts, bad, voxel)
    return out, means


def _voxel_reduction(parts: Iterable[tuple[ArrayLike, ArrayLike | None]], dim: int, voxel: float
                     ) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                                NDArray[np.float64]]:
    """The voxels (side ``voxel``) of the finite points (N, dim) of ``parts`` and their normals (or None), taken in
    order a part at a time, in the order of their keys (:func:`voxel_keys`): (keys, first points, first normals,
    point sums in input order, counts). Memory grows with the voxels, not with the points of all the parts."""
    from . import _kernels  # numba: compiled on first use
    cap, m = 0, 0
    table = keys = sums = counts = first = first_normals = None
    for points, normals in parts:
        pts = np.ascontiguousarray(points, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != dim:
            raise ShapeError(f"points must have shape (N, {dim}), got {pts.shape}")
        nrm = np.full(pts.shape, np.nan) if normals is None else np.ascontiguousarray(normals, dtype=float)
        if nrm.shape != pts.shape:
            raise ShapeError(f"normals must have the shape of the points {pts.shape}, got {nrm.shape}")
        if not len(pts):
            continue
        if m + len(pts) > cap:  # room for every point to be a new voxel; the table at most half full
            cap = max(2 * cap, m + len(pts), 1024)
            grown = []
            for a, dtype, width in ((keys, np.int64, 0), (counts, float, 0), (sums, float, dim), (first, float, dim),
                                    (first_normals, float, dim)):
                out = np.empty((cap, width) if width else cap, dtype=dtype)
                if m:
                    out[:m] = a[:m]
                grown.append(out)
            keys, counts, sums, first, first_normals = grown
            table = _kernels.voxel_rehash(keys, m, 1 << int(2 * cap - 1).bit_length())
        m, bad = _kernels.voxel_accumulate(pts, nrm, voxel, _BIAS, table, keys, sums, counts, first, first_normals, m)
        if bad >= 0:
            raise InputError(f"points beyond +/-{_BIAS * voxel:.0f} m cannot be stored at voxel size {voxel} m "
                             f"(e.g. {pts[bad].tolist()})")
    if m == 0:
        return np.empty(0, dtype=np.int64), *(np.empty((0, dim)),) * 3, np.empty(0)
    order = np.argsort(keys[:m])
    return keys[order], first[order], first_normals[order], sums[order], counts[order]


class VoxelMap:
    """A point map with at most one point per voxel.

    Parameters
    ----------
    dim : int
        2 or 3.
    voxel : float
        Voxel size in metres.
    average : bool
        Keep the mean of every point a voxel received instead of the first one: the range noise of one scan
        averages out over the scans that see the same surface (its normal stays the first one's). With the
        default, the first point of a voxel is kept for good.
    """

    def __init__(self, dim: int, voxel: float, *, average: bool = False) -> None:
        if dim not in (2, 3):
            raise ShapeError(f"map dimension must be 2 or 3, got {dim}")
        if not voxel > 0:
            raise InputError(f"map voxel size must be > 0 m, got {voxel}")
        self.dim = dim
        self.voxel = float(voxel)
        self.average = bool(average)
        self._keys = np.empty(0, dtype=np.int64)  # sorted
        self._points = np.empty((0, dim))  # in the order of _keys
        self._normals = np.empty((0, dim))  # NaN where unknown
        self._sums = np.empty((0, dim))  # average: the sum of the points each voxel received
        self._counts = np.empty(0)  # average: how many

    def __len__(self) -> int:
        return len(self._keys)

    @property
    def points(self) -> NDArray[np.float64]:
        """All map points, (N, dim)."""
        return self._points

    @property
    def normals(self) -> NDArray[np.float64]:
        """Unit normals of the map points, (N, dim); NaN rows where none was given."""
        return self._normals

    def add(self, points: ArrayLike, normals: ArrayLike | None = None, *, return_normals: bool = False):
        """Insert world points (and their normals); a point whose voxel already holds one is dropped (or, with
        ``average``, moves the voxel's point to the mean of all it received).

        Returns the points of the voxels that were new, (K, dim) (and their normals, with ``return_normals``).
        """
        from . import _kernels  # numba: compiled on first use
        keys, pts, nrm, sums, counts = _voxel_reduction([(points, normals)], self.dim, self.voxel)
        if len(keys) == 0:
            return (pts, nrm) if return_normals else pts
        if self.average:
            pts = sums / counts[:, None]
        if len(self._keys) == 0:  # a new map: the voxels as they come, already in key order
            self._keys, self._points, self._normals = keys, pts, nrm
            if self.average:
                self._sums, self._counts = sums, counts
            return (pts.copy(), nrm.copy()) if return_normals else pts.copy()
        pos = np.searchsorted(self._keys, keys)
        hit = pos < len(self._keys)
        hit[hit] = self._keys[pos[hit]] == keys[hit]
        new = ~hit
        if self.average and hit.any():
            at = pos[hit]
            self._sums[at] += sums[hit]
            self._counts[at] += counts[hit]
            self._points[at] = self._sums[at] / self._counts[at, None]
        if not new.any():
            return (pts[:0], nrm[:0]) if return_normals else pts[:0]
        pos_new = pos[new]  # where the new keys go in the sorted arrays (inserted there, they stay sorted)

        def inserted(a, rows):
            return _kernels.insert_rows(a.reshape(len(a), -1), pos_new, rows.reshape(len(rows), -1)).reshape(
                (-1, *a.shape[1:]))

        self._keys = inserted(self._keys, keys[new])
        self._points = inserted(self._points, pts[new])
        self._normals = inserted(self._normals, nrm[new])
        if self.average:
            self._sums = inserted(self._sums, sums[new])
            self._counts = inserted(self._counts, counts[new])
        return (pts[new], nrm[new]) if return_normals else pts[new]

    @classmethod
    def from_parts(cls, dim: int, voxel: float, parts: Iterable[tuple[ArrayLike, ArrayLike | None]], *,
                   average: bool = False) -> VoxelMap:
        """A new map of the points (N, dim) and normals (or None) of ``parts``, inserted in order: the map one
        :meth:`add` of all of them concatenated makes, built a part at a time, in memory that grows with the
        voxels rather than the points."""
        vm = cls(dim, voxel, average=average)
        keys, first, first_normals, sums, counts = _voxel_reduction(parts, dim, vm.voxel)
        if len(keys):
            vm._keys, vm._normals = keys, first_normals
            if average:
                vm._sums, vm._counts = sums, counts
                vm._points = sums / counts[:, None]
            else:
                vm._points = first
        return vm

    def crop(self, centre: ArrayLike, radius: float) -> NDArray[np.float64]:
        """Map points within ``radius`` metres of ``centre`` (horizontal distance in 3D)."""
        return self.crop_with_normals(centre, radius)[0]

    def crop_with_normals(self, centre: ArrayLike, radius: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Map points within ``radius`` metres of ``centre`` and their normals."""
        from . import _kernels  # numba: compiled on first use
        c = np.asarray(centre, dtype=float)
        return _kernels.crop_rows(self._points, self._normals, float(c[0]), float(c[1]), float(radius) * radius)
