"""Run HS-SLAM on a simulator folder, a ROS1/ROS2 bag, a CARMEN log or a folder of point clouds.

Writes into --out: trajectory.tum (stamps = the input's scan stamps), map.ply, metrics.json (per-scan time,
fitness, inlier ratio; totals; peak memory; skipped frames), config.yaml (the effective configuration) and
slam.rrd (a rerun recording: robot pose, scans and the growing map on a `scan` timeline; in 3-DOF also the
final occupancy grid in its 2D map view). With --dof 6 the frames are the 3D clouds (a 2D LiDAR usually runs
faster: its nearest scan within --sync-tolerance is attached), and --prior's 2D poses are interpolated at each
cloud's stamp; a prior that gives no cloud a pose is an error, one that gives some is warned about, and
metrics.json records its coverage. metrics.json also records what was read (input_info: topics, message counts, rates, frames, the
sensor offsets and where each came from, warnings such as a missing transform). A frame whose scan (cloud) is
missing or has too few usable points is skipped with a warning and counted (--strict stops instead).

--out is checked before the long work starts (a folder, or creatable, and writable). The outputs are written
into a hidden staging folder inside --out and moved into place together when all of them are complete
(metrics.json last), so a failed or interrupted run leaves the previous run's files as they were; a killed
run's leftovers are removed by the next run into the same folder.
"""

from __future__ import annotations

import argparse
import json
import sys

from .inputs import parse_vector  # noqa: F401  (its home was here)

NAME = "slam"
HELP = "HS-SLAM (Harmony-ICP scan-to-map) in 2D (3-DOF) or 3D (6-DOF)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from .inputs import INPUT_HELP, add_input_arguments

    parser.add_argument("input", help=INPUT_HELP)
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--dof", type=int, choices=(3, 6), help="3: 2D scans, 6: 3D clouds (default: the config's, 3)")
    parser.add_argument("--seed", type=int, default=0, help="random seed, >= 0 (default 0)")
    parser.add_argument("--config", help="YAML file of SlamConfig fields (see config.yaml of any run)")
    parser.add_argument("--no-odometry", action="store_true", help="ignore the input's odometry (no odometry seed)")
    parser.add_argument("--prior", help="6-DOF: a TUM trajectory of a 2D run whose poses, interpolated at each "
                                        "cloud's stamp (within --sync-tolerance), seed the search")
    parser.add_argument("--max-frames", type=int, help="stop after this many frames")
    add_input_arguments(parser)
    parser.add_argument("--no-loop-closure", action="store_true",
                        help="track only: no pose graph, no loop closure (one global tracking map)")
    parser.add_argument("--no-deskew", action="store_true",
                        help="use the clouds (6-DOF) or 2D scans (3-DOF) as they are (for drivers that deskew "
                             "them): no motion compensation by their per-point or per-beam times")
    parser.add_argument("--no-recording", action="store_true", help="do not write slam.rrd")
    parser.add_argument("--strict", action="store_true",
                        help="stop at the first frame whose scan or cloud is missing or has too few usable points "
                             "(default: skip it with a warning and count it in metrics.json)")
    parser.add_argument("--threads", type=int, default=None,
                        help="compute threads (default: $HSMAP_THREADS, else every core); the result is the same "
                             "for any count")
    parser.add_argument("--quiet", action="store_true", help="no progress bar or summary")


#: The files ``hsmap slam`` writes into --out (their stale temporaries are removed by the next run).
OUTPUTS = ("trajectory.tum", "map.ply", "config.yaml", "metrics.json", "slam.rrd")


def run(args: argparse.Namespace) -> int:

    from ..config import load_config
    from ..errors import InputError
    from ..io import prepare_output_dir, refuse_overwriting_input, staged_outputs, sweep_stale_temporaries
    from ..slam import SlamConfig, run_slam, write_slam_outputs
    from ..trajectory import read_tum
    from ..viz.replay import SlamRecorder
    from .inputs import open_input, slam_overrides

    if args.seed < 0:
        raise InputError(f"--seed must be >= 0, got {args.seed}")
    cfg = slam_overrides(load_config(SlamConfig, args.config) if args.config else SlamConfig(), args,
                         deskew=True)
    if args.threads is not None and args.threads < 1:
        raise InputError(f"--threads must be >= 1, got {args.threads}")
    if args.max_frames is not None and args.max_frames < 1:
        raise InputError(f"--max-frames must be >= 1, got {args.max_frames}")
    prior = read_tum(args.prior) if args.prior else None
    if prior is not None and cfg.dof != 6:
        raise InputError("--prior seeds 6-DOF runs only (--dof 6)")
    refuse_overwriting_input(args.out, [args.input, args.scans, args.prior, args.config], OUTPUTS)
    out = prepare_output_dir(args.out, "--out", create=False)  # before the long work: a bad folder is reported now
    dataset = open_input(args, drive="cloud" if cfg.dof == 6 else "scan", progress=False if args.quiet else None)
    sweep_stale_temporaries(out, OUTPUTS)  # left by a killed run

    with staged_outputs(out, last="metrics.json", replaces=OUTPUTS) as stage:
        recorder = None if args.no_recording else SlamRecorder(stage / "slam.rrd", cfg)
        try:
            result = run_slam(dataset, cfg, rng=args.seed, prior=prior, max_frames=args.max_frames,
                              progress=False if args.quiet else None,
                              on_frame=None if recorder is None else recorder.on_frame,
                              prior_name=f"--prior {args.prior}", strict=args.strict, threads=args.threads)
            if recorder is not None:
                recorder.finish(result)
        except BaseException:
            if recorder is not None:
                recorder.abort()
            raise
        if recorder is not None:
            recorder.close()
        write_slam_outputs(result, stage)
    if not args.quiet:
        m = result.metrics()
        summary = {k: m[k] for k in ("input", "dof", "frames", "skipped_frames", "keyframes", "map_points",
                                     "seconds_total", "seconds_per_frame_median", "real_time_factor",
                                     "peak_memory_mb", "loop_closure", "loops_closed", "pair_edges", "frames_retried")}
        json.dump(summary, sys.stderr, indent=2)
        sys.stderr.write(f"\nwrote {out}/{{trajectory.tum, map.ply, metrics.json, config.yaml"
                         f"{'' if args.no_recording else ', slam.rrd'}}}\n")
    return 0
