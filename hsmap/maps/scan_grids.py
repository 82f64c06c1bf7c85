"""Occupancy grids from 2D scans (log-odds along each beam) and from a height slice of 3D points."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import EmptyInputError, InputError, ShapeError
from ..geometry import compose, pose_to_matrix, transform_points
from ..limits import check_allocation
from .occupancy import FREE, OCCUPIED, UNKNOWN, GridGeometry, OccupancyGrid

__all__ = ["ScanGridConfig", "grid_from_scans", "grids_from_scan_prefixes", "scans_to_points", "grid_from_point_slice"]


@dataclass
class ScanGridConfig:
    """Log-odds occupancy update for :func:`grid_from_scans`.

    Attributes
    ----------
    hit : float
        Log-odds added to the cell of a beam's end point.
    miss : float
        Log-odds added (negative) to each cell a beam passes through before its end point.
    occupied_above : float
        Cells with log-odds above this are occupied (default: one hit outweighs one miss).
    free_below : float
        Cells with log-odds below this are free (default: one miss suffices).
    max_range_free : bool
        Beams without a return (NaN or ``>= range_max``) clear the cells up to ``range_max``.
    """

    hit: float = 0.85
    miss: float = -0.4
    occupied_above: float = 0.4
    free_below: float = -0.39
    max_range_free: bool = False


def _as_scan_points(scan, name: str) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """(K, 2) beam end points in the sensor frame and a (K,) mask of real returns."""
    if hasattr(scan, "ranges") and hasattr(scan, "angles"):
        r = np.asarray(scan.ranges, dtype=float)
        a = np.asarray(scan.angles, dtype=float)
        if r.shape != a.shape:
            raise ShapeError(f"{name}: ranges {r.shape} and angles {a.shape} differ")
        hit = np.isfinite(r) & (r >= scan.range_min) & (r < scan.range_max)
        rr = np.where(hit, r, np.where(np.isfinite(scan.range_max), scan.range_max, 0.0))
        rr = np.where(np.isfinite(rr), rr, 0.0)
        return np.column_stack([rr * np.cos(a), rr * np.sin(a)]), hit
    pts = np.asarray(scan, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ShapeError(f"{name} must be (N, 2) points or a LaserScan2D, got shape {pts.shape}")
    ok = np.all(np.isfinite(pts), axis=1)  # a row of NaN: a beam without return
    return np.where(ok[:, None], pts, 0.0), ok


def _placed_scans(scans, poses: ArrayLike, extrinsic: ArrayLike | None = None
                  ) -> list[tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]]:
    """Each scan's sensor position (2,), its beam end points in the world (K, 2) and its mask of real returns (K,).

    ``poses`` (M, 3) are the robot's; ``extrinsic`` is the sensor's pose in the robot frame, one (3,) for all
    scans or one per scan (M, 3); default identity.
    """

    poses = np.asarray(poses, dtype=float)
    scans = list(scans)
    if poses.ndim != 2 or poses.shape[1] != 3 or len(poses) != len(scans):
        raise ShapeError(f"poses must have shape ({len(scans)}, 3) (x, y, yaw) for {len(scans)} scans, "
                         f"got {poses.shape}")
    ext = np.zeros(3) if extrinsic is None else np.asarray(extrinsic, dtype=float)
    if ext.shape == (3,):
        ext = np.broadcast_to(ext, poses.shape)
    if ext.shape != poses.shape:
        raise ShapeError(f"extrinsic must have shape (3,) or ({len(scans)}, 3), got {ext.shape}")
    out = []
    for i, (scan, pose, e) in enumerate(zip(scans, poses, ext, strict=True)):
        pts, hit = _as_scan_points(scan, f"scans[{i}]")
        sensor = compose(pose, e)
        out.append((sensor[:2], transform_points(pose_to_matrix(sensor), pts), hit))
    return out


def scans_to_points(scans, poses: ArrayLike, extrinsic: ArrayLike | None = None) -> NDArray[np.float64]:
    """World (x, y) of the real returns of 2D scans placed at robot poses, all scans stacked.

    Parameters
    ----------
    scans : sequence of (K_i, 2) arrays or LaserScan2D
        Each scan in its sensor frame.
    poses : ndarray of shape (M, 3)
        World pose (x, y, yaw) of the robot at each scan (M = len(scans)).
    extrinsic : ndarray of shape (3,) or (M, 3), optional
        Pose of the sensor in the robot frame, one for all scans or one per scan (default identity).

    Returns
    -------
    ndarray of shape (N, 2)
    """
    placed = _placed_scans(scans, poses, extrinsic)
    return np.vstack([w[hit] for _, w, hit in placed]) if placed else np.empty((0, 2))


def grid_from_scans(
    scans,
    poses: ArrayLike,
    resolution: float = 0.05,
    *,
    extrinsic: ArrayLike | None = None,
    geometry: GridGeometry | None = None,
    margin: float = 0.5,
    config: ScanGridConfig | None = None,
) -> OccupancyGrid:
    """Occupancy grid from 2D scans taken at known poses: free along each beam, occupied at its end.

    Each scan adds ``config.miss`` to every cell its beams sweep (the scan polygon from the sensor through the
    consecutive end points, rasterised; a beam with no return contributes the sensor position, i.e. nothing,
    unless ``config.max_range_free``) and ``config.hit`` to the cell of every end point; the summed
    log-odds are thresholded.

    Parameters
    ----------
    scans : sequence of (N_i, 2) arrays or LaserScan2D
        Each scan in its sensor frame. Arrays are end points in beam order, a row of NaN a beam without a return
        (as a LaserScan2D's no-return beams: the swept area goes back to the sensor there instead of cutting
        across the unseen part between its neighbours).
    poses : ndarray of shape (M, 3)
        World pose (x, y, yaw) of the robot at each scan (M = len(scans)).
    resolution : float
        Metres per cell.
    extrinsic : ndarray of shape (3,) or (M, 3), optional
        Pose of the sensor in the robot frame, one for all scans or one per scan (default identity).
    geometry : GridGeometry, optional
        The grid to fill; by default the smallest grid covering all beams plus ``margin``.
    config : ScanGridConfig, optional
        Log-odds increments and thresholds.

    Returns
    -------
    OccupancyGrid
        Cells no beam touched are unknown.
    """
    return grids_from_scan_prefixes(scans, poses, [len(poses)], resolution, extrinsic=extrinsic, geometry=geometry,
                                    margin=margin, config=config)[0]


def _scans_in_world(scans, poses: NDArray[np.float64], extrinsic: ArrayLike | None,
                    cfg: ScanGridConfig) -> list[tuple[int, NDArray, NDArray, NDArray]]:
    """(index, sensor position, end points, hit mask) of every scan that adds to a grid, in the world."""
    world = []
    for k, (sensor, w, hit) in enumerate(_placed_scans(scans, poses, extrinsic)):
        if not cfg.max_range_free:
            w[~hit] = sensor
        if hit.any() or (cfg.max_range_free and len(w)):
            world.append((k, sensor, w, hit))
    if not world:
        raise EmptyInputError("grid_from_scans: no valid return in any scan")
    return world


def _covering(world: list, resolution: float, margin: float, max_cells: int | None) -> tuple[GridGeometry, float]:
    """The geometry covering every sensor position and end point of ``world``, and its resolution: coarsened
    where the grid would have more than ``max_cells`` cells."""
    allp = np.vstack([np.vstack([o[None], w]) for _, o, w, _ in world])
    lo, hi = allp.min(0), allp.max(0)
    geometry = GridGeometry.covering(lo, hi, resolution, margin)
    if max_cells is not None and geometry.height * geometry.width > max_cells:
        side = hi - lo + 2 * margin  # the coarsest cell that fits, then up until the rounding fits too
        resolution = float(np.sqrt(side[0] * side[1] / max_cells))
        geometry = GridGeometry.covering(lo, hi, resolution, margin)
        while geometry.height * geometry.width > max_cells:
            resolution *= 1.01
            geometry = GridGeometry.covering(lo, hi, resolution, margin)
    return geometry, resolution


class _LogOdds:
    """The log-odds of a grid's cells and which cells any beam touched, scan by scan."""

    def __init__(self, geometry: GridGeometry, cfg: ScanGridConfig) -> None:
        self.geometry, self.cfg = geometry, cfg
        self.logodds = np.zeros(geometry.shape)
        self.touched = np.zeros(geometry.shape, dtype=bool)

    def grid(self) -> OccupancyGrid:
        cfg, touched, logodds = self.cfg, self.touched, self.logodds
        data = np.full(self.geometry.shape, UNKNOWN, dtype=np.int8)
        data[touched & (logodds < cfg.free_below)] = FREE
        data[touched & (logodds > cfg.occupied_above)] = OCCUPIED
        return OccupancyGrid(data, self.geometry)

    def add(self, o: NDArray[np.float64], w: NDArray[np.float64], hit: NDArray[np.bool_]) -> None:
        """One scan from sensor position ``o``: a miss on the area its beams swept, a hit at each of its hits."""
        from PIL import Image, ImageDraw

        geometry, cfg, logodds, touched = self.geometry, self.cfg, self.logodds, self.touched
        H, W = geometry.shape
        # the swept area stops short of each end point by 0.75 cell, so the hit cell and those behind it
        # are not cleared by rounding
        v = w - o
        n = np.linalg.norm(v, axis=1, keepdims=True)
        w_short = o + v * np.clip(1.0 - 0.75 * geometry.resolution / np.maximum(n, 1e-12), 0.0, 1.0)
        poly = geometry.world_to_pixel(np.vstack([o[None], w_short]))  # (row, col), centres at integers
        lo = np.floor(poly.min(0)).astype(int) - 1
        hi = np.ceil(poly.max(0)).astype(int) + 2
        lo = np.maximum(lo, 0)
        hi = np.minimum(hi, [H, W])
        if np.any(hi <= lo):
            return
        canvas = Image.new("1", (int(hi[1] - lo[1]), int(hi[0] - lo[0])), 0)
        xy = (poly[:, ::-1] - lo[::-1]).ravel().tolist()  # PIL wants (x=col, y=row) pairs
        ImageDraw.Draw(canvas).polygon(xy, fill=1)
        swept = np.asarray(canvas, dtype=bool).copy()
        idx = geometry.world_to_index(w[hit])
        ok = geometry.inside(idx)
        hr, hc = idx[ok, 0], idx[ok, 1]
        inside = (hr >= lo[0]) & (hr < hi[0]) & (hc >= lo[1]) & (hc < hi[1])
        swept[hr[inside] - lo[0], hc[inside] - lo[1]] = False  # a scan's own hits are no misses
        box = logodds[lo[0]:hi[0], lo[1]:hi[1]]
        np.add(box, cfg.miss, out=box, where=swept)  # in place, no box-sized temporary (a 30 m scan's is 1.4 M cells)
        touched[lo[0]:hi[0], lo[1]:hi[1]] |= swept
        np.add.at(logodds, (hr, hc), cfg.hit)
        touched[hr, hc] = True


