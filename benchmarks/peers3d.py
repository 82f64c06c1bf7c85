"""Same-run 3D peers on real sweeps: HS-SLAM 6-DOF, KISS-ICP, GenZ-ICP and small_gicp on the BALM benchmark's 177
real 64-beam sweeps of an indoor hall ($HSMAP_DATASETS/balm, its README), scored the same way.

The sweeps are read by hsmap's cloud reader from a scratch folder (:func:`hsmap.study.real_sweeps.sweep_folder`:
links ``000.pcd`` .. to ``full0.pcd`` .. in their natural order and a ``times.txt`` of the reference stamps), so that
every method gets the same points. Each runs once per setting:

- ``hs_slam_6dof``: ``hsmap slam FOLDER --dof 6 --seed S`` (the command line's default configuration), for each
  ``--seeds``: mean, spread and worst over the seeds beside each seed's row;
- the peers and their settings of :mod:`hsmap.study.peers3d` (its docstring says where each setting comes from):
  KISS-ICP's defaults and Ouster's KISS-ICP settings (ouster-sdk ``KissBackend``: max_range 150 m, min_range 1 m,
  voxel from the first sweep's ranges); GenZ-ICP's defaults (= its ``pretuned/indoor.yaml``) and its
  ``pretuned/newer_college.yaml`` (handheld Ouster OS1-64); small_gicp's scan-to-scan GICP (its defaults: 0.25 m,
  one thread) and scan-to-model VGICP (its ``kitti_odometry.py -m``: GaussianVoxelMap 1 m, LRU 100/10, every core);
  deskewing off everywhere (no per-point time).

Scores (:func:`hsmap.study.real_sweeps.score_track`): ATE RMSE and maximum after an SE(3) Umeyama alignment,
per-DOF errors (aligned, and relative to the first sweep as the paper's Table 1), lost track (the first sweep more
than 1 m off, both trajectories relative to their first sweep), the worst sweep-to-sweep error; times: wall seconds
per sweep (median) and CPU seconds per sweep (the whole run's process CPU over the sweeps, every thread; HS-SLAM's
with its helper process). Reading the sweeps is not counted. A peer that is not installed or fails is reported with
``status`` and ``reason``, never dropped. Writes reports/benchmarks/peers3d.json (atomically, after each run).

    .venv/bin/python benchmarks/peers3d.py [--seeds 0,1,2] [--max-sweeps N] [--only hs_slam_6dof kiss_icp genz_icp
        small_gicp] [--settings defaults ouster] [--dataset DIR]
        [--scratch DIR]
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
from hsmap.io import write_json  # noqa: E402

METHODS = ("hs_slam_6dof", "kiss_icp", "genz_icp", "small_gicp")


def not_available(reason: str, status: str = "not installed") -> dict:
    """An entry for a run that did not happen: ``status`` and one line of ``reason``."""
    return {"status": status, "reason": reason}


def guarded(fn, *args, **kw) -> dict:
    """``fn(*args, **kw)``, or an entry saying why not: "not installed" (a missing module) or "failed" (the
    exception's first line)."""
    import traceback

    try:
        return fn(*args, **kw)
    except ModuleNotFoundError as e:
        return not_available(f"{e.name} is not importable: {e}")
    except Exception as e:  # a peer's failure is a result, reported beside the others
        traceback.print_exc()
        return not_available(f"{type(e).__name__}: {e}".splitlines()[0], status="failed")


def _trajectory_rows(stamps, poses) -> list:
    return [[float(t), *map(float, p)] for t, p in zip(stamps, poses, strict=True)]


def entry(score, timing: dict, settings: dict, trajectory) -> dict:
    """One run's JSON entry: status, scores, times, settings, and its trajectory (stamp, x, y, z, roll, pitch,
    yaw)."""
    return {"status": "ok", **score.as_dict(), **timing, "settings": settings,
            "trajectory": _trajectory_rows(trajectory.stamps, trajectory.poses)}


def run_peer_entry(peer: str, setting: str, sweeps, stamps, ref) -> dict:
    from hsmap.geometry import matrix_to_pose
    from hsmap.study.peers3d import run_peer
    from hsmap.study.real_sweeps import score_track
    from hsmap.trajectory import Trajectory

    r = run_peer(peer, setting, sweeps)
    traj = Trajectory(stamps[:len(r.poses)], matrix_to_pose(r.poses))
    return entry(score_track(traj, ref), r.timing(), r.settings, traj)


def run_hs_entry(folder: Path, seed: int, ref) -> dict:
    from hsmap.study.real_sweeps import run_hs_slam, score_track

    r = run_hs_slam(folder, seed=seed)
    m = r.metrics
    keep = ("keyframes", "loops_closed", "frames_retried", "frames_unverified", "skipped_frames",
            "inlier_ratio_median")
    return {**entry(score_track(r.trajectory, ref), r.timing(), {"seed": seed, "version": hsmap.__version__,
                                                                  "config": "SlamConfig(dof=6), the command line's"},
                    r.trajectory),
            "run": {k: m.get(k) for k in keep}}


def seed_summary(rows: dict) -> dict:
    """Mean, spread (max - min) and worst over the seeds of the ok rows' ATE RMSE, maximum error and lost sweep."""
    ok = [r for r in rows.values() if r.get("status") == "ok"]
    if not ok:
        return {"seeds_ok": 0}
    out: dict = {"seeds_ok": len(ok), "seeds": len(rows)}
    for k in ("ate_rmse_m", "ate_max_m", "cpu_per_sweep_mean_s", "wall_per_sweep_median_s"):
        v = np.array([r[k] for r in ok])
        out[k] = {"mean": float(v.mean()), "spread": float(v.max() - v.min()), "worst": float(v.max())}
    lost = [r["lost_track_from_sweep"] for r in ok]
    out["lost_track_runs"] = sum(v is not None for v in lost)
    out["lost_track_earliest_sweep"] = min((v for v in lost if v is not None), default=None)
    return out


def table(out: dict) -> str:
    """The results as a Markdown table (one row per run)."""
    lines = ["| method | setting | ATE RMSE (m) | max (m) | max roll/pitch/yaw from start (deg) | lost from sweep | "
             "CPU/sweep (s) | wall/sweep median (s) |", "|---|---|---|---|---|---|---|---|"]
    for name, runs in out["runs"].items():
        for setting, r in runs.items():
            if setting == "summary":
                continue
            if r.get("status") != "ok":
                lines.append(f"| {name} | {setting} | {r['status']}: {r['reason']} | | | | | |")
                continue
            e = r["max_abs_error_from_start"]
            lost = r["lost_track_from_sweep"]
            lines.append(f"| {name} | {setting} | {r['ate_rmse_m']:.3f} | {r['ate_max_m']:.3f} | "
                         f"{e['roll_deg']:.1f}/{e['pitch_deg']:.1f}/{e['yaw_deg']:.1f} | "
                         f"{'-' if lost is None else lost} | {r['cpu_per_sweep_mean_s']:.3f} | "
                         f"{r['wall_per_sweep_median_s']:.3f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", default=None, help="the BALM folder (default $HSMAP_DATASETS/balm)")
    ap.add_argument("--seeds", default="0,1,2", help="HS-SLAM seeds, comma-separated (0: the command line's default)")
    ap.add_argument("--max-sweeps", type=int, default=None, help="the first N sweeps only (smoke runs)")
    ap.add_argument("--only", nargs="+", choices=METHODS, default=list(METHODS))
    ap.add_argument("--settings", nargs="+", default=None,
                    help="the peers' settings to run (defaults, ouster; default: every setting of each peer)")
    ap.add_argument("--scratch", default=None, help="the sweep folder to make (default: a temporary one)")
    ap.add_argument("--out", default=str(ROOT / "reports/benchmarks/peers3d.json"))
    args = ap.parse_args(argv)
    from hsmap.study.peers3d import SETTINGS
    from hsmap.study.real_sweeps import (
        balm_folder,
        missing_balm_reason,
        open_sweeps,
        read_reference,
        sweep_folder,
    )

    seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    known = sorted({s for v in SETTINGS.values() for s in v})
    if args.settings is not None and set(args.settings) - set(known):
        ap.error(f"--settings: expected some of {known}, got {args.settings}")
    src = Path(args.dataset) if args.dataset else balm_folder()
    out: dict = {"benchmark": "peers3d", "machine": machine(), "hsmap_version": hsmap.__version__,
                 "command": " ".join([sys.executable, *sys.argv]), "runs": {}}
    if src is None or not (src / "alidarPose.csv").is_file():
        out["skipped"] = missing_balm_reason() if src is None else f"no alidarPose.csv in {src}"
        finish(out, args.out)
        return 0
    with tempfile.TemporaryDirectory(prefix="hsmap-peers3d-") as tmp:
        folder = sweep_folder(src, args.scratch or Path(tmp) / "sweeps", max_sweeps=args.max_sweeps)
        ref = read_reference(src)
        t0 = time.perf_counter()
        frames = list(open_sweeps(folder).frames(clouds=True))
        sweeps = [np.ascontiguousarray(f.cloud3d, dtype=np.float64) for f in frames]
        stamps = np.array([f.stamp for f in frames])
        del frames
        out["input"] = {"dataset": str(src), "sweeps": len(sweeps), "reference_sweeps": len(ref),
                        "points_per_sweep_median": int(np.median([len(s) for s in sweeps])),
                        "duration_s": float(stamps[-1] - stamps[0]), "read_seconds": time.perf_counter() - t0}
        for name in args.only:
            runs: dict = {}
            out["runs"][name] = runs
            todo = [(f"seed{s}", s) for s in seeds] if name == "hs_slam_6dof" else [(s, s) for s in SETTINGS[name]
                                                                          if args.settings is None
                                                                          or s in args.settings]
            for label, what in todo:
                load = load_average()
                if name == "hs_slam_6dof":
                    r = guarded(run_hs_entry, folder, what, ref)
                else:
                    r = guarded(run_peer_entry, name, what, sweeps, stamps, ref)
                r["load_average_at_start"] = load
                runs[label] = r
                if r["status"] == "ok":
                    print(f"{name} {label}: ATE RMSE {r['ate_rmse_m']:.3f} m, max {r['ate_max_m']:.3f} m, lost from "
                          f"{r['lost_track_from_sweep']}, {r['cpu_per_sweep_mean_s']:.3f} s CPU a sweep", flush=True)
                else:
                    print(f"{name} {label}: {r['status']}: {r['reason']}", flush=True)
                write_json(args.out, {**out, "unfinished": True})
            if name == "hs_slam_6dof":
                runs["summary"] = seed_summary(runs)
    out["table"] = table(out)
    print(out["table"])
    finish(out, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
