"""Numba kernels of the room segmentation: Zhang-Suen thinning on a border work list, the exact Euclidean distance
transform with its feature transform, the wedge of free space each obstacle pixel is the nearest obstacle to
(the corner detector), and the ray marches of the door and wall-gap lines.

Images are (row, col) arrays; callers pad them so that no kernel reads outside.
"""

from __future__ import annotations

import numba as nb
import numpy as np

__all__ = ["basis_points", "chord_median", "corner_wedges", "edt", "free_between", "label_max", "line_pixels",
           "ray_hit", "thin", "wall_steps"]

# Zhang & Suen (1984) as scikit-image implements it (skimage.morphology.skeletonize, method "zhang"): for each of
# the 256 neighbourhoods (bit 0 = north-west, clockwise: 1 N, 2 NE, 3 E, 4 SE, 5 S, 6 SW, 7 W) 1 = removable in
# the first sub-iteration, 2 = in the second, 3 = in both.
_LUT = np.array([
    0, 0, 0, 1, 0, 0, 1, 3, 0, 0, 3, 1, 1, 0, 1, 3, 0, 0, 0, 0, 0, 0,
    0, 0, 2, 0, 2, 0, 3, 0, 3, 3, 0, 0, 0, 0, 0, 0, 0, 0, 3, 0, 0, 0,
    0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 2, 0, 0, 0, 3, 0, 2, 2, 0, 0,
    0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
    0, 0, 0, 0, 0, 0, 0, 0, 2, 0, 0, 0, 0, 0, 0, 0, 2, 0, 0, 0, 2, 0,
    0, 0, 3, 0, 0, 0, 0, 0, 0, 0, 3, 0, 0, 0, 3, 0, 2, 0, 0, 0, 3, 1,
    0, 0, 1, 3, 0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
    0, 0, 0, 0, 0, 1, 3, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
    2, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 2, 3, 1, 3, 0, 0,
    1, 3, 0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
    0, 0, 0, 0, 2, 3, 0, 1, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 3, 3,
    0, 1, 0, 0, 0, 0, 2, 2, 0, 0, 2, 0, 0, 0], dtype=np.uint8)

_DR = np.array([-1, -1, -1, 0, 1, 1, 1, 0], dtype=np.int64)
_DC = np.array([-1, 0, 1, 1, 1, 0, -1, -1], dtype=np.int64)


@nb.njit(cache=True, nogil=True)
def _thin(img, lut, dr, dc):  # pragma: no cover - JIT
    """Zhang-Suen thinning in place. Only pixels whose neighbourhood changed within the last two
    sub-iterations are looked at: any other one was already judged, by both sub-iterations' rules, on the
    neighbourhood it still has."""
    H, W = img.shape
    pending = np.zeros((H, W), dtype=np.uint8)
    cap = 1024
    lr = np.empty(cap, dtype=np.int64)
    lc = np.empty(cap, dtype=np.int64)
    n = 0
    for r in range(1, H - 1):
        for c in range(1, W - 1):
            if img[r, c]:
                for k in range(8):
                    if not img[r + dr[k], c + dc[k]]:
                        if n == cap:
                            cap *= 2
                            lr2 = np.empty(cap, dtype=np.int64)
                            lc2 = np.empty(cap, dtype=np.int64)
                            lr2[:n] = lr[:n]
                            lc2[:n] = lc[:n]
                            lr, lc = lr2, lc2
                        lr[n] = r
                        lc[n] = c
                        pending[r, c] = 2
                        n += 1
                        break
    rem_r = np.empty(cap, dtype=np.int64)
    rem_c = np.empty(cap, dtype=np.int64)
    sub = 0
    while n > 0:
        # decide on the image as it stands (parallel thinning), then remove
        if len(rem_r) < n:
            rem_r = np.empty(n, dtype=np.int64)
            rem_c = np.empty(n, dtype=np.int64)
        m = 0
        for i in range(n):
            r = lr[i]
            c = lc[i]
            pending[r, c] -= 1
            code = 0
            for k in range(8):
                if img[r + dr[k], c + dc[k]]:
                    code |= 1 << k
            v = lut[code]
            if v == 3 or (v == 1 and sub == 0) or (v == 2 and sub == 1):
                rem_r[m] = r
                rem_c[m] = c
                m += 1
        for j in range(m):
            img[rem_r[j], rem_c[j]] = 0
            pending[rem_r[j], rem_c[j]] = 0
        # keep the pixels still to be judged, add the set neighbours of the removed ones
        k2 = 0
        for i in range(n):
            r = lr[i]
            c = lc[i]
            if img[r, c] and pending[r, c] > 0:
                lr[k2] = r
                lc[k2] = c
                k2 += 1
        n = k2
        for j in range(m):
            for k in range(8):
                r = rem_r[j] + dr[k]
                c = rem_c[j] + dc[k]
                if img[r, c]:
                    if pending[r, c] == 0:
                        if n == cap:
                            cap *= 2
                            lr2 = np.empty(cap, dtype=np.int64)
                            lc2 = np.empty(cap, dtype=np.int64)
                            lr2[:n] = lr[:n]
                            lc2[:n] = lc[:n]
                            lr, lc = lr2, lc2
                        lr[n] = r
                        lc[n] = c
                        n += 1
                    pending[r, c] = 2
        sub = 1 - sub
    return img


