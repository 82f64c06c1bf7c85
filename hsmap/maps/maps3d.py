"""3D occupancy maps: OctoMap ``.bt``/``.ot`` files and point maps (``.ply``/``.pcd``) as a dense voxel grid.

A :class:`Map3D` holds one state per voxel at the map's finest resolution: ``UNKNOWN`` (never observed),
``FREE`` (observed empty) or ``OCCUPIED``. OctoMap leaves larger than the finest resolution are expanded into
the voxels they cover. :func:`floor_height` finds the floor as the lowest large horizontal layer of occupied
voxels; :func:`band_grid` turns the voxels in a height band above it into a 2D :class:`~hsmap.maps.grid.OccupancyGrid`
that is free only where the map observed free space.

Voxel (i, j, k) spans ``origin + [i, j, k] * resolution`` to ``origin + [i + 1, j + 1, k + 1] * resolution``
along the world axes x, y, z.
"""

from __future__ import annotations

import errno
import os
import stat
from dataclasses import dataclass
from pathlib import Path

import numba as nb
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..datasets.clouds import read_points
from ..errors import DataFormatError, DatasetError, EmptyInputError, InputError, ShapeError
from .grid import FREE as G_FREE
from .grid import OCCUPIED as G_OCCUPIED
from .grid import UNKNOWN as G_UNKNOWN
from .grid import GridGeometry, OccupancyGrid
from .octomap_files import _OCTREE_DEPTH, _octomap_leaves

__all__ = [
    "UNKNOWN",
    "FREE",
    "OCCUPIED",
    "MAX_CELLS",
    "Map3D",
    "read_map3d",
    "floor_height",
    "band_grid",
    "band_layers",
    "seen_through",
    "segmentation_free",
]

#: Voxel states of :attr:`Map3D.state`.
UNKNOWN, FREE, OCCUPIED = 0, 1, 2

#: The largest dense voxel grid (cells, one byte each) a map may need; a larger one is refused.
MAX_CELLS = 400_000_000

#: A horizontal layer of occupied voxels counts as large (a floor candidate) when it holds at least this share
#: of the largest layer's occupied voxels.
FLOOR_LAYER_SHARE = 0.5

#: :func:`seen_through`: an occupied voxel within this many metres above or below a band keeps its column unknown
#: there (a wall seen just off the band: a 3D LiDAR's rings 1-2 deg apart leave gaps of this size on walls up to
#: about 10 m away).
WALL_MARGIN = 0.3


@dataclass(frozen=True)
class Map3D:
    """A dense voxel grid of occupancy states.

    Attributes
    ----------
    state : ndarray of shape (nx, ny, nz), uint8
        ``UNKNOWN`` (0), ``FREE`` (1) or ``OCCUPIED`` (2) per voxel, indexed along world x, y, z.
    origin : ndarray of shape (3,)
        World coordinates of the min corner of voxel (0, 0, 0), metres.
    resolution : float
        Voxel edge, metres.
    source : str
        The file the map was read from.
    """

    state: NDArray[np.uint8]
    origin: NDArray[np.float64]
    resolution: float
    source: str

    def __post_init__(self) -> None:
        state = np.asarray(self.state)
        if state.ndim != 3:
            raise ShapeError(f"Map3D.state must be a 3D voxel grid (nx, ny, nz), got shape {state.shape}")
        origin = np.asarray(self.origin, dtype=float).reshape(-1)
        if origin.shape != (3,) or not np.isfinite(origin).all():
            raise ShapeError(f"Map3D.origin must be 3 finite numbers, got {self.origin!r}")
        if not (np.isfinite(self.resolution) and self.resolution > 0):
            raise InputError(f"Map3D.resolution must be a positive number of metres, got {self.resolution}")
        object.__setattr__(self, "state", state.astype(np.uint8, copy=False))
        object.__setattr__(self, "origin", origin)
        object.__setattr__(self, "resolution", float(self.resolution))

    @property
    def shape(self) -> tuple[int, int, int]:
        """(nx, ny, nz)."""
        return tuple(int(s) for s in self.state.shape)  # type: ignore[return-value]

    @property
    def bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(min corner, max corner) of the grid, world metres, each of shape (3,)."""
        return self.origin.copy(), self.origin + np.asarray(self.state.shape) * self.resolution

    def z_centres(self) -> NDArray[np.float64]:
        """(nz,) world heights of the voxel layers' centres."""
        return self.origin[2] + (np.arange(self.state.shape[2]) + 0.5) * self.resolution

    def centres(self, which: int = OCCUPIED) -> NDArray[np.float64]:
        """(N, 3) world centres of the voxels in state ``which``."""
        idx = np.argwhere(self.state == which)
        return self.origin + (idx + 0.5) * self.resolution

    def index_of(self, points: ArrayLike) -> NDArray[np.int64]:
        """(N, 3) integer voxel indices of world points (N, 3) (may lie outside the grid)."""
        pts = np.asarray(points, dtype=float).reshape(-1, 3)
        return np.floor((pts - self.origin) / self.resolution).astype(np.int64)

    def counts(self) -> dict[str, int]:
        """Voxels per state: ``{"unknown": .., "free": .., "occupied": ..}``."""
        c = np.bincount(self.state.reshape(-1), minlength=3)
        return {"unknown": int(c[UNKNOWN]), "free": int(c[FREE]), "occupied": int(c[OCCUPIED])}


