"""A route through the known free space of a real 3D map: where the robot fits, and into every room the map saw.

:func:`plan_route3d` turns a :class:`hsmap.sim.voxelworld.VoxelWorld` into the inputs of the floor-plan
exploration (:func:`hsmap.sim.explore.plan_exploration`) and plans with it:

1. traversability, one pixel per voxel column: the robot may stand on a column where no voxel of its body's
   height band (``body``, from just above the floor to above the mast's LiDAR) is occupied and where the map
   knows the space is free at floor level (``known``): each voxel of that band is free, or unknown under a
   free voxel of the body band in the same column with the floor's slab observed under the column (an
   occupied voxel in ``floor_slab``): a laser passing over the floor and hitting it leaves floor-level voxels
   it never grazed unknown; unknown space with no observed floor under it may hold clutter the map never saw;
   ``sensor_heights`` must be free too;
2. visibility: the robot's centre may only be where the mast LiDAR would see the map: at least ``min_visible``
   of a coarse set of its beams (``visibility_beams``, over its vertical field of view, cast from the column's
   centre at the LiDAR's height) return a hit; a sensor inside a pocket of unknown space (where the map's own
   recording sensor stood, or a room seen only through its door) sees nothing, and a SLAM run would be blind
   there. The mast stands off the robot's centre (``lidar3d.position``) and sweeps a circle of that radius as
   the robot turns: every place within it must see the map. A blind column is no obstacle: the footprint's
   clearance is measured from the untraversable columns;
3. rooms: the map's own rooms in its ``rooms_band`` (the paper's 1.7-1.8 m slice), as ``hsmap segment MAP3D
   --band`` finds them (:func:`hsmap.maps.maps3d.band_grid` with :func:`hsmap.maps.maps3d.segmentation_free`'s free
   space, segmented by :func:`hsmap.rooms.segmentation.segment_rooms`);
4. planning grid: ``subdivision`` pixels per voxel edge, so the robot's centre may lie between voxel centres
   (a doorway an even number of voxels wide has its middle on a voxel face); the footprint keeps the robot's
   radius (``footprint``) clear of every untraversable column's faces;
5. goals covering the space the robot fits in: the largest connected part of the places the robot's centre may
   be is split by the rooms of the slice (a pixel of no room joins the nearest room's pixels), and each room's
   part is cut into cells around seeds spread by farthest-point sampling until every pixel is within
   ``cover_spacing`` of a seed (from the pixel with most room around it; ties to the lowest index): the route
   reaches the corridor's ends and goes into every room it fits into, as far as the robot fits and sees;
6. the route: :func:`~hsmap.sim.explore.plan_exploration` with those cells as its rooms (the footprint's
   clearance, costs keeping ``explore.preferred_clearance`` from obstacles where the space allows, each cell's
   free centre in turn, straight legs through places the robot may stand).

Heights are metres above the floor (the world's z = 0).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from ..errors import ConfigError, EmptyInputError
from ..maps.grid import FREE, OCCUPIED, UNKNOWN, GridGeometry, OccupancyGrid
from ..maps.maps3d import Map3D, band_grid, segmentation_free
from ..rooms.segmentation import SegmentationConfig, segment_rooms
from .explore import Exploration, ExploreConfig, plan_exploration
from .robot import RobotConfig
from .sensors import Lidar3DConfig
from .voxelworld import FREE as VFREE
from .voxelworld import OCCUPIED as VOCC
from .voxelworld import UNKNOWN as VUNK
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
        Heights where every voxel must be known free (the base and the 2D LiDAR's plane), or unknown under an
        observed-free column on an observed floor.
    floor_slab : list of 2 float
        Heights (below the floor's surface) where an occupied voxel shows the floor under a column was seen.
    rooms_band : list of 2 float
        Heights of the slice whose rooms are reported (:meth:`Route3D.rooms_entered`).
    cover_spacing : float
        Every place the robot fits is within this many metres of a goal of the route.
    min_visible : float
        Least share of the mast LiDAR's beams that return where the robot stands.
    visibility_beams : list of 2 int
        Channels and columns of the coarse beam set the visibility is measured with.
    subdivision : int
        Planning pixels per voxel edge.
    explore : ExploreConfig
        Path costs (``preferred_clearance``, ``wall_cost``, ``max_leg``), as for the floor-plan buildings; the
        least clearance is the robot's radius (:func:`plan_route3d`'s ``footprint``), not ``explore.clearance``.
    """

    body: list[float] = field(default_factory=lambda: [0.05, 1.8])
    known: list[float] = field(default_factory=lambda: [0.05, 0.45])
    floor_slab: list[float] = field(default_factory=lambda: [-0.15, 0.0])
    rooms_band: list[float] = field(default_factory=lambda: [1.7, 1.8])
    cover_spacing: float = 3.0
    min_visible: float = 0.3
    visibility_beams: list[int] = field(default_factory=lambda: [8, 32])
    subdivision: int = 2
    explore: ExploreConfig = field(default_factory=ExploreConfig)

    def __post_init__(self) -> None:
        self.body = list(_band("body", self.body))
        self.known = list(_band("known", self.known))
        self.floor_slab = list(_band("floor_slab", self.floor_slab))
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
        if isinstance(self.subdivision, bool) or not (isinstance(self.subdivision, int) and 1 <= self.subdivision <= 8):
            raise ConfigError(f"route3d.subdivision must be an integer in [1, 8], got {self.subdivision!r}")


