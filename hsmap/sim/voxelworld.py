"""A world of voxels: both LiDARs ray-cast into a dense trinary voxel map (a real 3D map, e.g. an OctoMap).

:class:`VoxelWorld` holds the map's states (unknown, free, occupied; :mod:`hsmap.maps.maps3d`) as a dense
(nx, ny, nz) array and casts rays through it with a 3D digital differential analyser (Amanatides and Woo): each
ray walks voxel by voxel from its origin and

- stops with a hit at the distance where it enters the first occupied voxel,
- stops with no return where it enters an unknown voxel (what lies there was never seen: no fake hit); the
  voxel a ray starts in is passed whatever the map says (the sensor stands there), and
- gives no return where it leaves the grid.

The world's frame is the map's, shifted in z so that the floor is z = 0 (as in every simulated world:
:mod:`hsmap.sim.world`); :meth:`VoxelWorld.scan2d` and :meth:`VoxelWorld.scan3d` are the mesh world's, so the
sensors, their noise and the dataset writer are shared.
"""

from __future__ import annotations

import numba as nb
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._threads import start_threading_layer
from ..errors import InputError, ShapeError
from ..maps._kernels import dda_start
from ..maps.maps3d import floor_height
from .world import World

__all__ = ["VoxelWorld", "cast_voxels", "ground_surface", "UNKNOWN", "FREE", "OCCUPIED"]

UNKNOWN, FREE, OCCUPIED = 0, 1, 2


@nb.njit(cache=True, parallel=True, fastmath=False)
def _cast_kernel(state, origin, res, rays, out):  # pragma: no cover - compiled
    nx, ny, nz = state.shape
    big = np.inf
    for i in nb.prange(rays.shape[0]):
        ox = (rays[i, 0] - origin[0]) / res
        oy = (rays[i, 1] - origin[1]) / res
        oz = (rays[i, 2] - origin[2]) / res
        dx, dy, dz = rays[i, 3], rays[i, 4], rays[i, 5]
        out[i] = big
        # clip the ray to the grid's box (in voxel units)
        t0, t1 = 0.0, big
        ok = True
        for a in range(3):
            o = ox if a == 0 else (oy if a == 1 else oz)
            d = dx if a == 0 else (dy if a == 1 else dz)
            n = nx if a == 0 else (ny if a == 1 else nz)
            if d == 0.0:
                if o < 0.0 or o >= n:
                    ok = False
            else:
                ta = (0.0 - o) / d
                tb = (n - o) / d
                if ta > tb:
                    ta, tb = tb, ta
                if ta > t0:
                    t0 = ta
                if tb < t1:
                    t1 = tb
        if not ok or t0 >= t1:
            continue
        px, py, pz = ox + t0 * dx, oy + t0 * dy, oz + t0 * dz
        ix = min(max(int(np.floor(px)), 0), nx - 1)
        iy = min(max(int(np.floor(py)), 0), ny - 1)
        iz = min(max(int(np.floor(pz)), 0), nz - 1)
        sx, sy, sz, tdx, tdy, tdz, tmx, tmy, tmz = dda_start(ix, iy, iz, ox, oy, oz, dx, dy, dz)
        t = t0
        first = t0 == 0.0
        while True:
            s = state[ix, iy, iz]
            if s == 2:
                out[i] = t * res
                break
            if s == 0 and not first:
                break
            first = False
            if tmx <= tmy and tmx <= tmz:
                t = tmx
                ix += sx
                tmx += tdx
                if ix < 0 or ix >= nx:
                    break
            elif tmy <= tmz:
                t = tmy
                iy += sy
                tmy += tdy
                if iy < 0 or iy >= ny:
                    break
            else:
                t = tmz
                iz += sz
                tmz += tdz
                if iz < 0 or iz >= nz:
                    break
            if t > t1 + 1e-6:
                break


def cast_voxels(state: NDArray[np.uint8], origin: ArrayLike, resolution: float,
                rays: NDArray[np.float32]) -> NDArray[np.float32]:
    """Distances (R,) along rays (R, 6) = (ox, oy, oz, dx, dy, dz) with unit directions to the first occupied
    voxel of ``state`` (nx, ny, nz) (0 unknown, 1 free, 2 occupied; voxel (0, 0, 0) has its low corner at
    ``origin`` (3,)); inf where the ray enters unknown space or leaves the grid first."""
    rays = np.ascontiguousarray(np.asarray(rays, dtype=np.float64).reshape(-1, 6))
    out = np.empty(len(rays), dtype=np.float64)
    if len(rays):
        start_threading_layer()  # quietly: numba warns about a TBB it will not use on the first parallel kernel
        _cast_kernel(state, np.asarray(origin, dtype=np.float64), float(resolution), rays, out)
    return out.astype(np.float32)