def grids_from_scan_prefixes(
    scans,
    poses: ArrayLike,
    counts: ArrayLike,
    resolution: float = 0.05,
    *,
    extrinsic: ArrayLike | None = None,
    geometry: GridGeometry | None = None,
    margin: float = 0.5,
    config: ScanGridConfig | None = None,
    max_cells: int | None = None,
) -> list[OccupancyGrid]:
    """The grids of :func:`grid_from_scans` of the first ``counts[i]`` scans, for each i, in one pass: each scan
    is rasterised once (a map growing along a recording's timeline costs one grid, not one per update).

    ``counts`` must not decrease; the grids share one geometry (``geometry``, else the one covering all the
    scans). Each grid is the one :func:`grid_from_scans` gives for the same scans on that geometry. With
    ``max_cells`` (and no ``geometry``), the resolution is coarsened where the covering grid would have more
    cells than that (a view of a campus-sized log: 5 cm cells over 444 m x 237 m are 42 million).
    """
    cfg = config or ScanGridConfig()
    if not (np.isfinite(resolution) and resolution > 0):
        raise InputError(f"resolution must be a positive number of metres per cell, got {resolution}")
    if max_cells is not None and not (isinstance(max_cells, (int, np.integer)) and max_cells >= 1):
        raise InputError(f"max_cells must be None or a positive integer, got {max_cells!r}")
    poses = np.asarray(poses, dtype=float)
    counts = [int(c) for c in np.atleast_1d(np.asarray(counts))]
    if any(b < a for a, b in zip(counts, counts[1:], strict=False)) or (counts and counts[0] < 0):
        raise InputError(f"counts must be >= 0 and must not decrease, got {counts}")
    world = _scans_in_world(scans, poses, extrinsic, cfg)
    if geometry is None:
        geometry, resolution = _covering(world, resolution, margin, max_cells)
    H, W = geometry.shape
    check_allocation(float(H) * float(W) * (16 + len(counts)),
                     f"a {W} x {H} cell occupancy grid at {resolution:g} m per cell (the resolution)")
    acc = _LogOdds(geometry, cfg)
    grids: list[OccupancyGrid] = []
    pending = list(counts)
    for k, o, w, hit in world:
        while pending and pending[0] <= k:  # the grids of the prefixes of at most k scans
            pending.pop(0)
            grids.append(acc.grid())
        acc.add(o, w, hit)
    grids.extend(acc.grid() for _ in pending)
    return grids


