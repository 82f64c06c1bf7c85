"""2D/3D map fusion: the floor-level 2D map registered to the high slice of the 3D map (the paper's Figure 13).

The robot carries a 2D LiDAR near the floor and a 3D LiDAR on top. The 2D map (built from the 2D scans) sees
the walls and everything standing on the floor: table and chair legs, desks, cabinets, sofas. The slice of the
3D map at 1.7-1.8 m (above the furniture) sees the walls and only the tallest furniture (shelves), and sees
over the furniture to the walls behind it. The two maps therefore overlap only partly: in the walls.

Each HS-SLAM run lives in its own frame (its first pose), so the two maps must be registered before they can be
overlaid. :func:`align_maps` registers the occupied cells (or points) of the floor map to those of the slice
with :func:`hsmap.harmony_icp` (3-DOF, a global search: no initial guess is needed within the configured box),
resamples both grids onto one grid in the slice's frame, and scores their overlap: the fraction of occupied
cells of each map within ``tolerance`` of an occupied cell of the other. :func:`overlay_image` colours the
cells seen by both maps, by the floor map only and by the slice only.

The slice itself comes from the 3D clouds placed at their poses (:func:`slice_grid`, in
:mod:`hsmap.maps.slicing`, re-exported here).

Coordinates: world (x, y[, z]) in metres, z up, the floor at z = 0; grids convert through
:class:`hsmap.maps.grid.GridGeometry` only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage as ndi

from ..errors import ConfigError, EmptyInputError, InputError, ShapeError
from ..geometry import matrix_to_pose, pose_to_matrix
from ..registration.correlative import correlative_match_2d
from ..registration.harmony import HarmonyConfig
from ..registration.icp import RegistrationConfig, RegistrationResult, harmony_icp
from .grid import UNKNOWN, GridGeometry, OccupancyGrid
from .slicing import slice_grid, slice_points, slice_scan, slice_scans

__all__ = [
    "FusionConfig",
    "MapAlignment",
    "OVERLAY_COLORS",
    "align_maps",
    "common_grids",
    "global_align",
    "GlobalSearch",
    "occupied_points",
    "overlap_scores",
    "overlay_classes",
    "overlay_image",
    "resample_grid",
    "slice_grid",
    "slice_points",
    "slice_scan",
    "slice_scans",
]


def _map_registration() -> RegistrationConfig:
    return RegistrationConfig(
        harmony=HarmonyConfig(memory_size=30, batch_size=16, max_iterations=500, patience=30,
                              convergence_tol=1e-6, init="lhs"),
        search_threshold=0.5,
        fine_threshold=0.15,
        threshold=0.10,
        max_points=400,
        voxel_size=0.05,
        translation_range=2.0,
        yaw_range=np.deg2rad(45.0),
        refine_points=6000,
        refine_iterations=40,
    )


@dataclass
class FusionConfig:
    """Parameters of the 2D/3D map alignment (lengths in metres).

    Attributes
    ----------
    z_min, z_max : float
        The slice of the 3D map (the paper: 1.7-1.8 m, above the furniture).
    resolution : float
        Metres per cell of the grids.
    slice_bins : int
        Azimuth bins of the virtual 2D scans a 3D cloud's slice is reduced to (:func:`slice_scan`).
    tolerance : float
        Occupied cells of one map within this distance of an occupied cell of the other count as seen by both
        (overlap score and overlay).
    registration : RegistrationConfig
        Harmony-ICP settings. Its ``translation_range`` and ``yaw_range`` (default 2 m and 45 deg) give the
        search box around the initial guess (or the identity) when no ``bounds`` are passed: two maps of the
        same building agree to a few metres and tens of degrees, and a wider yaw range lets the rotational
        symmetries of a building (a rectangle matches itself turned by 180 deg) compete.
    """

    z_min: float = 1.7
    z_max: float = 1.8
    resolution: float = 0.05
    slice_bins: int = 720
    tolerance: float = 0.10
    registration: RegistrationConfig = field(default_factory=_map_registration)

    def __post_init__(self) -> None:
        if not (np.isfinite(self.z_min) and np.isfinite(self.z_max) and self.z_min < self.z_max):
            raise ConfigError(f"fusion.z_min must be < fusion.z_max, got {self.z_min} and {self.z_max}")
        if not (np.isfinite(self.resolution) and self.resolution > 0):
            raise ConfigError(f"fusion.resolution must be > 0 metres, got {self.resolution}")
        if not isinstance(self.slice_bins, (int, np.integer)) or self.slice_bins < 8:
            raise ConfigError(f"fusion.slice_bins must be an integer >= 8, got {self.slice_bins!r}")
        if not (np.isfinite(self.tolerance) and self.tolerance >= 0):
            raise ConfigError(f"fusion.tolerance must be >= 0 metres, got {self.tolerance}")
        if isinstance(self.registration, dict):
            from ..config import from_dict

            self.registration = from_dict(RegistrationConfig, self.registration, "fusion.registration")
        if not isinstance(self.registration, RegistrationConfig):
            raise ConfigError(f"fusion.registration must be a RegistrationConfig, got "
                              f"{type(self.registration).__name__}")


# ----------------------------------------------------------------------------------------------------------
# grids: points, resampling, overlap
# ----------------------------------------------------------------------------------------------------------


def occupied_points(grid: OccupancyGrid) -> NDArray[np.float64]:
    """World (x, y) of the centres of the occupied cells of ``grid``: (K, 2)."""
    if not isinstance(grid, OccupancyGrid):
        raise InputError(f"expected an hsmap.maps.grid.OccupancyGrid, got {type(grid).__name__}")
    rc = np.argwhere(grid.occupied)
    return grid.geometry.pixel_to_world(rc)


def resample_grid(
    image: OccupancyGrid | ArrayLike,
    geometry: GridGeometry | None = None,
    target: GridGeometry | None = None,
    transform: ArrayLike | None = None,
    *,
    fill: int = UNKNOWN,
) -> OccupancyGrid | NDArray:
    """Nearest-neighbour resampling of a grid (or any (H, W) image) onto another grid, optionally moved.

    Parameters
    ----------
    image : OccupancyGrid or ndarray of shape (H, W)
        The source; an OccupancyGrid brings its own geometry.
    geometry : GridGeometry
        Where ``image`` lies (only for plain arrays).
    target : GridGeometry
        The grid to fill.
    transform : ndarray of shape (3, 3) or (3,), optional
        Rigid transform (matrix or (x, y, yaw)) mapping the source's world frame into the target's world frame
        (default identity).
    fill : int
        Value of target cells that fall outside the source.

    Returns
    -------
    OccupancyGrid (for an OccupancyGrid input) or ndarray of shape target.shape (same dtype as ``image``).
    """
    if isinstance(image, OccupancyGrid):
        data, geo, as_grid = image.data, image.geometry, True
    else:
        data, geo, as_grid = np.asarray(image), geometry, False
        if geo is None:
            raise InputError("resample_grid: a plain image needs its geometry")
        if data.shape[:2] != geo.shape:
            raise ShapeError(f"image {data.shape[:2]} differs from its geometry {geo.shape}")
    if not isinstance(target, GridGeometry):
        raise InputError(f"resample_grid: target must be a GridGeometry, got {type(target).__name__}")
    T = np.eye(3) if transform is None else np.asarray(transform, dtype=float)
    if T.shape == (3,):
        T = pose_to_matrix(T)
    if T.shape != (3, 3) or not np.all(np.isfinite(T)):
        raise ShapeError(f"transform must be a finite 3x3 matrix or an (x, y, yaw) pose, got shape {T.shape}")
    H, W = target.shape
    rr, cc = np.mgrid[0:H, 0:W]
    xy = target.pixel_to_world(np.stack([rr.ravel(), cc.ravel()], -1))
    R, t = T[:2, :2], T[:2, 2]
    src_xy = (xy - t) @ R  # R^T (p - t): target world -> source world
    idx = geo.world_to_index(src_xy)
    ok = geo.inside(idx)
    out = np.full((H * W,) + data.shape[2:], fill, dtype=data.dtype)
    out[ok] = data[idx[ok, 0], idx[ok, 1]]
    out = out.reshape((H, W) + data.shape[2:])
    return OccupancyGrid(out, target) if as_grid else out


def _snapped_union(base: GridGeometry, other: GridGeometry, T: NDArray[np.float64], resolution: float,
                   margin: float) -> GridGeometry:
    """A grid at ``resolution`` on ``base``'s lattice covering ``base`` and ``other`` moved by ``T``."""
    x0, x1, y0, y1 = other.extent()
    corners = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]]) @ T[:2, :2].T + T[:2, 2]
    bx0, bx1, by0, by1 = base.extent()
    lo = np.minimum(corners.min(0), [bx0, by0]) - margin
    hi = np.maximum(corners.max(0), [bx1, by1]) + margin
    o = np.asarray(base.origin)
    lo = o + np.floor((lo - o) / resolution) * resolution
    n = np.maximum(np.ceil((hi - lo) / resolution - 1e-9).astype(int), 1)
    return GridGeometry((int(n[1]), int(n[0])), resolution, (float(lo[0]), float(lo[1])))


