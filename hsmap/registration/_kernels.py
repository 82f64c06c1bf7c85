"""Numba kernels of Harmony-ICP: a point set transformed by each of B poses and looked up in a distance field
(bilinear in 2D, trilinear in 3D), truncated, its inliers counted, without temporaries; the fields' splatting,
the refinements on a field and point-to-plane, the neighbour grid.

Fields here are volumes indexed along the world axes, ``field[ix, iy(, iz)]``, padded by one cell of the
truncation value; ``origin`` is the world position of the corner of the first unpadded cell.
"""

from __future__ import annotations

import numba as nb
import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

__all__ = ["field_score", "hs_chunk_field", "hs_search_field", "splat_field_2d", "splat_field_3d", "PARALLEL_MIN_WORK"]

_OPTS = dict(fastmath=True, cache=True, nogil=True)

#: A round's batch is scored in parallel (numba's threads) when it holds at least this many point look-ups
#: (harmonies x points); smaller batches (tracking: 16 x 150) are scored on the calling thread: a parallel region
#: costs more than their ~0.1 ms of work, many times more when the cores are busy with other processes.
#: Which path runs depends on the problem's size only, never on the number of threads.
PARALLEL_MIN_WORK = 32768


#: _score_pose's fastmath flags: all but 'reassoc'. It is inlined into the kernels that call it, and with 'reassoc'
#: LLVM may vectorise its sum over the points (another order of additions) in one compilation and not in
#: another: a run that compiled the kernels could give other last bits than a run that loaded them from numba's
#: cache. Without it the sum keeps its order.
SCORE_FASTMATH = {"nnan", "ninf", "nsz", "arcp", "contract", "afn"}


@nb.njit(cache=True, nogil=True, fastmath=SCORE_FASTMATH)
def _score_pose(pose, pts, flat, shape, origin, inv_res, tau):  # pragma: no cover - JIT
    """Mean truncated distance and inlier ratio of `pts` moved by one pose, looked up in a padded flat field."""
    npts, d = pts.shape
    lim = tau * (1.0 - 1e-6)
    acc = 0.0
    inl = 0
    if d == 2:
        c = np.cos(pose[2])
        s = np.sin(pose[2])
        s1 = shape[1]
        for i in range(npts):
            x = c * pts[i, 0] - s * pts[i, 1] + pose[0]
            y = s * pts[i, 0] + c * pts[i, 1] + pose[1]
            u = (x - origin[0]) * inv_res + 0.5
            v = (y - origin[1]) * inv_res + 0.5
            iu = int(np.floor(u))
            iv = int(np.floor(v))
            if iu < 0 or iv < 0 or iu > shape[0] - 2 or iv > shape[1] - 2:
                dd = tau
            else:
                fu = u - iu
                fv = v - iv
                k = iu * s1 + iv
                dd = ((1 - fu) * ((1 - fv) * flat[k] + fv * flat[k + 1])
                      + fu * ((1 - fv) * flat[k + s1] + fv * flat[k + s1 + 1]))
            acc += dd
            if dd < lim:
                inl += 1
    else:
        cr = np.cos(pose[3])
        sr = np.sin(pose[3])
        cp = np.cos(pose[4])
        sp = np.sin(pose[4])
        cy = np.cos(pose[5])
        sy = np.sin(pose[5])
        r00 = cy * cp
        r01 = cy * sp * sr - sy * cr
        r02 = cy * sp * cr + sy * sr
        r10 = sy * cp
        r11 = sy * sp * sr + cy * cr
        r12 = sy * sp * cr - cy * sr
        r20 = -sp
        r21 = cp * sr
        r22 = cp * cr
        s2 = shape[2]
        s1 = shape[1] * s2
        for i in range(npts):
            px = pts[i, 0]
            py = pts[i, 1]
            pz = pts[i, 2]
            x = r00 * px + r01 * py + r02 * pz + pose[0]
            y = r10 * px + r11 * py + r12 * pz + pose[1]
            z = r20 * px + r21 * py + r22 * pz + pose[2]
            u = (x - origin[0]) * inv_res + 0.5
            v = (y - origin[1]) * inv_res + 0.5
            w = (z - origin[2]) * inv_res + 0.5
            iu = int(np.floor(u))
            iv = int(np.floor(v))
            iw = int(np.floor(w))
            if iu < 0 or iv < 0 or iw < 0 or iu > shape[0] - 2 or iv > shape[1] - 2 or iw > shape[2] - 2:
                dd = tau
            else:
                fu = u - iu
                fv = v - iv
                fw = w - iw
                k = iu * s1 + iv * s2 + iw
                c00 = (1 - fw) * flat[k] + fw * flat[k + 1]
                c01 = (1 - fw) * flat[k + s2] + fw * flat[k + s2 + 1]
                c10 = (1 - fw) * flat[k + s1] + fw * flat[k + s1 + 1]
                c11 = (1 - fw) * flat[k + s1 + s2] + fw * flat[k + s1 + s2 + 1]
                dd = (1 - fu) * ((1 - fv) * c00 + fv * c01) + fu * ((1 - fv) * c10 + fv * c11)
            acc += dd
            if dd < lim:
                inl += 1
    return acc / npts, inl / npts


@nb.njit(cache=True, nogil=True, parallel=True)
def field_score(poses, pts, flat, shape, origin, inv_res, tau, out_mean, out_inl):  # pragma: no cover - JIT
    """Mean truncated distance and inlier ratio for each of B poses (2D or 3D, by the points' width).

    The poses are shared between numba's threads, each pose scored wholly by one thread: the result does not
    depend on the number of threads.
    """
    if poses.shape[0] * pts.shape[0] < PARALLEL_MIN_WORK:
        for b in range(poses.shape[0]):
            out_mean[b], out_inl[b] = _score_pose(poses[b], pts, flat, shape, origin, inv_res, tau)
        return
    for b in nb.prange(poses.shape[0]):
        m, r = _score_pose(poses[b], pts, flat, shape, origin, inv_res, tau)
        out_mean[b] = m
        out_inl[b] = r


