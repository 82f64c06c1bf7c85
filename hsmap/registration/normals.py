"""Surface normals of point clouds: estimated from the neighbours' principal axes, turned to face the sensor."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from .._blas import blas_limited

__all__ = ["estimate_normals", "orient_normals", "load_3d_estimator"]


def orient_normals(points: NDArray[np.float64], normals: NDArray[np.float64],
                   viewpoint: ArrayLike | None = None) -> NDArray[np.float64]:
    """``normals`` turned to face ``viewpoint`` (default: the origin), the sensor that saw ``points``.

    A surface is seen from one side: a sensor-facing normal says which, so that a match can tell a wall's face
    from the face behind it, seen from the next room (:func:`hsmap.slam.loopclosure.same_side_share`). Only the signs
    change, which no point-to-plane residual or information sees.
    """
    pts = np.asarray(points, dtype=float)
    vp = np.zeros(pts.shape[1]) if viewpoint is None else np.asarray(viewpoint, dtype=float)
    out = np.array(normals, dtype=float, copy=True)
    out[np.einsum("ij,ij->i", out, vp - pts) < 0] *= -1.0
    return out


def load_3d_estimator() -> None:
    """Import the 3D estimator's library (Open3D, some seconds) now, not in the first 3D :func:`estimate_normals`."""
    import open3d  # noqa: F401


@blas_limited
def estimate_normals(points: NDArray[np.float64], k: int | None = None,
                     tree: cKDTree | None = None) -> NDArray[np.float64]:
    """Unit normals of points (N, 2) or (N, 3) from the principal axes of their k nearest neighbours.

    2D: the normal is across the principal axis of the 2x2 covariance (closed form); 3D: Open3D's estimator
    (the eigenvector of the smallest eigenvalue), oriented arbitrarily.
    """
    dim = points.shape[1]
    if dim == 3:
        import open3d as o3d

        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(k or 12))
        return np.asarray(pc.normals).copy()
    k = min(k or 8, len(points))
    tree = tree if tree is not None else cKDTree(points)
    _, idx = tree.query(points, k=k)
    nb = points[idx.reshape(len(points), -1)]
    nb = nb - nb.mean(axis=1, keepdims=True)
    cxx = (nb[..., 0] ** 2).sum(1)
    cyy = (nb[..., 1] ** 2).sum(1)
    cxy = (nb[..., 0] * nb[..., 1]).sum(1)
    a = 0.5 * np.arctan2(2 * cxy, cxx - cyy) + np.pi / 2  # principal axis at 0.5*atan2(2cxy, cxx-cyy)
    return np.column_stack([np.cos(a), np.sin(a)])
