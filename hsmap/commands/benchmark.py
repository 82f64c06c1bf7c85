"""Benchmarks of the paper's chain, run as a distributed batch on Dask.

``hsmap benchmark buildings --out DIR``: every floor plan of --maps (the Bormann et al. format: NAME.png,
NAME_furnitures.png, NAME_gt_segmentation.png, 0.05 m per pixel; default the ipa_room_segmentation folder of the
benchmark data) becomes a 3D world (walls to the 2.8 m ceiling, seeded furniture 0.4-1.5 m high, lintels at
2.05 m over the ground truth's doorway borders); the robot explores every ground-truth room with the paper's two
LiDARs and drifting wheel odometry; the chain (2D HS-SLAM, 6-DOF HS-SLAM seeded by it, the floor-level grid and
the 1.7-1.8 m slice grid, one segmentation on both) runs on it; both segmentations are scored against the ground
truth (Bormann's per-room mean precision and recall). One Dask task per building stage (simulate, chain, score)
on a local cluster of --workers processes, or on the cluster of --scheduler. Each building's DIR/NAME/result.json
is written atomically as it finishes (a rerun skips finished buildings; a failed one is recorded with its error
and the others go on); DIR/results.json and DIR/table.md at the end. Exit status 1 when a building failed.
"""

from __future__ import annotations

import argparse

NAME = "benchmark"
HELP = "benchmarks of the paper's chain as a distributed batch (buildings: floor-plan worlds on Dask)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="benchmark", metavar="BENCHMARK", required=True)
    b = sub.add_parser("buildings", help="the paper's Table 2 on floor-plan worlds, one Dask job per building",
                       description=__doc__)
    b.add_argument("--out", required=True, help="output folder (per-building folders, results.json, table.md)")
    b.add_argument("--maps", default=None,
                   help="folder of floor plans (default: ipa_room_segmentation/ of the benchmark data)")
    b.add_argument("--only", nargs="+", default=None, metavar="NAME", help="run only these buildings")
    where = b.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=2, help="processes of the local Dask cluster (default 2)")
    where.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="address of a running Dask scheduler (tcp://HOST:8786); its workers must see --out")
    b.add_argument("--quick", action="store_true", help="a 32 x 512 3D LiDAR (smoke runs)")
    b.add_argument("--seed", type=int, default=0, help="seed of the furniture, odometry slip, noise and HS-SLAM")


def run(args: argparse.Namespace) -> int:
    import json
    from pathlib import Path

    from ..errors import InputError
    from ..io import prepare_output_dir
    from ..study.buildings import run_buildings

    if args.seed < 0:
        raise InputError(f"--seed must be >= 0, got {args.seed}")
    if args.scheduler is None and args.workers < 1:
        raise InputError(f"--workers must be >= 1, got {args.workers}")
    if args.maps is None:
        from ..study.paths import datasets_dir

        args.maps = datasets_dir() / "ipa_room_segmentation"
    maps = Path(args.maps)
    if not maps.is_dir():
        raise InputError(f"--maps {maps}: no such folder (run `hsmap data fetch bormann`, or give --maps)")
    prepare_output_dir(args.out, "--out", create=True)
    results = run_buildings(maps, args.out, only=args.only, workers=args.workers, scheduler=args.scheduler,
                            quick=args.quick, seed=args.seed, progress=None, log=print)
    print((Path(args.out) / "table.md").read_text(encoding="utf-8"))
    print(json.dumps(results["mean"]))
    return 1 if any(r["status"] != "ok" for r in results["buildings"]) else 0
