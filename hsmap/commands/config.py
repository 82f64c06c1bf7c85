"""Every setting of hsmap with its default and meaning, by section: slam (hsmap slam --config FILE), map (hsmap
map --config FILE: the sections slam2d and slam3d take slam's keys, segmentation segmentation's; ``config show map``
shows all four with the chain's defaults, ``config show slam2d`` one), segmentation
(hsmap segment --config FILE), and the simulator's scenario files (scenario.robot, scenario.odometry,
scenario.sensors.lidar2d, scenario.sensors.lidar3d). --markdown prints the reference as docs/CONFIG.md holds it."""

from __future__ import annotations

import argparse

NAME = "config"
HELP = "every setting with its default and meaning (hsmap config show [SECTION])"


def sections() -> dict[str, object]:
    """The configuration sections: name -> the default configuration (a dataclass instance)."""
    from ..pipeline.config import GridsConfig
    from ..rooms.segmentation import SegmentationConfig
    from ..sim.robot import OdometryConfig, RobotConfig
    from ..sim.sensors import Lidar2DConfig, Lidar3DConfig
    from ..slam import SlamConfig

    return {"slam": SlamConfig(), "map.grids": GridsConfig(), "segmentation": SegmentationConfig(),
            "scenario.robot": RobotConfig(), "scenario.odometry": OdometryConfig(),
            "scenario.sensors.lidar2d": Lidar2DConfig(), "scenario.sensors.lidar3d": Lidar3DConfig()}


def map_sections() -> dict[str, object]:
    """The sections of ``hsmap map --config FILE`` (its keys slam2d, slam3d, grids, segmentation): name -> the
    chain's default for it (:class:`hsmap.pipeline.config.ChainConfig`)."""
    from ..pipeline.config import ChainConfig

    c = ChainConfig()
    return {"map.slam2d": c.slam2d, "map.slam3d": c.slam3d, "map.grids": c.grids, "map.segmentation": c.segmentation}


#: Section names ``config show`` takes beside those of :func:`sections`: a ``map --config`` key alone.
MAP_KEYS = {"slam2d": "map.slam2d", "slam3d": "map.slam3d", "grids": "map.grids"}

#: What each section configures, and where its keys go.
SECTION_HELP = {
    "map.slam2d": "the chain's 3-DOF HS-SLAM run (hsmap map --config FILE: under slam2d; slam's keys, dof 3)",
    "map.slam3d": "the chain's 6-DOF HS-SLAM run (hsmap map --config FILE: under slam3d; slam's keys, dof 6)",
    "map.segmentation": "the chain's doors and rooms (hsmap map --config FILE: under segmentation)",
    "slam": "HS-SLAM (hsmap slam --config FILE; hsmap map --config FILE: under slam2d and slam3d, slam3d with dof 6)",
    "map.grids": "the chain's grids (hsmap map --config FILE: under grids; segmentation's keys under segmentation)",
    "segmentation": "doors and rooms (hsmap segment --config FILE; hsmap map --config FILE: under segmentation)",
    "scenario.robot": "the simulated robot (a scenario YAML: under robot)",
    "scenario.odometry": "the simulated wheel odometry (a scenario YAML: under odometry)",
    "scenario.sensors.lidar2d": "the simulated 2D LiDAR (a scenario YAML: under sensors.lidar2d)",
    "scenario.sensors.lidar3d": "the simulated 3D LiDAR (a scenario YAML: under sensors.lidar3d)",
}


def reference(section: str | None = None) -> dict[str, list[tuple[str, str, str]]]:
    """Section -> rows (key, default, meaning); ``section`` picks one (or those under it: ``scenario``)."""
    from ..config import config_reference
    from ..errors import InputError

    all_ = sections()
    if section is None:
        return {name: config_reference(cfg) for name, cfg in all_.items()}
    shown = {"slam": all_["slam"], **map_sections(),
             **{k: v for k, v in all_.items() if k not in ("slam", "map.grids")}}
    key = MAP_KEYS.get(section, section)
    names = [s for s in shown if s == key or s.startswith(key + ".")]
    if not names:
        listed = ", ".join(["slam", "map", *[n for n in shown if n.startswith("map.")], "segmentation", "scenario",
                            *[n for n in shown if n.startswith("scenario.")]])
        raise InputError(f"config show: no section {section!r}; the sections are {listed} (and slam2d, slam3d, "
                         "grids: map's)")
    return {name: config_reference(shown[name]) for name in names}


def markdown() -> str:
    """The whole reference as Markdown (docs/CONFIG.md)."""
    out = ["# Configuration reference", "",
           "Every setting, its default and its meaning, generated from the configuration dataclasses by "
           "`hsmap config show --markdown` (a test checks that this file matches it).", ""]
    for name, rows in reference().items():
        out += [f"## {name}", "", SECTION_HELP[name] + ".", "", "| key | default | meaning |", "|---|---|---|"]
        out += [f"| `{k}` | `{d}` | {m.replace('|', '/')} |" for k, d, m in rows]
        out.append("")
    return "\n".join(out)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    p = sub.add_parser("show", help="every key of a section (default: all) with its default and meaning")
    p.add_argument("section", nargs="?", help="slam, map (map.slam2d, map.slam3d, map.grids, map.segmentation; "
                                              "or slam2d, slam3d, grids), segmentation, scenario, scenario.robot, "
                                              "... (default: all)")
    p.add_argument("--markdown", action="store_true", help="the reference as Markdown (docs/CONFIG.md)")


def run(args: argparse.Namespace) -> int:
    import shutil
    import textwrap

    if args.markdown:
        if args.section is not None:
            from ..errors import InputError

            raise InputError("config show: --markdown prints the whole reference; leave out SECTION")
        print(markdown())
        return 0
    width = max(shutil.get_terminal_size((100, 24)).columns, 60)
    for name, rows in reference(args.section).items():
        print(f"[{name}] {SECTION_HELP[name]}")
        for k, d, m in rows:
            print(f"  {k}: {d}")
            for t in textwrap.wrap(m, width - 6):
                print("      " + t)
        print()
    return 0
