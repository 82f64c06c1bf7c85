"""Occupancy grids and THE conversion between world (x, y) in metres and image (row, col).

Convention (ROS map_server, used by the paper): an image of shape (H, W), row 0 at the top; ``origin`` is the
world (x, y) of the lower-left corner of the lower-left pixel (row H-1, col 0); ``resolution`` is metres per
pixel. The centre of pixel (row, col) is at::

    x = origin_x + (col + 0.5) * resolution
    y = origin_y + (H - 1 - row + 0.5) * resolution

Every other module converts through :class:`GridGeometry`; nothing else flips rows.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import DataFormatError, DatasetError, EmptyInputError, HsmapWarning, InputError, ShapeError
from ..geometry import compose, pose_to_matrix, transform_points
from ..io import atomic_path, write_text
from ..limits import check_allocation, load_yaml, quote, read_bounded

__all__ = [
    "GridGeometry",
    "OccupancyGrid",
    "ScanGridConfig",
    "UNKNOWN",
    "FREE",
    "OCCUPIED",
    "read_map",
    "write_map",
    "grid_arrays",
    "grid_from_arrays",
    "read_image_gray",
    "read_label_image",
    "write_label_image",
    "resample_labels",
    "grid_from_scans",
    "grids_from_scan_prefixes",
    "scans_to_points",
    "grid_from_point_slice",
]


@dataclass(frozen=True)
class GridGeometry:
    """Where an (H, W) image lies in the world.

    Attributes
    ----------
    shape : tuple of int
        (H, W) = (rows, cols).
    resolution : float
        Metres per pixel, > 0.
    origin : tuple of float
        World (x, y) of the lower-left corner of pixel (H-1, 0).
    """

    shape: tuple[int, int]
    resolution: float
    origin: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        if not (np.isfinite(self.resolution) and self.resolution > 0):
            raise InputError(f"resolution must be a positive number of metres per pixel, got {self.resolution}")
        if len(self.shape) != 2 or min(self.shape) < 1:
            raise InputError(f"grid shape must be (rows, cols) with both >= 1, got {self.shape}")
        object.__setattr__(self, "shape", (int(self.shape[0]), int(self.shape[1])))
        object.__setattr__(self, "origin", (float(self.origin[0]), float(self.origin[1])))

    @classmethod
    def covering(cls, xy_min: ArrayLike, xy_max: ArrayLike, resolution: float, margin: float = 0.0) -> GridGeometry:
        """The smallest grid at ``resolution`` covering the box [xy_min, xy_max] plus ``margin`` metres."""
        lo = np.asarray(xy_min, dtype=float) - margin
        hi = np.asarray(xy_max, dtype=float) + margin
        if resolution <= 0:
            raise InputError(f"resolution must be > 0 metres per pixel, got {resolution}")
        w, h = np.maximum(np.ceil((hi - lo) / resolution).astype(int), 1)
        return cls((int(h), int(w)), float(resolution), (float(lo[0]), float(lo[1])))

    @property
    def height(self) -> int:
        return self.shape[0]

    @property
    def width(self) -> int:
        return self.shape[1]

    def world_to_pixel(self, xy: ArrayLike) -> NDArray[np.float64]:
        """Continuous (row, col) of world points (..., 2); pixel centres are at integer values."""
        xy = np.asarray(xy, dtype=float)
        col = (xy[..., 0] - self.origin[0]) / self.resolution - 0.5
        row = self.shape[0] - 1 - ((xy[..., 1] - self.origin[1]) / self.resolution - 0.5)
        return np.stack([row, col], -1)

    def world_to_index(self, xy: ArrayLike) -> NDArray[np.int64]:
        """Integer (row, col) of the pixels containing world points (..., 2) (may lie outside the image)."""
        return np.floor(self.world_to_pixel(xy) + 0.5).astype(np.int64)

    def pixel_to_world(self, rc: ArrayLike) -> NDArray[np.float64]:
        """World (x, y) of (row, col) pixel coordinates (..., 2); integers give pixel centres."""
        rc = np.asarray(rc, dtype=float)
        x = self.origin[0] + (rc[..., 1] + 0.5) * self.resolution
        y = self.origin[1] + (self.shape[0] - 1 - rc[..., 0] + 0.5) * self.resolution
        return np.stack([x, y], -1)

    def inside(self, rc: ArrayLike) -> NDArray[np.bool_]:
        """Whether integer (row, col) indices (..., 2) lie in the image."""
        rc = np.asarray(rc)
        return (rc[..., 0] >= 0) & (rc[..., 0] < self.shape[0]) & (rc[..., 1] >= 0) & (rc[..., 1] < self.shape[1])

    def extent(self) -> tuple[float, float, float, float]:
        """(left, right, bottom, top) in world metres, for matplotlib's ``imshow(extent=...)``."""
        x0, y0 = self.origin
        return (x0, x0 + self.shape[1] * self.resolution, y0, y0 + self.shape[0] * self.resolution)


