"""Room-segmentation benchmark on the maps of Bormann et al. (ICRA 2016): precision, recall, segments and time per map.

The 15 buildings of ``$HSMAP_DATASETS/ipa_room_segmentation`` (default ../shared/datasets), each plain and
furnished (30 maps, 0.05 m per pixel, pixels >= 250 free), segmented with ONE configuration for all maps and
scored against the building's ground truth with the benchmark's metric in both forms
(:func:`hsmap.evaluation.segmentation_scores`): the mean of ratios (per segment / per room, the benchmark's
tables; one merged segment costs one segment's precision) and area-weighted (a merged segment costs its area),
per map and as the mean over maps, beside the number of segments and of ground-truth rooms.

Methods, in this process, on the same maps:
- ``critical`` (hsmap default): critical points on the skeleton judged by the narrowing test, and gaps in
  walls narrow relative to the spaces they join;
- ``narrowing-only``: the previous default, critical points and the narrowing test only (half widths up to
  0.75 m, ratio 0.7): rooms opening onto a corridor through wider gaps are merged with it;
- ``paper``: the paper's Algorithm 2 as published (band of half door widths 40 +/- 5 cm), same merging of
  small regions;
- ``critical+furniture``: the default plus the optional step that gives furniture enclosed by a room that
  room's label (full-room labels; not in the default configuration).

Times are wall-clock medians over ``--repeats`` runs of ``segment_rooms`` per map (map already in memory, the
numba kernels loaded by a first call on a small map), one map at a time, single process. Writes reports/benchmarks/segmentation.json (atomically), the step
figure of one map (reports/benchmarks/segmentation_steps_<map>.png) and prints the tables, with the targets
(``TARGETS``) checked for the default method.

    .venv/bin/python benchmarks/segmentation.py [--repeats N] [--maps a,b] [--methods critical,paper]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
from pathlib import Path

import numpy as np

os.environ.setdefault("RERUN_ANALYTICS", "0")

from _report import finish, machine  # noqa: E402  (benchmarks/_report.py)

import hsmap  # noqa: E402
from hsmap.config import to_dict  # noqa: E402
from hsmap.io import atomic_path  # noqa: E402
from hsmap.maps.grid import FREE, OCCUPIED, OccupancyGrid, read_image_gray  # noqa: E402
from hsmap.rooms.segmentation import SegmentationConfig, segment_rooms  # noqa: E402
from hsmap.study.benchmarks import BORMANN_BUILDINGS, room_segmentation_benchmark, summarise_segmentation  # noqa: E402
from hsmap.study.paths import datasets_dir  # noqa: E402

NAMES = list(BORMANN_BUILDINGS)
#: The targets checked: means over the 15 buildings; times per map
TARGETS = {
    "plain": {"precision": 0.977, "recall": 0.985, "precision_area": 0.95},
    "furnished": {"precision": 0.975, "recall": 0.915, "precision_area": 0.95},
    "time_median_s": 0.5,
    "time_max_s": 3.0,
}
RESOLUTION = 0.05


def run_method(name: str, cfg: SegmentationConfig, folder: Path, maps: list[str], repeats: int) -> list[dict]:
    """hsmap.study's benchmark run of one method, after loading the numba kernels on a small map."""
    warm = np.zeros((60, 90), dtype=bool)
    warm[5:55, 5:40] = warm[5:55, 45:85] = warm[25:35, 40:45] = True
    segment_rooms(warm, RESOLUTION, config=cfg)
    rows = room_segmentation_benchmark(folder, maps, config=cfg, resolution=RESOLUTION, repeats=repeats,
                                       log=lambda line: print(f"  {name:18s} {line}", flush=True))
    return [{"method": name, **r} for r in rows]


