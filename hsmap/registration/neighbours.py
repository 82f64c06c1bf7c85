"""Exact nearest neighbours within a distance bound, on a dense voxel grid (2D or 3D).

The refinement of every registration asks one question thousands of times a second: for each moved source point,
the nearest target point closer than the trimming distance. :class:`NeighbourGrid` answers it as scipy's
``cKDTree.query(points, k=1, distance_upper_bound=bound)`` does, bit for bit (the same distances, the same rows;
``inf`` and ``len(points)`` where none is within the bound; of points at exactly the same distance, the lowest
row, where the tree answers whichever its walk met first), but looks only at the few cells within the bound of
each point instead of walking a tree: on the 6-DOF route's local maps (10-50 thousand points, 4,000 queries at
0.1-0.2 m) a query takes a fifth of the tree's time, and building the grid costs less than building the tree.

Like KISS-ICP's voxel hash, the grid holds the points themselves, sorted by cell (a counting sort); unlike it, the
answer is exact: every cell that can hold a point within the bound is searched. The cells are a dense array over
the points' bounding box, so the grid is for local maps and scans, not for a whole building at a fine cell:
:func:`grid_fits` says whether a point set fits, and callers fall back to the KD-tree where it does not
(:meth:`hsmap.registration.icp.RegistrationTarget.nearest`).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from .._threads import current_threads, helper_pool
from ..errors import InputError, ShapeError

__all__ = ["NeighbourGrid", "TrackedQuery", "grid_fits", "tree_query", "MAX_CELLS", "MAX_CELLS_PER_POINT"]

#: At most this many cells in a grid (4 bytes each: 128 MB)...
MAX_CELLS = 1 << 25
#: ... and at most this many per point (a grid's memory and build time grow with its cells, not its points).
MAX_CELLS_PER_POINT = 64

#: Queries of at least this many points are split between the compute threads (each point's answer is its own,
#: so the result does not depend on the number of threads). A grid answers 4,000 points in about 0.3 ms on one
#: thread: below this, handing half to another thread costs about what it saves.
PARALLEL_MIN_QUERIES = 2000


def _grid_shape(points: NDArray[np.float64], cell: float) -> tuple[NDArray[np.float64], NDArray[np.int64], float]:
    """(origin, cells per axis, total cells) of a grid of side ``cell`` over the points' bounding box."""
    from . import _kernels  # numba: compiled on first use

    if len(points) == 0:
        return np.zeros(points.shape[1]), np.ones(points.shape[1], dtype=np.int64), 1.0
    lo, hi = _kernels.bounding_box(np.ascontiguousarray(points, dtype=np.float64))
    with np.errstate(over="ignore", invalid="ignore"):
        span = np.floor((hi - lo) / cell) + 1
    total = float(np.prod(span)) if np.all(np.isfinite(span)) else float("inf")
    dims = span.astype(np.int64) if np.isfinite(total) else np.ones(points.shape[1], dtype=np.int64)
    return lo, dims, total


def grid_fits(points: NDArray[np.float64], cell: float) -> bool:
    """Whether a :class:`NeighbourGrid` of side ``cell`` over ``points`` stays within :data:`MAX_CELLS` and
    :data:`MAX_CELLS_PER_POINT`."""
    _, _, total = _grid_shape(points, cell)
    return total <= min(MAX_CELLS, MAX_CELLS_PER_POINT * max(len(points), 1024))


