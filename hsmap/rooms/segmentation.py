"""Door detection and room segmentation of 2D occupancy grids (the paper's Algorithm 2, and a refinement).

Pipeline (images in (row, col), world coordinates through :class:`hsmap.maps.grid.GridGeometry`):

1. binary free-space image, median filtered (by default the filter may clear free speckle but never erase
   an occupied pixel: a plain 3x3 median erases walls one pixel thick); occupied blobs smaller than
   ``min_obstacle_area`` (chairs, table legs, specks) are ignored by the door detection;
2. skeleton of the free space (Zhang-Suen thinning) and its Euclidean distance transform (clearance,
   metres); their product is the clearance along the skeleton;
3. door candidates on the skeleton:

   * ``method="paper"``: the skeleton pixels whose clearance lies in the band of half door widths
     (``door_half_width +/- door_half_width_tolerance``, 40 +/- 5 cm) form candidate segments; the centre of
     each segment is a door centre;
   * ``method="critical"`` (default): the Voronoi critical points of Thrun (1998) and Bormann et al. (2016):
     skeleton pixels whose clearance is the smallest within ``critical_radius`` along the skeleton and lies
     in ``[min_door_half_width, max_door_half_width]``, moved to the middle of their run of equal clearance
     (a doorway through a thick wall);

4. at each centre a line is drawn out to the nearest occupied cells on both sides, perpendicular to the
   skeleton (``paper``) or through the two nearest obstacle points on opposite sides (``critical``; this also
   closes gaps between free-standing wall ends). With ``critical`` a line is kept only if a wall runs on
   from one of its ends at least (a door frame, a partition's end; not a column or a bulge of a wall that
   narrows a corridor);
5. (``critical`` with ``wall_gaps``) openings that are no narrowing of the clearance (a room open to a
   corridor over most of its width, a cubicle, a ring corridor's side rooms) are found as gaps in walls,
   relative to the spaces they join:

   * corners: obstacle pixels that are the nearest obstacle to a wedge of free space at least
     ``corner_angle`` wide (a wall's end, the convex corner of a thick wall);
   * candidate lines, at most ``max_gap_width`` long, free, with no obstacle in the disc they are the
     diameter of: from corner to corner where a wall runs on beyond one end (over ``wall_continuation``),
     and from a corner along the wall it ends to the first obstacle, where that wall is at least 1 m and
     at least as long as the gap;
   * a line is narrow on a side if it is at most ``gap_ratio`` times the free chord parallel to it there
     (median over depths up to half its length), every other candidate drawn in as a wall: a line across a
     corridor then sees the corridor's width on both sides, a line closing a room off the corridor sees the
     room's width and the corridor's length. Narrow on both sides: a room border; on one side only (the
     mouth of a corridor, into a room or into another corridor): judged with the critical lines below;

6. the lines cut the free space, whose 4-connected components are the first regions; (``critical``) the
   regions on either side of a critical line, or of a wall-gap line narrow on one side, stay apart only where
   the line is a real narrowing: half its width at most ``narrowing_ratio`` times the geometric mean of the
   largest clearances of the two regions (the room borders being walls); the others are merged, least
   door-like first, each piece of a line between the room borders it crosses on its own;
7. regions under ``min_room_area`` (1.5 m^2) are merged into the neighbour they share the longest border
   with (isolated ones under ``min_isolated_area``, free specks, are dropped);
8. optionally (``assign_furniture``) occupied blobs enclosed by a single room are given its label.

The result carries the room labels (on the input's free pixels), the door list in world coordinates (only
doors between two different final rooms, one per passage, in the middle of the wall it crosses; ``kind``
"door" for a narrowing, "opening" for a wall gap) and, on request, every intermediate image (for the
step-by-step figure, :func:`hsmap.viz.map_figures.voronoi_steps_figure`).

On the Bormann et al. (2016) benchmark (``benchmarks/segmentation.py``, 15 buildings, one configuration) the
paper's band alone finds only doors 70-90 cm wide and under-segments (per-room precision about 0.73);
critical points with the narrowing test alone reach 0.95 precision, 0.99 (plain) / 0.92 (furnished) recall,
but merge rooms that open onto corridors (area-weighted precision 0.87); with the wall gaps (the defaults
below) precision is 0.98 plain and furnished (area-weighted 0.96) at the same recall.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage as ndi

from ..errors import ConfigError, EmptyInputError, InputError, ShapeError
from ..maps.grid import GridGeometry, OccupancyGrid
from ._doors import (
    _Crop,
    _door_lines,
    _filtered_free,
    _Lines,
    _Skeleton,
    _skeleton_candidates,
)
from ._kernels import (
    edt,
    label_max,
)
from ._steps import (
    FOUR,
    OFFSETS,
    UnionFind,
    assign_furniture,
    fill_from_neighbours,
    merge_by_narrowing,
    merge_small,
    middle_of_wall,
    pieces_between,
    relabel,
    separated_regions,
)

__all__ = [
    "SegmentationConfig",
    "Door",
    "Room",
    "Segmentation",
    "segment_rooms",
    "check_scale",
    "points_in_doors",
]


@dataclass
class SegmentationConfig:
    """Door detection and room segmentation settings; the defaults reproduce the paper where it says.

    Attributes
    ----------
    method : str
        ``"paper"``: Algorithm 2 as published (band of half door widths); ``"critical"``: critical points
        on the skeleton with the narrowing test, and gaps in walls (the default, see the module docstring).
    median_size : int
        Side of the median filter on the free-space image (paper: yes; 0 or 1 disables).
    median_keeps_walls : bool
        The filter may only turn free pixels occupied (removing free speckle), never erase occupied ones:
        a plain median erases walls one pixel thick. False gives the plain median of the paper.
    min_obstacle_area, min_obstacle_length : float
        Occupied blobs in free space smaller than ``min_obstacle_area`` (m^2) and shorter than
        ``min_obstacle_length`` (m, the longer side of their bounding box) are clutter the door detection ignores.
    door_half_width, door_half_width_tolerance : float
        The paper's band of half door widths, metres (40 +/- 5 cm). Used by ``method="paper"``.
    min_door_half_width, max_door_half_width : float
        Half widths (metres) a door may have with ``method="critical"``.
    critical_radius : float
        Metres along the skeleton within which a critical point has the smallest clearance.
    narrowing_ratio : float
        A door is kept only if its half width is at most this fraction of the geometric mean of the largest
        clearances of the two regions it separates.
    wall_gaps : bool
        (``critical``) Also close gaps in walls that are narrow relative to the spaces they join (step 5 of
        the module docstring); False gives the critical points and the narrowing test alone.
    max_gap_width : float
        Longest wall gap (metres) closed.
    gap_ratio : float
        A wall gap is narrow on a side if its length is at most this fraction of the free chord parallel to
        it on that side.
    corner_angle : float
        Degrees of free space an obstacle pixel must be the nearest obstacle to, to be a corner (a wall's
        end: 180; a thick wall's convex corner: 90; a straight wall: about 0).
    wall_continuation : float
        Metres a wall must run on beyond a door line's or a wall gap's end.
    min_room_area : float
        Regions smaller than this (m^2) are merged into a neighbour (paper: 1.5).
    min_isolated_area : float
        Regions with no neighbour (free space seen through a window, a pocket enclosed by furniture) stay
        rooms of their own if at least this large (m^2); smaller ones are dropped as speckle.
    assign_furniture : bool
        Give occupied pixels enclosed by a room (furniture) that room's label.
    """

    method: str = "critical"
    median_size: int = 3
    median_keeps_walls: bool = True
    min_obstacle_area: float = 0.25
    min_obstacle_length: float = 1.0
    door_half_width: float = 0.40
    door_half_width_tolerance: float = 0.05
    min_door_half_width: float = 0.15
    max_door_half_width: float = 1.5
    critical_radius: float = 0.5
    narrowing_ratio: float = 0.65
    wall_gaps: bool = True
    max_gap_width: float = 4.0
    gap_ratio: float = 0.85
    corner_angle: float = 70.0
    wall_continuation: float = 0.3
    min_room_area: float = 1.5
    min_isolated_area: float = 0.25
    assign_furniture: bool = False

    def __post_init__(self) -> None:
        if self.method not in ("paper", "critical"):
            raise ConfigError(f"method must be 'paper' or 'critical', got {self.method!r}")
        for name in ("door_half_width", "min_door_half_width", "max_door_half_width", "critical_radius"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"{name} must be > 0 metres, got {getattr(self, name)}")
        if self.door_half_width_tolerance < 0:
            raise ConfigError(f"door_half_width_tolerance must be >= 0, got {self.door_half_width_tolerance}")
        if self.min_door_half_width > self.max_door_half_width:
            raise ConfigError("min_door_half_width must not exceed max_door_half_width")
        if not 0 < self.narrowing_ratio <= 1:
            raise ConfigError(f"narrowing_ratio must lie in (0, 1], got {self.narrowing_ratio}")
        if self.min_room_area < 0 or self.min_isolated_area < 0:
            raise ConfigError("min_room_area and min_isolated_area must be >= 0 m^2")
        if self.min_obstacle_area < 0 or self.min_obstacle_length < 0:
            raise ConfigError("min_obstacle_area and min_obstacle_length must be >= 0")
        if self.median_size < 0:
            raise ConfigError(f"median_size must be >= 0, got {self.median_size}")
        for name in ("max_gap_width", "wall_continuation"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"{name} must be > 0 metres, got {getattr(self, name)}")
        if not 0 < self.gap_ratio <= 1:
            raise ConfigError(f"gap_ratio must lie in (0, 1], got {self.gap_ratio}")
        if not 0 < self.corner_angle <= 360:
            raise ConfigError(f"corner_angle must lie in (0, 360] degrees, got {self.corner_angle}")


@dataclass
class Door:
    """A door: a line across a narrow passage between two rooms.

    Attributes
    ----------
    centre : ndarray of shape (2,)
        World (x, y) of the door's centre (on the skeleton), metres.
    end_points : ndarray of shape (2, 2)
        World (x, y) of the two ends (the occupied cells it spans between).
    width : float
        Free span between the end points, metres (their distance less one pixel: the end points are the
        centres of the occupied pixels on either side).
    rooms : tuple of int
        Labels of the two rooms it connects (0 where not known).
    pixel : tuple of int
        (row, col) of the centre in the map image.
    kind : str
        ``"door"``: a narrowing of the free space (a critical point, or the paper's band); ``"opening"``: a
        gap in a wall, closed between two wall ends or a wall end and the face of another wall.
    """

    centre: NDArray[np.float64]
    end_points: NDArray[np.float64]
    width: float
    rooms: tuple[int, int] = (0, 0)
    pixel: tuple[int, int] = (0, 0)
    kind: str = "door"

    def as_dict(self) -> dict:
        return {
            "centre": [float(v) for v in self.centre],
            "end_points": [[float(v) for v in p] for p in self.end_points],
            "width": float(self.width),
            "rooms": [int(r) for r in self.rooms],
            "pixel": [int(v) for v in self.pixel],
            "kind": self.kind,
        }


@dataclass
class Room:
    """A room of a segmentation: label, area (m^2), centroid (world x, y)."""

    label: int
    area: float
    centroid: NDArray[np.float64]


@dataclass
class Segmentation:
    """Result of :func:`segment_rooms`.

    Attributes
    ----------
    labels : ndarray of shape (H, W), int32
        Room label per pixel, 0 = no room; rooms are numbered 1..R.
    doors : list of Door
    geometry : GridGeometry
    config : SegmentationConfig
    steps : dict of str to ndarray
        Intermediate (H, W) images when asked for (``keep_steps=True``): ``free``, ``filtered``,
        ``distance``, ``skeleton``, ``product``, ``candidates``, ``door_lines`` (every line drawn),
        ``gap_lines`` (the wall gaps that are room borders), ``regions``.
    """

    labels: NDArray[np.int32]
    doors: list[Door]
    geometry: GridGeometry
    config: SegmentationConfig
    steps: dict[str, NDArray] = field(default_factory=dict)

    @property
    def n_rooms(self) -> int:
        return int(self.labels.max(initial=0))

    @property
    def rooms(self) -> list[Room]:
        """Area and centroid of every room, in label order (a list, as :attr:`doors`)."""
        n = self.n_rooms
        if n == 0:
            return RoomList()
        idx = np.arange(1, n + 1)
        counts = np.bincount(self.labels.ravel(), minlength=n + 1)[1:]
        com = np.asarray(ndi.center_of_mass(np.ones_like(self.labels), self.labels, idx), dtype=float)
        xy = self.geometry.pixel_to_world(com.reshape(-1, 2))
        a = self.geometry.resolution**2
        return RoomList(Room(int(i), float(c * a), xy[k]) for k, (i, c) in enumerate(zip(idx, counts, strict=True)))


class RoomList(list):
    """The list :attr:`Segmentation.rooms` returns. Calling it (``seg.rooms()``, from when ``rooms`` was a method)
    returns the list itself with a :class:`DeprecationWarning`."""

    def __call__(self) -> RoomList:
        warnings.warn("Segmentation.rooms is a list: write seg.rooms, not seg.rooms()", DeprecationWarning,
                      stacklevel=2)
        return self


# ----------------------------------------------------------------------------------------------------------
# the algorithm
# ----------------------------------------------------------------------------------------------------------


def _as_free(grid: OccupancyGrid | ArrayLike, resolution: float | None) -> tuple[NDArray[np.bool_], GridGeometry]:
    if isinstance(grid, OccupancyGrid):
        free = grid.free
        geometry = grid.geometry
        if resolution is not None and abs(resolution - geometry.resolution) > 1e-12:
            geometry = GridGeometry(geometry.shape, resolution, geometry.origin)
    else:
        free = np.asarray(grid)
        if free.ndim != 2:
            raise ShapeError(f"the free-space image must be 2D (H, W), got shape {free.shape}")
        if free.dtype != bool:
            raise InputError(f"the free-space image must be boolean (True = free), got dtype {free.dtype}")
        geometry = GridGeometry(free.shape, 0.05 if resolution is None else resolution)
    if not free.any():
        raise EmptyInputError("the map has no free space to segment (no free pixel)")
    return free, geometry


def check_scale(free: NDArray[np.bool_], resolution: float, config: SegmentationConfig | None = None) -> None:
    """Check that a map's resolution lets the segmentation find doors and rooms at all.

    The configuration speaks in metres (door half widths, the smallest room); the map in pixels. A resolution
    coarser than the narrowest door half width the configuration looks for cannot show a door; one so fine that
    the whole free space is smaller than the smallest room kept can show no room (a map read at 1 mm per pixel
    instead of 5 cm). Both mean the resolution is wrong for this map.

    Parameters
    ----------
    free : ndarray of shape (H, W), bool
        The free space.
    resolution : float
        Metres per pixel.
    config : SegmentationConfig, optional

    Raises
    ------
    InputError
        The message names the resolution and the range it should lie in.
    EmptyInputError
        The map has no free pixel (whatever the resolution).
    """
    cfg = config or SegmentationConfig()
    narrowest = (cfg.min_door_half_width if cfg.method == "critical"
                 else cfg.door_half_width - cfg.door_half_width_tolerance)
    if not (np.isfinite(resolution) and resolution > 0):
        raise InputError(f"resolution must be a positive number of metres per pixel, got {resolution}")
    if resolution > narrowest:
        raise InputError(f"resolution {resolution:g} m/pixel is coarser than the narrowest door half width the "
                         f"segmentation looks for ({narrowest:g} m): no door can show; expected at most "
                         f"{narrowest:g} m/pixel")
    n_free = int(np.count_nonzero(free))
    if n_free == 0:  # not the resolution's fault
        raise EmptyInputError("the map has no free space to segment (no free pixel)")
    area = float(n_free) * resolution**2
    smallest = min(cfg.min_room_area, cfg.min_isolated_area)
    if area < smallest:
        raise InputError(f"at resolution {resolution:g} m/pixel the map's free space covers only {area:.3g} m^2, "
                         f"less than the smallest room kept ({smallest:g} m^2): no room can be found; is the "
                         "resolution right?")


def _regions(filtered: NDArray[np.bool_], lines: _Lines, dist_px: NDArray[np.float64], res: float,
             cfg: SegmentationConfig) -> tuple[NDArray, UnionFind]:
    """Step 5: every line cuts; the wall-gap lines stay, the regions facing each other across a critical line
    are merged unless it is a narrowing between them (``narrowing_ratio``); a critical line crossing wall-gap
    lines is judged piece by piece. Returns the regions and which of them are merged."""
    lab, n = ndi.label(filtered & ~lines.cut, structure=FOUR)
    uf = UnionFind(n + 1)
    if cfg.method == "critical" and any(lines.soft):
        # largest clearance of each region, the wall-gap lines being walls
        gap_cut = lines.gap_cut
        clear = edt(filtered & ~gap_cut)[0] if gap_cut.any() else dist_px
        peak = np.maximum(label_max(lab, clear, n), 0.0) * res
        peak[0] = 0.0
        near_gap = gap_cut.copy()
        gr, gc = np.nonzero(gap_cut)
        for dr, dc in OFFSETS:
            near_gap[gr + dr, gc + dc] = True
        edges = []
        for (_, a, b, px, width), sft in zip(lines.door_px, lines.soft, strict=True):
            if not sft:
                continue
            for run in pieces_between(px, a, b, near_gap):
                edges.append((*separated_regions(lab, run), width / 2.0))
        if edges:
            e = np.array(edges)
            merge_by_narrowing(e[:, 2], e[:, :2].astype(np.int64), peak, uf, cfg)
    return lab, uf


def _rooms(regions: NDArray, uf: UnionFind, free: NDArray[np.bool_], res: float,
           cfg: SegmentationConfig) -> NDArray:
    """Step 6: the merged regions, the cut pixels folded into them, small regions merged or dropped."""
    lab = relabel(regions, uf)
    lab = fill_from_neighbours(lab, free)
    lab[~free] = 0
    lab = merge_small(lab, res, cfg.min_room_area, cfg.min_isolated_area)
    if cfg.assign_furniture:
        lab = assign_furniture(lab, free)
    return lab


def _doors_between_rooms(lab: NDArray, lines: _Lines, filtered: NDArray[np.bool_], res: float) -> list[tuple]:
    """The lines that separate two final rooms, one per passage, moved to the middle of the wall they cross:
    (width, rooms, centre, a, b, is a wall gap) in work-image pixels, in (row, col) order of the centres."""
    found = []
    for k, (centre, a, b, px, width) in enumerate(lines.door_px):
        nb = (px[:, None, :] + OFFSETS[None, :, :]).reshape(-1, 2)
        ok = (nb[:, 0] >= 0) & (nb[:, 0] < lab.shape[0]) & (nb[:, 1] >= 0) & (nb[:, 1] < lab.shape[1])
        v = lab[nb[ok, 0], nb[ok, 1]]
        u, cnt = np.unique(v[v > 0], return_counts=True)
        if len(u) < 2:
            continue
        o = np.argsort(-cnt)
        found.append((width, tuple(sorted((int(u[o[0]]), int(u[o[1]])))), centre, a, b, k >= lines.n_critical))
    # one door per passage: of several lines between the same rooms closer than a door width, keep a critical
    # line (the middle of a passage through a thick wall) before a wall-gap line (its ends), the narrowest first
    kept: list[tuple] = []
    for width, pair, centre, a, b, gap in sorted(found, key=lambda t: (t[5], t[0])):
        if any(k[1] == pair and np.hypot(*(k[2] - centre)) * res < max(width, k[0]) for k in kept):
            continue
        kept.append((width, pair, centre, a, b, gap))
    thick = int(np.ceil(0.5 / res))  # the thickest wall a door passes through
    kept = [(w, pair, *middle_of_wall(filtered, c, a, b, thick), gap) for w, pair, c, a, b, gap in kept]
    kept.sort(key=lambda t: (t[2][0], t[2][1]))
    return kept


def _as_doors(kept: list[tuple], geometry: GridGeometry, off: NDArray[np.int64]) -> list[Door]:
    """Doors in world coordinates from :func:`_doors_between_rooms`'s lines (``off``: the work image's place)."""
    doors: list[Door] = []
    for width, pair, centre, a, b, gap in kept:
        ends = geometry.pixel_to_world(np.stack([a, b]) + off)
        doors.append(Door(geometry.pixel_to_world(centre + off), ends, width, pair,
                          (int(centre[0] + off[0]), int(centre[1] + off[1])), "opening" if gap else "door"))
    return doors


def _step_images(crop: _Crop, free_full: NDArray[np.bool_], filtered: NDArray[np.bool_], sk: _Skeleton,
                 lines: _Lines, regions: NDArray, res: float) -> dict[str, NDArray]:
    """Every intermediate image, in the map's size (:attr:`Segmentation.steps`)."""
    cand = np.zeros_like(filtered)
    for (r, c) in sk.centres:
        cand[r, c] = True
    return {
        "free": free_full.copy(),
        "filtered": crop.full(filtered),
        "distance": crop.full(sk.dist_px * res),
        "skeleton": crop.full(sk.skel),
        "product": crop.full(sk.product),
        "candidates": crop.full(cand),
        "door_lines": crop.full(lines.cut),
        "gap_lines": crop.full(lines.gap_cut),
        "regions": crop.full(regions.astype(np.int32)),
    }


def segment_rooms(
    grid: OccupancyGrid | ArrayLike,
    resolution: float | None = None,
    *,
    config: SegmentationConfig | None = None,
    keep_steps: bool = False,
) -> Segmentation:
    """Detect doors and segment a 2D map into rooms.

    Parameters
    ----------
    grid : OccupancyGrid or ndarray of shape (H, W), bool
        The map: an occupancy grid (its free cells are used) or a free-space mask (True = free).
    resolution : float, optional
        Metres per pixel (overrides the grid's; for a mask the default is 0.05).
    config : SegmentationConfig, optional
    keep_steps : bool
        Keep every intermediate image in ``result.steps``.

    Returns
    -------
    Segmentation

    Raises
    ------
    EmptyInputError
        The map has no free pixel.
    InputError
        The resolution cannot show a door or a room (:func:`check_scale`).
    """
    cfg = config or SegmentationConfig()
    free_full, geometry = _as_free(grid, resolution)
    res = geometry.resolution
    check_scale(free_full, res, cfg)
    crop = _Crop.around(free_full)  # work on the bounding box of the free space, padded
    free = crop.work_image(free_full)
    filtered = _filtered_free(free, res, cfg)
    sk = _skeleton_candidates(filtered, res, cfg)
    lines = _door_lines(filtered, sk, res, cfg)
    regions, uf = _regions(filtered, lines, sk.dist_px, res, cfg)
    lab = _rooms(regions, uf, free, res, cfg)
    doors = _as_doors(_doors_between_rooms(lab, lines, filtered, res), geometry, crop.offset)
    steps = _step_images(crop, free_full, filtered, sk, lines, regions, res) if keep_steps else {}
    return Segmentation(crop.full(lab, dtype=np.int32), doors, geometry, cfg, steps)


def points_in_doors(points: ArrayLike, doors: list[Door], depth: float = 0.3, margin: float = 0.1,
                    z_range: tuple[float, float] | None = None) -> list[NDArray[np.float64]]:
    """The points of a map inside each door's box, as one cloud per door.

    The box of a door is centred on the door line: along it, the door's width plus ``margin`` on each side;
    across it, ``depth`` metres on each side (the wall's thickness and the frame); vertically all heights
    or ``z_range``.

    Parameters
    ----------
    points : ndarray of shape (N, 2) or (N, 3)
        World points.
    doors : list of Door
    depth, margin : float
        Metres.
    z_range : (float, float), optional
        Height interval for (N, 3) points.

    Returns
    -------
    list of ndarray of shape (K_i, D)
        One array per door, in door order (possibly empty).
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] not in (2, 3):
        raise ShapeError(f"points must have shape (N, 2) or (N, 3), got {pts.shape}")
    if depth <= 0 or margin < 0:
        raise InputError(f"depth must be > 0 and margin >= 0, got depth={depth}, margin={margin}")
    out = []
    for d in doors:
        a, b = np.asarray(d.end_points, dtype=float)
        along = b - a
        L = float(np.hypot(*along))
        u = along / L if L > 0 else np.array([1.0, 0.0])
        v = np.array([-u[1], u[0]])
        mid = 0.5 * (a + b)
        rel = pts[:, :2] - mid
        s = rel @ u
        t = rel @ v
        m = (np.abs(s) <= L / 2 + margin) & (np.abs(t) <= depth)
        if z_range is not None and pts.shape[1] == 3:
            m &= (pts[:, 2] >= z_range[0]) & (pts[:, 2] <= z_range[1])
        out.append(pts[m])
    return out