def thin(mask: np.ndarray) -> np.ndarray:
    """Skeleton of a 2D boolean mask by Zhang-Suen thinning, the same pixels as
    ``skimage.morphology.skeletonize(mask)`` but working only on the shrinking border.

    Parameters
    ----------
    mask : ndarray of shape (H, W), bool

    Returns
    -------
    ndarray of shape (H, W), bool
    """
    img = np.zeros((mask.shape[0] + 2, mask.shape[1] + 2), dtype=np.uint8)
    img[1:-1, 1:-1] = mask
    return _thin(img, _LUT, _DR, _DC)[1:-1, 1:-1].astype(bool)


@nb.njit(cache=True, nogil=True)
def corner_wedges(free, dist, feat_r, feat_c, r_min, r_max, nbins):  # pragma: no cover - JIT
    """Angle (degrees) of the widest wedge of free space around each obstacle pixel (0 elsewhere) and the
    first of its sectors (-1 elsewhere); sector s spans directions (row, col) = (sin t, cos t) for t in
    [2 pi s / nbins - pi, 2 pi (s + 1) / nbins - pi).

    Every free pixel at ``r_min``..``r_max`` pixels from the obstacles votes, for its nearest obstacle pixel
    (``feat_r``, ``feat_c``), for the sector of ``nbins`` it lies in as seen from there; the votes of the 3x3
    neighbourhood of an obstacle pixel are pooled and the longest circular run of voted sectors is its wedge.
    ``free`` must have a free-less border of one pixel.
    """
    H, W = free.shape
    votes = np.zeros((H, W), dtype=np.uint64)
    two_pi = 2.0 * np.pi
    for r in range(H):
        for c in range(W):
            if free[r, c]:
                d = dist[r, c]
                if d >= r_min and d <= r_max:
                    orr = feat_r[r, c]
                    occ = feat_c[r, c]
                    a = np.arctan2(r - orr, c - occ) + np.pi
                    s = int(a / two_pi * nbins) % nbins
                    votes[orr, occ] |= np.uint64(1) << np.uint64(s)
    out = np.zeros((H, W), dtype=np.float64)
    start = np.full((H, W), -1, dtype=np.int64)
    for r in range(1, H - 1):
        for c in range(1, W - 1):
            if free[r, c]:
                continue
            m = np.uint64(0)
            for dr in range(-1, 2):
                for dc in range(-1, 2):
                    m |= votes[r + dr, c + dc]
            if m == 0:
                continue
            # longest circular run of set sectors and its first sector
            best = 0
            best_s = 0
            cur = 0
            cur_s = 0
            for i in range(2 * nbins):
                if (m >> np.uint64(i % nbins)) & np.uint64(1):
                    if cur == 0:
                        cur_s = i % nbins
                    cur += 1
                    if cur > best:
                        best = min(cur, nbins)
                        best_s = cur_s
                else:
                    cur = 0
            out[r, c] = best * 360.0 / nbins
            start[r, c] = best_s
    return out, start


