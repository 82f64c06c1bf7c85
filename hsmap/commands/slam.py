"""Run HS-SLAM on a simulator folder, a ROS1/ROS2 bag or a CARMEN log.

Writes into --out: trajectory.tum (stamps = the input's scan stamps), map.ply, metrics.json (per-scan time,
fitness, inlier ratio; totals; peak memory), config.yaml (the effective configuration) and slam.rrd (a rerun
recording: robot pose, scans and the growing map on a `scan` timeline). Every file is written atomically and
metrics.json last, so an interrupted run leaves no output that looks complete.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

NAME = "slam"
HELP = "HS-SLAM (Harmony-ICP scan-to-map) in 2D (3-DOF) or 3D (6-DOF)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("input", help="simulator folder (with dataset.yaml), ROS1 .bag / ROS2 bag folder, or CARMEN "
                                      "log (.log/.clf, optionally .gz)")
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--dof", type=int, choices=(3, 6), help="3: 2D scans, 6: 3D clouds (default: the config's, 3)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--config", help="YAML file of SlamConfig fields (see config.yaml of any run)")
    parser.add_argument("--no-odometry", action="store_true", help="ignore the input's odometry (no odometry seed)")
    parser.add_argument("--prior", help="6-DOF: a TUM trajectory of a 2D run whose poses seed the search")
    parser.add_argument("--max-frames", type=int, help="stop after this many frames")
    parser.add_argument("--scan-topic", help="bag topic of the 2D LaserScan (auto-detected by default)")
    parser.add_argument("--cloud-topic", help="bag topic of the 3D PointCloud2 (auto-detected by default)")
    parser.add_argument("--odom-topic", help="bag topic of the Odometry (auto-detected by default)")
    parser.add_argument("--extrinsic2d", metavar="X,Y,YAW",
                        help="pose of the 2D LiDAR in the robot base frame (metres, radians), overriding the "
                             "input's (e.g. a TF known to be wrong)")
    parser.add_argument("--extrinsic3d", metavar="X,Y,Z,ROLL,PITCH,YAW",
                        help="pose of the 3D LiDAR in the robot base frame (metres, radians), overriding the "
                             "input's")
    parser.add_argument("--no-loop-closure", action="store_true",
                        help="track only: no pose graph, no loop closure (one global tracking map)")
    parser.add_argument("--no-recording", action="store_true", help="do not write slam.rrd")
    parser.add_argument("--quiet", action="store_true", help="no progress bar or summary")


def parse_vector(text: str, n: int, flag: str):
    """``"a,b,c"`` -> n floats; an :class:`hsmap.errors.InputError` naming ``flag`` otherwise."""
    import numpy as np

    from ..errors import InputError

    parts = [p.strip() for p in str(text).split(",")]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise InputError(f"{flag} must be {n} comma-separated numbers, got {text!r}") from None
    if len(values) != n or not np.all(np.isfinite(values)):
        raise InputError(f"{flag} must be {n} comma-separated finite numbers, got {text!r}")
    return np.asarray(values)


def run(args: argparse.Namespace) -> int:
    import dataclasses

    from ..config import load_config
    from ..datasets.open import open_dataset
    from ..errors import InputError
    from ..slam import SlamConfig, run_slam, write_slam_outputs
    from ..trajectory import read_tum

    cfg = load_config(SlamConfig, args.config) if args.config else SlamConfig()
    if args.dof is not None:
        cfg = dataclasses.replace(cfg, dof=args.dof)  # validated like any SlamConfig
    if args.no_odometry:
        cfg = dataclasses.replace(cfg, use_odometry=False)
    if args.no_loop_closure:
        cfg = dataclasses.replace(cfg, loop_closure=dataclasses.replace(cfg.loop_closure, enabled=False))
    if args.max_frames is not None and args.max_frames < 1:
        raise InputError(f"--max-frames must be >= 1, got {args.max_frames}")
    ext2 = None if args.extrinsic2d is None else parse_vector(args.extrinsic2d, 3, "--extrinsic2d")
    ext3 = None if args.extrinsic3d is None else parse_vector(args.extrinsic3d, 6, "--extrinsic3d")
    prior = read_tum(args.prior) if args.prior else None
    dataset = open_dataset(args.input, scan_topic=args.scan_topic, cloud_topic=args.cloud_topic,
                           odom_topic=args.odom_topic, extrinsic2d=ext2, extrinsic3d=ext3)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "metrics.json").unlink(missing_ok=True)  # the marker of a complete folder goes first

    rec = None
    on_frame = None
    if not args.no_recording:
        from ..viz import rerun as hv

        rec = hv.open_recording(out / "slam.rrd", application_id="hsmap_slam",
                                blueprint=hv.default_blueprint(graph=False))
        map_logger = hv.PointMapLogger(rec, block=10, voxel=0.05 if cfg.dof == 3 else 0.15)

        def on_frame(frame, result, slam):
            hv.log_frame(rec, frame, result.pose, cloud_voxel=0.25)
            if result.keyframe:
                from ..geometry import pose_to_matrix, transform_points
                from ..slam import frame_points

                pts = frame_points(frame, cfg.dof, cfg.min_range, cfg.max_range)
                map_logger.add(transform_points(pose_to_matrix(result.pose), pts))

    try:
        result = run_slam(dataset, cfg, rng=args.seed, prior=prior, max_frames=args.max_frames,
                          progress=False if args.quiet else None, on_frame=on_frame)
        if rec is not None:
            map_logger.flush()
            from ..viz import rerun as hv

            hv.log_trajectory(rec, result.trajectory, robot_entity=None)
    except BaseException:
        if rec is not None:
            rec.abort()
        raise
    if rec is not None:
        rec.close()
    write_slam_outputs(result, out)
    if not args.quiet:
        m = result.metrics()
        summary = {k: m[k] for k in ("input", "dof", "frames", "keyframes", "map_points", "seconds_total",
                                     "seconds_per_frame_median", "real_time_factor", "peak_memory_mb",
                                     "loop_closure", "loops_closed", "frames_retried")}
        json.dump(summary, sys.stderr, indent=2)
        sys.stderr.write(f"\nwrote {out}/{{trajectory.tum, map.ply, metrics.json, config.yaml"
                         f"{'' if args.no_recording else ', slam.rrd'}}}\n")
    return 0
