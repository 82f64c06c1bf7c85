"""What registering fewer scans would cost: the relations error of a trajectory whose scans between two
registered ones are placed by the wheel odometry alone.

Scan-matching SLAM systems that register a scan only after the odometry has moved some distance or angle (MRPT's
``icp-slam``: 0.2 m or 5 deg in its stock configuration) do a fraction of the work of one that registers every
scan. This script asks what that costs in accuracy on a Freiburg log: it runs HS-SLAM (the command line's default
configuration, every scan registered) and then keeps its poses only at the scans such a motion filter would
register, each after the odometry moved at least ``d`` metres or ``a`` degrees since the last one. The scans in
between are placed by the odometry from the last registered scan, with the odometry's disagreement at the next
registered scan spread over them in proportion to their index (a linear bridge). The kept poses come from a run
that registered every scan, so the figure is a lower bound on the error of a run that registers only those.

    .venv/bin/python benchmarks/motion_filter.py --logs intel fr079 fr-clinic --seeds 1 2 3

Writes reports/benchmarks/motion_filter.json (atomically).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from _report import finish, machine  # noqa: E402  (benchmarks/_report.py)
from slam import FREIBURG  # noqa: E402

from hsmap.datasets.open import open_dataset  # noqa: E402
from hsmap.datasets.relations import read_relations  # noqa: E402
from hsmap.evaluation.trajectory import relations_error  # noqa: E402
from hsmap.geometry import compose, relative  # noqa: E402
from hsmap.slam import SlamConfig, run_slam  # noqa: E402
from hsmap.trajectory import Trajectory  # noqa: E402

#: (metres, degrees) of odometry motion after which the filter registers a scan; the last is icp-slam's
FILTERS = [(0.02, 1.0), (0.05, 2.0), (0.1, 3.0), (0.2, 5.0)]


def registered(odometry: np.ndarray, distance: float, angle_deg: float) -> np.ndarray:
    """Indices of the scans a motion filter registers: the first, each after the odometry poses (N, 3) moved at
    least ``distance`` or ``angle_deg`` from the last one registered, and the last."""
    keep, last = [0], 0
    for i in range(1, len(odometry)):
        step = relative(odometry[last], odometry[i])
        if np.hypot(step[0], step[1]) >= distance or abs(step[2]) >= np.radians(angle_deg):
            keep.append(i)
            last = i
    if keep[-1] != len(odometry) - 1:
        keep.append(len(odometry) - 1)
    return np.asarray(keep)


def bridged(poses: np.ndarray, odometry: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """``poses`` (N, 3) kept at ``keep``; between two kept scans, the odometry's motion from the first, corrected
    linearly towards the second."""
    out = poses.copy()
    for a, b in zip(keep[:-1], keep[1:], strict=True):
        if b - a < 2:
            continue
        steps = np.asarray([relative(odometry[a], odometry[k]) for k in range(a + 1, b + 1)])
        predicted = np.asarray(compose(np.broadcast_to(poses[a], steps.shape), steps))
        correction = relative(predicted[-1], poses[b])
        for j, k in enumerate(range(a + 1, b)):
            out[k] = compose(predicted[j], correction * (k - a) / (b - a))
    return out


def run_log(name: str, datasets: Path, seed: int) -> dict:
    spec = FREIBURG[name]
    ds = open_dataset(datasets / "slam2d" / spec["bag"], extrinsic2d=spec["extrinsic2d"])
    frames = list(ds.frames(clouds=False))
    res = run_slam(frames, SlamConfig(dof=3), rng=seed, progress=False)
    rel = read_relations(datasets / "slam2d" / spec["relations"])
    stamps, poses = res.trajectory.stamps, res.trajectory.poses
    odo = ds.odometry.interpolate(stamps, max_dt=1.0)[0]
    if not np.all(np.isfinite(odo)):
        raise SystemExit(f"{name}: the odometry does not cover every scan's stamp")

    def score(p: np.ndarray) -> dict:
        e = relations_error(Trajectory(stamps, p), rel)
        return {"translation_m": float(e.translation.mean()), "rotation_deg": float(np.degrees(e.rotation.mean()))}

    out = {"seed": seed, "scans": len(stamps), "every_scan": score(poses), "filters": []}
    for d, a in FILTERS:
        keep = registered(odo, d, a)
        out["filters"].append({"distance_m": d, "angle_deg": a, "registered": len(keep),
                               **score(bridged(poses, odo, keep))})
    print(f"{name} seed {seed}: every scan {out['every_scan']['translation_m']:.4f} m; "
          + ", ".join(f"{f['distance_m']} m / {f['angle_deg']:g} deg: {f['registered']} scans "
                      f"{f['translation_m']:.4f} m" for f in out["filters"]), flush=True)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--logs", nargs="+", default=["intel", "fr079", "fr-clinic"], choices=list(FREIBURG))
    ap.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3])
    ap.add_argument("--datasets", default=os.environ.get("HSMAP_DATASETS", str(ROOT.parent / "shared" / "datasets")))
    ap.add_argument("--out", default=str(ROOT / "reports" / "benchmarks" / "motion_filter.json"))
    args = ap.parse_args(argv)
    out = {"benchmark": "motion_filter", "machine": machine(), "filters": FILTERS, "logs": {}}
    for name in args.logs:
        runs = [run_log(name, Path(args.datasets), s) for s in args.seeds]
        summary = {"every_scan_m": [r["every_scan"]["translation_m"] for r in runs]}
        for i, (d, a) in enumerate(FILTERS):
            v = np.array([r["filters"][i]["translation_m"] for r in runs])
            summary[f"{d}m_{a:g}deg"] = {"mean_m": float(v.mean()), "sd_m": float(v.std(ddof=1)) if len(v) > 1
                                         else 0.0, "worst_m": float(v.max()),
                                         "registered": [r["filters"][i]["registered"] for r in runs]}
        out["logs"][name] = {"runs": runs, "summary": summary}
    finish(out, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