@nb.njit(cache=True, nogil=True, parallel=True)
def _score_batch_field(new, f_new, pts, flat, shape, origin, inv_res, tau, weight):  # pragma: no cover - JIT
    """f_new[b] = the two-term fitness of harmony b, the batch shared between numba's threads (one harmony each:
    the same sums, in the same order, whatever the number of threads)."""
    for b in nb.prange(new.shape[0]):
        m, r = _score_pose(new[b], pts, flat, shape, origin, inv_res, tau)
        f = m / tau + weight * (1.0 - r)
        f_new[b] = f if np.isfinite(f) else np.inf


@nb.njit(cache=True, nogil=True)
def _score_new(new, f_new, pts, flat, shape, origin, inv_res, tau, weight):  # pragma: no cover - JIT
    """f_new[b] = the two-term fitness of harmony b (non-finite: inf); a batch large enough is scored in parallel
    (:func:`_score_batch_field`), which depends on the problem's size only."""
    if new.shape[0] * pts.shape[0] >= PARALLEL_MIN_WORK:
        _score_batch_field(new, f_new, pts, flat, shape, origin, inv_res, tau, weight)
        return
    for b in range(new.shape[0]):
        m, r = _score_pose(new[b], pts, flat, shape, origin, inv_res, tau)
        f = m / tau + weight * (1.0 - r)
        f_new[b] = f if np.isfinite(f) else np.inf


@nb.njit(cache=True, nogil=True)
def hs_chunk_field(memory, fun, pick, consider, adjust_u, step, rand, par, bw, lo, hi, span, history, state,
                   global_best, patience, convergence_tol, min_improvement, spread, anchor,
                   pts, flat, shape, origin, inv_res, tau, weight):  # pragma: no cover - JIT
    """hsmap.registration.harmony._run_chunk with the two-term field fitness compiled (same arithmetic, same order); each
    round's batch is scored in parallel (:func:`_score_batch_field`)."""
    hms, dim = memory.shape
    nchunk, batch, _ = pick.shape
    new = np.empty((batch, dim))
    f_new = np.empty(batch)
    all_x = np.empty((hms + batch, dim))
    all_f = np.empty(hms + batch)
    stale = state[1]
    state[0] = 0
    for k in range(nchunk):
        for b in range(batch):
            for j in range(dim):
                if consider[k, b, j]:
                    v = memory[pick[k, b, j], j]
                    if adjust_u[k, b, j] < par[k]:
                        if global_best:
                            v = memory[0, j]
                        else:
                            v = v + step[k, b, j] * (bw[k] * span[j])
                else:
                    v = rand[k, b, j]
                new[b, j] = min(max(v, lo[j]), hi[j])
        _score_new(new, f_new, pts, flat, shape, origin, inv_res, tau, weight)
        all_x[:hms] = memory
        all_x[hms:] = new
        all_f[:hms] = fun
        all_f[hms:] = f_new
        keep = np.argsort(all_f, kind="mergesort")[:hms]
        for i in range(hms):
            memory[i] = all_x[keep[i]]
            fun[i] = all_f[keep[i]]
        improved = history[k] - fun[0] > min_improvement
        if improved and spread[0] >= 0:
            improved = False
            for j in range(dim):
                if abs(memory[0, j] - anchor[j]) > spread[j]:
                    improved = True
            if improved:
                for j in range(dim):
                    anchor[j] = memory[0, j]
        history[k + 1] = fun[0]
        stale = 0 if improved else stale + 1
        state[0] = k + 1
        state[1] = stale
        if convergence_tol >= 0 and np.isfinite(fun[hms - 1]) and fun[hms - 1] - fun[0] <= convergence_tol:
            state[2] = 1
            return
        if stale >= patience:
            state[2] = 2
            return


@nb.njit(cache=True, nogil=True)
def hs_search_field(gen, memory, fun, draw_rounds, batch, hmcr, par, bw, lo, hi, span, history, state,
                    global_best, patience, max_iterations, convergence_tol, min_improvement, spread, anchor,
                    pts, flat, shape, origin, inv_res, tau, weight):  # pragma: no cover - JIT
    """A whole Harmony Search on the two-term field fitness in one call: the first ``memory`` scored into ``fun``
    and sorted (stably), then hsmap.registration.harmony._improvise's rounds, the random numbers of
    ``draw_rounds`` rounds at a time drawn from the numpy Generator ``gen`` as numpy draws them (numba's Generator:
    the same stream), run by :func:`hs_chunk_field`. ``par`` and ``bw``: every round's rates; returns the rounds run."""
    hms, dim = memory.shape
    _score_new(memory, fun, pts, flat, shape, origin, inv_res, tau, weight)
    order = np.argsort(fun, kind="mergesort")
    memory[:] = memory[order]
    fun[:] = fun[order]
    anchor[:] = memory[0]
    history[0] = fun[0]
    it = 0
    while it < max_iterations and state[2] == 0:
        c = min(draw_rounds, max_iterations - it)
        pick = gen.integers(0, hms, size=(c, batch, dim))
        consider = gen.random((c, batch, dim)) < hmcr
        adjust_u = gen.random((c, batch, dim))
        step = gen.uniform(-1.0, 1.0, (c, batch, dim))
        rand = lo + gen.random((c, batch, dim)) * span
        hs_chunk_field(memory, fun, pick, consider, adjust_u, step, rand, par[it:it + c], bw[it:it + c], lo, hi,
                       span, history[it:], state, global_best, patience, convergence_tol, min_improvement, spread,
                       anchor, pts, flat, shape, origin, inv_res, tau, weight)
        it += state[0]
    return it


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
                s = dx * dx + dy * dy
                f = np.float64(field[a, b])
                if s >= f * f:  # f * f is exact (f is a float32): sqrt(s) >= f, so no update
                    continue
                d = np.sqrt(s)
                if d < f:
                    field[a, b] = d