def overlap_scores(a: ArrayLike, b: ArrayLike, resolution: float, tolerance: float = 0.10) -> dict[str, float]:
    """How much two occupied masks on the same grid agree, within ``tolerance`` metres.

    Returns
    -------
    dict
        ``a_matched``: fraction of a's occupied cells within ``tolerance`` of one of b's; ``b_matched``: the
        converse; ``overlap``: both together, ``(matched a + matched b) / (a + b)`` (a tolerant Dice score:
        1 when each map's structure lies on the other's); ``a_cells``, ``b_cells``: the counts.
    """
    A = np.asarray(a, dtype=bool)
    B = np.asarray(b, dtype=bool)
    if A.shape != B.shape or A.ndim != 2:
        raise ShapeError(f"the two masks must be 2D and of one shape, got {A.shape} and {B.shape}")
    na, nb = int(A.sum()), int(B.sum())
    if na == 0 or nb == 0:
        raise EmptyInputError(f"overlap needs occupied cells in both maps, got {na} and {nb}")
    da = ndi.distance_transform_edt(~A) * resolution
    db = ndi.distance_transform_edt(~B) * resolution
    tol = tolerance + 1e-9
    ma = int((A & (db <= tol)).sum())
    mb = int((B & (da <= tol)).sum())
    return {"a_matched": ma / na, "b_matched": mb / nb, "overlap": (ma + mb) / (na + nb),
            "a_cells": na, "b_cells": nb}


