"""Figures of the map half of the study (notebooks 04-07): the 2D/3D overlap (paper Fig. 13), the Voronoi steps
(Figs. 10, 11, 14), the room/door graph over the labels (Figs. 12, 16), the doors cut out of the point maps
(Fig. 15) and the occluded vs non-occluded segmentations (Fig. 18); plus rerun logging of an overlay.

Everything is drawn in world metres (images placed by :class:`hsmap.maps.grid.GridGeometry`), with the object API
of matplotlib (no pyplot state), like :mod:`hsmap.viz.figures`, whose ``plot_*`` helpers it uses.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.patches import Patch
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage as ndi

from ..errors import InputError, ShapeError
from ..maps.fusion import OVERLAY_COLORS, overlap_scores, overlay_image
from ..maps.grid import GridGeometry, OccupancyGrid
from . import figures

__all__ = [
    "graph_for_plot",
    "plot_overlay",
    "overlap_figure",
    "voronoi_steps_figure",
    "segmentation_figure",
    "door_clouds_figure",
    "segmentation_comparison_figure",
    "matched_labels",
    "log_overlay",
]


def _rgb01(c: Sequence[int]) -> tuple[float, float, float]:
    return tuple(float(v) / 255 for v in c[:3])  # type: ignore[return-value]


def _check_grid(g: Any, name: str) -> OccupancyGrid:
    if not isinstance(g, OccupancyGrid):
        raise InputError(f"{name} must be an hsmap.maps.grid.OccupancyGrid, got {type(g).__name__}")
    return g


def _zoom_to(ax: Axes, mask: NDArray[np.bool_], geometry: GridGeometry, margin: float = 0.4) -> None:
    """Limit the axes to the bounding box of ``mask`` (plus ``margin`` metres)."""
    if not mask.any():
        return
    rc = np.argwhere(mask)
    xy = geometry.pixel_to_world(np.array([rc.min(0), rc.max(0)]))
    ax.set_xlim(xy[:, 0].min() - margin, xy[:, 0].max() + margin)
    ax.set_ylim(xy[:, 1].min() - margin, xy[:, 1].max() + margin)


# ----------------------------------------------------------------------------------------------------------
# 2D/3D overlap (Fig. 13)
# ----------------------------------------------------------------------------------------------------------


def plot_overlay(floor: OccupancyGrid, slice_: OccupancyGrid, *, ax: Axes | None = None, tolerance: float = 0.10,
                 title: str | None = None, legend: bool = True) -> Axes:
    """Two grids on one geometry overlaid (:func:`hsmap.maps.fusion.overlay_image`): structure seen by both dark,
    by the floor map only red, by the slice only blue, free white, unknown light grey."""

    _check_grid(floor, "floor")
    _check_grid(slice_, "slice_")
    rgb = overlay_image(floor, slice_, tolerance)
    ax = figures.plot_image(rgb, floor.geometry, ax=ax, title=title)
    if legend:
        names = {"both": "both maps", "floor only": "floor map (2D LiDAR) only", "slice only": "3D slice only"}
        ax.legend(handles=[Patch(color=_rgb01(OVERLAY_COLORS[k]), label=v) for k, v in names.items()],
                  loc="upper right", fontsize=8, framealpha=0.9)
    _zoom_to(ax, (floor.data >= 0) | (slice_.data >= 0), floor.geometry)
    return ax


def overlap_figure(floor: OccupancyGrid, slice_: OccupancyGrid, alignment: Any,
                   before: tuple[OccupancyGrid, OccupancyGrid] | None = None,
                   *, slice_label: str = "1.7-1.8 m slice of the 3D map") -> Figure:
    """The paper's Figure 13: the floor-level 2D map, the slice of the 3D map, and the two overlaid after the
    registration (and, with ``before``, before it).

    Parameters
    ----------
    floor, slice_ : OccupancyGrid
        The two maps, each in its own frame.
    alignment : hsmap.maps.fusion.MapAlignment
    before : (OccupancyGrid, OccupancyGrid), optional
        The two maps on one grid without the registration (:func:`hsmap.maps.fusion.common_grids`).
    """
    n = 4 if before is not None else 3
    fig, axes = figures.new_figure(2, 2, size=(15, 9.5)) if n == 4 else figures.new_figure(1, 3, size=(20, 5.2))
    axes = np.atleast_1d(axes).ravel()
    figures.plot_grid(floor.data, floor.geometry, ax=axes[0], title="floor-level 2D map (2D LiDAR, 0.2 m)")
    _zoom_to(axes[0], floor.data >= 0, floor.geometry)
    figures.plot_grid(slice_.data, slice_.geometry, ax=axes[1], title=slice_label)
    _zoom_to(axes[1], slice_.data >= 0, slice_.geometry)
    k = 2
    if before is not None:
        plot_overlay(*before, ax=axes[k], tolerance=alignment.tolerance,
                     title=f"overlaid as they are (overlap {_overlap(before, alignment.tolerance):.2f})")
        k += 1
    x, y, yaw = alignment.pose
    plot_overlay(alignment.floor, alignment.slice, ax=axes[k], tolerance=alignment.tolerance,
                 title=f"after Harmony-ICP: ({x:+.2f} m, {y:+.2f} m, {np.degrees(yaw):+.1f}°), "
                       f"overlap {alignment.overlap:.2f}")
    return fig


def _overlap(grids: tuple[OccupancyGrid, OccupancyGrid], tolerance: float) -> float:

    a, b = grids
    if not a.occupied.any() or not b.occupied.any():
        return float("nan")
    return overlap_scores(a.occupied, b.occupied, a.geometry.resolution, tolerance)["overlap"]


# ----------------------------------------------------------------------------------------------------------
# Voronoi steps (Figs. 10, 11, 14)
# ----------------------------------------------------------------------------------------------------------


def _thick(mask: NDArray[np.bool_], px: int = 1) -> NDArray[np.bool_]:
    """A thin mask dilated by ``px`` pixels, so that one-pixel lines stay visible in a small panel."""
    return ndi.binary_dilation(mask, iterations=px) if px > 0 else mask


def _door_segments(segmentation) -> NDArray[np.bool_]:
    """The candidate door segments: skeleton pixels in the band of half door widths (``paper``), or the
    critical points (``critical``)."""
    st = segmentation.steps
    cfg = segmentation.config
    if cfg.method == "paper":
        lo = cfg.door_half_width - cfg.door_half_width_tolerance
        hi = cfg.door_half_width + cfg.door_half_width_tolerance
        return st["skeleton"] & (st["product"] >= lo) & (st["product"] <= hi)
    return st["candidates"].astype(bool)


def voronoi_steps_figure(grid: OccupancyGrid, segmentation, *, title: str | None = None,
                         thicken: int = 1) -> Figure:
    """The door detection step by step, in world metres (the paper's Figures 10, 11 and 14).

    Panels: (a) the map; (b) the binary free-space map after the median filter; (c) its skeleton (the
    Voronoi diagram of the free space); (d) the Euclidean distance transform; (e) their product, the clearance
    along the skeleton; (f) the door segments (skeleton pixels in the band of half door widths, or the
    critical points); (g) the doors drawn across the passages; (h) the final segmentation with the doors.

    ``segmentation`` must be made with ``keep_steps=True`` from ``grid``; ``thicken`` dilates one-pixel lines
    (skeleton, door segments, door lines) by that many pixels for visibility.
    """
    _check_grid(grid, "grid")
    st = getattr(segmentation, "steps", None)
    if not st:
        raise InputError("voronoi_steps_figure needs a segmentation made with keep_steps=True")
    geo = segmentation.geometry
    if st["free"].shape != geo.shape or grid.geometry.shape != geo.shape:
        raise ShapeError(f"the grid {grid.geometry.shape} and the segmentation {geo.shape} differ")
    cfg = segmentation.config
    W = geo.shape[1] * geo.resolution
    H = geo.shape[0] * geo.resolution
    ncols = 4 if W / max(H, 1e-9) < 2.2 else 2
    nrows = 8 // ncols
    panel_w = 4.6 if ncols == 4 else 8.0
    fig, axes = figures.new_figure(nrows, ncols, size=(panel_w * ncols, panel_w * H / W * nrows + 1.2))
    axes = axes.ravel()
    filt = st["filtered"]
    base = np.where(filt, 0.95, 0.25)

    def gray_rgb(extra: dict[tuple[float, float, float], NDArray[np.bool_]]) -> NDArray[np.float64]:
        rgb = np.repeat(base[..., None], 3, axis=2)
        for color, m in extra.items():
            rgb[m] = color
        return rgb

    figures.plot_grid(grid.data, geo, ax=axes[0], title="(a) map")
    figures.plot_image(filt, geo, ax=axes[1], cmap="gray", title=f"(b) binary map (median {cfg.median_size}x"
                       f"{cfg.median_size})")
    figures.plot_image(gray_rgb({(0.85, 0.1, 0.1): _thick(st["skeleton"], thicken)}), geo, ax=axes[2],
                       title="(c) skeleton (Voronoi diagram)")
    figures.plot_image(np.where(filt, st["distance"], np.nan), geo, ax=axes[3], cmap="viridis", colorbar=True,
                       title="(d) distance transform [m]")
    prod = np.where(st["skeleton"], st["product"], np.nan)
    prod_t = ndi.grey_dilation(np.nan_to_num(prod, nan=-1.0), size=2 * thicken + 1) if thicken else prod
    axes[4].imshow(base, extent=geo.extent(), cmap="gray", vmin=0, vmax=1, interpolation="nearest")
    figures.plot_image(np.where(prod_t >= 0, prod_t, np.nan), geo, ax=axes[4], cmap="plasma", colorbar=True,
                       title="(e) skeleton x distance [m]")
    seg = _door_segments(segmentation)
    if cfg.method == "paper":
        lo = cfg.door_half_width - cfg.door_half_width_tolerance
        hi = cfg.door_half_width + cfg.door_half_width_tolerance
        ttl = f"(f) door segments: clearance {lo:.2f}-{hi:.2f} m"
    else:
        ttl = f"(f) door candidates: {int(seg.sum())} critical points"
    figures.plot_image(gray_rgb({(0.1, 0.45, 0.85): _thick(st["skeleton"], 0),
                                 (0.9, 0.1, 0.1): _thick(seg, thicken + 1)}), geo, ax=axes[5], title=ttl)
    n_lines = int(ndi.label(st["door_lines"], np.ones((3, 3)))[1])
    figures.plot_image(gray_rgb({(0.9, 0.1, 0.1): _thick(st["door_lines"], thicken)}), geo, ax=axes[6],
                       title=f"(g) doors drawn ({n_lines} lines)")
    figures.plot_labels(segmentation.labels, geo, ax=axes[7], base=grid.data, annotate=True,
                        title=f"(h) segmentation: {segmentation.n_rooms} rooms, {len(segmentation.doors)} doors")
    if segmentation.doors:
        figures.plot_segments(np.array([d.end_points for d in segmentation.doors]), ax=axes[7], linewidth=2.5)
    axes[7].set_title(_final_title(segmentation.n_rooms, len(segmentation.doors), n_lines))
    for ax in axes:
        _zoom_to(ax, st["free"], geo, 0.3)
    if title:
        fig.suptitle(title)
    return fig


def _final_title(rooms: int, doors: int, lines: int) -> str:
    """Panel (h)'s title; where fewer doors than lines drawn, why: a line is a door only between two final rooms
    (not within a room merged across it, nor a small region merged away), one per passage."""
    head = f"(h) segmentation: {rooms} rooms, {doors} doors"
    if lines > doors:
        return f"{head} ({lines} lines drawn:\na line is a door only between two final rooms, one per passage)"
    return head


# ----------------------------------------------------------------------------------------------------------
# room graph, doors in the point maps (Figs. 12, 15, 16)
# ----------------------------------------------------------------------------------------------------------


def graph_for_plot(graph: Any) -> Any:
    """A copy of a :func:`hsmap.rooms.topology.room_graph` graph whose nodes also carry ``centroid`` (x, y), the
    attribute :func:`hsmap.viz.figures.plot_graph` and :func:`hsmap.viz.rerun.log_room_graph` read."""
    if not hasattr(graph, "nodes"):
        raise InputError(f"expected a networkx graph, got {type(graph).__name__}")
    g = graph.copy()
    for n, d in g.nodes(data=True):
        if "centroid" not in d:
            if "x" not in d or "y" not in d:
                raise InputError(f"graph node {n!r} has neither 'centroid' nor 'x'/'y'")
            d["centroid"] = (float(d["x"]), float(d["y"]))
    return g


def segmentation_figure(grid: OccupancyGrid, segmentation, graph: Any = None, *, ax: Axes | None = None,
                        title: str | None = None, names: Mapping[int, str] | None = None) -> Axes:
    """Room labels over the map, the doors as red lines and, given, the room/door graph at its world positions
    (the paper's Figures 12 and 16)."""
    _check_grid(grid, "grid")
    geo = segmentation.geometry
    ax = figures.plot_labels(segmentation.labels, geo, ax=ax, base=grid.data, annotate=graph is None, names=names,
                             alpha=0.55)
    if segmentation.doors:
        figures.plot_segments(np.array([d.end_points for d in segmentation.doors]), ax=ax, linewidth=3)
    if graph is not None:
        figures.plot_graph(graph_for_plot(graph), ax=ax)
    _zoom_to(ax, grid.data >= 0, grid.geometry, 0.3)
    if title:
        ax.set_title(title)
    return ax


def door_clouds_figure(doors: Sequence[Any], clouds3d: Sequence[NDArray], clouds2d: Sequence[NDArray] | None = None,
                       *, z_range: tuple[float, float] = (0.0, 2.8), sensor2d_height: float = 0.2,
                       title: str | None = None) -> Figure:
    """The points of the 3D (and 2D) map inside each door's box, seen from the front (the paper's Figure 15).

    Each panel looks at one door along its normal: the horizontal axis runs along the door line (0 at its
    centre), the vertical is the height; 3D points coloured by height, 2D points (drawn at the 2D LiDAR's
    height ``sensor2d_height``) as black crosses; the door's end points as red ticks.

    Parameters
    ----------
    doors : sequence of Door
    clouds3d : sequence of ndarray of shape (K_i, 3)
        Per door (:func:`hsmap.rooms.segmentation.points_in_doors` on the 3D map).
    clouds2d : sequence of ndarray of shape (L_i, 2), optional
        Per door, from the 2D map.
    """
    if len(clouds3d) != len(doors) or (clouds2d is not None and len(clouds2d) != len(doors)):
        raise ShapeError(f"one cloud per door is needed: {len(doors)} doors, {len(clouds3d)} 3D clouds"
                         + ("" if clouds2d is None else f", {len(clouds2d)} 2D clouds"))
    if not doors:
        raise InputError("no door to show")
    n = len(doors)
    ncols = min(n, 3)
    nrows = int(np.ceil(n / ncols))
    fig, axes = figures.new_figure(nrows, ncols, size=(4.6 * ncols, 4.4 * nrows))
    axes = np.atleast_1d(axes).ravel()
    sc = None
    for k, (d, ax) in enumerate(zip(doors, axes, strict=False)):
        a, b = np.asarray(d.end_points, dtype=float)
        L = float(np.hypot(*(b - a)))
        u = (b - a) / L if L > 0 else np.array([1.0, 0.0])
        mid = 0.5 * (a + b)
        p3 = np.asarray(clouds3d[k], dtype=float).reshape(-1, 3)
        s3 = (p3[:, :2] - mid) @ u
        sc = ax.scatter(s3, p3[:, 2], c=p3[:, 2], cmap="turbo", vmin=z_range[0], vmax=z_range[1], s=6,
                        linewidths=0, label=f"3D map ({len(p3)} points)")
        if clouds2d is not None:
            p2 = np.asarray(clouds2d[k], dtype=float).reshape(-1, 2)
            s2 = (p2 - mid) @ u
            ax.plot(s2, np.full(len(s2), sensor2d_height), "kx", ms=5, mew=1.2, label=f"2D map ({len(p2)} points)")
        for e in (-L / 2, L / 2):
            ax.axvline(e, color="red", lw=1.0, ls="--")
        ax.set_aspect("equal")
        ax.set_xlim(-L / 2 - 0.6, L / 2 + 0.6)
        ax.set_ylim(z_range[0] - 0.1, z_range[1] + 0.1)
        ax.set_xlabel("along the door [m]")
        ax.set_ylabel("z [m]")
        ax.set_title(f"door D{k + 1} at ({d.centre[0]:.2f}, {d.centre[1]:.2f}), width {d.width:.2f} m", fontsize=9)
        ax.legend(fontsize=7, loc="center")  # the opening is empty
    for ax in axes[n:]:
        ax.set_visible(False)
    if sc is not None:
        fig.colorbar(sc, ax=list(axes[:n]), label="z [m]", shrink=0.8)
    if title:
        fig.suptitle(title)
    return fig


# ----------------------------------------------------------------------------------------------------------
# occluded vs non-occluded (Fig. 18)
# ----------------------------------------------------------------------------------------------------------


def matched_labels(labels: ArrayLike, geometry: GridGeometry, reference: ArrayLike,
                   reference_geometry: GridGeometry) -> NDArray[np.int64]:
    """``labels`` (H, W) renumbered after the rooms of ``reference`` they cover: pairs of a room and a reference
    room taken one to one, the largest overlap (in world coordinates) first, each room given its reference room's
    label; a room that overlaps none left takes a label above every reference label. 0 stays 0."""
    lab = np.asarray(labels).astype(np.int64)
    ref = np.asarray(reference).astype(np.int64)
    rc = np.argwhere(lab > 0)
    idx = reference_geometry.world_to_index(geometry.pixel_to_world(rc))
    inside = reference_geometry.inside(idx)
    pairs = np.zeros((0, 2), dtype=np.int64)
    if inside.any():
        r = ref[idx[inside, 0], idx[inside, 1]]
        ok = r > 0
        pairs = np.column_stack([lab[rc[inside][ok, 0], rc[inside][ok, 1]], r[ok]])
    mapping: dict[int, int] = {}
    taken: set[int] = set()
    if len(pairs):
        uniq, counts = np.unique(pairs, axis=0, return_counts=True)
        for k in np.argsort(-counts, kind="stable"):
            a, b = int(uniq[k, 0]), int(uniq[k, 1])
            if a not in mapping and b not in taken:
                mapping[a] = b
                taken.add(b)
    nxt = int(max(ref.max(initial=0), 0)) + 1
    for a in np.unique(lab[lab > 0]):
        if int(a) not in mapping:
            mapping[int(a)] = nxt
            nxt += 1
    lut = np.zeros(int(lab.max(initial=0)) + 1, dtype=np.int64)
    for a, b in mapping.items():
        lut[a] = b
    return lut[lab]


def segmentation_comparison_figure(panels: Sequence[tuple[OccupancyGrid | None, Any, str]],
                                   *, title: str | None = None, reference: int | None = None) -> Figure:
    """Segmentations side by side (the paper's Figure 18): each panel ``(grid, labels_or_segmentation, title)``
    draws the labels (a Segmentation, or a (labels, GridGeometry) pair) over the grid (None: no base). With
    ``reference`` (a panel's index, e.g. the ground truth's), every other panel's rooms take the colours of the
    reference rooms they match (:func:`matched_labels`); each room keeps its own number."""
    if not panels:
        raise InputError("no panel to draw")
    n = len(panels)
    if reference is not None and not -n <= reference < n:
        raise InputError(f"reference must be a panel's index (0..{n - 1}), got {reference}")
    fig, axes = figures.new_figure(n, 1, size=(11, 4.0 * n))
    axes = np.atleast_1d(axes).ravel()

    def unpack(seg):
        return (seg.labels, seg.geometry, seg.doors) if hasattr(seg, "labels") else (*seg, [])

    ref = None if reference is None else unpack(panels[reference][1])[:2]
    for k, (ax, (grid, seg, ttl)) in enumerate(zip(axes, panels, strict=True)):
        labels, geo, doors = unpack(seg)
        base = None if grid is None else grid.data
        if grid is not None and grid.geometry.shape != geo.shape:
            raise ShapeError(f"panel {ttl!r}: grid {grid.geometry.shape} and labels {geo.shape} differ")
        names = None
        if ref is not None and k != reference % n:
            shown = matched_labels(labels, geo, *ref)
            lab = np.asarray(labels)
            names = {int(shown[tuple(np.argwhere(lab == v)[0])]): str(int(v)) for v in np.unique(lab[lab > 0])}
            labels = shown
        figures.plot_labels(labels, geo, ax=ax, base=base, alpha=0.6, title=ttl, names=names)
        if doors:
            figures.plot_segments(np.array([d.end_points for d in doors]), ax=ax, linewidth=2.5)
        ax.set_title(ttl)
    # one window for all panels: the union of the labelled areas
    boxes = []
    for ax in axes:
        boxes.append((*ax.get_xlim(), *ax.get_ylim()))
    b = np.array(boxes)
    for ax in axes:
        ax.set_xlim(b[:, 0].min(), b[:, 1].max())
        ax.set_ylim(b[:, 2].min(), b[:, 3].max())
    if title:
        fig.suptitle(title)
    return fig


# ----------------------------------------------------------------------------------------------------------
# rerun
# ----------------------------------------------------------------------------------------------------------


def log_overlay(rec: Any, rgb: ArrayLike, geometry: GridGeometry, *, entity: str = "world/map/overlay",
                map_entity: str | None = "map/overlay", z: float = 0.01, opacity: float = 0.9) -> None:
    """Log an (H, W, 3) overlay picture (:func:`hsmap.maps.fusion.overlay_image`) as a coloured quad in the 3D world
    placed by ``geometry`` (:func:`hsmap.viz.rerun.log_rgba_grid`) and as an ``Image`` in the 2D map view
    (static)."""
    import rerun as rr

    from .rerun_core import _stream
    from .rerun_maps import log_rgba_grid

    img = np.asarray(rgb)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise ShapeError(f"overlay must be an (H, W, 3) uint8 picture, got {img.shape} {img.dtype}")
    if img.shape[:2] != geometry.shape:
        raise ShapeError(f"overlay {img.shape[:2]} differs from its geometry {geometry.shape}")
    s = _stream(rec)
    alpha = np.full(img.shape[:2] + (1,), int(round(255 * float(opacity))), np.uint8)
    log_rgba_grid(rec, entity, np.concatenate([img, alpha], axis=2), geometry, z=z)
    if map_entity is not None:
        s.log(map_entity, rr.Image(img, color_model="RGB", draw_order=-5.0), static=True, strict=True)