@nb.njit(**_OPTS)
def splat_field_3d(pts, origin, res, field, radius, tau, a_lo=0, a_hi=-1):  # pragma: no cover - JIT
    """field[ix, iy, iz] = min(field, distance from the node's centre to each point within `radius` cells), for
    the nodes with a_lo <= ix < a_hi (a_hi -1: all): slabs of the field can be splatted by different threads,
    each node by one, with the same result (a minimum does not depend on the order).

    ``tau`` (finite) is the field's truncation, which no node exceeds: the nodes of the cube farther than it from
    the point (with a margin) are not visited, since none of them could be lowered; the ball is a sixth of the
    cube of 9 cells a side that a 0.3 m truncation at 0.1 m cells needs."""
    nx = field.shape[0] if a_hi < 0 else a_hi
    ny = field.shape[1]
    nz = field.shape[2]
    t2 = tau * tau * (1.0 + 1e-6)
    for i in range(pts.shape[0]):
        u = (pts[i, 0] - origin[0]) / res - 0.5
        v = (pts[i, 1] - origin[1]) / res - 0.5
        w = (pts[i, 2] - origin[2]) / res - 0.5
        cu = int(np.floor(u + 0.5))
        cv = int(np.floor(v + 0.5))
        cw = int(np.floor(w + 0.5))
        for a in range(max(cu - radius, a_lo), min(cu + radius + 1, nx)):
            dx = (a - u) * res
            for b in range(max(cv - radius, 0), min(cv + radius + 1, ny)):
                dy = (b - v) * res
                dxy = dx * dx + dy * dy
                if dxy > t2:
                    continue
                hz = np.sqrt(t2 - dxy) / res  # |c - w| beyond this (in cells): farther than tau
                c0 = max(max(cw - radius, 0), int(np.floor(w - hz)) - 1)
                c1 = min(min(cw + radius + 1, nz), int(np.floor(w + hz)) + 2)
                for c in range(c0, c1):
                    dz = (c - w) * res
                    s = dxy + dz * dz
                    f = np.float64(field[a, b, c])
                    if s >= f * f:  # f * f is exact (f is a float32): sqrt(s) >= f, so no update
                        continue
                    d = np.sqrt(s)
                    if d < f:
                        field[a, b, c] = d


@nb.njit(cache=True, nogil=True)
def _plane_equations(p, dist, idx, q, n, kernel):  # pragma: no cover - JIT
    """:func:`point_to_plane_normal_equations` of the correspondences (p_i, q_idx[i], n_idx[i]) of the points with
    a finite ``dist``, and how many there were."""
    m, d = p.shape
    k = 3 if d == 2 else 6
    A = np.zeros((k, k))
    g = np.zeros(k)
    J = np.empty(k)
    count = 0
    for i in range(m):
        if not np.isfinite(dist[i]):
            continue
        c = idx[i]
        count += 1
        r = 0.0
        for j in range(d):
            r += n[c, j] * (p[i, j] - q[c, j])
        if d == 2:
            J[0] = n[c, 0]
            J[1] = n[c, 1]
            J[2] = n[c, 1] * p[i, 0] - n[c, 0] * p[i, 1]
        else:
            J[0] = n[c, 0]
            J[1] = n[c, 1]
            J[2] = n[c, 2]
            J[3] = p[i, 1] * n[c, 2] - p[i, 2] * n[c, 1]
            J[4] = p[i, 2] * n[c, 0] - p[i, 0] * n[c, 2]
            J[5] = p[i, 0] * n[c, 1] - p[i, 1] * n[c, 0]
        w = 1.0
        if kernel > 0:
            t = kernel * kernel + r * r
            w = kernel * kernel * kernel * kernel / (t * t)
        for a in range(k):
            g[a] += w * J[a] * r
            for b in range(a, k):
                A[a, b] += w * J[a] * J[b]
    for a in range(k):
        for b in range(a):
            A[a, b] = A[b, a]
    return A, g, count


@nb.njit(cache=True, nogil=True)
def point_to_plane_normal_equations(p, q, n, kernel):  # pragma: no cover - JIT
    """J^T W J and J^T W r of the point-to-plane (point-to-line in 2D) residuals r_i = n_i . (p_i - q_i).

    2D: unknowns (tx, ty, theta), J_i = [n_x, n_y, n_y p_x - n_x p_y]; 3D: (t, omega), J_i = [n, p x n].
    W: Geman-McClure weights w_i = k^2 / (k^2 + r_i^2)^2 (times k^2, so w -> 1 for small r) with scale
    k = ``kernel``; ``kernel <= 0`` gives plain least squares.
    """
    m = p.shape[0]
    A, g, _ = _plane_equations(p, np.zeros(m), np.arange(m), q, n, kernel)
    return A, g


@nb.njit(cache=True, nogil=True)
def point_to_plane_step(p, dist, idx, q, n, kernel):  # pragma: no cover - JIT
    """One Gauss-Newton step of point-to-plane ICP on the correspondences (p_i, q_idx[i], n_idx[i]) of the points
    with a finite ``dist``: the update transform (d+1, d+1), the step's largest entry and how many correspondences
    there were (fewer than 2 d: no step, the identity).

    Solves the normal equations of :func:`point_to_plane_normal_equations` (a 1e-9 ridge keeps them regular) and
    turns the increment (translation, rotation) into a rigid transform (Rodrigues' formula in 3D).
    """
    A, g, count = _plane_equations(p, dist, idx, q, n, kernel)
    return _plane_step(A, g, count, p.shape[1])


@nb.njit(cache=True, nogil=True)
def _plane_step(A, g, count, d):  # pragma: no cover - JIT
    """:func:`point_to_plane_step` from the upper triangle and diagonal of the normal equations (``A``, ``g``; A is
    completed in place) of ``count`` correspondences."""
    k = A.shape[0]
    for a in range(k):
        for b in range(a):
            A[a, b] = A[b, a]
    dT = np.eye(d + 1)
    if count < 2 * d:
        return dT, 0.0, count
    for a in range(k):
        A[a, a] += 1e-9
    delta = -np.linalg.solve(A, g)
    if d == 2:
        c, s = np.cos(delta[2]), np.sin(delta[2])
        dT[0, 0], dT[0, 1], dT[1, 0], dT[1, 1] = c, -s, s, c
    else:
        wx, wy, wz = delta[3], delta[4], delta[5]
        theta = np.sqrt(wx * wx + wy * wy + wz * wz)
        if theta > 1e-12:
            K = np.array([[0.0, -wz, wy], [wz, 0.0, -wx], [-wy, wx, 0.0]]) / theta
            R = np.eye(3) + np.sin(theta) * K + (1.0 - np.cos(theta)) * (K @ K)
            dT[:3, :3] = R
    for a in range(d):
        dT[a, d] = delta[a]
    return dT, np.abs(delta).max(), count


