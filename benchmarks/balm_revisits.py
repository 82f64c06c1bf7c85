"""The BALM reference checked by direct registrations of revisits, beside 6-DOF estimates of the same sweeps.

BALM's reference poses (``alidarPose.csv``) are a lidar-inertial estimate, not a survey. Sweeps far apart in time
but near in space (:func:`hsmap.study.revisits.revisit_pairs` on the reference: every 6th sweep, at least 30
sweeps apart, at most 8 m apart) are registered to each other directly by small_gicp's GICP (0.1 m voxels,
correspondences within 0.5 m) from the relative pose of the reference and of every estimate given; a pair whose
registrations from those starts end more than 1 cm apart is left out. Each trajectory's relative poses between
the pairs' sweeps are then compared with the registrations (:func:`hsmap.study.revisits.revisit_agreement`):
translation (m) and rotation angle (deg). Each estimate is also scored as ``benchmarks/peers3d.py`` scores it
(ATE RMSE after SE(3), largest roll/pitch/yaw error) against the reference and against the reference with its
drift between the revisits taken out (:func:`hsmap.study.revisits.corrected_reference`), which is itself scored
against the reference.

The sweeps are read as ``hsmap slam`` reads them (:func:`hsmap.study.real_sweeps.open_sweeps`) and cut to
HS-SLAM's ranges (:class:`hsmap.slam.SlamConfig`'s ``min_range``, ``max_range``). Writes
reports/benchmarks/balm_revisits.json (atomically).

    .venv/bin/python benchmarks/balm_revisits.py --tum NAME=trajectory.tum [--tum ...] [--dataset DIR]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from _report import finish, machine  # noqa: E402

import hsmap  # noqa: E402
from hsmap.errors import InputError  # noqa: E402

MIN_GAP, MAX_DISTANCE, EVERY = 30, 8.0, 6


def at_sweeps(traj, ref) -> np.ndarray:
    """``traj``'s poses at the reference's sweeps (N, 4, 4), NaN where it has no pose within 1 ms of a sweep."""
    from hsmap.study.revisits import as_matrices

    M = np.full((len(ref), 4, 4), np.nan)
    t = traj.stamps
    k = np.searchsorted(ref.stamps, t)
    lo, hi = (k - 1).clip(0, len(ref) - 1), k.clip(0, len(ref) - 1)
    k = np.where(np.abs(ref.stamps[lo] - t) <= np.abs(ref.stamps[hi] - t), lo, hi)
    near = np.abs(ref.stamps[k] - t) <= 1e-3
    if not near.any():
        raise InputError("no pose of the trajectory lies within 1 ms of a reference sweep's stamp")
    M[k[near]] = as_matrices(traj)[near]
    return M


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", default=None, help="the BALM folder (default $HSMAP_DATASETS/balm)")
    ap.add_argument("--tum", action="append", default=[], metavar="NAME=FILE",
                    help="an estimate of the sweeps (TUM file), scored beside the reference; repeatable")
    ap.add_argument("--out", default=str(ROOT / "reports/benchmarks/balm_revisits.json"))
    args = ap.parse_args(argv)
    from hsmap.slam import SlamConfig
    from hsmap.study.real_sweeps import (
        balm_folder,
        missing_balm_reason,
        open_sweeps,
        read_reference,
        score_track,
        sweep_folder,
    )
    from hsmap.study.revisits import corrected_reference, register_revisits, revisit_agreement, revisit_pairs
    from hsmap.trajectory import read_tum

    estimates = {}
    for item in args.tum:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            print(f"--tum {item!r}: expected NAME=FILE", file=sys.stderr)
            return 2
        estimates[name] = read_tum(path).as_6dof()
    src = Path(args.dataset) if args.dataset else balm_folder()
    out: dict = {"benchmark": "balm_revisits", "machine": machine(), "hsmap_version": hsmap.__version__,
                 "command": " ".join([sys.executable, *sys.argv]),
                 "pairs_rule": {"min_gap_sweeps": MIN_GAP, "max_distance_m": MAX_DISTANCE, "every": EVERY,
                                "registration": "small_gicp GICP, 0.1 m voxels, 0.5 m correspondences, "
                                                "settled within 1 cm from every start"}}
    if src is None or not (src / "alidarPose.csv").is_file():
        out["skipped"] = missing_balm_reason() if src is None else f"no alidarPose.csv in {src}"
        finish(out, args.out)
        return 0
    ref = read_reference(src)
    starts = {"reference": at_sweeps(ref, ref), **{n: at_sweeps(t, ref) for n, t in estimates.items()}}
    present = np.all([np.isfinite(M[:, 0, 0]) for M in starts.values()], axis=0)
    pairs = revisit_pairs(ref, min_gap=MIN_GAP, max_distance=MAX_DISTANCE, every=EVERY)
    pairs = pairs[present[pairs].all(axis=1)]
    cfg = SlamConfig(dof=6)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="hsmap-revisits-") as tmp:
        folder = sweep_folder(src, Path(tmp) / "sweeps")
        needed = set(pairs.ravel().tolist())
        clouds = {}
        for i, f in enumerate(open_sweeps(folder).frames(clouds=True)):
            if i in needed:
                p = np.asarray(f.cloud3d, dtype=np.float64)
                r = np.linalg.norm(p, axis=1)
                clouds[i] = p[(r >= cfg.min_range) & (r <= cfg.max_range)]
    revisits = register_revisits(clouds.__getitem__, pairs, list(starts.values()))
    out["pairs"] = {"count": len(pairs), "settled": int(revisits.settled.sum()),
                    "spread_max_m": float(revisits.spread.max()) if len(pairs) else None,
                    "seconds": time.perf_counter() - t0}
    fixed = corrected_reference(ref, revisits)
    out["agreement"] = {n: revisit_agreement(M, revisits) for n, M in starts.items()}
    out["agreement"]["corrected_reference"] = revisit_agreement(fixed, revisits)
    out["against_reference"], out["against_corrected_reference"] = {}, {}
    for n, t in {"reference": ref, **estimates}.items():
        for key, against in (("against_reference", ref), ("against_corrected_reference", fixed)):
            if n == "reference" and key == "against_reference":
                continue
            s = score_track(t, against).summary
            e = s["max_abs_error"]
            out[key][n] = {"ate_rmse_m": s["ate_rmse_m"], "ate_max_m": s["ate_max_m"],
                           "rpy_max_deg": max(e["roll_deg"], e["pitch_deg"], e["yaw_deg"])}
    for n, a in out["agreement"].items():
        line = (f"{n}: {a['pairs']} pairs, off the direct registrations by {100 * a['translation_mean_m']:.1f} cm "
                f"mean, {100 * a['translation_max_m']:.1f} cm max, {a['rotation_mean_deg']:.3f} deg mean")
        for key, what in (("against_reference", "reference"), ("against_corrected_reference", "corrected")):
            if n in out[key]:
                line += (f"; against the {what} ATE {out[key][n]['ate_rmse_m']:.4f} m, rpy "
                         f"{out[key][n]['rpy_max_deg']:.2f} deg")
        print(line)
    finish(out, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
