"""Where HS-SLAM's time goes, per stage: one run under cProfile, the cumulative time of each stage's function.

``--input`` is a Freiburg log name (``intel``, ``fr079``, ``fr-clinic``: the command line's default configuration,
odometry and loop closure on) or ``3d`` (the simulated slam-office route: the 2D run, then the 6-DOF run seeded
by it, which is the one profiled). Stages overlap (the refinement runs inside harmony_icp, loop closure calls
harmony_icp too); each is the cumulative time of the named functions, as a share of the run's profiled time.
Writes reports/benchmarks/profile_<input>.json and prints the table.

    .venv/bin/python benchmarks/profile_slam.py --input fr079 --max-frames 2500
    .venv/bin/python benchmarks/profile_slam.py --input 3d --max-frames 200
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import sys
import time
from pathlib import Path

os.environ.setdefault("RERUN_ANALYTICS", "0")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

# stage -> (module file suffix, function name) pairs whose cumulative times are summed
STAGES = {
    "process (one frame, all of it)": [("hsmap/slam/tracker.py", "process")],
    "frame_points (range filter + voxel downsampling)": [("hsmap/slam/frames.py", "frame_points")],
    "harmony_icp (tracking + loop closure)": [("hsmap/registration/icp.py", "harmony_icp")],
    "  harmony_search (HS rounds)": [("hsmap/registration/harmony.py", "harmony_search")],
    "  refine_icp": [("hsmap/registration/icp.py", "refine_icp")],
    "  _alignment_cost / _match (correspondences)": [("hsmap/registration/icp.py", "_alignment_cost"),
                                                     ("hsmap/registration/icp.py", "_match")],
    "  RegistrationTarget.nearest (neighbour queries)": [("hsmap/registration/icp.py", "nearest")],
    "  RegistrationTarget.prepare (neighbour grid builds)": [("hsmap/registration/icp.py", "prepare")],
    "  _information_and_cost": [("hsmap/registration/icp.py", "_information_and_cost")],
    "  _subsample": [("hsmap/registration/icp.py", "_subsample")],
    "  RegistrationTarget.tree (KD-tree builds)": [("hsmap/registration/icp.py", "tree")],
    "Verifier.verify (prediction check, retries)": [("hsmap/slam/verify.py", "verify")],
    "ensure_target (local map crop, field)": [("hsmap/slam/keyframes.py", "ensure_target")],
    "  DistanceField.__init__": [("hsmap/registration/fitness.py", "__init__")],
    "  _rebuild_map": [("hsmap/slam/keyframes.py", "_rebuild_map")],
    "add_keyframe (normals, map, field, loops)": [("hsmap/slam/keyframes.py", "add_keyframe")],
    "  estimate_normals": [("hsmap/registration/icp.py", "estimate_normals")],
    "  VoxelMap.add": [("hsmap/maps/mapping.py", "add")],
    "  DistanceField.add": [("hsmap/registration/fitness.py", "add")],
    "  _pair_edges (scan-to-scan refinements)": [("hsmap/slam/keyframes.py", "_pair_edges")],
    "  path_distances (graph distances)": [("hsmap/slam/posegraph.py", "path_distances")],
    "  _close_loops (search + verify)": [("hsmap/slam/keyframes.py", "_close_loops")],
    "    attempt_far (far search, 2D)": [("hsmap/slam/loopclosure.py", "attempt_far")],
    "      correlative_match_2d (exhaustive)": [("hsmap/registration/correlative.py", "correlative_match_2d")],
    "  optimize (graph)": [("hsmap/slam/keyframes.py", "optimize")],
    "on_frame (recording)": [("benchmarks/profile_slam.py", "on_frame")],
}


def _cumulative(stats: pstats.Stats, wanted: list[tuple[str, str]]) -> float:
    total = 0.0
    for (file, _line, name), (_cc, _nc, _tt, ct, _callers) in stats.stats.items():  # type: ignore[attr-defined]
        for suffix, fn in wanted:
            if name == fn and file.replace("\\", "/").endswith(suffix):
                total += ct
    return total


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--input", default="fr079", choices=["intel", "fr079", "fr-clinic", "3d"])
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--top", type=int, default=25, help="also print the top functions by own time")
    ap.add_argument("--dataset3d", default=None, help="3d: this simulator folder instead of the study's slam-office "
                                                      "seed 1 (benchmarks/slam.py --dataset3d)")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)

    import numpy as np
    from _report import finish, machine  # benchmarks/_report.py

    from hsmap.datasets.open import open_dataset
    from hsmap.slam import SlamConfig, run_slam

    if args.input == "3d":
        from hsmap.study import simulated_dataset

        ds = open_dataset(args.dataset3d or simulated_dataset("slam-office", 1).path)
        n = min(len(ds), args.max_frames or len(ds))
        frames = [f for _, f in zip(range(n), ds.frames(clouds=True), strict=False)]
        run2d = run_slam(frames, SlamConfig(dof=3, use_odometry=False), rng=args.seed, progress=False)
        cfg, prior = SlamConfig(dof=6, use_odometry=False), run2d.trajectory
    else:
        from slam import FREIBURG  # benchmarks/slam.py

        from hsmap.study.paths import datasets_dir

        spec = FREIBURG[args.input]
        ds = open_dataset(datasets_dir() / "slam2d" / spec["bag"], extrinsic2d=spec["extrinsic2d"])
        n = min(len(ds), args.max_frames or len(ds))
        frames = [f for _, f in zip(range(n), ds.frames(clouds=False), strict=False)]
        cfg, prior = SlamConfig(dof=3), None
    # compile the kernels outside the profile (numba's cache may be cold)
    run_slam(frames[:5], cfg, rng=args.seed, prior=prior, progress=False)
    host = machine()
    prof = cProfile.Profile()
    t0 = time.perf_counter()
    prof.enable()
    res = run_slam(frames, cfg, rng=args.seed, prior=prior, progress=False)
    prof.disable()
    wall = time.perf_counter() - t0
    stats = pstats.Stats(prof)
    total = stats.total_tt  # type: ignore[attr-defined]
    stages = {}
    print(f"{args.input}: {n} frames, {wall:.1f} s wall under cProfile (profiled {total:.1f} s), "
          f"load {host['load_average_at_start'][0]:.2f}")
    for name, wanted in STAGES.items():
        s = _cumulative(stats, wanted)
        stages[name.strip()] = {"seconds": s, "share": s / total if total else float("nan")}
        print(f"  {name:52s} {s:8.2f} s {100 * s / total:5.1f} %")
    secs = np.array([f.seconds for f in res.frames])
    if args.top:
        stats.sort_stats("tottime").print_stats(args.top)
    out = {
        "benchmark": "profile_slam",
        "input": args.input,
        "frames": n,
        "seed": args.seed,
        "wall_seconds_under_profile": wall,
        "profiled_seconds": total,
        "seconds_per_frame_median_under_profile": float(np.median(secs)),
        "stages": stages,
        "machine": host,
    }
    path = Path(args.out or ROOT / "reports/benchmarks" / f"profile_{args.input}.json")
    finish(out, path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
