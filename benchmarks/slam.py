"""SLAM benchmark: HS-SLAM on the Freiburg logs over several seeds and, in 3D, beside KISS-ICP on the simulated route.

1. ``intel``, ``fr079`` and ``fr-clinic`` (the ROS1 ``.orig.bag`` files of $HSMAP_DATASETS/slam2d): 2D HS-SLAM
   with the command line's default configuration (odometry from the bag, loop closure on) over the whole log, one
   run per seed (``--seeds``, default 1-5), the seeds a batch of the study's Dask runner (``--jobs`` worker
   processes, the runner of ``hsmap benchmark buildings``, each run on ``--threads`` compute threads, by default
   the cores shared among the jobs; each seed's record in ``reports/benchmarks/slam/runs/``). Per
   seed: the Freiburg relations error (mean and sample sd, translational and rotational; also for relations with
   dt <= 10 s and dt > 60 s), loops closed, frames retried, wall and CPU time, real-time factor (log duration /
   wall time), peak memory; and over the seeds the mean, sd and worst of the relations errors. fr079 states its
   laser offset as the command line would (``--extrinsic2d -0.04,0,0``: the CARMEN log's PARAM, which the
   relations agree with, instead of the bag's TF, +0.04 m). Published numbers beside them: Kuemmerle et al. 2009
   (scan matching) and Hess et al. 2016 (Cartographer).
2. ``slam-office`` (simulated, seed 1): 6-DOF HS-SLAM (seeded by the 2D run's poses, as in the paper) on the
   128 x 1024 clouds, time per cloud beside KISS-ICP (``kiss-icp`` on PyPI) on the same clouds, and both
   methods' errors against ground truth (per-DOF maximum over the route, each trajectory relative to its first
   pose, no alignment; and the final-pose error).

Times exclude reading the input (frames are loaded first). Writes reports/benchmarks/slam.json (atomically).

    .venv/bin/python benchmarks/slam.py [--only intel fr079 fr-clinic 3d] [--seeds 1 2 3 4 5] [--jobs 1] [--threads N]
        [--max-frames N] [--no-loop-closure]
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("RERUN_ANALYTICS", "0")

from _report import finish, machine  # noqa: E402  (benchmarks/_report.py)

import hsmap  # noqa: E402
from hsmap.config import to_dict  # noqa: E402
from hsmap.datasets.open import open_dataset  # noqa: E402
from hsmap.datasets.relations import read_relations  # noqa: E402
from hsmap.evaluation.trajectory import pose_errors, relations_error  # noqa: E402
from hsmap.geometry import compose, invert, matrix_to_pose  # noqa: E402
from hsmap.slam import SlamConfig, run_slam  # noqa: E402
from hsmap.trajectory import Trajectory, read_tum  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
FREIBURG = {
    # published relations errors, mean translational (m) and rotational (deg): Kuemmerle et al. 2009 (scan
    # matching) and Hess et al. 2016 (Cartographer; fr-clinic: the local relations)
    "intel": {"bag": "intel/intel.orig.bag", "relations": "intel/intel.relations", "extrinsic2d": None,
              "published_scan_matching_m": 0.220, "cartographer_m": 0.0229, "cartographer_deg": 0.453},
    "fr079": {"bag": "fr079/fr079.orig.bag", "relations": "fr079/fr079.relations", "extrinsic2d": [-0.04, 0, 0],
              "published_scan_matching_m": 0.258, "cartographer_m": 0.0452, "cartographer_deg": 0.538},
    "fr-clinic": {"bag": "fr-clinic/fr-clinic_robotlaser.orig.bag", "relations": "fr-clinic/fr-clinic.relations",
                  "extrinsic2d": None, "cartographer_m": 0.1078, "cartographer_deg": 0.747},
}


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _stats(e: np.ndarray) -> dict:
    return {"mean": float(e.mean()), "sd": float(e.std(ddof=1)) if e.size > 1 else 0.0, "n": int(e.size)}


def freiburg_frames(name: str, datasets: str | Path, max_frames: int | None = None) -> tuple[list, object, int]:
    """The first ``max_frames`` frames (every one: None) of the Freiburg log ``name`` (its scans only), its
    relations, and the log's number of frames."""
    spec = FREIBURG[name]
    ds = open_dataset(Path(datasets) / "slam2d" / spec["bag"], extrinsic2d=spec["extrinsic2d"])
    frames = [f for _, f in zip(range(max_frames or len(ds)), ds.frames(clouds=False), strict=False)]
    return frames, read_relations(Path(datasets) / "slam2d" / spec["relations"]), len(ds)


