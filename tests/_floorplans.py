"""A tiny floor plan in the Bormann et al. format, drawn for the floor-plan world, route and benchmark tests.

Three rooms in a row, 0.05 m per pixel: A (4.5 m x 4 m, a 1 m x 0.6 m cabinet block and a 1.2 m x 0.8 m table
drawn in the furnished map), B (4 m x 4 m) joined to A by a 1 m door, and C (2 m x 4 m) joined to B by a 1 m door;
optionally a fourth room D with no door (unreachable). The ground truth is the plain map with a black line drawn
across each doorway.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

RES = 0.05
H, W = 100, 260  # 5 m x 13 m
WALL = 4  # px


def draw(closed_room: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(plain, furnished, ground truth) gray images (H, W) uint8: 255 free, 0 wall, 205 outside."""
    plain = np.full((H, W), 205, np.uint8)
    plain[8:92, 8:252] = 0
    plain[8 + WALL:92 - WALL, 8 + WALL:252 - WALL] = 255
    gt = plain.copy()
    for c, (r0, r1) in ((100, (40, 60)), (184, (40, 60))):  # interior walls at cols c..c+3 with a 1 m door
        plain[:, c:c + WALL][plain[:, c:c + WALL] == 255] = 0
        plain[r0:r1, c:c + WALL] = 255
    if closed_room:
        plain[8 + WALL:92 - WALL, 220:220 + WALL] = 0  # D: cols 224..247, no door
    gt = plain.copy()
    gt[40:60, 100:100 + WALL] = 0
    gt[40:60, 184:184 + WALL] = 0
    furnished = plain.copy()
    furnished[20:32, 20:40] = 0      # a 1 m x 0.6 m block
    furnished[60:76, 50:74] = 0      # a 1.2 m x 0.8 m piece (a table when the seed says so)
    return plain, furnished, gt


def write(folder: Path, name: str = "tiny", closed_room: bool = False) -> Path:
    """Write NAME.png, NAME_furnitures.png, NAME_gt_segmentation.png into ``folder``; returns the folder."""
    folder.mkdir(parents=True, exist_ok=True)
    plain, furnished, gt = draw(closed_room)
    for suffix, img in (("", plain), ("_furnitures", furnished), ("_gt_segmentation", gt)):
        Image.fromarray(img).save(folder / f"{name}{suffix}.png")
    return folder
