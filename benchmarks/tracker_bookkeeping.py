"""The 2D tracker's per-frame bookkeeping against a baseline checkout's, in one process, frame by frame alternated:
each stage's thread CPU time per call and per frame, and whether every frame's pose has the same bits.

The baseline's ``hsmap`` is copied to a temporary folder as ``hsmap_baseline`` and run beside this tree's on the
same frames (a Freiburg log's first ``--max-frames``, the default 2D configuration, one thread): the machine's
load then weighs on both alike. The bookkeeping is what ``HsSlam.process`` spends outside the registrations, the
keyframes' upkeep and the smoothing's scan matches (the stages in ``WORK``). Thread CPU time still grows with the
load (a shared core's caches): compare the two columns of one run, not runs.

    .venv/bin/python benchmarks/tracker_bookkeeping.py --input intel --max-frames 1500 --baseline /work/main
"""

from __future__ import annotations

import argparse
import functools
import importlib
import io
import os
import pickle
import shutil
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("RERUN_ANALYTICS", "0")
os.environ["HSMAP_THREADS"] = "1"  # the smoothing's scan matches inline, as with --threads 1

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

# (module under the package, class or None, function)
STAGES = [
    ("slam.tracker", "HsSlam", "process"),
    ("slam.tracker", None, "harmony_icp"),
    ("slam.search", "SearchBox", "widened"),
    ("slam.verify", "Verifier", "verify"),
    ("slam.verify", "Verifier", "_retry"),
    ("slam.verify", "Verifier", "fuse"),
    ("slam.prediction", "MotionPrediction", "seeds"),
    ("slam.prediction", "MotionPrediction", "predict"),
    ("slam.prediction", "MotionPrediction", "first_registration"),
    ("slam.prediction", "MotionPrediction", "kept_registration"),
    ("slam.prediction", "MotionPrediction", "advance"),
    ("slam.odometry", "OdometryModel", "learn_bias"),
    ("slam.odometry", "OdometryModel", "learn_scale"),
    ("slam.odometry", "OdometryModel", "accumulate_wheel"),
    ("slam.deskewing", "Deskewing", "points"),
    ("slam.keyframes", "KeyframeGraph", "ensure_target"),
    ("slam.keyframes", "KeyframeGraph", "add_keyframe"),
    ("slam.keyframes", "KeyframeGraph", "is_keyframe"),
    ("slam.keyframes", "KeyframeGraph", "attach"),
    ("slam.motions", "FrameMotions", "record"),
    ("slam.search", "SearchBox", "record"),
    ("slam.search", "SearchBox", "settled"),
]
#: The stages that are the frame's work rather than its bookkeeping (each called from process, not nested).
WORK = ["tracker.harmony_icp", "SearchBox.widened", "Verifier._retry", "KeyframeGraph.ensure_target",
        "KeyframeGraph.add_keyframe", "FrameMotions.record"]


class _Renamed(pickle.Unpickler):
    """Unpickles hsmap's objects as the package ``package``'s."""

    def __init__(self, data: bytes, package: str) -> None:
        super().__init__(io.BytesIO(data))
        self.package = package

    def find_class(self, module: str, name: str):
        if module == "hsmap" or module.startswith("hsmap."):
            module = self.package + module[len("hsmap"):]
        return super().find_class(module, name)


