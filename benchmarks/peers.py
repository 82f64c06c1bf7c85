"""Peers in the same run: other SLAM systems that install here, beside HS-SLAM on the same inputs in one process.

1. ``intel``, ``fr079``, ``fr-clinic`` (the ``.orig.bag`` files of $HSMAP_DATASETS/slam2d, read by hsmap's
   reader; fr079 with the CARMEN log's laser offset, as ``benchmarks/slam.py``): hsmap's HS-SLAM 2D (the command
   line's default configuration, loop closure on, ``--seed``, recording a ``slam.rrd`` as the command does unless
   ``--no-recording``), then
   - ``yag-slam`` (PyPI; OpenKarto's scan matcher and a sparse pose graph), in this process: its ``GraphSlam``
     with its default matcher configurations, every scan given to it (it has no minimum travel of its own);
   - MRPT ``icp-slam`` (stock ``icp-slam_demo_classic.ini``) and ``rbpf-slam`` with both of its stock
     configurations for the intel log (``gridmapping_intel.ini``: grid maps, optimal sampling;
     ``gridmapping_RBPF_ICPbased_intel.ini``: point maps, ICP-based proposal) (Debian ``mrpt-apps``), each as a
     subprocess on a rawlog written by ``benchmarks/rawlog.py`` (every observation with its own stamp); only the
     settings that name files and turn off windows, images and 3D scenes are changed. The trajectory of each is
     its ``log_estimated_path.txt``: icp-slam's pose after each scan, rbpf-slam's estimate after each step.
   Each: the Freiburg relations error (all, dt <= 10 s, dt > 60 s), wall and CPU time (the subprocess's CPU for
   the MRPT apps; writing the rawlog is not counted), real-time factor, and the time ratio to HS-SLAM.
2. ``3d`` (the simulated slam-office route, seed 1): HS-SLAM 6-DOF and KISS-ICP (``benchmarks/slam.py``'s
   comparison), then GenZ-ICP and small_gicp (scan-to-scan GICP, its defaults) on the same clouds: per-DOF
   maximum errors and final error against ground truth, ms per cloud (median), CPU per cloud.

A peer that is not installed or fails is reported with ``status`` and ``reason``, never dropped. Times exclude
reading the input. Writes reports/benchmarks/peers.json (atomically).

    .venv/bin/python benchmarks/peers.py [--only intel fr079 fr-clinic 3d] [--peers hs_slam yag_slam icp_slam
        rbpf_slam_grid rbpf_slam_icp] [--max-frames N] [--timeout S] [--seed 1] [--repeat N] [--no-recording]
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path

import numpy as np

os.environ.setdefault("RERUN_ANALYTICS", "0")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from _report import finish, load_average, machine  # noqa: E402

import hsmap  # noqa: E402
from hsmap.io import write_json  # noqa: E402

PEERS_2D = ("hs_slam", "yag_slam", "icp_slam", "rbpf_slam_grid", "rbpf_slam_icp")
MRPT_CONFIGS = Path("/usr/share/mrpt/config_files")
_RBPF_SET = {"SHOW_PROGRESS_IN_WINDOW": "0", "SAVE_3D_SCENE": "0", "SAVE_MAP_IMAGES": "0", "SAVE_POSE_LOG": "0",
             "LOG_FREQUENCY": "0"}
#: The MRPT apps: executable, stock configuration, rawlog form, settings changed (files, windows, images only).
MRPT = {
    "icp_slam": {"exe": "icp-slam", "config": MRPT_CONFIGS / "icp-slam" / "icp-slam_demo_classic.ini",
                 "actions": False,
                 "set": {"SHOW_PROGRESS_3D_REAL_TIME": "0", "SAVE_3D_SCENE": "0", "SAVE_POSE_LOG": "0"}},
    "rbpf_slam_grid": {"exe": "rbpf-slam", "config": MRPT_CONFIGS / "rbpf-slam" / "gridmapping_intel.ini",
                       "actions": True, "set": _RBPF_SET},
    "rbpf_slam_icp": {"exe": "rbpf-slam",
                      "config": MRPT_CONFIGS / "rbpf-slam" / "gridmapping_RBPF_ICPbased_intel.ini",
                      "actions": True, "set": _RBPF_SET},
}
#: yag-slam's scan matcher's range threshold (m): its default_config's.
YAG_RANGE_THRESHOLD = 20.0


def not_available(reason: str, status: str = "not installed") -> dict:
    """A peer's entry when it cannot run: ``status`` and one line of ``reason``."""
    return {"status": status, "reason": reason}