class NeighbourGrid:
    """Points (M, 2) or (M, 3) sorted into a dense grid of cubic (square) cells of side ``cell`` metres.

    A query with bound b searches the cells within b of each point: (2b / cell + 2) cells per axis at most, so a
    cell of about the usual bound (the refinement's trimming distance) keeps queries cheap; any finite bound is
    answered exactly.

    Raises
    ------
    ShapeError
        ``points`` is not (M, 2) or (M, 3).
    InputError
        ``cell`` is not > 0, a point is not finite, or the grid would exceed :data:`MAX_CELLS` (see
        :func:`grid_fits`).
    """

    def __init__(self, points: ArrayLike, cell: float) -> None:

        from . import _kernels  # numba: compiled on first use
        pts = np.ascontiguousarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] not in (2, 3):
            raise ShapeError(f"grid points must have shape (M, 2) or (M, 3), got {pts.shape}")
        if not (np.isfinite(cell) and cell > 0):
            raise InputError(f"grid cell must be a finite size > 0 m, got {cell}")
        if not np.all(np.isfinite(pts)):
            raise InputError("grid points must be finite (no NaN or inf)")
        if len(pts) >= np.iinfo(np.int32).max:
            raise InputError(f"a neighbour grid holds fewer than {np.iinfo(np.int32).max} points, got {len(pts)}")
        origin, dims, total = _grid_shape(pts, cell)
        if total > MAX_CELLS:
            raise InputError(f"a neighbour grid of {cell:g} m cells over these points would need {total:.3g} cells, "
                             f"more than {MAX_CELLS}; use a KD-tree")
        self.points = pts
        self.dim = pts.shape[1]
        self.cell = float(cell)
        self.origin = origin
        self.dims = dims
        self._inv = 1.0 / self.cell
        self._sorted, self._order, self._start = _kernels.grid_build(pts, origin, self._inv, dims)
        self._rank: NDArray[np.int64] | None = None  # each row's place in the sorted points, for hints
        self._sorted_values: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None
        self._kernel = _kernels.grid_nearest

    def __len__(self) -> int:
        return len(self.points)

    def query(self, points: ArrayLike, distance_upper_bound: float, hint: ArrayLike | None = None
              ) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
        """Distance to the nearest grid point closer than ``distance_upper_bound`` and its row, per point (N, d):
        ``inf`` and ``len(self)`` where none is (cKDTree's answer, bit for bit, but for exact ties: the lowest
        row here). Large queries are split between the compute threads (:func:`hsmap._threads.current_threads`);
        the answer does not depend on how many.

        ``hint`` (N,): a row near each point (any other value: none), e.g. the answer of a query from nearby
        (an ICP iteration's); it narrows the search without changing the answer."""
        q = np.ascontiguousarray(points, dtype=np.float64)
        if q.ndim != 2 or q.shape[1] != self.dim:
            raise ShapeError(f"query points must have shape (N, {self.dim}), got {q.shape}")
        bound = float(distance_upper_bound)
        if not (bound > 0 and math.isfinite(bound)):
            raise InputError(f"distance_upper_bound must be a finite distance > 0 m, got {distance_upper_bound}")
        n = len(q)
        d = np.empty(n)
        idx = np.empty(n, dtype=np.intp)
        args = (self._sorted, self._order, self._start, self.origin, self._inv, self.dims, q, bound,
                self._hint_places(hint, n), d, idx)
        t = current_threads()
        if t <= 1 or n < PARALLEL_MIN_QUERIES:
            self._kernel(*args, 0, n)
            return d, idx
        cuts = np.linspace(0, n, t + 1).astype(int)
        pool = helper_pool(t - 1)
        futures = [pool.submit(self._kernel, *args, int(a), int(b)) for a, b in zip(cuts[1:-1], cuts[2:], strict=True)]
        self._kernel(*args, 0, int(cuts[1]))
        for f in futures:
            f.result()
        return d, idx

    def _hint_places(self, hint: ArrayLike | None, n: int) -> NDArray[np.int64]:
        """The hinted rows' places in the sorted points (-1: no hint), (n,)."""
        if hint is None:
            return np.full(n, -1, dtype=np.int64)
        h = np.asarray(hint)
        if h.shape != (n,) or not np.issubdtype(h.dtype, np.integer):
            raise ShapeError(f"hint must be ({n},) whole numbers (rows of the grid's points), got {h.dtype} {h.shape}")
        from . import _kernels  # numba: compiled on first use

        return _kernels.hint_places(h, self.rank())

    def rank(self) -> NDArray[np.int64]:
        """Each row's place in the grid's sorted points (M,), built on first use."""
        if self._rank is None:
            self._rank = np.empty(len(self.points), dtype=np.int64)
            self._rank[self._order] = np.arange(len(self.points))
        return self._rank

    def polish_2d(self, source: NDArray[np.float64], T: NDArray[np.float64], bound: float, iterations: int,
                  tolerance: float, kernel: float, normals: NDArray[np.float64], hint: NDArray[np.intp] | None
                  ) -> NDArray[np.float64]:
        """Point-to-line ICP of the 2D ``source`` from the 3x3 transform ``T`` on this grid's points and their
        ``normals``, exact correspondences within ``bound`` (:func:`hsmap.registration._kernels.polish_on_grid_2d`):
        the refined transform. ``hint`` (N,): rows near the moved points (None: none)."""
        from . import _kernels  # numba: compiled on first use

        h = np.full(len(source), -1, dtype=np.intp) if hint is None else hint
        return _kernels.polish_on_grid_2d(source, T, self._sorted, self._order, self._start, self.origin, self._inv,
                                          self.dims, self.rank(), h, float(bound), int(iterations), float(tolerance),
                                          float(kernel), self.points, normals)

    def icp_3d(self, source: NDArray[np.float64], T: NDArray[np.float64], schedule: NDArray[np.float64],
               per_stage: int, tolerance: float, kernel: float, normals: NDArray[np.float64],
               hint: NDArray[np.intp] | None) -> NDArray[np.float64]:
        """Trimmed point-to-plane ICP of the 3D ``source`` from the 4x4 transform ``T`` on this grid's points and
        their ``normals``, exact correspondences within each distance of ``schedule`` in turn, ``per_stage``
        iterations at most each (:func:`hsmap.registration._kernels.icp_on_grid_3d`): the refined transform.
        ``hint`` (N,): rows near the moved points (None: none)."""
        from . import _kernels  # numba: compiled on first use

        places = self._hint_places(hint, len(source))
        return _kernels.icp_on_grid_3d(source, T, self._sorted, self._order, self._start, self.origin, self._inv,
                                       self.dims, places, np.asarray(schedule, dtype=float), int(per_stage),
                                       float(tolerance), float(kernel), self.sorted_like(normals),
                                       _kernels.CERTIFY_MARGIN)

    def sorted_like(self, values: NDArray[np.float64]) -> NDArray[np.float64]:
        """Per-row ``values`` (M, k) in the order of the grid's sorted points (the last array asked for is kept)."""
        kept = self._sorted_values
        if kept is None or kept[0] is not values:
            kept = self._sorted_values = (values, np.ascontiguousarray(values[self._order], dtype=np.float64))
        return kept[1]