def _instrument(package: str) -> dict:
    """Wrap each stage's function in ``package`` with a thread CPU clock; returns stage -> [seconds, calls]."""
    clock: dict = {}
    for module, owner, fn in STAGES:
        mod = importlib.import_module(f"{package}.{module}")
        holder = getattr(mod, owner) if owner else mod
        orig = getattr(holder, fn)
        cell = clock.setdefault(f"{owner or module.split('.')[-1]}.{fn}", [0.0, 0])

        def timed(*a, __orig=orig, __cell=cell, **k):
            t0 = time.thread_time()
            try:
                return __orig(*a, **k)
            finally:
                __cell[0] += time.thread_time() - t0
                __cell[1] += 1

        functools.update_wrapper(timed, orig)
        setattr(holder, fn, timed)
    return clock


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--input", default="intel", choices=["intel", "fr079", "fr-clinic"])
    ap.add_argument("--max-frames", type=int, default=1500)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--baseline", required=True, help="the root of a checkout whose hsmap/ is the baseline")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    source = Path(args.baseline) / "hsmap"
    if not (source / "__init__.py").is_file():
        print(f"--baseline {args.baseline}: no hsmap package there (expected {source}/__init__.py)", file=sys.stderr)
        return 2

    import numpy as np
    from _report import finish, machine  # benchmarks/_report.py
    from slam import FREIBURG  # benchmarks/slam.py

    from hsmap.datasets.open import open_dataset
    from hsmap.study.paths import datasets_dir

    spec = FREIBURG[args.input]
    ds = open_dataset(datasets_dir() / "slam2d" / spec["bag"], extrinsic2d=spec["extrinsic2d"])
    n = min(len(ds), args.max_frames)
    data = pickle.dumps([f for _, f in zip(range(n), ds.frames(clouds=False), strict=False)])
    host = machine()
    with tempfile.TemporaryDirectory() as tmp:
        shutil.copytree(source, Path(tmp) / "hsmap_baseline", ignore=shutil.ignore_patterns("__pycache__"))
        sys.path.insert(0, tmp)
        packages = {"baseline": "hsmap_baseline", "this": "hsmap"}
        slams, frames, clocks, unusable = {}, {}, {}, {}
        for key, package in packages.items():
            slam_mod = importlib.import_module(f"{package}.slam")
            tracker = importlib.import_module(f"{package}.slam.tracker")
            warm = tracker.HsSlam(slam_mod.SlamConfig(dof=3), rng=args.seed)  # compile the kernels first
            for f in _Renamed(data, package).load()[:5]:
                warm.process(f)
            clocks[key] = _instrument(package)
            frames[key] = _Renamed(data, package).load()
            slams[key] = tracker.HsSlam(slam_mod.SlamConfig(dof=3), rng=args.seed)
            unusable[key] = importlib.import_module(f"{package}.errors").UnusableFrameError
        same = 0
        order = list(packages)
        for i in range(n):
            for key in order if i % 2 == 0 else order[::-1]:
                try:
                    slams[key].process(frames[key][i])
                except unusable[key]:
                    pass
            a, b = (slams[k].poses for k in order)
            same += len(a) == len(b) and np.asarray(a[-1]).tobytes() == np.asarray(b[-1]).tobytes()
    stages = {key: {name: {"seconds": s, "calls": c, "us_per_call": 1e6 * s / max(c, 1), "us_per_frame": 1e6 * s / n}
                    for name, (s, c) in clock.items()} for key, clock in clocks.items()}
    bookkeeping = {key: st["HsSlam.process"]["us_per_frame"] - sum(st[w]["us_per_frame"] for w in WORK)
                   for key, st in stages.items()}
    print(f"{args.input}: {n} frames, seed {args.seed}, {same} frames with the same pose bits in both")
    print(f"  {'stage':38s} {'baseline':>10s} {'this':>10s}  us per frame (thread CPU)")
    for name in stages["this"]:
        print(f"  {name:38s} {stages['baseline'][name]['us_per_frame']:10.1f} {stages['this'][name]['us_per_frame']:10.1f}")
    print(f"  {'bookkeeping (process less WORK)':38s} {bookkeeping['baseline']:10.1f} {bookkeeping['this']:10.1f}")
    out = {"benchmark": "tracker_bookkeeping", "input": args.input, "frames": n, "seed": args.seed,
           "baseline": str(Path(args.baseline).resolve()), "same_pose_bits_frames": int(same), "stages": stages,
           "bookkeeping_us_per_frame": bookkeeping, "work_stages": WORK, "machine": host}
    finish(out, Path(args.out or ROOT / "reports/benchmarks" / f"tracker_bookkeeping_{args.input}.json"))
    return 0 if same == n else 1


if __name__ == "__main__":
    sys.exit(main())
