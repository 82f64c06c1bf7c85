"""Does limiting BLAS only where hsmap's hot loops run keep them as fast as a limit for the whole process?

hsmap takes the limit around ``harmony_icp``, ``estimate_normals`` and ``run_slam`` and gives it back
(``hsmap._blas``). This script times the same workloads, in one process, interleaved round by round, under three settings:

- ``process``: BLAS on one thread for the whole process (hsmap's own limit switched off);
- ``scoped``: hsmap's behaviour, nothing set by the caller, hsmap's limit around its hot loops;
- ``none``: no limit at all (the host's BLAS threads), to show what the limit is for.

Workloads: the registration benchmark's 2D (1081-beam scans, offsets up to 1 m / 45 deg) and 3D (~5,000-point
room clouds, up to 0.5 m / 30 deg) pairs, and HS-SLAM (3-DOF on the 2D scans, 6-DOF on the 3D clouds) over the
first frames of the simulated slam-office route, frames read into memory first. Each registration and each
SLAM run is timed under the three settings back to back (the order rotating), so that the paired ratio
scoped / process cancels the load drifting on a shared machine. Reported: the median time of each setting,
the median and interquartile range of the paired ratios (1.0 = no slower). ``--busy N`` starts N
CPU-bound processes for the duration, for a busy machine on demand (the machine's load average is recorded
either way). Writes reports/benchmarks/blas_threads.json.

    .venv/bin/python benchmarks/blas_threads.py [--rounds 5] [--pairs 6] [--frames 60] [--busy 0]
"""

from __future__ import annotations

import argparse
import contextlib
import multiprocessing
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from _report import finish, machine  # noqa: E402  (benchmarks/_report.py)
from threadpoolctl import threadpool_info, threadpool_limits

import hsmap
import hsmap._blas as blas
from hsmap.registration.icp import harmony_icp
from hsmap.slam import SlamConfig, run_slam

sys.path.insert(0, str(Path(__file__).resolve().parent))
from registration import pairs_2d, pairs_3d  # noqa: E402  (the registration benchmark's own cases)

ROOT = Path(__file__).resolve().parents[1]
SETTINGS = ("process", "scoped", "none")


@contextlib.contextmanager
def setting(name: str):
    """The BLAS setting ``name`` for the block (see the module docstring)."""
    scoped = blas.limited_blas
    if name != "scoped":
        blas.limited_blas = contextlib.nullcontext  # hsmap's own limit off: the decorators look it up per call
    try:
        if name == "process":
            with threadpool_limits(limits=1, user_api="blas"):
                yield
        else:
            yield
    finally:
        blas.limited_blas = scoped


