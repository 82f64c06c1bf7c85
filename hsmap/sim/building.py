"""A simulated run through a floor-plan building: world, exploring route, both LiDARs, drifting odometry.

:func:`simulate_building` is :func:`hsmap.sim.simulate` for a floor plan instead of a scenario file: it builds the
world (:func:`hsmap.sim.floorplan.build_world`), plans the route through every reachable ground-truth room
(:func:`hsmap.sim.explore.plan_exploration`), drives it with the simulator's differential drive and drifting
wheel odometry (:func:`hsmap.sim.robot.simulate_motion`) and writes the same dataset folder
(:class:`hsmap.datasets.simulated.SimulatedDataset` reads it): ``scans2d.npz``, ``clouds3d/``,
``groundtruth.tum``, ``odometry.tum``, ``rooms.png``/``rooms.yaml`` (the ground-truth rooms in the floor plan's
own pixel grid), ``doors.json`` (empty: a floor plan draws no doors), ``building.yaml`` (the world and the
route: furniture, unreachable rooms) and ``dataset.yaml`` last.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from .. import __version__
from ..config import to_dict
from ..datasets.simulated import FORMAT, FORMAT_VERSION
from ..errors import ScenarioError
from ..io import write_json, write_text
from ..maps.grid import write_label_image
from ..trajectory import Trajectory, write_tum
from .explore import Exploration, ExploreConfig, plan_exploration
from .floorplan import FloorPlan, FloorPlanWorld, FloorPlanWorldConfig, build_world
from .robot import Motion, OdometryConfig, RobotConfig, simulate_motion
from .sensors import Lidar2DConfig, Lidar3DConfig
from .writer import staged_dataset_folder, write_sensor_frames

__all__ = ["BuildingRunConfig", "BuildingRun", "simulate_building", "building_motion", "write_route_files",
           "write_dataset_yaml"]


@dataclass
class BuildingRunConfig:
    """The robot, its sensors and the world rules of a floor-plan run (one configuration for every building).

    The 3D LiDAR is the paper's on its 1.6 m mast, with 64 x 1024 beams over the same 45 deg instead of 128 x
    1024: half the rays and points per cloud keep the fifteen-building benchmark within its time budget, and the
    1.7-1.8 m slice still gets about one beam ring per 0.7 deg of elevation.
    """

    frame_rate: float = 1.0
    world: FloorPlanWorldConfig = field(default_factory=FloorPlanWorldConfig)
    explore: ExploreConfig = field(default_factory=ExploreConfig)
    robot: RobotConfig = field(default_factory=RobotConfig)
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    lidar2d: Lidar2DConfig = field(default_factory=Lidar2DConfig)
    lidar3d: Lidar3DConfig = field(default_factory=lambda: Lidar3DConfig(channels=32, columns=1024))


@dataclass
class BuildingRun:
    """What :func:`simulate_building` made."""

    path: Path
    world: FloorPlanWorld
    route: Exploration
    motion: Motion
    timings: dict

    @property
    def frames(self) -> int:
        return len(self.motion)

    def as_dict(self) -> dict:
        return {"path": str(self.path), "frames": self.frames, "route_m": round(self.motion.path_length(), 3),
                "duration_s": round(float(self.motion.stamps[-1] - self.motion.stamps[0]), 3),
                "route": self.route.as_dict(), "world": self.world.describe(),
                "timings_s": {k: round(v, 3) for k, v in self.timings.items()}}


def building_motion(route: Exploration, config: BuildingRunConfig, seed: int,
                    max_frames: int | None = None) -> Motion:
    """Drive a planned route: ground truth and drifting odometry at the configured frame rate."""
    if not route.steps():
        raise ScenarioError("the route has no leg: the building has a single reachable room and nothing to drive")
    m = simulate_motion(route.start, route.steps(), config.robot, config.odometry, config.frame_rate,
                        np.random.default_rng([int(seed), 1]))
    if max_frames is not None and max_frames < len(m):
        m.stamps, m.groundtruth, m.odometry = m.stamps[:max_frames], m.groundtruth[:max_frames], m.odometry[:max_frames]
        keep = m.sample_times <= m.stamps[-1] + 1e-9
        m.sample_times, m.sample_groundtruth, m.sample_odometry = (
            m.sample_times[keep], m.sample_groundtruth[keep], m.sample_odometry[keep])
    return m


def simulate_building(plan: FloorPlan, out: str | os.PathLike, *, seed: int = 0,
                      config: BuildingRunConfig | None = None, max_frames: int | None = None) -> BuildingRun:
    """Simulate the exploring run through a floor plan and write its dataset folder.

    Parameters
    ----------
    plan : FloorPlan
        From :func:`hsmap.sim.floorplan.read_floor_plan`.
    out : path
        The dataset folder (created). The dataset is written into a staging folder inside it and replaces a
        previous dataset there when complete; a failed or interrupted run leaves that as it was.
    seed : int
        Seeds the furniture, the odometry's slip and the range noise.
    config : BuildingRunConfig, optional
    max_frames : int, optional
        Stop after this many frames (quick runs).

    Returns
    -------
    BuildingRun
    """

    cfg = config or BuildingRunConfig()
    seed = int(seed)
    if seed < 0:
        raise ScenarioError(f"seed must be >= 0, got {seed}")
    final = Path(out)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()

    t = time.perf_counter()
    fw = build_world(plan, cfg.world, seed)
    world = fw.world()
    timings["world"] = time.perf_counter() - t
    t = time.perf_counter()
    route = plan_exploration(plan, cfg.explore)
    timings["route"] = time.perf_counter() - t
    t = time.perf_counter()
    motion = building_motion(route, cfg, seed, max_frames)
    timings["motion"] = time.perf_counter() - t

    with staged_dataset_folder(final) as out:
        write_sensor_frames(out, world, motion, cfg.lidar2d, cfg.lidar3d, seed, timings)
        write_route_files(out, motion, plan.rooms, plan.geometry, plan.n_rooms,
                          "the ground truth's rooms, in its own pixel grid")
        run = BuildingRun(final, fw, route, motion, timings)
        write_json(out / "building.json", {"world": fw.describe(), "route": route.as_dict(),
                                           "furniture": [p.as_dict() for p in fw.furniture]})
        timings["total"] = time.perf_counter() - t0
        write_dataset_yaml(out, plan.name, f"floor-plan world of {plan.name} ({plan.files.get('plain', '')})",
                           seed, motion, cfg, {"rooms.png": "ground-truth room labels (16-bit)",
                                               "doors.json": "no doors (a floor plan draws none)",
                                               "building.json": "the world (boxes, furniture) and the route "
                                                                "(goals, unreachable rooms)"})
    return run


def write_route_files(out: Path, motion: Motion, rooms: np.ndarray, geometry, n_rooms: int, rooms_note: str) -> None:
    """A route run's ``groundtruth.tum``, ``odometry.tum``, ``rooms.png`` (labels 1..``n_rooms`` on
    ``geometry``'s pixels), ``rooms.yaml`` (its map_server geometry; ``rooms_note`` says what the rooms are)
    and an empty ``doors.json``."""
    write_tum(out / "groundtruth.tum", Trajectory(motion.stamps, motion.groundtruth))
    write_tum(out / "odometry.tum", Trajectory(motion.stamps, motion.odometry))
    g = geometry
    write_label_image(out / "rooms.png", rooms)
    write_text(out / "rooms.yaml", yaml.safe_dump({
        "image": "rooms.png", "resolution": g.resolution, "origin": [g.origin[0], g.origin[1], 0.0],
        "labels": {int(k): f"room {k}" for k in range(1, n_rooms + 1)},
        "convention": "map_server: origin is the world (x, y, yaw) of the lower-left pixel's lower-left corner; "
                      f"row 0 of the image is the top; 0 = no room; {rooms_note}",
    }, sort_keys=False))
    write_json(out / "doors.json", {"format_version": FORMAT_VERSION, "frame": "world", "doors": []})


def write_dataset_yaml(out: Path, scenario: str, description: str, seed: int, motion: Motion, cfg,
                       files: dict[str, str]) -> None:
    """A route run's ``dataset.yaml`` (written last: it completes the folder). ``cfg`` has the run's
    ``frame_rate``, ``lidar2d``, ``lidar3d``, ``robot`` and ``odometry``; ``files`` describes the files beyond the
    sensors' and trajectories' (and may replace their descriptions)."""
    meta = {
        "format": FORMAT, "format_version": FORMAT_VERSION, "hsmap_version": __version__,
        "scenario": scenario, "description": description,
        "seed": seed, "frames": len(motion), "frame_rate": float(cfg.frame_rate),
        "start_time": float(motion.stamps[0]),
        "duration": round(float(motion.stamps[-1] - motion.stamps[0]), 6),
        "path_length": round(motion.path_length(), 6),
        "sensors": {"lidar2d": cfg.lidar2d.describe(), "lidar3d": cfg.lidar3d.describe()},
        "robot": to_dict(cfg.robot), "odometry_model": to_dict(cfg.odometry),
        "files": {"dataset.yaml": "this description; written last", "scans2d.npz": "2D LiDAR scans",
                  "clouds3d/": "3D LiDAR range images", "groundtruth.tum": "true base poses",
                  "odometry.tum": "wheel odometry", "rooms.png": "", "rooms.yaml": "its geometry", **files},
    }
    write_text(out / "dataset.yaml", yaml.safe_dump(meta, sort_keys=False, width=110))
