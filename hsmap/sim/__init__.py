"""Indoor-world simulator: scenario files, an open3d world, a floor-level 2D LiDAR, a mast-mounted 3D LiDAR,
a differential-drive robot with drifting wheel odometry, and the dataset writer behind ``hsmap simulate``.

Typical use::

    from hsmap.sim import simulate, load_scenario
    summary = simulate("two-rooms", "out/two-rooms", seed=0)   # a shipped scenario name or a YAML path
    # then: hsmap.datasets.simulated.SimulatedDataset("out/two-rooms")

Floor plans (the Bormann et al. benchmark's images) become worlds and exploring runs too::

    from hsmap.sim import read_floor_plan, simulate_building
    run = simulate_building(read_floor_plan("maps/office_a.png"), "out/office_a", seed=0)

Heavy modules (open3d, matplotlib) are imported only where they are used.
"""

from .building import BuildingRunConfig, simulate_building
from .catalog import list_scenarios, resolve_scenario, scenario_dir
from .explore import ExploreConfig, plan_exploration
from .floorplan import FloorPlanWorldConfig, build_world, read_floor_plan
from .robot import Motion, OdometryConfig, RobotConfig, RouteStep, integrate_odometry, simulate_motion
from .scenario import FURNITURE_TYPES, Scenario, load_scenario, parse_scenario
from .sensors import Lidar2DConfig, Lidar3DConfig, range_image_to_points
from .writer import SimulationSummary, motion_for, simulate


def __getattr__(name):  # lazy: World needs open3d, the figures need matplotlib
    if name == "World":
        from .world import World

        return World
    if name in ("plot_world", "plot_cloud", "plot_odometry_map", "write_previews", "preview_dataset"):
        from . import plot

        return getattr(plot, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "BuildingRunConfig", "ExploreConfig", "FloorPlanWorldConfig", "build_world", "plan_exploration",
    "read_floor_plan", "simulate_building",
    "FURNITURE_TYPES", "Lidar2DConfig", "Lidar3DConfig", "Motion", "OdometryConfig", "RobotConfig", "RouteStep",
    "Scenario", "SimulationSummary", "World", "integrate_odometry",
    "list_scenarios", "load_scenario", "motion_for", "parse_scenario", "plot_cloud", "plot_odometry_map",
    "plot_world", "preview_dataset", "range_image_to_points", "resolve_scenario", "scenario_dir", "simulate", "simulate_motion",
    "write_previews",
]
