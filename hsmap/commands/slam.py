"""Run HS-SLAM on a simulator folder, a ROS1/ROS2 bag or a CARMEN log.

Writes into --out: trajectory.tum (stamps = the input's scan stamps), map.ply, metrics.json (per-scan time,
fitness, inlier ratio; totals; peak memory; skipped frames), config.yaml (the effective configuration) and
slam.rrd (a rerun recording: robot pose, scans and the growing map on a `scan` timeline). The outputs are
written into a hidden staging folder inside --out and moved into place together when all of them are complete
(metrics.json last), so a failed or interrupted run leaves the previous run's files as they were; a killed
run's leftovers are removed by the next run into the same folder. A frame whose scan (cloud) is missing or has
too few usable points is skipped with a warning and counted (--strict stops instead).
"""

from __future__ import annotations

import argparse
import json
import sys

NAME = "slam"
HELP = "HS-SLAM (Harmony-ICP scan-to-map) in 2D (3-DOF) or 3D (6-DOF)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("input", help="simulator folder (with dataset.yaml), ROS1 .bag / ROS2 bag folder, or CARMEN "
                                      "log (.log/.clf, optionally .gz)")
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--dof", type=int, choices=(3, 6), help="3: 2D scans, 6: 3D clouds (default: the config's, 3)")
    parser.add_argument("--seed", type=int, default=0, help="random seed, >= 0 (default 0)")
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
    parser.add_argument("--strict", action="store_true",
                        help="stop at the first frame whose scan or cloud is missing or has too few usable points "
                             "(default: skip it with a warning and count it in metrics.json)")
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


#: The files ``hsmap slam`` writes into --out (their stale temporaries are removed by the next run).
OUTPUTS = ("trajectory.tum", "map.ply", "config.yaml", "metrics.json", "slam.rrd")


def check_prior(prior, dataset, max_frames: int | None, flag: str = "--prior") -> dict:
    """How many of the input's frames the prior trajectory has a pose for (within 1 ms, as HS-SLAM looks them up).

    Returns ``{"file", "frames", "frames_with_prior"}``; raises :class:`~hsmap.errors.InputError` when it
    covers none of them (it would be silently ignored) and warns when it covers only some.
    """
    import warnings

    import numpy as np

    from ..errors import HsmapWarning, InputError

    stamps = getattr(dataset, "stamps", None)
    if stamps is None:
        return {}
    stamps = np.asarray(stamps, dtype=float)[: max_frames if max_frames is not None else None]
    _, found = prior.at(stamps, max_dt=1e-3)
    k, n = int(found.sum()), len(stamps)
    if k == 0:
        raise InputError(
            f"{flag}: none of its {len(prior)} stamps ({prior.stamps.min():.3f}..{prior.stamps.max():.3f} s) lies "
            f"within 1 ms of the input's {n} frame stamps ({stamps.min():.3f}..{stamps.max():.3f} s); expected the "
            "trajectory.tum of a 2D run of the same input")
    if k < n:
        warnings.warn(f"{flag} has a pose for {k} of the {n} frames ({100.0 * k / n:.1f} %); the others are "
                      "seeded without it", HsmapWarning, stacklevel=2)
    return {"frames": n, "frames_with_prior": k}


def run(args: argparse.Namespace) -> int:
    import dataclasses

    from ..config import load_config
    from ..datasets.open import open_dataset
    from ..errors import InputError
    from ..io import prepare_output_dir, staged_outputs, sweep_stale_temporaries, write_json
    from ..slam import SlamConfig, run_slam, write_slam_outputs
    from ..trajectory import read_tum

    if args.seed < 0:
        raise InputError(f"--seed must be >= 0, got {args.seed}")
    if args.max_frames is not None and args.max_frames < 1:
        raise InputError(f"--max-frames must be >= 1, got {args.max_frames}")
    cfg = load_config(SlamConfig, args.config) if args.config else SlamConfig()
    if args.dof is not None:
        cfg = dataclasses.replace(cfg, dof=args.dof)  # validated like any SlamConfig
    if args.no_odometry:
        cfg = dataclasses.replace(cfg, use_odometry=False)
    if args.no_loop_closure:
        cfg = dataclasses.replace(cfg, loop_closure=dataclasses.replace(cfg.loop_closure, enabled=False))
    ext2 = None if args.extrinsic2d is None else parse_vector(args.extrinsic2d, 3, "--extrinsic2d")
    ext3 = None if args.extrinsic3d is None else parse_vector(args.extrinsic3d, 6, "--extrinsic3d")
    prior = read_tum(args.prior) if args.prior else None
    if prior is not None and cfg.dof != 6:
        raise InputError("--prior seeds 6-DOF runs only (--dof 6)")
    out = prepare_output_dir(args.out, "--out", create=False)  # before the long work: a bad folder is reported now
    dataset = open_dataset(args.input, scan_topic=args.scan_topic, cloud_topic=args.cloud_topic,
                           odom_topic=args.odom_topic, extrinsic2d=ext2, extrinsic3d=ext3)
    prior_info = check_prior(prior, dataset, args.max_frames) if prior is not None else {}
    sweep_stale_temporaries(out, OUTPUTS)  # left by a killed run

    with staged_outputs(out, last="metrics.json") as stage:
        rec = None
        on_frame = None
        if not args.no_recording:
            from ..viz import rerun as hv

            rec = hv.open_recording(stage / "slam.rrd", application_id="hsmap_slam",
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
                              progress=False if args.quiet else None, on_frame=on_frame, strict=args.strict)
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
        paths = write_slam_outputs(result, stage)
        if prior_info:
            m = json.loads(paths["metrics"].read_text(encoding="utf-8"))
            m["prior"] = {"file": str(args.prior), **prior_info}
            write_json(paths["metrics"], m)
    if not args.quiet:
        m = result.metrics()
        summary = {k: m[k] for k in ("input", "dof", "frames", "skipped_frames", "keyframes", "map_points",
                                     "seconds_total", "seconds_per_frame_median", "real_time_factor",
                                     "peak_memory_mb", "loop_closure", "loops_closed", "frames_retried")}
        if prior_info:
            summary["prior"] = prior_info
        json.dump(summary, sys.stderr, indent=2)
        sys.stderr.write(f"\nwrote {out}/{{trajectory.tum, map.ply, metrics.json, config.yaml"
                         f"{'' if args.no_recording else ', slam.rrd'}}}\n")
    return 0