# --------------------------------------------------------------------------------------------------------------
# Occupancy grids
# --------------------------------------------------------------------------------------------------------------

#: Cell values of :class:`OccupancyGrid` (those of ROS ``nav_msgs/OccupancyGrid``).
UNKNOWN, FREE, OCCUPIED = -1, 0, 100

#: Gray values map_server's ``trinary`` mode writes (and the benchmark's ``*_scan`` maps use).
PGM_FREE, PGM_OCCUPIED, PGM_UNKNOWN = 254, 0, 205

#: Default free-space rule for plain images (no YAML): gray value >= 250 is free (the IPA benchmark's rule).
IMAGE_FREE_MIN = 250

#: Image formats (as PIL names them) whose compression changes pixel values.
_LOSSY_FORMATS = {"JPEG", "MPO"}

_IMAGE_SUFFIXES = {".png", ".pgm", ".ppm", ".pnm", ".bmp", ".tif", ".tiff", ".jpg", ".jpeg"}


@dataclass
class OccupancyGrid:
    """A 2D occupancy grid: cell states plus where the image lies in the world.

    Attributes
    ----------
    data : ndarray of shape (H, W), int8
        ``FREE`` (0), ``OCCUPIED`` (100) or ``UNKNOWN`` (-1); row 0 is the top of the image (largest y).
    geometry : GridGeometry
        Resolution and origin; convert with ``geometry.world_to_index`` / ``pixel_to_world``.
    """

    data: NDArray[np.int8]
    geometry: GridGeometry

    def __post_init__(self) -> None:
        self.data = np.asarray(self.data, dtype=np.int8)
        if self.data.ndim != 2:
            raise ShapeError(f"OccupancyGrid.data must be 2D (H, W), got shape {self.data.shape}")
        if self.data.shape != self.geometry.shape:
            raise ShapeError(f"OccupancyGrid.data {self.data.shape} differs from geometry {self.geometry.shape}")

    @property
    def free(self) -> NDArray[np.bool_]:
        """(H, W) bool, True on free cells."""
        return self.data == FREE

    @property
    def occupied(self) -> NDArray[np.bool_]:
        """(H, W) bool, True on occupied cells."""
        return self.data == OCCUPIED

    @property
    def resolution(self) -> float:
        return self.geometry.resolution

    def to_image(self) -> NDArray[np.uint8]:
        """(H, W) uint8 gray image as map_server writes it: 254 free, 0 occupied, 205 unknown."""
        img = np.full(self.data.shape, PGM_UNKNOWN, dtype=np.uint8)
        img[self.data == FREE] = PGM_FREE
        img[self.data == OCCUPIED] = PGM_OCCUPIED
        return img

    @classmethod
    def from_image(
        cls,
        image: ArrayLike,
        resolution: float,
        origin: tuple[float, float] = (0.0, 0.0),
        *,
        free_min: int = IMAGE_FREE_MIN,
        occupied_max: int = 89,
    ) -> OccupancyGrid:
        """Cell states from a gray image: ``>= free_min`` free, ``<= occupied_max`` occupied, else unknown.

        The defaults are the benchmark's rule (>= 250 free) and map_server's occupied threshold (0.65).
        """
        img = np.asarray(image)
        if img.ndim != 2:
            raise ShapeError(f"map image must be a 2D gray image (H, W), got shape {img.shape}")
        data = np.full(img.shape, UNKNOWN, dtype=np.int8)
        data[img >= free_min] = FREE
        data[img <= occupied_max] = OCCUPIED
        return cls(data, GridGeometry(img.shape, resolution, origin))