def freiburg_run(name: str, datasets: str, seed: int, max_frames: int | None, loop_closure: bool,
                 threads: int | None = None) -> dict:
    """One seed on one log, in its own process (see main), on ``threads`` compute threads (None: every core)."""
    spec = FREIBURG[name]
    t0 = time.perf_counter()
    ds = open_dataset(Path(datasets) / "slam2d" / spec["bag"], extrinsic2d=spec["extrinsic2d"])
    frames = [f for k, f in zip(range(max_frames or len(ds)), ds.frames(clouds=False), strict=False)]
    read_s = time.perf_counter() - t0
    cfg = SlamConfig(dof=3)  # the command line's default configuration
    cfg.loop_closure.enabled = loop_closure
    res = run_slam(frames, cfg, rng=seed, progress=False, threads=threads)
    rel = read_relations(Path(datasets) / "slam2d" / spec["relations"])
    stamps = np.array([f.stamp for f in frames])
    odometry = ds.odometry if max_frames is None else ds.odometry.head(max_frames)
    duration = float(stamps.max() - stamps.min())
    m = res.metrics()
    out = {
        "seed": seed,
        "threads": threads,
        "frames": len(frames),
        "log_duration_s": duration,
        "read_seconds": read_s,
        "wall_seconds": res.seconds,
        "cpu_seconds": res.cpu_seconds,
        "real_time_factor": duration / res.seconds,
        "seconds_per_scan_median": m["seconds_per_frame_median"],
        "peak_memory_mb": peak_rss_mb(),
        "map_points": m["map_points"],
        "keyframes": m["keyframes"],
        "loop_closure": m["loop_closure"],
        "loops_closed": m["loops_closed"],
        "pair_edges": m["pair_edges"],
        "loop_closure_detail": m["loop_closure_detail"],
        "frames_retried": m["frames_retried"],
        "odometry_model": m["odometry_model"],
        "relations": _relations(res.trajectory, rel, skip_unmatched=max_frames is not None),
        # the same run before the smoothing with the odometry (hsmap.slam.smoothing): the graph's trajectory
        "unsmoothed_relations": _relations(res.unsmoothed, rel, skip_unmatched=max_frames is not None)
        if res.unsmoothed is not None else None,
        "smoothing": m["smoothing"],
        # the raw wheel odometry, the same breakdown: what the scan matching adds
        "odometry_relations": _relations(odometry, rel, skip_unmatched=True) if odometry is not None else None,
        "config": to_dict(cfg),
    }
    r = out["relations"]
    print(f"{name} seed {seed}: {len(frames)} scans, {res.seconds:.1f} s wall ({res.cpu_seconds:.1f} s CPU), "
          f"{out['real_time_factor']:.1f}x real time, relations {r['all']['translation_m']['mean']:.4f} m / "
          f"{r['all']['rotation_deg']['mean']:.3f} deg (dt<=10 s {r['dt_le_10s']['translation_m']['mean']:.4f} m, "
          f"dt>60 s {r['dt_gt_60s']['translation_m']['mean']:.4f} m), loops {m['loops_closed']}, retried "
          f"{m['frames_retried']}" + (f"; before the smoothing {u['all']['translation_m']['mean']:.4f} m / "
                                       f"{u['all']['rotation_deg']['mean']:.3f} deg"
                                       if (u := out["unsmoothed_relations"]) else ""), flush=True)
    return out


def _relations(traj, rel, skip_unmatched: bool) -> dict:
    """The relations error of a trajectory, all and split by dt (<= 10 s, > 60 s), with its distance scale."""
    err = relations_error(traj, rel, skip_unmatched=skip_unmatched)
    dt = np.abs(rel.t_j - rel.t_i)[err.used]
    rot = np.degrees(err.rotation)
    scale = err.distance_scale(mask=dt <= 10)
    return {
        part: {"translation_m": _stats(err.translation[m]), "rotation_deg": _stats(rot[m])}
        for part, m in (("all", dt >= 0), ("dt_le_10s", dt <= 10), ("dt_gt_60s", dt > 60))
    } | {
        # > 1: the trajectory makes the relations' distances longer than they are (dt <= 10 s, 0.2 m or more)
        "distance_scale": float(scale) if np.isfinite(scale) else None,  # JSON has no NaN
    }