def _burn(stop) -> None:  # pragma: no cover - runs in a child process
    x = 0
    while not stop.is_set():
        x = (x * 1103515245 + 12345) % 2147483648


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=5, help="rounds; each runs every workload under every setting")
    ap.add_argument("--pairs", type=int, default=6, help="registration pairs per workload and round")
    ap.add_argument("--frames", type=int, default=60, help="HS-SLAM frames per run")
    ap.add_argument("--busy", type=int, default=0, help="CPU-bound processes to start for the duration")
    ap.add_argument("--out", default=str(ROOT / "reports" / "benchmarks" / "blas_threads.json"))
    args = ap.parse_args(argv)

    from hsmap.study import simulated_dataset

    host = {lib["filepath"]: lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"}
    rng = np.random.default_rng(0)
    reg2d = list(pairs_2d((1.0, 45), args.pairs, rng))
    reg3d = list(pairs_3d((0.5, 30), args.pairs, rng))
    ds = simulated_dataset("slam-office", 1)
    frames = [f for _, f in zip(range(args.frames), ds.frames(clouds=True), strict=False)]
    start = ds.groundtruth.poses[0]

    # a unit is one registration or one SLAM run; each unit runs under the three settings back to back (order
    # rotating), so the paired ratios cancel the load drifting on a shared machine
    units = {
        "registration_2d": [lambda s=s, t=t, k=k: harmony_icp(s, t, rng=k) for k, (s, t, _) in enumerate(reg2d)],
        "registration_3d": [lambda s=s, t=t, k=k: harmony_icp(s, t, rng=k) for k, (s, t, _) in enumerate(reg3d)],
        "slam_3dof": [lambda: run_slam(frames, SlamConfig(dof=3, use_odometry=False), rng=1, initial_pose=start,
                                       progress=False)],
        "slam_6dof": [lambda: run_slam(frames, SlamConfig(dof=6, use_odometry=False), rng=1,
                                       initial_pose=np.r_[start[:2], 0, 0, 0, start[2]], progress=False)],
    }
    for fns in units.values():  # warm-up: numba compilation, caches
        with setting("scoped"):
            fns[0]()

    stop = multiprocessing.Event()
    burners = [multiprocessing.Process(target=_burn, args=(stop,), daemon=True) for _ in range(args.busy)]
    for b in burners:
        b.start()
    times: dict[str, dict[str, list[float]]] = {w: {s: [] for s in SETTINGS} for w in units}
    load = [os.getloadavg()[0]]
    turn = 0
    try:
        for r in range(args.rounds):
            for w, fns in units.items():
                for fn in fns:
                    order = SETTINGS[turn % 3:] + SETTINGS[:turn % 3]  # each setting first as often
                    turn += 1
                    for s in order:
                        with setting(s):
                            t0 = time.perf_counter()
                            fn()
                            times[w][s].append(time.perf_counter() - t0)
            load.append(os.getloadavg()[0])
            print(f"round {r + 1}/{args.rounds}: " + ", ".join(
                f"{w} " + "/".join(f"{times[w][s][-1]:.2f}" for s in SETTINGS) for w in units), flush=True)
    finally:
        stop.set()
        for b in burners:
            b.join(timeout=5)
    after = {lib["filepath"]: lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"}

    summary = {}
    for w in units:
        med = {s: statistics.median(times[w][s]) for s in SETTINGS}
        ratio = np.asarray(times[w]["scoped"]) / np.asarray(times[w]["process"])
        none = np.asarray(times[w]["none"]) / np.asarray(times[w]["process"])
        summary[w] = {**{f"{s}_median_s": med[s] for s in SETTINGS}, "units": len(ratio),
                      "scoped_over_process": float(np.median(ratio)),
                      "scoped_over_process_iqr": [float(v) for v in np.percentile(ratio, [25, 75])],
                      "none_over_process": float(np.median(none))}
    result = {
        "benchmark": "BLAS threads: the old process-wide limit vs hsmap's scoped limit vs none, same run",
        "hsmap_version": hsmap.__version__,
        "rounds": args.rounds, "pairs": args.pairs, "frames": args.frames, "busy_processes": args.busy,
        "load_average_1min": load, "host_blas_threads_before": host, "host_blas_threads_after": after,
        "machine": machine(),
        "summary": summary, "times_s": times,
    }
    finish(result, args.out)
    print(f"\n{'workload':18s} {'process s':>10s} {'scoped s':>10s} {'none s':>10s} {'scoped/process':>15s} "
          f"{'(IQR)':>14s} {'none/process':>13s}")
    for w, s in summary.items():
        lo, hi = s["scoped_over_process_iqr"]
        print(f"{w:18s} {s['process_median_s']:10.3f} {s['scoped_median_s']:10.3f} {s['none_median_s']:10.3f} "
              f"{s['scoped_over_process']:15.3f} {f'{lo:.2f}-{hi:.2f}':>14s} {s['none_over_process']:13.3f}")
    print(f"host BLAS threads before {sorted(set(host.values()))}, after {sorted(set(after.values()))}; "
          f"load average {min(load):.1f}-{max(load):.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
