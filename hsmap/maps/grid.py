"""Occupancy grids: their map files (map_server's PGM + YAML) and label images; the grids and their geometry
(:mod:`hsmap.maps.occupancy`) and the grids made from scans and point slices (:mod:`hsmap.maps.scan_grids`) are
importable from here too."""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import DataFormatError, DatasetError, HsmapWarning, InputError, ShapeError
from ..io import atomic_path, write_text
from ..limits import check_allocation, load_yaml, quote, read_bounded
from .occupancy import (
    FREE,
    IMAGE_FREE_MIN,
    OCCUPIED,
    UNKNOWN,
    GridGeometry,
    OccupancyGrid,
)
from .scan_grids import (
    ScanGridConfig,
    grid_from_point_slice,
    grid_from_scans,
    grids_from_scan_prefixes,
    scans_to_points,
)

__all__ = [
    "GridGeometry",
    "OccupancyGrid",
    "ScanGridConfig",
    "UNKNOWN",
    "FREE",
    "OCCUPIED",
    "IMAGE_FREE_MIN",
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



#: Image formats (as PIL names them) whose compression changes pixel values.
_LOSSY_FORMATS = {"JPEG", "MPO"}


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
