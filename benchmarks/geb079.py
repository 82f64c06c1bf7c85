"""OctoMap's geb079 (a real 3D map of Freiburg building 079) through ``hsmap segment`` and ``hsmap align``.

1. Reading: ``hsmap.maps.maps3d.read_map3d`` on ``$HSMAP_DATASETS/octomap/geb079.bt`` (median of ``--repeats``, numba
   kernels loaded by a first call), the grid's size and voxel counts, the floor found.
2. ``hsmap segment geb079.bt --band LO,HI`` for the slice (1.7-1.8 m) and the floor band (0.1-0.35 m): the
   command's wall time in a fresh process (median and worst of ``--repeats``), rooms, doors, cells.
3. ``hsmap align`` of fr079's 2D HS-SLAM map (``--map2d``, e.g. the map.ply of ``hsmap slam
   fr079.orig.bag --dof 3 --seed 1 --extrinsic2d -0.04,0,0``; made here in a temporary folder when not given)
   onto the slice, one alignment per seed: the transform's mean, spread (max - min) and worst distance from the
   mean, overlap, residual, what each map covers of the other.

Writes reports/benchmarks/geb079.json.

    .venv/bin/python benchmarks/geb079.py [--repeats 3] [--seeds 1 2 3 4 5] [--map2d /tmp/fr079/map.ply]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("RERUN_ANALYTICS", "0")

from _report import finish, machine  # noqa: E402  (benchmarks/_report.py)

REPO = Path(__file__).resolve().parent.parent
BANDS = {"slice": "1.7,1.8", "floor": "0.1,0.35"}


def _hsmap(*args: str) -> tuple[float, str]:
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "hsmap", *args], capture_output=True, text=True, cwd=REPO)
    took = time.perf_counter() - t0
    if done.returncode != 0:
        raise SystemExit(f"hsmap {' '.join(args)} failed: {done.stderr.strip()}")
    return took, done.stdout


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--map2d", default=None, help="fr079's 2D map (map.ply of hsmap slam, or a map_server YAML)")
    ap.add_argument("--out", default=str(REPO / "reports" / "benchmarks" / "geb079.json"))
    args = ap.parse_args()

    from hsmap.maps.maps3d import floor_height, read_map3d
    from hsmap.study.paths import datasets_dir

    root = datasets_dir()
    bt = root / "octomap" / "geb079.bt"
    if not bt.is_file():
        raise SystemExit(f"{bt}: not found (hsmap data fetch octomap)")
    report: dict = {"machine": machine(), "map": str(bt)}

    read_map3d(bt)
    times = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        m = read_map3d(bt)
        times.append(time.perf_counter() - t0)
    report["read"] = {"seconds_median": float(np.median(times)), "seconds": times, "voxels": list(m.shape),
                      "resolution": m.resolution, "counts": m.counts(), "floor": floor_height(m)}
    print(f"read {np.median(times):.3f} s, grid {m.shape}, floor {floor_height(m):.3f} m")

    with tempfile.TemporaryDirectory(prefix="geb079-") as tmp:
        tmp = Path(tmp)
        for name, band in BANDS.items():
            walls = []
            for _ in range(args.repeats):
                took, _ = _hsmap("segment", str(bt), "--band", band, "--out", str(tmp / name))
                walls.append(took)
            info = json.loads((tmp / name / "band.json").read_text())
            report[f"segment_{name}"] = {"band": band, "wall_seconds_median": float(np.median(walls)),
                                         "wall_seconds_worst": float(max(walls)), "wall_seconds": walls,
                                         "floor": info["floor"], "rooms": info["rooms"], "doors": info["doors"],
                                         "cells": info["cells"]}
            print(f"segment --band {band}: {np.median(walls):.2f} s (worst {max(walls):.2f}), {info['rooms']} "
                  f"rooms, {info['doors']} doors")

        map2d = args.map2d
        if map2d is None:
            bag = root / "slam2d" / "fr079" / "fr079.orig.bag"
            took, _ = _hsmap("slam", str(bag), "--out", str(tmp / "fr079"), "--dof", "3", "--seed", "1",
                             "--extrinsic2d", "-0.04,0,0")
            map2d = str(tmp / "fr079" / "map.ply")
            report["fr079_slam_seconds"] = took
        runs = []
        for seed in args.seeds:
            took, _ = _hsmap("align", map2d, str(bt), "--out", str(tmp / f"align{seed}"), "--seed", str(seed))
            res = json.loads((tmp / f"align{seed}" / "alignment.json").read_text())
            runs.append({"seed": seed, "wall_seconds": took, **{k: res[k] for k in
                                                                 ("transform", "overlap", "residual", "coverage")}})
            t = res["transform"]
            print(f"align seed {seed}: x {t['x']:.4f} y {t['y']:.4f} yaw {t['yaw_deg']:.4f} deg, overlap "
                  f"{res['overlap']['overlap']:.3f}, rmse {res['residual']['rmse']:.4f} m ({took:.1f} s)")
    xyz = np.array([[r["transform"]["x"], r["transform"]["y"], r["transform"]["yaw_deg"]] for r in runs])
    mean = xyz.mean(axis=0)
    report["align"] = {
        "map2d": map2d,
        "mean": {"x": mean[0], "y": mean[1], "yaw_deg": mean[2]},
        "spread": {"x": float(np.ptp(xyz[:, 0])), "y": float(np.ptp(xyz[:, 1])), "yaw_deg": float(np.ptp(xyz[:, 2]))},
        "worst_from_mean": {"translation": float(np.hypot(*(xyz[:, :2] - mean[:2]).T).max()),
                            "yaw_deg": float(np.abs(xyz[:, 2] - mean[2]).max())},
        "runs": runs,
    }
    print(f"align over seeds {args.seeds}: mean {mean.round(4).tolist()}, spread "
          f"{[round(v, 4) for v in report['align']['spread'].values()]}")
    finish(report, args.out)


if __name__ == "__main__":
    main()
