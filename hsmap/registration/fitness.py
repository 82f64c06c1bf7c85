"""The two-term registration fitness of Harmony-ICP and its look-up back ends.

For a candidate pose T, a source cloud P = {p_i} (N points) and a target cloud Q, let
``d_i = min(dist(T p_i, Q), tau)`` be the nearest-neighbour distance truncated at the threshold ``tau``. The paper
scores a pose by (a) the sum of these distances and (b) the number of source points within ``tau`` of the target.
hsmap combines them into one value to minimise, each term normalised to [0, 1]::

    fitness = mean_i(d_i) / tau  +  w * (1 - inlier_ratio),    inlier_ratio = #{i : d_i < tau} / N

``w`` (``inlier_weight``, default 1) weighs the count term; with w = 0 the fitness is the plain truncated mean
distance. A perfect alignment of identical clouds scores 0; a pose that overlaps nothing scores 1 + w.

Two back ends compute ``d_i`` for a batch of B poses at once:

- :class:`DistanceField`: a precomputed grid (2D) or voxel volume (3D) of truncated distances, looked up with
  multilinear interpolation. Each node holds the exact distance from its centre to the nearest target point
  (within the truncation band), so look-ups are accurate well below a cell. This is the fast path.
- :class:`KDTreeLookup`: scipy's cKDTree, exact distances.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from .._threads import current_threads, helper_pool, start_threading_layer
from ..errors import InputError
from ..geometry import euler_to_matrix
from .neighbours import tree_query

__all__ = ["DistanceField", "KDTreeLookup", "FieldObjective", "transform_batch", "Fitness", "score", "field_bounds"]


def transform_batch(poses: NDArray[np.float64], points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Apply B pose vectors (B, 3) to (N, 2) points or (B, 6) to (N, 3) points: returns (B, N, d)."""
    poses = np.atleast_2d(poses)
    if points.shape[1] == 2:
        c = np.cos(poses[:, 2])[:, None]
        s = np.sin(poses[:, 2])[:, None]
        x, y = points[:, 0], points[:, 1]
        out = np.empty((poses.shape[0], points.shape[0], 2), dtype=points.dtype)
        out[..., 0] = c * x - s * y + poses[:, 0:1]
        out[..., 1] = s * x + c * y + poses[:, 1:2]
        return out
    R = euler_to_matrix(poses[:, 3], poses[:, 4], poses[:, 5]).astype(points.dtype)
    out = np.matmul(points, np.swapaxes(R, 1, 2))
    out += poses[:, None, :3].astype(points.dtype)
    return out


#: The most cells a :class:`DistanceField` allocates (float32: 1 GiB); a larger one is an input error.
MAX_FIELD_CELLS = 2**28


#: A 3D splat is split into slabs between the compute threads from this many node updates (points x cube of the
#: band): a keyframe's 2,000-5,000 new points in a 9-cell band are 1.5-3.6 million.
PARALLEL_MIN_SPLAT = 200_000


def field_bounds(points: NDArray[np.float64], resolution: float, truncation: float,
                 within: ArrayLike | None = None) -> NDArray[np.float64]:
    """[lower, upper] corners of a field of ``points``: their bounding box grown by the truncation and two cells
    (:class:`DistanceField`'s default), or the part of it that covers the box ``within`` = [lower, upper] and the
    cells its look-ups interpolate from. That part's lower corner is one of the default volume's nodes, so the
    nodes the two share lie at the same places (up to rounding) and hold the same distances: a field there answers
    as the whole one does inside ``within``."""
    margin = truncation + 2 * resolution
    lo, hi = points.min(axis=0) - margin, points.max(axis=0) + margin
    if within is None:
        return np.array([lo, hi])
    w = np.asarray(within, dtype=float)
    start = lo + np.maximum(np.floor((w[0] - lo) / resolution) - 2, 0.0) * resolution
    end = np.minimum(hi, w[1] + 2 * resolution)
    return np.array([lo, hi]) if np.any(end <= start) else np.array([start, end])