@dataclass
class Route3D:
    """The planned route and the grids it was planned on.

    Attributes
    ----------
    route : Exploration
    geometry : GridGeometry
        One pixel per voxel column.
    traversable : ndarray of shape (H, W), bool
        Traversable columns from whose centre the mast LiDAR sees the map (before the clearance and the mast's
        sweep are applied).
    rooms : ndarray of shape (H, W), int32
        The map's rooms in its ``rooms_band`` (0 = none).
    slice_grid : OccupancyGrid
        The ``rooms_band`` grid the rooms were found on.
    cells : ndarray of shape (H * s, W * s), int32
        The cells whose free centres are the route's goals, on ``plan_geometry``.
    visible : ndarray of shape (H, W), float
        Share of the mast LiDAR's coarse beams that return, per traversable column.
    plan_geometry : GridGeometry
        The planning grid: ``s`` = ``subdivision`` pixels per voxel edge.
    footprint : float
        The robot's radius the route keeps clear, metres.
    """

    route: Exploration
    geometry: GridGeometry
    traversable: NDArray[np.bool_]
    rooms: NDArray[np.int32]
    slice_grid: OccupancyGrid
    cells: NDArray[np.int32]
    visible: NDArray[np.float64]
    plan_geometry: GridGeometry | None = None
    footprint: float = 0.0

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
    """A height band (metres above the floor) as :func:`hsmap.maps.maps3d.band_grid` makes it, and the grid
    ``hsmap segment MAP3D --band`` segments (:func:`hsmap.maps.maps3d.segmentation_free`'s free space)."""

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
    body, known = _layers(world, *cfg.body), _layers(world, *cfg.known)
    ok = ~(st[:, :, body] == VOCC).any(axis=2)
    top = max(body.stop, known.stop)
    # free_above[..., i]: a free voxel of the body band above layer known.start + i of the column
    free_body = np.zeros(st.shape[:2] + (top - known.start,), dtype=bool)
    lo = max(body.start, known.start)
    free_body[:, :, lo - known.start:body.stop - known.start] = st[:, :, lo:body.stop] == VFREE
    free_above = np.zeros_like(free_body)
    free_above[:, :, :-1] = np.flip(np.logical_or.accumulate(np.flip(free_body[:, :, 1:], axis=2), axis=2), axis=2)
    floor_seen = (st[:, :, _layers(world, *cfg.floor_slab)] == VOCC).any(axis=2)
    kn = st[:, :, known]
    under = (kn == VUNK) & free_above[:, :, :known.stop - known.start] & floor_seen[:, :, None]
    ok &= ((kn == VFREE) | under).all(axis=2)
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
                 sensor_heights: tuple[float, ...] = (), lidar3d: Lidar3DConfig | None = None,
                 footprint: float | None = None) -> Route3D:
    """Plan the route through a voxel world (see the module docstring).

    Parameters
    ----------
    world : VoxelWorld
    config : Route3DConfig, optional
    sensor_heights : tuple of float
        Heights of the robot's sensors above the floor, metres: their voxels must be known free.
    lidar3d : Lidar3DConfig, optional
        The mast LiDAR (its height, field of view and range set the visibility); default the study's.
    footprint : float, optional
        The robot's radius, metres (default :class:`~hsmap.sim.robot.RobotConfig`'s).

    Returns
    -------
    Route3D

    Raises
    ------
    EmptyInputError
        No room of the map has free space the robot fits in.
    """

    cfg = config or Route3DConfig()
    need = RobotConfig().radius if footprint is None else float(footprint)
    if not (np.isfinite(need) and need > 0):
        raise ConfigError(f"the robot's footprint radius must be > 0 metres, got {footprint!r}")
    from scipy import ndimage as ndi

    geo = voxel_geometry(world)
    l3 = lidar3d or Lidar3DConfig()
    free = traversable(world, cfg, sensor_heights)
    vis = visibility(world, free, l3, tuple(cfg.visibility_beams))
    grid, segmented = band_image(world, *cfg.rooms_band)
    k = cfg.subdivision
    fine = GridGeometry((geo.shape[0] * k, geo.shape[1] * k), geo.resolution / k, geo.origin)
    up = lambda a: np.repeat(np.repeat(a, k, axis=0), k, axis=1)  # noqa: E731
    # the least visibility within the circle the mast sweeps about the centre as the robot turns
    n = int(np.ceil(float(np.hypot(*l3.position[:2])) / fine.resolution))
    yy, xx = np.mgrid[-n:n + 1, -n:n + 1]
    seen = ndi.minimum_filter(up(vis), footprint=yy ** 2 + xx ** 2 <= n * n, mode="constant", cval=0.0)
    stand = up(free) & (seen >= cfg.min_visible)
    try:
        rooms = np.asarray(segment_rooms(segmented).labels, dtype=np.int32)
        cells = cover_cells(up(free), fine.resolution, cfg, stand=stand, rooms=up(rooms), footprint=need)
    except EmptyInputError as exc:
        raise EmptyInputError(f"{world.source}: {exc}") from None
    route = plan_exploration(_VoxelPlan(world.source, fine, up(free), cells), cfg.explore, footprint=need,
                             stand=stand)
    return Route3D(route, geo, free & (vis >= cfg.min_visible), rooms, grid, cells, vis, fine, need)


