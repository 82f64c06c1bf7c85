"""The paper's Table 2 over real building layouts: the chain on floor-plan worlds, one Dask job per building.

For each building of a folder of floor plans in the Bormann et al. format (``NAME.png``, ``NAME_furnitures.png``,
``NAME_gt_segmentation.png``, 0.05 m per pixel), three stages, each a Dask task (:mod:`hsmap.study.distributed`):

1. ``simulate``: the world and the exploring run (:func:`hsmap.sim.building.simulate_building`) into
   ``OUT/NAME/data``;
2. ``chain``: the paper's chain on it (:func:`hsmap.pipeline.chain.map_recording`: 2D HS-SLAM, 6-DOF HS-SLAM seeded
   by it, both with loop closure, the floor-level grid and the 1.7-1.8 m slice grid from the estimated poses,
   one segmentation on both) into ``OUT/NAME/chain``;
3. ``score``: both segmentations sampled onto the ground truth's pixels and scored with Bormann's per-room mean
   precision and recall (:func:`hsmap.evaluation.segmentation_scores`; ``recall_reached`` beside it: the mean
   recall over the rooms the route reached, as some ground truths count regions the robot cannot enter, e.g.
   fragments outside the walls); both paths against the ground truth
   (:func:`hsmap.evaluation.pose_errors`); ``OUT/NAME/result.json``.

:func:`run_buildings` runs them and writes ``OUT/results.json`` (schema in its docstring) and ``OUT/table.md``.
``quick`` runs the same stages with a 32 x 512 3D LiDAR (the smoke test and the notebook's quick mode).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from ..datasets.simulated import SimulatedDataset
from ..errors import DatasetError
from ..evaluation import pose_errors, segmentation_scores
from ..io import write_json, write_text
from ..maps.grid import IMAGE_FREE_MIN, read_image_gray, read_label_image, read_map, resample_labels
from ..pipeline.chain import map_recording
from ..sim.building import BuildingRunConfig, simulate_building
from ..sim.floorplan import floor_plan_files, list_floor_plans, read_floor_plan
from ..sim.sensors import Lidar3DConfig
from ..trajectory import read_tum
from .benchmarks import published_references
from .distributed import Job, run_jobs

__all__ = ["run_buildings", "building_config", "simulate_stage", "chain_stage", "score_stage", "summarise",
           "buildings_table", "SCHEMA_VERSION"]

SCHEMA_VERSION = 1


def building_config(quick: bool = False):
    """The one run configuration of every building (:class:`hsmap.sim.building.BuildingRunConfig`); quick: a
    32 x 512 3D LiDAR (half the columns)."""

    cfg = BuildingRunConfig()
    if quick:
        cfg.lidar3d = Lidar3DConfig(channels=32, columns=512)
    return cfg


def simulate_stage(*, name: str, maps: str, out: str, seed: int = 0, quick: bool = False) -> dict:
    """Stage 1: read the floor plan, build the world, plan and drive the route, write the dataset."""

    t = time.perf_counter()
    plan = read_floor_plan(maps, name=name)
    folder = Path(out) / name
    run = simulate_building(plan, folder / "data", seed=seed, config=building_config(quick))
    info = run.as_dict()
    return {"name": name, "maps": str(maps), "folder": str(folder), "seed": int(seed), "quick": bool(quick),
            "frames": info["frames"], "route_m": info["route_m"], "rooms": plan.n_rooms,
            "rooms_visited": len(run.route.order), "unreachable": info["route"]["unreachable"],
            "world": {k: info["world"][k] for k in ("boxes", "furniture_pieces", "tables", "cabinets")},
            "seconds": {"simulate": round(time.perf_counter() - t, 2)}}


def chain_stage(state: dict) -> dict:
    """Stage 2: the paper's chain on the simulated run."""

    t = time.perf_counter()
    folder = Path(state["folder"])
    ds = SimulatedDataset(folder / "data")
    m = map_recording(ds, folder / "chain", seed=state["seed"], recording=False, progress=False)
    state = dict(state)
    state["seconds"] = state["seconds"] | {"chain": round(time.perf_counter() - t, 2)}
    state["chain"] = {"stages_s": {k: v["seconds"] for k, v in m["stages"].items()},
                      "slam2d": m["slam2d"], "slam3d": m["slam3d"],
                      "rooms_found": {"floor": m["floor"]["rooms"], "slice": m["slice"]["rooms"]},
                      "doors_found": {"floor": m["floor"]["doors"], "slice": m["slice"]["doors"]}}
    return state


