"""A simulated run through a real 3D map: the robot, both LiDARs and drifting odometry in a voxel world.

:func:`simulate_world` is :func:`hsmap.sim.simulate_building` for a 3D occupancy map (an OctoMap ``.bt``/``.ot``
or a point map, read by :func:`hsmap.maps.maps3d.read_map3d`): the world is the map's voxels
(:class:`hsmap.sim.voxelworld.VoxelWorld`, the floor's surface at z = 0), the route goes through the known free
space into every room of the map's slice the robot's footprint (its radius) fits in
(:func:`hsmap.sim.route3d.plan_route3d`), and the robot, its odometry, both LiDARs and the writer are the
floor-plan buildings' (:class:`BuildingRunConfig`'s robot, odometry and 2D LiDAR; the paper's 128 x 1024 mast
LiDAR). The folder is the simulator's
(:class:`hsmap.datasets.simulated.SimulatedDataset` reads it): ``scans2d.npz``, ``clouds3d/``,
``groundtruth.tum``, ``odometry.tum``, ``rooms.png``/``rooms.yaml`` (the rooms of the map's own slice, the
route's goals: no hand-drawn ground truth), ``doors.json`` (empty), ``world.json`` (the voxel world and the
route) and ``dataset.yaml`` last.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import EmptyInputError, ScenarioError
from ..io import write_json
from ..maps.maps3d import read_map3d
from .building import BuildingRunConfig, building_motion, write_dataset_yaml, write_route_files
from .robot import Motion, OdometryConfig, RobotConfig
from .route3d import Route3D, Route3DConfig, plan_route3d
from .sensors import Lidar2DConfig, Lidar3DConfig
from .voxelworld import FREE, VoxelWorld
from .writer import staged_dataset_folder, write_sensor_frames

__all__ = ["WorldRunConfig", "WorldRun", "simulate_world", "load_voxel_world"]


@dataclass
class WorldRunConfig:
    """The robot, its sensors and the route rules of a run through a 3D map (one configuration for every map):
    the floor-plan buildings' robot, odometry, 2D LiDAR and frame rate, and the paper's 128 x 1024 mast LiDAR."""

    frame_rate: float = 1.0
    route: Route3DConfig = field(default_factory=Route3DConfig)
    robot: RobotConfig = field(default_factory=RobotConfig)
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    lidar2d: Lidar2DConfig = field(default_factory=Lidar2DConfig)
    lidar3d: Lidar3DConfig = field(default_factory=Lidar3DConfig)


@dataclass
class WorldRun:
    """What :func:`simulate_world` made."""

    path: Path
    world: VoxelWorld
    route: Route3D
    motion: Motion
    timings: dict

    @property
    def frames(self) -> int:
        return len(self.motion)

    def as_dict(self) -> dict:
        r = self.route
        return {"path": str(self.path), "frames": self.frames, "route_m": round(self.motion.path_length(), 3),
                "duration_s": round(float(self.motion.stamps[-1] - self.motion.stamps[0]), 3),
                "rooms": int(r.rooms.max(initial=0)), "rooms_visited": [int(k) for k in r.route.order],
                "rooms_entered": r.rooms_entered(), "unreachable_rooms": len(r.route.unreachable),
                "footprint_m": r.footprint,
                "route": r.route.as_dict(), "world": self.world.describe(),
                "timings_s": {k: round(v, 3) for k, v in self.timings.items()}}


def load_voxel_world(path: str | os.PathLike, floor: float | None = None) -> VoxelWorld:
    """Read a 3D map (:func:`hsmap.maps.maps3d.read_map3d`) as a voxel world, its floor's surface at z = 0."""

    return VoxelWorld.from_map(read_map3d(path), floor)


def simulate_world(world: VoxelWorld | str | os.PathLike, out: str | os.PathLike, *, seed: int = 0,
                   config: WorldRunConfig | None = None, max_frames: int | None = None) -> WorldRun:
    """Simulate the exploring run through a 3D map and write its dataset folder.

    Parameters
    ----------
    world : VoxelWorld or path
        The world, or a 3D map file (:func:`load_voxel_world`).
    out : path
        The dataset folder (created). The dataset is written into a staging folder inside it and replaces a
        previous dataset there when complete; a failed or interrupted run leaves that as it was.
    seed : int
        Seeds the odometry's slip and the range noise.
    config : WorldRunConfig, optional
    max_frames : int, optional
        Stop after this many frames (quick runs).

    Returns
    -------
    WorldRun
    """

    cfg = config or WorldRunConfig()
    seed = int(seed)
    if seed < 0:
        raise ScenarioError(f"seed must be >= 0, got {seed}")
    if max_frames is not None and max_frames < 1:
        raise ScenarioError(f"max_frames must be >= 1, got {max_frames}")
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    if not isinstance(world, VoxelWorld):
        world = load_voxel_world(world)
    timings["world"] = time.perf_counter() - t0
    if not (world.state == FREE).any():
        what = ("a point map records occupied voxels only" if str(world.source).lower().endswith((".ply", ".pcd"))
                else "the map holds no free voxel")
        raise EmptyInputError(f"{world.source}: {what}, so there is no known free space to drive through; simulate "
                              "in an OctoMap .bt/.ot that records free space")
    final = Path(out)

    t = time.perf_counter()
    route = plan_route3d(world, cfg.route, lidar3d=cfg.lidar3d, footprint=cfg.robot.radius)
    timings["route"] = time.perf_counter() - t
    if not route.route.path_length > 0:
        x, y = route.route.start[:2]
        n = int(route.rooms.max(initial=0))
        raise EmptyInputError(
            f"{world.source}: the route has nowhere to drive: the map's {cfg.route.rooms_band[0]:g}-"
            f"{cfg.route.rooms_band[1]:g} m band shows {n} room{'s' if n != 1 else ''} the robot fits in, and every "
            f"place it fits is within {cfg.route.cover_spacing:g} m (route.cover_spacing) of its start "
            f"({x:.2f}, {y:.2f}); a run needs a map with somewhere to go")
    t = time.perf_counter()
    bcfg = BuildingRunConfig(frame_rate=cfg.frame_rate, robot=cfg.robot, odometry=cfg.odometry)
    motion = building_motion(route.route, bcfg, seed, max_frames)
    timings["motion"] = time.perf_counter() - t

    with staged_dataset_folder(final) as out:
        write_sensor_frames(out, world, motion, cfg.lidar2d, cfg.lidar3d, seed, timings)
        write_route_files(out, motion, route.rooms, route.geometry, int(route.rooms.max(initial=0)),
                          f"the rooms hsmap.rooms.segmentation finds in the source map's {cfg.route.rooms_band[0]:g}-"
                          f"{cfg.route.rooms_band[1]:g} m band (the route's goals), not a hand-drawn ground truth")
        run = WorldRun(final, world, route, motion, timings)
        timings["total"] = time.perf_counter() - t0
        write_json(out / "world.json", {k: v for k, v in run.as_dict().items() if k != "path"})
        write_dataset_yaml(out, Path(world.source).stem,
                           f"voxel world of the 3D map {world.source} (floor surface at z = 0, "
                           f"{world.floor:+.3f} m in the map's frame; the map's x, y)", seed, motion, cfg,
                           {"rooms.png": "the rooms of the source map's slice (16-bit labels; not a hand-drawn "
                                         "ground truth)",
                            "doors.json": "no doors (the map draws none)",
                            "world.json": "the voxel world, the route (goals, rooms entered, unreachable rooms), "
                                          "timings"})
    return run
