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
        self._frames = hv.FrameLogger(self.rec, block=256, cloud_voxel=0.25)
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
    index_of = {int(i): k for k, i in enumerate(run.frame_indices)}
    n_frames = len(run.trajectory)
    paths = {"estimate": run.trajectory}
    if groundtruth is not None:
        paths["groundtruth"] = groundtruth
    if odometry is not None:
        paths["odometry"] = odometry
    replay = _Replay(rec, run, map_voxel or (0.05 if dof == 3 else 0.15), int(map_block), grid,
                     {name: _aligned(t, run.trajectory) for name, t in paths.items()}, cloud_voxel, map_z_range)
    grid_every = max(1, -(-n_frames // int(grid_updates)))
    path_every = max(1, -(-n_frames // int(path_updates)))
    hv.log_legend(rec, _slam_legend(dof, list(paths), grid is not None))
    last = -1
    for f in (dataset.frames(clouds=dof == 6) if isinstance(dataset, Dataset) else iter(dataset)):
        k = index_of.get(int(f.index))
        if k is None:
            if f.index > run.frame_indices.max():
                break
            continue
        final = k == n_frames - 1
        show = k % int(every) == 0 or final
        update_grid = replay.geometry is not None and (k % grid_every == 0 or final)
        update_path = k % path_every == 0 or final
        if not (show or run.keyframes[k] or update_grid or update_path):
            continue
        replay.log(k, f, show, update_grid, update_path)
        last = k
    replay.logger.flush()
    if last >= 0 and last != n_frames - 1:
        replay.log_paths(last)
    return {"frames": replay.frames, "map_blocks": replay.logger.blocks, "map_points": replay.logger.points_logged,
            "grid_updates": replay.grids}


class _Replay:
    """What :func:`record_slam_run` logs of a run's frames into ``rec``: each shown frame, the keyframes' points
    (thinned to ``map_voxel``, in blocks of ``map_block`` keyframes), the growing grid over ``grid``'s geometry
    and the paths (``path_at``: each path's poses at the run's frames)."""

    def __init__(self, rec: Any, run: Any, map_voxel: float, map_block: int, grid: Any,
                 path_at: dict[str, np.ndarray], cloud_voxel: float, z_range: tuple[float, float] | None) -> None:
        self.rec, self.run, self.dof, self.grid, self.path_at = rec, run, run.dof, grid, path_at
        self.poses = run.trajectory.poses
        self.map_voxel, self.cloud_voxel, self.z_range = map_voxel, cloud_voxel, z_range
        self.logger = hv.PointMapLogger(rec, block=map_block, voxel=map_voxel,
                                        z_range=(-0.2, 3.0) if self.dof == 6 else None,
                                        radius=0.02 if self.dof == 3 else 0.015)
        self.geometry = None if grid is None else grid.geometry
        self.scans, self.scan_poses, self.extrinsics = [], [], []  # the keyframes' 2D scans, for the grid
        self.frames = self.grids = 0  # logged

    def log(self, k: int, f: Frame, show: bool, update_grid: bool, update_path: bool) -> None:
        """Frame ``k`` (``f``) at its time: itself where ``show``, its points where it is a keyframe, the grid
        (``update_grid``) and the paths (``update_path``)."""
        if self.dof == 6 and f.cloud3d is not None:
            f = dataclasses.replace(f, cloud3d=first_per_voxel(np.asarray(f.cloud3d, dtype=float),
                                                               min(self.cloud_voxel, self.map_voxel)))
        hv.set_frame_time(self.rec, k, f.stamp)
        if show:
            self.log_frame(k, f)
        if self.run.keyframes[k]:
            self.log_keyframe(k, f)
        if update_grid and self.scans:
            self.log_grid(k == len(self.poses) - 1)
        if update_path:
            self.log_paths(k)

    def log_frame(self, k: int, f: Frame) -> None:
        """Frame ``k`` (``f``) at its pose: the robot, its scan and cloud; over the grid, the robot and its scan."""
        pose = self.poses[k]
        shown = f if self.dof == 6 else dataclasses.replace(f, cloud3d=None)
        hv.log_frame(self.rec, shown, pose, index=k, cloud_voxel=self.cloud_voxel)
        self.frames += 1
        if self.geometry is not None:
            hv.log_map2d_robot(self.rec, pose, self.geometry)
            if f.scan2d is not None and self.dof == 3:
                sensor = pose_to_matrix(pose) @ pose_to_matrix(f.extrinsic2d)
                hv.log_map2d_points(self.rec, "scan", transform_points(sensor, f.scan2d.points()), self.geometry)

    def log_keyframe(self, k: int, f: Frame) -> None:
        """Keyframe ``k``'s points (within ``z_range`` of height) into the map; its 2D scan kept for the grid."""
        z_range = self.z_range
        cfg, pose = self.run.config, self.poses[k]
        pts = frame_points(f, self.dof, cfg.min_range, cfg.max_range)
        world = first_per_voxel(transform_points(pose_to_matrix(pose), pts), self.map_voxel)
        if z_range is not None and world.shape[1] == 3:
            world = world[(world[:, 2] >= z_range[0]) & (world[:, 2] <= z_range[1])]
        self.logger.add(world)
        if self.geometry is not None and f.scan2d is not None:
            self.scans.append(f.scan2d)
            self.scan_poses.append(pose[:3] if self.dof == 3 else pose[[0, 1, 5]])
            self.extrinsics.append(f.extrinsic2d)

    def log_grid(self, final: bool) -> None:
        """The grid of the keyframes' scans so far (at the last frame, the run's own grid)."""
        g = self.grid if final else grid_from_scans(self.scans, np.array(self.scan_poses),
                                                    extrinsic=np.array(self.extrinsics), geometry=self.geometry)
        hv.log_occupancy_grid(self.rec, g.data, self.geometry, static=False)
        self.grids += 1

    def log_paths(self, k: int) -> None:
        """Every path up to frame ``k``, in 3D and over the grid."""
        for name, p in self.path_at.items():
            upto = p[: k + 1]
            if len(upto) < 2:
                continue
            wide = 1.8 if name == "groundtruth" else 1.0  # under the estimate, which mostly lies on it
            hv.log_path(self.rec, name, upto, static=False, radius=wide * (0.04 if self.dof == 3 else 0.05))
            if self.geometry is not None:
                hv.log_map2d_path(self.rec, name, upto, self.geometry, static=False, radius=wide * 1.5)


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
            from .map_figures import graph_for_plot  # matplotlib: not for a SLAM run's recording

            hv.log_room_graph(rec, graph_for_plot(graph), geometry=g.geometry, z=2.9)
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
