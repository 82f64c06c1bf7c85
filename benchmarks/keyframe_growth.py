"""How a 2D HS-SLAM run's keyframe step grows over a whole log: the wall time of each of its parts (loop-candidate
search, loop matches, far searches, pair edges, graph optimisation, path distances, tracking-map rebuilds), and
the counted work (:class:`hsmap.slam.costs.Costs`), per block of frames.

A part's time goes to the block of the frame being processed when it ran (the final optimisation and the
smoothing after the last frame go to the last block). Each row is the inclusive time of the named function.

    .venv/bin/python benchmarks/keyframe_growth.py --input intel --seed 1
    .venv/bin/python benchmarks/keyframe_growth.py --input fr079 --block 500
"""

from __future__ import annotations

import argparse
import functools
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("RERUN_ANALYTICS", "0")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

# part -> (module, owner class, function name)
PARTS = {
    "frame": ("hsmap.slam.tracker", "HsSlam", "process"),
    "keyframe": ("hsmap.slam.keyframes", "KeyframeGraph", "add_keyframe"),
    "candidates": ("hsmap.slam.loopclosure", "LoopCloser", "candidates"),
    "far_candidates": ("hsmap.slam.loopclosure", "LoopCloser", "far_candidates"),
    "loop_match": ("hsmap.slam.loopclosure", "LoopCloser", "attempt"),
    "far_match": ("hsmap.slam.loopclosure", "LoopCloser", "attempt_far"),
    "pair_edges": ("hsmap.slam.keyframes", "KeyframeGraph", "_pair_edges"),
    "optimize": ("hsmap.slam.keyframes", "KeyframeGraph", "optimize"),
    "path_distances": ("hsmap.slam.posegraph", "PoseGraph", "path_distances"),
    "map_rebuild": ("hsmap.slam.keyframes", "KeyframeGraph", "_rebuild_map"),
    "ensure_target": ("hsmap.slam.keyframes", "KeyframeGraph", "ensure_target"),
}
COUNTED = ("registrations", "refinements", "loop_searches", "far_searches", "optimizations",
           "optimization_iterations", "map_rebuilds", "points_inserted")


def _instrument(table: dict, block: list) -> list:
    """Wrap each part's function with a clock adding to ``table[part][block[0]]``; returns the undo list."""
    import importlib

    undo = []
    for name, (module, owner, fn) in PARTS.items():
        holder = getattr(importlib.import_module(module), owner)
        orig = getattr(holder, fn)
        table[name] = {}

        def timed(*a, __orig=orig, __name=name, **k):
            t0 = time.perf_counter()
            try:
                return __orig(*a, **k)
            finally:
                row = table[__name].setdefault(block[0], [0.0, 0])
                row[0] += time.perf_counter() - t0
                row[1] += 1

        functools.update_wrapper(timed, orig)
        setattr(holder, fn, timed)
        undo.append((holder, fn, orig))
    return undo


def run_once(frames, seed: int, size: int, threads: int) -> dict:
    from hsmap.slam import SlamConfig
    from hsmap.slam.tracker import HsSlam

    table: dict = {}
    block = [0]
    costs: dict[int, dict] = {}
    undo = _instrument(table, block)
    try:
        from hsmap._threads import using_threads

        with using_threads(threads):
            t0, c0 = time.perf_counter(), time.process_time()
            slam = HsSlam(SlamConfig(dof=3), rng=seed)
            for i, f in enumerate(frames):
                block[0] = i // size
                if i % size == 0 and i:
                    costs[i // size - 1] = slam.costs.as_dict()
                slam.process(f)
            slam.finish()
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            costs[block[0]] = slam.costs.as_dict()
    finally:
        for holder, fn, orig in undo:
            setattr(holder, fn, orig)
    n_blocks = block[0] + 1
    rows = []
    prev = dict.fromkeys(COUNTED, 0)
    for b in range(n_blocks):
        c = costs[b]
        row = {"frames": [b * size, min((b + 1) * size, len(frames))],
               "seconds": {k: round(table[k].get(b, [0.0, 0])[0], 3) for k in PARTS},
               "calls": {k: table[k].get(b, [0.0, 0])[1] for k in PARTS},
               "counts": {k: c[k] - prev[k] for k in COUNTED}}
        prev = c
        rows.append(row)
    return {"seed": seed, "wall_seconds": wall, "cpu_seconds": cpu, "keyframes": len(slam.keyframes), "blocks": rows,
            "costs": slam.costs.as_dict(), "loop_closure": slam.keyframe_graph.summary(),
            "trajectory": slam.trajectory}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--input", default="intel", choices=["intel", "fr079", "fr-clinic"])
    ap.add_argument("--max-frames", type=int, default=0, help="0: the whole log")
    ap.add_argument("--block", type=int, default=1000, help="frames per row")
    ap.add_argument("--seed", type=int, nargs="+", default=[1])
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)

    from _report import finish, machine  # benchmarks/_report.py
    from slam import _relations, freiburg_frames  # benchmarks/slam.py

    from hsmap.slam import SlamConfig, run_slam
    from hsmap.study.paths import datasets_dir

    frames, rel, _ = freiburg_frames(args.input, datasets_dir(), args.max_frames)
    n = len(frames)
    run_slam(frames[:5], SlamConfig(dof=3), rng=1, progress=False)  # compile the kernels first
    runs = []
    for seed in args.seed:
        r = run_once(frames, seed, args.block, args.threads)
        r["relations"] = _relations(r.pop("trajectory"), rel, True)
        runs.append(r)
        t = r["relations"]["all"]["translation_m"]["mean"]
        print(f"{args.input} seed {seed}: {n} frames, {r['keyframes']} keyframes, {r['wall_seconds']:.1f} s wall, {r['cpu_seconds']:.1f} s CPU, "
              f"relations {t:.4f} m")
        print("  frames       " + " ".join(f"{k[:9]:>9s}" for k in PARTS))
        for row in r["blocks"]:
            print(f"  {row['frames'][0]:5d}-{row['frames'][1]:5d}" + " ".join(
                f"{row['seconds'][k]:9.2f}" for k in PARTS))
        print("  counts       " + " ".join(f"{k[:9]:>9s}" for k in COUNTED))
        for row in r["blocks"]:
            print(f"  {row['frames'][0]:5d}-{row['frames'][1]:5d}" + " ".join(
                f"{row['counts'][k]:9d}" for k in COUNTED))
        print("  loop closure:", r["loop_closure"], flush=True)
    out = {"benchmark": "keyframe_growth", "input": args.input, "frames": n, "block": args.block,
           "threads": args.threads, "runs": runs, "machine": machine()}
    finish(out, Path(args.out or ROOT / "reports/benchmarks" / f"keyframe_growth_{args.input}.json"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