#: Overlay classes of :func:`overlay_classes` and their RGB colours in :func:`overlay_image`.
OVERLAY_COLORS: dict[str, tuple[int, int, int]] = {
    "unknown": (215, 215, 215),
    "free": (255, 255, 255),
    "both": (20, 20, 20),
    "floor only": (214, 39, 40),
    "slice only": (31, 119, 180),
}
_CLASS_ORDER = ("unknown", "free", "both", "floor only", "slice only")


def overlay_classes(floor: OccupancyGrid, slice_: OccupancyGrid, tolerance: float = 0.10) -> NDArray[np.uint8]:
    """Per cell: 0 unknown in both, 1 free (in either, occupied in neither), 2 occupied and matched by the
    other map within ``tolerance`` ("both"), 3 occupied in the floor map only, 4 in the slice only.

    Both grids must share one geometry (see :func:`resample_grid`, :attr:`MapAlignment.floor`)."""
    for name, g in (("floor", floor), ("slice", slice_)):
        if not isinstance(g, OccupancyGrid):
            raise InputError(f"{name} must be an OccupancyGrid, got {type(g).__name__}")
    if floor.geometry != slice_.geometry:
        raise ShapeError(f"the grids must share one geometry (resample first), got {floor.geometry} and "
                         f"{slice_.geometry}")
    A, B = floor.occupied, slice_.occupied
    res = floor.geometry.resolution
    tol = tolerance + 1e-9
    near_b = ndi.distance_transform_edt(~B) * res <= tol if B.any() else np.zeros_like(B)
    near_a = ndi.distance_transform_edt(~A) * res <= tol if A.any() else np.zeros_like(A)
    out = np.zeros(A.shape, dtype=np.uint8)
    out[floor.free | slice_.free] = 1
    out[A & ~near_b] = 3
    out[B & ~near_a] = 4
    out[(A & near_b) | (B & near_a)] = 2
    return out


def overlay_image(floor: OccupancyGrid, slice_: OccupancyGrid, tolerance: float = 0.10,
                  colors: dict[str, tuple[int, int, int]] | None = None) -> NDArray[np.uint8]:
    """(H, W, 3) uint8 picture of two aligned grids: structure seen by both maps dark, by the floor map only
    red, by the slice only blue, free white, unknown light grey (see :data:`OVERLAY_COLORS`)."""
    cols = {**OVERLAY_COLORS, **(colors or {})}
    lut = np.array([cols[k] for k in _CLASS_ORDER], dtype=np.uint8)
    return lut[overlay_classes(floor, slice_, tolerance)]


