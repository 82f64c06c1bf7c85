"""The study's rerun recordings: a cached HS-SLAM run replayed frame by frame (as ``hsmap slam`` logs it live),
the map overlap (notebook 04) and the topology (notebook 06), each with the layout it opens on."""

from __future__ import annotations

from typing import Any

import numpy as np

from .runs import SlamRun

__all__ = [
    "record_slam_run", "slam_blueprint", "record_overlap", "overlap_blueprint", "record_topology",
    "topology_blueprint",
]


def record_slam_run(rec: Any, dataset: Any, run: SlamRun, **kwargs: Any) -> dict:
    """A cached run replayed into a recording: :func:`hsmap.viz.replay.record_slam_run` (rerun is imported when a
    recording is made)."""
    from ..viz.replay import record_slam_run as replay

    return replay(rec, dataset, run, **kwargs)


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