def _pose_error_record(est, gt) -> dict:

    e = pose_errors(est, gt).as_dict()
    mx = e["max_abs_error"]
    return {"max_abs": {k: round(v, 4) for k, v in mx.items()},
            "max_translation_m": round(float(np.hypot(mx["x_m"], mx["y_m"])), 4),
            "final_translation_m": round(e["final_error"]["translation_m"], 4)}


def score_stage(state: dict) -> dict:
    """Stage 3: both segmentations against the ground truth, both paths against the true one; the record."""

    t = time.perf_counter()
    folder = Path(state["folder"])
    plan = read_floor_plan(state["maps"], name=state["name"])
    rec = {k: state[k] for k in ("name", "frames", "route_m", "rooms", "rooms_visited", "unreachable", "seed",
                                 "quick", "world", "chain")}
    for kind, prefix in (("floor", "floor_"), ("slice", "")):
        grid = read_map(folder / "chain" / f"{kind}.yaml")
        labels = read_label_image(folder / "chain" / f"{prefix}rooms.png")
        on_gt = resample_labels(labels, grid.geometry, plan.geometry)
        s = segmentation_scores(on_gt, plan.rooms, gt_is_labels=True)
        # the ground truth's rooms are 1..R, all counted: room_recall[k - 1] is room k's
        reached = [r for k, r in enumerate(s.room_recall, start=1) if str(k) not in state["unreachable"]]
        rec[kind] = {"precision": round(s.precision, 4), "recall": round(s.recall, 4),
                     "precision_area": round(s.precision_area, 4), "recall_area": round(s.recall_area, 4),
                     "recall_reached": round(float(np.mean(reached)), 4) if reached else 0.0,
                     "segments": s.n_segments, "rooms": s.n_rooms}
    gt = SimulatedDataset(folder / "data").groundtruth
    rec["pose_error"] = {"2d": _pose_error_record(read_tum(folder / "chain" / "trajectory2d.tum", dof=3), gt),
                         "6dof": _pose_error_record(read_tum(folder / "chain" / "trajectory3d.tum", dof=6),
                                                    gt.as_6dof())}
    rec["seconds_by_stage"] = state["seconds"] | {"score": round(time.perf_counter() - t, 2)}
    rec["seconds"] = round(sum(rec["seconds_by_stage"].values()), 2)
    return rec


STAGES = (("simulate", simulate_stage), ("chain", chain_stage), ("score", score_stage))


def summarise(records: Sequence[dict]) -> dict:
    """Means over the buildings that ran to the end: Bormann's per-room mean precision and recall of each, then
    averaged over the buildings; the mean pose errors, route, frames and time; the recall gain count."""
    ok = [r for r in records if r.get("status") == "ok"]
    if not ok:
        return {"buildings_ok": 0, "buildings": len(records)}

    def mean(f: Callable[[dict], float]) -> float:
        return round(float(np.mean([f(r) for r in ok])), 4)

    gain = [r["slice"]["recall"] - r["floor"]["recall"] for r in ok]
    return {
        "buildings_ok": len(ok), "buildings": len(records),
        "floor": {"precision": mean(lambda r: r["floor"]["precision"]), "recall": mean(lambda r: r["floor"]["recall"])},
        "slice": {"precision": mean(lambda r: r["slice"]["precision"]), "recall": mean(lambda r: r["slice"]["recall"])},
        "recall_reached": {k: mean(lambda r, k=k: r[k].get("recall_reached", r[k]["recall"])) for k in ("floor", "slice")},
        "recall_gain": round(float(np.mean(gain)), 4),
        "buildings_with_recall_gain": int(sum(g > 0 for g in gain)),
        "pose_error": {"2d_max_translation_m": mean(lambda r: r["pose_error"]["2d"]["max_translation_m"]),
                       "6dof_max_translation_m": mean(lambda r: r["pose_error"]["6dof"]["max_translation_m"]),
                       "2d_max_yaw_deg": mean(lambda r: r["pose_error"]["2d"]["max_abs"]["yaw_deg"]),
                       "6dof_max_yaw_deg": mean(lambda r: r["pose_error"]["6dof"]["max_abs"]["yaw_deg"])},
        "route_m": mean(lambda r: r["route_m"]), "frames": mean(lambda r: r["frames"]),
        "seconds": mean(lambda r: r["seconds"]),
    }


