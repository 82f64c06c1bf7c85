"""SLAM benchmark: HS-SLAM on the Freiburg logs and, in 3D, beside KISS-ICP on the simulated route.

1. ``intel`` and ``fr079`` (the ROS1 ``.orig.bag`` files of $HSMAP_DATASETS/slam2d): 2D HS-SLAM without
   odometry over the whole log: wall time, CPU time, real-time factor (log duration / wall time), peak memory
   (resident set of this process) and the Freiburg relations error. fr079 uses the laser offset of the CARMEN
   log's PARAM (-0.04 m), which the relations agree with, instead of the bag's TF (+0.04 m).
2. ``slam-office`` (simulated, seed 1): 6-DOF HS-SLAM (seeded by the 2D run's poses, as in the paper) on the
   128 x 1024 clouds, time per cloud beside KISS-ICP (``kiss-icp`` on PyPI) on the same clouds, and both
   methods' errors against ground truth (per-DOF maximum over the route, each trajectory relative to its first
   pose, no alignment; and the final-pose error).

Times exclude reading the input (frames are loaded first). Writes reports/benchmarks/slam.json (atomically).

    .venv/bin/python benchmarks/slam.py [--only intel fr079 3d] [--max-frames N]
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import sys
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("RERUN_ANALYTICS", "0")

import hsmap  # noqa: E402
from hsmap.config import to_dict  # noqa: E402
from hsmap.datasets.open import open_dataset  # noqa: E402
from hsmap.datasets.relations import read_relations  # noqa: E402
from hsmap.evaluation.trajectory import pose_errors, relations_error  # noqa: E402
from hsmap.geometry import compose, invert, matrix_to_pose  # noqa: E402
from hsmap.io import write_json  # noqa: E402
from hsmap.slam import SlamConfig, run_slam  # noqa: E402
from hsmap.trajectory import Trajectory  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
FREIBURG = {
    # published relations errors, mean translational (m) and rotational (deg): Kümmerle et al. 2009 (scan
    # matching, the baseline the issue names) and Hess et al. 2016 (Cartographer, 179 s wall for intel)
    "intel": {"bag": "intel/intel.orig.bag", "relations": "intel/intel.relations", "extrinsic2d": None,
              "published_scan_matching_m": 0.220, "cartographer_m": 0.0229},
    "fr079": {"bag": "fr079/fr079.orig.bag", "relations": "fr079/fr079.relations", "extrinsic2d": [-0.04, 0, 0],
              "published_scan_matching_m": 0.258, "cartographer_m": 0.0452},
}


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def bench_freiburg(name: str, datasets: Path, max_frames: int | None) -> dict:
    spec = FREIBURG[name]
    t0 = time.perf_counter()
    ds = open_dataset(datasets / "slam2d" / spec["bag"], extrinsic2d=spec["extrinsic2d"])
    frames = [f for k, f in zip(range(max_frames or len(ds)), ds.frames(clouds=False), strict=False)]
    read_s = time.perf_counter() - t0
    cfg = SlamConfig(dof=3, use_odometry=False)
    res = run_slam(frames, cfg, rng=1, progress=False)
    rel = read_relations(datasets / "slam2d" / spec["relations"])
    err = relations_error(res.trajectory, rel, skip_unmatched=max_frames is not None).as_dict()
    stamps = np.array([f.stamp for f in frames])
    duration = float(stamps.max() - stamps.min())
    m = res.metrics()
    out = {
        "frames": len(frames),
        "log_duration_s": duration,
        "read_seconds": read_s,
        "wall_seconds": res.seconds,
        "cpu_seconds": res.cpu_seconds,
        "real_time_factor": duration / res.seconds,
        "seconds_per_scan_median": m["seconds_per_frame_median"],
        "peak_memory_mb": peak_rss_mb(),
        "map_points": m["map_points"],
        "relations": err,
        "published": {k: v for k, v in spec.items() if k.endswith("_m")},
        "config": to_dict(cfg),
    }
    print(f"{name}: {len(frames)} scans, {res.seconds:.1f} s wall ({res.cpu_seconds:.1f} s CPU), "
          f"{out['real_time_factor']:.1f}x real time, relations {err['translation_m']['mean']:.4f} +/- "
          f"{err['translation_m']['std']:.4f} m, {err['rotation_deg']['mean']:.3f} +/- {err['rotation_deg']['std']:.3f}"
          f" deg (published scan matching {spec['published_scan_matching_m']} m)", flush=True)
    return out


def bench_3d(max_frames: int | None) -> dict:
    from kiss_icp.config import KISSConfig
    from kiss_icp.kiss_icp import KissICP

    from hsmap.study import simulated_dataset

    ds = open_dataset(simulated_dataset("slam-office", 1).path)
    n = min(len(ds), max_frames or len(ds))
    t0 = time.perf_counter()
    frames = [f for _, f in zip(range(n), ds.frames(clouds=True), strict=False)]
    read_s = time.perf_counter() - t0
    gt = Trajectory(ds.groundtruth.stamps[:n], ds.groundtruth.as_6dof().poses[:n])

    # HS-SLAM: the 2D run seeds the 6-DOF run, as in the paper
    run2d = run_slam(frames, SlamConfig(dof=3, use_odometry=False), rng=1, progress=False)
    cfg6 = SlamConfig(dof=6, use_odometry=False)
    run6 = run_slam(frames, cfg6, rng=1, prior=run2d.trajectory, progress=False)
    hs_times = np.array([f.seconds for f in run6.frames])

    # KISS-ICP on the same clouds (sensor frame), its own defaults for this range (voxel = max_range / 100), no
    # deskewing (the simulated clouds are instantaneous); poses of the sensor mapped to the robot base
    kcfg = KISSConfig()
    kcfg.data.max_range = cfg6.max_range
    kcfg.data.min_range = cfg6.min_range
    kcfg.data.deskew = False
    kcfg.mapping.voxel_size = kcfg.data.max_range / 100.0
    kiss = KissICP(kcfg)
    ext = frames[0].extrinsic3d
    k_times, k_poses = [], []
    for f in frames:
        pts = np.ascontiguousarray(f.cloud3d, dtype=np.float64)
        t1 = time.perf_counter()
        kiss.register_frame(pts, np.zeros(len(pts)))
        k_times.append(time.perf_counter() - t1)
        sensor = matrix_to_pose(np.asarray(kiss.last_pose))  # sensor pose in the first sensor frame
        k_poses.append(compose(compose(ext, sensor), invert(ext)))  # base pose in the first base frame
    kiss_traj = Trajectory(gt.stamps, np.asarray(k_poses))
    out = {
        "frames": n,
        "points_per_cloud_median": int(np.median([len(f.cloud3d) for f in frames])),
        "read_seconds": read_s,
        "hs_slam_6dof": {
            "seconds_per_cloud_median": float(np.median(hs_times)),
            "seconds_per_cloud_p95": float(np.percentile(hs_times, 95)),
            "wall_seconds": run6.seconds,
            "cpu_seconds": run6.cpu_seconds,
            "errors": pose_errors(run6.trajectory, gt).as_dict(),
            "config": to_dict(cfg6),
            "seeded_by_2d_run": True,
            "run_2d_wall_seconds": run2d.seconds,
            "errors_2d": pose_errors(run2d.trajectory, gt.as_3dof()).as_dict(),
        },
        "kiss_icp": {
            "version": __import__("kiss_icp").__version__,
            "seconds_per_cloud_median": float(np.median(k_times)),
            "seconds_per_cloud_p95": float(np.percentile(k_times, 95)),
            "wall_seconds": float(np.sum(k_times)),
            "errors": pose_errors(kiss_traj, gt).as_dict(),
            "config": {"max_range": kcfg.data.max_range, "min_range": kcfg.data.min_range, "deskew": False,
                       "voxel_size": kcfg.mapping.voxel_size},
        },
    }
    out["time_ratio_hs_over_kiss"] = (out["hs_slam_6dof"]["seconds_per_cloud_median"]
                                      / out["kiss_icp"]["seconds_per_cloud_median"])
    for name in ("hs_slam_6dof", "kiss_icp"):
        r = out[name]
        e = r["errors"]
        mx, fin = e["max_abs_error"], e["final_error"]
        print(f"3D {name}: {1000 * r['seconds_per_cloud_median']:.1f} ms per cloud (p95 "
              f"{1000 * r['seconds_per_cloud_p95']:.1f}), max error x {100 * mx['x_m']:.2f} cm, "
              f"y {100 * mx['y_m']:.2f} cm, z {100 * mx['z_m']:.2f} cm, roll {mx['roll_deg']:.3f}, pitch "
              f"{mx['pitch_deg']:.3f}, yaw {mx['yaw_deg']:.3f} deg; final {100 * fin['translation_m']:.2f} cm / "
              f"{fin['rotation_deg']:.3f} deg", flush=True)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="+", choices=["intel", "fr079", "3d"], default=["intel", "fr079", "3d"])
    ap.add_argument("--max-frames", type=int, default=None, help="cut every input (smoke runs)")
    ap.add_argument("--out", default=str(ROOT / "reports/benchmarks/slam.json"))
    args = ap.parse_args(argv)
    datasets = Path(os.environ.get("HSMAP_DATASETS", ROOT.parent / "shared/datasets"))
    out = {
        "benchmark": "slam",
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "python": sys.version.split()[0],
                    "load_average_at_start": os.getloadavg()},
        "hsmap_version": hsmap.__version__,
    }
    for name in args.only:
        if name == "3d":
            out["3d_slam_office"] = bench_3d(args.max_frames)
        elif (datasets / "slam2d").is_dir():
            out[name] = bench_freiburg(name, datasets, args.max_frames)
        else:
            out[name] = {"skipped": f"no Freiburg data at {datasets}/slam2d (set HSMAP_DATASETS)"}
            print(out[name]["skipped"])
    out["machine"]["load_average_at_end"] = os.getloadavg()
    write_json(args.out, out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
