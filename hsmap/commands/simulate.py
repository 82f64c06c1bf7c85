"""Simulate a scenario: drive its route, cast the floor-level 2D LiDAR and the mast-mounted 3D LiDAR, integrate
drifting wheel odometry, and write a documented dataset folder (2D scans, 3D range images, groundtruth.tum,
odometry.tum, sensor description, ground-truth room labels and doors; see the folder's README.md).

SCENARIO is a shipped scenario name (default slam-office; --list shows them) or a path to a scenario YAML.
With --world MAP3D the world is a real 3D map instead (an OctoMap .bt/.ot or a PLY/PCD point map): the robot
drives a route through the map's known free space, both LiDARs are cast into its occupied voxels (a ray into
unknown space returns nothing), and the same dataset folder is written (see hsmap.sim.voxelrun).
"""

from __future__ import annotations

import argparse

NAME = "simulate"
HELP = "simulate a scenario into a dataset folder (2D scans, 3D clouds, ground truth, odometry)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scenario", nargs="?", default=None, metavar="SCENARIO",
                        help="shipped scenario name or YAML file (default: slam-office); not with --world")
    parser.add_argument("--world", metavar="MAP3D", default=None,
                        help="simulate in a real 3D map (OctoMap .bt/.ot, PLY/PCD) instead of a scenario")
    parser.add_argument("--out", metavar="DIR", default=None,
                        help="output folder (default: data/generated/SCENARIO)")
    parser.add_argument("--seed", type=int, default=None, metavar="N",
                        help="seed of odometry slip and range noise (default: the scenario's seed)")
    parser.add_argument("--max-frames", type=int, default=None, metavar="N", help="stop after N frames")
    parser.add_argument("--label-resolution", type=float, default=None, metavar="M",
                        help="metres per pixel of rooms.png (default: the scenario's, 0.05)")
    parser.add_argument("--figures", action="store_true",
                        help="also write preview pictures into DIR/figures/ (top view, a 3D cloud, odometry map)")
    parser.add_argument("--check", action="store_true", help="only parse and check the scenario, write nothing")
    parser.add_argument("--list", action="store_true", help="list the shipped scenarios and exit")


def run(args: argparse.Namespace) -> int:
    import json

    from ..errors import InputError
    from ..sim import list_scenarios, load_scenario, motion_for, resolve_scenario, scenario_dir, simulate

    if args.list:
        for name in list_scenarios():
            print(name)
        if not list_scenarios():
            print(f"(no scenarios in {scenario_dir()})")
        return 0
    if args.seed is not None and args.seed < 0:
        raise InputError(f"--seed must be >= 0, got {args.seed}")
    if args.max_frames is not None and args.max_frames < 1:
        raise InputError(f"--max-frames must be >= 1, got {args.max_frames}")
    if args.label_resolution is not None and not args.label_resolution > 0:
        raise InputError(f"--label-resolution must be > 0 metres, got {args.label_resolution}")
    if args.world is not None:
        if args.scenario is not None:
            raise InputError(f"SCENARIO {args.scenario!r} and --world {args.world} both name the world to simulate; "
                             "give one of them")
        return _run_world(args)
    scn = load_scenario(resolve_scenario("slam-office" if args.scenario is None else args.scenario))
    if args.check:
        m = motion_for(scn, args.seed, args.max_frames)
        print(json.dumps({"scenario": scn.name, "file": scn.path, "ok": True, "frames": len(m),
                          "path_length_m": round(m.path_length(), 3),
                          "odometry_end_error_m": round(float(
                              ((m.odometry[-1, :2] - m.groundtruth[-1, :2]) ** 2).sum() ** 0.5), 4)}))
        return 0
    if args.out is None:  # the repository's data/generated/SCENARIO, as the study uses it
        from ..study.paths import generated_dir

        args.out = generated_dir() / scn.name
    from ..io import prepare_output_dir

    prepare_output_dir(args.out, "--out", create=False)
    summary = simulate(scn, args.out, args.seed, max_frames=args.max_frames,
                       label_resolution=args.label_resolution)
    if args.figures:
        from ..viz.scenario_figures import preview_dataset

        preview_dataset(args.out)
    print(json.dumps(summary.as_dict(), indent=2))
    return 0


def _run_world(args: argparse.Namespace) -> int:
    import json
    from pathlib import Path

    from ..errors import InputError
    from ..io import prepare_output_dir
    from ..sim.voxelrun import simulate_world

    for flag, value in (("--check", args.check), ("--figures", args.figures),
                        ("--label-resolution", args.label_resolution is not None)):
        if value:
            raise InputError(f"{flag} is for scenarios, not for --world")
    if args.out is None:
        from ..study.paths import generated_dir

        args.out = generated_dir() / f"world-{Path(args.world).stem}"
    prepare_output_dir(args.out, "--out", create=False)
    run = simulate_world(args.world, args.out, seed=0 if args.seed is None else args.seed,
                         max_frames=args.max_frames)
    print(json.dumps(run.as_dict(), indent=2))
    return 0
