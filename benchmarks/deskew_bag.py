"""Rolling sweeps through ``hsmap map``: the two-rooms route at ``--speed`` times the robot's default 0.5 m/s
and 30 deg/s (default 2: 1 m/s and 60 deg/s) as a robot's ROS2 bag (:func:`hsmap.sim.bag.write_simulated_bag`:
2D scans at 8 Hz, odometry at 20 Hz, a 128 x 1024 Ouster-style PointCloud2 at 2 Hz whose columns sweep over
0.1 s, per-point ``t`` in ns, the cloud stamped at the sweep's start), mapped with and without ``--no-deskew``,
and the same bag with static sweeps; the largest error of each 6-DOF trajectory in x, y, z, roll, pitch and yaw
against the truth at the cloud stamps (as written, no alignment), and its yaw error where the robot turns in
place (the true yaw rate over the sweep above 10 deg/s): the largest, the mean, and the clouds over 0.5 deg.

    .venv/bin/python benchmarks/deskew_bag.py [--seed 1] [--speed 2] [--rolling-only] [--work DIR]
        [--out reports/benchmarks/deskew_bag.json]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from _report import finish, machine  # benchmarks/_report.py

from hsmap.geometry import wrap_angle
from hsmap.sim import Lidar3DConfig
from hsmap.sim.bag import write_simulated_bag
from hsmap.sim.catalog import resolve_scenario
from hsmap.sim.robot import RobotConfig
from hsmap.sim.scenario import load_scenario
from hsmap.trajectory import read_tum

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1, help="the bag's noise and odometry seed")
    ap.add_argument("--speed", type=float, default=2.0, help="the route's speed and turn rate, times the default")
    ap.add_argument("--rolling-only", action="store_true", help="map the rolling bag only, deskewed")
    ap.add_argument("--work", default=None, help="folder for the bags and maps (default a temporary one)")
    ap.add_argument("--out", default=str(ROOT / "reports/benchmarks/deskew_bag.json"))
    args = ap.parse_args(argv)
    work = Path(args.work or tempfile.mkdtemp(prefix="deskew-bag-"))
    robot = RobotConfig(max_speed=0.5 * args.speed, max_turn_rate_deg=30.0 * args.speed)
    scn = load_scenario(resolve_scenario("two-rooms")).replace(robot=robot)
    out: dict = {"benchmark": "deskew_bag", "machine": machine(), "seed": args.seed, "speed": args.speed,
                 "runs": {}}
    for name, sweep in (("rolling", 0.1),) + ((("static", 0.0),) if not args.rolling_only else ()):
        bag = write_simulated_bag(scn.replace(lidar3d=Lidar3DConfig(sweep_time=sweep)), work / f"{name}.mcap",
                                  seed=args.seed)
        for flag in ([[], ["--no-deskew"]] if sweep and not args.rolling_only else [[]]):
            folder = work / f"{name}{''.join(flag)}"
            p = subprocess.run([sys.executable, "-m", "hsmap", "map", str(bag.path), "--out", str(folder), "--quiet",
                                "--no-recording", *flag], capture_output=True, text=True)
            if p.returncode:
                out["runs"][name + "".join(flag)] = {"failed": p.stderr[-2000:]}
                continue
            t3 = read_tum(folder / "trajectory3d.tum")
            e = t3.poses.copy()
            e[:, :2] -= bag.clouds.poses[:, :2]
            e[:, 5] = wrap_angle(e[:, 5] - bag.clouds.poses[:, 2])
            mx = np.abs(e).max(0)
            r = {"x_cm": 100 * mx[0], "y_cm": 100 * mx[1], "z_cm": 100 * mx[2], "roll_deg": np.degrees(mx[3]),
                 "pitch_deg": np.degrees(mx[4]), "yaw_deg": np.degrees(mx[5])}
            # the true yaw rate over 0.1 s from each stamp (a sweep), from the true poses at the scans (8 Hz)
            st, yaw_true = bag.clouds.stamps, np.unwrap(bag.scans.poses[:, 2])
            rate = np.degrees(np.abs(np.interp(st + 0.1, bag.scans.stamps, yaw_true)
                                     - np.interp(st, bag.scans.stamps, yaw_true))) / 0.1
            turning = rate > 10.0
            yaw = np.degrees(np.abs(e[:, 5]))
            r |= {"turning_clouds": int(turning.sum()), "turning_yaw_max_deg": float(yaw[turning].max(initial=0.0)),
                  "turning_yaw_mean_deg": float(yaw[turning].mean()) if turning.any() else 0.0,
                  "clouds_over_0.5deg": int((yaw > 0.5).sum())}
            r = {k: round(float(v), 3) if isinstance(v, float) else v for k, v in r.items()}
            r["clouds"] = len(bag.clouds)
            info = json.loads((folder / "metrics.json").read_text())["input_info"]
            r["point_time"] = (info.get("clouds") or info).get("point_time")
            r["within_2cm_0.5deg"] = bool(max(r["x_cm"], r["y_cm"], r["z_cm"]) < 2
                                          and max(r["roll_deg"], r["pitch_deg"], r["yaw_deg"]) < 0.5)
            out["runs"][name + "".join(flag)] = r
            print(name, *flag, r, flush=True)
    finish(out, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
