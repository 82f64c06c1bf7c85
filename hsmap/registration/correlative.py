"""Correlative scan matching in 2D: an exhaustive search of a window of poses, coarse to fine (Olson, 2009).

The far loop search (:meth:`hsmap.slam.loopclosure.LoopCloser.attempt_far`) and the global map alignment
(:func:`hsmap.maps.fusion.global_align`) use it where no initial guess is good enough for Harmony-ICP: every
rotation and translation of the window is scored against a likelihood field of the target, the best coarse poses
are refined on the fine grid, and the runner-up far from the best says how ambiguous the match is.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .._threads import current_threads, helper_pool
from ..geometry import wrap_angle

__all__ = ["correlative_match_2d"]


def _likelihood_field(points: NDArray[np.float64], resolution: float) -> tuple[NDArray[np.float64],
                                                                                NDArray[np.float64]]:
    """A Gaussian of the distance to the nearest of ``points`` (sigma: one cell, zero beyond three), on a grid
    indexed (x cell, y cell), not image (row, col); and the grid's origin."""
    from scipy.ndimage import distance_transform_edt

    t0 = points.min(axis=0) - 3 * resolution
    shape = np.floor((points.max(axis=0) + 3 * resolution - t0) / resolution).astype(int) + 1
    occ = np.zeros(shape, bool)
    ti = np.floor((points - t0) / resolution).astype(int)
    occ[ti[:, 0], ti[:, 1]] = True
    dist = distance_transform_edt(~occ)
    field = np.exp(-0.5 * dist**2)
    field[dist > 3] = 0.0
    return field, t0


def _rotated(points: NDArray[np.float64], yaw: float) -> NDArray[np.float64]:
    c, s_ = np.cos(yaw), np.sin(yaw)
    return points @ np.array([[c, s_], [-s_, c]])


