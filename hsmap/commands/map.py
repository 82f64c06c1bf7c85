"""The paper's whole chain on one recording with a floor-level 2D LiDAR and a 3D LiDAR.

2D HS-SLAM on the scans; 6-DOF HS-SLAM on the clouds seeded by the 2D poses (interpolated at each cloud's
stamp); the floor-level occupancy grid and the grid of the 3D map's 1.7-1.8 m slice (--slice), each as a
map_server PGM+YAML that Nav2's map_server loads, and PNG; their registration and overlay; doors, rooms and the
room/door graph of the slice and of the floor grid (the paper's Figure 18 comparison); the doors' points in
both point maps; map2d.ply and map3d.ply; summary.html with the figures and numbers; metrics.json (what was read,
the offsets and their sources, warnings, every stage's numbers); map.rrd, one rerun recording of it all.

A recording with a 3D LiDAR only (no 2D scans) goes through the chain's 3D stages: 6-DOF HS-SLAM on the clouds
alone (or the poses of --poses TUM), a voxel occupancy map with free space carved along every ray (map3d.bt, an
OctoMap), the floor found under the sensor's path (several floor levels), the floor-level band and the slice in
heights above that floor, rooms, doors and graphs of both; the 2D-only outputs (trajectory2d.tum, map2d.ply,
overlay.png) are skipped, and the output says so.

A line says when each stage starts and, while it runs, a line at least every 30 s says how far it is, on any
output (not with --quiet); on a terminal each stage shows a progress bar too. Every stage is kept in
--out/.stages/: run again with the same inputs and the stages are read back ("unchanged"); change a flag and only
the stages after it run again. --out is checked before
the long work starts (a folder, or creatable, and writable). The outputs are written into a hidden staging
folder inside --out and moved into place together when all of them are complete (metrics.json last), so a
failed or interrupted run leaves the previous run's outputs as they were, and the stages it finished for the next.
"""

from __future__ import annotations

import argparse
import math

NAME = "map"
HELP = "the paper's whole chain on one recording: both SLAM maps, Nav2 grids, overlay, rooms, doors, graph"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from .inputs import INPUT_HELP, add_input_arguments

    parser.add_argument("input", help=INPUT_HELP + "; it needs 3D clouds, and 2D scans for the 2D stages")
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--seed", type=int, default=0, help="seed of every random choice (default 0)")
    parser.add_argument("--config", help="YAML file with the sections slam2d, slam3d, grids, segmentation "
                                         "(hsmap config show lists every key)")
    parser.add_argument("--slice", metavar="ZMIN,ZMAX",
                        help="heights (m above the base frame) of the 3D map's slice (default: grids.slice, "
                             "1.7,1.8, the paper's)")
    parser.add_argument("--resolution", type=float,
                        help="metres per grid cell (default: grids.resolution, 0.05)")
    parser.add_argument("--method", choices=("critical", "paper"), default=None,
                        help="door detection: critical points + narrowing test (default) or the paper's band")
    parser.add_argument("--no-odometry", action="store_true", help="ignore the input's odometry")
    parser.add_argument("--no-loop-closure", action="store_true", help="HS-SLAM without pose graph and loop closure")
    parser.add_argument("--no-deskew", action="store_true",
                        help="use the 3D clouds and 2D scans as they are (for drivers that deskew them): no motion "
                             "compensation by their per-point and per-beam times")
    parser.add_argument("--poses", metavar="TUM",
                        help="3D-only recordings: the sensor's poses from this TUM trajectory (interpolated at each "
                             "cloud's stamp) instead of the 6-DOF HS-SLAM run")
    add_input_arguments(parser)
    parser.add_argument("--no-recording", action="store_true", help="do not write map.rrd")
    parser.add_argument("--quiet", action="store_true", help="no progress bars or summary")


MAP_OUTPUTS = ("summary.html", "metrics.json", "slice.yaml", "slice.pgm", "floor.yaml", "floor.pgm", "rooms.png",
               "doors.json", "topology.json", "map2d.ply", "map3d.ply", "map.rrd")


