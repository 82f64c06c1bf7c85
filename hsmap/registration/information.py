"""Information matrices of registrations: the adjoint that carries them between frames, the inverse that
tolerates singular ones, and the directions a scene constrains."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError

__all__ = ["adjoint", "constrained_axes", "drop_degenerate", "safe_inverse"]


def safe_inverse(info: NDArray[np.float64] | None) -> NDArray[np.float64]:
    if info is None:
        raise InputError("no information matrix was computed for this registration")
    w, V = np.linalg.eigh(0.5 * (info + info.T))
    inv = np.where(w > 1e-12 * max(w.max(), 1e-300), 1.0 / np.maximum(w, 1e-300), np.inf)
    finite = np.isfinite(inv)
    cov = (V[:, finite] * inv[finite]) @ V[:, finite].T
    if not finite.all():
        cov = cov + (V[:, ~finite] * 1e18) @ V[:, ~finite].T
    return cov


def adjoint(T: NDArray[np.float64]) -> NDArray[np.float64]:
    """Adjoint of a rigid transform (3x3 in 2D, also a stack (..., 3, 3); 4x4 in 3D) acting on twists ordered
    (translation, rotation).

    ``exp(adjoint(T) @ xi) @ T == T @ exp(xi)`` to first order: it maps a motion in T's own (body) frame to the
    same motion applied in the outer frame.
    """
    T = np.asarray(T, dtype=float)
    if T.shape[-2:] == (3, 3):  # 2D, one transform or a stack of them (..., 3, 3)
        A = np.zeros(T.shape)
        A[..., :2, :2] = T[..., :2, :2]
        A[..., 0, 2], A[..., 1, 2], A[..., 2, 2] = T[..., 1, 2], -T[..., 0, 2], 1.0
        return A
    R, t = T[:3, :3], T[:3, 3]
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    A = np.zeros((6, 6))
    A[:3, :3] = R
    A[:3, 3:] = tx @ R
    A[3:, 3:] = R
    return A


def constrained_axes(translation_information: NDArray[np.float64], ratio: float = 0.05) -> NDArray[np.float64]:
    """The translation directions a registration's scene constrains: the unit eigenvectors (columns) of the
    information's translation block whose eigenvalue is at least ``ratio`` times the largest; none where the block
    holds no information. See :func:`drop_degenerate` for why directions below the ratio are not told from noise."""
    w, V = np.linalg.eigh(np.asarray(translation_information, dtype=float))
    if not w.max() > 0:
        return V[:, :0]
    return V[:, w >= ratio * w.max()]


def drop_degenerate(information: NDArray[np.float64], ratio: float = 0.05) -> NDArray[np.float64]:
    """Information with the translation directions the scene does not constrain removed.

    A translation direction whose eigenvalue (of the translation block) is below ``ratio`` times the largest one
    is treated as unconstrained (a featureless corridor's axis): normals estimated from a few noisy neighbours
    are tilted by several degrees, which alone gives every direction a few per cent of the largest eigenvalue
    (a tilt of 13 degrees gives 0.05), so information below that level cannot be told from noise. Its rows and
    columns (cross terms with the rotation included) are projected out.
    """
    info = np.asarray(information, dtype=float)
    dim = 2 if info.shape[0] == 3 else 3
    strong = constrained_axes(info[:dim, :dim], ratio)
    if not strong.shape[1]:
        return np.zeros_like(info)
    M = np.eye(info.shape[0])
    M[:dim, :dim] = strong @ strong.T
    return M @ info @ M