@nb.njit(cache=True, nogil=True)
def splat_nearest_2d(pts, normals, origin, res, field, near, radius):  # pragma: no cover - JIT
    """:func:`splat_field_2d` that also records, per node, the nearest point and its normal: near[a, b] =
    (x, y, nx, ny) of the point whose distance set field[a, b]."""
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
                s = dx * dx + dy * dy
                f = np.float64(field[a, b])
                if s >= f * f:  # f * f is exact (f is a float32): sqrt(s) >= f, so no update
                    continue
                d = np.sqrt(s)
                if d < f:
                    field[a, b] = d
                    near[a, b, 0] = pts[i, 0]
                    near[a, b, 1] = pts[i, 1]
                    near[a, b, 2] = normals[i, 0]
                    near[a, b, 3] = normals[i, 1]


@nb.njit(cache=True, nogil=True)
def refine_on_field_2d(src, T, near, origin, res, schedule, per_stage, tol, kernel):  # pragma: no cover - JIT
    """Trimmed point-to-line ICP in 2D with correspondences read from a nearest-point field (see
    :func:`splat_nearest_2d`): each source point takes the map point nearest to the node it falls in.

    ``schedule`` holds the trimming distances (halving), ``per_stage`` iterations at most each, a stage ending
    when the step's largest entry is below ``tol``. Returns the refined 3x3 transform.
    """
    nx = near.shape[0]
    ny = near.shape[1]
    m = src.shape[0]
    T = T.copy()
    A = np.zeros((3, 3))
    g = np.zeros(3)
    for s in range(schedule.shape[0]):
        dist = schedule[s]
        d2max = dist * dist
        for _ in range(per_stage):
            A[:, :] = 0.0
            g[:] = 0.0
            c, sn = T[0, 0], T[1, 0]
            count = 0
            for i in range(m):
                px = c * src[i, 0] - sn * src[i, 1] + T[0, 2]
                py = sn * src[i, 0] + c * src[i, 1] + T[1, 2]
                a = int(np.floor((px - origin[0]) / res))
                b = int(np.floor((py - origin[1]) / res))
                if a < 0 or b < 0 or a >= nx or b >= ny:
                    continue
                qx = near[a, b, 0]
                if np.isnan(qx):
                    continue
                qy = near[a, b, 1]
                ex = px - qx
                ey = py - qy
                if ex * ex + ey * ey > d2max:
                    continue
                n0 = near[a, b, 2]
                n1 = near[a, b, 3]
                r = n0 * ex + n1 * ey
                j0, j1, j2 = n0, n1, n1 * px - n0 * py
                w = 1.0
                if kernel > 0:
                    t = kernel * kernel + r * r
                    w = kernel * kernel * kernel * kernel / (t * t)
                g[0] += w * j0 * r
                g[1] += w * j1 * r
                g[2] += w * j2 * r
                A[0, 0] += w * j0 * j0
                A[0, 1] += w * j0 * j1
                A[0, 2] += w * j0 * j2
                A[1, 1] += w * j1 * j1
                A[1, 2] += w * j1 * j2
                A[2, 2] += w * j2 * j2
                count += 1
            if count < 4:
                break
            A[1, 0] = A[0, 1]
            A[2, 0] = A[0, 2]
            A[2, 1] = A[1, 2]
            for k in range(3):
                A[k, k] += 1e-9
            delta = -np.linalg.solve(A, g)
            cd, sd = np.cos(delta[2]), np.sin(delta[2])
            dT = np.eye(3)
            dT[0, 0], dT[0, 1], dT[1, 0], dT[1, 1] = cd, -sd, sd, cd
            dT[0, 2], dT[1, 2] = delta[0], delta[1]
            T = dT @ T
            if np.abs(delta).max() < tol:
                break
    return T


@nb.njit(cache=True, nogil=True)
def splat_nearest_index_3d(pts, origin, res, field, index, radius, offset):  # pragma: no cover - JIT
    """:func:`splat_field_3d` that also records, per node, which point set it: index[a, b, c] = offset + i of
    the point ``pts[i]`` nearest to the node's centre (within the band; -1 where none)."""
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
                        index[a, b, c] = offset + i