def read_image_gray(path: str | os.PathLike) -> NDArray[np.uint8]:
    """Read an image file as 8-bit gray, the way OpenCV's ``imread(path, 0)`` does (alpha dropped).

    16-bit images are scaled to 8 bits. Raises :class:`DataFormatError` for files that are not images.
    """
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: no such map image")
    try:
        with Image.open(path) as im:
            _check_image_size(path, im.size)
            if im.format in _LOSSY_FORMATS:
                warnings.warn(f"{path}: {im.format} is a lossy format: its compression blurs walls and speckles free "
                              "space, which changes what is free and occupied (and the rooms found); use PNG or PGM",
                              HsmapWarning, stacklevel=2)
            if im.mode in ("I;16", "I;16B", "I;16L", "I"):
                arr = np.asarray(im, dtype=np.int64)
                return np.clip(arr // 256 if arr.max(initial=0) > 255 else arr, 0, 255).astype(np.uint8)
            return np.asarray(im.convert("L"), dtype=np.uint8)
    except (UnidentifiedImageError, OSError, SyntaxError, Image.DecompressionBombError) as exc:
        raise DataFormatError(f"{path}: not a readable image ({' '.join(str(exc).split())[:300]})") from None


#: Memory a map's processing (distance transforms, skeleton, labels of ``hsmap segment``) takes per pixel, bytes.
MAP_BYTES_PER_PIXEL = 256


def _check_image_size(path: Path, size: tuple[int, int]) -> None:
    """InputError naming ``path`` when an image of ``size`` (width, height) pixels is more than the memory
    available can process, checked from the header before the pixels are decoded."""

    w, h = size
    check_allocation(float(w) * float(h) * MAP_BYTES_PER_PIXEL, f"{path}: a {w} x {h} pixel map", InputError)


def read_label_image(path: str | os.PathLike) -> NDArray[np.int32]:
    """Read a room label image (8- or 16-bit gray PNG; 0 = no room) as int32 without rescaling."""
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: no such label image")
    try:
        with Image.open(path) as im:
            _check_image_size(path, im.size)
            if im.mode in ("I;16", "I;16B", "I;16L", "I", "L", "P"):
                return np.asarray(im, dtype=np.int64).astype(np.int32)
            if im.mode in ("LA", "RGB", "RGBA"):
                return np.asarray(im.convert("L"), dtype=np.int32)
            raise DataFormatError(f"{path}: label images must be gray (L or I;16), got mode {im.mode}")
    except (UnidentifiedImageError, OSError, SyntaxError, Image.DecompressionBombError) as exc:
        raise DataFormatError(f"{path}: not a readable image ({' '.join(str(exc).split())[:300]})") from None


def write_label_image(path: str | os.PathLike, labels: ArrayLike) -> None:
    """Write a room label image as a 16-bit gray PNG (0 = no room), atomically."""
    from PIL import Image

    lab = np.asarray(labels)
    if lab.ndim != 2:
        raise ShapeError(f"labels must be 2D (H, W), got shape {lab.shape}")
    if lab.size and (lab.min() < 0 or lab.max() > 65535):
        raise InputError(f"labels must lie in 0..65535 for a 16-bit PNG, got {lab.min()}..{lab.max()}")
    with atomic_path(path, suffix=".png") as tmp:
        Image.fromarray(lab.astype(np.uint16)).save(tmp, format="PNG")


def resample_labels(labels: ArrayLike, geometry: GridGeometry, target: GridGeometry) -> NDArray[np.int32]:
    """A label image (H, W) lying at ``geometry`` sampled onto the pixels of ``target`` (nearest pixel; 0 where
    ``target``'s pixel centre falls outside the image): e.g. rooms found on a SLAM map, scored in a ground truth's
    own pixel grid."""
    lab = np.asarray(labels)
    if lab.shape != geometry.shape:
        raise ShapeError(f"labels {lab.shape} do not match their geometry {geometry.shape}")
    rows, cols = np.indices(target.shape)
    rc = geometry.world_to_index(target.pixel_to_world(np.stack([rows, cols], -1)))
    ok = geometry.inside(rc)
    out = np.zeros(target.shape, dtype=np.int32)
    out[ok] = lab[rc[ok][:, 0], rc[ok][:, 1]]
    return out


def read_map(path: str | os.PathLike, resolution: float | None = None) -> OccupancyGrid:
    """Read a map: a map_server YAML (with its PGM/PNG image) or a plain image.

    Parameters
    ----------
    path : path-like
        ``.yaml``/``.yml``: map_server metadata (``image``, ``resolution``, ``origin``, ``negate``,
        ``occupied_thresh``, ``free_thresh``); otherwise a gray image read with the benchmark's rule
        (>= 250 free).
    resolution : float, optional
        Metres per pixel. Overrides the YAML's value; for plain images the default is 0.05.

    Raises
    ------
    DatasetError
        The file, or the image a YAML names, does not exist.
    DataFormatError
        The file is not an image, or the YAML lacks a key or has a malformed one.
    InputError
        ``resolution <= 0``.
    """
    path = Path(path)
    if resolution is not None and not (np.isfinite(resolution) and resolution > 0):
        raise InputError(f"resolution must be a positive number of metres per pixel, got {resolution}")
    if not path.is_file():
        raise DatasetError(f"{path}: no such map file")
    if path.suffix.lower() in (".yaml", ".yml"):
        return _read_map_yaml(path, resolution)
    img = read_image_gray(path)
    return OccupancyGrid.from_image(img, 0.05 if resolution is None else float(resolution))


def _read_map_yaml(path: Path, resolution: float | None) -> OccupancyGrid:
    """A map_server YAML, every key checked: ``image`` (an existing image file), ``resolution`` (finite, > 0),
    ``origin`` ([x, y] or [x, y, yaw], finite, yaw 0), ``negate`` (0 or 1), ``occupied_thresh`` and
    ``free_thresh`` (in [0, 1], free below occupied), ``mode`` (trinary, scale or raw)."""
    import yaml

    try:
        meta = load_yaml(read_bounded(path, "map_server YAML").decode("utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise DataFormatError(f"{path}: not valid YAML ({' '.join(str(exc).split())[:400]})") from None
    except OSError as exc:
        raise DatasetError(f"{path}: cannot read it ({exc.strerror})") from None
    if not isinstance(meta, dict):
        raise DataFormatError(f"{path}: expected a map_server mapping with 'image', 'resolution', 'origin'")
    for key in ("image", "resolution", "origin"):
        if key not in meta:
            raise DataFormatError(f"{path}: missing key '{key}' (map_server YAML needs image, resolution, origin)")

    def as_number(v: object, key: str) -> float:
        # YAML 1.1 reads 1e-3 (no dot) as a string; map_server's parser reads it as a number, and so do we
        if isinstance(v, bool) or not isinstance(v, (int, float, str)):
            raise DataFormatError(f"{path}: '{key}' must be a number, got {quote(v)}")
        try:
            x = float(v)
        except ValueError:
            raise DataFormatError(f"{path}: '{key}' must be a number, got {quote(v)}") from None
        if not np.isfinite(x):
            raise DataFormatError(f"{path}: '{key}' must be finite, got {quote(v)}")
        return x

    def number(key: str, default: float | None = None) -> float:
        return as_number(meta.get(key, default), key)

    if not isinstance(meta["image"], str) or not meta["image"].strip():
        raise DataFormatError(f"{path}: 'image' must be the file name of the map image, got {quote(meta['image'])}")
    image_path = Path(meta["image"])
    if not image_path.is_absolute():
        image_path = path.parent / image_path
    if not image_path.is_file():
        raise DatasetError(f"{path}: its image '{meta['image']}' does not exist ({image_path})")
    res = number("resolution") if resolution is None else float(resolution)
    if not res > 0:
        raise DataFormatError(f"{path}: 'resolution' must be > 0 metres per pixel, got {res}")
    origin = meta["origin"]
    if not isinstance(origin, (list, tuple)) or len(origin) not in (2, 3):
        raise DataFormatError(f"{path}: 'origin' must be [x, y, yaw], got {quote(origin)}")
    origin = [as_number(v, "origin") for v in origin]
    if len(origin) > 2 and abs(origin[2]) > 1e-9:
        raise DataFormatError(f"{path}: rotated map origins (yaw = {origin[2]}) are not supported")
    negate = meta.get("negate", 0)
    if negate not in (0, 1) or isinstance(negate, float):
        raise DataFormatError(f"{path}: 'negate' must be 0 or 1, got {quote(negate)}")
    occ_t = number("occupied_thresh", 0.65)
    free_t = number("free_thresh", 0.196)
    for key, v in (("occupied_thresh", occ_t), ("free_thresh", free_t)):
        if not 0.0 <= v <= 1.0:
            raise DataFormatError(f"{path}: '{key}' must lie in [0, 1] (a probability), got {v}")
    if not free_t < occ_t:
        raise DataFormatError(f"{path}: 'free_thresh' ({free_t}) must be below 'occupied_thresh' ({occ_t})")
    mode = meta.get("mode", "trinary")
    if mode not in ("trinary", "scale", "raw"):
        raise DataFormatError(f"{path}: 'mode' must be trinary, scale or raw, got {quote(mode)}")
    img = read_image_gray(image_path).astype(float)
    occ = img / 255.0 if negate else (255.0 - img) / 255.0
    data = np.full(img.shape, UNKNOWN, dtype=np.int8)
    data[occ > occ_t] = OCCUPIED
    data[occ < free_t] = FREE
    return OccupancyGrid(data, GridGeometry(img.shape, res, (origin[0], origin[1])))


def write_map(path: str | os.PathLike, grid: OccupancyGrid) -> tuple[Path, Path]:
    """Write ``grid`` as map_server PGM + YAML (``trinary``: 254 free, 0 occupied, 205 unknown), atomically.

    Parameters
    ----------
    path : path-like
        The YAML file (``.yaml``) or the stem; the PGM is written beside it with the same stem.

    Returns
    -------
    (yaml_path, pgm_path)
    """
    import yaml
    from PIL import Image

    path = Path(path)
    yaml_path = path if path.suffix.lower() in (".yaml", ".yml") else path.with_suffix(".yaml")
    pgm_path = yaml_path.with_suffix(".pgm")
    with atomic_path(pgm_path, suffix=".pgm") as tmp:
        Image.fromarray(grid.to_image()).save(tmp, format="PPM")
    meta = {
        "image": pgm_path.name,
        "mode": "trinary",
        "resolution": float(grid.geometry.resolution),
        "origin": [float(grid.geometry.origin[0]), float(grid.geometry.origin[1]), 0.0],
        "negate": 0,
        "occupied_thresh": 0.65,
        "free_thresh": 0.196,
    }
    write_text(yaml_path, yaml.safe_dump(meta, sort_keys=False))
    return yaml_path, pgm_path


def grid_arrays(prefix: str, grid: OccupancyGrid) -> dict[str, NDArray]:
    """``grid`` as two arrays to store in an ``.npz`` (``PREFIX_data``, ``PREFIX_geometry``: resolution and
    origin); :func:`grid_from_arrays` reads them back."""
    geo = grid.geometry
    return {f"{prefix}_data": grid.data, f"{prefix}_geometry": np.array([geo.resolution, *geo.origin])}


def grid_from_arrays(arrays, prefix: str) -> OccupancyGrid:
    """The grid that :func:`grid_arrays` stored under ``prefix`` in ``arrays`` (an open ``.npz`` or a mapping)."""
    data = arrays[f"{prefix}_data"]
    res, ox, oy = (float(v) for v in arrays[f"{prefix}_geometry"])
    return OccupancyGrid(data, GridGeometry(data.shape, res, (ox, oy)))


# --------------------------------------------------------------------------------------------------------------
# Grids from scans and from 3D point maps
# --------------------------------------------------------------------------------------------------------------


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