def summarise_seeds(runs: list[dict], spec: dict) -> dict:
    """Mean, sd and worst over the seeds of each relations error; the loop closure's targets."""
    out = {}
    for part in ("all", "dt_le_10s", "dt_gt_60s"):
        for q in ("translation_m", "rotation_deg"):
            v = np.array([r["relations"][part][q]["mean"] for r in runs])
            out[f"{part}.{q}"] = {"mean": float(v.mean()), "sd": float(v.std(ddof=1)) if v.size > 1 else 0.0,
                                  "worst": float(v.max())}
    for q in ("real_time_factor", "wall_seconds", "cpu_seconds", "peak_memory_mb", "loops_closed", "pair_edges",
              "frames_retried"):
        v = np.array([r[q] for r in runs], dtype=float)
        out[q] = {"mean": float(v.mean()), "min": float(v.min()), "max": float(v.max())}
    v = np.array([r["relations"]["distance_scale"] for r in runs if r["relations"]["distance_scale"] is not None])
    out["distance_scale"] = ({"mean": float(v.mean()), "min": float(v.min()), "max": float(v.max())} if v.size
                             else {"mean": None, "min": None, "max": None})
    out["odometry_relations"] = runs[0].get("odometry_relations")  # the same log, the same odometry every seed
    if all(r.get("unsmoothed_relations") for r in runs):  # the same runs before the smoothing, side by side
        for part in ("all", "dt_le_10s", "dt_gt_60s"):
            for q in ("translation_m", "rotation_deg"):
                v = np.array([r["unsmoothed_relations"][part][q]["mean"] for r in runs])
                out[f"unsmoothed.{part}.{q}"] = {"mean": float(v.mean()),
                                                 "sd": float(v.std(ddof=1)) if v.size > 1 else 0.0,
                                                 "worst": float(v.max())}
    t = out["all.translation_m"]
    car_m, car_deg = spec.get("cartographer_m"), spec.get("cartographer_deg")
    out["targets"] = {
        "mean_below_cartographer_m": bool(t["mean"] < car_m),
        "no_seed_above_1.5x_cartographer_m": bool(t["worst"] <= 1.5 * car_m),
        "rotation_below_cartographer_deg": bool(out["all.rotation_deg"]["mean"] < car_deg),
        "long_at_most_twice_short": bool(out["dt_gt_60s.translation_m"]["mean"]
                                         <= 2 * out["dt_le_10s.translation_m"]["mean"]),
        "at_least_15x_real_time": bool(out["real_time_factor"]["min"] >= 15),
    }
    return out


def _freiburg_job(*, name: str, datasets: str, seed: int, max_frames: int | None, loop_closure: bool,
                  threads: int | None = None) -> dict:
    return freiburg_run(name, datasets, seed, max_frames, loop_closure, threads)


def run_fresh(batch: list, runs_dir: Path, jobs: int, label: str, unit: str) -> list[dict]:
    """A batch of :class:`hsmap.study.distributed.Job` on the study's Dask runner, ``jobs`` worker processes, every
    run fresh (a benchmark measures this code, so finished runs are not read back); each run's record, without the
    runner's own fields. Raises HsmapError (``LABEL`` N of M ``UNIT`` failed) naming the first failure."""
    from hsmap.errors import HsmapError
    from hsmap.study.distributed import run_jobs

    records = run_jobs(batch, runs_dir, workers=jobs, retries=0, skip_finished=False, progress=False)
    failed = [r for r in records if r["status"] != "ok"]
    if failed:
        raise HsmapError(f"{label}{len(failed)} of {len(records)} {unit} failed; first: {failed[0]['error']}")
    return [{k: v for k, v in r.items() if k not in ("name", "status", "skipped", "finished")} for r in records]


