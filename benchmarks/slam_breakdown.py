"""Where a 2D HS-SLAM scan's time goes, without a profiler's overhead: the inclusive wall time of each stage's
function (wrapped with a clock for the run), the run's counted work (:class:`hsmap.slam.costs.Costs`) and its
Freiburg relations error over the frames run.

Stages nest (the refinement runs inside harmony_icp, the loop searches call harmony_icp too): each row is the
inclusive time of the named function, as a share of the run's wall time. ``--repeat`` alternates the runs of
the same frames (the machine is shared: compare counts, and the ratios of runs made side by side).
``--compare FIELD=VALUE`` also runs, alternated with the default configuration, one whose registration field
(:class:`hsmap.registration.icp.RegistrationConfig`) is set to VALUE, for a change's effect on time, work and error.

    .venv/bin/python benchmarks/slam_breakdown.py --input intel --max-frames 3000 --seed 1
    .venv/bin/python benchmarks/slam_breakdown.py --input intel --max-frames 3000 --clock cpu --recording --threads 2
    .venv/bin/python benchmarks/slam_breakdown.py --input fr079 --max-frames 3000 --seed 1 \
        --compare stop_within_cell=False --no-instrument
"""

from __future__ import annotations

import argparse
import functools
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("RERUN_ANALYTICS", "0")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

# stage -> (module, owner (class name or None), function name)
STAGES = {
    "process (one frame, all of it)": ("hsmap.slam.tracker", "HsSlam", "process"),
    "tracking harmony_icp (first search)": ("hsmap.slam.tracker", None, "harmony_icp"),
    "harmony_search (every registration's HS rounds)": ("hsmap.registration.icp", None, "harmony_search"),
    "refine_icp (every refinement)": ("hsmap.registration.icp", None, "refine_icp"),
    "_information_and_cost": ("hsmap.registration.icp", None, "_information_and_cost"),
    "Verifier.verify (check, retries)": ("hsmap.slam.verify", "Verifier", "verify"),
    "OdometryModel.learn_scale": ("hsmap.slam.odometry", "OdometryModel", "learn_scale"),
    "ensure_target (crop, field, neighbour grid)": ("hsmap.slam.keyframes", "KeyframeGraph", "ensure_target"),
    "_rebuild_map (tracking map from keyframes)": ("hsmap.slam.keyframes", "KeyframeGraph", "_rebuild_map"),
    "DistanceField.__init__ (field builds)": ("hsmap.registration.fitness", "DistanceField", "__init__"),
    "DistanceField.add (field updates)": ("hsmap.registration.fitness", "DistanceField", "add"),
    "add_keyframe (normals, map, edges, loops)": ("hsmap.slam.keyframes", "KeyframeGraph", "add_keyframe"),
    "_pair_edges": ("hsmap.slam.keyframes", "KeyframeGraph", "_pair_edges"),
    "_close_loops (searches + optimisation)": ("hsmap.slam.keyframes", "KeyframeGraph", "_close_loops"),
    "optimize (graph)": ("hsmap.slam.keyframes", "KeyframeGraph", "optimize"),
    "path_distances": ("hsmap.slam.posegraph", "PoseGraph", "path_distances"),
    "frame_points (scan filter, voxels)": ("hsmap.slam.deskewing", None, "frame_points"),
    "deskew_scan_frame": ("hsmap.slam.deskewing", None, "deskew_scan_frame"),
    "MotionPrediction.seeds": ("hsmap.slam.prediction", "MotionPrediction", "seeds"),
    "MotionPrediction.predict": ("hsmap.slam.prediction", "MotionPrediction", "predict"),
    "Verifier.fuse": ("hsmap.slam.verify", "Verifier", "fuse"),
    "OdometryModel.learn_bias": ("hsmap.slam.odometry", "OdometryModel", "learn_bias"),
    "OdometryModel.accumulate_wheel": ("hsmap.slam.odometry", "OdometryModel", "accumulate_wheel"),
    "OdometryModel.advance": ("hsmap.slam.odometry", "OdometryModel", "advance"),
    "Deskewing.points (deskew, filter, voxels)": ("hsmap.slam.deskewing", "Deskewing", "points"),
    "FrameMotions.record (smoothing's scan matches inline)": ("hsmap.slam.motions", "FrameMotions", "record"),
    "scan_motions (smoothing's scan matches)": ("hsmap.slam.motions", None, "scan_motions"),
    "smoothing (after the frames)": ("hsmap.slam.tracker", None, "smooth_with_odometry"),
    "MotionPrediction.first_registration": ("hsmap.slam.prediction", "MotionPrediction", "first_registration"),
    "MotionPrediction.kept_registration": ("hsmap.slam.prediction", "MotionPrediction", "kept_registration"),
    "SearchBox.escapes": ("hsmap.slam.search", "SearchBox", "escapes"),
    "SearchBox.widened": ("hsmap.slam.search", "SearchBox", "widened"),
    "SearchBox.settled": ("hsmap.slam.search", "SearchBox", "settled"),
    "KeyframeGraph.attach": ("hsmap.slam.keyframes", "KeyframeGraph", "attach"),
    "KeyframeGraph.is_keyframe": ("hsmap.slam.keyframes", "KeyframeGraph", "is_keyframe"),
    "SlamRecorder.on_frame (recording, --recording)": ("hsmap.viz.replay", "SlamRecorder", "on_frame"),
    "SlamRecorder.finish (final path and grids)": ("hsmap.viz.replay", "SlamRecorder", "finish"),
}