def run(args: argparse.Namespace) -> int:
    import contextlib

    from ..progress import reporting

    # a line when each stage starts and a heartbeat while it runs, on any output (a terminal, a log, CI)
    with reporting(_log_line) if not args.quiet else contextlib.nullcontext():
        return _run(args)


def _log_line(line: str) -> None:
    """A progress line on stderr, at once, above any progress bar."""
    import sys

    from tqdm.auto import tqdm

    tqdm.write(line, file=sys.stderr)
    sys.stderr.flush()


def _run(args: argparse.Namespace) -> int:
    from ..datasets.carmen import CarmenDataset
    from ..errors import DatasetError, InputError
    from ..io import prepare_output_dir, refuse_overwriting_input
    from ..pipeline import map_recording
    from ..progress import stage
    from .inputs import open_input

    if args.seed < 0:
        raise InputError(f"--seed must be >= 0, got {args.seed}")
    config = _chain_config(args)
    # before the long work: a file, a folder that cannot be created or written is reported now
    refuse_overwriting_input(args.out, [args.input, args.scans, args.poses], MAP_OUTPUTS)
    out = prepare_output_dir(args.out, "--out", create=False)
    progress = False if args.quiet else None
    stage("read", announce=False)  # a heartbeat names it when reading takes long; bad input stays one line
    dataset = open_input(args, progress=progress)
    if isinstance(dataset, CarmenDataset):
        raise DatasetError(f"{args.input}: a CARMEN log has 2D scans only; hsmap map needs 3D clouds")
    if not _has_scans(dataset):
        return _run_3d(args, dataset, out, config, progress)
    if args.poses is not None:
        raise InputError(f"--poses applies to recordings with a 3D LiDAR only; {args.input} has 2D scans")
    for sensor in ("scan", "cloud"):
        try:
            dataset.driven_by(sensor)
        except DatasetError as exc:
            raise DatasetError(f"hsmap map needs 2D scans and 3D clouds: {exc}") from None
    m = map_recording(dataset, out, config, seed=args.seed, recording=not args.no_recording, progress=progress,
                      configuration=_configuration(args))
    if not args.quiet:
        _report_2d(m, out, args.no_recording)
    return 0


def _chain_config(args: argparse.Namespace):
    """The chain's configuration: the ``--config`` file (or the defaults) with the flags over it."""
    import dataclasses

    from ..errors import InputError
    from ..pipeline import load_chain_config
    from .inputs import parse_vector, slam_overrides

    cfg = load_chain_config(args.config)
    grids = cfg.grids
    if args.slice is not None:
        z = parse_vector(args.slice, 2, "--slice")
        if not z[0] < z[1]:
            raise InputError(f"--slice must be ZMIN,ZMAX with ZMIN < ZMAX (metres), got {args.slice!r}")
        grids = dataclasses.replace(grids, slice=(float(z[0]), float(z[1])))
    if args.resolution is not None:
        if not (math.isfinite(args.resolution) and args.resolution > 0):
            raise InputError(f"--resolution must be > 0 metres per cell, got {args.resolution}")
        grids = dataclasses.replace(grids, resolution=float(args.resolution))
    seg = cfg.segmentation if args.method is None else dataclasses.replace(cfg.segmentation, method=args.method)
    return dataclasses.replace(cfg, slam2d=slam_overrides(cfg.slam2d, args, deskew=True),
                               slam3d=slam_overrides(cfg.slam3d, args, deskew=True), grids=grids, segmentation=seg)


def _has_scans(dataset) -> bool:
    """Whether the recording has 2D scans (a 3D-only recording has clouds alone)."""
    from ..errors import DatasetError

    try:
        view = dataset.driven_by("scan")
    except DatasetError:
        return False
    first = next(iter(view.frames(clouds=False)), None)
    return first is not None and first.scan2d is not None


