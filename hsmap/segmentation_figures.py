"""Pictures of a room segmentation: the coloured overlay ``hsmap segment`` writes and the step-by-step figure.

Matplotlib is used through its object API (``Figure``, Agg), never pyplot's global state. Images are drawn
in (row, col) pixel coordinates with the map's row 0 at the top, as stored.
"""

from __future__ import annotations

import colorsys

import numpy as np
from numpy.typing import NDArray

__all__ = ["label_colors", "label_overlay", "steps_figure"]


def label_colors(n: int) -> NDArray[np.uint8]:
    """(n + 1, 3) distinct RGB colours; row 0 (no room) is black. Deterministic (golden-ratio hues)."""
    out = np.zeros((n + 1, 3), dtype=np.uint8)
    for i in range(1, n + 1):
        h = (i * 0.618033988749895) % 1.0
        s = 0.45 + 0.25 * ((i * 7) % 3) / 2
        v = 0.80 + 0.15 * ((i * 5) % 2)
        out[i] = np.round(np.array(colorsys.hsv_to_rgb(h, s, v)) * 255)
    return out


def label_overlay(labels: NDArray, free: NDArray[np.bool_], door_lines: NDArray[np.bool_] | None = None,
                  doors=None) -> NDArray[np.uint8]:
    """(H, W, 3) uint8 picture: rooms in colour, free pixels without a room white, the rest dark gray,
    door lines (a mask, or the Door list's end points) in red and door centres as small black squares."""
    labels = np.asarray(labels)
    n = int(labels.max(initial=0))
    rgb = label_colors(n)[labels]
    rgb[(labels == 0) & free] = 255
    rgb[(labels == 0) & ~free] = 60
    H, W = labels.shape
    if door_lines is not None:
        rgb[door_lines & free] = (220, 30, 30)
    if doors:
        for d in doors:
            r, c = d.pixel
            rgb[max(r - 1, 0):min(r + 2, H), max(c - 1, 0):min(c + 2, W)] = (0, 0, 0)
    return rgb


def steps_figure(segmentation, title: str | None = None, crop: bool = True):
    """One panel per step of the algorithm, for a segmentation made with ``keep_steps=True``.

    Panels: free space; median filtered; distance transform; skeleton; skeleton x distance (clearance on
    the skeleton) with the door band or the critical points; door lines; regions before merging; final
    rooms with doors and the room graph.

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.figure import Figure

    st = segmentation.steps
    if not st:
        raise ValueError("steps_figure needs a segmentation made with keep_steps=True")
    free = st["free"]
    if crop:
        rows = np.nonzero(free.any(1))[0]
        cols = np.nonzero(free.any(0))[0]
        sl = (slice(max(rows[0] - 5, 0), rows[-1] + 6), slice(max(cols[0] - 5, 0), cols[-1] + 6))
    else:
        sl = (slice(None), slice(None))
    off = np.array([sl[0].start or 0, sl[1].start or 0])
    cfg = segmentation.config
    h = (sl[0].stop or free.shape[0]) - off[0]
    w = (sl[1].stop or free.shape[1]) - off[1]
    aspect = min(max(w / max(h, 1), 0.5), 3.0)
    fig = Figure(figsize=(17, 2 * 4.0 / aspect + 1.4), layout="constrained")
    axes = fig.subplots(2, 4)
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])

    def show(ax, img, ttl, **kw):
        ax.imshow(img[sl], interpolation="nearest", **kw)
        ax.set_title(ttl, fontsize=10)

    show(axes[0, 0], free, "1. free space (input)", cmap="gray")
    show(axes[0, 1], st["filtered"], f"2. median {cfg.median_size}x{cfg.median_size}"
         + (", specks ignored" if cfg.min_obstacle_area > 0 else ""), cmap="gray")
    im = axes[0, 2].imshow(np.where(st["filtered"], st["distance"], np.nan)[sl], cmap="viridis",
                           interpolation="nearest")
    axes[0, 2].set_title("3. Euclidean distance transform (m)", fontsize=10)
    fig.colorbar(im, ax=axes[0, 2], shrink=0.7)
    sk = np.where(st["filtered"], 0.85, 0.25)
    sk[st["skeleton"]] = 0.0
    show(axes[0, 3], sk, "4. skeleton of the free space", cmap="gray", vmin=0, vmax=1)

    ax = axes[1, 0]
    prod = np.where(st["skeleton"], st["product"], np.nan)
    ax.imshow(np.where(st["filtered"], 0.92, 0.3)[sl], cmap="gray", vmin=0, vmax=1, interpolation="nearest")
    # thicken the skeleton for visibility
    from scipy import ndimage as ndi

    thick = ndi.grey_dilation(np.nan_to_num(prod, nan=-1.0), size=3)
    im = ax.imshow(np.where(thick >= 0, thick, np.nan)[sl], cmap="plasma", interpolation="nearest")
    fig.colorbar(im, ax=ax, shrink=0.7)
    cr, cc = np.nonzero(st["candidates"])
    ax.plot(cc - off[1], cr - off[0], "o", ms=4, mfc="none", mec="cyan", mew=1.2)
    if cfg.method == "paper":
        lo = cfg.door_half_width - cfg.door_half_width_tolerance
        hi = cfg.door_half_width + cfg.door_half_width_tolerance
        ax.set_title(f"5. skeleton x distance; band {lo:.2f}-{hi:.2f} m centres", fontsize=10)
    else:
        ax.set_title(f"5. skeleton x distance; critical points ({len(cr)})", fontsize=10)

    img = np.where(st["filtered"], 0.92, 0.3)
    rgb = np.stack([img] * 3, -1)
    rgb[st["door_lines"]] = (0.9, 0.1, 0.1)
    show(axes[1, 1], rgb, f"6. door lines ({int(ndi.label(st['door_lines'], np.ones((3, 3)))[1])})")

    reg = st["regions"]
    show(axes[1, 2], label_overlay(reg, free), f"7. regions before merging ({int(reg.max())})")

    ax = axes[1, 3]
    show(ax, label_overlay(segmentation.labels, free, st["door_lines"] & (segmentation.labels > 0) & False,
                           None), f"8. rooms ({segmentation.n_rooms}) and doors ({len(segmentation.doors)})")
    geo = segmentation.geometry
    for d in segmentation.doors:
        ends = geo.world_to_pixel(np.asarray(d.end_points)) - off
        ax.plot(ends[:, 1], ends[:, 0], "-", color="red", lw=1.5)
    rooms = {r.label: r for r in segmentation.rooms()}
    for d in segmentation.doors:
        c = np.asarray(d.pixel) - off
        for lab in d.rooms:
            if lab in rooms:
                rc = geo.world_to_pixel(rooms[lab].centroid) - off
                ax.plot([c[1], rc[1]], [c[0], rc[0]], "-", color="k", lw=0.6)
        ax.plot(c[1], c[0], "s", ms=3.5, color="k")
    for r in rooms.values():
        rc = geo.world_to_pixel(r.centroid) - off
        ax.plot(rc[1], rc[0], "o", ms=4, color="k")
    if title:
        fig.suptitle(title)
    return fig
