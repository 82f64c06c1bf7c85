"""Door detection and room segmentation of 2D occupancy grids (the paper's Algorithm 2, and a refinement).

Pipeline (images in (row, col), world coordinates through :class:`hsmap.grid.GridGeometry`):

1. binary free-space image, median filtered (by default the filter may clear free speckle but never erase
   an occupied pixel: a plain 3x3 median erases walls one pixel thick); occupied blobs smaller than
   ``min_obstacle_area`` (chairs, table legs, specks) are ignored by the door detection;
2. skeleton of the free space and its Euclidean distance transform (clearance, metres); their product is
   the clearance along the skeleton;
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
   closes gaps between free-standing wall ends); the lines cut the free space, whose 4-connected components
   are the first regions;
5. (``critical`` only) a door is kept only where it is a real narrowing: its half width is at most
   ``narrowing_ratio`` times the geometric mean of the largest clearances of the two regions it separates
   (a door from a narrow corridor into a room narrows the room much more than the corridor); the other
   doors are removed and their regions merged, least door-like first;
6. regions under ``min_room_area`` (1.5 m^2) are merged into the neighbour they share the longest border
   with (isolated ones under ``min_isolated_area``, free specks, are dropped);
7. optionally (``assign_furniture``) occupied blobs enclosed by a single room are given its label.

The result carries the room labels (on the input's free pixels), the door list in world coordinates (only
doors between two different final rooms, one per passage) and, on request, every intermediate image (for
the step-by-step figure, :func:`hsmap.segmentation_figures.steps_figure`).

On the Bormann et al. (2016) benchmark (``benchmarks/segmentation.py``) the paper's band alone finds only
doors 70-90 cm wide and under-segments (per-room precision about 0.73); the critical-point variant reaches
about 0.94 precision and 0.98 (plain) / 0.92 (furnished) recall with the defaults below.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage as ndi

from .errors import ConfigError, EmptyInputError, InputError, ShapeError
from .grid import GridGeometry, OccupancyGrid

__all__ = [
    "SegmentationConfig",
    "Door",
    "Room",
    "Segmentation",
    "segment_rooms",
    "points_in_doors",
]

_FOUR = ndi.generate_binary_structure(2, 1)
_EIGHT = np.ones((3, 3), dtype=bool)
_OFFSETS = np.array([(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)])


@dataclass
class SegmentationConfig:
    """Door detection and room segmentation settings; the defaults reproduce the paper where it says.

    Attributes
    ----------
    method : str
        ``"paper"``: Algorithm 2 as published (band of half door widths); ``"critical"``: critical points
        on the skeleton plus the narrowing test (the default, see the module docstring).
    median_size : int
        Side of the median filter on the free-space image (paper: yes; 0 or 1 disables).
    median_keeps_walls : bool
        The filter may only turn free pixels occupied (removing free speckle), never erase occupied ones:
        a plain median erases walls one pixel thick. False gives the plain median of the paper.
    min_obstacle_area, min_obstacle_length : float
        Occupied blobs surrounded by free space that are smaller than ``min_obstacle_area`` (m^2) and
        shorter than ``min_obstacle_length`` (m, the longer side of their bounding box) are clutter
        (specks, chairs, table legs) and ignored by the door detection; a thin free-standing wall piece
        is kept by its length.
    door_half_width, door_half_width_tolerance : float
        The paper's band of half door widths, metres (40 +/- 5 cm). Used by ``method="paper"``.
    min_door_half_width, max_door_half_width : float
        Half widths (metres) a door may have with ``method="critical"``.
    critical_radius : float
        Metres along the skeleton within which a critical point has the smallest clearance.
    narrowing_ratio : float
        A door is kept only if its half width is at most this fraction of the geometric mean of the largest
        clearances of the two regions it separates.
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
    narrowing_ratio: float = 0.7
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
    """

    centre: NDArray[np.float64]
    end_points: NDArray[np.float64]
    width: float
    rooms: tuple[int, int] = (0, 0)
    pixel: tuple[int, int] = (0, 0)

    def as_dict(self) -> dict:
        return {
            "centre": [float(v) for v in self.centre],
            "end_points": [[float(v) for v in p] for p in self.end_points],
            "width": float(self.width),
            "rooms": [int(r) for r in self.rooms],
            "pixel": [int(v) for v in self.pixel],
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
        ``distance``, ``skeleton``, ``product``, ``candidates``, ``door_lines``, ``regions``.
    """

    labels: NDArray[np.int32]
    doors: list[Door]
    geometry: GridGeometry
    config: SegmentationConfig
    steps: dict[str, NDArray] = field(default_factory=dict)

    @property
    def n_rooms(self) -> int:
        return int(self.labels.max(initial=0))

    def rooms(self) -> list[Room]:
        """Area and centroid of every room, in label order."""
        n = self.n_rooms
        if n == 0:
            return []
        idx = np.arange(1, n + 1)
        counts = np.bincount(self.labels.ravel(), minlength=n + 1)[1:]
        com = np.asarray(ndi.center_of_mass(np.ones_like(self.labels), self.labels, idx), dtype=float)
        xy = self.geometry.pixel_to_world(com.reshape(-1, 2))
        a = self.geometry.resolution**2
        return [Room(int(i), float(c * a), xy[k]) for k, (i, c) in enumerate(zip(idx, counts, strict=True))]