#: KD-tree queries of at least this many points are split between the compute threads
#: (:func:`hsmap._threads.current_threads`); each point's answer is its own, so the result does not depend on the
#: number of threads. Smaller ones stay on the calling thread (250 points: 0.10 ms alone, 0.11 ms split in two;
#: 500: 0.21 and 0.15 ms).
TREE_PARALLEL_MIN_QUERIES = 500


def tree_query(tree: cKDTree, points: NDArray[np.float64], *, k: int = 1,
               distance_upper_bound: float = np.inf) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """``tree.query(points, k, distance_upper_bound=...)``, split between the compute threads for a large query.

    The calling thread answers the first share and :func:`hsmap._threads.helper_pool`'s threads the others
    (cKDTree releases the GIL); the answers are the same, bit for bit, whatever the number of threads.
    """
    t = current_threads()
    if t <= 1 or len(points) < TREE_PARALLEL_MIN_QUERIES:
        return tree.query(points, k=k, distance_upper_bound=distance_upper_bound)
    parts = np.array_split(points, t)
    pool = helper_pool(t - 1)
    futures = [pool.submit(tree.query, part, k=k, distance_upper_bound=distance_upper_bound) for part in parts[1:]]
    answers = [tree.query(parts[0], k=k, distance_upper_bound=distance_upper_bound)]
    answers += [f.result() for f in futures]
    return np.concatenate([d for d, _ in answers]), np.concatenate([i for _, i in answers])


class TrackedQuery:
    """Nearest neighbours within a bound, from a KD-tree, of points that move a little between queries (an ICP's
    source points, iteration by iteration): ``tree_query(tree, moved, distance_upper_bound=bound)``'s answer,
    bit for bit, but for exact ties.

    Each point's search looks ``margin`` metres beyond the bound (its two nearest points); a later query searches
    the point again only when it may have moved so far that another point could be its nearest, and otherwise
    takes the nearest it knows, its distance summed as the tree sums it.
    """

    def __init__(self, tree: cKDTree, margin: float) -> None:
        self.tree = tree
        self.points = np.asarray(tree.data, dtype=np.float64)
        self.margin = float(margin)
        self._ref: NDArray[np.float64] | None = None  # where each point was last searched ...
        self._row: NDArray[np.intp] | None = None  # ... its nearest row there (len(points): none within reach)
        self._clear: NDArray[np.float64] | None = None  # ... and how far from there no other row lies

    def __call__(self, moved: NDArray[np.float64], bound: float) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
        """Distance to the nearest point closer than ``bound`` and its row, per moved point (N, d); ``inf`` and
        ``len(points)`` where none is. ``moved`` holds the same points as at the previous call, in the same order."""
        n = len(self.points)
        if self._ref is None or len(self._ref) != len(moved):
            again = np.arange(len(moved))
            self._ref = np.empty_like(moved)
            self._row = np.full(len(moved), n, dtype=np.intp)
            self._clear = np.zeros(len(moved))
        else:
            lim = self._clear - np.sqrt(((moved - self._ref) ** 2).sum(1)) - 1e-9  # a nanometre spares the rounding
            known = self._row < n
            s2 = self._squared(moved, self._row)
            keep = np.where(known, (lim > 0) & (s2 < lim * lim), lim >= bound)
            again = np.flatnonzero(~keep)
        if len(again):
            reach = bound + self.margin
            d, i = tree_query(self.tree, moved[again], k=2, distance_upper_bound=reach)
            self._ref[again] = moved[again]
            self._row[again] = np.where(np.isfinite(d[:, 0]), i[:, 0], n)
            self._clear[again] = np.where(np.isfinite(d[:, 1]), d[:, 1], reach)
        s2 = self._squared(moved, self._row)
        found = (self._row < n) & (s2 < bound * bound)
        return np.where(found, np.sqrt(s2), np.inf), np.where(found, self._row, n)

    def _squared(self, moved: NDArray[np.float64], rows: NDArray[np.intp]) -> NDArray[np.float64]:
        """Squared distances of the moved points to the rows (any where a row is len(points)), summed over the
        axes in order as the tree sums them."""
        e = moved - self.points[np.minimum(rows, len(self.points) - 1)]
        s2 = e[:, 0] * e[:, 0] + e[:, 1] * e[:, 1]
        for k in range(2, e.shape[1]):
            s2 += e[:, k] * e[:, k]
        return s2
