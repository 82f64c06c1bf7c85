"""Room-segmentation benchmark on the maps of Bormann et al. (ICRA 2016): precision, recall and time per map.

The 15 buildings of ``$HSMAP_DATASETS/ipa_room_segmentation`` (default ../shared/datasets), each plain and
furnished (30 maps, 0.05 m per pixel, pixels >= 250 free), segmented with ONE configuration for all maps and
scored against the building's ground truth with the benchmark's metric (per-room mean and area-weighted
precision and recall, :func:`hsmap.evaluation.segmentation_scores`).

Methods, in this process, on the same maps:
- ``critical`` (hsmap default): critical points on the skeleton + narrowing test + merging;
- ``paper``: the paper's Algorithm 2 as published (band of half door widths 40 +/- 5 cm), same merging of
  small regions;
- ``critical+furniture``: the default plus the optional step that gives furniture enclosed by a room that
  room's label (full-room labels; not in the default configuration).

Times are wall-clock medians over ``--repeats`` runs of ``segment_rooms`` per map (map already in memory),
one map at a time, single process. Writes reports/benchmarks/segmentation.json (atomically), the step
figure of one map (reports/benchmarks/segmentation_steps_<map>.png) and prints the tables.

    .venv/bin/python benchmarks/segmentation.py [--repeats N] [--maps a,b] [--methods critical,paper]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import sys
from pathlib import Path

import numpy as np

os.environ.setdefault("RERUN_ANALYTICS", "0")

import hsmap  # noqa: E402
from hsmap.config import to_dict  # noqa: E402
from hsmap.grid import FREE, OCCUPIED, OccupancyGrid, read_image_gray  # noqa: E402
from hsmap.io import atomic_path, write_json  # noqa: E402
from hsmap.segmentation import SegmentationConfig, segment_rooms  # noqa: E402
from hsmap.study.benchmarks import BORMANN_BUILDINGS, room_segmentation_benchmark, summarise_segmentation  # noqa: E402
from hsmap.study.paths import datasets_dir  # noqa: E402

TARGETS = {"plain": {"recall": 0.90, "precision": 0.90}, "furnished": {"recall": 0.80, "precision": 0.90}}
RESOLUTION = 0.05


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--datasets", default=str(datasets_dir()))
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--maps", default=",".join(BORMANN_BUILDINGS), help="comma-separated building names")
    ap.add_argument("--methods", default="critical,paper,critical+furniture")
    ap.add_argument("--figure-map", default="Freiburg52_scan_furnitures",
                    help="map whose step-by-step figure is written ('' for none)")
    ap.add_argument("--out", default="reports/benchmarks/segmentation.json")
    args = ap.parse_args(argv)
    folder = Path(args.datasets) / "ipa_room_segmentation"
    if not folder.is_dir():
        print(f"benchmark data not found: {folder} (set HSMAP_DATASETS)", file=sys.stderr)
        return 2
    maps = [m for m in args.maps.split(",") if m]
    configs = {
        "critical": SegmentationConfig(),
        "paper": dataclasses.replace(SegmentationConfig(), method="paper"),
        "critical+furniture": dataclasses.replace(SegmentationConfig(), assign_furniture=True),
    }
    methods = [m for m in args.methods.split(",") if m]
    result = {
        "benchmark": "ipa_room_segmentation (Bormann et al. 2016), 15 buildings x {plain, furnished}",
        "metric": "per-room mean precision/recall (area-weighted beside), averaged over maps; "
                  "GT rooms = 8-connected regions of GT > 250 larger than 100 px",
        "targets": TARGETS,
        "resolution": RESOLUTION,
        "repeats": args.repeats,
        "hsmap_version": hsmap.__version__,
        "machine": {"python": platform.python_version(), "platform": platform.platform(),
                    "cpus": os.cpu_count()},
        "methods": {},
    }
    for m in methods:
        print(f"method {m}:", flush=True)
        rows = room_segmentation_benchmark(folder, maps, config=configs[m], resolution=RESOLUTION,
                                           repeats=args.repeats, log=lambda line, m=m: print(f"  {m:18s} {line}", flush=True))
        rows = [{"method": m, **r} for r in rows]
        result["methods"][m] = {"config": to_dict(configs[m]), "summary": summarise_segmentation(rows), "maps": rows}

    if args.figure_map:
        from hsmap.viz.map_figures import voronoi_steps_figure

        name = args.figure_map
        free = read_image_gray(folder / f"{name}.png") >= 250
        seg = segment_rooms(free, RESOLUTION, config=configs[methods[0]], keep_steps=True)
        grid = OccupancyGrid(np.where(free, FREE, OCCUPIED), seg.geometry)
        fig = voronoi_steps_figure(grid, seg, title=f"{name}: segmentation steps ({methods[0]})")
        fig_path = Path(args.out).with_name(f"segmentation_steps_{name}.png")
        fig_path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(fig_path) as tmp:
            fig.savefig(tmp, dpi=110)
        result["figure"] = str(fig_path)
    write_json(args.out, result)

    # tables
    for m in methods:
        rows = result["methods"][m]["maps"]
        print(f"\n{m}: per map (P = precision, R = recall, per-room means; t = median seconds)")
        print(f"{'building':18s} {'plain P':>8s} {'plain R':>8s} {'t':>6s}   {'furn P':>7s} {'furn R':>7s} {'t':>6s}")
        for n in maps:
            a = next(x for x in rows if x["map"] == n)
            b = next(x for x in rows if x["map"] == n + "_furnitures")
            print(f"{n:18s} {a['precision']:8.3f} {a['recall']:8.3f} {a['seconds']:6.2f}   "
                  f"{b['precision']:7.3f} {b['recall']:7.3f} {b['seconds']:6.2f}")
    print("\nsummary (means over maps; targets plain P,R >= 0.90; furnished R >= 0.80, P >= 0.90)")
    print(f"{'method':18s} {'kind':10s} {'P':>6s} {'R':>6s} {'P_area':>7s} {'R_area':>7s} {'t_med':>6s} {'t_max':>6s}")
    for m in methods:
        for kind, s in result["methods"][m]["summary"].items():
            if kind == "all":
                continue
            print(f"{m:18s} {kind:10s} {s['precision']:6.3f} {s['recall']:6.3f} {s['precision_area']:7.3f} "
                  f"{s['recall_area']:7.3f} {s['seconds_median']:6.2f} {s['seconds_max']:6.2f}")
    print(f"\nwrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
