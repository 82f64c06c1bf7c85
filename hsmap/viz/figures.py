"""Matplotlib figures for the study: paths over ground truth, point maps and occupancy grids in world metres,
room-label overlays, the room graph, top and side views of 3D point maps, error curves.

Figures are made with the object API (``matplotlib.figure.Figure``, rendered by Agg), never through pyplot's
global state, so they work the same in a notebook, a script and a test. Every ``plot_*`` function draws on
an ``ax`` it is given (or a new figure when ``ax`` is None) and returns the ``ax``; save with
``study.savefig(ax.figure, "name")`` or ``fig.savefig(path)``.

World coordinates are (x, y[, z]) in metres; images are placed with :meth:`hsmap.maps.grid.GridGeometry.extent`,
so a grid and the points drawn over it line up exactly.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from numpy.typing import ArrayLike, NDArray

from ..errors import InputError, ShapeError
from ..maps.grid import GridGeometry
from .colors import SERIES_COLORS, SPARE_COLORS, label_color, label_colors
from .occupancy import occupancy_to_image

__all__ = [
    "new_figure",
    "plot_trajectories",
    "series_colors",
    "plot_errors",
    "plot_points2d",
    "plot_grid",
    "plot_labels",
    "plot_segments",
    "plot_graph",
    "plot_cloud_views",
    "plot_image",
]


def _rgb(c: Any) -> Any:
    """0-255 RGB tuples -> matplotlib 0-1; anything else (names, hex) unchanged."""
    if isinstance(c, (tuple, list, np.ndarray)) and len(c) in (3, 4) and max(c) > 1:
        return tuple(float(v) / 255 for v in c)
    return c


def new_figure(nrows: int = 1, ncols: int = 1, *, size: tuple[float, float] | None = None,
               **subplot_kw: Any) -> tuple[Figure, Any]:
    """A figure with a grid of axes (constrained layout), without pyplot.

    Returns
    -------
    fig : Figure
    axes : Axes or ndarray of Axes
        One ``Axes`` for 1x1, else an array shaped (nrows, ncols) squeezed like ``plt.subplots``.
    """
    size = size or (5.5 * ncols, 4.5 * nrows)
    fig = Figure(figsize=size, layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=True, subplot_kw=subplot_kw or None)
    return fig, axes


def _ax(ax: Axes | None, size: tuple[float, float] = (6, 5)) -> Axes:
    if ax is None:
        _, ax = new_figure(size=size)
    return ax


def _xy(poses: Any, name: str) -> NDArray[np.float64]:
    p = getattr(poses, "poses", poses)
    p = np.asarray(p, dtype=float)
    if p.ndim != 2 or p.shape[1] not in (2, 3, 6):
        raise ShapeError(f"{name}: expected (N, 2) positions or (N, 3)/(N, 6) poses, got shape {p.shape}")
    return p[:, :2]


def _world_axes(ax: Axes, title: str | None) -> None:
    # an image fixes the data limits to its extent: shrink the box; plain curves: widen the limits
    ax.set_aspect("equal", adjustable="box" if ax.images else "datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    if title:
        ax.set_title(title)


def series_colors(names: Sequence[str]) -> dict[str, tuple[int, int, int]]:
    """One distinct RGB colour per curve name: a name that says what it is ("HS-SLAM" -> ``slam``, "wheel
    odometry" -> ``odometry``) takes that colour of :data:`SERIES_COLORS` unless an earlier name took it; every
    other name takes the next colour not in use (the spare ``other``, then :data:`SPARE_COLORS`, cycled)."""
    palette = ["slam", "odometry", "other"]
    out: dict[str, tuple[int, int, int]] = {}
    used: set[tuple[int, int, int]] = set()
    for name in names:
        key = next((p for p in palette if p in name.lower()), None)
        if key is not None and SERIES_COLORS[key] not in used:
            out[name] = SERIES_COLORS[key]
            used.add(out[name])
    spare = [SERIES_COLORS[p] for p in palette] + list(SPARE_COLORS)
    free = [c for c in spare if c not in used]
    for k, name in enumerate(n for n in names if n not in out):
        out[name] = free[k] if k < len(free) else spare[k % len(spare)]
    return out


def plot_trajectories(
    trajectories: Mapping[str, Any],
    *,
    ax: Axes | None = None,
    groundtruth: Any = None,
    colors: Mapping[str, Any] | None = None,
    title: str | None = None,
    markers: bool = True,
    linewidth: float = 1.6,
) -> Axes:
    """Paths from above, each over the ground truth.

    Parameters
    ----------
    trajectories : mapping of name to Trajectory or array (N, 2)/(N, 3)/(N, 6)
        E.g. ``{"odometry": odo, "HS-SLAM": est}``. Colours follow ``SERIES_COLORS`` by name.
    groundtruth : Trajectory or array, optional
        Drawn first, as a wide grey band under the paths.
    markers : bool
        Mark the start (a black circle: the ground truth's, else the first path's) and the end of each path (a
        square in its colour), both named in the legend.
    """
    ax = _ax(ax)
    colors = dict(colors or {})
    picked = series_colors(list(trajectories))
    if groundtruth is not None:
        g = _xy(groundtruth, "groundtruth")
        # a wide grey band underneath, so that the paths drawn over it stay readable and it stays visible
        ax.plot(g[:, 0], g[:, 1], "-", color="0.6", lw=linewidth * 3.0, alpha=0.55, solid_capstyle="round",
                label="ground truth", zorder=3)
    start = g[0] if groundtruth is not None and len(g) else None
    ends = 0
    for name, traj in trajectories.items():
        xy = _xy(traj, name)
        c = colors.get(name) or picked[name]
        ax.plot(xy[:, 0], xy[:, 1], "-", color=_rgb(c), lw=linewidth, label=name, zorder=4)
        if markers and len(xy):
            ax.plot(*xy[-1], "s", color=_rgb(c), ms=5, zorder=5)
            ends += 1
            start = xy[0] if start is None else start
    if markers and start is not None:
        ax.plot(*start, "o", color="k", ms=6, zorder=5, label="start")
    if ends:
        ax.plot([], [], "s", color="0.45", ms=5, label="end (in the path's colour)")
    _world_axes(ax, title)
    ax.legend(loc="best", fontsize=9)
    ax.grid(True, lw=0.3, alpha=0.5)
    return ax


def plot_errors(
    errors: Mapping[str, ArrayLike],
    *,
    x: ArrayLike | None = None,
    xlabel: str = "scan",
    units: Mapping[str, str] | None = None,
    limits: Mapping[str, float] | None = None,
    title: str | None = None,
) -> Figure:
    """One small plot per error series (e.g. per DOF), optionally with the paper's bound as a band.

    Parameters
    ----------
    errors : mapping of name to array (N,)
        E.g. ``{"x": ex, "y": ey, "yaw": eyaw}``.
    x : array (N,), optional
        Abscissa (default 0..N-1).
    units : mapping of name to unit, optional
    limits : mapping of name to float, optional
        A bound to show as a dashed line at +/- the value (e.g. the paper's maximum error).
    """
    if not errors:
        raise InputError("plot_errors needs at least one error series")
    n = len(errors)
    ncols = min(3, n)
    nrows = int(np.ceil(n / ncols))
    fig, axes = new_figure(nrows, ncols, size=(4.2 * ncols, 2.8 * nrows))
    axes = np.atleast_1d(axes).ravel()
    for ax, (name, e) in zip(axes, errors.items(), strict=False):
        e = np.asarray(e, dtype=float).reshape(-1)
        xs = np.arange(len(e)) if x is None else np.asarray(x, dtype=float)
        if xs.shape != e.shape:
            raise ShapeError(f"x has shape {xs.shape} but errors[{name!r}] has {e.shape}")
        ax.plot(xs, e, lw=1.2, color=_rgb(SERIES_COLORS["slam"]))
        ax.axhline(0, color="k", lw=0.5)
        if limits and name in limits:
            lim = float(limits[name])
            ax.axhline(lim, color=_rgb(SERIES_COLORS["odometry"]), ls="--", lw=0.9, label="paper bound")
            ax.axhline(-lim, color=_rgb(SERIES_COLORS["odometry"]), ls="--", lw=0.9)
            ax.legend(fontsize=8, loc="best")
        unit = (units or {}).get(name, "")
        ax.set_ylabel(f"{name} error" + (f" [{unit}]" if unit else ""))
        ax.set_xlabel(xlabel)
        ax.grid(True, lw=0.3, alpha=0.5)
    for ax in axes[n:]:
        ax.set_visible(False)
    if title:
        fig.suptitle(title)
    return fig


def plot_points2d(
    points: ArrayLike,
    *,
    ax: Axes | None = None,
    color: Any = (30, 30, 30),
    size: float | None = None,
    title: str | None = None,
    max_points: int | None = 400_000,
    label: str | None = None,
) -> Axes:
    """A 2D point map (N, 2) (or the x, y of (N, 3)) from above, equal axes in metres.

    ``max_points`` thins very large maps with a fixed stride (deterministic) to keep figures light; ``size``
    is the marker area in points^2 (default: larger for sparser maps).
    """
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] not in (2, 3):
        raise ShapeError(f"points must have shape (N, 2) or (N, 3), got {p.shape}")
    if max_points is not None and len(p) > max_points:
        p = p[:: int(np.ceil(len(p) / max_points))]
    ax = _ax(ax)
    if size is None:
        size = float(np.clip(30_000 / max(len(p), 1), 0.2, 6.0))
    ax.scatter(p[:, 0], p[:, 1], s=size, color=_rgb(color), marker="o", linewidths=0, label=label,
               rasterized=True)
    _world_axes(ax, title)
    return ax


def _check_image(img: NDArray[Any], geometry: GridGeometry, what: str) -> None:
    if not isinstance(geometry, GridGeometry):
        raise InputError(f"geometry must be an hsmap.maps.grid.GridGeometry, got {type(geometry).__name__}")
    if img.shape[:2] != geometry.shape:
        raise ShapeError(f"{what} has shape {img.shape[:2]} but its GridGeometry says {geometry.shape}")


def plot_image(
    image: ArrayLike,
    geometry: GridGeometry,
    *,
    ax: Axes | None = None,
    title: str | None = None,
    cmap: str = "gray",
    colorbar: bool = False,
    **imshow_kw: Any,
) -> Axes:
    """Any (H, W) or (H, W, 3/4) image placed in world metres (a distance transform, a skeleton, ...)."""
    img = np.asarray(image)
    _check_image(img, geometry, "image")
    ax = _ax(ax)
    kw = {"interpolation": "nearest", "cmap": cmap, **imshow_kw}
    im = ax.imshow(img, extent=geometry.extent(), origin="upper", **kw)
    if colorbar:
        ax.figure.colorbar(im, ax=ax, shrink=0.8)
    _world_axes(ax, title)
    return ax


def plot_grid(
    grid: ArrayLike,
    geometry: GridGeometry,
    *,
    ax: Axes | None = None,
    convention: str = "auto",
    title: str | None = None,
) -> Axes:
    """An occupancy grid in map_server greys (free white, occupied black, unknown grey) in world metres.

    See :func:`hsmap.viz.occupancy.occupancy_to_ros` for ``convention``.
    """
    img = occupancy_to_image(grid, convention)
    return plot_image(img, geometry, ax=ax, title=title, cmap="gray", vmin=0, vmax=255)


def plot_labels(
    labels: ArrayLike,
    geometry: GridGeometry,
    *,
    ax: Axes | None = None,
    base: ArrayLike | None = None,
    base_convention: str = "auto",
    alpha: float = 0.65,
    names: Mapping[int, str] | None = None,
    annotate: bool = True,
    title: str | None = None,
) -> Axes:
    """Room labels (H, W) (0 = none) in their palette colours over an optional occupancy grid ``base``.

    ``annotate`` writes each room's name (``names``, default its number) at the centre of its pixels.
    """
    lab = np.asarray(labels)
    if lab.ndim != 2:
        raise ShapeError(f"labels must be an (H, W) image, got shape {lab.shape}")
    _check_image(lab, geometry, "label image")
    ax = _ax(ax)
    if base is not None:
        plot_grid(base, geometry, ax=ax, convention=base_convention)
    rgba = label_colors(lab).astype(float) / 255
    rgba[..., 3] *= alpha
    ax.imshow(rgba, extent=geometry.extent(), origin="upper", interpolation="nearest")
    if annotate:
        for k in np.unique(lab[lab > 0]):
            rc = np.argwhere(lab == k).mean(axis=0)
            x, y = geometry.pixel_to_world(rc)
            ax.text(x, y, (names or {}).get(int(k), str(int(k))), ha="center", va="center", fontsize=8,
                    bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": _rgb(label_color(int(k))),
                          "alpha": 0.8})
    _world_axes(ax, title)
    return ax


def plot_segments(
    segments: ArrayLike,
    *,
    ax: Axes | None = None,
    color: Any = (214, 39, 40),
    linewidth: float = 2.5,
    labels: Sequence[str] | None = None,
    title: str | None = None,
) -> Axes:
    """Line segments (N, 2, 2) in world metres: ``segments[i] = [[x0, y0], [x1, y1]]`` (doors, walls)."""
    s = np.asarray(segments, dtype=float)
    if s.size == 0:
        s = s.reshape(0, 2, 2)
    if s.ndim != 3 or s.shape[1:] != (2, 2):
        raise ShapeError(f"segments must have shape (N, 2, 2), got {s.shape}")
    ax = _ax(ax)
    for i, seg in enumerate(s):
        ax.plot(seg[:, 0], seg[:, 1], "-", color=_rgb(color), lw=linewidth, solid_capstyle="butt", zorder=6)
        if labels is not None:
            ax.annotate(labels[i], seg.mean(axis=0), textcoords="offset points", xytext=(4, 4), fontsize=8,
                        color=_rgb(color))
    _world_axes(ax, title)
    return ax


def plot_graph(
    graph: Any,
    *,
    ax: Axes | None = None,
    show_distances: bool = True,
    title: str | None = None,
) -> Axes:
    """The room/door graph at its world positions: rooms as large discs (labelled with name and area), doors
    as small squares, edges as lines (labelled with their ``distance``). Node attributes as in
    :func:`hsmap.viz.rerun.log_room_graph`; draw it over :func:`plot_labels` for the paper's Figure 12/16."""
    if not hasattr(graph, "nodes") or not hasattr(graph, "edges"):
        raise InputError(f"expected a networkx graph, got {type(graph).__name__}")
    ax = _ax(ax)
    pos = {}
    for n, d in graph.nodes(data=True):
        c = d.get("centroid")
        if c is None:
            raise InputError(f"graph node {n!r} has no 'centroid' (x, y) attribute")
        pos[n] = np.asarray(c, dtype=float).reshape(-1)[:2]
    for u, v, d in graph.edges(data=True):
        a, b = pos[u], pos[v]
        ax.plot([a[0], b[0]], [a[1], b[1]], "-", color="0.2", lw=1.2, zorder=7)
        if show_distances and d.get("distance") is not None:
            m = (a + b) / 2
            ax.text(m[0], m[1], f"{float(d['distance']):.2f}", fontsize=7, color="0.2", ha="center",
                    va="bottom", zorder=9)
    for i, (n, d) in enumerate(graph.nodes(data=True)):
        kind = d.get("kind", d.get("type")) or ("room" if "area" in d else "door")
        x, y = pos[n]
        if kind == "room":
            lab = d.get("label", n if isinstance(n, (int, np.integer)) else i + 1)
            c = label_color(int(lab)) if isinstance(lab, (int, np.integer)) else SERIES_COLORS["slam"]
            ax.plot(x, y, "o", ms=13, mfc=_rgb(c), mec="k", zorder=8)
            text = str(d.get("name") or (f"R{n}" if isinstance(n, (int, np.integer)) else n))
            if d.get("area") is not None:
                text += f"\n{float(d['area']):.1f} m²"
            ax.annotate(text, (x, y), textcoords="offset points", xytext=(9, 9), fontsize=8, zorder=10,
                        bbox={"boxstyle": "round,pad=0.2", "fc": "white", "alpha": 0.8, "lw": 0})
        else:
            ax.plot(x, y, "s", ms=7, mfc="white", mec="k", mew=1.5, zorder=8)
            ax.annotate(str(d.get("name") or (f"D{n}" if isinstance(n, (int, np.integer)) else n)), (x, y), textcoords="offset points", xytext=(6, -11),
                        fontsize=7, zorder=10)
    _world_axes(ax, title)
    return ax


def plot_cloud_views(
    points: ArrayLike,
    *,
    views: Sequence[str] = ("top", "side"),
    z_range: tuple[float, float] | None = None,
    max_points: int = 300_000,
    size: float | None = None,
    title: str | None = None,
    figsize: tuple[float, float] | None = None,
) -> Figure:
    """Views of a 3D point map (N, 3) coloured by height: ``top`` (x-y), ``side`` (x-z), ``front`` (y-z).

    Large maps are thinned with a fixed stride to ``max_points``; ``size`` (points^2, default: larger for
    sparser maps) is the marker area.
    """
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ShapeError(f"points must have shape (N, 3), got {p.shape}")
    p = p[np.all(np.isfinite(p), axis=1)]
    if len(p) == 0:
        raise InputError("the point map is empty")
    if len(p) > max_points:
        p = p[:: int(np.ceil(len(p) / max_points))]
    if size is None:
        size = float(np.clip(60_000 / len(p), 0.3, 6.0))
    axes_of = {"top": (0, 1, "x [m]", "y [m]"), "side": (0, 2, "x [m]", "z [m]"), "front": (1, 2, "y [m]", "z [m]")}
    bad = [v for v in views if v not in axes_of]
    if bad or not views:
        raise InputError(f"views must be among {list(axes_of)}, got {list(views)}")
    lo, hi = z_range if z_range is not None else (float(np.percentile(p[:, 2], 1)), float(np.percentile(p[:, 2], 99)))
    order = np.argsort(p[:, 2])  # draw high points last so walls show over the floor in the top view
    p = p[order]
    # side views are wide and flat: give them less height than the top view
    extents = {v: (np.ptp(p[:, axes_of[v][0]]) + 1e-6, np.ptp(p[:, axes_of[v][1]]) + 1e-6) for v in views}
    ratios = [max(extents[v][1] / extents[v][0], 0.15) for v in views]
    fig = Figure(figsize=figsize or (9, 9 * min(sum(ratios), 2.2) * 0.85 + 0.8), layout="constrained")
    axs = fig.subplots(len(views), 1, squeeze=False, gridspec_kw={"height_ratios": ratios})[:, 0]
    sc = None
    for ax, v in zip(axs, views, strict=True):
        i, j, xl, yl = axes_of[v]
        sc = ax.scatter(p[:, i], p[:, j], c=p[:, 2], s=size, cmap="turbo", vmin=lo, vmax=hi, marker="o",
                        linewidths=0, rasterized=True)
        ax.set_aspect("equal")
        ax.set_xlabel(xl)
        ax.set_ylabel(yl)
        ax.set_title(f"{v} view", fontsize=10)
    fig.colorbar(sc, ax=list(axs), label="z [m]", shrink=0.8)
    if title:
        fig.suptitle(title)
    return fig