def guarded(fn, *args, **kw) -> dict:
    """``fn(*args, **kw)``, or a "failed" entry with the exception's last line (a missing module: "not
    installed")."""
    try:
        return fn(*args, **kw)
    except ModuleNotFoundError as e:
        return not_available(f"{e.name} is not importable: {e}")
    except FileNotFoundError as e:
        return not_available(str(e))
    except subprocess.TimeoutExpired as e:
        return not_available(f"ran past the timeout of {e.timeout:.0f} s", status="timed out")
    except Exception as e:  # a peer's failure is a result, reported beside the others
        traceback.print_exc()
        return not_available(f"{type(e).__name__}: {e}".splitlines()[0], status="failed")


def _relations(traj, rel, partial: bool) -> dict:
    from slam import _relations as relations  # benchmarks/slam.py

    return relations(traj, rel, skip_unmatched=partial)


def _timed(entry: dict, duration: float, wall: float, cpu: float) -> dict:
    return {"status": "ok", "wall_seconds": wall, "cpu_seconds": cpu, "real_time_factor": duration / wall, **entry}


def run_hs_slam(frames, seed: int, record: bool = True) -> tuple[object, float, float]:
    """HS-SLAM 2D on ``frames`` as ``hsmap slam`` runs it: recording into a scratch ``slam.rrd`` unless ``record`` is
    false. Wall and CPU (this process's and the helper process's) include the recording's finish."""
    from hsmap._helper_process import cpu_seconds
    from hsmap.slam import SlamConfig, run_slam
    from hsmap.viz.replay import SlamRecorder

    cfg = SlamConfig(dof=3)
    with tempfile.TemporaryDirectory(prefix="hsmap-peers-rrd-") as tmp:
        t0, c0 = time.perf_counter(), cpu_seconds()
        recorder = SlamRecorder(Path(tmp) / "slam.rrd", cfg) if record else None
        res = run_slam(frames, cfg, rng=seed, progress=False,
                       on_frame=None if recorder is None else recorder.on_frame)
        if recorder is not None:
            recorder.finish(res)
            recorder.close()
        wall, cpu = time.perf_counter() - t0, cpu_seconds() - c0
    return res.trajectory, wall, cpu


def run_yag_slam(frames) -> tuple[object, float, float, dict]:
    """yag-slam on every scan (its ``GraphSlam`` with its default matchers); the base trajectory, wall and CPU
    seconds, details."""
    import yag_slam  # noqa: F401  (a missing package: "not installed")
    from yag_slam.graph_slam import GraphSlam
    from yag_slam.models import LocalizedRangeScan
    from yag_slam.scan_matching import Scan2DMatcherCpp

    from hsmap.geometry import compose, invert
    from hsmap.trajectory import Trajectory

    t0, c0 = time.perf_counter(), time.process_time()
    slam = GraphSlam(Scan2DMatcherCpp({}), Scan2DMatcherCpp({}, loop=True))
    scans = []
    closed = 0
    for f in frames:
        odo = f.odometry if f.odometry is not None else np.zeros(3)
        s = f.scan2d
        a = s.angles
        r = np.where(np.isfinite(s.ranges), s.ranges, s.range_max)
        laser = compose(odo, f.extrinsic2d)  # yag-slam's scans are at the laser
        scan = LocalizedRangeScan(r.astype(np.float64), float(a[0]), float(a[-1]), float((a[-1] - a[0]) / (len(a) - 1)),
                                  float(s.range_min), float(min(s.range_max, 80.0)), YAG_RANGE_THRESHOLD, *laser)
        _, c = slam.process_scan(scan)
        closed += bool(c)
        scans.append(scan)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    poses = np.array([compose(np.array([sc.corrected_pose.x, sc.corrected_pose.y, sc.corrected_pose.euler[-1]]),
                              invert(f.extrinsic2d)) for f, sc in zip(frames, scans, strict=True)])
    info = {"version": _dist_version("yag-slam"), "scans_processed": len(scans), "loops_closed": closed,
            "range_threshold_m": YAG_RANGE_THRESHOLD}
    return Trajectory(np.array([f.stamp for f in frames]), poses), wall, cpu, info


def _dist_version(name: str) -> str | None:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(name)
    except PackageNotFoundError:
        return None


