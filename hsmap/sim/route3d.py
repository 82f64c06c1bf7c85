"""A route through the known free space of a real 3D map: where the robot fits, and into every room the map saw.

:func:`plan_route3d` turns a :class:`hsmap.sim.voxelworld.VoxelWorld` into the inputs of the floor-plan
exploration (:func:`hsmap.sim.explore.plan_exploration`) and plans with it:

1. traversability, one pixel per voxel column: the robot may stand on a column where no voxel of its body's
   height band (``body``, from just above the floor to above the mast's LiDAR) is occupied and where the map
   knows the space is free at floor level (``known``, every voxel of that band free: clutter the map never saw
   may stand in unknown space) and at both LiDARs' heights (a sensor inside unknown space would see nothing);
2. visibility: the robot may only stand where the mast LiDAR would see the map: at least ``min_visible`` of a
   coarse set of its beams (``visibility_beams``, over its vertical field of view, cast from the column's centre
   at the LiDAR's height) return a hit; a sensor inside a pocket of unknown space (where the map's own recording
   sensor stood, or a room seen only through its door) sees nothing, and a SLAM run would be blind there;
3. rooms: the map's own rooms in its ``rooms_band`` (the paper's 1.7-1.8 m slice), as ``hsmap segment MAP3D
   --band`` finds them (:func:`hsmap.maps3d.band_grid` with :func:`hsmap.maps3d.segmentation_free`'s free
   space, segmented by :func:`hsmap.segmentation.segment_rooms`): reported, not
   planned on;
4. goals covering the space the robot fits in: the largest connected part of the traversable columns with the
   robot's clearance (:class:`~hsmap.sim.explore.ExploreConfig`) is cut into cells around seeds spread by
   farthest-point sampling until every pixel is within ``cover_spacing`` of a seed (from the pixel with most
   room around it; ties to the lowest index), so the route reaches the corridor's ends and every part of a room
   the robot fits into, not only one centre per room of the slice;
5. the route: :func:`~hsmap.sim.explore.plan_exploration` with those cells as its rooms (footprint clearance,
   costs keeping to the middle of corridors and doorways, each cell's free centre in turn, straight legs).

Heights are metres above the floor (the world's z = 0).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from ..errors import ConfigError, EmptyInputError
from ..grid import FREE, OCCUPIED, UNKNOWN, GridGeometry, OccupancyGrid
from ..maps3d import Map3D, band_grid, segmentation_free
from ..segmentation import SegmentationConfig, segment_rooms
from .explore import Exploration, ExploreConfig, plan_exploration
from .sensors import Lidar3DConfig
from .voxelworld import FREE as VFREE
from .voxelworld import OCCUPIED as VOCC
from .voxelworld import VoxelWorld

__all__ = ["Route3DConfig", "Route3D", "plan_route3d", "traversable", "band_image", "voxel_geometry", "cover_cells",
           "visibility"]


def _band(name: str, v) -> tuple[float, float]:
    try:
        lo, hi = (float(x) for x in v)
    except (TypeError, ValueError):
        raise ConfigError(f"route3d.{name} must be [low, high] metres, got {v!r}") from None
    if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
        raise ConfigError(f"route3d.{name} must be [low, high] metres with low < high, got {v!r}")
    return lo, hi


@dataclass
class Route3DConfig:
    """How the route through a voxel map is planned (one configuration for every map).

    Attributes
    ----------
    body : list of 2 float
        Heights the robot occupies (base, mast and its LiDAR), metres above the floor: no occupied voxel there.
    known : list of 2 float
        Heights where every voxel must be known free (the base and the 2D LiDAR's plane).
    rooms_band : list of 2 float
        Heights of the slice whose rooms are reported (:meth:`Route3D.rooms_entered`).
    cover_spacing : float
        Every place the robot fits is within this many metres of a goal of the route.
    min_visible : float
        Least share of the mast LiDAR's beams that return where the robot stands.
    visibility_beams : list of 2 int
        Channels and columns of the coarse beam set the visibility is measured with.
    explore : ExploreConfig
        Clearance and path costs, as for the floor-plan buildings.
    """

    body: list[float] = field(default_factory=lambda: [0.05, 1.8])
    known: list[float] = field(default_factory=lambda: [0.05, 0.45])
    rooms_band: list[float] = field(default_factory=lambda: [1.7, 1.8])
    cover_spacing: float = 3.0
    min_visible: float = 0.3
    visibility_beams: list[int] = field(default_factory=lambda: [8, 32])
    explore: ExploreConfig = field(default_factory=ExploreConfig)

    def __post_init__(self) -> None:
        self.body = list(_band("body", self.body))
        self.known = list(_band("known", self.known))
        self.rooms_band = list(_band("rooms_band", self.rooms_band))
        if not (isinstance(self.cover_spacing, (int, float)) and np.isfinite(self.cover_spacing)
                and self.cover_spacing > 0):
            raise ConfigError(f"route3d.cover_spacing must be > 0 metres, got {self.cover_spacing!r}")
        if not (isinstance(self.min_visible, (int, float)) and 0 <= self.min_visible <= 1):
            raise ConfigError(f"route3d.min_visible must be in [0, 1], got {self.min_visible!r}")
        v = self.visibility_beams
        if not (isinstance(v, (list, tuple)) and len(v) == 2 and all(isinstance(k, int) and k >= 1 for k in v)):
            raise ConfigError(f"route3d.visibility_beams must be [channels, columns] >= 1, got {v!r}")
        self.visibility_beams = [int(k) for k in v]


@dataclass
class Route3D:
    """The planned route and the grids it was planned on.

    Attributes
    ----------
    route : Exploration
    geometry : GridGeometry
        One pixel per voxel column.
    traversable : ndarray of shape (H, W), bool
        Where the robot's centre may be before the clearance is applied (traversable and visible).
    rooms : ndarray of shape (H, W), int32
        The map's rooms in its ``rooms_band`` (0 = none).
    slice_grid : OccupancyGrid
        The ``rooms_band`` grid the rooms were found on.
    cells : ndarray of shape (H, W), int32
        The cells whose free centres are the route's goals.
    visible : ndarray of shape (H, W), float
        Share of the mast LiDAR's coarse beams that return, per traversable column.
    """

    route: Exploration
    geometry: GridGeometry
    traversable: NDArray[np.bool_]
    rooms: NDArray[np.int32]
    slice_grid: OccupancyGrid
    cells: NDArray[np.int32]
    visible: NDArray[np.float64]

    def rooms_entered(self) -> list[int]:
        """Rooms (labels) the route's driven path passes through, in label order."""
        wp = np.vstack([self.route.start[None, :2], self.route.waypoints])
        pts = [wp[:1]]
        for a, b in zip(wp[:-1], wp[1:], strict=True):
            n = max(2, int(np.ceil(np.hypot(*(b - a)) / (self.geometry.resolution / 2))))
            pts.append(a + np.linspace(0, 1, n)[:, None] * (b - a))
        rc = self.geometry.world_to_index(np.vstack(pts))
        h, w = self.rooms.shape
        ok = (rc[:, 0] >= 0) & (rc[:, 0] < h) & (rc[:, 1] >= 0) & (rc[:, 1] < w)
        lab = self.rooms[rc[ok, 0], rc[ok, 1]]
        return sorted(int(v) for v in np.unique(lab[lab > 0]))


def voxel_geometry(world: VoxelWorld) -> GridGeometry:
    """The 2D grid of the voxel columns: pixel (row, col) is column (x = col, y = H - 1 - row)."""
    nx, ny, _ = world.shape
    return GridGeometry((ny, nx), world.resolution, (float(world.origin[0]), float(world.origin[1])))


def _layers(world: VoxelWorld, lo: float, hi: float) -> slice:
    """The voxel layers whose centres lie in [lo, hi] metres above the floor (at least one)."""
    z = world.origin[2] + (np.arange(world.shape[2]) + 0.5) * world.resolution
    k = np.flatnonzero((z >= lo) & (z <= hi))
    if len(k) == 0:
        k = np.array([world.layer(0.5 * (lo + hi))])
    return slice(int(k[0]), int(k[-1]) + 1)


def _image(columns: NDArray) -> NDArray:
    """(nx, ny) column values as an (H, W) = (ny, nx) image, row 0 at the largest y."""
    return np.ascontiguousarray(columns.T[::-1])


def band_image(world: VoxelWorld, lo: float, hi: float) -> tuple[OccupancyGrid, OccupancyGrid]:
    """A height band (metres above the floor) as :func:`hsmap.maps3d.band_grid` makes it, and the grid
    ``hsmap segment MAP3D --band`` segments (:func:`hsmap.maps3d.segmentation_free`'s free space)."""

    m = Map3D(world.state, world.origin, world.resolution, world.source)
    grid = band_grid(m, lo, hi, floor=0.0)
    free = segmentation_free(m, lo, hi, floor=0.0, min_passage=2.0 * SegmentationConfig().min_door_half_width)
    data = np.where(free, FREE, np.where(grid.occupied, OCCUPIED, UNKNOWN)).astype(np.int8)
    return grid, OccupancyGrid(data, grid.geometry)


def traversable(world: VoxelWorld, config: Route3DConfig | None = None,
                sensor_heights: tuple[float, ...] = ()) -> NDArray[np.bool_]:
    """Columns (H, W) where the robot may stand (see the module docstring, step 1)."""
    cfg = config or Route3DConfig()
    st = world.state
    ok = ~(st[:, :, _layers(world, *cfg.body)] == VOCC).any(axis=2)
    ok &= (st[:, :, _layers(world, *cfg.known)] == VFREE).all(axis=2)
    for h in sensor_heights:
        ok &= st[:, :, world.layer(h)] == VFREE
    return _image(ok)


class _VoxelPlan:
    """What :func:`plan_exploration` reads of a floor plan, made from a voxel map."""

    def __init__(self, name: str, geometry: GridGeometry, free: NDArray[np.bool_], rooms: NDArray[np.int32]):
        self.name = name
        self.geometry = geometry
        self.furnished_free = free
        self.rooms = rooms
        self.files = {"furnished": name}


def visibility(world: VoxelWorld, where: NDArray[np.bool_], lidar3d: Lidar3DConfig,
               beams: tuple[int, int] = (8, 32)) -> NDArray[np.float64]:
    """Share (H, W) of a coarse set of the mast LiDAR's beams (``beams`` = channels, columns over its vertical
    field of view) that return a hit within its range, cast from each pixel of ``where`` (H, W) at the LiDAR's
    height; 0 elsewhere."""
    geo = voxel_geometry(world)
    coarse = Lidar3DConfig(channels=beams[0], columns=beams[1], vertical_fov_deg=list(lidar3d.vertical_fov_deg),
                           range_min=lidar3d.range_min, range_max=lidar3d.range_max)
    d = coarse.directions().reshape(-1, 3).astype(np.float32)
    rc = np.argwhere(where)
    out = np.zeros(where.shape)
    for a in range(0, len(rc), 4096):
        xy = geo.pixel_to_world(rc[a:a + 4096].astype(float))
        rays = np.empty((len(xy), len(d), 6), dtype=np.float32)
        rays[:, :, 0], rays[:, :, 1] = xy[:, :1], xy[:, 1:]
        rays[:, :, 2] = lidar3d.position[2]
        rays[:, :, 3:] = d[None]
        r = world.cast_rays(rays.reshape(-1, 6)).reshape(len(xy), len(d))
        ok = np.isfinite(r) & (r >= lidar3d.range_min) & (r <= lidar3d.range_max)
        out[rc[a:a + 4096, 0], rc[a:a + 4096, 1]] = ok.mean(axis=1)
    return out


def plan_route3d(world: VoxelWorld, config: Route3DConfig | None = None,
                 sensor_heights: tuple[float, ...] = (), lidar3d: Lidar3DConfig | None = None) -> Route3D:
    """Plan the route through a voxel world (see the module docstring).

    Parameters
    ----------
    world : VoxelWorld
    config : Route3DConfig, optional
    sensor_heights : tuple of float
        Heights of the robot's sensors above the floor, metres: their voxels must be known free.
    lidar3d : Lidar3DConfig, optional
        The mast LiDAR (its height, field of view and range set the visibility); default the study's.

    Returns
    -------
    Route3D

    Raises
    ------
    EmptyInputError
        No room of the map has free space the robot fits in.
    """

    cfg = config or Route3DConfig()
    geo = voxel_geometry(world)
    free = traversable(world, cfg, sensor_heights)
    vis = visibility(world, free, lidar3d or Lidar3DConfig(), tuple(cfg.visibility_beams))
    free &= vis >= cfg.min_visible
    grid, segmented = band_image(world, *cfg.rooms_band)
    try:
        cells = cover_cells(free, geo.resolution, cfg)
        rooms = np.asarray(segment_rooms(segmented).labels, dtype=np.int32)
    except EmptyInputError as exc:
        raise EmptyInputError(f"{world.source}: {exc}") from None
    route = plan_exploration(_VoxelPlan(world.source, geo, free, cells), cfg.explore)
    return Route3D(route, geo, free, rooms, grid, cells, vis)


def cover_cells(free: NDArray[np.bool_], resolution: float, config: Route3DConfig | None = None) -> NDArray[np.int32]:
    """Cells (H, W) (0 = none, 1..K) covering the largest connected part of ``free`` where the robot's centre
    may be (see the module docstring, step 3).

    Raises
    ------
    EmptyInputError
        No free pixel has the robot's clearance.
    """
    from scipy import ndimage as ndi

    cfg = config or Route3DConfig()
    clear = np.where(free, (ndi.distance_transform_edt(free) - 0.5) * resolution, 0.0)
    ok = clear >= cfg.explore.clearance
    comp, n = ndi.label(ok, structure=np.ones((3, 3), dtype=bool))
    if n == 0:
        raise EmptyInputError(f"no traversable place {cfg.explore.clearance:g} m clear of occupied and unknown "
                              "space at floor level: the robot fits nowhere in the map")
    main = 1 + int(np.argmax(np.bincount(comp.ravel())[1:]))
    rc = np.argwhere(comp == main).astype(float)
    c = clear[comp == main]
    seeds = [int(np.argmax(c))]
    d = np.hypot(*(rc - rc[seeds[0]]).T)
    limit = cfg.cover_spacing / resolution
    while d.max() > limit:
        k = int(np.argmax(d))
        seeds.append(k)
        d = np.minimum(d, np.hypot(*(rc - rc[k]).T))
    owner = np.zeros(len(rc), dtype=np.int64)
    best = np.full(len(rc), np.inf)
    for j, k in enumerate(seeds):
        dk = np.hypot(*(rc - rc[k]).T)
        closer = dk < best
        owner[closer], best[closer] = j, dk[closer]
    cells = np.zeros(free.shape, dtype=np.int32)
    cells[comp == main] = owner + 1
    return cells