def _run_3d(args: argparse.Namespace, dataset, out, cfg, progress) -> int:
    import sys

    from ..pipeline.chain3d import given_poses, map_recording_3d
    from ..trajectory import read_tum

    poses = None
    if args.poses is not None:
        ds3 = dataset.driven_by("cloud")
        poses = given_poses(ds3, read_tum(args.poses), f"--poses {args.poses}", cfg.slam3d.sync_tolerance)
    m = map_recording_3d(dataset, out, config=cfg, seed=args.seed, poses=poses, recording=not args.no_recording,
                         progress=progress)
    if not args.quiet:
        s3, v = m["slam3d"], m["voxels"]
        lines = [
            "3D LiDAR only: " + (f"poses from {s3['poses_from']}" if "poses_from" in s3 else
                                 f"6-DOF HS-SLAM on {s3['frames']} clouds, no 2D prior, {s3['loops_closed']} loops "
                                 "closed"),
            f"3D map: {v['voxels']['occupied']} occupied, {v['voxels']['free']} free voxels of {v['resolution']:g} m; "
            f"floor under the path at z {v['floor_z']['min']:.2f} to {v['floor_z']['max']:.2f} m",
            f"slice: {m['slice']['rooms']} rooms, {m['slice']['doors']} doors ({m['slice']['graph']}); floor-level "
            f"band: {m['floor']['rooms']} rooms, {m['floor']['doors']} doors",
            "skipped (no 2D LiDAR): " + ", ".join(m["skipped"]),
            *(f"warning: {w}" for w in m["warnings"]),
            "stages: " + ", ".join(f"{k} " + ("unchanged" if v["unchanged"] else f"{v['seconds']:.1f} s")
                                   for k, v in m["stages"].items()),
            f"wrote {out}/summary.html, metrics.json, map3d.bt, slice.yaml/.pgm, floor.yaml/.pgm, rooms.png, "
            f"doors.json, topology.json, map3d.ply{'' if args.no_recording else ', map.rrd'}",
        ]
        sys.stderr.write("\n".join(lines) + "\n")
    return 0


def _report_2d(m: dict, out, no_recording: bool) -> None:
    import sys

    s2, s3, fus = m["slam2d"], m["slam3d"], m["fusion"]
    lines = [
        f"2D HS-SLAM: {s2['frames']} scans, {s2['loops_closed']} loops closed; 6-DOF HS-SLAM: {s3['frames']} "
        f"clouds, 2D prior for {(s3.get('prior') or {}).get('frames_with_prior')} of them",
        f"2D map -> slice: ({fus['x']:+.3f} m, {fus['y']:+.3f} m, {fus['yaw_deg']:+.2f} deg), overlap "
        f"{fus['overlap']:.3f}",
        f"slice: {m['slice']['rooms']} rooms, {m['slice']['doors']} doors ({m['slice']['graph']}); floor-level "
        f"map: {m['floor']['rooms']} rooms, {m['floor']['doors']} doors",
        *(f"warning: {w}" for w in m["warnings"]),
        "stages: " + ", ".join(f"{k} " + ("unchanged" if v["unchanged"] else f"{v['seconds']:.1f} s")
                               for k, v in m["stages"].items()),
        f"wrote {out}/summary.html, metrics.json, slice.yaml/.pgm, floor.yaml/.pgm, rooms.png, doors.json, "
        f"topology.json, map2d.ply, map3d.ply{'' if no_recording else ', map.rrd'}",
    ]
    sys.stderr.write("\n".join(lines) + "\n")


def _configuration(args: argparse.Namespace) -> str | None:
    """Where the run's settings came from, for the summary: the ``--config`` file and the flags over it."""
    flags = [f"{flag} {value}" for flag, value in (("--slice", args.slice), ("--resolution", args.resolution),
                                                    ("--method", args.method)) if value is not None]
    said = ([f"--config {args.config}"] if args.config else []) + flags
    return ", ".join(said) or None