# --------------------------------------------------------------------------------------------------------------
# OctoMap files
# --------------------------------------------------------------------------------------------------------------


def _check_budget(path: Path, shape: ArrayLike, max_cells: int) -> tuple[int, int, int]:
    """The grid's shape as integers, checked against ``max_cells`` while still floats: a coordinate or resolution
    far out of range (3e38 m, res 1e300) gives a shape no integer holds, or none at all (NaN)."""
    extent = np.asarray(shape, dtype=np.float64)
    if not np.isfinite(extent).all():
        raise InputError(f"{path}: its coordinates and resolution give no finite voxel grid (a coordinate or the "
                         "resolution far out of range)")
    cells = float(np.prod(extent))
    if cells > max_cells:
        def count(v: float) -> str:
            return str(int(v)) if v < 1e15 else f"{v:.3g}"

        raise InputError(f"{path}: its voxel grid {' x '.join(count(v) for v in extent)} = {count(cells)} cells "
                         f"exceeds the limit of {max_cells} cells (max_cells)")
    return tuple(int(v) for v in extent)  # type: ignore[return-value]


def _map_from_leaves(path: Path, centres: NDArray[np.float64], depth: NDArray[np.int64],
                     occupied: NDArray[np.bool_], res: float, max_cells: int) -> Map3D:
    """Expand OctoMap leaves (centres, depths, occupied flags) into a dense grid at the finest resolution."""
    if not np.isfinite(centres).all():
        raise DataFormatError(f"{path}: its leaves' coordinates are not finite at the header's resolution 'res "
                              f"{res:g}' (a voxel size far out of range)")
    k = (1 << np.clip(_OCTREE_DEPTH - depth, 0, _OCTREE_DEPTH)).astype(np.int64)
    lo = centres - (k[:, None] * res) / 2.0
    origin = lo.min(axis=0)
    first_f = np.rint((lo - origin) / res)
    shape = _check_budget(path, (first_f + k[:, None]).max(axis=0), max_cells)
    first = first_f.astype(np.int64)
    state = np.zeros(shape, dtype=np.uint8)
    values = np.where(occupied, OCCUPIED, FREE).astype(np.uint8)
    for size in np.unique(k):
        sel = k == size
        base = first[sel]
        v = values[sel]
        if size == 1:
            state[base[:, 0], base[:, 1], base[:, 2]] = v
            continue
        off = np.stack(np.meshgrid(*([np.arange(size)] * 3), indexing="ij"), -1).reshape(-1, 3)
        # one leaf size at a time, in chunks bounded by the grid's own size (leaves never overlap)
        per = max(1, min(len(base), 4_000_000 // len(off)))
        for s in range(0, len(base), per):
            idx = (base[s:s + per, None, :] + off[None]).reshape(-1, 3)
            state[idx[:, 0], idx[:, 1], idx[:, 2]] = np.repeat(v[s:s + per], len(off))
    return Map3D(state, origin, res, str(path))


# --------------------------------------------------------------------------------------------------------------
# Point maps
# --------------------------------------------------------------------------------------------------------------


@nb.njit(cache=True, nogil=True)
def _carve(state, origin, res, starts, ends, step):  # pragma: no cover - JIT
    """Mark voxels on the segments starts[i] -> ends[i] (sampled every ``step`` metres, the end voxel excluded)
    FREE where they are not OCCUPIED."""
    nx, ny, nz = state.shape
    for i in range(starts.shape[0]):
        dx = ends[i, 0] - starts[i, 0]
        dy = ends[i, 1] - starts[i, 1]
        dz = ends[i, 2] - starts[i, 2]
        length = np.sqrt(dx * dx + dy * dy + dz * dz)
        n = int(length / step)
        ex = int(np.floor((ends[i, 0] - origin[0]) / res))
        ey = int(np.floor((ends[i, 1] - origin[1]) / res))
        ez = int(np.floor((ends[i, 2] - origin[2]) / res))
        for s in range(n):
            t = s * step / length
            ix = int(np.floor((starts[i, 0] + t * dx - origin[0]) / res))
            iy = int(np.floor((starts[i, 1] + t * dy - origin[1]) / res))
            iz = int(np.floor((starts[i, 2] + t * dz - origin[2]) / res))
            if ix == ex and iy == ey and iz == ez:
                break
            if 0 <= ix < nx and 0 <= iy < ny and 0 <= iz < nz and state[ix, iy, iz] == 0:
                state[ix, iy, iz] = 1


def _point_map(path: Path, poses: ArrayLike | None, resolution: float, max_cells: int) -> Map3D:
    """A point map's occupied voxels; free voxels along the rays from each point's nearest sensor origin."""

    if not (np.isfinite(resolution) and resolution > 0):
        raise InputError(f"resolution must be a positive number of metres, got {resolution}")
    try:
        pts = read_points(path)
    except DataFormatError:
        raise
    except Exception as exc:  # noqa: BLE001 - Open3D's reader raises plain exceptions
        raise DataFormatError(f"{path}: cannot read the point map ({exc})") from None
    if len(pts) == 0:
        raise EmptyInputError(f"{path}: no points (expected a .ply/.pcd point map)")
    origins = None
    if poses is not None:
        p = np.asarray(poses, dtype=float)
        if p.ndim != 2 or p.shape[1] not in (3, 6) or len(p) == 0:
            raise ShapeError(f"poses must be (N, 3) sensor positions or (N, 6) poses x, y, z, roll, pitch, yaw; "
                             f"got shape {p.shape}")
        origins = p[:, :3]
        if not np.isfinite(origins).all():
            raise InputError("poses must be finite")
    allp = pts if origins is None else np.vstack([pts, origins])
    origin = np.floor(allp.min(axis=0) / resolution) * resolution
    shape = _check_budget(path, np.floor((allp.max(axis=0) - origin) / resolution) + 1, max_cells)
    state = np.zeros(shape, dtype=np.uint8)
    idx = np.floor((pts - origin) / resolution).astype(np.int64)
    idx = np.minimum(idx, np.asarray(shape) - 1)
    state[idx[:, 0], idx[:, 1], idx[:, 2]] = OCCUPIED
    if origins is not None:
        from scipy.spatial import cKDTree

        _, near = cKDTree(origins).query(pts)
        _carve(state, origin, float(resolution), np.ascontiguousarray(origins[near]), np.ascontiguousarray(pts),
               float(resolution) / 2.0)
    return Map3D(state, origin, float(resolution), str(path))


def _not_a_file(path: Path) -> str:
    """Why ``path``, which is not a regular file, cannot be read as a 3D map."""
    try:
        st = path.stat()
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return "a symbolic link loop, not a 3D map file"
        if path.is_symlink():
            return f"a broken symbolic link (to {os.readlink(path)}), not a 3D map file"
        return "no such 3D map file"
    if stat.S_ISDIR(st.st_mode):
        return "a folder, not a 3D map file (expected a .bt, .ot, .ply or .pcd file)"
    return "not a regular file (a FIFO, socket or device), not a 3D map file"


def read_map3d(path: str | os.PathLike, *, poses: ArrayLike | None = None, resolution: float = 0.05,
               max_cells: int = MAX_CELLS) -> Map3D:
    """Read a 3D map into a dense voxel grid.

    Parameters
    ----------
    path : path-like
        An OctoMap tree (``.bt`` binary or ``.ot`` full, read with octomap-python; occupied and free leaves, at
        the tree's resolution) or a point map (``.ply``/``.pcd``: every point's voxel occupied).
    poses : array_like of shape (N, 3) or (N, 6), optional
        Point maps only: sensor positions (x, y, z[, roll, pitch, yaw]). Voxels on the segment from each point's
        nearest position to the point become free; without poses only the occupied voxels are known.
    resolution : float
        Point maps only: the voxel edge, metres.
    max_cells : int
        The largest dense grid accepted.

    Raises
    ------
    DatasetError
        No such file.
    DataFormatError
        The file is damaged, truncated or not of the format its ending says.
    InputError
        The dense grid would exceed ``max_cells``.
    """
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: {_not_a_file(path)}")
    suffix = path.suffix.lower()
    if suffix in (".bt", ".ot"):
        if poses is not None:
            raise InputError(f"{path}: poses apply to point maps only (an OctoMap tree knows its free space)")
        centres, depth, occupied, res = _octomap_leaves(path)
        return _map_from_leaves(path, centres, depth, occupied, res, max_cells)
    if suffix in (".ply", ".pcd"):
        return _point_map(path, poses, resolution, max_cells)
    raise DataFormatError(f"{path}: unknown 3D map format '{suffix}' (expected .bt, .ot, .ply or .pcd)")


# --------------------------------------------------------------------------------------------------------------
# The floor and height bands
# --------------------------------------------------------------------------------------------------------------


def floor_height(m: Map3D) -> float:
    """The floor's height: the top face of the lowest large horizontal layer of occupied voxels.

    A layer is large when it holds at least ``FLOOR_LAYER_SHARE`` of the largest layer's occupied voxels.

    Raises
    ------
    EmptyInputError
        The map has no occupied voxel.
    """
    per_layer = (m.state == OCCUPIED).sum(axis=(0, 1))
    if per_layer.max(initial=0) == 0:
        raise EmptyInputError(f"{m.source}: no occupied voxel, so no floor to find")
    k = int(np.flatnonzero(per_layer >= FLOOR_LAYER_SHARE * per_layer.max())[0])
    return float(m.origin[2] + (k + 1) * m.resolution)


#: Share of a voxel's height by which a layer must overlap a band to belong to it: a band edge on a voxel face
#: (0 on the floor's top face, a multiple of the resolution above it) takes no layer beyond the face, whatever
#: the rounding of the floor's and the edges' heights.
BAND_FACE_TOLERANCE = 1e-6


def band_layers(m: Map3D, lo: float, hi: float, *, floor: float | None = None) -> slice:
    """The voxel layers overlapping heights [lo, hi] above the floor (``floor`` or :func:`floor_height`) by more
    than :data:`BAND_FACE_TOLERANCE` of a voxel: an edge on a voxel face takes only the layer on the band's side."""
    if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
        raise InputError(f"band must be two finite heights LO < HI above the floor, got {lo}, {hi}")
    f = floor_height(m) if floor is None else float(floor)
    if not np.isfinite(f):
        raise InputError(f"floor must be a finite height, got {floor}")
    z0, z1 = f + lo, f + hi
    bottom = m.origin[2] + np.arange(m.state.shape[2]) * m.resolution
    eps = BAND_FACE_TOLERANCE * m.resolution
    over = np.flatnonzero((bottom < z1 - eps) & (bottom + m.resolution > z0 + eps))
    if len(over) == 0:
        lo_m, hi_m = m.bounds
        raise InputError(f"band {lo:g}-{hi:g} m above the floor at {f:.3f} m ({z0:.3f}-{z1:.3f} m) lies outside "
                         f"{m.source}'s heights {lo_m[2]:.3f}-{hi_m[2]:.3f} m")
    return slice(int(over[0]), int(over[-1]) + 1)


def band_grid(m: Map3D, lo: float, hi: float, *, floor: float | None = None):
    """The 2D occupancy grid of heights [lo, hi] above the floor, at the map's resolution.

    A cell is occupied when any voxel of its column in the band is occupied, free when none is occupied and at
    least one is observed free, else unknown.

    Parameters
    ----------
    m : Map3D
    lo, hi : float
        The band, metres above the floor.
    floor : float, optional
        The floor's world height; default :func:`floor_height`.

    Returns
    -------
    hsmap.maps.grid.OccupancyGrid
        Shape (ny, nx) with row 0 at the largest y; origin the map's (x, y) min corner.
    """

    band = m.state[:, :, band_layers(m, lo, hi, floor=floor)]
    occ = (band == OCCUPIED).any(axis=2)
    free = ~occ & (band == FREE).any(axis=2)
    data = np.full(occ.shape, G_UNKNOWN, dtype=np.int8)
    data[free] = G_FREE
    data[occ] = G_OCCUPIED
    img = np.ascontiguousarray(data.T[::-1])
    return OccupancyGrid(img, GridGeometry(img.shape, m.resolution, (float(m.origin[0]), float(m.origin[1]))))


def seen_through(m: Map3D, lo: float, hi: float, *, floor: float | None = None,
                 wall_margin: float = WALL_MARGIN) -> NDArray[np.bool_]:
    """The cells of :func:`band_grid` that are unknown in the band but whose column the sensor saw through.

    A column observed free at some height above the floor holds no floor-to-ceiling wall; when nothing in the
    band is observed there (the band was never swept at that spot: a room seen through its door from the
    corridor, below a desk top) and nothing occupied lies within ``wall_margin`` above or below the band (a
    wall seen just off the band, between two of a LiDAR's rings), the band is taken to be open space like the
    heights that were seen.

    Parameters
    ----------
    m : Map3D
    lo, hi : float
        The band, metres above the floor.
    floor : float, optional
        The floor's world height; default :func:`floor_height`.
    wall_margin : float
        Metres above and below the band in which an occupied voxel keeps a column unknown.

    Returns
    -------
    ndarray of shape (ny, nx), bool
        In :func:`band_grid`'s image layout (row 0 at the largest y).
    """
    if not (np.isfinite(wall_margin) and wall_margin >= 0):
        raise InputError(f"wall_margin must be a number of metres >= 0, got {wall_margin}")
    f = floor_height(m) if floor is None else float(floor)
    layers = band_layers(m, lo, hi, floor=f)
    unknown = (m.state[:, :, layers] == UNKNOWN).all(axis=2)
    z = m.z_centres()
    above = z > f
    column_free = (m.state[:, :, above] == FREE).any(axis=2)
    near = above & (z > f + lo - wall_margin) & (z < f + hi + wall_margin)
    wall_near = (m.state[:, :, near] == OCCUPIED).any(axis=2)
    return np.ascontiguousarray((unknown & column_free & ~wall_near).T[::-1])


def segmentation_free(m: Map3D, lo: float, hi: float, *, floor: float | None = None,
                      min_passage: float = 0.0, wall_margin: float = WALL_MARGIN) -> NDArray[np.bool_]:
    """The free space of a band to segment into rooms: observed free or :func:`seen_through`, without passages
    narrower than ``min_passage``.

    A crack a voxel or two wide between two rooms is a part of a wall the sensor missed, not a way through: the
    free space is opened (eroded, then dilated) and the occupied cells closed (dilated, then eroded) with a
    square ``min_passage`` wide at the map's resolution, so that such cracks close (through a thick wall and
    between two wall pieces) and doors at least ``min_passage`` wide stay open.

    Parameters
    ----------
    m : Map3D
    lo, hi : float
        The band, metres above the floor.
    floor : float, optional
        The floor's world height; default :func:`floor_height`.
    min_passage : float
        Metres; e.g. the narrowest door the segmentation accepts. 0 keeps every passage.
    wall_margin : float
        See :func:`seen_through`.

    Returns
    -------
    ndarray of shape (ny, nx), bool
        In :func:`band_grid`'s image layout.
    """
    from scipy import ndimage as ndi

    if not (np.isfinite(min_passage) and min_passage >= 0):
        raise InputError(f"min_passage must be a number of metres >= 0, got {min_passage}")
    f = floor_height(m) if floor is None else float(floor)
    layers = band_layers(m, lo, hi, floor=f)
    band = m.state[:, :, layers]
    observed = (~(band == OCCUPIED).any(axis=2) & (band == FREE).any(axis=2)).T[::-1]
    free = observed | seen_through(m, lo, hi, floor=f, wall_margin=wall_margin)
    r = int(np.floor(min_passage / 2.0 / m.resolution))
    if r >= 1:
        square = np.ones((2 * r + 1, 2 * r + 1), dtype=bool)
        occupied = ((band == OCCUPIED).any(axis=2)).T[::-1]
        walls = ndi.binary_closing(np.pad(occupied, r), structure=square)[r:-r, r:-r]
        free = ndi.binary_opening(free, structure=square) & ~walls
    return np.ascontiguousarray(free)
