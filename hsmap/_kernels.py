"""Numba kernels for the hot loop of Harmony-ICP: transform a point set by each of B poses, look the points up
in a distance field (bilinear in 2D, trilinear in 3D), truncate and count inliers, without temporaries.

Fields here are volumes indexed along the world axes, ``field[ix, iy(, iz)]``, padded by one cell of the
truncation value; ``origin`` is the world position of the corner of the first unpadded cell.
"""

from __future__ import annotations

import numba as nb
import numpy as np

__all__ = ["field_score_2d", "field_score_3d"]

_OPTS = dict(fastmath=True, cache=True, nogil=True)


@nb.njit(**_OPTS)
def field_score_2d(poses, pts, field, origin, inv_res, tau, out_mean, out_inl):  # pragma: no cover - JIT
    nbatch = poses.shape[0]
    npts = pts.shape[0]
    nx = field.shape[0]
    ny = field.shape[1]
    lim = tau * (1.0 - 1e-6)
    for b in range(nbatch):
        c = np.cos(poses[b, 2])
        s = np.sin(poses[b, 2])
        tx = poses[b, 0]
        ty = poses[b, 1]
        acc = 0.0
        inl = 0
        for i in range(npts):
            x = c * pts[i, 0] - s * pts[i, 1] + tx
            y = s * pts[i, 0] + c * pts[i, 1] + ty
            u = (x - origin[0]) * inv_res + 0.5
            v = (y - origin[1]) * inv_res + 0.5
            iu = int(np.floor(u))
            iv = int(np.floor(v))
            if iu < 0 or iv < 0 or iu > nx - 2 or iv > ny - 2:
                d = tau
            else:
                fu = u - iu
                fv = v - iv
                d = ((1 - fu) * ((1 - fv) * field[iu, iv] + fv * field[iu, iv + 1])
                     + fu * ((1 - fv) * field[iu + 1, iv] + fv * field[iu + 1, iv + 1]))
            acc += d
            if d < lim:
                inl += 1
        out_mean[b] = acc / npts
        out_inl[b] = inl / npts


@nb.njit(**_OPTS)
def field_score_3d(poses, pts, field, origin, inv_res, tau, out_mean, out_inl):  # pragma: no cover - JIT
    nbatch = poses.shape[0]
    npts = pts.shape[0]
    nx = field.shape[0]
    ny = field.shape[1]
    nz = field.shape[2]
    lim = tau * (1.0 - 1e-6)
    for b in range(nbatch):
        cr = np.cos(poses[b, 3])
        sr = np.sin(poses[b, 3])
        cp = np.cos(poses[b, 4])
        sp = np.sin(poses[b, 4])
        cy = np.cos(poses[b, 5])
        sy = np.sin(poses[b, 5])
        r00 = cy * cp
        r01 = cy * sp * sr - sy * cr
        r02 = cy * sp * cr + sy * sr
        r10 = sy * cp
        r11 = sy * sp * sr + cy * cr
        r12 = sy * sp * cr - cy * sr
        r20 = -sp
        r21 = cp * sr
        r22 = cp * cr
        acc = 0.0
        inl = 0
        for i in range(npts):
            px = pts[i, 0]
            py = pts[i, 1]
            pz = pts[i, 2]
            x = r00 * px + r01 * py + r02 * pz + poses[b, 0]
            y = r10 * px + r11 * py + r12 * pz + poses[b, 1]
            z = r20 * px + r21 * py + r22 * pz + poses[b, 2]
            u = (x - origin[0]) * inv_res + 0.5
            v = (y - origin[1]) * inv_res + 0.5
            w = (z - origin[2]) * inv_res + 0.5
            iu = int(np.floor(u))
            iv = int(np.floor(v))
            iw = int(np.floor(w))
            if iu < 0 or iv < 0 or iw < 0 or iu > nx - 2 or iv > ny - 2 or iw > nz - 2:
                d = tau
            else:
                fu = u - iu
                fv = v - iv
                fw = w - iw
                c00 = (1 - fw) * field[iu, iv, iw] + fw * field[iu, iv, iw + 1]
                c01 = (1 - fw) * field[iu, iv + 1, iw] + fw * field[iu, iv + 1, iw + 1]
                c10 = (1 - fw) * field[iu + 1, iv, iw] + fw * field[iu + 1, iv, iw + 1]
                c11 = (1 - fw) * field[iu + 1, iv + 1, iw] + fw * field[iu + 1, iv + 1, iw + 1]
                d = (1 - fu) * ((1 - fv) * c00 + fv * c01) + fu * ((1 - fv) * c10 + fv * c11)
            acc += d
            if d < lim:
                inl += 1
        out_mean[b] = acc / npts
        out_inl[b] = inl / npts


