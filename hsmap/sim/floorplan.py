"""Worlds from floor plans: a 3D building from the three images of the Bormann et al. (2016) benchmark.

A floor plan is three gray images of the same size and resolution (0.05 m per pixel in the benchmark), read the
way the benchmark reads them (8-bit gray, pixels >= 250 free):

- the plain map: every pixel that is not free is wall;
- the furnished map: the plain map with furniture drawn in; a pixel free in the plain map but not in the
  furnished one is furniture;
- the ground truth: the plain map with room borders drawn across the doorways; its rooms are the 8-connected
  regions of pixels > 250 larger than 100 px (:func:`hsmap.evaluation.ground_truth_rooms`).

:func:`build_world` turns them into solid boxes (:mod:`hsmap.sim.shapes`) and a :class:`~hsmap.sim.world.World`:

- walls: every non-free pixel of the plain map within ``wall_band`` of free space, from the floor to the ceiling
  (``ceiling_height``, 2.8 m); pixels deeper inside solid regions can never be seen and are left out;
- furniture: the furniture pixels grouped into 8-connected pieces, each seeded: a share (``table_share``) of the
  pieces large enough becomes a table or desk (a 4 cm top at 0.65-0.8 m on four 5 cm legs at the piece's
  corners), the others solid cabinets and shelves 0.4-1.5 m high; nothing reaches the paper's 1.7-1.8 m slice;
- lintels: wherever the ground truth draws a border across an opening of the plain map (free in the plain map,
  in no ground-truth room), a solid from the door height (2.05 m) to the ceiling;
- room labels: the ground-truth rooms, in the images' own pixel grid.

Pixels become boxes through one rectangle cover per mask (runs of each row, merged down the rows while they
repeat), so that the mesh of the largest building (office_i, 82 m x 103 m) stays small and ray casting fast.
The world frame: x to the right, y up the image, metres, the lower-left corner of the image at (0, 0)
(:class:`hsmap.maps.grid.GridGeometry` does every pixel <-> world conversion).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage as ndi

from ..errors import ConfigError, DataFormatError, DatasetError
from ..evaluation.segmentation import ground_truth_rooms
from ..maps.grid import IMAGE_FREE_MIN, GridGeometry, read_image_gray
from .world import World

__all__ = ["FloorPlan", "FloorPlanWorldConfig", "FurniturePiece", "FloorPlanWorld", "read_floor_plan",
           "floor_plan_files", "list_floor_plans", "build_world", "mask_rectangles", "BORMANN_RESOLUTION"]

#: Metres per pixel of the Bormann et al. benchmark maps (hard-coded in its evaluation).
BORMANN_RESOLUTION = 0.05

_EIGHT = np.ones((3, 3), dtype=bool)


@dataclass
class FloorPlan:
    """The three images of a building, read and checked.

    Attributes
    ----------
    name : str
    plain_free, furnished_free : ndarray of shape (H, W), bool
        Free pixels (>= 250) of the plain and the furnished map.
    groundtruth : ndarray of shape (H, W), uint8
        The ground-truth gray image.
    rooms : ndarray of shape (H, W), int32
        Ground-truth room labels, 0 = no room, 1..R (:func:`hsmap.evaluation.ground_truth_rooms`).
    geometry : GridGeometry
        Where the images lie in the world (origin (0, 0), the images' resolution).
    files : dict of str to str
        ``plain``, ``furnished``, ``groundtruth``: the files read.
    """

    name: str
    plain_free: NDArray[np.bool_]
    furnished_free: NDArray[np.bool_]
    groundtruth: NDArray[np.uint8]
    rooms: NDArray[np.int32]
    geometry: GridGeometry
    files: dict[str, str] = field(default_factory=dict)

    @property
    def n_rooms(self) -> int:
        return int(self.rooms.max(initial=0))

    @property
    def furniture(self) -> NDArray[np.bool_]:
        """Pixels free in the plain map and not in the furnished one, (H, W) bool."""
        return self.plain_free & ~self.furnished_free

    @property
    def borders(self) -> NDArray[np.bool_]:
        """Pixels free in the plain map that belong to no ground-truth room (borders drawn across openings)."""
        return self.plain_free & (self.rooms == 0)


def floor_plan_files(folder: str | os.PathLike, name: str) -> tuple[Path, Path, Path]:
    """The benchmark's file names of building ``name`` in ``folder``: plain, furnished, ground truth."""
    folder = Path(folder)
    return folder / f"{name}.png", folder / f"{name}_furnitures.png", folder / f"{name}_gt_segmentation.png"


def list_floor_plans(folder: str | os.PathLike) -> list[str]:
    """Names of the buildings in ``folder`` that have all three images, sorted.

    Raises
    ------
    DatasetError
        ``folder`` is not a folder.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise DatasetError(f"{folder}: no such folder of floor plans")
    names = []
    for gt in folder.glob("*_gt_segmentation.png"):
        name = gt.name[: -len("_gt_segmentation.png")]
        if all(p.is_file() for p in floor_plan_files(folder, name)):
            names.append(name)
    return sorted(names)


def read_floor_plan(plain: str | os.PathLike, furnished: str | os.PathLike | None = None,
                    groundtruth: str | os.PathLike | None = None, *, resolution: float = BORMANN_RESOLUTION,
                    name: str | None = None) -> FloorPlan:
    """Read and check a floor plan's three images.

    Parameters
    ----------
    plain : path
        The plain map (``NAME.png``), or a folder together with ``name``.
    furnished, groundtruth : path, optional
        Default the benchmark's names beside ``plain``: ``NAME_furnitures.png``, ``NAME_gt_segmentation.png``.
    resolution : float
        Metres per pixel.
    name : str, optional
        The building's name (default the plain map's file stem); with ``plain`` a folder, the building to read.

    Raises
    ------
    DatasetError
        A file is missing.
    DataFormatError
        A file is not an image, the sizes differ, the plain map has no free pixel, or the ground truth has no room;
        the message names the file.
    """

    if not (np.isfinite(resolution) and resolution > 0):
        raise ConfigError(f"resolution must be > 0 metres per pixel, got {resolution}")
    plain = Path(plain)
    if plain.is_dir():
        if name is None:
            raise DatasetError(f"{plain}: a folder; name the building to read from it")
        plain, f_default, g_default = floor_plan_files(plain, name)
    else:
        name = name or plain.stem
        f_default = plain.with_name(f"{plain.stem}_furnitures{plain.suffix}")
        g_default = plain.with_name(f"{plain.stem}_gt_segmentation{plain.suffix}")
    furnished = Path(furnished) if furnished is not None else f_default
    groundtruth = Path(groundtruth) if groundtruth is not None else g_default
    images = {}
    for role, path in (("plain", plain), ("furnished", furnished), ("groundtruth", groundtruth)):
        if not path.is_file():
            raise DatasetError(f"{path}: no such file (the {role} map of floor plan {name!r})")
        images[role] = read_image_gray(path)
    h, w = images["plain"].shape
    for role, path in (("furnished", furnished), ("groundtruth", groundtruth)):
        if images[role].shape != (h, w):
            hh, ww = images[role].shape
            raise DataFormatError(f"{path}: {ww} x {hh} px, but the plain map {plain.name} is {w} x {h} px; the "
                                  "three images of a floor plan must have the same size")
    plain_free = images["plain"] >= IMAGE_FREE_MIN
    if not plain_free.any():
        raise DataFormatError(f"{plain}: no free pixel (gray >= {IMAGE_FREE_MIN}): the plain map has no free space")
    furnished_free = images["furnished"] >= IMAGE_FREE_MIN
    if not furnished_free.any():
        raise DataFormatError(f"{furnished}: no free pixel (gray >= {IMAGE_FREE_MIN}): the furnished map has no "
                              "free space")
    rooms = ground_truth_rooms(images["groundtruth"])
    if rooms.max(initial=0) == 0:
        raise DataFormatError(f"{groundtruth}: no ground-truth room (an 8-connected region of pixels > 250 larger "
                              "than 100 px)")
    return FloorPlan(name, plain_free, furnished_free, images["groundtruth"], rooms,
                     GridGeometry((h, w), float(resolution), (0.0, 0.0)),
                     {"plain": str(plain), "furnished": str(furnished), "groundtruth": str(groundtruth)})


# --- pixels to boxes ----------------------------------------------------------------------------------------------

def mask_rectangles(mask: NDArray[np.bool_]) -> NDArray[np.int64]:
    """A cover of a mask by disjoint pixel rectangles: rows (r0, c0, r1, c1), inclusive bounds.

    Each row's runs of True pixels, merged down the rows while the same run repeats: walls drawn along the image
    axes become a few long rectangles.
    """
    m = np.asarray(mask, dtype=bool)
    rects: list[tuple[int, int, int, int]] = []
    open_: dict[tuple[int, int], int] = {}  # (c0, c1) -> first row
    padded = np.zeros(m.shape[1] + 2, dtype=np.int8)
    for r in range(m.shape[0] + 1):
        runs: set[tuple[int, int]] = set()
        if r < m.shape[0] and m[r].any():
            padded[1:-1] = m[r]
            d = np.diff(padded)
            starts = np.flatnonzero(d == 1)
            ends = np.flatnonzero(d == -1) - 1
            runs = set(zip(starts.tolist(), ends.tolist(), strict=True))
        for run in [k for k in open_ if k not in runs]:
            rects.append((open_.pop(run), run[0], r - 1, run[1]))
        for run in runs:
            open_.setdefault(run, r)
    return np.array(sorted(rects), dtype=np.int64).reshape(-1, 4)


def _rect_boxes(rects: NDArray[np.int64], geometry: GridGeometry, z0, z1) -> NDArray[np.float64]:
    """Boxes (B, 7) of pixel rectangles (B, 4) between heights z0 and z1 (scalars or (B,))."""
    r = np.asarray(rects, dtype=float).reshape(-1, 4)
    centre = geometry.pixel_to_world(np.stack([(r[:, 0] + r[:, 2]) / 2, (r[:, 1] + r[:, 3]) / 2], -1))
    res = geometry.resolution
    out = np.empty((len(r), 7))
    out[:, :2] = centre
    out[:, 2] = (r[:, 3] - r[:, 1] + 1) * res
    out[:, 3] = (r[:, 2] - r[:, 0] + 1) * res
    out[:, 4] = 0.0
    out[:, 5] = z0
    out[:, 6] = z1
    return out


# --- the world ----------------------------------------------------------------------------------------------------

@dataclass
class FloorPlanWorldConfig:
    """How a floor plan becomes a 3D world (one configuration for every building).

    Attributes
    ----------
    ceiling_height : float
        Walls reach the ceiling, metres (2.8).
    door_height : float
        Lintels hang from the ceiling down to this height, metres (2.05).
    wall_band : float
        Non-free pixels farther than this from free space are inside solid regions and left out, metres.
    table_share : float
        Share of the furniture pieces (large enough for legs) that become tables and desks, the rest solid.
    table_height : (float, float)
        Range of table and desk heights, metres.
    solid_height : (float, float)
        Range of cabinet and shelf heights, metres.
    table_min_size : float
        A piece narrower than this (its bounding box's short side) is always solid, metres.
    top_thickness, leg_size : float
        Table top thickness and leg width, metres.
    """

    ceiling_height: float = 2.8
    door_height: float = 2.05
    wall_band: float = 0.3
    table_share: float = 0.5
    table_height: tuple[float, float] = (0.65, 0.8)
    solid_height: tuple[float, float] = (0.4, 1.5)
    table_min_size: float = 0.4
    top_thickness: float = 0.04
    leg_size: float = 0.05

    def __post_init__(self) -> None:
        self.table_height = tuple(float(v) for v in self.table_height)
        self.solid_height = tuple(float(v) for v in self.solid_height)
        for name in ("ceiling_height", "door_height", "wall_band", "table_min_size", "top_thickness", "leg_size"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise ConfigError(f"floor-plan world: {name} must be > 0, got {v!r}")
        if not self.door_height < self.ceiling_height:
            raise ConfigError(f"floor-plan world: door_height ({self.door_height}) must be below ceiling_height "
                              f"({self.ceiling_height})")
        if not 0.0 <= self.table_share <= 1.0:
            raise ConfigError(f"floor-plan world: table_share must lie in [0, 1], got {self.table_share}")
        for name in ("table_height", "solid_height"):
            lo, hi = getattr(self, name)
            if not (0 < lo <= hi < self.door_height):
                raise ConfigError(f"floor-plan world: {name} must be (low, high) with 0 < low <= high < door_height, "
                                  f"got {(lo, hi)}")
        if self.top_thickness >= self.table_height[0]:
            raise ConfigError("floor-plan world: top_thickness must be below the lowest table height")


@dataclass
class FurniturePiece:
    """One 8-connected piece of furniture pixels and what it became."""

    index: int
    kind: str  # "table" (a top on legs) or "cabinet" (solid)
    height: float
    pixels: int
    bbox: tuple[int, int, int, int]  # r0, c0, r1, c1 inclusive
    boxes: int

    def as_dict(self) -> dict:
        return {"index": self.index, "kind": self.kind, "height": round(self.height, 4), "pixels": self.pixels,
                "bbox_rc": list(self.bbox), "boxes": self.boxes}


@dataclass
class FloorPlanWorld:
    """A floor plan built into solid boxes (:func:`build_world`); :meth:`world` makes the ray-casting scene."""

    plan: FloorPlan
    config: FloorPlanWorldConfig
    seed: int
    boxes: NDArray[np.float64]
    kinds: list[str]
    furniture: list[FurniturePiece]

    def world(self):
        """The :class:`~hsmap.sim.world.World` (open3d ray-casting scene) of the boxes."""

        x0, x1, y0, y1 = self.plan.geometry.extent()
        return World.from_boxes(self.boxes, self.kinds, ((x0, y0), (x1, y1)), self.config.ceiling_height)

    def counts(self) -> dict[str, int]:
        """Boxes per kind."""
        kinds, n = np.unique(np.asarray(self.kinds, dtype=object).astype(str), return_counts=True)
        return {str(k): int(v) for k, v in zip(kinds, n, strict=True)}

    def describe(self) -> dict:
        """A plain summary (for the benchmark's records)."""
        kinds = [p.kind for p in self.furniture]
        return {"name": self.plan.name, "files": self.plan.files, "shape": list(self.plan.geometry.shape),
                "resolution": self.plan.geometry.resolution, "seed": self.seed, "rooms": self.plan.n_rooms,
                "boxes": self.counts(), "furniture_pieces": len(self.furniture), "tables": kinds.count("table"),
                "cabinets": kinds.count("cabinet"),
                "config": {k: (list(v) if isinstance(v, tuple) else v) for k, v in vars(self.config).items()}}


def build_world(plan: FloorPlan, config: FloorPlanWorldConfig | None = None, seed: int = 0) -> FloorPlanWorld:
    """Walls, furniture and lintels of a floor plan as solid boxes (see the module docstring).

    Parameters
    ----------
    plan : FloorPlan
        From :func:`read_floor_plan`.
    config : FloorPlanWorldConfig, optional
    seed : int
        Seeds every furniture piece's kind and height (piece ``k`` draws from ``default_rng([seed, k])``, so a
        piece's draw does not depend on the others).

    Returns
    -------
    FloorPlanWorld
    """
    cfg = config or FloorPlanWorldConfig()
    g = plan.geometry
    res = g.resolution
    # walls: the non-free pixels of the plain map near free space
    depth = ndi.distance_transform_edt(~plan.plain_free) * res
    walls = ~plan.plain_free & (depth <= cfg.wall_band + 1e-9)
    parts = [_rect_boxes(mask_rectangles(walls), g, 0.0, cfg.ceiling_height)]
    kinds = ["wall"] * len(parts[0])
    # lintels over the ground truth's borders across openings
    lint = _rect_boxes(mask_rectangles(plan.borders), g, cfg.door_height, cfg.ceiling_height)
    parts.append(lint)
    kinds += ["lintel"] * len(lint)
    # furniture pieces
    pieces, n = ndi.label(plan.furniture, structure=_EIGHT)
    furniture = []
    for k, sl in enumerate(ndi.find_objects(pieces), start=1):
        local = pieces[sl] == k
        r0, c0 = sl[0].start, sl[1].start
        rng = np.random.default_rng([int(seed), k])
        short = min(local.shape) * res
        table = short >= cfg.table_min_size and rng.random() < cfg.table_share
        rects = mask_rectangles(local) + np.array([r0, c0, r0, c0])
        if table:
            h = float(rng.uniform(*cfg.table_height))
            top = _rect_boxes(rects, g, h - cfg.top_thickness, h)
            rows, cols = np.nonzero(local)
            legs = []
            for rr, cc in ((0, 0), (0, local.shape[1] - 1), (local.shape[0] - 1, 0),
                           (local.shape[0] - 1, local.shape[1] - 1)):
                i = int(np.argmin((rows - rr) ** 2 + (cols - cc) ** 2))
                legs.append(g.pixel_to_world([rows[i] + r0, cols[i] + c0]))
            leg = np.array([[x, y, cfg.leg_size, cfg.leg_size, 0.0, 0.0, h - cfg.top_thickness]
                            for x, y in np.unique(np.round(legs, 6), axis=0)])
            boxes = np.concatenate([top, leg], 0)
            kind = "table"
        else:
            h = float(rng.uniform(*cfg.solid_height))
            boxes = _rect_boxes(rects, g, 0.0, h)
            kind = "cabinet"
        parts.append(boxes)
        kinds += [kind] * len(boxes)
        furniture.append(FurniturePiece(k - 1, kind, h, int(local.sum()),
                                        (r0, c0, sl[0].stop - 1, sl[1].stop - 1), len(boxes)))
    return FloorPlanWorld(plan, cfg, int(seed), np.concatenate(parts, 0), kinds, furniture)