def grid_from_point_slice(
    points: ArrayLike,
    *,
    z_min: float = 1.7,
    z_max: float = 1.8,
    resolution: float = 0.05,
    floor_band: tuple[float, float] | None = (-0.15, 0.15),
    geometry: GridGeometry | None = None,
    margin: float = 0.5,
    min_points: int = 1,
) -> OccupancyGrid:
    """Occupancy grid from a horizontal slice of a 3D point map (the paper slices at 1.7-1.8 m).

    Cells holding at least ``min_points`` points with ``z_min <= z < z_max`` are occupied (walls above the
    furniture). Cells holding floor points (``floor_band[0] <= z < floor_band[1]``) and no slice point are
    free: the floor is seen wherever the room is open. Everything else is unknown.

    Parameters
    ----------
    points : ndarray of shape (N, 3)
        World points, z up, metres.
    z_min, z_max : float
        The slice (z_min < z_max).
    resolution : float
        Metres per cell.
    floor_band : (float, float) or None
        Height band of floor points giving free space; None leaves non-occupied cells unknown.
    geometry : GridGeometry, optional
        The grid to fill (e.g. a 2D map's, to overlay both); by default the slice's and floor's extent
        plus ``margin``.
    min_points : int
        Points a cell needs to count as occupied.
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ShapeError(f"points must have shape (N, 3), got {pts.shape}")
    if not z_min < z_max:
        raise InputError(f"the slice needs z_min < z_max, got {z_min} >= {z_max}")
    if not (np.isfinite(resolution) and resolution > 0):
        raise InputError(f"resolution must be a positive number of metres per cell, got {resolution}")
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    in_slice = (pts[:, 2] >= z_min) & (pts[:, 2] < z_max)
    on_floor = (
        (pts[:, 2] >= floor_band[0]) & (pts[:, 2] < floor_band[1]) if floor_band is not None else np.zeros(len(pts), bool)
    )
    if not in_slice.any():
        raise EmptyInputError(f"no point lies in the slice {z_min} <= z < {z_max} (of {len(pts)} points)")
    if geometry is None:
        used = pts[in_slice | on_floor, :2]
        geometry = GridGeometry.covering(used.min(0), used.max(0), resolution, margin)
    H, W = geometry.shape

    def counts(mask: NDArray[np.bool_]) -> NDArray[np.int64]:
        idx = geometry.world_to_index(pts[mask, :2])
        ok = geometry.inside(idx)
        return np.bincount(idx[ok, 0] * W + idx[ok, 1], minlength=H * W)

    occ = counts(in_slice) >= max(1, int(min_points))
    data = np.full(H * W, UNKNOWN, dtype=np.int8)
    if floor_band is not None:
        data[counts(on_floor) > 0] = FREE
    data[occ] = OCCUPIED
    return OccupancyGrid(data.reshape(H, W), geometry)
