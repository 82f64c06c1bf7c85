"""Noise models: how uncertain are a log's registrations and its odometry, measured against each other?

HS-SLAM fuses each registration with the odometry's prediction, weighted by the registration's information
(Gauss-Newton, floored at ``loop_closure.edge_sigma_*``) and the configured odometry model
(``SlamConfig.odometry_sigma``). This script runs the command line's default configuration on a Freiburg log and
records, for every frame, the disagreement d between its first registration and the raw odometry's prediction
(in the prediction's frame, per component x, y, yaw), the registration's variance (the inverse of its information,
before the floor) and the odometry model's variance. If both were right, d would be distributed with variance
``v_reg + v_odo``. It fits one scale per sigma, ``d ~ t_nu(0, k^2 v_reg + l^2 v_odo)`` by maximum likelihood
(Student-t, nu = 3, so that wheel slips and failed registrations do not decide the fit), and reports k and l per
component: k > 1 means the registration claims too little uncertainty, l < 1 that the odometry is better than its
model.

It is a diagnosis, not part of HS-SLAM: d also holds the previous fused pose's error, and where one source's
variance is small against the other's the fit cannot tell its scale (it runs to the bound). What it found on each
log is in ``docs/slam-results.md``.

    .venv/bin/python benchmarks/noise_models.py fr-clinic --seed 1

Writes reports/benchmarks/noise_models_<log>.json (atomically).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from _report import finish, machine  # noqa: E402  (benchmarks/_report.py)
from slam import FREIBURG  # noqa: E402

from hsmap.datasets.open import open_dataset  # noqa: E402
from hsmap.geometry import compose, relative, wrap_angle  # noqa: E402
from hsmap.slam import MotionPrediction, SlamConfig, run_slam  # noqa: E402
from hsmap.study.paths import datasets_dir  # noqa: E402

NU = 3.0
COMPONENTS = ("x", "y", "yaw")


def record(log: str, seed: int, max_frames: int | None) -> np.ndarray:
    """Per frame with odometry and a registration: d (x, y, yaw), registration variances, odometry variances."""
    spec = FREIBURG[log]
    ds = open_dataset(datasets_dir() / "slam2d" / spec["bag"], extrinsic2d=spec["extrinsic2d"])
    frames = [f for _, f in zip(range(max_frames or len(ds)), ds.frames(clouds=False), strict=False)]
    rows: list[list[float]] = []
    learn = MotionPrediction.first_registration

    def recording(self, res):
        step = self.odometry.step(self.frame)
        if step is not None and res.information is not None:
            st, sr = self.odometry.model_sigmas(step)
            d = relative(compose(self.poses[-1], step), res.pose)
            d[2] = wrap_angle(d[2])
            try:
                cov = np.diag(np.linalg.inv(res.information))
            except np.linalg.LinAlgError:
                cov = np.full(3, np.nan)
            rows.append([*d, *cov, st * st, st * st, sr * sr])
        return learn(self, res)

    MotionPrediction.first_registration = recording
    try:
        run_slam(frames, SlamConfig(dof=3), rng=seed, progress=False)
    finally:
        MotionPrediction.first_registration = learn
    return np.asarray(rows)


def fit_scales(d: np.ndarray, v_reg: np.ndarray, v_odo: np.ndarray) -> tuple[float, float, int]:
    """(k, l, frames): d ~ Student-t(nu, scale^2 = k^2 v_reg + l^2 v_odo), maximum likelihood."""
    ok = np.isfinite(d) & np.isfinite(v_reg) & (v_reg > 0) & (v_odo > 0)
    d, v_reg, v_odo = d[ok], v_reg[ok], v_odo[ok]

    def nll(p):
        v = np.exp(p[0]) * v_reg + np.exp(p[1]) * v_odo
        return float(np.sum(0.5 * np.log(v) + 0.5 * (NU + 1) * np.log1p(d * d / (NU * v))))

    best = min((minimize(nll, x0, method="Nelder-Mead") for x0 in ([0, 0], [3, -3], [-3, 3], [5, 0])),
               key=lambda r: r.fun)
    k2, l2 = np.exp(best.x)
    return float(np.sqrt(k2)), float(np.sqrt(l2)), int(ok.sum())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("log", choices=list(FREIBURG))
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    host = machine()
    rows = record(a.log, a.seed, a.max_frames)
    out = {"benchmark": "noise_models", "log": a.log, "seed": a.seed, "nu": NU, "frames": len(rows),
           "machine": host, "components": {}}
    for i, name in enumerate(COMPONENTS):
        k, l_, n = fit_scales(rows[:, i], rows[:, 3 + i], rows[:, 6 + i])
        unit, f = ("deg", np.degrees) if name == "yaw" else ("m", float)
        out["components"][name] = {
            "registration_sigma_scale": k, "odometry_sigma_scale": l_, "frames": n,
            f"median_abs_disagreement_{unit}": float(f(np.median(np.abs(rows[:, i])))),
            f"median_registration_sigma_{unit}": float(f(np.nanmedian(np.sqrt(rows[:, 3 + i])))),
            f"median_odometry_model_sigma_{unit}": float(f(np.median(np.sqrt(rows[:, 6 + i])))),
        }
        print(f"{a.log} {name}: registration sigma x{k:.2f}, odometry model sigma x{l_:.3f} ({n} frames)")
    path = a.out or ROOT / "reports" / "benchmarks" / f"noise_models_{a.log}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    finish(out, path)


if __name__ == "__main__":
    main()
