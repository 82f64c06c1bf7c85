"""Registration benchmark: basin of convergence and time per registration, Harmony-ICP beside its peers.

For offsets of growing magnitude (translation in a random direction, yaw of random sign, and in 3D small roll
and pitch), each method registers a source scan taken at the offset pose to a target scan, with no initial
guess. A trial succeeds when the recovered transform is within 3 cm and 0.5 deg of the truth.

Methods, all in this process, on the same pairs:
- ``harmony_icp``: hsmap's Harmony-ICP (global search + local refinement), no initial guess.
- ``harmony_no_refinement``: the same global search with a second, fine Harmony Search stage instead of ICP.
- ``o3d_icp_p2p`` / ``o3d_icp_p2plane``: Open3D ICP from the identity (2D scans lifted to z = 0; the 2D
  point-to-plane variant gets a second copy of the scan at z = 1 m so that the system is not singular in roll and
  pitch).
- ``o3d_ransac_fpfh`` (3D): Open3D RANSAC on FPFH features, then point-to-plane ICP.
- ``differential_evolution``: scipy's differential evolution on the same two-term fitness and distance field,
  then the same refinement as Harmony-ICP.

Data: 2D, a Hokuyo-like scan (270 deg, 0.25 deg steps, 1081 beams, 10 m, 1 cm noise) of a furnished room,
against another; 3D, clouds of about 5,000 points of a furnished room (1 cm noise), each sampled independently.

Writes reports/benchmarks/registration.json (atomically) and prints a table. Times are medians over the trials
of each level, wall clock, in one process, one registration at a time.

    .venv/bin/python benchmarks/registration.py [--trials N] [--quick]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("RERUN_ANALYTICS", "0")

from _report import finish, machine  # noqa: E402  (benchmarks/_report.py)

import hsmap  # noqa: E402
from hsmap.config import to_dict  # noqa: E402
from hsmap.geometry import matrix_to_pose, relative, wrap_angle  # noqa: E402
from hsmap.registration.fitness import score  # noqa: E402
from hsmap.registration.icp import (  # noqa: E402
    RegistrationConfig,
    RegistrationTarget,
    _subsample,
    default_bounds,
    harmony_icp,
    refine_icp,
)
from hsmap.testing import raycast_2d, room_cloud_3d, room_segments, scan_points_2d, sensor_cloud  # noqa: E402

SUCCESS_T = 0.03
SUCCESS_R = 0.5  # degrees
LEVELS_2D = [(0.1, 5), (0.25, 11), (0.5, 22), (0.75, 34), (1.0, 45), (1.5, 60), (2.0, 90)]  # (m, deg)
LEVELS_3D = [(0.1, 5), (0.2, 10), (0.3, 15), (0.4, 22), (0.5, 30), (0.75, 45), (1.0, 60)]
TARGET_2D = (1.0, 45)
TARGET_3D = (0.5, 30)


def pairs_2d(level, trials, rng):
    segs = room_segments()
    t_mag, yaw_deg = level
    for _ in range(trials):
        p0 = np.array([4.0, 3.0, 0.0]) + np.r_[rng.uniform(-0.5, 0.5, 2), rng.uniform(-np.pi, np.pi)]
        a = rng.uniform(0, 2 * np.pi)
        p1 = p0 + np.r_[t_mag * np.cos(a), t_mag * np.sin(a), rng.choice([-1, 1]) * np.deg2rad(yaw_deg)]
        seed = int(rng.integers(1 << 30))
        tgt = scan_points_2d(*raycast_2d(segs, p0, noise=0.01, rng=seed))
        src = scan_points_2d(*raycast_2d(segs, p1, noise=0.01, rng=seed + 1))
        yield src, tgt, relative(p0, p1)


def pairs_3d(level, trials, rng):
    t_mag, yaw_deg = level
    for _ in range(trials):
        p0 = np.r_[4.0 + rng.uniform(-0.5, 0.5), 3.0 + rng.uniform(-0.5, 0.5), 1.6, 0, 0, rng.uniform(-np.pi, np.pi)]
        a = rng.uniform(0, 2 * np.pi)
        off = np.r_[t_mag * np.cos(a), t_mag * np.sin(a), rng.uniform(-0.05, 0.05),
                    np.deg2rad(rng.uniform(-3, 3, 2)), rng.choice([-1, 1]) * np.deg2rad(yaw_deg)]
        p1 = p0 + off
        seed = int(rng.integers(1 << 30))
        tgt = sensor_cloud(room_cloud_3d(5000, viewpoint=p0[:3], noise=0.01, rng=seed), p0)
        src = sensor_cloud(room_cloud_3d(5000, viewpoint=p1[:3], noise=0.01, rng=seed + 1), p1)
        yield src, tgt, relative(p0, p1)


# ----------------------------------------------------------------------------------------------- methods
def m_harmony(src, tgt, rng):
    return harmony_icp(src, tgt, rng=rng).pose


def m_harmony_no_refinement(src, tgt, rng):
    """Harmony Search alone (a fine second stage at 0.1 m instead of ICP): does the refinement earn its place?"""
    return harmony_icp(src, tgt, config=RegistrationConfig(refinement="none", fine_threshold=0.1), rng=rng).pose


def _lift(points, layers=(0.0,)):
    return np.concatenate([np.column_stack([points, np.full(len(points), z)]) for z in layers])


def _o3d_icp(src, tgt, plane: bool):
    import open3d as o3d

    reg = o3d.pipelines.registration
    dim = src.shape[1]
    layers = (0.0, 1.0) if (dim == 2 and plane) else (0.0,)
    s3 = _lift(src, layers) if dim == 2 else src
    t3 = _lift(tgt, layers) if dim == 2 else tgt
    s = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(s3))
    t = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(t3))
    if plane and dim == 2:  # normals of a vertical extrusion: the scan's line normals, horizontal
        n2 = RegistrationTarget(tgt).normals
        t.normals = o3d.utility.Vector3dVector(np.column_stack([np.tile(n2, (len(layers), 1)),
                                                                np.zeros(len(t3))]))
    elif plane:
        t.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(12))
    est = reg.TransformationEstimationPointToPlane() if plane else reg.TransformationEstimationPointToPoint()
    crit = reg.ICPConvergenceCriteria(max_iteration=60)
    T = np.asarray(reg.registration_icp(s, t, 0.5, np.eye(4), est, crit).transformation)
    if dim == 2:
        return np.array([T[0, 3], T[1, 3], np.arctan2(T[1, 0], T[0, 0])])
    return matrix_to_pose(T)


def m_o3d_p2p(src, tgt, rng):
    return _o3d_icp(src, tgt, plane=False)


def m_o3d_p2plane(src, tgt, rng):
    return _o3d_icp(src, tgt, plane=True)


def m_ransac_fpfh(src, tgt, rng):
    import open3d as o3d

    reg = o3d.pipelines.registration
    voxel = 0.1

    def prep(p):
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p)).voxel_down_sample(voxel)
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
        f = reg.compute_fpfh_feature(pc, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100))
        return pc, f

    o3d.utility.random.seed(int(rng.integers(1 << 30)))
    s, fs = prep(src)
    t, ft = prep(tgt)
    res = reg.registration_ransac_based_on_feature_matching(
        s, t, fs, ft, True, 1.5 * voxel, reg.TransformationEstimationPointToPoint(False), 3,
        [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(1.5 * voxel)],
        reg.RANSACConvergenceCriteria(100000, 0.999))
    target = RegistrationTarget(tgt)
    return refine_icp(src, target, matrix_to_pose(np.asarray(res.transformation)), max_distance=0.1,
                      start_distance=0.25)


def m_differential_evolution(src, tgt, rng):
    from scipy.optimize import differential_evolution

    cfg = RegistrationConfig()
    target = RegistrationTarget(tgt, cfg)
    lookup = target.lookup(cfg.search_threshold)
    dim = src.shape[1]
    sample = _subsample(src, cfg.voxel_size or (0.05 if dim == 2 else 0.1), cfg.max_points, rng)
    bounds = default_bounds(np.zeros((1, 3 if dim == 2 else 6)), cfg)

    def f(X):  # vectorized: X has shape (D, S)
        return score(X.T, sample, lookup, cfg.inlier_weight).value

    res = differential_evolution(f, bounds, vectorized=True, updating="deferred", popsize=15, maxiter=200,
                                 tol=1e-6, polish=False, seed=rng, init="latinhypercube")
    return refine_icp(src, target, res.x, max_distance=cfg.threshold, start_distance=cfg.search_threshold / 2,
                      iterations=cfg.refine_iterations)


METHODS_2D = {"harmony_icp": m_harmony, "harmony_no_refinement": m_harmony_no_refinement, "o3d_icp_p2p": m_o3d_p2p, "o3d_icp_p2plane": m_o3d_p2plane,
              "differential_evolution": m_differential_evolution}
METHODS_3D = {"harmony_icp": m_harmony, "harmony_no_refinement": m_harmony_no_refinement, "o3d_icp_p2p": m_o3d_p2p, "o3d_icp_p2plane": m_o3d_p2plane,
              "o3d_ransac_fpfh": m_ransac_fpfh, "differential_evolution": m_differential_evolution}


def run_suite(name, levels, make_pairs, methods, trials, seed, target_level):
    print(f"\n== {name}: success rate (< {SUCCESS_T * 100:.0f} cm and < {SUCCESS_R} deg) and median ms per "
          f"registration, {trials} trials per level")
    rows = []
    header = f"{'offset':>12} " + " ".join(f"{m[:22]:>24}" for m in methods)
    print(header)
    for level in levels:
        pairs = list(make_pairs(level, trials, np.random.default_rng([seed, int(level[0] * 1000)])))
        row = {"translation_m": level[0], "yaw_deg": level[1], "methods": {}}
        for mname, fn in methods.items():
            ok, times, t_errs, r_errs = 0, [], [], []
            for k, (src, tgt, truth) in enumerate(pairs):
                rng = np.random.default_rng([seed, k])
                t0 = time.perf_counter()
                pose = np.asarray(fn(src, tgt, rng))
                times.append(time.perf_counter() - t0)
                d = pose - truth
                h = len(truth) // 2
                te = float(np.linalg.norm(d[:h]))
                re = float(np.rad2deg(np.abs(wrap_angle(d[h:])).max()))
                t_errs.append(te)
                r_errs.append(re)
                ok += te < SUCCESS_T and re < SUCCESS_R
            row["methods"][mname] = {
                "success_rate": ok / len(pairs),
                "median_ms": 1000 * float(np.median(times)),
                "median_translation_error_m": float(np.median(t_errs)),
                "median_rotation_error_deg": float(np.median(r_errs)),
                "trials": len(pairs),
            }
        rows.append(row)
        cells = " ".join(f"{100 * v['success_rate']:>10.1f}% {v['median_ms']:>9.1f} ms"
                         for v in row["methods"].values())
        print(f"{level[0]:>5.2f} m {level[1]:>3d}d {cells}")
    within = [r for r in rows if r["translation_m"] <= target_level[0] + 1e-9]
    summary = {}
    for mname in methods:
        n = sum(r["methods"][mname]["trials"] for r in within)
        succ = sum(r["methods"][mname]["success_rate"] * r["methods"][mname]["trials"] for r in within)
        times = [r["methods"][mname]["median_ms"] for r in within]
        summary[mname] = {"success_rate_within_target_range": succ / n, "trials": n,
                          "median_ms_over_levels": float(np.median(times))}
    print(f"within {target_level[0]} m / {target_level[1]} deg: " + ", ".join(
        f"{m} {100 * s['success_rate_within_target_range']:.1f}% ({s['median_ms_over_levels']:.1f} ms)"
        for m, s in summary.items()))
    return {"levels": rows, "summary_within_target_range": summary,
            "target_range": {"translation_m": target_level[0], "yaw_deg": target_level[1]}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=40, help="pairs per offset level (default 40)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true", help="5 trials per level, for a smoke run")
    ap.add_argument("--only", choices=["2d", "3d"], default=None)
    ap.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "reports/benchmarks/registration.json"))
    args = ap.parse_args(argv)
    trials = 5 if args.quick else args.trials
    # warm-up: JIT compilation and imports are not part of any timing
    for fn in (m_harmony, m_o3d_p2p, m_o3d_p2plane, m_differential_evolution):
        src, tgt, _ = next(pairs_2d((0.1, 5), 1, np.random.default_rng(99)))
        fn(src, tgt, np.random.default_rng(0))
        src, tgt, _ = next(pairs_3d((0.1, 5), 1, np.random.default_rng(99)))
        fn(src, tgt, np.random.default_rng(0))
    out = {
        "benchmark": "registration",
        "success": {"translation_m": SUCCESS_T, "rotation_deg": SUCCESS_R},
        "machine": machine(),
        "hsmap_version": hsmap.__version__,
        "trials_per_level": trials,
        "config": to_dict(RegistrationConfig()),
    }
    t0 = time.perf_counter()
    if args.only in (None, "2d"):
        out["2d"] = run_suite("2D: 1081-beam scan vs scan", LEVELS_2D, pairs_2d, METHODS_2D, trials, args.seed,
                              TARGET_2D)
    if args.only in (None, "3d"):
        out["3d"] = run_suite("3D: room clouds of ~5000 points", LEVELS_3D, pairs_3d, METHODS_3D, trials,
                              args.seed, TARGET_3D)
    out["seconds"] = time.perf_counter() - t0
    print(f"\nin {out['seconds']:.0f} s")
    finish(out, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
