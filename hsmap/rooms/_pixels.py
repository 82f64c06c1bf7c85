"""The pixel-grid primitives of the room segmentation's steps (:mod:`hsmap.rooms._steps`): neighbourhoods, the
skeleton's graph and its geodesic filter, marching along a direction, basis points, the pixels of a line, a
union-find over labels and the borders between regions. Images are (row, col)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage as ndi

from ._kernels import basis_points, line_pixels

FOUR = ndi.generate_binary_structure(2, 1)
EIGHT = np.ones((3, 3), dtype=bool)
OFFSETS = np.array([(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)])


def skeleton_graph(skel: NDArray[np.bool_]) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """Skeleton pixels (N,) rows, cols and their (N, 8) neighbour indices (-1: none)."""
    rr, cc = np.nonzero(skel)
    index = np.full(skel.shape, -1, dtype=np.int64)
    index[rr, cc] = np.arange(len(rr))
    H, W = skel.shape
    nbr = np.full((len(rr), 8), -1, dtype=np.int64)
    for k, (dr, dc) in enumerate(OFFSETS):
        r2, c2 = rr + dr, cc + dc
        ok = (r2 >= 0) & (r2 < H) & (c2 >= 0) & (c2 < W)
        nbr[ok, k] = index[r2[ok], c2[ok]]
    return rr, cc, nbr


def geodesic_filter(values: NDArray[np.float64], nbr: NDArray[np.int64], steps: int, op) -> NDArray[np.float64]:
    """min/max of ``values`` within ``steps`` hops on the skeleton graph (stops early once nothing changes)."""
    fill = np.inf if op is np.minimum else -np.inf
    m = values.copy()
    for _ in range(min(steps, len(values))):
        ext = np.append(m, fill)
        red = ext[nbr].min(axis=1) if op is np.minimum else ext[nbr].max(axis=1)
        new = op(m, red)
        if np.array_equal(new, m):
            break
        m = new
    return m


def march(free: NDArray[np.bool_], start: NDArray[np.float64], direction: NDArray[np.float64],
           max_steps: int) -> NDArray[np.int64] | None:
    """First non-free pixel (row, col) from ``start`` along ``direction`` (unit, pixels), or None."""
    t = np.arange(1, 2 * max_steps + 1) * 0.5
    pts = start[None, :] + t[:, None] * direction[None, :]
    idx = np.floor(pts + 0.5).astype(np.int64)
    H, W = free.shape
    inside = (idx[:, 0] >= 0) & (idx[:, 0] < H) & (idx[:, 1] >= 0) & (idx[:, 1] < W)
    if not inside.all():
        idx = idx[: int(np.argmin(inside))] if not inside[0] else idx[inside.cumprod().astype(bool)]
    if not len(idx):
        return None
    hit = ~free[idx[:, 0], idx[:, 1]]
    if not hit.any():
        return None
    return idx[int(np.argmax(hit))]


def basis_points_at(free: NDArray[np.bool_], p: NDArray[np.int64], radius: int, clearance: float = np.inf,
                  min_angle: float = np.deg2rad(110)) -> tuple[NDArray[np.int64] | None, NDArray[np.int64] | None]:
    """The two obstacle pixels a critical line joins: the nearest one to ``p`` and the nearest one seen from
    ``p`` at least ``min_angle`` away from the first (on the other side of the passage); None if absent
    within ``radius`` pixels. ``clearance``, the distance from ``p`` to the nearest obstacle if known, only
    speeds the search up."""
    ir, ic, jr, jc = basis_points(free, int(p[0]), int(p[1]), int(radius), float(np.cos(min_angle)),
                                  float(min(clearance, radius)))
    if ir < 0:
        return None, None
    return np.array([ir, ic], dtype=np.int64), np.array([jr, jc], dtype=np.int64)


def line_pixels_between(a: NDArray[np.int64], b: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """4-connected pixel line from a to b (rows, cols), so that 4-connected regions cannot leak through."""
    return line_pixels(int(a[0]), int(a[1]), int(b[0]), int(b[1]))


class UnionFind:
    def __init__(self, n: int) -> None:
        self.parent = np.arange(n)

    def find(self, a: int) -> int:
        p = self.parent
        root = a
        while p[root] != root:
            root = p[root]
        while p[a] != root:
            p[a], a = root, p[a]
        return int(root)

    def union(self, a: int, b: int) -> int:
        ra, rb = self.find(a), self.find(b)
        if ra != rb:
            self.parent[rb] = ra
        return ra


def region_borders(labels: NDArray[np.int64]) -> dict[tuple[int, int], int]:
    """Number of 4-adjacent pixel pairs between every two different positive labels."""
    pairs = []
    for a, b in ((labels[:, :-1], labels[:, 1:]), (labels[:-1, :], labels[1:, :])):
        m = (a != b) & (a > 0) & (b > 0)
        lo = np.minimum(a[m], b[m])
        hi = np.maximum(a[m], b[m])
        pairs.append(np.stack([lo, hi], 1))
    allp = np.concatenate(pairs)
    if not len(allp):
        return {}
    u, c = np.unique(allp, axis=0, return_counts=True)
    return {(int(x), int(y)): int(n) for (x, y), n in zip(u, c, strict=True)}