@nb.njit(**_OPTS)
def splat_field_2d(pts, origin, res, field, radius):  # pragma: no cover - JIT
    """field[ix, iy] = min(field, distance from the node's centre to each point within `radius` cells)."""
    nx = field.shape[0]
    ny = field.shape[1]
    for i in range(pts.shape[0]):
        u = (pts[i, 0] - origin[0]) / res - 0.5
        v = (pts[i, 1] - origin[1]) / res - 0.5
        cu = int(np.floor(u + 0.5))
        cv = int(np.floor(v + 0.5))
        for a in range(max(cu - radius, 0), min(cu + radius + 1, nx)):
            dx = (a - u) * res
            for b in range(max(cv - radius, 0), min(cv + radius + 1, ny)):
                dy = (b - v) * res
                d = np.sqrt(dx * dx + dy * dy)
                if d < field[a, b]:
                    field[a, b] = d


@nb.njit(**_OPTS)
def splat_field_3d(pts, origin, res, field, radius):  # pragma: no cover - JIT
    """field[ix, iy, iz] = min(field, distance from the node's centre to each point within `radius` cells)."""
    nx = field.shape[0]
    ny = field.shape[1]
    nz = field.shape[2]
    for i in range(pts.shape[0]):
        u = (pts[i, 0] - origin[0]) / res - 0.5
        v = (pts[i, 1] - origin[1]) / res - 0.5
        w = (pts[i, 2] - origin[2]) / res - 0.5
        cu = int(np.floor(u + 0.5))
        cv = int(np.floor(v + 0.5))
        cw = int(np.floor(w + 0.5))
        for a in range(max(cu - radius, 0), min(cu + radius + 1, nx)):
            dx = (a - u) * res
            for b in range(max(cv - radius, 0), min(cv + radius + 1, ny)):
                dy = (b - v) * res
                dxy = dx * dx + dy * dy
                for c in range(max(cw - radius, 0), min(cw + radius + 1, nz)):
                    dz = (c - w) * res
                    d = np.sqrt(dxy + dz * dz)
                    if d < field[a, b, c]:
                        field[a, b, c] = d


@nb.njit(cache=True, nogil=True)
def voxel_centroids(pts, voxel, rmin=0.0, rmax=np.inf):  # pragma: no cover - JIT
    """Centroid of the points in each occupied voxel (side `voxel`), in the order of their voxel keys.

    Points that are not finite, or whose distance from the origin is outside [rmin, rmax], are skipped.
    """
    n, d = pts.shape
    keys = np.empty(n, dtype=np.int64)
    big = np.iinfo(np.int64).max
    for i in range(n):
        r2 = 0.0
        for j in range(d):
            r2 += pts[i, j] * pts[i, j]
        if not (r2 >= rmin * rmin and r2 <= rmax * rmax):  # also false for NaN
            keys[i] = big
            continue
        k = np.int64(0)
        for j in range(d):
            k = (k << 21) | (np.int64(np.floor(pts[i, j] / voxel)) + (1 << 20))
        keys[i] = k
    order = np.argsort(keys)
    while n > 0 and keys[order[n - 1]] == big:
        n -= 1
    out = np.empty((n, d))
    m = -1
    count = 0
    last = np.int64(-1)
    for ii in range(n):
        i = order[ii]
        if ii == 0 or keys[i] != last:
            if m >= 0:
                for j in range(d):
                    out[m, j] /= count
            m += 1
            count = 0
            last = keys[i]
            for j in range(d):
                out[m, j] = 0.0
        for j in range(d):
            out[m, j] += pts[i, j]
        count += 1
    if m >= 0:
        for j in range(d):
            out[m, j] /= count
    return out[: m + 1]