@nb.njit(cache=True, nogil=True)
def refine_on_field_3d(src, T, index, npts, nnrm, origin, res, schedule, per_stage, tol,
                       kernel):  # pragma: no cover - JIT
    """Trimmed point-to-plane ICP in 3D with correspondences read from a nearest-point index field (see
    :func:`splat_nearest_index_3d`): each source point takes the map point nearest to the node it falls in.

    ``schedule`` holds the trimming distances (halving), ``per_stage`` iterations at most each, a stage ending
    when the step's largest entry is below ``tol``. The steps are :func:`point_to_plane_step`'s (Geman-McClure
    weights of scale ``kernel``, a 1e-9 ridge, Rodrigues' formula). Returns the refined 4x4 transform.
    """
    nx = index.shape[0]
    ny = index.shape[1]
    nz = index.shape[2]
    m = src.shape[0]
    T = T.copy()
    A = np.zeros((6, 6))
    g = np.zeros(6)
    J = np.empty(6)
    for s in range(schedule.shape[0]):
        dist = schedule[s]
        d2max = dist * dist
        for _ in range(per_stage):
            A[:, :] = 0.0
            g[:] = 0.0
            count = 0
            for i in range(m):
                sx, sy, sz = src[i, 0], src[i, 1], src[i, 2]
                px = T[0, 0] * sx + T[0, 1] * sy + T[0, 2] * sz + T[0, 3]
                py = T[1, 0] * sx + T[1, 1] * sy + T[1, 2] * sz + T[1, 3]
                pz = T[2, 0] * sx + T[2, 1] * sy + T[2, 2] * sz + T[2, 3]
                a = int(np.floor((px - origin[0]) / res))
                b = int(np.floor((py - origin[1]) / res))
                c = int(np.floor((pz - origin[2]) / res))
                if a < 0 or b < 0 or c < 0 or a >= nx or b >= ny or c >= nz:
                    continue
                k = index[a, b, c]
                if k < 0:
                    continue
                ex = px - npts[k, 0]
                ey = py - npts[k, 1]
                ez = pz - npts[k, 2]
                if ex * ex + ey * ey + ez * ez > d2max:
                    continue
                n0, n1, n2 = nnrm[k, 0], nnrm[k, 1], nnrm[k, 2]
                r = n0 * ex + n1 * ey + n2 * ez
                J[0] = n0
                J[1] = n1
                J[2] = n2
                J[3] = py * n2 - pz * n1
                J[4] = pz * n0 - px * n2
                J[5] = px * n1 - py * n0
                w = 1.0
                if kernel > 0:
                    t = kernel * kernel + r * r
                    w = kernel * kernel * kernel * kernel / (t * t)
                for u in range(6):
                    g[u] += w * J[u] * r
                    for v in range(u, 6):
                        A[u, v] += w * J[u] * J[v]
                count += 1
            if count < 6:
                break
            for u in range(6):
                for v in range(u):
                    A[u, v] = A[v, u]
                A[u, u] += 1e-9
            delta = -np.linalg.solve(A, g)
            dT = np.eye(4)
            wx, wy, wz = delta[3], delta[4], delta[5]
            theta = np.sqrt(wx * wx + wy * wy + wz * wz)
            if theta > 1e-12:
                K = np.array([[0.0, -wz, wy], [wz, 0.0, -wx], [-wy, wx, 0.0]]) / theta
                R = np.eye(3) + np.sin(theta) * K + (1.0 - np.cos(theta)) * (K @ K)
                dT[:3, :3] = R
            dT[0, 3], dT[1, 3], dT[2, 3] = delta[0], delta[1], delta[2]
            T = dT @ T
            if np.abs(delta).max() < tol:
                break
    return T


# ---------------------------------------------------------------------------------------- nearest neighbours
# Exact nearest neighbours within a distance bound on a dense voxel grid (hsmap.registration.neighbours). No fastmath: the
# squared distances are summed in the order scipy's cKDTree sums them, so the distances are the same bit for bit;
# of points at exactly the same distance, the lowest row is the answer.


@nb.njit(cache=True, nogil=True)
def grid_build(points, origin, inv_cell, dims):  # pragma: no cover - JIT
    """Counting sort of points (N, d) by cell (row-major over ``dims``, the last axis fastest).

    Returns (sorted points, their original rows, start): the points of cell c are rows start[c]:start[c + 1] of
    the sorted points, so the cells along the last axis are one run of rows.
    """
    n, d = points.shape
    ncell = 1
    for k in range(d):
        ncell *= dims[k]
    lin = np.empty(n, np.int64)
    start = np.zeros(ncell + 1, np.int32)  # rows fit: hsmap.registration.neighbours refuses 2**31 points
    for i in range(n):
        c = 0
        for k in range(d):
            ik = int(np.floor((points[i, k] - origin[k]) * inv_cell))
            ik = min(max(ik, 0), dims[k] - 1)
            c = c * dims[k] + ik
        lin[i] = c
        start[c + 1] += 1
    for c in range(ncell):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    order = np.empty(n, np.int64)
    for i in range(n):
        order[fill[lin[i]]] = i
        fill[lin[i]] += 1
    out = np.empty((n, d))
    for j in range(n):
        for k in range(d):
            out[j, k] = points[order[j], k]
    return out, order, start


@nb.njit(cache=True, nogil=True, inline="always")
def _cell_range(x, bound, origin, inv_cell, size):  # pragma: no cover - JIT
    """First and last cell along one axis within ``bound`` of ``x`` (last < first: none), widened by a hair so
    that rounding never drops a cell that holds a point within the bound."""
    lo = (x - bound - origin) * inv_cell - 1e-7
    hi = (x + bound - origin) * inv_cell + 1e-7
    if not (hi >= 0.0 and lo < size):  # also false for NaN
        return 0, -1
    a = 0 if lo < 0.0 else int(np.floor(lo))
    b = size - 1 if hi >= size else int(np.floor(hi))
    return a, b


@nb.njit(cache=True, nogil=True, inline="always")
def _own_cell(sp, start, origin, inv_cell, dims, x, y, z):  # pragma: no cover - JIT
    """The nearest of the points in the grid cell that holds (x, y(, z)) (2D: x, z): (squared distance, place;
    -1: none there or outside the grid)."""
    d = sp.shape[1]
    last = d - 1
    cx = np.floor((x - origin[0]) * inv_cell)
    cz = np.floor((z - origin[last]) * inv_cell)
    if not (cx >= 0.0 and cx < dims[0] and cz >= 0.0 and cz < dims[last]):  # also false for NaN
        return np.inf, -1
    row = int(cx)
    if d == 3:
        cy = np.floor((y - origin[1]) * inv_cell)
        if not (cy >= 0.0 and cy < dims[1]):
            return np.inf, -1
        row = row * dims[1] + int(cy)
    c = row * dims[last] + int(cz)
    best = np.inf
    bj = -1
    for j in range(start[c], start[c + 1]):
        e0 = sp[j, 0] - x
        e1 = sp[j, 1] - y
        s = e0 * e0 + e1 * e1
        if d == 3:
            e2 = sp[j, 2] - z
            s += e2 * e2
        if s < best:
            best = s
            bj = j
    return best, bj


@nb.njit(cache=True, nogil=True, inline="always")
def _dist2(sp, j, x, y, z):  # pragma: no cover - JIT
    """Squared distance of row ``j`` of ``sp`` (2D or 3D) to (x, y(, z)), summed in the order cKDTree sums in."""
    e0 = sp[j, 0] - x
    e1 = sp[j, 1] - y
    s = e0 * e0 + e1 * e1
    if sp.shape[1] == 3:
        e2 = sp[j, 2] - z
        s += e2 * e2
    return s