@nb.njit(cache=True, nogil=True)
def _edt_1d(f, idx_in, n, d, idx_out, v, z):  # pragma: no cover - JIT
    """Lower envelope of the parabolas (q, f[q]) (Felzenszwalb & Huttenlocher 2012): d[p] = min_q (p - q)^2
    + f[q] and the q attaining it (``idx_out`` takes ``idx_in[q]``)."""
    k = 0
    first = -1
    for q in range(n):
        if f[q] < np.inf:
            first = q
            break
    if first < 0:
        for p in range(n):
            d[p] = np.inf
            idx_out[p] = -1
        return
    v[0] = first
    z[0] = -np.inf
    z[1] = np.inf
    for q in range(first + 1, n):
        if f[q] == np.inf:
            continue
        while True:
            vk = v[k]
            s = ((f[q] + q * q) - (f[vk] + vk * vk)) / (2.0 * (q - vk))
            if s <= z[k]:
                k -= 1
                if k < 0:
                    break
            else:
                break
        k += 1
        v[k] = q
        z[k] = s if k > 0 else -np.inf
        z[k + 1] = np.inf
    k = 0
    for p in range(n):
        while z[k + 1] < p:
            k += 1
        q = v[k]
        d[p] = (p - q) * (p - q) + f[q]
        idx_out[p] = idx_in[q]


@nb.njit(cache=True, nogil=True)
def _edt_rows(f0, free_in, rows_in):  # pragma: no cover - JIT
    """One separable pass along the rows of ``f0`` (squared distances, inf where unknown; ``free_in`` True:
    build them from a mask instead), returning squared distances and the column of the minimiser."""
    H, W = f0.shape
    d2 = np.empty((H, W), dtype=np.float64)
    arg = np.empty((H, W), dtype=np.int64)
    f = np.empty(W, dtype=np.float64)
    ii = np.arange(W)
    d = np.empty(W, dtype=np.float64)
    io = np.empty(W, dtype=np.int64)
    v = np.empty(W, dtype=np.int64)
    z = np.empty(W + 1, dtype=np.float64)
    for r in range(H):
        for c in range(W):
            f[c] = f0[r, c]
        _edt_1d(f, ii, W, d, io, v, z)
        for c in range(W):
            d2[r, c] = d[c]
            arg[r, c] = io[c]
    return d2, arg