def bench_freiburg(name: str, datasets: Path, seeds: list[int], max_frames: int | None, jobs: int,
                   loop_closure: bool, runs_dir: Path, threads: int | None = None) -> dict:
    """The seeds of one log as a batch of the study's Dask runner (:func:`hsmap.study.distributed.run_jobs`, the
    runner of ``hsmap benchmark buildings``): one job per seed on ``jobs`` worker processes, each seed's record
    written atomically into ``runs_dir/NAME-seedS/result.json`` as it finishes; every run is fresh (a benchmark
    measures this code, so finished seeds are not read back). ``peak_memory_mb`` is the peak of the worker process
    that ran the seed (the runs of one log are alike)."""
    from hsmap.study.distributed import Job

    spec = FREIBURG[name]
    batch = [Job(f"{name}-seed{s}", [("slam", _freiburg_job)],
                 {"name": name, "datasets": str(datasets), "seed": s, "max_frames": max_frames,
                  "loop_closure": loop_closure, "threads": threads}) for s in seeds]
    runs = run_fresh(batch, runs_dir, jobs, f"{name}: ", "seeds")
    summary = summarise_seeds(runs, spec)
    t, r = summary["all.translation_m"], summary["all.rotation_deg"]
    print(f"{name} over seeds {seeds}: {t['mean']:.4f} +/- {t['sd']:.4f} m (worst {t['worst']:.4f}), "
          f"{r['mean']:.3f} deg; Cartographer {spec['cartographer_m']} m / {spec['cartographer_deg']} deg; "
          f"targets {summary['targets']}", flush=True)
    return {"seeds": runs, "summary": summary, "published": {k: v for k, v in spec.items() if "_m" in k or "_deg" in k},
            "extrinsic2d": spec["extrinsic2d"], "loop_closure": loop_closure, "jobs": jobs, "threads": threads}


def bench_3d(max_frames: int | None, folder: str | None = None) -> dict:
    from kiss_icp.config import KISSConfig
    from kiss_icp.kiss_icp import KissICP

    from hsmap.study import simulated_dataset

    ds = open_dataset(folder or simulated_dataset("slam-office", 1).path)
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
    k_cpu0 = time.process_time()
    for f in frames:
        pts = np.ascontiguousarray(f.cloud3d, dtype=np.float64)
        t1 = time.perf_counter()
        kiss.register_frame(pts, np.zeros(len(pts)))
        k_times.append(time.perf_counter() - t1)
        sensor = matrix_to_pose(np.asarray(kiss.last_pose))  # sensor pose in the first sensor frame
        k_poses.append(compose(compose(ext, sensor), invert(ext)))  # base pose in the first base frame
    k_cpu = time.process_time() - k_cpu0  # all of KISS-ICP's threads (and the pose conversions, tiny)
    kiss_traj = Trajectory(gt.stamps, np.asarray(k_poses))
    out = {
        "frames": n,
        "points_per_cloud_median": int(np.median([len(f.cloud3d) for f in frames])),
        "read_seconds": read_s,
        "hs_slam_6dof": {
            "seconds_per_cloud_median": float(np.median(hs_times)),
            "seconds_per_cloud_mean": float(np.mean(hs_times)),
            "seconds_per_cloud_p95": float(np.percentile(hs_times, 95)),
            "keyframes": int(sum(f.keyframe for f in run6.frames)),
            "wall_seconds": run6.seconds,
            "cpu_seconds": run6.cpu_seconds,
            "cpu_seconds_per_cloud_mean": run6.cpu_seconds / n,
            "errors": pose_errors(run6.trajectory, gt).as_dict(),
            "config": to_dict(cfg6),
            "seeded_by_2d_run": True,
            "run_2d_wall_seconds": run2d.seconds,
            "errors_2d": pose_errors(run2d.trajectory, gt.as_3dof()).as_dict(),
        },
        "kiss_icp": {
            "version": __import__("kiss_icp").__version__,
            "seconds_per_cloud_median": float(np.median(k_times)),
            "seconds_per_cloud_mean": float(np.mean(k_times)),
            "seconds_per_cloud_p95": float(np.percentile(k_times, 95)),
            "wall_seconds": float(np.sum(k_times)),
            "cpu_seconds_per_cloud_mean": k_cpu / n,
            "errors": pose_errors(kiss_traj, gt).as_dict(),
            "config": {"max_range": kcfg.data.max_range, "min_range": kcfg.data.min_range, "deskew": False,
                       "voxel_size": kcfg.mapping.voxel_size},
        },
    }
    out["time_ratio_hs_over_kiss"] = (out["hs_slam_6dof"]["seconds_per_cloud_median"]
                                      / out["kiss_icp"]["seconds_per_cloud_median"])
    out["mean_time_ratio_hs_over_kiss"] = (out["hs_slam_6dof"]["seconds_per_cloud_mean"]
                                           / out["kiss_icp"]["seconds_per_cloud_mean"])
    # CPU time (all threads) per cloud: the work done, less sensitive to a busy machine than wall times
    out["cpu_ratio_hs_over_kiss"] = (out["hs_slam_6dof"]["cpu_seconds_per_cloud_mean"]
                                     / out["kiss_icp"]["cpu_seconds_per_cloud_mean"])
    for name in ("hs_slam_6dof", "kiss_icp"):
        r = out[name]
        e = r["errors"]
        mx, fin = e["max_abs_error"], e["final_error"]
        print(f"3D {name}: {1000 * r['seconds_per_cloud_median']:.1f} ms per cloud (mean "
              f"{1000 * r['seconds_per_cloud_mean']:.1f}, p95 "
              f"{1000 * r['seconds_per_cloud_p95']:.1f}), max error x {100 * mx['x_m']:.2f} cm, "
              f"y {100 * mx['y_m']:.2f} cm, z {100 * mx['z_m']:.2f} cm, roll {mx['roll_deg']:.3f}, pitch "
              f"{mx['pitch_deg']:.3f}, yaw {mx['yaw_deg']:.3f} deg; final {100 * fin['translation_m']:.2f} cm / "
              f"{fin['rotation_deg']:.3f} deg", flush=True)
    return out