def mrpt_config(stock: Path, rawlog: Path, out_dir: Path, settings: dict) -> str:
    """The stock configuration text with ``rawlog_file``, ``logOutput_dir`` and ``settings`` replaced (in
    ``[MappingApplication]``)."""
    lines = []
    section = None
    done = set()
    values = {"rawlog_file": str(rawlog), "logOutput_dir": str(out_dir), **settings}
    for line in stock.read_text().splitlines():
        s = line.strip()
        if s.startswith("["):
            section = s.strip("[] ")
        key = s.split("=", 1)[0].strip() if "=" in s and not s.startswith(("#", "//", ";")) else None
        if section == "MappingApplication" and key in values:
            line = f"{key}={values[key]}"
            done.add(key)
        lines.append(line)
    missing = set(values) - done
    if missing:  # not in the stock file: added to its section
        i = next(k for k, ln in enumerate(lines) if ln.strip() == "[MappingApplication]")
        lines[i + 1:i + 1] = [f"{k}={values[k]}" for k in sorted(missing)]
    return "\n".join(lines) + "\n"


def run_mrpt(name: str, frames, timeout: float, workdir: Path) -> tuple[object, float, float, dict]:
    """One MRPT app on a rawlog of the frames; the base trajectory at the scans, wall and CPU seconds, details."""
    from rawlog import write_rawlog  # benchmarks/rawlog.py

    from hsmap.trajectory import Trajectory

    spec = MRPT[name]
    exe = shutil.which(spec["exe"])
    if exe is None:
        raise FileNotFoundError(f"{spec['exe']} is not on PATH (Debian: apt-get install mrpt-apps)")
    if not spec["config"].is_file():
        raise FileNotFoundError(f"no stock configuration at {spec['config']}")
    rawlog = workdir / f"{name}.rawlog"
    entries = write_rawlog(frames, rawlog, actions=spec["actions"])
    out_dir = workdir / f"{name}-out"
    ini = workdir / f"{name}.ini"
    ini.write_text(mrpt_config(spec["config"], rawlog, out_dir, spec["set"]))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run([exe, str(ini), str(rawlog)], capture_output=True, text=True, timeout=timeout)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    path = out_dir / "log_estimated_path.txt"
    if proc.returncode != 0 or not path.is_file():
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or [""]
        raise RuntimeError(f"{spec['exe']} exited {proc.returncode}: {tail[0][:200]}")
    est = np.loadtxt(path, ndmin=2)
    if spec["actions"]:  # step, x, y, z, yaw, pitch, roll, stamp: the filter's estimate after each step
        stamps, poses = est[:, 7], est[:, [1, 2, 4]]
    else:  # step, x, y, yaw: one row per rawlog entry
        steps = est[:, 0].astype(int)
        kinds = np.array([k for k, _ in entries])
        st = np.array([t for _, t in entries])
        ok = (steps < len(entries)) & (kinds[np.minimum(steps, len(entries) - 1)] == "scan")
        stamps, poses = st[steps[ok]], est[ok][:, 1:4]
    _, keep = np.unique(stamps, return_index=True)
    info = {"executable": exe, "config": str(spec["config"]), "changed_settings": spec["set"],
            "rawlog_form": "actions and sensory frames" if spec["actions"] else "observations",
            "poses": int(keep.size)}
    return Trajectory(stamps[keep], poses[keep]), wall, cpu, info


