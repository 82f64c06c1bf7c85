"""Simulator benchmark: frames per second of ``hsmap simulate`` on the shipped scenarios.

Each scenario is simulated ``--repeats`` times into a temporary folder with the default sensors (2D: 1081
beams; 3D: 128 x 1024) and all files written, in this one process (open3d imported once, before timing).
Reported per scenario: median wall time and frames per second, median process CPU time (all threads; on two
idle cores the wall time can drop to about half of it), the median time of each stage, the load average
around the runs (the machine is shared), and the dataset size. Peer in the same process: the 3D ray casting
alone on the same frames (``World.scan3d`` without noise or writing), to show what the writing costs.

With ``--figures DIR`` the preview pictures of each scenario (top view, one 3D cloud, odometry-only map) are
also written to ``DIR/<scenario>/`` (outside the timing).

Writes reports/benchmarks/simulate.json (atomically) and prints a table.

    .venv/bin/python benchmarks/simulate.py [--repeats N] [--scenarios a b] [--figures reports/figures/simulate]
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("RERUN_ANALYTICS", "0")
os.environ.setdefault("MPLBACKEND", "Agg")

import hsmap  # noqa: E402
from hsmap.io import write_json  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def cpu_seconds() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def folder_bytes(p: Path) -> int:
    return sum(f.stat().st_size for f in p.rglob("*") if f.is_file())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--scenarios", nargs="+", default=["slam-office", "two-rooms"])
    ap.add_argument("--figures", default=None, metavar="DIR", help="also write preview pictures to DIR/<scenario>/")
    ap.add_argument("--out", default=str(ROOT / "reports/benchmarks/simulate.json"))
    args = ap.parse_args()

    t = time.perf_counter()
    import open3d  # noqa: F401

    import_s = time.perf_counter() - t
    from hsmap.sim import load_scenario, motion_for, resolve_scenario, simulate
    from hsmap.sim.world import World
    from hsmap.viz.scenario_figures import preview_dataset

    results = {}
    for name in args.scenarios:
        scn = load_scenario(resolve_scenario(name))
        runs = []
        for rep in range(args.repeats):
            with tempfile.TemporaryDirectory(prefix="hsmap-sim-bench-") as tmp:
                out = Path(tmp) / name
                load0 = os.getloadavg()[0]
                c0, t0 = cpu_seconds(), time.perf_counter()
                s = simulate(scn, out, seed=0)
                wall, cpu = time.perf_counter() - t0, cpu_seconds() - c0
                runs.append({"wall_s": wall, "cpu_s": cpu, "frames": s.frames, "timings": s.timings,
                             "bytes": folder_bytes(out), "load_before": load0, "load_after": os.getloadavg()[0]})
                if rep == 0 and args.figures:
                    dest = Path(args.figures) / name
                    shutil.rmtree(dest, ignore_errors=True)
                    dest.mkdir(parents=True, exist_ok=True)
                    preview_dataset(out)
                    for f in (out / "figures").iterdir():
                        shutil.copyfile(f, dest / f.name)
                    summary = s.as_dict()
                    summary.pop("path")
                    write_json(dest / "summary.json", summary)
                print(f"{name} run {rep + 1}/{args.repeats}: {s.frames} frames in {wall:.1f} s "
                      f"({s.frames / wall:.1f} frames/s, cpu {cpu:.1f} s, load {load0:.1f})", flush=True)
        # peer: ray casting only, same frames, batches of 8
        world = World(scn)
        m = motion_for(scn, 0)
        dirs = scn.lidar3d.directions()
        c0, t0 = cpu_seconds(), time.perf_counter()
        for a in range(0, len(m), 8):
            world.scan3d(m.groundtruth[a:a + 8], scn.lidar3d, None, dirs)
        cast_wall, cast_cpu = time.perf_counter() - t0, cpu_seconds() - c0
        med = statistics.median
        n = runs[0]["frames"]
        results[name] = {
            "frames": n,
            "path_length_m": round(s.path_length, 2),
            "repeats": len(runs),
            "wall_s_median": round(med(r["wall_s"] for r in runs), 3),
            "wall_s_all": [round(r["wall_s"], 3) for r in runs],
            "frames_per_s_median": round(med(n / r["wall_s"] for r in runs), 2),
            "cpu_s_median": round(med(r["cpu_s"] for r in runs), 3),
            "stages_s_median": {k: round(med(r["timings"][k] for r in runs), 3) for k in runs[0]["timings"]},
            "dataset_mb": round(runs[0]["bytes"] / 1e6, 1),
            "load_average_1min": [round(r["load_before"], 2) for r in runs],
            "peer_raycast_only": {"wall_s": round(cast_wall, 3), "cpu_s": round(cast_cpu, 3),
                                  "frames_per_s": round(n / cast_wall, 2),
                                  "rays_per_s_million": round(n * dirs.shape[0] * dirs.shape[1] / cast_wall / 1e6,
                                                              2)},
        }
    total_wall = sum(r["wall_s_median"] for r in results.values())
    total_cpu = sum(r["cpu_s_median"] for r in results.values())
    report = {
        "benchmark": "simulate",
        "hsmap_version": hsmap.__version__,
        "python": platform.python_version(),
        "numpy": np.__version__,
        "open3d": open3d.__version__,
        "cpu_count": os.cpu_count(),
        "import_open3d_s": round(import_s, 3),
        "scenarios": results,
        "all_scenarios_wall_s": round(total_wall, 3),
        "all_scenarios_cpu_s": round(total_cpu, 3),
        "all_under_a_minute_wall": total_wall < 60.0,
        "note": "wall times on a shared machine; cpu_s counts all threads of this process",
    }
    write_json(args.out, report)
    print(f"\n{'scenario':<14}{'frames':>8}{'wall s':>9}{'fps':>8}{'cpu s':>8}{'MB':>8}{'raycast-only fps':>18}")
    for name, r in results.items():
        print(f"{name:<14}{r['frames']:>8}{r['wall_s_median']:>9.1f}{r['frames_per_s_median']:>8.1f}"
              f"{r['cpu_s_median']:>8.1f}{r['dataset_mb']:>8.1f}{r['peer_raycast_only']['frames_per_s']:>18.1f}")
    print(f"all scenarios: {total_wall:.1f} s wall, {total_cpu:.1f} s cpu -> {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