# ----------------------------------------------------------------------------------------------------------
# the alignment
# ----------------------------------------------------------------------------------------------------------


@dataclass
class MapAlignment:
    """Result of :func:`align_maps`.

    Attributes
    ----------
    transformation : ndarray of shape (3, 3)
        Maps the floor map's world frame into the slice's (the 3D map's) frame.
    pose : ndarray of shape (3,)
        The same as (x, y, yaw).
    floor : OccupancyGrid
        The floor map moved by ``transformation`` and resampled onto the common grid (the slice's frame).
    slice : OccupancyGrid
        The slice on the common grid.
    overlap : float
        Tolerant Dice score of the two aligned maps' occupied cells (see :func:`overlap_scores`).
    floor_matched, slice_matched : float
        Fraction of the floor map's (the slice's) occupied cells within ``tolerance`` of the other's.
    tolerance : float
        Metres, the matching distance of the scores.
    registration : RegistrationResult
        The Harmony-ICP result (fitness, inlier ratio, evaluations, ...).
    """

    transformation: NDArray[np.float64]
    pose: NDArray[np.float64]
    floor: OccupancyGrid
    slice: OccupancyGrid
    overlap: float
    floor_matched: float
    slice_matched: float
    tolerance: float
    registration: RegistrationResult

    def overlay(self, colors: dict[str, tuple[int, int, int]] | None = None) -> NDArray[np.uint8]:
        """(H, W, 3) uint8 overlay of the aligned grids (:func:`overlay_image`)."""
        return overlay_image(self.floor, self.slice, self.tolerance, colors)

    def as_dict(self) -> dict:
        """JSON-ready summary (no grids)."""
        return {
            "x": float(self.pose[0]), "y": float(self.pose[1]), "yaw_deg": float(np.rad2deg(self.pose[2])),
            "overlap": self.overlap, "floor_matched": self.floor_matched, "slice_matched": self.slice_matched,
            "tolerance": self.tolerance, "fitness": self.registration.fitness,
            "inlier_ratio": self.registration.inlier_ratio, "rmse": self.registration.rmse,
            "evaluations": self.registration.evaluations, "seconds": self.registration.seconds,
        }


def _as_points2(pts: ArrayLike | None, name: str) -> NDArray[np.float64] | None:
    if pts is None:
        return None
    p = np.asarray(pts, dtype=float)
    if p.ndim != 2 or p.shape[1] != 2:
        raise ShapeError(f"{name} must have shape (N, 2) (world x, y), got {p.shape}")
    p = p[np.all(np.isfinite(p), axis=1)]
    if not len(p):
        raise EmptyInputError(f"{name} has no finite point")
    return p


def align_maps(
    floor: OccupancyGrid,
    slice_: OccupancyGrid,
    *,
    floor_points: ArrayLike | None = None,
    slice_points: ArrayLike | None = None,
    config: FusionConfig | None = None,
    initial_guess: ArrayLike | None = None,
    bounds: ArrayLike | None = None,
    rng: int | np.random.Generator | None = None,
) -> MapAlignment:
    """Register the floor-level 2D map to the slice of the 3D map and overlay them.

    Parameters
    ----------
    floor : OccupancyGrid
        The 2D LiDAR's map (e.g. :func:`hsmap.maps.grid.grid_from_scans` at the 2D SLAM poses), in its own frame.
    slice_ : OccupancyGrid
        The 3D map's slice (e.g. :func:`slice_grid` at the 3D SLAM poses), in the 3D map's frame.
    floor_points, slice_points : ndarray of shape (N, 2), optional
        Points to register instead of the occupied cell centres (e.g. the point maps; finer than the cells).
    config : FusionConfig, optional
    initial_guess : array_like of shape (3,) or (K, 3), optional
        (x, y, yaw) guesses of the floor->slice transform seeding the search (default: none; the search box
        is then centred on the identity).
    bounds : array_like of shape (3, 2), optional
        Absolute search limits of (x, y, yaw); default the configured ranges around the guesses.
    rng : int or Generator, optional

    Returns
    -------
    MapAlignment

    Raises
    ------
    InputError
        A map is not an OccupancyGrid.
    EmptyInputError
        A map has no occupied cell (and no points are given).
    """
    cfg = config or FusionConfig()
    for name, g in (("floor", floor), ("slice_", slice_)):
        if not isinstance(g, OccupancyGrid):
            raise InputError(f"{name} must be an hsmap.maps.grid.OccupancyGrid, got {type(g).__name__}")
    src = _as_points2(floor_points, "floor_points")
    dst = _as_points2(slice_points, "slice_points")
    if src is None:
        src = occupied_points(floor)
        if not len(src):
            raise EmptyInputError("the floor map has no occupied cell to register")
    if dst is None:
        dst = occupied_points(slice_)
        if not len(dst):
            raise EmptyInputError("the slice has no occupied cell to register to")
    if len(src) < 3 or len(dst) < 3:
        raise EmptyInputError(f"registration needs at least 3 points in each map, got {len(src)} and {len(dst)}")
    res = harmony_icp(src, dst, initial_guesses=initial_guess, bounds=bounds, config=cfg.registration, rng=rng)
    T = res.transformation
    geo = _snapped_union(slice_.geometry, floor.geometry, T, cfg.resolution, 0.0)
    floor_c, slice_c = _crop_known(resample_grid(floor, target=geo, transform=T), resample_grid(slice_, target=geo))
    sc = overlap_scores(floor_c.occupied, slice_c.occupied, cfg.resolution, cfg.tolerance)
    return MapAlignment(T, res.pose.copy(), floor_c, slice_c, sc["overlap"], sc["a_matched"], sc["b_matched"],
                        float(cfg.tolerance), res)