def _median_run(runs: list[dict]) -> dict:
    """The run with the median wall time (the lower middle one of an even count) and every run's wall and CPU
    seconds; the first failed run if any failed."""
    failed = [r for r in runs if r["status"] != "ok"]
    if failed:
        return failed[0]
    order = sorted(range(len(runs)), key=lambda i: runs[i]["wall_seconds"])
    mid = dict(runs[order[(len(runs) - 1) // 2]])
    if len(runs) > 1:
        mid["runs_wall_seconds"] = [r["wall_seconds"] for r in runs]
        mid["runs_cpu_seconds"] = [r["cpu_seconds"] for r in runs]
        mid["wall_seconds_median"] = float(np.median(mid["runs_wall_seconds"]))
    return mid


def bench_log(name: str, datasets: Path, peers: list[str], max_frames: int | None, seed: int,
              timeout: float, repeat: int = 1, record: bool = True) -> dict:
    from slam import FREIBURG, freiburg_frames  # benchmarks/slam.py

    spec = FREIBURG[name]
    frames, rel, total = freiburg_frames(name, datasets, max_frames)
    stamps = np.array([f.stamp for f in frames])
    duration = float(stamps.max() - stamps.min())
    partial = max_frames is not None and max_frames < total
    out: dict = {"frames": len(frames), "log_duration_s": duration, "max_frames": max_frames,
                 "published": {k: v for k, v in spec.items() if k.endswith(("_m", "_deg"))}}

    def one(peer: str) -> dict:
        load = load_average()
        if peer == "hs_slam":
            traj, wall, cpu = run_hs_slam(frames, seed, record)
            info = {"seed": seed, "version": hsmap.__version__, "recording": record}
        elif peer == "yag_slam":
            traj, wall, cpu, info = run_yag_slam(frames)
        else:
            with tempfile.TemporaryDirectory(prefix=f"hsmap-peers-{peer}-") as tmp:
                traj, wall, cpu, info = run_mrpt(peer, frames, timeout, Path(tmp))
        return _timed({"relations": _relations(traj, rel, partial), "load_average": load, **info},
                      duration, wall, cpu)

    if "hs_slam" in peers:  # warm-up, not measured: compiled kernels read from numba's cache, thread pools
        run_hs_slam(frames[:30], seed, record)
    runs: dict[str, list[dict]] = {peer: [] for peer in peers}
    for _ in range(repeat):  # alternated: every peer once per round, so load changes hit them alike
        for peer in peers:
            runs[peer].append(guarded(one, peer))
    for peer in peers:
        out[peer] = r = _median_run(runs[peer])
        if r["status"] == "ok":
            print(f"{name} {peer}: {r['wall_seconds']:.1f} s wall, {r['cpu_seconds']:.1f} s CPU, "
                  f"{r['real_time_factor']:.1f}x real time, relations "
                  f"{r['relations']['all']['translation_m']['mean']:.4f} m / "
                  f"{r['relations']['all']['rotation_deg']['mean']:.3f} deg", flush=True)
        else:
            print(f"{name} {peer}: {r['status']}: {r['reason']}", flush=True)
    hs = out.get("hs_slam", {})
    if hs.get("status") == "ok":
        for peer in peers:
            r = out[peer]
            if peer != "hs_slam" and r["status"] == "ok":
                r["wall_ratio_to_hs_slam"] = r["wall_seconds"] / hs["wall_seconds"]
                r["cpu_ratio_to_hs_slam"] = r["cpu_seconds"] / hs["cpu_seconds"]
    return out


def _odometry_3d(name: str, frames, gt, register) -> dict:
    """A scan-to-scan or scan-to-map odometry ``register(points) -> 4x4 sensor pose`` over the clouds; its errors
    against ground truth (base poses, relative to the first) and time per cloud."""
    from hsmap.evaluation.trajectory import pose_errors
    from hsmap.geometry import compose, invert, matrix_to_pose
    from hsmap.trajectory import Trajectory

    ext = frames[0].extrinsic3d
    times, poses = [], []
    c0 = time.process_time()
    for f in frames:
        pts = np.ascontiguousarray(f.cloud3d, dtype=np.float64)
        t1 = time.perf_counter()
        T = register(pts)
        times.append(time.perf_counter() - t1)
        poses.append(compose(compose(ext, matrix_to_pose(np.asarray(T))), invert(ext)))
    cpu = time.process_time() - c0
    n = len(frames)
    return {"status": "ok", "seconds_per_cloud_median": float(np.median(times)),
            "seconds_per_cloud_mean": float(np.mean(times)), "wall_seconds": float(np.sum(times)),
            "cpu_seconds_per_cloud_mean": cpu / n,
            "errors": pose_errors(Trajectory(gt.stamps, np.asarray(poses)), gt).as_dict()}


def run_genz(frames, gt, max_range: float, min_range: float) -> dict:
    from genz_icp.config import load_config
    from genz_icp.genz_icp import GenZICP

    cfg = load_config(None)  # its defaults
    cfg.data.max_range, cfg.data.min_range, cfg.data.deskew = max_range, min_range, False
    odo = GenZICP(cfg)

    def register(pts):
        odo.register_frame(pts, np.zeros(len(pts)))
        return odo.last_pose

    out = _odometry_3d("genz_icp", frames, gt, register)
    out["version"] = _dist_version("genz-icp")
    out["config"] = {"max_range": max_range, "min_range": min_range, "deskew": False,
                     "voxel_size": cfg.mapping.voxel_size}
    return out


def run_small_gicp(frames, gt) -> dict:
    import small_gicp

    state = {"prev": None, "T": np.eye(4), "delta": np.eye(4)}

    def register(pts):
        cloud, tree = small_gicp.preprocess_points(pts, downsampling_resolution=0.25)
        if state["prev"] is not None:
            res = small_gicp.align(state["prev"][0], cloud, state["prev"][1], init_T_target_source=state["delta"])
            state["delta"] = np.asarray(res.T_target_source)
            state["T"] = state["T"] @ state["delta"]
        state["prev"] = (cloud, tree)
        return state["T"]

    out = _odometry_3d("small_gicp", frames, gt, register)
    out["version"] = _dist_version("small-gicp")
    out["config"] = {"registration": "GICP", "scan_to_scan": True, "downsampling_resolution": 0.25}
    return out


def bench_3d(max_frames: int | None, folder: str | None) -> dict:
    from slam import bench_3d as hs_and_kiss  # benchmarks/slam.py

    from hsmap.datasets.open import open_dataset
    from hsmap.slam import SlamConfig
    from hsmap.study import simulated_dataset
    from hsmap.trajectory import Trajectory

    out = {}
    base = guarded(hs_and_kiss, max_frames, folder)
    if base.get("status") in ("failed", "not installed", "timed out"):
        out["hs_slam_6dof"] = out["kiss_icp"] = base
    else:
        out.update({k: v for k, v in base.items() if k not in ("hs_slam_6dof", "kiss_icp")})
        out["hs_slam_6dof"] = {"status": "ok", **base["hs_slam_6dof"]}
        out["kiss_icp"] = {"status": "ok", **base["kiss_icp"]}
    ds = open_dataset(folder or simulated_dataset("slam-office", 1).path)
    n = min(len(ds), max_frames or len(ds))
    frames = [f for _, f in zip(range(n), ds.frames(clouds=True), strict=False)]
    gt = Trajectory(ds.groundtruth.stamps[:n], ds.groundtruth.as_6dof().poses[:n])
    cfg6 = SlamConfig(dof=6, use_odometry=False)
    out["genz_icp"] = guarded(run_genz, frames, gt, cfg6.max_range, cfg6.min_range)
    out["small_gicp"] = guarded(run_small_gicp, frames, gt)
    for k in ("hs_slam_6dof", "kiss_icp", "genz_icp", "small_gicp"):
        r = out[k]
        if r.get("status") == "ok":
            mx = r["errors"]["max_abs_error"]
            print(f"3d {k}: {1000 * r['seconds_per_cloud_median']:.1f} ms per cloud, max error x "
                  f"{100 * mx['x_m']:.2f} cm, y {100 * mx['y_m']:.2f} cm, yaw {mx['yaw_deg']:.3f} deg", flush=True)
        else:
            print(f"3d {k}: {r['status']}: {r['reason']}", flush=True)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="+", choices=["intel", "fr079", "fr-clinic", "3d"],
                    default=["intel", "fr079", "fr-clinic", "3d"])
    ap.add_argument("--peers", nargs="+", choices=PEERS_2D, default=list(PEERS_2D), help="2D runs, in this order")
    ap.add_argument("--max-frames", type=int, default=None, help="cut every input (smoke runs)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=1,
                    help="2D: run the peers this many times, alternated; each peer's entry is its median run")
    ap.add_argument("--no-recording", action="store_true",
                    help="HS-SLAM without its rerun recording (hsmap slam --no-recording)")
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds an MRPT app may run")
    ap.add_argument("--dataset3d", default=None, help="3d: this simulator folder instead of the study's")
    ap.add_argument("--out", default=str(ROOT / "reports/benchmarks/peers.json"))
    args = ap.parse_args(argv)
    from hsmap.study.paths import datasets_dir

    datasets = datasets_dir()
    out = {"benchmark": "peers", "machine": machine(), "hsmap_version": hsmap.__version__,
           "command": " ".join([sys.executable, *sys.argv])}
    for name in args.only:
        if name == "3d":
            out["3d_slam_office"] = bench_3d(args.max_frames, args.dataset3d)
        elif (datasets / "slam2d").is_dir():
            out[name] = bench_log(name, datasets, args.peers, args.max_frames, args.seed, args.timeout,
                                  args.repeat, not args.no_recording)
        else:
            out[name] = {"skipped": f"no Freiburg data at {datasets}/slam2d"}
        if name != args.only[-1]:  # what has run so far, should a later part not finish
            write_json(args.out, {**out, "unfinished": args.only[args.only.index(name) + 1:]})
    finish(out, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