def _instrument(clock: dict, now=time.perf_counter) -> list:
    """Wrap each stage's function with the clock ``now``; returns the undo list."""
    import importlib

    undo = []
    for name, (module, owner, fn) in STAGES.items():
        mod = importlib.import_module(module)
        holder = getattr(mod, owner) if owner else mod
        if not hasattr(holder, fn):
            continue
        orig = getattr(holder, fn)
        clock[name] = [0.0, 0]

        def timed(*a, __orig=orig, __name=name, **k):
            t0 = now()
            try:
                return __orig(*a, **k)
            finally:
                c = clock[__name]
                c[0] += now() - t0
                c[1] += 1

        functools.update_wrapper(timed, orig)
        setattr(holder, fn, timed)
        undo.append((holder, fn, orig))
    return undo


def run_once(frames, rel, seed: int, threads: int, instrument: bool, change: dict | None = None, *,
             clock_name: str = "wall", recording: Path | None = None) -> dict:
    import numpy as np
    from slam import _relations  # benchmarks/slam.py

    from hsmap._helper_process import helper_cpu_seconds
    from hsmap.slam import SlamConfig, run_slam

    clock: dict = {}
    now = time.thread_time if clock_name == "cpu" else time.perf_counter
    undo = _instrument(clock, now) if instrument else []
    try:
        t0, c0, h0 = time.perf_counter(), time.process_time(), helper_cpu_seconds()
        cfg = SlamConfig(dof=3)
        for k, v in (change or {}).items():
            setattr(cfg.registration, k, v)
        recorder = None
        if recording is not None:
            from hsmap.viz.replay import SlamRecorder

            recorder = SlamRecorder(recording, cfg)
        res = run_slam(frames, cfg, rng=seed, progress=False, threads=threads,
                       on_frame=None if recorder is None else recorder.on_frame)
        if recorder is not None:
            recorder.finish(res)
            recorder.close()
        wall, cpu, helper = time.perf_counter() - t0, time.process_time() - c0, helper_cpu_seconds() - h0
    finally:
        for holder, fn, orig in undo:
            setattr(holder, fn, orig)
    secs = np.array([f.seconds for f in res.frames])
    whole = cpu if clock_name == "cpu" else wall
    return {
        "seed": seed,
        "registration_change": change or {},
        "recording": recording is not None,
        "clock": clock_name,
        "wall_seconds": wall,
        "cpu_seconds": cpu,
        "helper_cpu_seconds": helper,
        "frame_ms_median": 1e3 * float(np.median(secs)),
        "frame_ms_mean": 1e3 * float(np.mean(secs)),
        "costs": res.costs,
        "relations": _relations(res.trajectory, rel, True),
        "stages": {k: {"seconds": v[0], "calls": v[1], "share": v[0] / whole} for k, v in clock.items()},
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--input", default="intel", choices=["intel", "fr079", "fr-clinic"])
    ap.add_argument("--max-frames", type=int, default=3000)
    ap.add_argument("--seed", type=int, nargs="+", default=[1])
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--no-instrument", action="store_true", help="time the run alone")
    ap.add_argument("--clock", choices=["wall", "cpu"], default="wall",
                    help="cpu: each stage's CPU time on the main thread, shares of the process's CPU time (a "
                         "loaded machine's wall times say little)")
    ap.add_argument("--recording", action="store_true", help="record the run as hsmap slam does (slam.rrd)")
    ap.add_argument("--compare", default=None, metavar="FIELD=VALUE",
                    help="also run with this RegistrationConfig field changed (a Python literal), alternated")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    import ast

    variants: list[dict] = [{}]
    if args.compare:
        key, _, value = args.compare.partition("=")
        variants = [{key: ast.literal_eval(value)}, {}]

    from _report import finish, machine  # benchmarks/_report.py
    from slam import freiburg_frames  # benchmarks/slam.py

    from hsmap.slam import SlamConfig, run_slam
    from hsmap.study.paths import datasets_dir

    frames, rel, _ = freiburg_frames(args.input, datasets_dir(), args.max_frames)
    n = len(frames)
    run_slam(frames[:5], SlamConfig(dof=3), rng=1, progress=False)  # compile the kernels first
    host = machine()
    runs = []
    for seed in args.seed:
        for change in variants:
            with tempfile.TemporaryDirectory() as tmp:
                r = run_once(frames, rel, seed, args.threads, not args.no_instrument, change, clock_name=args.clock,
                             recording=Path(tmp) / "slam.rrd" if args.recording else None)
            runs.append(r)
            t = r["relations"]["all"]["translation_m"]["mean"]
            print(f"{args.input} seed {seed} {change or 'default'}: {n} frames, {r['wall_seconds']:.1f} s wall, "
                  f"{r['cpu_seconds']:.1f} s CPU (+ {r['helper_cpu_seconds']:.1f} s helper), "
                  f"{r['frame_ms_median']:.2f} ms/frame median, relations {t:.4f} m")
            for k, v in r["stages"].items():
                print(f"  {k:48s} {v['seconds']:8.2f} s {100 * v['share']:5.1f} % {v['calls']:7d} calls")
            print("  costs:", r["costs"], flush=True)
    out = {"benchmark": "slam_breakdown", "input": args.input, "frames": n, "threads": args.threads,
           "clock": args.clock, "recording": args.recording,
           "runs": runs, "machine": host}
    finish(out, Path(args.out or ROOT / "reports/benchmarks" / f"slam_breakdown_{args.input}.json"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
