"""Oriented boxes: the only solid the simulated worlds are made of, and the 2D geometry the checks need.

A box is a row ``(cx, cy, lx, ly, yaw, z0, z1)``: its footprint is a rectangle of size ``lx`` x ``ly`` centred at
``(cx, cy)`` and turned by ``yaw`` radians (``lx`` along the turned x axis); it spans heights ``z0`` to ``z1``.
Arrays of boxes have shape (B, 7). Everything here is plain numpy so that scenario checks need no open3d.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "make_box",
    "box_corners",
    "box_sdf",
    "boxes_overlap",
    "segment_box_distance",
    "boxes_to_mesh_arrays",
    "points_in_polygon",
]

# the 12 triangles of a box whose 8 corners are ordered as in boxes_to_mesh_arrays (outward normals)
_BOX_TRIANGLES = np.array(
    [
        [0, 2, 1], [0, 3, 2],  # bottom (z0)
        [4, 5, 6], [4, 6, 7],  # top (z1)
        [0, 1, 5], [0, 5, 4],
        [1, 2, 6], [1, 6, 5],
        [2, 3, 7], [2, 7, 6],
        [3, 0, 4], [3, 4, 7],
    ],
    dtype=np.int64,
)


def make_box(center: ArrayLike, size: ArrayLike, yaw: float = 0.0, z0: float = 0.0, z1: float = 1.0) -> NDArray:
    """One box row (7,) from its footprint centre (x, y), size (lx, ly), yaw (rad) and height span."""
    c = np.asarray(center, dtype=float)
    s = np.asarray(size, dtype=float)
    return np.array([c[0], c[1], s[0], s[1], float(yaw), float(z0), float(z1)])


def box_corners(boxes: ArrayLike) -> NDArray[np.float64]:
    """Footprint corners of boxes (B, 7) -> (B, 4, 2), counter-clockwise from (-lx/2, -ly/2)."""
    b = np.atleast_2d(np.asarray(boxes, dtype=float))
    hx, hy = b[:, 2] / 2, b[:, 3] / 2
    local = np.stack(
        [np.stack([-hx, -hy], -1), np.stack([hx, -hy], -1), np.stack([hx, hy], -1), np.stack([-hx, hy], -1)], 1
    )
    c, s = np.cos(b[:, 4]), np.sin(b[:, 4])
    R = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)  # (B, 2, 2)
    return np.einsum("bij,bkj->bki", R, local) + b[:, None, :2]


def box_sdf(points: ArrayLike, boxes: ArrayLike) -> NDArray[np.float64]:
    """Signed distance (P, B) from 2D points (P, 2) to box footprints (B, 7); negative inside."""
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    b = np.atleast_2d(np.asarray(boxes, dtype=float))
    d = p[:, None, :] - b[None, :, :2]
    c, s = np.cos(b[:, 4]), np.sin(b[:, 4])
    lx = d[..., 0] * c + d[..., 1] * s
    ly = -d[..., 0] * s + d[..., 1] * c
    qx = np.abs(lx) - b[:, 2] / 2
    qy = np.abs(ly) - b[:, 3] / 2
    outside = np.hypot(np.maximum(qx, 0.0), np.maximum(qy, 0.0))
    inside = np.minimum(np.maximum(qx, qy), 0.0)
    return outside + inside


def boxes_overlap(a: ArrayLike, b: ArrayLike, tol: float = 0.0) -> bool:
    """Whether two box footprints overlap by more than ``tol`` metres (separating-axis test)."""
    ca, cb = box_corners(a)[0], box_corners(b)[0]
    for corners in (ca, cb):
        for k in range(2):
            axis = corners[k + 1] - corners[k]
            axis = axis / np.linalg.norm(axis)
            pa, pb = ca @ axis, cb @ axis
            if min(pa.max(), pb.max()) - max(pa.min(), pb.min()) <= tol:
                return False
    return True


def segment_box_distance(p0: ArrayLike, p1: ArrayLike, boxes: ArrayLike) -> NDArray[np.float64]:
    """Exact distance (B,) from the segment p0-p1 to each box footprint (B, 7); 0 where they intersect."""
    b = np.atleast_2d(np.asarray(boxes, dtype=float))
    p0 = np.asarray(p0, dtype=float)
    p1 = np.asarray(p1, dtype=float)
    c, s = np.cos(b[:, 4]), np.sin(b[:, 4])

    def to_local(p):
        d = p[None, :] - b[:, :2]
        return np.stack([d[:, 0] * c + d[:, 1] * s, -d[:, 0] * s + d[:, 1] * c], -1)

    a, e = to_local(p0), to_local(p1)
    h = b[:, 2:4] / 2
    # Liang-Barsky clipping of the segment against [-h, h]: intersection when the clipped interval is non-empty
    d = e - a
    t0 = np.zeros(len(b))
    t1 = np.ones(len(b))
    hit = np.ones(len(b), dtype=bool)
    for k in range(2):
        for sign in (-1.0, 1.0):
            pk = sign * d[:, k]
            qk = h[:, k] - sign * a[:, k]
            parallel = np.abs(pk) < 1e-15
            hit &= ~(parallel & (qk < 0))
            with np.errstate(divide="ignore", invalid="ignore"):
                r = np.where(parallel, 0.0, qk / np.where(parallel, 1.0, pk))
            t1 = np.where(~parallel & (pk > 0), np.minimum(t1, r), t1)
            t0 = np.where(~parallel & (pk < 0), np.maximum(t0, r), t0)
    hit &= t0 <= t1

    def point_box(q):  # distance from local points (B, 2) to their box
        qq = np.abs(q) - h
        return np.hypot(np.maximum(qq[:, 0], 0), np.maximum(qq[:, 1], 0))

    dist = np.minimum(point_box(a), point_box(e))
    # box corners to the segment
    seg = e - a
    L2 = np.maximum((seg**2).sum(1), 1e-30)
    for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
        corner = np.stack([sx * h[:, 0], sy * h[:, 1]], -1)
        t = np.clip(((corner - a) * seg).sum(1) / L2, 0.0, 1.0)
        proj = a + t[:, None] * seg
        dist = np.minimum(dist, np.linalg.norm(corner - proj, axis=1))
    return np.where(hit, 0.0, dist)


def boxes_to_mesh_arrays(boxes: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Vertices (8B, 3) and triangles (12B, 3) of solid boxes (B, 7)."""
    b = np.atleast_2d(np.asarray(boxes, dtype=float))
    foot = box_corners(b)  # (B, 4, 2)
    low = np.concatenate([foot, np.broadcast_to(b[:, None, 5:6], (len(b), 4, 1))], -1)
    high = np.concatenate([foot, np.broadcast_to(b[:, None, 6:7], (len(b), 4, 1))], -1)
    verts = np.concatenate([low, high], 1).reshape(-1, 3)
    tris = (_BOX_TRIANGLES[None, :, :] + 8 * np.arange(len(b))[:, None, None]).reshape(-1, 3)
    return verts, tris


def points_in_polygon(points: ArrayLike, polygon: ArrayLike) -> NDArray[np.bool_]:
    """Whether 2D points (P, 2) lie inside a simple polygon (K, 2) (even-odd rule; edges count as either)."""
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    poly = np.asarray(polygon, dtype=float)
    x, y = p[:, 0], p[:, 1]
    inside = np.zeros(len(p), dtype=bool)
    for (x0, y0), (x1, y1) in zip(poly, np.roll(poly, -1, axis=0), strict=True):
        crosses = (y0 > y) != (y1 > y)
        if not crosses.any():
            continue
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
        inside ^= crosses & (x < xc)
    return inside