def _unique_cells(cells: NDArray[np.int64]) -> NDArray[np.int64]:
    """``np.unique(cells, axis=0)`` for (N, 2) integer cells, the rows in the same (lexicographic) order: one
    integer key per cell sorts several times faster than rows."""
    lo = cells.min(axis=0)
    width = int(cells[:, 1].max() - lo[1]) + 1
    key = np.unique((cells[:, 0] - lo[0]) * width + (cells[:, 1] - lo[1]))
    return np.column_stack([key // width + lo[0], key % width + lo[1]])


@dataclass(frozen=True)
class _CoarseField:
    """The coarse likelihood field of :func:`correlative_match_2d`'s target: ``field_shape`` cells of ``rc`` metres
    from ``t0c``, and its real 2D transform ``field_f`` at ``shape`` (large enough to hold the full correlation with
    the source at any rotation)."""

    field_f: NDArray[np.complex128]
    field_shape: tuple[int, int]
    shape: list[int]
    t0c: NDArray[np.float64]
    rc: float

    @classmethod
    def of(cls, src: NDArray[np.float64], tgt: NDArray[np.float64], rc: float) -> _CoarseField:
        from scipy import fft

        field_c, t0c = _likelihood_field(tgt, rc)
        # the source's cells span at most its diameter plus one each way
        span = int(np.ceil(2 * np.linalg.norm(src, axis=1).max() / rc)) + 2
        shape = [fft.next_fast_len(n + span - 1, real=True) for n in field_c.shape]
        return cls(fft.rfft2(field_c, shape), field_c.shape, shape, t0c, rc)


def _coarse_peaks(angles: NDArray[np.float64], src: NDArray[np.float64], field: _CoarseField,
                  centre: NDArray[np.float64], half_translation: float, sep_c: int, peaks: int
                  ) -> list[tuple[float, float, float, float]]:
    """:func:`correlative_match_2d`'s coarse stage at the rotations ``angles``: each one's ``peaks`` best cells of
    the window at least ``sep_c`` cells apart, as (score, x, y, yaw), rotation by rotation, best first. The
    source's image at each rotation is cross-correlated with the coarse field by FFT.
    """
    from scipy import fft

    field_f, field_shape, shape, t0c, rc = field.field_f, field.field_shape, field.shape, field.t0c, field.rc
    scale = float(1 / np.longdouble(shape[0] * shape[1]))  # irfft2's own factor, on the rows kept
    column = np.zeros((shape[0], shape[1] // 2 + 1), dtype=complex)
    used = 0  # rows of `column` that may hold an earlier image's transform
    found = []
    for yaw in angles:
        p = _rotated(src, yaw)
        s0 = np.array([p[:, 0].min(), p[:, 1].min()])
        si = np.floor((p - s0) / rc).astype(int)
        h, w = int(si[:, 0].max()) + 1, int(si[:, 1].max()) + 1
        # translation of output cell (m, k) of the full convolution: t0 - s0 + (m - h + 1, k - w + 1) * rc
        off = t0c - s0 - np.array([h - 1, w - 1]) * rc
        lo = np.maximum(np.ceil((centre - half_translation - off) / rc).astype(int), 0)
        hi = np.minimum(np.floor((centre + half_translation - off) / rc).astype(int),
                        np.array([field_shape[0] + h - 2, field_shape[1] + w - 2]))
        if np.any(hi < lo):
            continue
        img = np.zeros((h, w))
        img[si[:, 0], si[:, 1]] = 1.0
        n = img.sum()
        # rfft2 and irfft2 axis by axis, as they run: the image's h rows alone through the first pass, and the
        # window's rows alone through the last (the others are zeros in, unread out)
        column[:h] = fft.rfft(img[::-1, ::-1], shape[1], axis=1)
        column[h:used] = 0.0
        used = h
        rows = fft.ifft(field_f * fft.fft(column, axis=0), axis=0, norm="forward")[lo[0]:hi[0] + 1]
        win = fft.irfft(rows, shape[1], axis=1, norm="forward")[:, lo[1]:hi[1] + 1] * scale / n
        # the best cells at least `separation` apart (a slope's, too: a corridor's axis scores alike along it)
        flat = win.ravel()
        top = min(flat.size, peaks * (2 * sep_c + 1) ** 2)
        order = np.argpartition(-flat, top - 1)[:top]
        order = order[np.argsort(-flat[order], kind="stable")]
        order = order[flat[order] > 0]
        mm, kk = np.unravel_index(order, win.shape)
        for _ in range(peaks):  # greedily: the best left, then none within sep_c cells of it
            if not len(mm):
                break
            m, k = int(mm[0]), int(kk[0])
            found.append((float(win[m, k]), off[0] + (lo[0] + m) * rc, off[1] + (lo[1] + k) * rc, float(yaw)))
            far = (np.abs(mm - m) >= sep_c) | (np.abs(kk - k) >= sep_c)
            mm, kk = mm[far], kk[far]
    return found


def _coarse_search(src: NDArray[np.float64], tgt: NDArray[np.float64], angles: NDArray[np.float64],
                   centre: NDArray[np.float64], half_translation: float, rc: float, separation: float,
                   peaks: int) -> list[tuple[float, float, float, float]]:
    """The ``peaks`` best coarse poses (score, x, y, yaw) at least ``separation`` metres apart: every rotation,
    every translation of the window, on cells of ``rc`` metres."""
    sep_c = max(int(np.ceil(separation / rc)), 1)
    field = _CoarseField.of(src, tgt, rc)  # the field's transform once
    # the rotations in contiguous shares, one per compute thread (the transforms release the GIL); each
    # rotation's peaks are its own, so the list, joined in order, is the same for any number of threads
    args = (src, field, centre, half_translation, sep_c, peaks)
    shares = np.array_split(angles, max(1, min(current_threads(), len(angles) // 16)))
    futures = [helper_pool(len(shares) - 1).submit(_coarse_peaks, share, *args) for share in shares[1:]]
    found = _coarse_peaks(shares[0], *args)
    for f in futures:
        found += f.result()
    found.sort(key=lambda f: -f[0])
    chosen: list[tuple[float, float, float, float]] = []
    for f in found:  # the best coarse poses, one per place
        if all(np.hypot(f[1] - c[1], f[2] - c[2]) > separation for c in chosen):
            chosen.append(f)
            if len(chosen) == peaks:
                break
    return chosen


@dataclass(frozen=True)
class _Window:
    """The poses :func:`correlative_match_2d` searches: ``predicted`` (x, y, yaw) +/- ``half_translation`` and
    ``half_rotation``, rotations ``angle_step`` apart."""

    predicted: NDArray[np.float64]
    half_translation: float
    half_rotation: float
    angle_step: float


def _fine_search(src: NDArray[np.float64], tgt: NDArray[np.float64], chosen: list, window: _Window, res: float,
                 coarse: int) -> list[NDArray[np.float64]]:
    """Each chosen coarse pose searched at ``res`` over two coarse cells each way and the neighbouring rotations,
    within the window: (score, x, y, yaw) rows. The translations are whole cells apart, so each source cell reads
    a (2W+1)^2 patch of the field: one gather per rotation."""
    predicted, half_translation = window.predicted, window.half_translation
    half_rotation, angle_step = window.half_rotation, window.angle_step
    centre = predicted[:2]
    field, t0 = _likelihood_field(tgt, res)
    W = 2 * max(int(coarse), 1)
    padded = np.pad(field, 2 * W)
    patches = np.lib.stride_tricks.sliding_window_view(padded, (2 * W + 1, 2 * W + 1))
    shift = np.stack(np.meshgrid(np.arange(-W, W + 1), np.arange(-W, W + 1), indexing="ij"), axis=-1) * res
    cells_at: dict[float, NDArray[np.int_]] = {}  # the rotated source's occupied cells, per rotation (peaks share)
    evaluated = []  # (score, x, y, yaw) of every fine pose
    for _, x, y, yaw0 in chosen:
        xy = np.array([x, y]) + shift.reshape(-1, 2)
        inside = (np.abs(xy - centre) <= half_translation + 1e-9).all(axis=1)
        if not inside.any():
            continue
        for yaw in yaw0 + angle_step * np.arange(-coarse, coarse + 1):
            if abs(wrap_angle(yaw - predicted[2])) > half_rotation + 1e-9:
                continue
            cells = cells_at.get(yaw)
            if cells is None:
                cells = cells_at[yaw] = _unique_cells(np.floor(_rotated(src, yaw) / res).astype(np.int64))
            pts = (cells + 0.5) * res  # the source's occupied cells, as the coarse level counts them
            base = np.floor((pts + np.array([x, y]) - t0) / res).astype(int)
            keep = ((base >= -W) & (base < np.array(field.shape) + W)).all(axis=1)  # others read zeros only
            start = base[keep] + W
            score = patches[start[:, 0], start[:, 1]].sum(axis=0).reshape(-1) / len(cells)
            evaluated.append(np.column_stack([score[inside], xy[inside], np.full(int(inside.sum()), yaw)]))
    return evaluated


def correlative_match_2d(source: NDArray[np.float64], target: NDArray[np.float64], predicted: NDArray[np.float64],
                         half_translation: float, half_rotation: float, resolution: float = 0.2,
                         angle_step: float = float(np.deg2rad(1.0)), separation: float = 2.0, *, coarse: int = 4,
                         peaks: int = 8) -> tuple[NDArray[np.float64], float, float]:
    """Exhaustive 2D scan matching over a window (Olson's correlative scan matching, 2009), coarse to fine.

    A pose is scored by the mean, over the source's occupied cells, of a likelihood field of the target (a
    Gaussian of the distance to the nearest target point, sigma = one cell). Every rotation in ``predicted[2] +/-
    half_rotation`` (steps of ``angle_step``) and every translation in ``predicted[:2] +/- half_translation`` is
    scored on a grid ``coarse`` times coarser than ``resolution`` (the translations of one rotation at once, by an
    FFT cross-correlation); the ``peaks`` best coarse poses at least ``separation`` apart are then searched at
    ``resolution`` over their coarse cell and the neighbouring rotations. No initial guess is needed inside the
    window, however wide; the coarse grid keeps a 100 m window's cost near a fine 25 m one's.

    Returns ``(pose, score, ambiguity)``: the best pose of the source in the target's frame (x, y, yaw), its
    (fine) score in [0, 1], and the best fine score of any other peak more than ``separation`` metres from it
    divided by its score (near 1: a look-alike place or a corridor, the match says little).
    """
    src = np.asarray(source, dtype=float)[:, :2]
    tgt = np.asarray(target, dtype=float)[:, :2]
    predicted = np.asarray(predicted, dtype=float)
    res = float(resolution)
    rc = res * max(int(coarse), 1)
    n_rot = int(np.floor(half_rotation / angle_step))
    angles = predicted[2] + angle_step * np.arange(-n_rot, n_rot + 1)
    chosen = _coarse_search(src, tgt, angles, predicted[:2], half_translation, rc, separation, peaks)
    if not chosen:
        return predicted.copy(), 0.0, 1.0
    window = _Window(predicted, half_translation, half_rotation, angle_step)
    evaluated = _fine_search(src, tgt, chosen, window, res, coarse)
    if not evaluated:
        return predicted.copy(), 0.0, 1.0
    ev = np.concatenate(evaluated)
    b = int(np.argmax(ev[:, 0]))
    score, bx, by, byaw = ev[b]
    if score <= 0:
        return predicted.copy(), 0.0, 1.0
    far = np.hypot(ev[:, 1] - bx, ev[:, 2] - by) > separation
    ambiguity = float(ev[far, 0].max() / score) if far.any() else 0.0
    return np.array([bx, by, byaw]), float(score), ambiguity
