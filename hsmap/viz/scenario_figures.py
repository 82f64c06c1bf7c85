"""Pictures of simulated worlds and data (matplotlib, Agg; no pyplot state).

- :func:`plot_world`: top view with ground-truth rooms, walls, doors (open green, closed red), furniture
  (coloured by type) and the route.
- :func:`plot_cloud`: one frame's 3D cloud in perspective, and a top view comparing the 2D scan with the
  3D cloud's 1.7-1.8 m slice.
- :func:`plot_odometry_map`: every 2D scan placed at the ground-truth poses and at the odometry poses (the
  drift picture of the paper's Fig. 2).
- :func:`write_previews`: the three for a written dataset folder.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from ..datasets.simulated import SimulatedDataset
from ..geometry import transform_points
from ..io import atomic_path
from ..maps.grid import scans_to_points
from ..sim import layout
from ..sim.robot import plan_legs, sample_legs
from ..sim.scenario import Scenario, load_scenario
from ..sim.shapes import box_corners
from ..sim.world import sensor_poses_3d

__all__ = ["plot_world", "plot_cloud", "plot_odometry_map", "write_previews", "preview_dataset", "draw_floorplan",
           "FURNITURE_COLOURS"]

FURNITURE_COLOURS = {
    "table": "#b07a3b", "desk": "#8c5a2b", "chair": "#d9a441", "shelf": "#5b7fa6", "cabinet": "#6d8f5e",
    "counter": "#7f7f7f", "sofa": "#a65b8c", "column": "#404040", "box": "#999999",
}


def _figure(w: float, h: float, ncols: int = 1, projection3d: tuple[int, ...] = ()):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w, h), dpi=110)
    FigureCanvasAgg(fig)
    axes = [fig.add_subplot(1, ncols, k + 1, projection="3d" if k in projection3d else None)
            for k in range(ncols)]
    return fig, axes


def _save(fig, path: str | os.PathLike | None) -> None:
    if path is None:
        return
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=path.suffix.lstrip(".") or "png", bbox_inches="tight")


def draw_floorplan(ax, scn: Scenario, rooms: bool = True, furniture: bool = True, doors: bool = True,
                   names: bool = True, wall_colour: str = "#303030", alpha: float = 1.0) -> None:
    """Draw the world's top view into a matplotlib Axes (world metres, equal aspect)."""
    from matplotlib.collections import PolyCollection

    if rooms and scn.rooms:
        labels, grid, rnames, _ = layout.rasterize_rooms(scn, 0.05)
        rgba = np.zeros(labels.shape + (4,))
        palette = np.array([[0.65, 0.81, 0.89], [0.70, 0.87, 0.54], [0.99, 0.75, 0.44], [0.79, 0.70, 0.84],
                            [1.00, 1.00, 0.60], [0.98, 0.60, 0.60], [0.85, 0.85, 0.85], [0.55, 0.83, 0.78]])
        for lab in rnames:
            rgba[labels == lab, :3] = palette[(lab - 1) % len(palette)]
            rgba[labels == lab, 3] = 0.45 * alpha
        ax.imshow(rgba, extent=grid.extent(), origin="upper", interpolation="nearest", zorder=0)
        if names:
            for r in scn.rooms:
                m = labels == r.label
                if m.any():
                    rc = np.argwhere(m).mean(0)
                    x, y = grid.pixel_to_world(rc)
                    ax.text(x, y, r.name, ha="center", va="center", fontsize=8, color="#1f3b57", zorder=6,
                            bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": "none", "alpha": 0.7})
    boxes, kinds, _ = layout.structure_boxes(scn)
    walls = boxes[[k == "wall" for k in kinds]]
    ax.add_collection(PolyCollection(box_corners(walls), facecolors=wall_colour, edgecolors=wall_colour,
                                     linewidths=0.3, zorder=3, alpha=alpha))
    if furniture and scn.furniture:
        fb = np.array([layout.furniture_footprint(f) for f in scn.furniture])
        cols = [FURNITURE_COLOURS.get(f.type, "#999999") for f in scn.furniture]
        ax.add_collection(PolyCollection(box_corners(fb), facecolors=cols, edgecolors="black", linewidths=0.4,
                                         alpha=0.8 * alpha, zorder=2))
    if doors:
        for d in layout.door_records(scn):
            (x0, y0), (x1, y1) = d["endpoints"]
            ax.plot([x0, x1], [y0, y1], color="#1a9850" if d["open"] else "#d73027", lw=3.0, zorder=4,
                    solid_capstyle="butt", alpha=alpha)
    lo, hi = layout.bounds(scn)
    ax.set_xlim(lo[0] - 0.5, hi[0] + 0.5)
    ax.set_ylim(lo[1] - 0.5, hi[1] + 0.5)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")


def plot_world(scn: Scenario, path: str | os.PathLike | None = None, route: ArrayLike | None = None,
               odometry: ArrayLike | None = None, title: str | None = None):
    """Top view of a scenario: rooms, walls, doors, furniture and the route.

    Parameters
    ----------
    route : array of shape (S, 2+), optional
        Ground-truth positions to draw as the route (default: the planned legs, densely sampled).
    odometry : array of shape (S, 2+), optional
        Odometry positions to draw for comparison.

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.lines import Line2D

    lo, hi = layout.bounds(scn)
    span = hi - lo
    fig, (ax,) = _figure(min(16.0, 1.2 + 0.75 * span[0]), min(12.0, 1.0 + 0.75 * span[1]) + 0.6)
    draw_floorplan(ax, scn)
    if route is None:

        legs = plan_legs(scn.start, scn.steps, scn.robot)
        t = np.linspace(0.0, legs[-1].t0 + legs[-1].duration, 4000)
        route = sample_legs(legs, t)
    route = np.asarray(route, dtype=float)
    ax.plot(route[:, 0], route[:, 1], color="#2166ac", lw=1.2, zorder=5)
    ax.plot(*route[0, :2], marker="o", color="#2166ac", ms=7, zorder=7)
    ax.plot(*route[-1, :2], marker="s", color="#2166ac", ms=7, mfc="white", zorder=7)
    handles = [Line2D([], [], color="#2166ac", marker="o", label="route (start o, end □)"),
               Line2D([], [], color="#1a9850", lw=3, label="open door"),
               Line2D([], [], color="#d73027", lw=3, label="closed door")]
    if odometry is not None:
        odo = np.asarray(odometry, dtype=float)
        ax.plot(odo[:, 0], odo[:, 1], color="#b2182b", lw=0.9, ls="--", zorder=5)
        handles.append(Line2D([], [], color="#b2182b", ls="--", label="wheel odometry"))
    for ftype in sorted({f.type for f in scn.furniture}):
        handles.append(Line2D([], [], color=FURNITURE_COLOURS.get(ftype, "#999"), marker="s", ls="", label=ftype))
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    length = float(np.linalg.norm(np.diff(route[:, :2], axis=0), axis=1).sum())
    ax.set_title(title or f"{scn.name}: {len(scn.rooms)} rooms, {len(scn.doors)} doors, "
                 f"{len(scn.furniture)} pieces of furniture, route {length:.0f} m")
    _save(fig, path)
    return fig


def plot_cloud(scn: Scenario, base_pose: ArrayLike, cloud_world: ArrayLike, scan_world: ArrayLike | None = None,
               path: str | os.PathLike | None = None, slice_z: tuple[float, float] = (1.7, 1.8),
               max_points: int = 60000, radius: float = 9.0, title: str | None = None):
    """One frame: the 3D cloud in perspective (coloured by height, ceiling hidden, within ``radius`` m of
    the robot) above a top view of the 2D scan (red) and the 3D cloud's ``slice_z`` slice (blue) over the
    floor plan.

    Parameters
    ----------
    base_pose : array of shape (3,)
        Robot base pose (x, y, yaw) in the world.
    cloud_world : array of shape (K, 3)
        3D points in the world frame.
    scan_world : array of shape (M, 2), optional
        2D scan points in the world frame.
    """
    from matplotlib.gridspec import GridSpec

    pts = np.asarray(cloud_world, dtype=float)
    bp = np.asarray(base_pose, dtype=float)
    lo, hi = layout.bounds(scn)
    span = hi - lo
    fig, _ = _figure(14.0, 6.0 + 12.0 * span[1] / span[0], 0)
    gs = GridSpec(2, 1, figure=fig, height_ratios=[1.1, span[1] / span[0] * 1.6])
    ax3 = fig.add_subplot(gs[0], projection="3d")
    ax2 = fig.add_subplot(gs[1])
    ceiling = scn.ceiling_height if scn.ceiling_height is not None else np.inf
    near = (np.hypot(pts[:, 0] - bp[0], pts[:, 1] - bp[1]) < radius) & (pts[:, 2] < ceiling - 0.05)
    sub = pts[near]
    if len(sub) > max_points:
        sub = sub[np.random.default_rng(0).choice(len(sub), max_points, replace=False)]
    ax3.scatter(sub[:, 0], sub[:, 1], sub[:, 2], c=sub[:, 2], cmap="viridis", s=0.4, linewidths=0,
                rasterized=True)
    ax3.scatter([bp[0]], [bp[1]], [scn.lidar3d.position[2]], c="red", s=30, depthshade=False)
    ax3.set_box_aspect((np.ptp(sub[:, 0]), np.ptp(sub[:, 1]), max(np.ptp(sub[:, 2]), 0.5)), zoom=1.25)
    ax3.view_init(elev=35, azim=-110)
    ax3.set_xlabel("x [m]")
    ax3.set_ylabel("y [m]")
    ax3.set_zlabel("z [m]")
    n_ceiling = int(np.count_nonzero(pts[:, 2] >= ceiling - 0.05))
    ax3.set_title(f"3D LiDAR cloud: {len(pts)} points ({n_ceiling} on the ceiling, hidden); "
                  f"shown: within {radius:g} m of the robot (red), colour = height")
    draw_floorplan(ax2, scn, rooms=False, names=False, wall_colour="#bbbbbb", alpha=0.6)
    band = pts[(pts[:, 2] >= slice_z[0]) & (pts[:, 2] <= slice_z[1])]
    ax2.scatter(band[:, 0], band[:, 1], s=0.8, c="#2166ac", linewidths=0, zorder=6,
                label=f"3D cloud, slice {slice_z[0]:g}-{slice_z[1]:g} m ({len(band)} pts)")
    if scan_world is not None:
        sw = np.asarray(scan_world, dtype=float)
        ax2.scatter(sw[:, 0], sw[:, 1], s=1.5, c="#d73027", linewidths=0, zorder=7,
                    label=f"2D scan at {scn.lidar2d.height:g} m ({len(sw)} pts)")
    ax2.plot(*bp[:2], marker="o", color="black", ms=5, zorder=8)
    ax2.arrow(bp[0], bp[1], 0.5 * np.cos(bp[2]), 0.5 * np.sin(bp[2]), width=0.04, color="black", zorder=8)
    ax2.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, markerscale=8, frameon=False)
    ax2.set_title("top view: the 2D scan sees furniture, the 3D slice sees walls")
    if title:
        fig.suptitle(title)
    _save(fig, path)
    return fig


def _scans_to_world(ranges: ArrayLike, angles: ArrayLike, poses: ArrayLike, extrinsic2d: ArrayLike,
                    step: int = 1) -> np.ndarray:
    """All valid 2D returns (P, 2) in the world, for scans (N, M) taken at base poses (N, 3); every ``step``-th
    beam."""

    a = np.asarray(angles, dtype=float)[::step]
    scans = [np.column_stack([r * np.cos(a), r * np.sin(a)]) for r in np.asarray(ranges, dtype=float)[:, ::step]]
    return scans_to_points(scans, poses, extrinsic2d)


def plot_odometry_map(ranges: ArrayLike, angles: ArrayLike, extrinsic2d: ArrayLike, groundtruth: ArrayLike,
                      odometry: ArrayLike, path: str | os.PathLike | None = None, title: str | None = None,
                      step: int = 2):
    """The 2D scans placed at ground-truth poses (left) and at wheel-odometry poses (right).

    Parameters
    ----------
    ranges : array of shape (N, M)
    angles : array of shape (M,)
    extrinsic2d : array of shape (3,)
    groundtruth, odometry : array of shape (N, 3)
    step : int
        Use every ``step``-th beam (the picture does not need all of them).
    """
    gt = np.asarray(groundtruth, dtype=float)
    odo = np.asarray(odometry, dtype=float)
    maps = [_scans_to_world(ranges, angles, poses, extrinsic2d, step) for poses in (gt, odo)]
    allp = np.concatenate(maps + [gt[:, :2], odo[:, :2]])
    lo, hi = np.percentile(allp, 0.2, axis=0) - 0.5, np.percentile(allp, 99.8, axis=0) + 0.5
    span = hi - lo
    wide = span[0] > 1.6 * span[1]
    if wide:  # one above the other
        fig, axes = _figure(13.0, 2 * 13.0 * span[1] / span[0] + 1.2, 0)
        axes = [fig.add_subplot(2, 1, 1), fig.add_subplot(2, 1, 2)]
    else:
        fig, axes = _figure(2 * 8.0 * span[0] / span[1] + 1.0, 8.0, 2)
    end_err = float(np.hypot(*(odo[-1, :2] - gt[-1, :2])))
    for ax, poses, pts, name in ((axes[0], gt, maps[0], "ground-truth poses"),
                                 (axes[1], odo, maps[1], "wheel-odometry poses")):
        ax.scatter(pts[:, 0], pts[:, 1], s=0.3, c="black", alpha=0.3, linewidths=0, rasterized=True)
        ax.plot(poses[:, 0], poses[:, 1], color="#2166ac" if poses is gt else "#b2182b", lw=1.0)
        ax.plot(*poses[0, :2], marker="o", color="#2166ac", ms=6)
        ax.set_aspect("equal")
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_title(f"2D scans at {name}")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
    axes[1].plot(gt[:, 0], gt[:, 1], color="#2166ac", lw=0.8, ls=":", label="ground truth")
    axes[1].legend(loc="lower right", fontsize=8)
    fig.suptitle(title or f"odometry-only map: {len(gt)} scans, odometry ends {end_err:.2f} m off")
    _save(fig, path)
    return fig


def write_previews(folder: str | os.PathLike, scn: Scenario, groundtruth: ArrayLike, odometry: ArrayLike,
                   ranges2d: ArrayLike, cloud_frame: int, cloud_sensor: ArrayLike,
                   stamps: ArrayLike | None = None) -> list[str]:
    """Write ``figures/world.png``, ``figures/cloud.png`` and ``figures/odometry.png`` into ``folder``.

    Parameters
    ----------
    groundtruth, odometry : array of shape (N, 3)
        Robot base poses.
    ranges2d : array of shape (N, M)
        The 2D scans (NaN = no return), beams at ``scn.lidar2d.angles()``.
    cloud_frame : int
        The frame whose 3D cloud ``cloud_sensor`` (K, 3), in the 3D sensor frame, is pictured.

    Returns
    -------
    list of str
        The file names written under ``figures/``.
    """

    out = Path(folder) / "figures"
    gt, odo = np.asarray(groundtruth, dtype=float), np.asarray(odometry, dtype=float)
    plot_world(scn, out / "world.png", route=gt, odometry=odo)
    k = int(cloud_frame)
    cloud_w = transform_points(sensor_poses_3d(gt[k:k + 1], scn.lidar3d)[0], cloud_sensor)
    ext = scn.lidar2d.extrinsic()
    scan_w = _scans_to_world(np.asarray(ranges2d)[k:k + 1], scn.lidar2d.angles(), gt[k:k + 1], ext)
    when = f" (t = {float(np.asarray(stamps)[k]):.1f} s)" if stamps is not None else ""
    plot_cloud(scn, gt[k], cloud_w, scan_w, out / "cloud.png", title=f"{scn.name}, frame {k}{when}")
    plot_odometry_map(ranges2d, scn.lidar2d.angles(), ext, gt, odo, out / "odometry.png",
                      title=f"{scn.name}: odometry-only 2D map ({len(gt)} scans, odometry ends "
                            f"{float(np.hypot(*(odo[-1, :2] - gt[-1, :2]))):.2f} m off)")
    return ["world.png", "cloud.png", "odometry.png"]


def preview_dataset(folder: str | os.PathLike, frame: int | None = None) -> list[str]:
    """:func:`write_previews` for a complete dataset folder (reads it with SimulatedDataset)."""

    ds = SimulatedDataset(folder)
    scn = load_scenario(ds.scenario_path(), check=False)
    k = len(ds) // 2 if frame is None else int(frame)
    return write_previews(folder, scn, ds.groundtruth.poses, ds.odometry.poses, ds.ranges2d, k, ds.cloud3d(k),
                          ds.stamps)