def edt(free: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Euclidean distance transform with its feature transform, like
    ``scipy.ndimage.distance_transform_edt(free, return_indices=True)``.

    Parameters
    ----------
    free : ndarray of shape (H, W), bool
        True where the distance is wanted; it must contain a False pixel.

    Returns
    -------
    dist : ndarray of shape (H, W), float64
        Distance (pixels) from each True pixel to the nearest False one, 0 on False pixels.
    rows, cols : ndarray of shape (H, W), int64
        Row and column of that nearest False pixel.
    """
    f0 = np.where(free, np.inf, 0.0).T.copy()
    g, grow_t = _edt_rows(f0, True, True)  # along the columns of the image
    d2, col = _edt_rows(np.ascontiguousarray(g.T), True, True)  # along its rows
    grow = np.ascontiguousarray(grow_t.T)
    rows = np.take_along_axis(grow, col, axis=1)
    return np.sqrt(d2), rows, col


@nb.njit(cache=True, nogil=True)
def label_max(labels, values, n):  # pragma: no cover - JIT
    """Largest value per label 0..n (labels (H, W) int, values (H, W) float); -inf for labels without pixels."""
    out = np.full(n + 1, -np.inf)
    H, W = labels.shape
    for r in range(H):
        for c in range(W):
            k = labels[r, c]
            if values[r, c] > out[k]:
                out[k] = values[r, c]
    return out


@nb.njit(cache=True, nogil=True)
def _free_or(free, r, c, outside):  # pragma: no cover - JIT
    H, W = free.shape
    if r < 0 or r >= H or c < 0 or c >= W:
        return outside
    return free[r, c]


@nb.njit(cache=True, nogil=True)
def wall_steps(free, ar, ac, ur, uc, steps, side):  # pragma: no cover - JIT
    """For the line from obstacle pixel (ar, ac) along the unit vector (ur, uc), shifted across by -1, 0 or 1
    pixel and watched from either side: per step 1..steps, whether it lies on an obstacle pixel with free space
    2 to ``side`` pixels to that side (outside the image counts as free). Returns the (6, steps) table, in the
    order shift 0, -1, 1 times side -1, 1."""
    vr, vc = -uc, ur
    out = np.zeros((6, steps), dtype=np.bool_)
    row = 0
    for s in (0.0, -1.0, 1.0):
        for sgn in (-1.0, 1.0):
            for i in range(steps):
                t = i + 1.0
                pr = ar + t * ur + s * vr
                pc = ac + t * uc + s * vc
                if _free_or(free, int(np.rint(pr)), int(np.rint(pc)), True):
                    continue
                near = False
                for k in range(2, max(side, 2) + 1):
                    if _free_or(free, int(np.rint(pr + sgn * k * vr)), int(np.rint(pc + sgn * k * vc)), True):
                        near = True
                        break
                out[row, i] = near
            row += 1
    return out


@nb.njit(cache=True, nogil=True)
def chord_median(free, mr, mc, ur, uc, nr, nc, depths, reach):  # pragma: no cover - JIT
    """Median over the depths t of the free chord (pixels) parallel to (ur, uc) through (mr, mc) + t (nr, nc),
    followed up to ``reach`` pixels each side of the centre (outside the image is blocked; 0 where the centre
    itself is blocked)."""
    n = len(depths)
    runs = np.empty(n, dtype=np.float64)
    for j in range(n):
        cr = mr + depths[j] * nr
        cc = mc + depths[j] * nc
        total = -1.0
        for sign in (1.0, -1.0):
            first = reach + 1
            for k in range(reach + 1):
                if not _free_or(free, int(np.rint(cr + sign * k * ur)), int(np.rint(cc + sign * k * uc)), False):
                    first = k
                    break
            total += first
        runs[j] = max(total, 0.0)
    return np.median(runs)


@nb.njit(cache=True, nogil=True)
def free_between(free, ar, ac, br, bc, end_px):  # pragma: no cover - JIT
    """Whether the line from obstacle pixel a to obstacle pixel b (half-pixel samples) is free from its first
    free sample to its last, and these lie within ``end_px`` of the ends."""
    L = np.hypot(br - ar, bc - ac)
    n_s = max(int(np.ceil(L)) * 2, 2)
    i0 = -1
    i1 = -1
    for i in range(n_s + 1):
        t = i / n_s
        if free[int(np.rint(ar + t * (br - ar))), int(np.rint(ac + t * (bc - ac)))]:
            if i0 < 0:
                i0 = i
            i1 = i
    if i0 < 0:
        return False
    for i in range(i0, i1 + 1):
        t = i / n_s
        if not free[int(np.rint(ar + t * (br - ar))), int(np.rint(ac + t * (bc - ac)))]:
            return False
    return i0 / n_s * L <= end_px and (1.0 - i1 / n_s) * L <= end_px


@nb.njit(cache=True, nogil=True)
def ray_hit(free, ar, ac, er, ec, max_px, end_px):  # pragma: no cover - JIT
    """The first obstacle pixel met by the ray from obstacle pixel a along (er, ec) (half-pixel steps) after
    it has left a's obstacle within ``end_px``, at most ``max_px`` from a; (-1, -1) if none."""
    H, W = free.shape
    left = False
    t = 0.5
    while t < max_px + end_px + 1.0:
        r = int(np.rint(ar + t * er))
        c = int(np.rint(ac + t * ec))
        if r < 0 or r >= H or c < 0 or c >= W:
            return -1, -1
        if not left:
            if free[r, c]:
                left = True
            elif t > end_px:
                return -1, -1
        elif not free[r, c]:
            if np.hypot(r - ar, c - ac) <= max_px:
                return r, c
            return -1, -1
        t += 0.5
    return -1, -1


@nb.njit(cache=True, nogil=True)
def _nearest_two(free, pr, pc, half, radius, cos_min):  # pragma: no cover - JIT
    H, W = free.shape
    r0 = max(pr - half, 0)
    r1 = min(pr + half + 1, H)
    c0 = max(pc - half, 0)
    c1 = min(pc + half + 1, W)
    best = np.inf
    ir = -1
    ic = -1
    for r in range(r0, r1):
        for c in range(c0, c1):
            if not free[r, c]:
                d = np.hypot(float(r - pr), float(c - pc))
                if d < best:
                    best = d
                    ir = r
                    ic = c
    if ir < 0 or best < 1e-9:
        return -1, -1, -1, -1, best, np.inf
    vr = float(ir - pr)
    vc = float(ic - pc)
    best2 = np.inf
    jr = -1
    jc = -1
    for r in range(r0, r1):
        for c in range(c0, c1):
            if not free[r, c]:
                wr = float(r - pr)
                wc = float(c - pc)
                d = np.hypot(wr, wc)
                if d <= radius and d < best2 and (wr * vr + wc * vc) / max(d * best, 1e-9) <= cos_min:
                    best2 = d
                    jr = r
                    jc = c
    return ir, ic, jr, jc, best, best2


@nb.njit(cache=True, nogil=True)
def basis_points(free, pr, pc, radius, cos_min, clearance):  # pragma: no cover - JIT
    """The obstacle pixel nearest to (pr, pc) within the square of half side ``radius``, and the nearest one
    whose direction from (pr, pc) makes an angle with the first's of cosine at most ``cos_min`` (within
    ``radius``); the first in row-major order among equals. Returns (r1, c1, r2, c2), -1s where absent.
    ``clearance`` (the pixel's distance to the nearest obstacle) lets the search start in a small square,
    widened to the whole one only where the answer could lie outside it."""
    half = min(radius, int(np.ceil(2.0 * clearance)) + 3)
    ir, ic, jr, jc, d1, d2 = _nearest_two(free, pr, pc, half, radius, cos_min)
    if half < radius and (ir < 0 or d1 > half or jr < 0 or d2 > half):
        ir, ic, jr, jc, d1, d2 = _nearest_two(free, pr, pc, radius, radius, cos_min)
    if ir < 0 or jr < 0:
        return -1, -1, -1, -1
    return ir, ic, jr, jc


@nb.njit(cache=True, nogil=True)
def line_pixels(ar, ac, br, bc):  # pragma: no cover - JIT
    """4-connected pixel line from (ar, ac) to (br, bc): samples at half-pixel steps rounded to pixels, then
    at each diagonal step the pixel (previous row, next column) appended."""
    n = max(abs(br - ar), abs(bc - ac)) * 2 + 1
    r = np.empty(n, dtype=np.int64)
    c = np.empty(n, dtype=np.int64)
    step = 1.0 / (n - 1) if n > 1 else 0.0
    for i in range(n):
        t = i * step if i < n - 1 else 1.0  # as numpy.linspace(0, 1, n)
        r[i] = int(np.rint(ar + t * (br - ar)))
        c[i] = int(np.rint(ac + t * (bc - ac)))
    m = 0
    for i in range(n - 1):
        if r[i + 1] != r[i] and c[i + 1] != c[i]:
            m += 1
    rr = np.empty(n + m, dtype=np.int64)
    cc = np.empty(n + m, dtype=np.int64)
    rr[:n] = r
    cc[:n] = c
    k = n
    for i in range(n - 1):
        if r[i + 1] != r[i] and c[i + 1] != c[i]:
            rr[k] = r[i]
            cc[k] = c[i + 1]
            k += 1
    return rr, cc
