"""HS-SLAM runs as rerun recordings: live, as ``hsmap slam`` runs (:class:`SlamRecorder`), replayed from a
finished run's poses (:func:`record_slam_run`), and the whole chain's maps (:func:`record_map`, ``hsmap map``)."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from ..datasets.frames import Dataset, Frame
from ..errors import InputError
from ..geometry import pose_to_matrix, transform_points
from ..maps.grid import grid_from_scans, grids_from_scan_prefixes
from ..maps.mapping import first_per_voxel
from ..slam import SlamConfig, frame_points
from ..trajectory import Trajectory, nearest_index
from . import map_figures
from . import rerun as hv
from .rerun import series_legend

__all__ = ["SlamRecorder", "record_slam_run", "record_map", "REPLAY_GRID_CELLS"]

#: The live recording's growing 2D map: 5 cm cells up to a 2000 x 2000 image, coarser beyond
REPLAY_GRID_CELLS = 4_000_000


class SlamRecorder:
    """A run recorded as it goes (``hsmap slam``): each frame (robot, scan, cloud), the map as keyframes join it;
    after the run (:meth:`finish`) the final path drawn up to each time and, in 3-DOF, the growing occupancy grid
    of the keyframes' scans at their final poses.

    Parameters
    ----------
    path : path
        The ``.rrd`` file.
    config : SlamConfig
        The run's settings (dof, range limits).
    """

    def __init__(self, path: str | Path, config: SlamConfig) -> None:
        self.config = config
        dof = config.dof
        # a 2D map view only where there is a 2D map: the occupancy grid of a 3-DOF run, logged at the end
        self.rec = hv.open_recording(path, application_id="hsmap_slam",
                                     blueprint=hv.default_blueprint(graph=False, map2d=dof == 3, legend=True))
        hv.log_legend(self.rec, _live_legend(dof))
        self._map = hv.PointMapLogger(self.rec, block=10, voxel=0.05 if dof == 3 else 0.15)
        # the frames are logged in blocks, as columns: a few calls per block instead of a few per frame
        self._frames = hv.FrameLogger(self.rec, block=64, cloud_voxel=0.25)
        self._keyscans: list[Frame] = []  # 3-DOF: the keyframes' scans, for the grid at their final poses

    def on_frame(self, frame: Frame, result: Any, slam: Any = None) -> None:
        """Log one processed frame (``run_slam``'s ``on_frame``): ``result`` is its :class:`FrameResult`."""
        cfg = self.config
        self._frames.add(frame, result.pose)
        if result.keyframe:
            if cfg.dof == 3:
                self._keyscans.append(frame)
            pts = frame_points(frame, cfg.dof, cfg.min_range, cfg.max_range)
            hv.set_frame_time(self.rec, frame.index, frame.stamp)  # the map block's time
            self._map.add(transform_points(pose_to_matrix(result.pose), pts))

    def finish(self, result: Any) -> None:
        """After the run (``result``: its :class:`~hsmap.slam.SlamResult`): flush, then the final path and grids."""
        self._frames.flush()
        if result.frames:
            hv.set_frame_time(self.rec, result.frames[-1].index, result.frames[-1].stamp)
        self._map.flush()
        _log_final(self.rec, self._keyscans, result)

    def close(self) -> None:
        self.rec.close()

    def abort(self) -> None:
        self.rec.abort()


def _live_legend(dof: int) -> str:
    lines = [f"### hsmap slam ({'3-DOF' if dof == 3 else '6-DOF'})",
             "Move the time cursor (timelines `time` and `scan`) to replay the run.", "",
             series_legend(["estimate"]) + " (after loop closure: the optimised poses, drawn up to the current time)",
             "- **orange box** (3D)" + (" / **orange arrow** (2D map)" if dof == 3 else "") + ": the robot",
             "- **orange-red points**: the current scan" + ("" if dof == 3 else " and cloud (coloured by height)"),
             "- **points**: the map, the keyframes at their poses when they were added"]
    if dof == 3:
        lines.append("- **2D map**: the occupancy grid of the keyframes' scans so far, at their final poses")
    return "\n".join(lines)


def _log_final(rec, keyscans, result, grid_updates: int = 10, path_updates: int = 60) -> None:
    """After the run: the final (optimised) path drawn up to each time, and, in 3-DOF, the occupancy grid of
    the keyframes' scans so far (at their final poses) growing along the timelines in both views, with the
    robot in the 2D map view."""
    traj = result.trajectory
    n = len(traj)
    if n == 0:
        return
    idx = np.array([f.index for f in result.frames]) if len(result.frames) == n else np.arange(n)
    stamps = np.asarray(traj.stamps, dtype=float)
    poses = np.asarray(traj.poses, dtype=float)
    grid = geo = None
    grids: dict = {}
    if keyscans and result.config.dof == 3:
        kposes, found = traj.as_3dof().at([f.stamp for f in keyscans], max_dt=1e-3)
        kept = [f for f, ok in zip(keyscans, found, strict=True) if ok]
        if kept:
            scans = [f.scan2d for f in kept]
            ext = np.asarray([f.extrinsic2d for f in kept], dtype=float)
            kstamps = np.array([f.stamp for f in kept])
            # the growing grid at every update and the final one, all in one pass over the scans (keyframes
            # come in stamp order: the scans up to a time are a prefix)
            at = sorted(set(np.linspace(0, n - 1, grid_updates).round().astype(int)) - {n - 1})
            counts = [int((kstamps <= stamps[r]).sum()) for r in at]
            *partial, grid = grids_from_scan_prefixes(scans, kposes, [*counts, len(kept)], 0.05, extrinsic=ext,
                                                      max_cells=REPLAY_GRID_CELLS)
            geo = grid.geometry
            grids = {**dict(zip(at, partial, strict=True)), n - 1: grid}
    grid_at = set(grids) if geo is not None else set()
    path_at = set(np.linspace(0, n - 1, path_updates).round().astype(int))
    robot_every = max(1, n // 600)
    if geo is not None:  # the robot in the 2D map view, as columns (one call)
        hv.log_map2d_robots(rec, poses[::robot_every], geo, idx[::robot_every], stamps[::robot_every])
    for r in range(n):
        g, p = r in grid_at, r in path_at
        if not (g or p):
            continue
        hv.set_frame_time(rec, int(idx[r]), stamps[r])
        if p and r > 0:
            hv.log_path(rec, "estimate", poses[: r + 1], static=False)
            if geo is not None:
                hv.log_map2d_path(rec, "estimate", poses[: r + 1], geo, static=False)
        if g:
            if r < n - 1 and not (kstamps <= stamps[r]).any():
                continue
            hv.log_occupancy_grid(rec, grids[r].data, geo, static=False)


def record_slam_run(
    rec: Any,
    dataset: Dataset | Iterable[Frame],
    run: Any,
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
    grid : hsmap.maps.grid.OccupancyGrid, optional
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
    from . import rerun as hv

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

    idx = nearest_index(t.stamps, ref.stamps)
    return np.asarray(t.poses, dtype=float)[idx]


def _slam_legend(dof: int, paths: list[str], grid: bool) -> str:
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


MAP_LEGEND = """### hsmap map: the paper's chain on one recording
- **coloured cells**: the rooms found on the 3D map's slice, one colour per room; the graph floats above the
  map (rooms and doors, each edge's length at its middle)
- **height-coloured points**: the 6-DOF HS-SLAM 3D map below 2.4 m (`world/map/ceiling`, above it, is hidden at
  first; the eye icon in the blueprint panel shows it)
- **red points** at the 2D LiDAR's height: the 2D HS-SLAM map; `world/map/floor`, its grid, is hidden at first
- **red / black points** in a door: the door's points in the 3D / 2D map (`world/doors/D<k>`)
- **blue line**: the 6-DOF trajectory (estimate); **yellow line**: the 2D trajectory; **orange box**: the robot
- a recording with a 3D LiDAR only has no 2D map, path or door points
"""


def record_map(path: Path, run2, run3, grids, fusion, seg, graph, doors, pts2, pts3, h2) -> None:
    """The chain's recording; ``run2`` and ``fusion`` are None for a 3D-only recording (no 2D map or path)."""
    g = grids["slice"]
    blueprint = hv.default_blueprint(
        legend=True, eye=hv.eye_for_bounds(*hv.grid_bounds(g.geometry, (0.0, 3.0))),
        hidden=("world/map/ceiling", "world/map/floor"),
        names={"3D world": "3D map, rooms, doors and graph (Figures 15/16)", "2D map": "slice: rooms and doors",
               "Room graph": "room/door graph (Figure 16)"})
    with hv.open_recording(path, application_id="hsmap_map", blueprint=blueprint) as rec:
        hv.log_legend(rec, MAP_LEGEND)
        hv.log_occupancy_grid(rec, g.data, g.geometry)
        if fusion is not None:  # a recording with a 2D LiDAR: its floor-level map registered to the slice
            f = fusion["floor"]
            hv.log_occupancy_grid(rec, f.data, f.geometry, entity="world/map/floor", map_entity=None, z=h2,
                                  opacity=0.6)
        hv.log_room_labels(rec, seg.labels, g.geometry)
        if graph.number_of_nodes():
            hv.log_room_graph(rec, map_figures.graph_for_plot(graph), geometry=g.geometry, z=2.9)
        m3 = np.asarray(run3.map_points, dtype=float)
        low = m3[:, 2] <= 2.4 if len(m3) else np.zeros(0, bool)
        hv.log_points(rec, "world/map/points3d", m3[low], color_by_height=True, z_range=(0.0, 2.8),
                      voxel=0.1, static=True, radius=0.015)
        hv.log_points(rec, "world/map/ceiling", m3[~low], color_by_height=True, z_range=(0.0, 2.8),
                      voxel=0.1, static=True, radius=0.015)
        hv.log_path(rec, "estimate", run3.trajectory.poses)
        if run2 is not None:
            m2 = run2.map_points
            hv.log_points(rec, "world/map/points2d", np.column_stack([m2, np.full(len(m2), h2)]),
                          colors=(214, 39, 40), radius=0.02, static=True)
            hv.log_path(rec, "2d", run2.trajectory.poses, z=h2)
        hv.log_map2d_path(rec, "estimate", run3.trajectory, g.geometry)
        hv.log_trajectory(rec, run3.trajectory, name="estimate")
        for k, (p2, p3) in enumerate(zip(pts2, pts3, strict=True), start=1):
            if len(p3):
                hv.log_points(rec, f"world/doors/D{k}/points3d", p3, colors=(214, 39, 40), radius=0.04, static=True)
            if len(p2):
                hv.log_points(rec, f"world/doors/D{k}/points2d", np.column_stack([p2, np.full(len(p2), h2)]),
                              colors=(20, 20, 20), radius=0.05, static=True)