# ----------------------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------------------


def _skeleton_graph(skel: NDArray[np.bool_]) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """Skeleton pixels (N,) rows, cols and their (N, 8) neighbour indices (-1: none)."""
    rr, cc = np.nonzero(skel)
    index = np.full(skel.shape, -1, dtype=np.int64)
    index[rr, cc] = np.arange(len(rr))
    H, W = skel.shape
    nbr = np.full((len(rr), 8), -1, dtype=np.int64)
    for k, (dr, dc) in enumerate(_OFFSETS):
        r2, c2 = rr + dr, cc + dc
        ok = (r2 >= 0) & (r2 < H) & (c2 >= 0) & (c2 < W)
        nbr[ok, k] = index[r2[ok], c2[ok]]
    return rr, cc, nbr


def _geodesic_filter(values: NDArray[np.float64], nbr: NDArray[np.int64], steps: int, op) -> NDArray[np.float64]:
    """min/max of ``values`` within ``steps`` hops on the skeleton graph."""
    fill = np.inf if op is np.minimum else -np.inf
    m = values.copy()
    for _ in range(steps):
        ext = np.append(m, fill)
        red = ext[nbr].min(axis=1) if op is np.minimum else ext[nbr].max(axis=1)
        m = op(m, red)
    return m


def _march(free: NDArray[np.bool_], start: NDArray[np.float64], direction: NDArray[np.float64],
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


def _basis_points(free: NDArray[np.bool_], p: NDArray[np.int64], radius: int,
                  min_angle: float = np.deg2rad(110)) -> tuple[NDArray[np.int64] | None, NDArray[np.int64] | None]:
    """The two obstacle pixels a critical line joins: the nearest one to ``p`` and the nearest one seen from
    ``p`` at least ``min_angle`` away from the first (on the other side of the passage); None if absent
    within ``radius`` pixels."""
    H, W = free.shape
    r0, r1 = max(p[0] - radius, 0), min(p[0] + radius + 1, H)
    c0, c1 = max(p[1] - radius, 0), min(p[1] + radius + 1, W)
    orr, occ = np.nonzero(~free[r0:r1, c0:c1])
    if not len(orr):
        return None, None
    v = np.stack([orr + r0 - p[0], occ + c0 - p[1]], 1).astype(float)
    d = np.hypot(v[:, 0], v[:, 1])
    i = int(np.argmin(d))
    if d[i] < 1e-9:
        return None, None
    cosang = (v @ v[i]) / np.maximum(d * d[i], 1e-9)
    ok = (cosang <= np.cos(min_angle)) & (d <= radius)
    if not ok.any():
        return None, None
    j = np.nonzero(ok)[0][np.argmin(d[ok])]
    return np.array([orr[i] + r0, occ[i] + c0], dtype=np.int64), np.array([orr[j] + r0, occ[j] + c0], dtype=np.int64)


def _line_pixels(a: NDArray[np.int64], b: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """4-connected pixel line from a to b (rows, cols), so that 4-connected regions cannot leak through."""
    n = int(max(abs(b[0] - a[0]), abs(b[1] - a[1]))) * 2 + 1
    t = np.linspace(0.0, 1.0, n)
    r = np.rint(a[0] + t * (b[0] - a[0])).astype(np.int64)
    c = np.rint(a[1] + t * (b[1] - a[1])).astype(np.int64)
    # close diagonal steps: add the pixel (r_prev, c_next) at each diagonal move
    dr = np.diff(r) != 0
    dc = np.diff(c) != 0
    diag = np.nonzero(dr & dc)[0]
    r = np.concatenate([r, r[diag]])
    c = np.concatenate([c, c[diag + 1]])
    return r, c


class _UnionFind:
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


def _region_borders(labels: NDArray[np.int64]) -> dict[tuple[int, int], int]:
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


# ----------------------------------------------------------------------------------------------------------
# wall gaps: lines between two obstacle corners that close a gap in a wall
# ----------------------------------------------------------------------------------------------------------


def _corner_angles(filtered: NDArray[np.bool_], dist_px: NDArray[np.float64], feat: NDArray[np.int64],
                   res: float, r_min: float, r_max: float, nbins: int = 32) -> NDArray[np.float64]:
    """Angle (degrees) of the widest wedge of free space an obstacle pixel is the nearest obstacle to.

    Every free pixel at ``r_min``..``r_max`` metres from the obstacles votes, for its nearest obstacle pixel
    (``feat``, flat indices), for the direction it lies in (``nbins`` sectors); the votes of the 3x3
    neighbourhood are pooled (a corner's wedge is shared by the few pixels that round it) and the longest
    circular run of sectors is the wedge. A straight wall face sees one direction (a thin wall two opposite
    ones), a convex corner of a thick wall about 90 degrees, the end of a thin wall about 180.
    """
    H, W = filtered.shape
    m = filtered & (dist_px >= r_min / res) & (dist_px <= r_max / res)
    flat = np.flatnonzero(m)
    owner = feat.ravel()[flat]
    pr, pc = np.divmod(flat, W)
    orr, occ = np.divmod(owner, W)
    sector = (((np.arctan2(pr - orr, pc - occ) + np.pi) / (2 * np.pi) * nbins).astype(np.int64)) % nbins
    key = np.unique(owner * nbins + sector)
    mask = np.zeros(H * W, dtype=np.uint64)
    np.bitwise_or.at(mask, key // nbins, np.left_shift(np.uint64(1), (key % nbins).astype(np.uint64)))
    mask = mask.reshape(H, W)
    pad = np.pad(mask, 1)
    pooled = np.zeros_like(mask)
    for dr in (0, 1, 2):
        for dc in (0, 1, 2):
            pooled |= pad[dr:dr + H, dc:dc + W]
    pooled[filtered] = 0
    full = np.uint64((1 << nbins) - 1)
    run = np.zeros((H, W), dtype=np.int16)
    cur = pooled
    one, back = np.uint64(1), np.uint64(nbins - 1)
    for _ in range(nbins):
        nz = cur != 0
        if not nz.any():
            break
        run[nz] += 1
        cur = cur & (((cur << one) | (cur >> back)) & full)
    return run * (360.0 / nbins)


def _corner_points(angles: NDArray[np.float64], min_angle: float) -> NDArray[np.int64]:
    """(K, 2) rows and columns of the corners: one pixel (the widest wedge) per 8-connected group of obstacle
    pixels whose wedge is at least ``min_angle`` degrees."""
    mask = angles >= min_angle
    lab, n = ndi.label(mask, structure=_EIGHT)
    if n == 0:
        return np.zeros((0, 2), dtype=np.int64)
    return np.array(ndi.maximum_position(angles, lab, np.arange(1, n + 1)), dtype=np.int64).reshape(-1, 2)


def _runs_along_wall(filtered: NDArray[np.bool_], a: NDArray[np.float64], u: NDArray[np.float64],
                     steps: int) -> bool:
    """Whether a wall runs on from obstacle pixel ``a`` in direction ``u`` for ``steps`` pixels: the line
    (shifted by at most one pixel across) stays on obstacle pixels while free space lies two pixels to one
    side of it (a wall face or a thin wall, not the inside of a thick wall entered at an angle)."""
    H, W = filtered.shape
    v = np.array([-u[1], u[0]])
    t = np.arange(1, steps + 1, dtype=float)[:, None]

    def free_at(p):
        idx = np.rint(p).astype(np.int64)
        ok = (idx[:, 0] >= 0) & (idx[:, 0] < H) & (idx[:, 1] >= 0) & (idx[:, 1] < W)
        out = np.ones(len(idx), dtype=bool)
        out[ok] = filtered[idx[ok, 0], idx[ok, 1]]
        return out

    need = 0.8 * steps
    for s in (0.0, -1.0, 1.0):
        line = a + t * u + s * v
        on_wall = ~free_at(line)
        if on_wall.sum() < need:
            continue
        for side in (-2.0, 2.0):
            if (on_wall & free_at(line + side * v)).sum() >= need:
                return True
    return False


def _free_width(filtered: NDArray[np.bool_], mid: NDArray[np.float64], u: NDArray[np.float64],
                n: NDArray[np.float64], depths: NDArray[np.float64], reach: int) -> float:
    """Largest free chord (pixels) parallel to ``u`` through ``mid + t n`` over the depths ``t``, each side
    of the centre followed up to ``reach`` pixels."""
    H, W = filtered.shape
    k = np.arange(0, reach + 1, dtype=float)
    for sign in (1.0, -1.0):
        pts = mid[None, None, :] + depths[:, None, None] * n[None, None, :] + sign * k[None, :, None] * u[None, None, :]
        idx = np.rint(pts).astype(np.int64)
        ok = (idx[..., 0] >= 0) & (idx[..., 0] < H) & (idx[..., 1] >= 0) & (idx[..., 1] < W)
        fr = np.zeros(ok.shape, dtype=bool)
        fr[ok] = filtered[idx[ok][:, 0], idx[ok][:, 1]]
        # free run from the centre: index of the first obstacle (reach + 1 when none)
        blocked = ~fr
        first = np.where(blocked.any(1), blocked.argmax(1), reach + 1)
        if sign > 0:
            run = first.astype(float)
        else:
            run = run + first - 1.0  # the centre pixel counted twice
    return float(np.median(np.maximum(run, 0.0)))


def _wall_gap_lines(filtered: NDArray[np.bool_], dist_px: NDArray[np.float64], corners: NDArray[np.int64],
                    res: float, cfg: SegmentationConfig) -> list[tuple[NDArray[np.int64], NDArray[np.int64], float]]:
    """Lines across gaps in walls: between two corners (obstacle pixels with a wide wedge of free space)
    at most ``max_gap_width`` apart, along a free straight line, with no obstacle in the disc it is the
    diameter of (the corners face each other), continuing a wall beyond at least one end, and narrow
    relative to the free space on both sides: at most ``gap_ratio`` times the widest free chord parallel
    to it within its own length on either side. Returns (a, b, width in metres) per line."""
    from scipy.spatial import cKDTree

    if len(corners) < 2:
        return []
    pairs = cKDTree(corners).query_pairs(cfg.max_gap_width / res + 1.0, output_type="ndarray")
    if not len(pairs):
        return []
    a_all = corners[pairs[:, 0]].astype(float)
    b_all = corners[pairs[:, 1]].astype(float)
    length = np.hypot(*(b_all - a_all).T)
    mid = np.rint((a_all + b_all) / 2).astype(np.int64)
    # Gabriel: the midpoint's clearance is half the length (nothing nearer than the two corners)
    ok = (length >= 3.0) & filtered[mid[:, 0], mid[:, 1]]
    ok &= dist_px[mid[:, 0], mid[:, 1]] >= 0.9 * length / 2 - 1.0
    steps = max(2, int(round(cfg.wall_continuation / res)))
    cands = []
    for i in np.nonzero(ok)[0]:
        a, b, L = a_all[i], b_all[i], float(length[i])
        n_s = int(np.ceil(L)) * 2
        t = np.linspace(0.0, 1.0, n_s + 1)[1:-1, None]
        pts = a + t * (b - a)
        far = (np.hypot(*(pts - a).T) > 1.5) & (np.hypot(*(pts - b).T) > 1.5)
        idx = np.rint(pts[far]).astype(np.int64)
        if not filtered[idx[:, 0], idx[:, 1]].all():
            continue
        u = (b - a) / L
        if not (_runs_along_wall(filtered, a, -u, steps) or _runs_along_wall(filtered, b, u, steps)):
            continue
        cands.append(i)
    if not cands:
        return []
    # the free space with every candidate line drawn in as a wall: a line across a corridor then sees the
    # corridor's width on both sides even where rooms open onto the corridor through other candidates
    walls = filtered.copy()
    for i in cands:
        lr, lc = _line_pixels(corners[pairs[i, 0]], corners[pairs[i, 1]])
        walls[lr, lc] = False
    out = []
    for i in cands:
        a, b, L = a_all[i], b_all[i], float(length[i])
        u = (b - a) / L
        nrm = np.array([-u[1], u[0]])
        depths = np.arange(2.0, max(L, 3.0) + 1.0)
        reach = int(np.ceil(L / cfg.gap_ratio)) + 2
        centre = (a + b) / 2
        if all(L - 1.0 <= cfg.gap_ratio * _free_width(walls, centre, u, side * nrm, depths, reach)
               for side in (1.0, -1.0)):
            out.append((corners[pairs[i, 0]], corners[pairs[i, 1]], max(L - 1.0, 0.0) * res))
    return out


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
    """
    cfg = config or SegmentationConfig()
    free_full, geometry = _as_free(grid, resolution)
    res = geometry.resolution
    # work on the bounding box of the free space, padded
    rows = np.nonzero(free_full.any(1))[0]
    cols = np.nonzero(free_full.any(0))[0]
    pad = 3
    r0, r1 = max(rows[0] - pad, 0), min(rows[-1] + pad + 1, free_full.shape[0])
    c0, c1 = max(cols[0] - pad, 0), min(cols[-1] + pad + 1, free_full.shape[1])
    free = np.zeros((r1 - r0 + 2 * pad, c1 - c0 + 2 * pad), dtype=bool)
    free[pad:-pad, pad:-pad] = free_full[r0:r1, c0:c1]
    off = np.array([r0 - pad, c0 - pad])
    steps: dict[str, NDArray] = {}

    # 1. median filter
    if cfg.median_size > 1:
        filtered = ndi.median_filter(free.astype(np.uint8), size=cfg.median_size).astype(bool)
        if cfg.median_keeps_walls:
            filtered &= free
    else:
        filtered = free.copy()
    if not filtered.any():
        filtered = free.copy()
    if cfg.min_obstacle_area > 0:
        occ, n_occ = ndi.label(~filtered, structure=_EIGHT)
        boxes = ndi.find_objects(occ)
        small = np.bincount(occ.ravel(), minlength=n_occ + 1) * res * res < cfg.min_obstacle_area
        small[0] = False
        for k in np.nonzero(small)[0]:
            box = boxes[k - 1]
            if box is not None and max(box[0].stop - box[0].start, box[1].stop - box[1].start) * res >= \
                    cfg.min_obstacle_length:
                small[k] = False
        filtered |= small[occ]
    # 2. skeleton x distance transform
    from skimage.morphology import skeletonize

    if cfg.method == "critical" and cfg.wall_gaps:
        dist_px, feat = ndi.distance_transform_edt(filtered, return_indices=True)
        feat = feat[0].astype(np.int64) * filtered.shape[1] + feat[1]
    else:
        dist_px = ndi.distance_transform_edt(filtered)
    skel = skeletonize(filtered)
    product = np.where(skel, dist_px * res, 0.0)

    # 3. candidates
    rr, cc, nbr = _skeleton_graph(skel)
    dvals = dist_px[rr, cc] * res
    if cfg.method == "paper":
        centres, directions = _paper_candidates(skel, product, rr, cc, nbr, dvals, cfg, res)
    else:
        centres, directions = _critical_candidates(rr, cc, nbr, dvals, cfg, res)

    # 4. door lines
    cut = np.zeros_like(free)
    door_px: list[tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], float]] = []
    max_len = 2.0 * (cfg.max_door_half_width if cfg.method == "critical"
                     else cfg.door_half_width + cfg.door_half_width_tolerance)
    max_steps = int(np.ceil(1.5 * max_len / res)) + 2
    for (r, c), u in zip(centres, directions, strict=True):
        p = np.array([r, c], dtype=float)
        if cfg.method == "paper":
            a = _march(filtered, p, u, max_steps)
            b = _march(filtered, p, -u, max_steps)
        else:
            a, b = _basis_points(filtered, np.array([r, c]), max_steps)
        if a is None or b is None:
            continue
        # the free span: between the facing edges of the two end pixels
        width = max(float(np.hypot(*(a - b))) - 1.0, 0.0) * res
        if width > 1.5 * max_len:
            continue
        lr, lc = _line_pixels(a, b)
        cut[lr, lc] = True
        door_px.append((np.array([r, c]), a, b, np.stack([lr, lc], 1), width))
    n_critical = len(door_px)
    gap_cut = np.zeros_like(free)
    if cfg.method == "critical" and cfg.wall_gaps:
        angles = _corner_angles(filtered, dist_px, feat, res, 0.15, 0.5)
        corners = _corner_points(angles, cfg.corner_angle)
        for a, b, width in _wall_gap_lines(filtered, dist_px, corners, res, cfg):
            lr, lc = _line_pixels(a, b)
            cut[lr, lc] = True
            gap_cut[lr, lc] = True
            door_px.append((np.rint((a + b) / 2).astype(np.int64), a, b, np.stack([lr, lc], 1), width))

    # 5. regions: every line cuts; the critical lines are then judged by the narrowing test, each piece of a
    # line between the wall-gap lines it crosses on its own
    lab, n = ndi.label(filtered & ~cut, structure=_FOUR)
    uf = _UnionFind(n + 1)
    if cfg.method == "critical" and n_critical:
        peak = np.zeros(n + 1)
        # largest clearance of each region (the wall-gap lines are walls): it lies on a local maximum of the
        # distance transform
        clear = ndi.distance_transform_edt(filtered & ~gap_cut) if gap_cut.any() else dist_px
        top = (clear >= ndi.maximum_filter(clear, size=3)) & (lab > 0)
        np.maximum.at(peak, lab[top], clear[top] * res)
        peak[0] = 0.0
        near_gap = ndi.binary_dilation(gap_cut, structure=_EIGHT) if gap_cut.any() else gap_cut
        pieces, regions = [], []
        for _, a, b, px, width in door_px[:n_critical]:
            for run in _pieces_between(px, a, b, near_gap):
                pieces.append((None, a, b, run, width))
                regions.append(_separated_regions(lab, run))
        _merge_by_narrowing(pieces, regions, peak, uf, cfg)
    regions0 = lab.copy()

    # 6. fold the cut pixels into regions, then merge small regions
    lab = _relabel(lab, uf)
    lab = _fill_from_neighbours(lab, free)
    lab[~free] = 0
    lab = _merge_small(lab, res, cfg.min_room_area, cfg.min_isolated_area)
    if cfg.assign_furniture:
        lab = _assign_furniture(lab, free)

    # doors that separate two final rooms
    doors: list[Door] = []
    full_labels = np.zeros(free_full.shape, dtype=np.int32)
    full_labels[r0:r1, c0:c1] = lab[pad:-pad, pad:-pad]
    found = []
    for centre, a, b, px, width in door_px:
        nb = (px[:, None, :] + _OFFSETS[None, :, :]).reshape(-1, 2)
        ok = (nb[:, 0] >= 0) & (nb[:, 0] < lab.shape[0]) & (nb[:, 1] >= 0) & (nb[:, 1] < lab.shape[1])
        v = lab[nb[ok, 0], nb[ok, 1]]
        u, cnt = np.unique(v[v > 0], return_counts=True)
        if len(u) < 2:
            continue
        o = np.argsort(-cnt)
        found.append((width, tuple(sorted((int(u[o[0]]), int(u[o[1]])))), centre, a, b))
    # one door per passage: of several lines between the same rooms closer than a door width, keep the
    # narrowest
    kept: list[tuple] = []
    for width, pair, centre, a, b in sorted(found, key=lambda t: t[0]):
        if any(k[1] == pair and np.hypot(*(k[2] - centre)) * res < max(width, k[0]) for k in kept):
            continue
        kept.append((width, pair, centre, a, b))
    kept.sort(key=lambda t: (t[2][0], t[2][1]))
    for width, pair, centre, a, b in kept:
        ends = geometry.pixel_to_world(np.stack([a, b]) + off)
        doors.append(Door(geometry.pixel_to_world(centre + off), ends, width, pair,
                          (int(centre[0] + off[0]), int(centre[1] + off[1]))))

    if keep_steps:
        def full(img: NDArray, fill=0) -> NDArray:
            out = np.full(free_full.shape, fill, dtype=img.dtype)
            out[r0:r1, c0:c1] = img[pad:-pad, pad:-pad]
            return out

        cand = np.zeros_like(free)
        for (r, c) in centres:
            cand[r, c] = True
        steps = {
            "free": free_full.copy(),
            "filtered": full(filtered),
            "distance": full(dist_px * res),
            "skeleton": full(skel),
            "product": full(product),
            "candidates": full(cand),
            "door_lines": full(cut),
            "gap_lines": full(gap_cut),
            "regions": full(regions0.astype(np.int32)),
        }
    return Segmentation(full_labels, doors, geometry, cfg, steps)


def _paper_candidates(skel, product, rr, cc, nbr, dvals, cfg, res):
    """Centres of the skeleton segments inside the band of half door widths; directions perpendicular."""
    lo = cfg.door_half_width - cfg.door_half_width_tolerance
    hi = cfg.door_half_width + cfg.door_half_width_tolerance
    band = skel & (product >= lo) & (product <= hi)
    seg, n = ndi.label(band, structure=_EIGHT)
    centres, dirs = [], []
    if n == 0:
        return centres, dirs
    coms = ndi.center_of_mass(band, seg, np.arange(1, n + 1))
    br, bc = np.nonzero(band)
    bl = seg[br, bc]
    for k, com in enumerate(coms, start=1):
        m = bl == k
        pr, pc = br[m], bc[m]
        j = int(np.argmin((pr - com[0]) ** 2 + (pc - com[1]) ** 2))
        centre = (int(pr[j]), int(pc[j]))
        # local skeleton direction: principal axis of skeleton pixels within 4 px
        near = (np.abs(rr - centre[0]) <= 4) & (np.abs(cc - centre[1]) <= 4)
        pts = np.stack([rr[near], cc[near]], 1).astype(float)
        if len(pts) < 2:
            continue
        pts -= pts.mean(0)
        _, _, vt = np.linalg.svd(pts, full_matrices=False)
        t = vt[0]
        centres.append(centre)
        dirs.append(np.array([-t[1], t[0]]))
    return centres, dirs


def _critical_candidates(rr, cc, nbr, dvals, cfg, res):
    """Critical points: skeleton pixels with the least clearance within ``critical_radius`` along it."""
    from scipy.spatial import cKDTree

    steps = max(1, int(round(cfg.critical_radius / res)))
    gmin = _geodesic_filter(dvals, nbr, steps, np.minimum)
    degree = (nbr >= 0).sum(1)
    cand = (dvals <= gmin + 1e-9) & (degree >= 2)
    cand &= (dvals >= cfg.min_door_half_width) & (dvals <= cfg.max_door_half_width)
    idx = np.nonzero(cand)[0]
    if not len(idx):
        return [], []
    # non-maximum suppression of ties (plateaus): greedily keep the lowest, drop the others within the radius
    order = idx[np.argsort(dvals[idx], kind="stable")]
    pos = np.stack([rr[order], cc[order]], 1).astype(float)
    tree = cKDTree(pos)
    close = tree.query_ball_point(pos, r=steps - 1e-6)
    alive = np.ones(len(order), dtype=bool)
    centres = []
    for k in range(len(order)):
        if not alive[k]:
            continue
        alive[close[k]] = False
        j = _plateau_centre(int(order[k]), rr, cc, nbr, dvals, 0.5 * res, steps)
        centres.append((int(rr[j]), int(cc[j])))
    return centres, [None] * len(centres)


def _plateau_centre(i: int, rr, cc, nbr: NDArray[np.int64], dvals: NDArray[np.float64], tol: float,
                    steps: int) -> int:
    """The middle of the run of skeleton pixels around ``i`` whose clearance is within ``tol`` of its own
    (a doorway through a thick wall is such a run; its middle is the door's centre)."""
    level = dvals[i] + tol
    seen = {i}
    frontier = [i]
    for _ in range(steps):
        nxt = []
        for a in frontier:
            for b in nbr[a]:
                if b >= 0 and b not in seen and dvals[b] <= level:
                    seen.add(int(b))
                    nxt.append(int(b))
        if not nxt:
            break
        frontier = nxt
    if len(seen) < 3:
        return i
    m = np.fromiter(seen, dtype=np.int64)
    pr, pc = rr[m].astype(float), cc[m].astype(float)
    k = int(np.argmin((pr - pr.mean()) ** 2 + (pc - pc.mean()) ** 2))
    return int(m[k])


def _pieces_between(px: NDArray[np.int64], a: NDArray[np.int64], b: NDArray[np.int64],
                    block: NDArray[np.bool_]) -> list[NDArray[np.int64]]:
    """The runs of a line's pixels ``px`` (from ``a`` to ``b``) outside ``block``, in order along the line."""
    if not block[px[:, 0], px[:, 1]].any():
        return [px]
    d = (b - a).astype(float)
    order = np.argsort((px - a) @ d, kind="stable")
    p = px[order]
    out = block[p[:, 0], p[:, 1]]
    runs, start = [], None
    for i, o in enumerate(np.append(out, True)):
        if not o and start is None:
            start = i
        elif o and start is not None:
            if i - start >= 2:
                runs.append(p[start:i])
            start = None
    return runs


def _separated_regions(lab: NDArray[np.int64], px: NDArray[np.int64]) -> tuple[int, int]:
    """The two regions a door line (pixels ``px``) separates: the two most frequent labels around it."""
    nb = (px[:, None, :] + _OFFSETS[None, :, :]).reshape(-1, 2)
    ok = (nb[:, 0] >= 0) & (nb[:, 0] < lab.shape[0]) & (nb[:, 1] >= 0) & (nb[:, 1] < lab.shape[1])
    v = lab[nb[ok, 0], nb[ok, 1]]
    v = v[v > 0]
    if not len(v):
        return (0, 0)
    u, cnt = np.unique(v, return_counts=True)
    o = np.argsort(-cnt)
    return (int(u[o[0]]), int(u[o[1]])) if len(u) > 1 else (int(u[0]), int(u[0]))


def _merge_by_narrowing(door_px, door_regions, peak, uf, cfg) -> None:
    """Remove doors that are not narrowings (half width > ratio x geometric mean of the two regions' largest
    clearances), least door-like first; merged regions take the larger clearance."""
    if not door_px:
        return
    half = np.array([d[4] / 2.0 for d in door_px])
    pairs = np.array(door_regions, dtype=np.int64)
    root = np.arange(len(peak))
    pk = peak.copy()
    while True:
        ra, rb = root[pairs[:, 0]], root[pairs[:, 1]]
        live = (ra != rb) & (ra > 0) & (rb > 0)
        if not live.any():
            break
        ratio = np.where(live, half / np.maximum(np.sqrt(pk[ra] * pk[rb]), 1e-9), -1.0)
        j = int(np.argmax(ratio))
        if ratio[j] <= cfg.narrowing_ratio:
            break
        a, b = int(ra[j]), int(rb[j])
        root[root == b] = a
        pk[a] = max(pk[a], pk[b])
    for i in range(1, len(root)):
        if root[i] != i:
            uf.union(int(root[i]), i)


def _relabel(lab: NDArray[np.int64], uf: _UnionFind) -> NDArray[np.int64]:
    n = len(uf.parent)
    roots = np.array([uf.find(i) for i in range(n)])
    roots[0] = 0
    return roots[lab]


def _fill_from_neighbours(lab: NDArray[np.int64], free: NDArray[np.bool_]) -> NDArray[np.int64]:
    """Give unlabelled free pixels (door lines, filtered-out specks) the label of a labelled neighbour within
    three pixels; free specks further away stay unlabelled."""
    out = lab.copy()
    for _ in range(3):
        hole = free & (out == 0)
        if not hole.any():
            return out
        grown = ndi.maximum_filter(out, size=3)
        out[hole] = grown[hole]
    return out


def _merge_small(lab: NDArray[np.int64], res: float, min_area: float, min_isolated: float) -> NDArray[np.int64]:
    """Merge regions under ``min_area`` m^2 into the neighbour with the longest shared border; isolated ones
    (no neighbour) are kept if at least ``min_isolated`` m^2, else dropped; renumber 1..R in scan order."""
    lab = lab.copy()
    min_px = min_area / (res * res)
    min_iso_px = min_isolated / (res * res)
    while True:
        n = int(lab.max(initial=0))
        if n == 0:
            return lab
        size = np.bincount(lab.ravel(), minlength=n + 1)
        small = np.nonzero((size < min_px) & (size > 0))[0]
        small = small[small > 0]
        if not len(small):
            break
        borders = _region_borders(lab)
        best: dict[int, tuple[int, int]] = {}
        for (a, b), m in borders.items():
            for x, y in ((a, b), (b, a)):
                if size[x] < min_px and (x not in best or m > best[x][1]
                                          or (m == best[x][1] and size[y] > size[best[x][0]])):
                    best[x] = (y, m)
        remap = np.arange(n + 1)
        changed = False
        # merge the smallest first; a small region merging into another small one is fine (iterates)
        for x in sorted(small, key=lambda k: size[k]):
            if x in best:
                tgt = best[x][0]
                while remap[tgt] != tgt:
                    tgt = remap[tgt]
                if tgt != x:
                    remap[x] = tgt
                    changed = True
            elif size[x] < min_iso_px:
                remap[x] = 0
                changed = True
        # resolve chains
        for i in range(n + 1):
            j = i
            while remap[j] != j:
                j = remap[j]
            remap[i] = j
        lab = remap[lab]
        if not changed:
            break
    u = np.unique(lab)
    u = u[u > 0]
    remap = np.zeros(int(lab.max(initial=0)) + 1, dtype=np.int64)
    remap[u] = np.arange(1, len(u) + 1)
    return remap[lab]


def _assign_furniture(lab: NDArray[np.int64], free: NDArray[np.bool_]) -> NDArray[np.int64]:
    """Occupied blobs entirely surrounded by one room get that room's label."""
    occ, n = ndi.label(~free, structure=_EIGHT)
    if n == 0:
        return lab
    # labels of the pixels bordering each occupied blob
    ring = ndi.binary_dilation(~free, structure=_EIGHT) & free
    _, ind = ndi.distance_transform_edt(free, return_indices=True)
    owner = occ[ind[0][ring], ind[1][ring]]
    room = lab[ring]
    out = lab.copy()
    touches_edge = np.zeros(n + 1, dtype=bool)
    edge = np.concatenate([occ[0], occ[-1], occ[:, 0], occ[:, -1]])
    touches_edge[edge] = True
    pair = np.stack([owner, room], 1)
    u = np.unique(pair, axis=0)
    kinds = np.bincount(u[:, 0], minlength=n + 1)
    only = np.zeros(n + 1, dtype=np.int64)
    only[u[:, 0]] = u[:, 1]
    ok = (kinds == 1) & ~touches_edge & (only > 0)
    ok[0] = False
    m = ok[occ]
    out[m] = only[occ[m]]
    return out


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
