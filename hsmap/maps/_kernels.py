"""Numba kernels of the voxel maps: voxel centroids, insertion through a hash table, row cropping and insertion,
the start of a 3D DDA ray walk."""

from __future__ import annotations

import numba as nb
import numpy as np

__all__ = ["voxel_centroids", "voxel_centroids_with", "voxel_accumulate", "voxel_rehash", "crop_rows", "insert_rows",
           "dda_start"]


@nb.njit(cache=True, nogil=True, inline="always")
def dda_start(ix, iy, iz, ox, oy, oz, dx, dy, dz):  # pragma: no cover - JIT
    """The start of a 3D DDA (Amanatides-Woo) walk from (ox, oy, oz), in voxel units inside voxel (ix, iy, iz),
    along (dx, dy, dz): the step of each axis (+-1), the ray parameter per voxel along each axis and the ray
    parameter at the first voxel boundary of each axis (inf along an axis the ray does not move on)."""
    big = np.inf
    sx = 1 if dx > 0 else -1
    sy = 1 if dy > 0 else -1
    sz = 1 if dz > 0 else -1
    tdx = abs(1.0 / dx) if dx != 0.0 else big
    tdy = abs(1.0 / dy) if dy != 0.0 else big
    tdz = abs(1.0 / dz) if dz != 0.0 else big
    tmx = ((ix + (1 if dx > 0 else 0)) - ox) / dx if dx != 0.0 else big
    tmy = ((iy + (1 if dy > 0 else 0)) - oy) / dy if dy != 0.0 else big
    tmz = ((iz + (1 if dz > 0 else 0)) - oz) / dz if dz != 0.0 else big
    return sx, sy, sz, tdx, tdy, tdz, tmx, tmy, tmz