@nb.njit(cache=True, nogil=True, inline="always")
def _search_start(sp, start, origin, inv_cell, dims, x, y, z, bound, h):  # pragma: no cover - JIT
    """Where a search for the nearest of the sorted points ``sp`` to (x, y(, z)) within ``bound`` starts: the hint
    place ``h`` (-1: none) where it lies within the bound, else the nearest point in the query's own cell, else
    nothing: (squared distance, place, reach), (bound squared, -1, bound) for nothing. Only the cells within the
    reach can hold a point as near."""
    b2 = bound * bound
    if h >= 0:
        s = _dist2(sp, h, x, y, z)
        if s < b2:
            return s, h, np.sqrt(s)
    s, h = _own_cell(sp, start, origin, inv_cell, dims, x, y, z)
    if s < b2:
        return s, h, np.sqrt(s)
    return b2, -1, bound


@nb.njit(cache=True, nogil=True)
def grid_nearest(sp, order, start, origin, inv_cell, dims, q, bound, hint, out_d, out_i, lo, hi):  # pragma: no cover
    """Nearest of the sorted points ``sp`` (2D or 3D) to q[lo:hi] closer than ``bound``: distance (inf if none)
    and original row (len(sp) if none) into out_d, out_i.

    The cells within the bound are visited as runs along the last axis, one run per cell of the axes before it
    (in 2D, the first axis only: the middle loop is then one pass with a stride of 1). ``hint[i]`` (a row of
    ``sp``, -1: none) is a point near q[i]: when closer than the bound, only the cells within its distance are
    visited, which holds every point at least as near, so the answer is the same. Without one, the nearest point
    in q[i]'s own cell serves as the hint."""
    n, d = sp.shape
    last = d - 1
    for i in range(lo, hi):
        x = q[i, 0]
        y = q[i, 1]
        z = q[i, last]
        best, bj, reach = _search_start(sp, start, origin, inv_cell, dims, x, y, z, bound, hint[i])
        x0, x1 = _cell_range(x, reach, origin[0], inv_cell, dims[0])
        if d == 3:
            y0, y1 = _cell_range(y, reach, origin[1], inv_cell, dims[1])
            stride = dims[1]
        else:
            y0, y1, stride = 0, 0, 1
        z0, z1 = _cell_range(z, reach, origin[last], inv_cell, dims[last])
        if z1 >= z0:
            for cx in range(x0, x1 + 1):
                for cy in range(y0, y1 + 1):
                    base = (cx * stride + cy) * dims[last]
                    for j in range(start[base + z0], start[base + z1 + 1]):
                        s = _dist2(sp, j, x, y, z)
                        if s < best or (s == best and bj >= 0 and order[j] < order[bj]):
                            best = s
                            bj = j
        if bj < 0:
            out_d[i] = np.inf
            out_i[i] = n
        else:
            out_d[i] = np.sqrt(best)
            out_i[i] = order[bj]


@nb.njit(cache=True, nogil=True)
def hint_places(hint, rank):  # pragma: no cover - JIT
    """The places in a grid's sorted points (``rank``: each row's) of the hinted rows ``hint`` (N,), -1 where a
    hint is not a row."""
    m = rank.shape[0]
    out = np.empty(hint.shape[0], dtype=np.int64)
    for i in range(hint.shape[0]):
        h = hint[i]
        out[i] = rank[h] if 0 <= h < m else -1
    return out


@nb.njit(cache=True, nogil=True)
def spans_rank(pts, rank):  # pragma: no cover - JIT
    """Whether points (N, d), N >= 1, span ``rank`` dimensions: the scatter's (:func:`centred_scatter`) eigenvalue
    ``d - rank`` (ascending) above 1e-18 of the largest; with no spread (or a coordinate not finite), rank 0 only
    (which any point spans)."""
    d = pts.shape[1]
    if rank == 0:
        return True
    scale, S = centred_scatter(pts)
    if not scale > 0 or not scale < np.inf:
        return False
    ev = np.linalg.eigvalsh(S)
    return ev[d - rank] > 1e-18 * ev[d - 1]


@nb.njit(cache=True, nogil=True)
def centred_scatter(pts):  # pragma: no cover - JIT
    """The spread of points (N, d), N >= 1, about their mean: (scale, S) with scale the largest absolute centred
    coordinate and S (d, d) the sum of the outer products of the centred points divided by it; scale is NaN where
    a coordinate is not finite."""
    n, d = pts.shape
    mean = np.zeros(d)
    for i in range(n):
        for j in range(d):
            mean[j] += pts[i, j]
    for j in range(d):
        mean[j] /= n
    scale = 0.0
    for i in range(n):
        for j in range(d):
            a = abs(pts[i, j] - mean[j])
            if not a < np.inf:
                return np.nan, np.zeros((d, d))
            if a > scale:
                scale = a
    S = np.zeros((d, d))
    if scale == 0.0:
        return scale, S
    c = np.empty(d)
    for i in range(n):
        for j in range(d):
            c[j] = (pts[i, j] - mean[j]) / scale
        for j in range(d):
            for k in range(j, d):
                S[j, k] += c[j] * c[k]
    for j in range(d):
        for k in range(j):
            S[j, k] = S[k, j]
    return scale, S


@nb.njit(cache=True, nogil=True)
def bounding_box(points):  # pragma: no cover - JIT
    """(lower, upper) corners of points (N, d), N >= 1: one pass (numpy's min(axis=0) on an (N, 3) array walks
    it three elements at a time, some 20 times slower)."""
    n, d = points.shape
    lo = points[0].copy()
    hi = points[0].copy()
    for i in range(1, n):
        for k in range(d):
            v = points[i, k]
            if v < lo[k]:
                lo[k] = v
            if v > hi[k]:
                hi[k] = v
    return lo, hi