TABLE1_BOUNDS = {"x_m": 0.03, "y_m": 0.05, "z_m": 0.01, "roll_deg": 0.2, "pitch_deg": 0.2, "yaw_deg": 1.5}


def _max_errors(traj: Trajectory, gt: Trajectory) -> dict:
    e = pose_errors(traj, gt).as_dict()
    mx = e["max_abs_error"]
    return {"max_abs_error": mx, "final_error": e["final_error"],
            "within_table1": all(mx[k] <= b for k, b in TABLE1_BOUNDS.items()),
            "over_table1": {k: mx[k] / b for k, b in TABLE1_BOUNDS.items() if mx[k] > b}}


def bench_3d_rolling_seed(seed: int, max_frames: int | None, root: str, kiss: bool = True) -> dict:
    """slam-office-rolling (rolling 0.1 s sweeps, a swaying mast, 1 m/s, 60 deg/s), one seed: 6-DOF HS-SLAM
    seeded by its 2D run with and without deskewing, and KISS-ICP (default configuration, its deskewing on, given
    the per-point times); per-DOF maximum errors against the base's ground truth and (``vs_mast``) against the
    swaying mast's (``groundtruth3d.tum``: the pose the 3D LiDAR really had, through its extrinsic), and time per
    cloud. ``kiss``: False leaves KISS-ICP out."""
    from kiss_icp.config import KISSConfig
    from kiss_icp.kiss_icp import KissICP

    from hsmap.sim.robot import sample_legs
    from hsmap.sim.scenario import load_scenario
    from hsmap.sim.writer import motion_for
    from hsmap.study import simulated_dataset

    ds = simulated_dataset("slam-office-rolling", seed, max_frames=max_frames, root=root)
    n = min(len(ds), max_frames or len(ds))
    frames = [f for _, f in zip(range(n), ds.frames(clouds=True), strict=False)]
    gt = Trajectory(ds.groundtruth.stamps[:n], ds.groundtruth.as_6dof().poses[:n])
    mast = read_tum(ds.root / "groundtruth3d.tum", dof=6)
    gt_mast = Trajectory(mast.stamps[:n], mast.poses[:n])
    out: dict = {"seed": seed, "frames": n, "points_per_cloud_median": int(np.median([len(f.cloud3d) for f in frames]))}
    run2d = run_slam(frames, SlamConfig(dof=3, use_odometry=False), rng=seed, progress=False)
    out["hs_slam_2d"] = {"errors": pose_errors(run2d.trajectory, gt.as_3dof()).as_dict()["max_abs_error"]}
    for deskew in (True, False):
        cfg6 = SlamConfig(dof=6, use_odometry=False, deskew=deskew)
        run6 = run_slam(frames, cfg6, rng=seed, prior=run2d.trajectory, progress=False)
        t = np.array([f.seconds for f in run6.frames])
        out["hs_slam_6dof" + ("" if deskew else "_no_deskew")] = {
            "seconds_per_cloud_median": float(np.median(t)), "cpu_seconds_per_cloud_mean": run6.cpu_seconds / n,
            **_max_errors(run6.trajectory, gt), "vs_mast": _max_errors(run6.trajectory, gt_mast)}
    if kiss:
        # KISS-ICP deskews every cloud to its last point's time with the last frame-to-frame motion spread over the
        # sweep; its poses are compared with the ground truth at that time
        kcfg = KISSConfig()
        kcfg.data.max_range, kcfg.data.min_range, kcfg.data.deskew = 30.0, 0.1, True
        kcfg.mapping.voxel_size = kcfg.data.max_range / 100.0
        kicp = KissICP(kcfg)
        ext = frames[0].extrinsic3d
        k_times, k_poses, k_end = [], [], []
        c0 = time.process_time()
        for f in frames:
            pts = np.ascontiguousarray(f.cloud3d, dtype=np.float64)
            ts = np.asarray(f.point_times, dtype=np.float64)
            t1 = time.perf_counter()
            kicp.register_frame(pts, ts)
            k_times.append(time.perf_counter() - t1)
            k_poses.append(compose(compose(ext, matrix_to_pose(np.asarray(kicp.last_pose))), invert(ext)))
            k_end.append(f.stamp + float(ts.max()))
        k_cpu = time.process_time() - c0
        m = motion_for(load_scenario(ds.scenario_path()), seed)
        end = sample_legs(m.legs, np.asarray(k_end))
        gt_end = np.zeros((n, 6))
        gt_end[:, :2], gt_end[:, 5] = end[:, :2], end[:, 2]
        out["kiss_icp"] = {"version": __import__("kiss_icp").__version__,
                           "seconds_per_cloud_median": float(np.median(k_times)), "cpu_seconds_per_cloud_mean": k_cpu / n,
                           "config": {"max_range": 30.0, "min_range": 0.1, "deskew": True,
                                      "voxel_size": kcfg.mapping.voxel_size},
                           "compared_at": "each sweep's last point time (where KISS-ICP deskews to)",
                           **_max_errors(Trajectory(np.asarray(k_end), k_poses), Trajectory(np.asarray(k_end), gt_end))}
    for name in [k for k in ("hs_slam_6dof", "hs_slam_6dof_no_deskew", "kiss_icp") if k in out]:
        mx = out[name]["max_abs_error"]
        print(f"rolling seed {seed} {name}: {1000 * out[name]['seconds_per_cloud_median']:.0f} ms/cloud, max x "
              f"{100 * mx['x_m']:.2f} y {100 * mx['y_m']:.2f} z {100 * mx['z_m']:.2f} cm, roll {mx['roll_deg']:.3f} "
              f"pitch {mx['pitch_deg']:.3f} yaw {mx['yaw_deg']:.3f} deg; Table 1: {out[name]['within_table1']}",
              flush=True)
        if "vs_mast" in out[name]:
            mm = out[name]["vs_mast"]["max_abs_error"]
            print(f"  against the mast's truth: max x {100 * mm['x_m']:.2f} y {100 * mm['y_m']:.2f} z "
                  f"{100 * mm['z_m']:.2f} cm, roll {mm['roll_deg']:.3f} pitch {mm['pitch_deg']:.3f} yaw "
                  f"{mm['yaw_deg']:.3f} deg; Table 1: {out[name]['vs_mast']['within_table1']}", flush=True)
    return out


