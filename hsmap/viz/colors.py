"""Colours shared by the rerun recordings and the matplotlib figures, so a room has one colour everywhere."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "ROOM_PALETTE", "label_colors", "label_color", "label_overlay", "segmentation_picture", "DOOR_COLOR", "WALL_GREY",
    "SERIES_COLORS", "SPARE_COLORS", "VIEWER_SERIES_COLORS", "height_colors",
]

# matplotlib's tab20, dark shades first then light ones, so that consecutive labels contrast.
_TAB20 = [
    (31, 119, 180), (174, 199, 232), (255, 127, 14), (255, 187, 120), (44, 160, 44), (152, 223, 138),
    (214, 39, 40), (255, 152, 150), (148, 103, 189), (197, 176, 213), (140, 86, 75), (196, 156, 148),
    (227, 119, 194), (247, 182, 210), (127, 127, 127), (199, 199, 199), (188, 189, 34), (219, 219, 141),
    (23, 190, 207), (158, 218, 229),
]
#: (20, 3) uint8 colours for labels 1, 2, ... (cycled); label 0 ("no room") has no colour.
ROOM_PALETTE: NDArray[np.uint8] = np.array(_TAB20[0::2] + _TAB20[1::2], dtype=np.uint8)

#: Colours for the usual curves: ground truth, estimate (ours), odometry, and a spare one.
SERIES_COLORS = {
    "groundtruth": (40, 40, 40),
    "estimate": (31, 119, 180),
    "slam": (31, 119, 180),
    "odometry": (214, 39, 40),
    "other": (44, 160, 44),
}

#: Colours for further curves once those of :data:`SERIES_COLORS` are taken.
SPARE_COLORS = [(255, 127, 14), (148, 103, 189), (140, 86, 75), (227, 119, 194), (23, 190, 207)]

#: The colour of the door lines in the segmentation pictures: in no room's palette, apart from the walls' grey.
DOOR_COLOR = (255, 0, 255)
#: The grey of the pixels that are neither free nor in a room (walls, unknown) in the segmentation pictures.
WALL_GREY = 60


#: The same curves in the rerun viewer, whose background is dark and whose maps are white: colours that stand
#: apart on both (the figures' dark-grey ground truth disappears on the viewer's black).
VIEWER_SERIES_COLORS = {
    "groundtruth": (60, 210, 90),
    "estimate": (40, 150, 255),
    "slam": (40, 150, 255),
    "odometry": (245, 70, 50),
    "other": (250, 200, 40),
}


def label_color(label: int) -> tuple[int, int, int]:
    """RGB colour of one positive label."""
    c = ROOM_PALETTE[(int(label) - 1) % len(ROOM_PALETTE)]
    return int(c[0]), int(c[1]), int(c[2])


def label_colors(labels: ArrayLike, alpha_background: bool = True) -> NDArray[np.uint8]:
    """RGBA colours of a label image.

    Parameters
    ----------
    labels : ndarray of int, shape (...)
        0 = background (no room), k > 0 a room.
    alpha_background : bool
        Background transparent (alpha 0) when True, else black and opaque.

    Returns
    -------
    ndarray of uint8, shape (..., 4)
    """
    lab = np.asarray(labels)
    if not np.issubdtype(lab.dtype, np.integer):
        if not np.all(np.isfinite(lab)) or not np.all(lab == np.round(lab)):
            from ..errors import InputError

            raise InputError("labels must be integers (0 = no room)")
        lab = lab.astype(np.int64)
    out = np.zeros(lab.shape + (4,), dtype=np.uint8)
    fg = lab > 0
    out[fg, :3] = ROOM_PALETTE[(lab[fg] - 1) % len(ROOM_PALETTE)]
    out[fg, 3] = 255
    if not alpha_background:
        out[~fg, 3] = 255
    return out


def label_overlay(labels: ArrayLike, free: ArrayLike, door_lines: ArrayLike | None = None,
                  doors=None) -> NDArray[np.uint8]:
    """(H, W, 3) uint8 picture of a segmentation, in the pixels of its map (row 0 at the top).

    Rooms in their palette colours (:data:`ROOM_PALETTE`, as in the figures and the recordings), free pixels
    without a room white, the rest dark gray; the free pixels of ``door_lines`` (a mask) red, and the centre
    of each door (``segmentation.doors``) a small black square.
    """
    lab = np.asarray(labels)
    free = np.asarray(free, dtype=bool)
    if lab.ndim != 2 or free.shape != lab.shape:
        from ..errors import ShapeError

        raise ShapeError(f"labels and free must be (H, W) images of one shape, got {lab.shape} and {free.shape}")
    rgb = label_colors(lab, alpha_background=False)[..., :3].copy()
    rgb[(lab == 0) & free] = 255
    rgb[(lab == 0) & ~free] = WALL_GREY
    if door_lines is not None:
        rgb[np.asarray(door_lines, dtype=bool) & free] = (220, 30, 30)
    H, W = lab.shape
    for d in doors or ():
        r, c = d.pixel
        rgb[max(r - 1, 0):min(r + 2, H), max(c - 1, 0):min(c + 2, W)] = (0, 0, 0)
    return rgb


def segmentation_picture(labels: ArrayLike, free: ArrayLike, doors=(), geometry=None,
                         legend: bool = True) -> NDArray[np.uint8]:
    """(H', W', 3) uint8 picture of a segmentation: :func:`label_overlay` with each door's line drawn between its
    end points in :data:`DOOR_COLOR` (given the map's ``geometry``: an :class:`hsmap.maps.grid.GridGeometry`) and,
    with ``legend``, a key below the map (a swatch per room R1, R2, ..., the doors, the walls and the free space
    in no room). The map keeps its pixels (one per cell, row 0 at the top); the picture is widened where the
    key needs it."""
    lab = np.asarray(labels)
    rgb = label_overlay(lab, free, doors=doors)
    if geometry is not None:
        for d in doors or ():
            a, b = geometry.world_to_pixel(np.asarray(d.end_points, dtype=float))
            n = int(np.ceil(np.abs(b - a).max() * 2)) + 1
            rc = np.floor(a + np.linspace(0.0, 1.0, n)[:, None] * (b - a) + 0.5).astype(np.int64)
            rc = np.concatenate([rc, rc + (0, 1), rc + (1, 0)])  # two pixels wide: visible when scaled down
            rc = rc[(rc[:, 0] >= 0) & (rc[:, 0] < lab.shape[0]) & (rc[:, 1] >= 0) & (rc[:, 1] < lab.shape[1])]
            rgb[rc[:, 0], rc[:, 1]] = DOOR_COLOR
    if not legend:
        return rgb
    return _with_key(rgb, sorted(int(v) for v in np.unique(lab) if v > 0))


def _with_key(rgb: NDArray[np.uint8], rooms: list[int]) -> NDArray[np.uint8]:
    """The picture with a key of its colours below it (at most 24 rooms named, then how many more)."""
    from PIL import Image, ImageDraw, ImageFont

    try:
        font = ImageFont.load_default(size=13)
    except (TypeError, OSError):  # a Pillow without FreeType: the fixed bitmap font
        font = ImageFont.load_default()
    shown = rooms[:24]
    entries = [(f"R{r}", label_color(r)) for r in shown]
    if len(rooms) > len(shown):
        entries.append((f"+{len(rooms) - len(shown)} rooms", None))
    entries += [("door", DOOR_COLOR), ("door centre", (0, 0, 0)), ("wall / unknown", (WALL_GREY,) * 3),
                ("free, no room", (255, 255, 255))]
    probe = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    sizes = [int(np.ceil(probe.textlength(t, font=font))) + 26 for t, _ in entries]
    H, W = rgb.shape[:2]
    width = max(W, 360)
    rows, x = [[]], 6
    for e, w in zip(entries, sizes, strict=True):
        if x + w > width - 6 and rows[-1]:
            rows.append([])
            x = 6
        rows[-1].append((e, x))
        x += w
    line = 20
    out = Image.new("RGB", (width, H + 8 + line * len(rows)), (255, 255, 255))
    out.paste(Image.fromarray(np.ascontiguousarray(rgb)), (0, 0))
    draw = ImageDraw.Draw(out)
    for k, row in enumerate(rows):
        y = H + 6 + k * line
        for (text, colour), x in row:
            if colour is not None:
                draw.rectangle([x, y + 2, x + 13, y + 15], fill=tuple(int(c) for c in colour), outline=(0, 0, 0))
            draw.text((x + (18 if colour is not None else 0), y + 1), text, fill=(0, 0, 0), font=font)
    return np.asarray(out, dtype=np.uint8)


def height_colors(z: ArrayLike, z_range: tuple[float, float] | None = None) -> NDArray[np.uint8]:
    """RGB colours (N, 3) uint8 for heights z (N,), on a fixed blue-green-yellow-red ramp over ``z_range``.

    A fixed ``z_range`` keeps colours consistent across calls (a growing map logged in blocks).
    """
    z = np.asarray(z, dtype=float).reshape(-1)
    if z.size == 0:
        return np.zeros((0, 3), np.uint8)
    lo, hi = z_range if z_range is not None else (float(np.nanmin(z)), float(np.nanmax(z)))
    t = np.clip((z - lo) / max(hi - lo, 1e-9), 0.0, 1.0)
    t = np.nan_to_num(t)
    # a compact "turbo"-like ramp: (t, r, g, b) stops
    stops = np.array([
        [0.00, 48, 18, 59], [0.15, 70, 107, 227], [0.35, 27, 208, 213], [0.50, 97, 252, 108],
        [0.65, 210, 233, 53], [0.80, 254, 155, 45], [1.00, 122, 4, 3],
    ])
    rgb = np.stack([np.interp(t, stops[:, 0], stops[:, i]) for i in (1, 2, 3)], -1)
    return np.round(rgb).astype(np.uint8)