@dataclass(frozen=True)
class GlobalSearch:
    """The exhaustive search of :func:`global_align` (lengths in metres).

    Attributes
    ----------
    resolution : float
        Translation step of the fine correlative search (its coarse grid is 4 times coarser).
    angle_step_deg : float
        Rotation step, degrees; every rotation of the full turn is scored.
    cell : float
        The points of each map are thinned to one per cell of this size before the search.
    refine_translation, refine_yaw_deg : float
        Half sides of the Harmony-ICP box around each candidate of the search.
    """

    resolution: float = 0.1
    angle_step_deg: float = 1.0
    cell: float = 0.1
    refine_translation: float = 0.5
    refine_yaw_deg: float = 3.0

    def __post_init__(self) -> None:
        for name in ("resolution", "angle_step_deg", "cell", "refine_translation", "refine_yaw_deg"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ConfigError(f"GlobalSearch.{name} must be > 0, got {v}")


def _thinned(points: NDArray[np.float64], cell: float) -> NDArray[np.float64]:
    """One point (the first) per ``cell``-sized square: (M, 2)."""
    keys = np.floor(points / cell).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return points[np.sort(first)]


def _correlative_candidate(src: NDArray[np.float64], dst: NDArray[np.float64], search: GlobalSearch
                           ) -> tuple[NDArray[np.float64], float, float]:
    """The pose (x, y, yaw) of ``src`` in ``dst``'s frame best explaining ``src`` by ``dst`` over every rotation
    and every translation that makes the two overlap; with its score and ambiguity
    (:func:`hsmap.registration.correlative.correlative_match_2d`)."""

    centre = src.mean(axis=0)
    s = src - centre
    lo, hi = dst.min(axis=0), dst.max(axis=0)
    half = float(np.max((hi - lo) / 2.0) + np.linalg.norm(s, axis=1).max())
    pose, score, ambiguity = correlative_match_2d(
        s, dst, np.r_[(lo + hi) / 2.0, 0.0], half, np.pi, resolution=search.resolution,
        angle_step=float(np.deg2rad(search.angle_step_deg)), separation=2.0)
    c, si = np.cos(pose[2]), np.sin(pose[2])
    t = pose[:2] - np.array([[c, -si], [si, c]]) @ centre
    return np.array([t[0], t[1], pose[2]]), float(score), float(ambiguity)


def global_align(
    floor: OccupancyGrid,
    slice_: OccupancyGrid,
    *,
    floor_points: ArrayLike | None = None,
    slice_points: ArrayLike | None = None,
    config: FusionConfig | None = None,
    search: GlobalSearch | None = None,
    rng: int | np.random.Generator | None = None,
) -> tuple[MapAlignment, list[dict]]:
    """Register two 2D maps of one building with no initial guess: an exhaustive correlative search over every
    rotation and every overlapping translation, then Harmony-ICP around its candidates.

    The search runs both ways (the floor map's structure explained by the slice's, and the converse, so that
    neither map needs to cover the other); each way's best pose is a candidate, and :func:`align_maps` refines
    them together in a box of ``search.refine_translation`` / ``search.refine_yaw_deg`` around each.

    Parameters
    ----------
    floor, slice_ : OccupancyGrid
        The map to move and the map it is registered to (see :func:`align_maps`).
    floor_points, slice_points : ndarray of shape (N, 2), optional
        Points to register instead of the occupied cell centres.
    config : FusionConfig, optional
    search : GlobalSearch, optional
    rng : int or Generator, optional
        Seeds the Harmony-ICP refinement (the search is deterministic).

    Returns
    -------
    (MapAlignment, candidates)
        The alignment (floor -> slice) and per search direction a dict with the candidate pose (x, y, yaw_deg in
        the floor -> slice direction), its correlative score and ambiguity.
    """
    import dataclasses

    cfg = config or FusionConfig()
    sch = search or GlobalSearch()
    src = _as_points2(floor_points, "floor_points")
    dst = _as_points2(slice_points, "slice_points")
    src = occupied_points(floor) if src is None else src
    dst = occupied_points(slice_) if dst is None else dst
    if len(src) < 3 or len(dst) < 3:
        raise EmptyInputError(f"registration needs at least 3 occupied points in each map, got {len(src)} and "
                              f"{len(dst)}")
    a, b = _thinned(src, sch.cell), _thinned(dst, sch.cell)
    candidates = []
    forward, score_f, amb_f = _correlative_candidate(a, b, sch)
    candidates.append({"direction": "floor onto slice", "x": forward[0], "y": forward[1],
                       "yaw_deg": float(np.rad2deg(forward[2])), "score": score_f, "ambiguity": amb_f})
    back, score_b, amb_b = _correlative_candidate(b, a, sch)
    inv = matrix_to_pose(np.linalg.inv(pose_to_matrix(back)))
    candidates.append({"direction": "slice onto floor", "x": inv[0], "y": inv[1],
                       "yaw_deg": float(np.rad2deg(inv[2])), "score": score_b, "ambiguity": amb_b})
    reg = dataclasses.replace(cfg.registration, translation_range=sch.refine_translation,
                              yaw_range=float(np.deg2rad(sch.refine_yaw_deg)))
    guesses = np.array([forward, inv])
    al = align_maps(floor, slice_, floor_points=src, slice_points=dst,
                    config=dataclasses.replace(cfg, registration=reg), initial_guess=guesses, rng=rng)
    return al, [{k: (float(v) if isinstance(v, (float, np.floating)) else v) for k, v in c.items()}
                for c in candidates]


def common_grids(floor: OccupancyGrid, slice_: OccupancyGrid, transform: ArrayLike | None = None,
                 resolution: float | None = None) -> tuple[OccupancyGrid, OccupancyGrid]:
    """Both grids on one grid in the slice's frame, the floor map moved by ``transform`` (default identity):
    e.g. to show them before the alignment."""
    T = np.eye(3) if transform is None else np.asarray(transform, dtype=float)
    if T.shape == (3,):
        T = pose_to_matrix(T)
    geo = _snapped_union(slice_.geometry, floor.geometry, T, resolution or slice_.geometry.resolution, 0.0)
    return _crop_known(resample_grid(floor, target=geo, transform=T), resample_grid(slice_, target=geo))


def _crop_known(a: OccupancyGrid, b: OccupancyGrid, margin: float = 0.25) -> tuple[OccupancyGrid, OccupancyGrid]:
    """Both grids (one geometry) cropped to the cells known in either, plus ``margin`` metres."""
    known = (a.data != UNKNOWN) | (b.data != UNKNOWN)
    if not known.any():
        return a, b
    geo = a.geometry
    m = int(np.ceil(margin / geo.resolution))
    rows = np.nonzero(known.any(1))[0]
    cols = np.nonzero(known.any(0))[0]
    r0, r1 = max(rows[0] - m, 0), min(rows[-1] + m + 1, geo.height)
    c0, c1 = max(cols[0] - m, 0), min(cols[-1] + m + 1, geo.width)
    # the lower-left corner of the crop: pixel (r1 - 1, c0)
    x0 = geo.origin[0] + c0 * geo.resolution
    y0 = geo.origin[1] + (geo.height - r1) * geo.resolution
    g2 = GridGeometry((r1 - r0, c1 - c0), geo.resolution, (x0, y0))
    return OccupancyGrid(a.data[r0:r1, c0:c1], g2), OccupancyGrid(b.data[r0:r1, c0:c1], g2)