def bench_3d_rolling(seeds: list[int], max_frames: int | None, root: str, kiss: bool = True) -> dict:
    runs = [bench_3d_rolling_seed(s, max_frames, root, kiss) for s in seeds]
    summary = {}
    for name in [k for k in ("hs_slam_6dof", "hs_slam_6dof_no_deskew", "kiss_icp") if k in runs[0]]:
        mx = {k: [r[name]["max_abs_error"][k] for r in runs] for k in TABLE1_BOUNDS}
        summary[name] = {"worst_max_abs_error": {k: float(max(v)) for k, v in mx.items()},
                         "mean_max_abs_error": {k: float(np.mean(v)) for k, v in mx.items()},
                         "seeds_within_table1": sum(r[name]["within_table1"] for r in runs),
                         "seconds_per_cloud_median": float(np.median([r[name]["seconds_per_cloud_median"]
                                                                      for r in runs]))}
        if "vs_mast" in runs[0][name]:
            mm = {k: [r[name]["vs_mast"]["max_abs_error"][k] for r in runs] for k in TABLE1_BOUNDS}
            summary[name]["vs_mast"] = {"worst_max_abs_error": {k: float(max(v)) for k, v in mm.items()},
                                        "mean_max_abs_error": {k: float(np.mean(v)) for k, v in mm.items()},
                                        "seeds_within_table1": sum(r[name]["vs_mast"]["within_table1"] for r in runs)}
    return {"scenario": "slam-office-rolling", "table1_bounds": TABLE1_BOUNDS, "seeds": runs, "summary": summary}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="+", choices=[*FREIBURG, "3d", "3d-static", "3d-rolling"],
                    default=[*FREIBURG, "3d"])
    ap.add_argument("--rolling-seeds", nargs="+", type=int, default=[1, 2, 3],
                    help="3d: seeds of the rolling-sweep route (slam-office-rolling)")
    ap.add_argument("--no-kiss-icp", action="store_true", help="3d-rolling: HS-SLAM only (KISS-ICP left out)")
    ap.add_argument("--generated", default=None,
                    help="3d: where the rolling-sweep datasets are simulated (default the study's data/generated)")
    ap.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3, 4, 5])
    ap.add_argument("--jobs", type=int, default=1, help="runs at once (1: times free of each other's load)")
    ap.add_argument("--threads", type=int, default=None,
                    help="compute threads per run (default: the cores shared among the jobs, at least 1); the "
                         "result is the same for any count, the time is not")
    ap.add_argument("--max-frames", type=int, default=None, help="cut every input (smoke runs)")
    ap.add_argument("--no-loop-closure", action="store_true", help="tracking only, for comparison")
    ap.add_argument("--dataset3d", default=None,
                    help="3d: this simulator folder instead of the study's slam-office seed 1 (a copy of it: the "
                         "study's cache simulates it anew after every code change)")
    ap.add_argument("--out", default=str(ROOT / "reports/benchmarks/slam.json"))
    args = ap.parse_args(argv)
    if args.jobs < 1 or (args.threads is not None and args.threads < 1):
        ap.error("--jobs and --threads must be >= 1")
    threads = args.threads or max(1, (os.cpu_count() or 1) // args.jobs)
    from hsmap.study.paths import datasets_dir

    datasets = datasets_dir()  # $HSMAP_DATASETS, else what hsmap data fetch downloaded, else ../shared/datasets
    out = {
        "benchmark": "slam",
        "machine": machine(),
        "hsmap_version": hsmap.__version__,
    }
    for name in args.only:
        if name.startswith("3d"):
            if name in ("3d", "3d-static"):
                out["3d_slam_office"] = bench_3d(args.max_frames, args.dataset3d)
            if name in ("3d", "3d-rolling"):
                out["3d_slam_office_rolling"] = bench_3d_rolling(args.rolling_seeds, args.max_frames, args.generated,
                                                                   not args.no_kiss_icp)
        elif (datasets / "slam2d").is_dir():
            out[name] = bench_freiburg(name, datasets, args.seeds, args.max_frames, args.jobs,
                                       not args.no_loop_closure, Path(args.out).with_suffix("") / "runs", threads)
        else:
            out[name] = {"skipped": f"no Freiburg data at {datasets}/slam2d (run hsmap data fetch, or set HSMAP_DATASETS)"}
            print(out[name]["skipped"])
    finish(out, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
