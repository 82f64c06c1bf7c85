"""The study's rerun recordings: a cached HS-SLAM run replayed frame by frame (as ``hsmap slam`` logs it live),
the map overlap (notebook 04) and the topology (notebook 06), each with the layout it opens on."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from typing import Any

import numpy as np

from ..datasets.frames import Dataset, Frame
from ..errors import InputError
from ..geometry import pose_to_matrix, transform_points
from ..mapping import first_per_voxel
from ..slam import frame_points
from ..trajectory import Trajectory
from .runs import SlamRun

__all__ = [
    "record_slam_run", "slam_blueprint", "record_overlap", "overlap_blueprint", "record_topology",
    "topology_blueprint",
]


def record_slam_run(
    rec: Any,
    dataset: Dataset | Iterable[Frame],
    run: SlamRun,
    *,
    every: int = 1,
    map_block: int = 10,
    map_voxel: float | None = None,
    cloud_voxel: float = 0.25,
    groundtruth: Trajectory | None = None,
    odometry: Trajectory | None = None,
    grid: Any = None,
    grid_updates: int = 12,
    path_updates: int = 60,
    map_z_range: tuple[float, float] | None = None,
) -> dict:
    """Log a (cached) SLAM run to a rerun recording, frame by frame on the ``scan`` and ``time`` timelines.

    Replays the run from its stored poses, as ``hsmap slam`` logs it live: the robot (a box at ``world/robot``),
    the current 2D scan and 3D cloud under their sensors, the growing map (the keyframes' points, in blocks of
    ``map_block`` keyframes under ``world/map/points``), the estimated path and the optional ground truth and
    odometry drawn up to the current time (``path_updates`` times over the run), and a legend
    (``legend``, shown by ``default_blueprint(legend=True)``).

    Parameters
    ----------
    every : int
        Log every n-th frame's pose and scan (the map still gets every keyframe).
    grid : hsmap.grid.OccupancyGrid, optional
        The run's final occupancy grid (3-DOF runs). Its geometry is the 2D map view's frame: the grid of the
        keyframes' scans so far is logged ``grid_updates`` times over the run (the map grows in both views,
        the final one at the last frame), with the robot, its scan and the paths over it.
    map_z_range : (float, float), optional
        Only map points within these heights are logged (6-DOF: leave out the floor and the ceiling, which
        hide the paths and the rooms from above).

    Returns
    -------
    dict
        ``frames`` logged, ``map_blocks``, ``map_points`` logged, ``grid_updates`` logged.
    """
    from ..grid import grid_from_scans
    from ..viz import rerun as hv

    if int(every) < 1:
        raise InputError(f"every must be >= 1, got {every}")
    if int(grid_updates) < 1 or int(path_updates) < 1:
        raise InputError(f"grid_updates and path_updates must be >= 1, got {grid_updates} and {path_updates}")
    dof = run.dof
    cfg = run.config
    index_of = {int(i): k for k, i in enumerate(run.frame_indices)}
    key = run.keyframes
    poses = run.trajectory.poses
    map_vox = map_voxel or (0.05 if dof == 3 else 0.15)
    logger = hv.PointMapLogger(rec, block=int(map_block), voxel=map_vox,
                               z_range=(-0.2, 3.0) if dof == 6 else None, radius=0.02 if dof == 3 else 0.015)
    logged = 0
    n_frames = len(run.trajectory)
    geometry = None if grid is None else grid.geometry
    paths = {"estimate": run.trajectory}
    if groundtruth is not None:
        paths["groundtruth"] = groundtruth
    if odometry is not None:
        paths["odometry"] = odometry
    path_at = {name: _aligned(t, run.trajectory) for name, t in paths.items()}
    grid_every = max(1, -(-n_frames // int(grid_updates)))
    path_every = max(1, -(-n_frames // int(path_updates)))
    scans, scan_poses, extrinsics = [], [], []
    grids_logged = 0
    hv.log_legend(rec, _slam_legend(dof, list(paths), grid is not None))

    thin = first_per_voxel  # one point per voxel; the viewer-side thinning then has little left to do

    def log_paths(k: int) -> None:
        for name, p in path_at.items():
            upto = p[: k + 1]
            if len(upto) < 2:
                continue
            wide = 1.8 if name == "groundtruth" else 1.0  # under the estimate, which mostly lies on it
            hv.log_path(rec, name, upto, static=False, radius=wide * (0.04 if dof == 3 else 0.05))
            if geometry is not None:
                hv.log_map2d_path(rec, name, upto, geometry, static=False, radius=wide * 1.5)

    last = -1
    for f in (dataset.frames(clouds=dof == 6) if isinstance(dataset, Dataset) else iter(dataset)):
        k = index_of.get(int(f.index))
        if k is None:
            if f.index > run.frame_indices.max():
                break
            continue
        final = k == n_frames - 1
        show = k % int(every) == 0 or final
        update_grid = geometry is not None and (k % grid_every == 0 or final)
        update_path = k % path_every == 0 or final
        if not (show or key[k] or update_grid or update_path):
            continue
        if dof == 6 and f.cloud3d is not None:
            f = dataclasses.replace(f, cloud3d=thin(np.asarray(f.cloud3d, dtype=float), min(cloud_voxel, map_vox)))
        hv.set_frame_time(rec, k, f.stamp)
        if show:
            shown = f if dof == 6 else dataclasses.replace(f, cloud3d=None)
            hv.log_frame(rec, shown, poses[k], index=k, cloud_voxel=cloud_voxel)
            logged += 1
            if geometry is not None:
                hv.log_map2d_robot(rec, poses[k], geometry)
                if f.scan2d is not None and dof == 3:
                    sensor = pose_to_matrix(poses[k]) @ pose_to_matrix(f.extrinsic2d)
                    hv.log_map2d_points(rec, "scan", transform_points(sensor, f.scan2d.points()), geometry)
        if key[k]:
            pts = frame_points(f, dof, cfg.min_range, cfg.max_range)
            world = thin(transform_points(pose_to_matrix(poses[k]), pts), map_vox)
            if map_z_range is not None and world.shape[1] == 3:
                world = world[(world[:, 2] >= map_z_range[0]) & (world[:, 2] <= map_z_range[1])]
            logger.add(world)
            if geometry is not None and f.scan2d is not None:
                scans.append(f.scan2d)
                scan_poses.append(poses[k][:3] if dof == 3 else poses[k][[0, 1, 5]])
                extrinsics.append(f.extrinsic2d)
        if update_grid and scans:
            g = grid if final else grid_from_scans(scans, np.array(scan_poses), extrinsic=np.array(extrinsics),
                                                   geometry=geometry)
            hv.log_occupancy_grid(rec, g.data, geometry, static=False)
            grids_logged += 1
        if update_path:
            log_paths(k)
        last = k
    logger.flush()
    if last >= 0 and last != n_frames - 1:
        log_paths(last)
    return {"frames": logged, "map_blocks": logger.blocks, "map_points": logger.points_logged,
            "grid_updates": grids_logged}


def _aligned(t: Trajectory, ref: Trajectory) -> np.ndarray:
    """The poses of ``t`` at the stamps of ``ref`` (nearest stamp), so every path is cut at the same time."""
    from ..trajectory import nearest_index

    idx = nearest_index(t.stamps, ref.stamps)
    return np.asarray(t.poses, dtype=float)[idx]


def _slam_legend(dof: int, paths: list[str], grid: bool) -> str:
    from ..viz.rerun import series_legend

    what = "2D LiDAR scans" if dof == 3 else "3D LiDAR clouds"
    lines = [
        f"### HS-SLAM {'2D (3-DOF)' if dof == 3 else '6-DOF'} run, replayed",
        "Move the time cursor (timelines `time` and `scan`): the map grows as the robot goes.",
        "",
        series_legend(paths),
        "- **orange box** (3D) / **orange arrow** (2D map): the robot at the current time",
        f"- **orange-red points**: the current {'scan' if dof == 3 else 'cloud (coloured by height)'}",
        f"- **{'grey' if dof == 3 else 'height-coloured'} points**: the map, the keyframes' {what} at their "
        "estimated poses" + ("" if dof == 3 else " (floor and ceiling left out)"),
    ]
    if grid:
        lines.append("- **2D map**: the occupancy grid of the keyframes' scans so far (white free, black "
                     "occupied, grey unknown)")
    return "\n".join(lines)


# --- layouts and recordings of the study's figures ---------------------------------------------------------


def slam_blueprint(run: SlamRun, *, grid: Any = None, names: dict[str, str] | None = None) -> Any:
    """The layout of a SLAM run's recording (:func:`record_slam_run`): the 3D world framed on the run's map
    (the grid's extent, else the path's with 5 m around it), the 2D map when there is a grid, and the legend."""
    from ..viz import rerun as hv

    if grid is not None:
        lo, hi = hv.grid_bounds(grid.geometry)
    else:
        p = np.asarray(run.trajectory.poses, dtype=float)
        lo = np.array([p[:, 0].min() - 5.0, p[:, 1].min() - 5.0, 0.0])
        hi = np.array([p[:, 0].max() + 5.0, p[:, 1].max() + 5.0, 2.8])
    return hv.default_blueprint(map2d=grid is not None, graph=False, legend=True, names=names,
                                eye=hv.eye_for_bounds(lo, hi))


OVERLAP_LEGEND = """### The floor-level 2D map and the 3D map's slice, registered (paper's Figure 13)
- **red** cells: seen by the 2D LiDAR only (at floor level: legs of tables and chairs, low furniture)
- **blue** cells: seen in the 3D map's 1.7-1.8 m slice only (behind furniture, tall furniture)
- **black** cells: seen by both (walls); white: free in both
- **red points** (0.2 m): the 2D HS-SLAM map's points, moved by the registration found
- **height-coloured points**: the 6-DOF HS-SLAM 3D map below the ceiling
- hidden at first (eye icon in the blueprint panel): `world/map/slice`, the slice grid at its height, and
  `world/map/ceiling`, the map's points above 2.4 m
