"""2D HS-SLAM on simulated runs through the fifteen Bormann floor plans: how it generalises to buildings nobody
tuned for, with the ground truth known.

For each floor plan of $HSMAP_DATASETS/ipa_room_segmentation and each simulator seed (``--sim-seeds``, default
0 1 2): the exploring run of ``hsmap benchmark buildings`` (:func:`hsmap.sim.building.simulate_building`: the
route through every reachable room, the 2D LiDAR, drifting wheel odometry; the seed draws the furniture, the
odometry's slip and the range noise), simulated into a temporary folder, then 2D HS-SLAM with the command line's
default configuration (odometry and loop closure on) and ``--slam-seed``. The 3D LiDAR is not used here, so the
simulation casts a minimal one (4 x 64 beams) to stay fast.

``--laser`` picks the robot's 2D laser: ``default`` is the simulator's (270 deg, 0.25 deg beams, 10 m), ``sparse``
another robot's, of the SICK LMS-200 class that Freiburg's intel and fr-clinic robots carried (180 deg, 1 deg
beams, 30 m, 1 cm noise): a quarter of the angular resolution (181 beams against 1081) and two thirds of the
field of view, with the SLAM configuration unchanged.

Per run: the largest and mean 2D position error and the largest yaw error along the route (the estimate and the
ground truth each relative to their first pose, no alignment), the final position error, the raw odometry's
largest error, loops closed, frames retried, frames, route length and SLAM time. Over all runs: the mean, median
and worst of the largest errors, and how many runs end up more than 0.1 m and 0.3 m off at their worst. One job
per building and seed on the study's Dask runner (``--jobs`` worker processes). Writes
reports/benchmarks/slam_buildings.json (atomically).

    .venv/bin/python benchmarks/slam_buildings.py [--only NAME ...] [--sim-seeds 0 1 2] [--slam-seed 1]
        [--jobs 2] [--maps DIR] [--laser default|sparse]
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

import hsmap  # noqa: E402

#: The 2D lasers a run can carry (``--laser``): keyword arguments of :class:`hsmap.sim.sensors.Lidar2DConfig`.
LASERS = {
    "default": {},
    "sparse": {"angle_min_deg": -90.0, "angle_max_deg": 90.0, "angle_increment_deg": 1.0, "range_max": 30.0,
               "noise_sigma": 0.01},
}

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from _report import finish, machine  # noqa: E402
from slam import run_fresh  # noqa: E402  (the Freiburg benchmark's batch runner)


def floor_plan_names(maps: Path) -> list[str]:
    """The buildings of a Bormann-style folder: every ``NAME.png`` with its furnished and ground-truth images."""
    suffixes = ("_furnitures", "_gt_segmentation")
    return sorted(p.stem for p in maps.glob("*.png")
                  if not p.stem.endswith(suffixes) and all((maps / f"{p.stem}{s}.png").is_file() for s in suffixes))


def building_run(*, name: str, maps: str, sim_seed: int, slam_seed: int, threads: int | None = None,
                 laser: str = "default") -> dict:
    """Simulate one building's exploring run and score 2D HS-SLAM on it (see the module docstring)."""
    from hsmap.datasets.simulated import SimulatedDataset
    from hsmap.evaluation import pose_errors
    from hsmap.sim.building import BuildingRunConfig, simulate_building
    from hsmap.sim.floorplan import read_floor_plan
    from hsmap.sim.sensors import Lidar2DConfig, Lidar3DConfig
    from hsmap.slam import SlamConfig, run_slam

    config = BuildingRunConfig()
    config.lidar3d = Lidar3DConfig(channels=4, columns=64)  # not used: 2D SLAM only
    config.lidar2d = Lidar2DConfig(**LASERS[laser])
    with tempfile.TemporaryDirectory(prefix=f"hsmap-{name}-") as tmp:
        t = time.perf_counter()
        simulate_building(read_floor_plan(maps, name=name), Path(tmp) / "data", seed=sim_seed, config=config)
        simulate_s = time.perf_counter() - t
        ds = SimulatedDataset(Path(tmp) / "data")
        frames = list(ds.frames(clouds=False))
        truth, odometry = ds.trajectory("groundtruth"), ds.trajectory("odometry")
    res = run_slam(frames, SlamConfig(dof=3), rng=slam_seed, progress=False, threads=threads)
    est = pose_errors(res.trajectory, truth)
    xy = np.hypot(est.errors[:, 0], est.errors[:, 1])
    odo = pose_errors(odometry, truth)
    # the same run before the smoothing with the odometry (hsmap.slam.smoothing): the graph's trajectory
    raw = pose_errors(res.unsmoothed, truth) if res.unsmoothed is not None else est
    xy_raw = np.hypot(raw.errors[:, 0], raw.errors[:, 1])
    m = res.metrics()
    return {"building": name, "sim_seed": sim_seed, "slam_seed": slam_seed, "laser": laser, "frames": len(frames),
            "route_m": round(float(truth.path_length()), 2),
            "max_error_m": float(xy.max()), "mean_error_m": float(xy.mean()),
            "unsmoothed_max_error_m": float(xy_raw.max()), "unsmoothed_mean_error_m": float(xy_raw.mean()),
            "smoothing": m["smoothing"],
            "max_yaw_error_deg": float(np.degrees(np.abs(est.errors[:, 2]).max())),
            "final_error_m": float(est.final_translation),
            "odometry_max_error_m": float(np.hypot(odo.errors[:, 0], odo.errors[:, 1]).max()),
            "loops_closed": m["loops_closed"], "frames_retried": m["frames_retried"],
            "loop_closure": m["loop_closure"], "simulate_seconds": round(simulate_s, 2),
            "slam_seconds": round(res.seconds, 2)}