class DistanceField:
    """Truncated distance to a point set, precomputed on a regular grid (2D) or voxel volume (3D).

    The volume is indexed along the world axes, ``values[ix, iy(, iz)]`` (it is not an image), and padded by one
    cell of the truncation value so that points outside it read ``truncation``. Points can be added later
    (:meth:`add`): each new point lowers the nodes within the truncation band around it, so a map's field can
    grow scan by scan without being rebuilt.

    Parameters
    ----------
    points : ndarray of shape (M, d), d in {2, 3}
        Target points.
    resolution : float
        Cell size in metres.
    truncation : float
        Distances are clipped at this value (the fitness threshold).
    bounds : array_like of shape (2, d), optional
        [lower corner, upper corner] of the volume in world metres; default: the points' bounding box grown by
        the truncation and two cells (:func:`field_bounds`). Points outside the volume still lower the nodes
        inside it within the truncation of them; look-ups outside it read the truncation.
    normals : ndarray of shape (M, d), optional
        Unit normals of the points. The field then also keeps, per node, the nearest point and its normal:
        correspondences for a point-to-line (point-to-plane) refinement at the cost of one look-up
        (:func:`hsmap.registration.icp.refine_icp`). 2D: :attr:`nearest`, (nx, ny, 4) float32 (x, y, nx, ny), NaN
        where none is within the band; 3D: :attr:`nearest_index`, (nx, ny, nz) int32 rows of
        :attr:`nearest_points` and :attr:`nearest_normals` (-1 where none), a quarter of the memory.
    recycle : DistanceField, optional
        A field its owner no longer uses: its grid's memory is reused where it is large enough (a map's field
        rebuilt around the robot then touches no fresh memory), and that field is invalid afterwards.

    Notes
    -----
    Memory is one float32 per cell: a 40 m x 40 m floor at 2 cm is 4 M cells (16 MB).
    """

    def __init__(self, points: ArrayLike, resolution: float, truncation: float,
                 bounds: ArrayLike | None = None, normals: ArrayLike | None = None,
                 recycle: DistanceField | None = None) -> None:
        pts = np.asarray(points, dtype=float)
        if not resolution > 0:
            raise InputError(f"field resolution must be > 0 m, got {resolution}")
        if not truncation > 0:
            raise InputError(f"threshold must be > 0 m, got {truncation}")
        self.dim = pts.shape[1]
        self.resolution = float(resolution)
        self.truncation = float(truncation)
        if bounds is None:
            lo, hi = field_bounds(pts, resolution, truncation)
        else:
            lo, hi = np.asarray(bounds, dtype=float)
            if lo.shape != (self.dim,) or np.any(hi <= lo):
                raise InputError(f"field bounds must be [lower, upper] corners of {self.dim} values with "
                                 f"lower < upper, got {np.asarray(bounds).tolist()}")
        self.origin = lo
        with np.errstate(over="ignore", invalid="ignore"):
            cells = np.ceil((hi - lo) / resolution) + 1
            total = float(np.prod(cells + 2))
            span = hi - lo
        if not (np.all(np.isfinite(cells)) and total <= MAX_FIELD_CELLS):
            raise InputError(
                f"the target's points span {' x '.join(f'{v:.4g}' for v in span)} m: a distance field at "
                f"{resolution:g} m would need {total:.3g} cells, more than {MAX_FIELD_CELLS:.3g}; crop the target or "
                "use the KD-tree backend (RegistrationConfig(backend='kdtree'))")
        shape = cells.astype(int)
        self.shape = tuple(int(s) for s in shape)
        self._stores: dict[str, NDArray] = {}  # the grids' memory (the successor's too, where it recycles this)
        # Padded storage: one cell of `truncation` on every side; `values` is a view of the interior.
        self._padded = self._grid("padded", tuple(s + 2 for s in self.shape), np.float32(truncation), recycle)
        self.values = self._padded[(slice(1, -1),) * self.dim]
        self._strides = np.array([int(np.prod(self._padded.shape[i + 1 :])) for i in range(self.dim)])
        self._pshape = np.array(self._padded.shape)
        self._flat = self._padded.ravel()
        self._radius = int(np.ceil(truncation / resolution)) + 1
        self.nearest = None
        self.nearest_index = None
        self.nearest_points = np.empty((0, self.dim))
        self.nearest_normals = np.empty((0, self.dim))
        if normals is not None:
            if self.dim == 2:
                self.nearest = self._grid("nearest", self.shape + (4,), np.float32(np.nan), recycle)
            else:
                self.nearest_index = self._grid("nearest_index", self.shape, np.int32(-1), recycle)
        self.add(pts, normals)

    def _grid(self, name: str, shape: tuple[int, ...], fill: np.generic, recycle: DistanceField | None
              ) -> NDArray:
        """An array of ``shape`` and ``fill``'s type holding ``fill``, in ``recycle``'s grid of that name where it
        is large enough; a recycled grid grows with a quarter's margin (the next may be larger still)."""
        size = int(np.prod(shape))
        store = None if recycle is None else recycle._stores.get(name)
        if store is None or store.size < size or store.dtype != fill.dtype:
            store = np.empty(size if recycle is None else size + size // 4, dtype=fill.dtype)
        self._stores[name] = store
        out = store[:size].reshape(shape)
        out.fill(fill)
        return out

    @property
    def keeps_nearest(self) -> bool:
        """Whether the field keeps each node's nearest point and normal (it was built with normals)."""
        return self.nearest is not None or self.nearest_index is not None

    def add(self, points: ArrayLike, normals: ArrayLike | None = None) -> None:
        """Lower the field around new target points (N, d); points outside the volume are ignored.

        Each node within the truncation band of a point takes the exact distance from its centre to the point if
        that is smaller (cheaper than a Euclidean distance transform when only short distances matter).
        """
        from . import _kernels  # numba: compiled on first use

        pts = np.ascontiguousarray(points, dtype=float)
        if len(pts) == 0:
            return
        if self.keeps_nearest:
            if normals is None:
                raise InputError("this field keeps nearest points: add() needs their normals too")
            nrm = np.ascontiguousarray(normals, dtype=float)
            if nrm.shape != pts.shape:
                raise InputError(f"normals must have the shape of the points {pts.shape}, got {nrm.shape}")
            if self.nearest is not None:
                _kernels.splat_nearest_2d(pts, nrm, self.origin, self.resolution, self.values, self.nearest,
                                          self._radius)
                return
            offset = len(self.nearest_points)
            if offset + len(pts) > np.iinfo(np.int32).max:
                raise InputError(f"a nearest-point field holds at most {np.iinfo(np.int32).max} points")
            self.nearest_points = np.concatenate([self.nearest_points, pts])
            self.nearest_normals = np.concatenate([self.nearest_normals, nrm])
            _kernels.splat_nearest_index_3d(pts, self.origin, self.resolution, self.values, self.nearest_index,
                                            self._radius, offset)
            return
        if self.dim == 2:
            _kernels.splat_field_2d(pts, self.origin, self.resolution, self.values, self._radius)
            return

        # slabs along x, one per compute thread, each node lowered by one thread: the same field for any count
        t = current_threads() if len(pts) * (2 * self._radius + 1) ** 3 >= PARALLEL_MIN_SPLAT else 1
        cuts = np.linspace(0, self.shape[0], t + 1).astype(int)
        args = (pts, self.origin, self.resolution, self.values, self._radius, self.truncation)
        futures = [helper_pool(t - 1).submit(_kernels.splat_field_3d, *args, int(a), int(b))
                   for a, b in zip(cuts[1:-1], cuts[2:], strict=True)]
        _kernels.splat_field_3d(*args, 0, int(cuts[1]))
        for f in futures:
            f.result()

    def covers(self, lower: ArrayLike, upper: ArrayLike) -> bool:
        """Whether the box [lower, upper] (world metres) lies inside the volume."""
        top = self.origin + (np.asarray(self.shape) - 1) * self.resolution
        return bool(np.all(np.asarray(lower) >= self.origin) and np.all(np.asarray(upper) <= top))

    @property
    def nbytes(self) -> int:
        extra = sum(int(a.nbytes) for a in (self.nearest, self.nearest_index) if a is not None)
        return int(self._padded.nbytes) + extra

    def score_batch(self, poses: NDArray[np.float64], points: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
        """Mean truncated distance (B,) and inlier ratio (B,) of ``points`` moved by each of the B ``poses``."""
        from . import _kernels  # numba: compiled on first use

        start_threading_layer()
        poses = np.ascontiguousarray(poses, dtype=np.float64)
        points = np.ascontiguousarray(points, dtype=np.float64)
        mean = np.empty(poses.shape[0])
        inl = np.empty(poses.shape[0])
        _kernels.field_score(poses, points, self._flat, self._pshape, self.origin, 1.0 / self.resolution,
                             self.truncation, mean, inl)
        return mean, inl

    def __call__(self, points: NDArray[np.floating]) -> NDArray[np.float32]:
        """Truncated distances of points (..., d), multilinear between cell centres."""
        u = (points - self.origin) / self.resolution + 0.5  # +1 for the pad, -0.5 for cell centres
        base = np.floor(u)
        frac = (u - base).astype(np.float32)
        base = base.astype(np.int64)
        # keep all corners inside the padded array (points far outside read the padding)
        np.clip(base, 0, self._pshape - 2, out=base)
        lin = base @ self._strides
        out = np.zeros(points.shape[:-1], dtype=np.float32)
        for corner in range(1 << self.dim):
            offs = 0
            w = np.ones(points.shape[:-1], dtype=np.float32)
            for k in range(self.dim):
                if corner >> k & 1:
                    offs += self._strides[k]
                    w *= frac[..., k]
                else:
                    w *= 1.0 - frac[..., k]
            out += w * self._flat[lin + offs]
        return out


class KDTreeLookup:
    """Exact truncated nearest-neighbour distances with scipy's cKDTree (``workers``: query threads, scipy's
    meaning; None: hsmap's compute threads for large queries, :func:`hsmap.registration.neighbours.tree_query`)."""

    def __init__(self, points: ArrayLike, truncation: float, workers: int | None = 1) -> None:
        if not truncation > 0:
            raise InputError(f"threshold must be > 0 m, got {truncation}")
        self.points = np.asarray(points, dtype=float)
        self.tree = cKDTree(self.points)
        self.truncation = float(truncation)
        self.workers = workers

    def score_batch(self, poses: NDArray[np.float64], points: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
        """Mean truncated distance (B,) and inlier ratio (B,) of ``points`` moved by each of the B ``poses``."""
        d = self(transform_batch(poses, points))
        return d.mean(axis=1), (d < self.truncation * (1 - 1e-6)).mean(axis=1)

    def __call__(self, points: NDArray[np.floating]) -> NDArray[np.float64]:
        flat = points.reshape(-1, points.shape[-1])
        if self.workers is None:  # the compute threads for a large query
            d, _ = tree_query(self.tree, flat, distance_upper_bound=self.truncation)
        else:
            d, _ = self.tree.query(flat, k=1, distance_upper_bound=self.truncation, workers=self.workers)
        return np.minimum(d, self.truncation).reshape(points.shape[:-1])


class FieldObjective:
    """The two-term fitness of poses for ``source`` against a :class:`DistanceField`, as a Harmony Search
    objective with a compiled fast path: :func:`hsmap.registration.harmony.harmony_search` runs whole chunks of improvisation
    rounds in one call (:meth:`run_chunk`), with the same arithmetic as the Python loop.
    """

    def __init__(self, source: NDArray[np.float64], field: DistanceField, inlier_weight: float = 1.0) -> None:
        self.source = np.ascontiguousarray(source, dtype=np.float64)
        self.field = field
        self.inlier_weight = float(inlier_weight)

    def __call__(self, poses: NDArray[np.float64]) -> NDArray[np.float64]:
        return score(poses, self.source, self.field, self.inlier_weight).value

    def run_chunk(self, *args) -> None:
        from . import _kernels  # numba: compiled on first use
        start_threading_layer()
        f = self.field
        _kernels.hs_chunk_field(*args, self.source, f._flat, f._pshape, f.origin, 1.0 / f.resolution,
                                f.truncation, self.inlier_weight)

    def run_search(self, gen: np.random.Generator, memory: NDArray[np.float64], fun: NDArray[np.float64], *args
                   ) -> int:
        """A whole search (:func:`hsmap.registration._kernels.hs_search_field`) from the first ``memory``, which
        ends sorted, its values in ``fun``. Returns the rounds run."""
        from . import _kernels  # numba: compiled on first use
        start_threading_layer()
        f = self.field
        return int(_kernels.hs_search_field(gen, memory, fun, *args, np.empty(memory.shape[1]), self.source,
                                            f._flat, f._pshape, f.origin, 1.0 / f.resolution, f.truncation,
                                            self.inlier_weight))


@dataclass
class Fitness:
    """Scores of B poses: ``value`` (to minimise), ``mean_distance`` (m) and ``inlier_ratio``."""

    value: NDArray[np.float64]
    mean_distance: NDArray[np.float64]
    inlier_ratio: NDArray[np.float64]


def score(
    poses: ArrayLike,
    source: NDArray[np.floating],
    lookup: DistanceField | KDTreeLookup,
    inlier_weight: float = 1.0,
) -> Fitness:
    """The two-term fitness of a batch of poses (B, dof) for ``source`` (N, d) against a target look-up."""
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    mean_d, inliers = lookup.score_batch(poses, source)
    return Fitness(mean_d / lookup.truncation + inlier_weight * (1.0 - inliers), mean_d, inliers)
