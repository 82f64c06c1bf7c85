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
                        help="6-DOF: use the clouds as they are (for drivers that deskew them): no motion "
                             "compensation by their per-point times")
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
# the recording's growing 2D map: 5 cm cells up to a 2000 x 2000 image (a building such as intel or fr079), coarser
# beyond (fr-clinic's 444 m x 237 m at 5 cm are 42 million cells a grid: a sixth of the run's time went into drawing
# and logging eleven of them)
REPLAY_GRID_CELLS = 4_000_000


def run(args: argparse.Namespace) -> int:
    import dataclasses

    from ..config import load_config
    from ..errors import InputError
    from ..io import prepare_output_dir, refuse_overwriting_input, staged_outputs, sweep_stale_temporaries
    from ..slam import SlamConfig, run_slam, write_slam_outputs
    from ..trajectory import read_tum

    if args.seed < 0:
        raise InputError(f"--seed must be >= 0, got {args.seed}")
    cfg = load_config(SlamConfig, args.config) if args.config else SlamConfig()
    if args.dof is not None:
        cfg = dataclasses.replace(cfg, dof=args.dof)  # validated like any SlamConfig
    if args.no_odometry:
        cfg = dataclasses.replace(cfg, use_odometry=False)
    if args.no_loop_closure:
        cfg = dataclasses.replace(cfg, loop_closure=dataclasses.replace(cfg.loop_closure, enabled=False))
    if args.no_deskew:
        cfg = dataclasses.replace(cfg, deskew=False)
    from .inputs import open_input, sync_tolerance

    if sync_tolerance(args) is not None:
        cfg = dataclasses.replace(cfg, sync_tolerance=args.sync_tolerance)
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
        rec = None
        on_frame = None
        if not args.no_recording:
            from ..viz import rerun as hv

            # a 2D map view only where there is a 2D map: the occupancy grid of a 3-DOF run, logged at the end
            rec = hv.open_recording(stage / "slam.rrd", application_id="hsmap_slam",
                                    blueprint=hv.default_blueprint(graph=False, map2d=cfg.dof == 3, legend=True))
            hv.log_legend(rec, _legend(cfg.dof))
            map_logger = hv.PointMapLogger(rec, block=10, voxel=0.05 if cfg.dof == 3 else 0.15)
            # the frames are logged in blocks, as columns: a few calls per block instead of a few per frame
            frame_logger = hv.FrameLogger(rec, block=64, cloud_voxel=0.25)

            keyscans: list = []  # 3-DOF: the keyframes' scans, for the grid at their final poses

            def on_frame(frame, result, slam):
                frame_logger.add(frame, result.pose)
                if result.keyframe and cfg.dof == 3:
                    keyscans.append(frame)
                if result.keyframe:
                    from ..geometry import pose_to_matrix, transform_points
                    from ..slam import frame_points

                    pts = frame_points(frame, cfg.dof, cfg.min_range, cfg.max_range)
                    hv.set_frame_time(rec, frame.index, frame.stamp)  # the map block's time
                    map_logger.add(transform_points(pose_to_matrix(result.pose), pts))

        try:
            result = run_slam(dataset, cfg, rng=args.seed, prior=prior, max_frames=args.max_frames,
                              progress=False if args.quiet else None, on_frame=on_frame,
                              prior_name=f"--prior {args.prior}", strict=args.strict, threads=args.threads)
            if rec is not None:
                frame_logger.flush()
                if result.frames:
                    hv.set_frame_time(rec, result.frames[-1].index, result.frames[-1].stamp)
                map_logger.flush()
                _log_replay(rec, keyscans, result)
        except BaseException:
            if rec is not None:
                rec.abort()
            raise
        if rec is not None:
            rec.close()
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


def _legend(dof: int) -> str:
    from ..viz.rerun import series_legend

    lines = [f"### hsmap slam ({'3-DOF' if dof == 3 else '6-DOF'})",
             "Move the time cursor (timelines `time` and `scan`) to replay the run.", "",
             series_legend(["estimate"]) + " (after loop closure: the optimised poses, drawn up to the current time)",
             "- **orange box** (3D)" + (" / **orange arrow** (2D map)" if dof == 3 else "") + ": the robot",
             "- **orange-red points**: the current scan" + ("" if dof == 3 else " and cloud (coloured by height)"),
             "- **points**: the map, the keyframes at their poses when they were added"]
    if dof == 3:
        lines.append("- **2D map**: the occupancy grid of the keyframes' scans so far, at their final poses")
    return "\n".join(lines)


def _log_replay(rec, keyscans, result, grid_updates: int = 10, path_updates: int = 60) -> None:
    """After the run: the final (optimised) path drawn up to each time, and, in 3-DOF, the occupancy grid of
    the keyframes' scans so far (at their final poses) growing along the timelines in both views, with the
    robot in the 2D map view."""
    import numpy as np

    from ..grid import grids_from_scan_prefixes
    from ..viz import rerun as hv

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