- **2D map**: the overlay, and `map/floor`, the floor-level grid
"""


def record_overlap(
    rec: Any,
    *,
    map3d: np.ndarray,
    slice_grid: Any,
    floor_grid: Any,
    overlay: np.ndarray,
    floor_points: np.ndarray,
    slice_height: float,
    ceiling: float = 2.4,
) -> dict:
    """Notebook 04's recording: the 3D map, the slice grid (hidden at first), the registered floor-level grid
    and points, the overlay (3D and 2D) and the legend. ``floor_points`` are already moved into the 3D map's
    frame. Use :func:`overlap_blueprint` for the layout."""
    from ..viz import map_figures
    from ..viz import rerun as hv

    pts = np.asarray(map3d, dtype=float)
    below = pts[:, 2] <= ceiling
    n = hv.log_points(rec, "world/map/points3d", pts[below], color_by_height=True, z_range=(0.0, 2.8), voxel=0.1,
                      static=True, radius=0.015)
    hv.log_points(rec, "world/map/ceiling", pts[~below], color_by_height=True, z_range=(0.0, 2.8), voxel=0.1,
                  static=True, radius=0.015)
    hv.log_occupancy_grid(rec, slice_grid.data, slice_grid.geometry, entity="world/map/slice", map_entity=None,
                          z=slice_height, opacity=0.6)
    hv.log_occupancy_grid(rec, floor_grid.data, floor_grid.geometry, entity="world/map/floor",
                          map_entity="map/floor", z=0.2, opacity=0.6)
    map_figures.log_overlay(rec, overlay, floor_grid.geometry, z=0.01)
    fp = np.asarray(floor_points, dtype=float)
    hv.log_points(rec, "world/map/points2d", np.column_stack([fp[:, :2], np.full(len(fp), 0.2)]),
                  colors=(214, 39, 40), radius=0.02, static=True)
    hv.log_legend(rec, OVERLAP_LEGEND)
    return {"map3d_points": n, "floor_points": len(fp)}


def overlap_blueprint(geometry: Any) -> Any:
    """The layout of :func:`record_overlap`'s recording, framed on ``geometry`` (the overlay's grid)."""
    from ..viz import rerun as hv

    return hv.default_blueprint(
        graph=False, legend=True, eye=hv.eye_for_bounds(*hv.grid_bounds(geometry)),
        hidden=("world/map/slice", "world/map/ceiling"),
        names={"3D world": "Figure 13: 3D map, slice and floor-level map", "2D map": "Figure 13: overlay"})


TOPOLOGY_LEGEND = """### Rooms, doors and the topological map (paper's Figures 12, 15 and 16)
- **coloured cells**: the rooms of the slice's segmentation, one colour per room (as in the figures)
- **graph**: a node per room (its centroid; name and area) and per door, an edge from each door to the two
  rooms it joins; in the 3D view the graph floats above the map, each edge's length (m) at its middle;
  in the graph view a door that lies on the line between its rooms is drawn a little aside
