"""Speed benchmark: HS-SLAM at sensor rate, every number measured side by side in one process.

1. ``3d``: 6-DOF HS-SLAM (seeded by the 2D run, as in the paper) and KISS-ICP on the same simulated 128 x 1024
   clouds (slam-office, seed 1; ``benchmarks/slam.py``'s comparison): median and p95 ms per cloud of both, their
   ratio (HS-SLAM / KISS-ICP, target <= 1.0), both methods' errors against the ground truth. Then the
   6-DOF run again with 1 and with 2 compute threads (``--threads-compare``), alternated ``--repeats`` times:
   the median ms per cloud of each and the speed-up, and whether the trajectories are identical (they must be).
2. ``intel``, ``fr079``, ``fr-clinic``: the ``hsmap slam`` command in this process (odometry, loop closure and
   ``slam.rrd`` on, the command line's defaults; fr079 with ``--extrinsic2d -0.04,0,0``), alternated with the
   same command with ``--no-recording``, ``--repeats`` times each: the command's wall time (reading the bag,
   SLAM, recording, writing), the real-time factor (log duration / wall time; target >= 40x with
   the recording on), and the recording's share of the wall time (the target <= 10 %).

Every run records ``os.getloadavg()`` beside it: the machine is shared, so only ratios within one run mean much.
Writes reports/benchmarks/speed.json (atomically).

    .venv/bin/python benchmarks/speed.py [--only 3d intel fr079 fr-clinic] [--max-frames N] [--repeats 1]
        [--threads-compare 1 2] [--dataset3d FOLDER]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("RERUN_ANALYTICS", "0")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from _report import finish, load_average, machine  # noqa: E402

import hsmap  # noqa: E402


def bench_3d(max_frames: int | None, folder: str | None, threads: list[int], repeats: int) -> dict:
    from slam import bench_3d as compare_with_kiss  # benchmarks/slam.py

    from hsmap.datasets.open import open_dataset
    from hsmap.evaluation.trajectory import pose_errors
    from hsmap.slam import SlamConfig, run_slam
    from hsmap.study import simulated_dataset
    from hsmap.trajectory import Trajectory

    load0 = load_average()
    out = compare_with_kiss(max_frames, folder)
    out["load_average"] = [load0, load_average()]
    hs, kiss = out["hs_slam_6dof"], out["kiss_icp"]
    print(f"3d: HS-SLAM {1000 * hs['seconds_per_cloud_median']:.1f} ms per cloud, KISS-ICP "
          f"{1000 * kiss['seconds_per_cloud_median']:.1f} ms: ratio {out['time_ratio_hs_over_kiss']:.2f} (of means "
          f"{out['mean_time_ratio_hs_over_kiss']:.2f}); CPU per "
          f"cloud {1000 * hs['cpu_seconds_per_cloud_mean']:.1f} / {1000 * kiss['cpu_seconds_per_cloud_mean']:.1f} "
          f"ms, ratio {out['cpu_ratio_hs_over_kiss']:.2f} (load {load0[0]})", flush=True)
    if len(threads) < 2:
        return out
    ds = open_dataset(folder or simulated_dataset("slam-office", 1).path)
    n = min(len(ds), max_frames or len(ds))
    frames = [f for _, f in zip(range(n), ds.frames(clouds=True), strict=False)]
    gt = Trajectory(ds.groundtruth.stamps[:n], ds.groundtruth.as_6dof().poses[:n])
    prior = run_slam(frames, SlamConfig(dof=3, use_odometry=False), rng=1, progress=False).trajectory
    runs: dict[int, list[dict]] = {t: [] for t in threads}
    poses: dict[int, np.ndarray] = {}
    for _ in range(repeats):
        for t in threads:  # alternated: the machine's load falls on both alike
            load = load_average()
            r = run_slam(frames, SlamConfig(dof=6, use_odometry=False), rng=1, prior=prior, progress=False,
                         threads=t)
            secs = np.array([f.seconds for f in r.frames])
            runs[t].append({"seconds_per_cloud_median": float(np.median(secs)), "wall_seconds": r.seconds,
                            "cpu_seconds": r.cpu_seconds, "load_average": load})
            poses.setdefault(t, r.trajectory.poses)
            err = pose_errors(r.trajectory, gt).as_dict()["max_abs_error"]
            print(f"3d threads {t}: {1000 * np.median(secs):.1f} ms per cloud, wall {r.seconds:.1f} s, CPU "
                  f"{r.cpu_seconds:.1f} s, max error x {100 * err['x_m']:.2f} cm (load {load[0]})", flush=True)
    med = {t: float(np.median([x["seconds_per_cloud_median"] for x in runs[t]])) for t in threads}
    base = threads[0]
    out["threads"] = {
        "runs": {str(t): runs[t] for t in threads},
        "seconds_per_cloud_median": {str(t): med[t] for t in threads},
        "speed_up_over": base,
        "speed_up": {str(t): med[base] / med[t] for t in threads},
        "identical_trajectories": bool(all(np.array_equal(poses[base], poses[t]) for t in threads)),
        "numba_threading_layer": _threading_layer(),
    }
    print(f"3d speed-up {threads[-1]} threads over {base}: {med[base] / med[threads[-1]]:.2f}x; identical "
          f"trajectories: {out['threads']['identical_trajectories']}", flush=True)
    return out


def _threading_layer() -> str:
    import numba

    try:
        return str(numba.threading_layer())
    except ValueError:  # no parallel kernel ran
        return "none"


def bench_freiburg(name: str, datasets: Path, max_frames: int | None, repeats: int, seed: int) -> dict:
    import json

    from slam import FREIBURG  # benchmarks/slam.py

    from hsmap._helper_process import cpu_seconds
    from hsmap.cli import main as hsmap_main

    spec = FREIBURG[name]
    bag = datasets / "slam2d" / spec["bag"]
    base = ["slam", str(bag), "--seed", str(seed), "--quiet"]
    if spec["extrinsic2d"] is not None:
        base.append("--extrinsic2d=" + ",".join(str(v) for v in spec["extrinsic2d"]))
    short = base + ["--max-frames", "30"]  # the warm-up
    if max_frames is not None:
        base += ["--max-frames", str(max_frames)]
    runs: dict[str, list[dict]] = {"recording": [], "no_recording": []}
    with tempfile.TemporaryDirectory(prefix="hsmap-speed-") as tmp:
        # warm-up, not measured: imports (rerun, open3d), compiled kernels read from numba's cache, the thread
        # pools; the first measured run would pay for them
        for extra in ([], ["--no-recording"]):
            if hsmap_main(short + ["--out", str(Path(tmp) / "warm-up")] + extra) != 0:
                raise SystemExit("the warm-up run failed")
        for _ in range(repeats):
            for kind in ("recording", "no_recording"):  # alternated
                out_dir = Path(tmp) / kind
                argv = base + ["--out", str(out_dir)] + (["--no-recording"] if kind == "no_recording" else [])
                load = load_average()
                # CPU: this process's and the helper process's (the smoothing's scan matches)
                t0, c0 = time.perf_counter(), cpu_seconds()
                rc = hsmap_main(argv)
                wall, cpu = time.perf_counter() - t0, cpu_seconds() - c0
                if rc != 0:
                    raise SystemExit(f"hsmap {' '.join(argv)} exited {rc}")
                m = json.loads((out_dir / "metrics.json").read_text())
                duration = m["input_duration_s"]
                runs[kind].append({"command_wall_seconds": wall, "command_cpu_seconds": cpu,
                                   "slam_seconds": m["seconds_total"], "slam_cpu_seconds": m["cpu_seconds_total"],
                                   "real_time_factor": duration / wall, "log_duration_s": duration,
                                   "frames": m["frames"], "loops_closed": m["loops_closed"],
                                   "rrd_bytes": (out_dir / "slam.rrd").stat().st_size
                                   if kind == "recording" else 0, "load_average": load})
                print(f"{name} {kind}: {wall:.1f} s wall ({cpu:.1f} s CPU), {duration / wall:.1f}x real time "
                      f"({duration / cpu:.1f}x by CPU time), SLAM {m['seconds_total']:.1f} s, {m['loops_closed']} "
                      f"loops (load {load[0]})", flush=True)
    rec = float(np.median([r["command_wall_seconds"] for r in runs["recording"]]))
    bare = float(np.median([r["command_wall_seconds"] for r in runs["no_recording"]]))
    rec_cpu = float(np.median([r["command_cpu_seconds"] for r in runs["recording"]]))
    bare_cpu = float(np.median([r["command_cpu_seconds"] for r in runs["no_recording"]]))
    out = {
        "runs": runs,
        "seed": seed,
        "max_frames": max_frames,
        "command_wall_seconds_median": {"recording": rec, "no_recording": bare},
        "real_time_factor_with_recording": float(np.median([r["real_time_factor"] for r in runs["recording"]])),
        "recording_share_of_wall": (rec - bare) / rec,
        "recording_overhead_over_bare": (rec - bare) / bare,
        # CPU time of the process (all its threads, rerun's writer included): the recording's work, less
        # sensitive than wall times to the load of a shared machine
        "command_cpu_seconds_median": {"recording": rec_cpu, "no_recording": bare_cpu},
        "real_time_factor_by_cpu_with_recording": float(np.median([r["log_duration_s"] / r["command_cpu_seconds"]
                                                                   for r in runs["recording"]])),
        "recording_share_of_cpu": (rec_cpu - bare_cpu) / rec_cpu,
    }
    print(f"{name}: {out['real_time_factor_with_recording']:.1f}x real time with the recording; the recording "
          f"{100 * out['recording_share_of_wall']:.1f} % of the wall time, {100 * out['recording_share_of_cpu']:.1f} % "
          "of the CPU time", flush=True)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="+", choices=["3d", "intel", "fr079", "fr-clinic"],
                    default=["3d", "intel", "fr079", "fr-clinic"])
    ap.add_argument("--max-frames", type=int, default=None, help="cut every input (smoke runs)")
    ap.add_argument("--repeats", type=int, default=1, help="alternated runs of each setting")
    ap.add_argument("--threads-compare", nargs="*", type=int, default=[1, 2],
                    help="3d: thread counts compared (none: skip)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--dataset3d", default=None, help="3d: this simulator folder instead of the study's")
    ap.add_argument("--out", default=str(ROOT / "reports/benchmarks/speed.json"))
    args = ap.parse_args(argv)
    import numba

    from hsmap.study.paths import datasets_dir

    out = {
        "benchmark": "speed",
        "machine": machine(numba_threads=int(numba.config.NUMBA_NUM_THREADS)),
        "hsmap_version": hsmap.__version__,
        "command": " ".join([sys.executable, *sys.argv]),
    }
    datasets = datasets_dir()
    for name in args.only:
        if name == "3d":
            out["3d_slam_office"] = bench_3d(args.max_frames, args.dataset3d, args.threads_compare, args.repeats)
        elif (datasets / "slam2d").is_dir():
            out[name] = bench_freiburg(name, datasets, args.max_frames, args.repeats, args.seed)
        else:
            out[name] = {"skipped": f"no Freiburg data at {datasets}/slam2d"}
    finish(out, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