@nb.njit(cache=True, nogil=True)
def _number_voxels(keys, skip, valid):  # pragma: no cover - JIT
    """Number the distinct voxel keys in the order they first appear, through a hash table (one pass): (voxel
    number of each key, -1 where it is ``skip``; the keys of the numbers; the row where each first appears; how
    many). ``valid``: how many keys are not ``skip`` (sizes the table)."""
    n = keys.shape[0]
    bits = 1
    while (1 << bits) < 2 * valid:
        bits += 1
    size = 1 << bits
    mask = np.uint64(size - 1)
    table = np.full(size, -1, dtype=np.int64)  # slot -> voxel number
    voxel_of = np.empty(n, dtype=np.int64)
    ukeys = np.empty(max(valid, 1), dtype=np.int64)
    first = np.empty(max(valid, 1), dtype=np.int64)
    m = 0
    for i in range(n):
        k = keys[i]
        if k == skip:
            voxel_of[i] = -1
            continue
        h = (np.uint64(k) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(64 - bits)
        while True:
            v = table[h]
            if v < 0:
                table[h] = m
                ukeys[m] = k
                first[m] = i
                voxel_of[i] = m
                m += 1
                break
            if ukeys[v] == k:
                voxel_of[i] = v
                break
            h = (h + np.uint64(1)) & mask
    return voxel_of, ukeys, first, m


@nb.njit(cache=True, nogil=True)
def _range_voxel_keys(pts, voxel, rmin, rmax):  # pragma: no cover - JIT
    """Each point's voxel key (indices floor(p / voxel) + 2^20, 21 bits each), the int64 maximum for a point
    not finite or whose distance from the origin is outside [rmin, rmax]; that maximum; the count of the others;
    the first of those whose indices do not fit 21 bits (-1: none; the keys are then incomplete)."""
    n, d = pts.shape
    keys = np.empty(n, dtype=np.int64)
    big = np.iinfo(np.int64).max
    valid = 0
    for i in range(n):
        r2 = 0.0
        finite = True
        for j in range(d):
            r2 += pts[i, j] * pts[i, j]
            finite &= np.isfinite(pts[i, j])
        if not (finite and r2 >= rmin * rmin and r2 <= rmax * rmax):  # also false for NaN
            keys[i] = big
            continue
        k = np.int64(0)
        for j in range(d):
            ix = np.int64(np.floor(pts[i, j] / voxel)) + (1 << 20)
            if ix < 0 or ix >= (1 << 21):
                return keys, big, valid, i
            k = (k << 21) | ix
        keys[i] = k
        valid += 1
    return keys, big, valid, -1


@nb.njit(cache=True, nogil=True)
def _voxel_sums(pts, voxel, rmin, rmax):  # pragma: no cover - JIT
    """Each kept point's voxel number (-1: skipped), the voxels' order by key, and per voxel the sum of its points
    (in input order) and their count; and the first kept point beyond the keys' reach (-1: none; then no voxels)."""
    n, d = pts.shape
    keys, big, valid, bad = _range_voxel_keys(pts, voxel, rmin, rmax)
    if bad >= 0:
        return np.full(n, -1, dtype=np.int64), np.empty(0, dtype=np.int64), np.zeros((0, d)), np.zeros(0), bad
    voxel_of, ukeys, _, m = _number_voxels(keys, big, valid)
    sums = np.zeros((m, d))
    counts = np.zeros(m)
    for i in range(n):
        v = voxel_of[i]
        if v < 0:
            continue
        for j in range(d):
            sums[v, j] += pts[i, j]
        counts[v] += 1.0
    return voxel_of, np.argsort(ukeys[:m]), sums, counts, bad


@nb.njit(cache=True, nogil=True)
def _centroids(order, sums, counts):  # pragma: no cover - JIT
    """The voxels' mean points (M, d), in ``order``."""
    m, d = sums.shape
    out = np.empty((m, d))
    for r in range(m):
        v = order[r]
        for j in range(d):
            out[r, j] = sums[v, j] / counts[v]
    return out


@nb.njit(cache=True, nogil=True)
def voxel_centroids(pts, voxel, rmin=0.0, rmax=np.inf):  # pragma: no cover - JIT
    """Centroid of the points in each occupied voxel (side `voxel`), in the order of their voxel keys.

    Points that are not finite, or whose distance from the origin is outside [rmin, rmax], are skipped. The
    voxels are found with a hash table (one pass over the points, which are summed in input order) and only the
    occupied voxels' keys are sorted: a 131,072-point cloud has some 10-30 thousand voxels at 0.1-0.15 m.
    Returns the centroids and the first kept point beyond the keys' 2^20 voxels from the origin (-1: none; else
    no centroids).
    """
    _, order, sums, counts, bad = _voxel_sums(pts, voxel, rmin, rmax)
    return _centroids(order, sums, counts), bad


@nb.njit(cache=True, nogil=True)
def voxel_accumulate(pts, nrm, voxel, bias, table, ukeys, sums, counts, fpts, fnrm, m):  # pragma: no cover - JIT
    """Add the finite points (N, d) and their normals to a running voxel reduction: ``m`` voxels so far, numbered in
    the order they first appear, each with its key (:func:`hsmap.maps.mapping.voxel_keys`: the indices
    floor(p / voxel) + bias, 21 bits each), the sum of its points in input order, their count, and its first point
    and normal; ``table`` (a power of two, slot -> voxel number) hashes the keys. The arrays must hold m + N voxels
    and ``table`` twice as many. Returns (the new m, -1), or (m, row) for the first point beyond the keys' 21 bits."""
    n, d = pts.shape
    size = table.shape[0]
    bits = 0
    while (1 << bits) < size:
        bits += 1
    mask = np.uint64(size - 1)
    for i in range(n):
        finite = True
        for j in range(d):
            if not np.isfinite(pts[i, j]):
                finite = False
        if not finite:
            continue
        k = np.int64(0)
        for j in range(d):
            ix = np.int64(np.floor(pts[i, j] / voxel)) + bias
            if ix < 0 or ix >= 2 * bias:
                return m, i
            k = (k << 21) | ix
        h = (np.uint64(k) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(64 - bits)
        while True:
            v = table[h]
            if v < 0:
                v = m
                table[h] = v
                ukeys[v] = k
                counts[v] = 0.0
                for j in range(d):
                    sums[v, j] = 0.0
                    fpts[v, j] = pts[i, j]
                    fnrm[v, j] = nrm[i, j]
                m += 1
                break
            if ukeys[v] == k:
                break
            h = (h + np.uint64(1)) & mask
        for j in range(d):
            sums[v, j] += pts[i, j]
        counts[v] += 1.0
    return m, -1


@nb.njit(cache=True, nogil=True)
def voxel_rehash(ukeys, m, size):  # pragma: no cover - JIT
    """A hash table of ``size`` slots (a power of two) for the first ``m`` voxel keys, as :func:`voxel_accumulate`
    probes it."""
    bits = 0
    while (1 << bits) < size:
        bits += 1
    mask = np.uint64(size - 1)
    table = np.full(size, -1, dtype=np.int64)
    for v in range(m):
        h = (np.uint64(ukeys[v]) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(64 - bits)
        while table[h] >= 0:
            h = (h + np.uint64(1)) & mask
        table[h] = v
    return table


@nb.njit(cache=True, nogil=True)
def crop_rows(points, normals, cx, cy, r2):  # pragma: no cover - JIT
    """The rows of points (N, d) and normals (N, d) whose first two coordinates lie within squared distance ``r2``
    of (cx, cy), in order: one pass to count, one to copy."""
    n, d = points.shape
    keep = np.empty(n, dtype=np.bool_)
    m = 0
    for i in range(n):
        dx = points[i, 0] - cx
        dy = points[i, 1] - cy
        keep[i] = dx * dx + dy * dy <= r2
        m += keep[i]
    out_p = np.empty((m, d))
    out_n = np.empty((m, d))
    j = 0
    for i in range(n):
        if keep[i]:
            for k in range(d):
                out_p[j, k] = points[i, k]
                out_n[j, k] = normals[i, k]
            j += 1
    return out_p, out_n


@nb.njit(cache=True, nogil=True)
def insert_rows(a, pos, rows):  # pragma: no cover - JIT
    """``np.insert(a, pos, rows, axis=0)`` for a (M, d) and rows (K, d) with ``pos`` (K,) ascending: row k goes
    before a's row pos[k]. One pass, copying the runs of ``a`` between the insertions."""
    m, d = a.shape
    k = pos.shape[0]
    out = np.empty((m + k, d), dtype=a.dtype)
    src = 0
    for r in range(k):
        stop = pos[r]
        dst = src + r
        for i in range(src, stop):
            for j in range(d):
                out[dst, j] = a[i, j]
            dst += 1
        for j in range(d):
            out[dst, j] = rows[r, j]
        src = stop
    dst = src + k
    for i in range(src, m):
        for j in range(d):
            out[dst, j] = a[i, j]
        dst += 1
    return out


@nb.njit(cache=True, nogil=True)
def voxel_centroids_with(pts, vals, voxel, rmin=0.0, rmax=np.inf):  # pragma: no cover - JIT
    """:func:`voxel_centroids` of points (N, d), and the mean of ``vals`` (N,) over each voxel (a point's time,
    say): (centroids (M, d), means (M,), the first point beyond reach or -1)."""
    voxel_of, order, sums, counts, bad = _voxel_sums(pts, voxel, rmin, rmax)
    vsums = np.zeros(len(counts))
    for i in range(len(voxel_of)):
        if voxel_of[i] >= 0:
            vsums[voxel_of[i]] += vals[i]
    return _centroids(order, sums, counts), vsums[order] / counts[order], bad
