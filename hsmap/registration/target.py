"""The cloud registered against (:class:`RegistrationTarget`): its points cleaned and checked for spread, its
normals and its distance look-up, built once and reused across registrations."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from ..errors import DegenerateInputError, EmptyInputError, ShapeError
from ..maps.mapping import voxel_downsample
from .config import Backend, Refinement, RegistrationConfig
from .fitness import DistanceField, KDTreeLookup, field_bounds
from .neighbours import NeighbourGrid, grid_fits, tree_query
from .normals import estimate_normals


def _clean_cloud(points: ArrayLike, name: str, dim: int | None = None) -> tuple[NDArray[np.float64], int]:
    try:
        arr = np.asarray(points, dtype=float)
    except (TypeError, ValueError):
        raise ShapeError(f"{name} must be a numeric array of shape (N, 2) or (N, 3)") from None
    if arr.ndim != 2 or arr.shape[1] not in (2, 3):
        raise ShapeError(f"{name} must have shape (N, 2) or (N, 3), got {arr.shape}")
    if dim is not None and arr.shape[1] != dim:
        raise ShapeError(f"{name} has {arr.shape[1]} columns but the other cloud has {dim}: "
                         f"both must be 2D (N, 2) or both 3D (N, 3)")
    if arr.shape[0] == 0:
        raise EmptyInputError(f"{name} is empty: expected at least one point")
    if np.isfinite(arr).all():
        return arr, 0
    ok = np.all(np.isfinite(arr), axis=1)
    dropped = int((~ok).sum())
    if dropped:
        arr = arr[ok]
        if arr.shape[0] == 0:
            raise EmptyInputError(f"{name} has no finite points: all {dropped} contain NaN or inf")
    return arr, dropped


def _check_spread(arr: NDArray[np.float64], name: str) -> None:
    """DegenerateInputError naming ``name`` when its (finite) points do not span the plane (2D) or space (3D)."""
    if not spans_its_space(arr):
        d = arr.shape[1]
        where = "on one line" if d == 2 else "on one plane"
        raise DegenerateInputError(
            f"{name} cannot be registered: its {len(arr)} finite points "
            f"{'coincide' if not spans_its_space(arr, 1) else 'all lie ' + where}; a {d}D registration needs points "
            f"that span the {'plane' if d == 2 else 'space'} (at least {d + 1} not {where})")


def spans_its_space(points: NDArray[np.float64], rank: int | None = None) -> bool:
    """Whether finite points (N, d) span ``rank`` dimensions (default d): not all equal, not all on one line
    (2D), not all on one plane (3D), up to rounding (the smallest spread is below 1e-9 of the largest).

    A cloud that does not span its space has no unique registration: it can slide or turn without changing its
    fit (:func:`harmony_icp` raises :class:`~hsmap.errors.DegenerateInputError` for one).
    """
    from . import _kernels  # numba: compiled on first use
    pts = np.ascontiguousarray(points, dtype=float)
    d = pts.shape[1]
    rank = d if rank is None else rank
    if len(pts) < rank + 1:
        return False
    return bool(_kernels.spans_rank(pts, rank))


class RegistrationTarget:
    """A target cloud prepared for repeated registrations (distance fields, KD-tree, normals built once).

    Parameters
    ----------
    points : array_like of shape (M, 2) or (M, 3)
    config : RegistrationConfig, optional
    normals : array_like of shape (M, 2) or (M, 3), optional
        Unit normals of the points, when known (otherwise estimated on first use by PCA of neighbourhoods).
    fields : dict of float to DistanceField, optional
        Distance fields already built for given truncations (e.g. a map's field grown scan by scan).
    field_within : array_like of shape (2, d), optional
        [lower, upper] corners of the box that the registrations' transformed source points stay in: the fields
        built here cover only that box (:func:`hsmap.registration.fitness.field_bounds`), and answer as whole ones there.
    """

    def __init__(self, points: ArrayLike, config: RegistrationConfig | None = None, *,
                 normals: ArrayLike | None = None, fields: dict[float, DistanceField] | None = None,
                 field_within: ArrayLike | None = None) -> None:
        self.config = config or RegistrationConfig()
        self.points, self.dropped = _clean_cloud(points, "target")
        _check_spread(self.points, "target")
        self.dim = self.points.shape[1]
        self._lookups: dict[float, DistanceField | KDTreeLookup] = dict(fields or {})
        self._field_within = None if field_within is None else np.asarray(field_within, dtype=float)
        self._tree: cKDTree | None = None
        self._grid: NeighbourGrid | None | bool = None  # False: the points do not fit a grid
        self._normals: NDArray[np.float64] | None = None
        self._voxelised: dict[float, RegistrationTarget] = {}
        if normals is not None:
            n = np.asarray(normals, dtype=float)
            if n.shape != self.points.shape or self.dropped:
                raise ShapeError(f"target normals must have the shape of the (finite) points {self.points.shape}, "
                                 f"got {n.shape}")
            self._normals = n

    def voxelised(self, voxel: float) -> RegistrationTarget:
        """This target averaged in voxels of side ``voxel`` (:func:`hsmap.maps.mapping.voxel_downsample`), as a target
        of its own with its own normals; built on first use, then cached."""
        cached = self._voxelised.get(voxel)
        if cached is None:
            pts = voxel_downsample(self.points, voxel)
            cached = self if len(pts) == len(self.points) or not spans_its_space(pts) else \
                RegistrationTarget(pts, self.config)
            self._voxelised[voxel] = cached
        return cached

    def lookup(self, truncation: float) -> DistanceField | KDTreeLookup:
        """The distance look-up for a truncation distance (built on first use, then cached)."""
        lk = self._lookups.get(truncation)
        if lk is None:
            if self.config.backend is Backend.FIELD:
                res = self.config.field_resolution
                if res is None:
                    res = max(0.02, truncation / 10.0) if self.dim == 2 else truncation / 4.0
                # 2D: keep nearest points too, for the point-to-line refinement's correspondences
                plane = self.dim == 2 and self.config.refinement is Refinement.POINT_TO_PLANE
                bounds = (None if self._field_within is None
                          else field_bounds(self.points, res, truncation, self._field_within))
                lk = DistanceField(self.points, res, truncation, bounds=bounds,
                                   normals=self.normals if plane else None)
            else:
                lk = KDTreeLookup(self.points, truncation)
            self._lookups[truncation] = lk
        return lk

    def nearest_field(self, reach: float) -> DistanceField | None:
        """A field of this target that keeps nearest points and reaches at least ``reach`` metres, if any."""
        best = None
        for lk in self._lookups.values():
            if (isinstance(lk, DistanceField) and lk.keeps_nearest and lk.truncation >= reach
                    and (best is None or lk.resolution < best.resolution)):
                best = lk
        return best

    def prepare(self) -> NeighbourGrid | bool:
        """Build the neighbour grid of :meth:`nearest` now rather than on the first query (False: the target
        does not fit one, :func:`hsmap.registration.neighbours.grid_fits`)."""
        if self._grid is None:
            cell = 2.0 * self.config.threshold
            self._grid = NeighbourGrid(self.points, cell) if grid_fits(self.points, cell) else False
        return self._grid

    def nearest(self, points: NDArray[np.float64], bound: float, hint: NDArray[np.intp] | None = None
                ) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
        """Nearest target point of each point (N, d) closer than ``bound``: (distance, row), ``inf`` and
        ``len(self.points)`` where none is; cKDTree's answer, bit for bit, except that of points at exactly the
        same distance the lowest row is the answer wherever it comes from.

        Answered by a :class:`hsmap.registration.neighbours.NeighbourGrid` of cells twice the configured ``threshold`` (the
        refinement's trimming distances) where the target fits one and ``bound`` is at most two cells, else by
        the KD-tree; large queries are split between the compute threads either way. ``hint`` (N,): rows near
        the points (a previous answer), which speed the grid's search and change no answer.
        """
        grid = self.prepare()
        if grid is not False and bound <= 2.0 * grid.cell:
            return grid.query(points, bound, hint)
        return tree_query(self.tree, points, distance_upper_bound=bound)

    def grid_for(self, bound: float) -> NeighbourGrid | None:
        """The neighbour grid that answers :meth:`nearest` within ``bound``, or None where the KD-tree does."""
        grid = self.prepare()
        return grid if grid is not False and bound <= 2.0 * grid.cell else None

    @property
    def tree(self) -> cKDTree:
        if self._tree is None:
            # sliding-midpoint splits: half the build time of a balanced tree, the same exact answers
            self._tree = cKDTree(self.points, balanced_tree=False, compact_nodes=False)
        return self._tree

    @property
    def normals(self) -> NDArray[np.float64]:
        """Unit normals of the target points (lines in 2D, planes in 3D), estimated once when not given."""
        if self._normals is None:
            self._normals = estimate_normals(self.points, tree=self.tree)
        return self._normals