- **red points**: each door's points in the 3D map (its frame and lintel, Figure 15); **black points**: in the
  2D map (`world/doors/D<k>`)
- **height-coloured points**: the 6-DOF HS-SLAM 3D map below the ceiling; the ceiling (`world/map/ceiling`)
  is hidden at first
"""


def record_topology(
    rec: Any,
    *,
    grid: Any,
    labels: np.ndarray,
    names: dict[int, str],
    graph: Any,
    map3d: np.ndarray,
    door_points2d: list[np.ndarray],
    door_points3d: list[np.ndarray],
    ceiling: float = 2.4,
    graph_height: float = 2.9,
) -> dict:
    """Notebook 06's recording: the occupancy grid, the room labels, the room/door graph (3D, 2D map and graph
    view), the 3D map (ceiling hidden at first), each door's 2D and 3D points, and the legend. Use
    :func:`topology_blueprint` for the layout."""
    from ..viz import rerun as hv

    hv.log_occupancy_grid(rec, grid.data, grid.geometry)
    hv.log_room_labels(rec, labels, grid.geometry, names=names)
    if graph.number_of_nodes():
        hv.log_room_graph(rec, graph, geometry=grid.geometry, z=graph_height)
    pts = np.asarray(map3d, dtype=float)
    below = pts[:, 2] <= ceiling
    hv.log_points(rec, "world/map/points3d", pts[below], color_by_height=True, z_range=(0.0, 2.8), voxel=0.1,
                  static=True, radius=0.012)
    hv.log_points(rec, "world/map/ceiling", pts[~below], color_by_height=True, z_range=(0.0, 2.8), voxel=0.1,
                  static=True, radius=0.012)
    doors = 0
    for k, (c2, c3) in enumerate(zip(door_points2d, door_points3d, strict=True), start=1):
        if len(c3):
            hv.log_points(rec, f"world/doors/D{k}/points3d", c3, colors=(214, 39, 40), radius=0.04, static=True)
        if len(c2):
            hv.log_points(rec, f"world/doors/D{k}/points2d", np.column_stack([c2, np.full(len(c2), 0.2)]),
                          colors=(20, 20, 20), radius=0.05, static=True)
        doors += bool(len(c2) or len(c3))
    hv.log_legend(rec, TOPOLOGY_LEGEND)
    return {"rooms": int(sum(1 for _, d in graph.nodes(data=True) if d.get("kind", "room") == "room")),
            "doors_with_points": doors}


def topology_blueprint(geometry: Any) -> Any:
    """The layout of :func:`record_topology`'s recording, framed on ``geometry``."""
    from ..viz import rerun as hv

    lo, hi = hv.grid_bounds(geometry, (0.0, 3.0))
    return hv.default_blueprint(
        legend=True, eye=hv.eye_for_bounds(lo, hi), hidden=("world/map/ceiling",),
        names={"3D world": "Figures 15/16: rooms, doors and graph in 3D", "2D map": "Figure 12: rooms and doors",
               "Room graph": "Figure 16: room/door graph"})