@nb.njit(cache=True, nogil=True)
def polish_on_grid_2d(src, T, sp, order, start, origin, inv_cell, dims, rank, hint, bound, iterations, tol, kernel,
                      q, nrm):  # pragma: no cover - JIT
    """Point-to-line ICP in 2D with exact correspondences within ``bound`` from a neighbour grid (the sorted
    points ``sp``, their rows ``order``, the cell starts ``start``: :func:`grid_build`; ``rank``: each row's place
    in ``sp``), ``iterations`` at most, stopping when the step's largest entry is below ``tol``; each iteration's
    search starts from the previous one's answers, the first from the rows ``hint`` (N,; out of range: none).
    Returns the refined 3x3 transform."""
    m = src.shape[0]
    n = sp.shape[0]
    T = T.copy()
    moved = np.empty((m, 2))
    dist = np.empty(m)
    idx = np.empty(m, dtype=np.intp)
    places = np.empty(m, dtype=np.int64)
    for i in range(m):
        h = hint[i]
        places[i] = rank[h] if 0 <= h < n else -1
    for _ in range(iterations):
        for i in range(m):
            moved[i, 0] = src[i, 0] * T[0, 0] + src[i, 1] * T[0, 1] + T[0, 2]
            moved[i, 1] = src[i, 0] * T[1, 0] + src[i, 1] * T[1, 1] + T[1, 2]
        grid_nearest(sp, order, start, origin, inv_cell, dims, moved, bound, places, dist, idx, 0, m)
        dT, step, found = point_to_plane_step(moved, dist, idx, q, nrm, kernel)
        if found < 4:
            break
        T = dT @ T
        for i in range(m):
            places[i] = rank[idx[i]] if idx[i] < n else -1
        if step < tol:
            break
    return T


@nb.njit(cache=True, nogil=True)
def truncated_cost(moved, dist, idx, q, nrm, threshold, plane):  # pragma: no cover - JIT
    """Mean over the points of min(residual, threshold) / threshold, a point without a correspondence (``dist``
    not finite) costing 1: the residual the point-to-plane (point-to-line) distance |n . (p - q)| with ``plane``,
    else the point distance."""
    m, d = moved.shape
    acc = 0.0
    for i in range(m):
        if not np.isfinite(dist[i]):
            acc += threshold
            continue
        if plane:
            j = idx[i]
            r = 0.0
            for k in range(d):
                r += nrm[j, k] * (moved[i, k] - q[j, k])
            r = abs(r)
        else:
            r = dist[i]
        acc += min(r, threshold)
    return acc / m / threshold


@nb.njit(cache=True, nogil=True)
def plane_information_terms(moved, dist, idx, q, nrm, kernel, threshold):  # pragma: no cover - JIT
    """From the correspondences (moved_i, q_idx[i], n_idx[i]) of the points with a finite ``dist``: J^T W J of
    their point-to-plane residuals (:func:`point_to_plane_normal_equations`), how many there are, the sum of
    min(|r_i|, threshold) over them, and the sums of w_i r_i^2 and of w_i (Geman-McClure weights of scale
    ``kernel``; 1 where ``kernel <= 0``)."""
    A, _, count = _plane_equations(moved, dist, idx, q, nrm, kernel)
    m, d = moved.shape
    k2 = kernel * kernel
    cost = 0.0
    wr2 = 0.0
    wsum = 0.0
    for i in range(m):
        if not np.isfinite(dist[i]):
            continue
        j = idx[i]
        r = 0.0
        for k in range(d):
            r += nrm[j, k] * (moved[i, k] - q[j, k])
        cost += min(abs(r), threshold)
        w = 1.0
        if kernel > 0:
            t = k2 + r * r
            w = k2 * k2 / (t * t)
        wr2 += w * r * r
        wsum += w
    return A, count, cost, wr2, wsum