def ground_surface(state: NDArray[np.uint8], origin: ArrayLike, resolution: float, floor: float) -> float:
    """The height the robot's wheels stand on, in the map's frame: the top face of the floor's voxels.

    From the layer holding ``floor`` (a height in the floor or on its top face, :func:`hsmap.maps.maps3d.floor_height`;
    a face counts for the layer below it), the layers
    above it count as floor while each holds at least half as many occupied voxels as the one below (a floor
    several voxels thick); the surface is the top of the last.
    """
    st = np.asarray(state)
    nz = st.shape[2]
    k = int(np.clip(np.ceil((floor - float(np.asarray(origin)[2])) / resolution - 1e-6) - 1, 0, nz - 1))
    occ = (st == OCCUPIED).sum(axis=(0, 1))
    while k + 1 < nz and occ[k] > 0 and occ[k + 1] >= 0.5 * occ[k]:
        k += 1
    return float(np.asarray(origin)[2] + (k + 1) * resolution)


class VoxelWorld(World):
    """A dense voxel map as a world for the simulator's sensors (see the module docstring).

    Parameters
    ----------
    state : ndarray of shape (nx, ny, nz), uint8
        0 unknown, 1 free, 2 occupied.
    origin : array_like of shape (3,)
        World position of voxel (0, 0, 0)'s low corner, metres, in the map's frame.
    resolution : float
        Voxel edge, metres.
    floor : float
        Height of the floor in the map's frame; the world's z = 0 (so ``origin[2] - floor`` is the grid's
        lowest height in the world).
    source : str
        What the map was read from (for messages).
    """

    def __init__(self, state: ArrayLike, origin: ArrayLike, resolution: float, floor: float = 0.0,
                 source: str = "<voxels>"):
        st = np.ascontiguousarray(np.asarray(state, dtype=np.uint8))
        if st.ndim != 3:
            raise ShapeError(f"{source}: voxel states must be (nx, ny, nz), got shape {st.shape}")
        if not (np.isfinite(resolution) and resolution > 0):
            raise InputError(f"{source}: voxel resolution must be > 0 metres, got {resolution}")
        if st.size and st.max() > 2:
            raise InputError(f"{source}: voxel states must be 0 (unknown), 1 (free) or 2 (occupied)")
        o = np.asarray(origin, dtype=float).reshape(3).copy()
        o[2] -= float(floor)
        self.scenario = None
        self.state = st
        self.origin = o
        self.resolution = float(resolution)
        self.floor = float(floor)
        self.source = source

    @classmethod
    def from_map(cls, m, floor: float | None = None) -> VoxelWorld:
        """The world of a :class:`hsmap.maps.maps3d.Map3D`, its floor at z = 0 (``floor`` in the map's frame;
        default :func:`hsmap.maps.maps3d.floor_height`)."""

        f = floor_height(m) if floor is None else float(floor)
        return cls(m.state, m.origin, m.resolution, ground_surface(m.state, m.origin, m.resolution, f),
                   getattr(m, "source", "<map>"))

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(self.state.shape)

    def voxel_index(self, xyz: ArrayLike) -> NDArray[np.int64]:
        """Integer voxel indices (..., 3) of world points (..., 3) (may lie outside the grid)."""
        return np.floor((np.asarray(xyz, dtype=float) - self.origin) / self.resolution).astype(np.int64)

    def state_at(self, xyz: ArrayLike) -> NDArray[np.uint8]:
        """The state (...) of the voxels holding world points (..., 3); unknown outside the grid."""
        idx = self.voxel_index(xyz)
        inside = np.all((idx >= 0) & (idx < np.array(self.state.shape)), axis=-1)
        out = np.zeros(idx.shape[:-1], dtype=np.uint8)
        out[inside] = self.state[tuple(idx[inside].T)]
        return out

    def layer(self, z: float) -> int:
        """Index of the voxel layer holding world height ``z`` (clipped to the grid)."""
        return int(np.clip(np.floor((z - self.origin[2]) / self.resolution), 0, self.state.shape[2] - 1))

    def cast_rays(self, rays: NDArray[np.float32], return_kinds: bool = False):
        """Distances (R,) along packed rays (R, 6) to the first occupied voxel; inf for no return."""
        if return_kinds:
            raise InputError("a voxel world has no triangle kinds")
        return cast_voxels(self.state, self.origin, self.resolution, rays)

    def describe(self) -> dict:
        c = np.bincount(self.state.ravel(), minlength=3)
        return {"source": self.source, "shape": list(self.shape), "resolution": self.resolution,
                "origin_world": [round(float(v), 4) for v in self.origin],
                "floor_in_map_frame": round(self.floor, 4),
                "voxels": {"unknown": int(c[0]), "free": int(c[1]), "occupied": int(c[2])}}