def check_targets(summary: dict) -> dict[str, bool]:
    """Which of the ``TARGETS`` a method's summary meets."""
    ok = {}
    for kind in ("plain", "furnished"):
        if kind not in summary:
            continue
        for key, target in TARGETS[kind].items():
            ok[f"{kind} {key} >= {target}"] = summary[kind][key] >= target
    ok[f"median time <= {TARGETS['time_median_s']} s"] = summary["all"]["seconds_median"] <= TARGETS["time_median_s"]
    ok[f"largest time <= {TARGETS['time_max_s']} s"] = summary["all"]["seconds_max"] <= TARGETS["time_max_s"]
    return ok


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--datasets", default=str(datasets_dir()))
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--maps", default=",".join(NAMES), help="comma-separated building names")
    ap.add_argument("--methods", default="critical,narrowing-only,paper,critical+furniture")
    ap.add_argument("--figure-map", default="Freiburg52_scan_furnitures",
                    help="map whose step-by-step figure is written ('' for none)")
    ap.add_argument("--out", default="reports/benchmarks/segmentation.json")
    args = ap.parse_args(argv)
    folder = Path(args.datasets) / "ipa_room_segmentation"
    if not folder.is_dir():
        print(f"benchmark data not found: {folder} (run hsmap data fetch, or set HSMAP_DATASETS)", file=sys.stderr)
        return 2
    maps = [m for m in args.maps.split(",") if m]
    configs = {
        "critical": SegmentationConfig(),
        "narrowing-only": dataclasses.replace(SegmentationConfig(), wall_gaps=False, max_door_half_width=0.75,
                                              narrowing_ratio=0.7),
        "paper": dataclasses.replace(SegmentationConfig(), method="paper"),
        "critical+furniture": dataclasses.replace(SegmentationConfig(), assign_furniture=True),
    }
    methods = [m for m in args.methods.split(",") if m]
    result = {
        "benchmark": "ipa_room_segmentation (Bormann et al. 2016), 15 buildings x {plain, furnished}",
        "metric": "precision/recall as the mean of ratios (per segment, per room) and area-weighted, each "
                  "averaged over maps; GT rooms = 8-connected regions of GT > 250 larger than 100 px",
        "targets": TARGETS,
        "resolution": RESOLUTION,
        "repeats": args.repeats,
        "hsmap_version": hsmap.__version__,
        "machine": machine(),
        "methods": {},
    }
    for m in methods:
        print(f"method {m}:", flush=True)
        rows = run_method(m, configs[m], folder, maps, args.repeats)
        summary = summarise_segmentation(rows)
        result["methods"][m] = {"config": to_dict(configs[m]), "summary": summary, "maps": rows}
        if set(maps) == set(NAMES):
            result["methods"][m]["targets_met"] = check_targets(summary)

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
    finish(result, args.out)

    # tables
    for m in methods:
        rows = result["methods"][m]["maps"]
        print(f"\n{m}: per map (P, R: mean of ratios; Pa, Ra: area-weighted; segs/rooms; t: median seconds)")
        head = f"{'P':>6s} {'R':>6s} {'Pa':>6s} {'Ra':>6s} {'segs':>7s} {'t':>5s}"
        print(f"{'building':18s} plain  {head}   furnished  {head}")
        for n in maps:
            cells = []
            for x in (next(x for x in rows if x["map"] == n), next(x for x in rows if x["map"] == n + "_furnitures")):
                cells.append(f"{x['precision']:6.3f} {x['recall']:6.3f} {x['precision_area']:6.3f} "
                             f"{x['recall_area']:6.3f} {x['segments']:3d}/{x['rooms']:<3d} {x['seconds']:5.2f}")
            print(f"{n:18s}        {cells[0]}              {cells[1]}")
    print("\nsummary (means over maps; segs/rooms summed)")
    print(f"{'method':18s} {'kind':10s} {'P':>6s} {'R':>6s} {'P_area':>7s} {'R_area':>7s} {'segs/rooms':>11s} "
          f"{'t_med':>6s} {'t_max':>6s}")
    for m in methods:
        for kind, s in result["methods"][m]["summary"].items():
            if kind == "all":
                continue
            print(f"{m:18s} {kind:10s} {s['precision']:6.3f} {s['recall']:6.3f} {s['precision_area']:7.3f} "
                  f"{s['recall_area']:7.3f} {s['segments']:5d}/{s['rooms']:<5d} {s['seconds_median']:6.2f} "
                  f"{s['seconds_max']:6.2f}")
    if "targets_met" in result["methods"].get(methods[0], {}):
        print(f"\ntargets, {methods[0]}:")
        for what, ok in result["methods"][methods[0]]["targets_met"].items():
            print(f"  {'met    ' if ok else 'MISSED '} {what}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