@intrinsic
def _fma(typingctx, a, b, c):  # pragma: no cover - JIT
    """a * b + c rounded once (LLVM's fma intrinsic), for float64."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):
        d = ir.DoubleType()
        fn = builder.module.declare_intrinsic("llvm.fma", [d], ir.FunctionType(d, [d, d, d]))
        return builder.call(fn, args)

    return sig, codegen


@nb.njit(cache=True, nogil=True, inline="always")
def _nearest_3d(sp, order, start, origin, inv_cell, dims, x, y, z, bound, h, margin):  # pragma: no cover - JIT
    """:func:`grid_nearest` of one 3D point (x, y, z) with hint place ``h``: (squared distance, place in ``sp``;
    -1: none within ``bound``), and a squared distance within which no other grid point lies.

    The cells searched reach ``margin`` beyond those :func:`grid_nearest` searches (which changes no answer): the
    nearest of the other points in them, or the reach where none is, bounds how far the point can move before
    another grid point could be its nearest."""
    best, bj, reach = _search_start(sp, start, origin, inv_cell, dims, x, y, z, bound, h)
    reach += margin
    second = np.inf
    x0, x1 = _cell_range(x, reach, origin[0], inv_cell, dims[0])
    y0, y1 = _cell_range(y, reach, origin[1], inv_cell, dims[1])
    z0, z1 = _cell_range(z, reach, origin[2], inv_cell, dims[2])
    if z1 >= z0:
        for cx in range(x0, x1 + 1):
            for cy in range(y0, y1 + 1):
                base = (cx * dims[1] + cy) * dims[2]
                for j in range(start[base + z0], start[base + z1 + 1]):
                    if j == bj:
                        continue
                    e0 = sp[j, 0] - x
                    e1 = sp[j, 1] - y
                    s = e0 * e0 + e1 * e1
                    e2 = sp[j, 2] - z
                    s += e2 * e2
                    if s < best or (s == best and bj >= 0 and order[j] < order[bj]):
                        if bj >= 0 and best < second:
                            second = best
                        best = s
                        bj = j
                    elif s < second:
                        second = s
    return best, bj, min(second, reach * reach)


#: How far beyond the nearest point (or the trimming distance, where none is within it) the exact 3D ICP's
#: searches look (metres): the farther, the longer a search and the more iterations its answer holds for.
CERTIFY_MARGIN = 0.02


@nb.njit(cache=True, nogil=True)
def icp_on_grid_3d(src, T, sp, order, start, origin, inv_cell, dims, places, schedule, per_stage, tol, kernel,
                   sn, margin):  # pragma: no cover - JIT
    """Trimmed point-to-plane ICP in 3D with exact correspondences from a neighbour grid (the sorted points ``sp``,
    their rows ``order``, the cell starts ``start``: :func:`grid_build`; ``sn``: the target normals in the order
    of ``sp``).

    ``schedule`` holds the trimming distances, ``per_stage`` iterations at most each; a stage ends when the step's
    largest entry is below ``tol`` or fewer than 6 correspondences are found. Each search starts from the previous
    one's answers, the first from ``places`` (N,; places in ``sp``, -1: none), which is updated. Each iteration
    moves the points as numpy's ``src @ R.T + t`` (:func:`hsmap.geometry.transform_points`) rounds them with
    OpenBLAS (per coordinate, the three products summed by fused multiply-adds in axis order, then the translation
    added), finds their nearest grid points as :func:`grid_nearest` and takes :func:`point_to_plane_step`'s step,
    with the same arithmetic. Returns the refined 4x4 transform."""
    m = src.shape[0]
    T = T.copy()
    A = np.zeros((6, 6))
    g = np.zeros(6)
    ref = np.empty((m, 3))  # where each point's last search was made ...
    clear = np.full(m, -1.0)  # ... and how far from there no grid point but its nearest lies (< 0: no search yet)
    near = np.zeros((m, 6))  # ... and its nearest point and normal (read in the source's order)
    for s in range(schedule.shape[0]):
        bound = schedule[s]
        for _ in range(per_stage):
            a00 = a01 = a02 = a03 = a04 = a05 = 0.0
            a11 = a12 = a13 = a14 = a15 = 0.0
            a22 = a23 = a24 = a25 = 0.0
            a33 = a34 = a35 = 0.0
            a44 = a45 = 0.0
            a55 = 0.0
            g0 = g1 = g2 = g3 = g4 = g5 = 0.0
            count = 0
            for i in range(m):
                sx, sy, sz = src[i, 0], src[i, 1], src[i, 2]
                px = _fma(sz, T[0, 2], _fma(sy, T[0, 1], sx * T[0, 0])) + T[0, 3]
                py = _fma(sz, T[1, 2], _fma(sy, T[1, 1], sx * T[1, 0])) + T[1, 3]
                pz = _fma(sz, T[2, 2], _fma(sy, T[2, 1], sx * T[2, 0])) + T[2, 3]
                c = places[i]
                s2 = 0.0
                searched = True
                if clear[i] >= 0.0:
                    # no grid point but c is within clear[i] of ref[i]: c stays the nearest while the point has
                    # moved less than that minus its distance to c (a nanometre spares the rounding)
                    dx = px - ref[i, 0]
                    dy = py - ref[i, 1]
                    dz = pz - ref[i, 2]
                    lim = clear[i] - np.sqrt(dx * dx + dy * dy + dz * dz) - 1e-9
                    if c >= 0:
                        e0 = near[i, 0] - px
                        e1 = near[i, 1] - py
                        s2 = e0 * e0 + e1 * e1
                        e2 = near[i, 2] - pz
                        s2 += e2 * e2
                        searched = not (lim > 0.0 and s2 < lim * lim)
                    else:
                        searched = not (lim >= bound)
                if searched:
                    s2, c, free2 = _nearest_3d(sp, order, start, origin, inv_cell, dims, px, py, pz, bound, c, margin)
                    places[i] = c
                    ref[i, 0], ref[i, 1], ref[i, 2] = px, py, pz
                    clear[i] = np.sqrt(free2)
                    if c >= 0:
                        for k in range(3):
                            near[i, k] = sp[c, k]
                            near[i, 3 + k] = sn[c, k]
                if c < 0 or not s2 < bound * bound:
                    continue
                count += 1
                n0, n1, n2 = near[i, 3], near[i, 4], near[i, 5]
                r = 0.0
                r += n0 * (px - near[i, 0])
                r += n1 * (py - near[i, 1])
                r += n2 * (pz - near[i, 2])
                j3 = py * n2 - pz * n1
                j4 = pz * n0 - px * n2
                j5 = px * n1 - py * n0
                w = 1.0
                if kernel > 0:
                    t = kernel * kernel + r * r
                    w = kernel * kernel * kernel * kernel / (t * t)
                w0 = w * n0
                w1 = w * n1
                w2 = w * n2
                w3 = w * j3
                w4 = w * j4
                w5 = w * j5
                g0 += w0 * r
                g1 += w1 * r
                g2 += w2 * r
                g3 += w3 * r
                g4 += w4 * r
                g5 += w5 * r
                a00 += w0 * n0
                a01 += w0 * n1
                a02 += w0 * n2
                a03 += w0 * j3
                a04 += w0 * j4
                a05 += w0 * j5
                a11 += w1 * n1
                a12 += w1 * n2
                a13 += w1 * j3
                a14 += w1 * j4
                a15 += w1 * j5
                a22 += w2 * n2
                a23 += w2 * j3
                a24 += w2 * j4
                a25 += w2 * j5
                a33 += w3 * j3
                a34 += w3 * j4
                a35 += w3 * j5
                a44 += w4 * j4
                a45 += w4 * j5
                a55 += w5 * j5
            A[0, 0], A[0, 1], A[0, 2], A[0, 3], A[0, 4], A[0, 5] = a00, a01, a02, a03, a04, a05
            A[1, 1], A[1, 2], A[1, 3], A[1, 4], A[1, 5] = a11, a12, a13, a14, a15
            A[2, 2], A[2, 3], A[2, 4], A[2, 5] = a22, a23, a24, a25
            A[3, 3], A[3, 4], A[3, 5] = a33, a34, a35
            A[4, 4], A[4, 5] = a44, a45
            A[5, 5] = a55
            g[0], g[1], g[2], g[3], g[4], g[5] = g0, g1, g2, g3, g4, g5
            dT, step, found = _plane_step(A, g, count, 3)
            if found < 6:
                break
            T = dT @ T
            if step < tol:
                break
    return T