def cover_cells(free: NDArray[np.bool_], resolution: float, config: Route3DConfig | None = None, *,
                stand: NDArray[np.bool_] | None = None, rooms: NDArray[np.integer] | None = None,
                footprint: float | None = None) -> NDArray[np.int32]:
    """Cells (H, W) (0 = none, 1..K) covering the largest connected part of the pixels of ``free`` (H, W) where
    the robot's centre may be (see the module docstring, step 5).

    Parameters
    ----------
    free : ndarray of shape (H, W), bool
        Traversable pixels (the clearance is measured from the others).
    resolution : float
        Metres per pixel.
    config : Route3DConfig, optional
    stand : ndarray of shape (H, W), bool, optional
        Where the centre may be besides the clearance (default everywhere).
    rooms : ndarray of shape (H, W), int, optional
        Room labels (0 = none): each room's part is covered on its own (default one part).
    footprint : float, optional
        Least clearance of the centre, metres (default ``config.explore.clearance``).

    Raises
    ------
    EmptyInputError
        No free pixel has the robot's clearance.
    """
    from scipy import ndimage as ndi

    cfg = config or Route3DConfig()
    need = cfg.explore.clearance if footprint is None else float(footprint)
    clear = np.where(free, (ndi.distance_transform_edt(free) - 0.5) * resolution, 0.0)
    ok = clear >= need
    if stand is not None:
        ok &= stand
    comp, n = ndi.label(ok, structure=np.ones((3, 3), dtype=bool))
    if n == 0:
        raise EmptyInputError(f"no traversable place {need:g} m clear of occupied and unknown "
                              "space at floor level: the robot fits nowhere in the map")
    main = comp == 1 + int(np.argmax(np.bincount(comp.ravel())[1:]))
    group = np.zeros(free.shape, dtype=np.int64)
    if rooms is not None and (rooms[main] > 0).any():
        lab = np.where(main, rooms, 0)
        _, near = ndi.distance_transform_edt(lab == 0, return_indices=True)
        group = lab[near[0], near[1]]  # a pixel of no room joins the nearest room's pixels
    cells = np.zeros(free.shape, dtype=np.int32)
    limit = cfg.cover_spacing / resolution
    n_cells = 0
    for g in np.unique(group[main]):
        part = main & (group == g)
        rc = np.argwhere(part).astype(float)
        c = clear[part]
        seeds = [int(np.argmax(c))]
        d = np.hypot(*(rc - rc[seeds[0]]).T)
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
        cells[part] = n_cells + owner + 1
        n_cells += len(seeds)
    return cells