def buildings_table(results: dict, paper: dict | None = None) -> str:
    """The per-building table (Markdown) with the means and, when given, the paper's Table 2 beside them."""
    head = ("| building | rooms | floor P | floor R | slice P | slice R | 2D err m / deg | 6-DOF err m / deg | "
            "route m | frames | s |\n|---|---|---|---|---|---|---|---|---|---|---|\n")
    lines = []
    for r in results["buildings"]:
        if r.get("status") != "ok":
            lines.append(f"| {r['name']} | failed: {r.get('stage', '?')}: {r.get('error', '')[:80]} |||||||||||")
            continue
        p2, p3 = r["pose_error"]["2d"], r["pose_error"]["6dof"]
        unreach = f" ({len(r['unreachable'])} unreachable)" if r.get("unreachable") else ""
        lines.append(
            f"| {r['name']} | {r['rooms']}{unreach} | {r['floor']['precision']:.3f} | {r['floor']['recall']:.3f} | "
            f"{r['slice']['precision']:.3f} | {r['slice']['recall']:.3f} | {p2['max_translation_m']:.3f} / "
            f"{p2['max_abs']['yaw_deg']:.2f} | {p3['max_translation_m']:.3f} / {p3['max_abs']['yaw_deg']:.2f} | "
            f"{r['route_m']:.0f} | {r['frames']} | {r['seconds']:.0f} |")
    m = results.get("mean") or {}
    if m.get("buildings_ok"):
        pe = m["pose_error"]
        lines.append(f"| **mean** ({m['buildings_ok']} of {m['buildings']}) | | {m['floor']['precision']:.3f} | "
                     f"{m['floor']['recall']:.3f} | {m['slice']['precision']:.3f} | {m['slice']['recall']:.3f} | "
                     f"{pe['2d_max_translation_m']:.3f} / {pe['2d_max_yaw_deg']:.2f} | {pe['6dof_max_translation_m']:.3f}"
                     f" / {pe['6dof_max_yaw_deg']:.2f} | {m['route_m']:.0f} | {m['frames']:.0f} | {m['seconds']:.0f} |")
    if paper:
        lines.append(f"| paper's Table 2 (one building) | | {paper['floor_precision']:.3f} | {paper['floor_recall']:.3f} | "
                     f"{paper['slice_precision']:.3f} | {paper['slice_recall']:.3f} | | | | | |")
    return head + "\n".join(lines) + "\n"


def run_buildings(maps: str | os.PathLike, out: str | os.PathLike, *, only: Sequence[str] | None = None,
                  workers: int | None = 2, scheduler: str | None = None, quick: bool = False, seed: int = 0,
                  progress: bool | None = None, log: Callable[[str], None] | None = None, client=None) -> dict:
    """Run the benchmark over the buildings of ``maps`` (all, or ``only``) and write ``OUT/results.json``.

    ``results.json``: ``{"schema": 1, "maps", "quick", "seed", "buildings": [{"name", "status": "ok"|"failed",
    "floor": {"precision", "recall", ...}, "slice": {...}, "pose_error": {"2d": {...}, "6dof": {...}},
    "route_m", "frames", "seconds", ...} | {"name", "status": "failed", "stage", "error"}, ...], "mean": {"floor":
    {"precision", "recall"}, "slice": {...}, ...}, "seconds"}`` (per-room mean precision and recall of each
    building, then the mean over the buildings). A building already finished in ``OUT`` is read back, not rerun.

    Raises
    ------
    DatasetError
        ``maps`` holds no floor plan, or a name of ``only`` is not one of them.
    """

    t0 = time.perf_counter()
    maps, out = Path(maps), Path(out)
    names = list_floor_plans(maps)
    if not names:
        raise DatasetError(f"{maps}: no floor plan (NAME.png with NAME_furnitures.png and NAME_gt_segmentation.png)")
    if only:
        missing = [n for n in only if n not in names]
        if missing:
            raise DatasetError(f"--only {' '.join(missing)}: not a floor plan in {maps} (there: {', '.join(names)})")
        names = [n for n in names if n in set(only)]
    jobs = [Job(n, STAGES, {"name": n, "maps": str(maps), "out": str(out), "seed": int(seed), "quick": bool(quick)},
                priority=_free_pixels(maps, n)) for n in names]  # the largest buildings first
    records = run_jobs(jobs, out, workers=workers, scheduler=scheduler, progress=progress, log=log, client=client)
    clean = [{k: v for k, v in r.items() if k not in ("traceback", "skipped")} for r in records]
    results = {"schema": SCHEMA_VERSION, "maps": str(maps), "quick": bool(quick), "seed": int(seed),
               "buildings": clean, "mean": summarise(clean), "seconds": round(time.perf_counter() - t0, 2)}
    write_json(out / "results.json", results)
    write_text(out / "table.md", buildings_table(results, _paper_table2()))
    return results


def _free_pixels(maps: Path, name: str) -> int:

    return int((read_image_gray(floor_plan_files(maps, name)[0]) >= IMAGE_FREE_MIN).sum())


def _paper_table2() -> dict | None:

    try:
        return published_references().get("table2")
    except Exception:  # noqa: BLE001 - the table is written without the paper's row then
        return None