def summarise(runs: list[dict]) -> dict:
    worst = np.array([r["max_error_m"] for r in runs])
    i = int(worst.argmax())
    return {"runs": len(runs), "max_error_m": {"mean": float(worst.mean()), "median": float(np.median(worst)),
                                               "worst": float(worst[i]),
                                               "worst_run": f"{runs[i]['building']} seed {runs[i]['sim_seed']}"},
            "mean_error_m": float(np.mean([r["mean_error_m"] for r in runs])),
            "runs_above_0.1_m": int((worst > 0.1).sum()), "runs_above_0.3_m": int((worst > 0.3).sum()),
            **({"unsmoothed": {"max_error_m_mean": float(np.mean([r["unsmoothed_max_error_m"] for r in runs])),
                               "max_error_m_median": float(np.median([r["unsmoothed_max_error_m"] for r in runs])),
                               "max_error_m_worst": float(np.max([r["unsmoothed_max_error_m"] for r in runs])),
                               "mean_error_m": float(np.mean([r["unsmoothed_mean_error_m"] for r in runs]))}}
               if all("unsmoothed_max_error_m" in r for r in runs) else {})}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="+", default=None, metavar="NAME", help="these buildings (default: all)")
    ap.add_argument("--sim-seeds", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument("--slam-seed", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=2, help="runs at once")
    ap.add_argument("--maps", default=None, help="a Bormann-style folder (default $HSMAP_DATASETS/ipa_room_segmentation)")
    ap.add_argument("--laser", choices=sorted(LASERS), default="default",
                    help="the robot's 2D laser (default: the simulator's; sparse: 180 deg, 1 deg beams, 30 m)")
    ap.add_argument("--out", default=None,
                    help="default reports/benchmarks/slam_buildings.json (slam_buildings_sparse.json with --laser sparse)")
    args = ap.parse_args(argv)
    if args.out is None:
        suffix = "" if args.laser == "default" else f"_{args.laser}"
        args.out = str(ROOT / f"reports/benchmarks/slam_buildings{suffix}.json")
    if args.jobs < 1:
        ap.error("--jobs must be >= 1")
    from hsmap.study.distributed import Job
    from hsmap.study.paths import datasets_dir

    maps = Path(args.maps) if args.maps else datasets_dir() / "ipa_room_segmentation"
    out = {"benchmark": "slam_buildings",
           "machine": machine(),
           "hsmap_version": hsmap.__version__, "maps": str(maps), "laser": {"name": args.laser, **LASERS[args.laser]}}
    names = floor_plan_names(maps) if maps.is_dir() else []
    if args.only:
        unknown = sorted(set(args.only) - set(names))
        if unknown:
            ap.error(f"--only: no floor plan {', '.join(unknown)} in {maps} (have: {', '.join(names) or 'none'})")
        names = [n for n in names if n in args.only]
    if not names:
        out["skipped"] = f"no floor plans at {maps} (run hsmap data fetch, or set HSMAP_DATASETS)"
        print(out["skipped"])
    else:
        threads = max(1, (os.cpu_count() or 1) // args.jobs)
        batch = [Job(f"{n}-sim{s}", [("run", building_run)],
                     {"name": n, "maps": str(maps), "sim_seed": s, "slam_seed": args.slam_seed, "threads": threads,
                      "laser": args.laser})
                 for s in args.sim_seeds for n in names]
        runs_dir = Path(args.out).with_suffix("") / "runs"
        runs = run_fresh(batch, runs_dir, args.jobs, "", "runs")
        for r in runs:
            print(f"{r['building']:16s} sim seed {r['sim_seed']}: max {r['max_error_m']:.3f} m, mean "
                  f"{r['mean_error_m']:.3f} m, yaw {r['max_yaw_error_deg']:.2f} deg (odometry {r['odometry_max_error_m']:.2f} m)"
                  f", {r['route_m']:.0f} m route, {r['loops_closed']} loops, {r['frames_retried']} retried", flush=True)
        out["runs"], out["summary"] = runs, summarise(runs)
        s = out["summary"]
        print(f"{s['runs']} runs: largest error mean {s['max_error_m']['mean']:.3f} m, median "
              f"{s['max_error_m']['median']:.3f}, worst {s['max_error_m']['worst']:.3f} ({s['max_error_m']['worst_run']}); "
              f"{s['runs_above_0.1_m']} above 0.1 m, {s['runs_above_0.3_m']} above 0.3 m")
    finish(out, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
