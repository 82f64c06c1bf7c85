"""The paper's whole chain on one recording (``hsmap map INPUT --out DIR``).

A recording with a floor-level 2D LiDAR and a 3D LiDAR (a ROS bag, a folder of clouds with a folder of scans,
a simulator folder) goes through the paper's pipeline, stage by stage:

1. ``slam2d``: 3-DOF HS-SLAM on the 2D scans (one frame per scan), started at the first odometry pose when
   the input has odometry (so the maps share the odometry frame), else at the origin;
2. ``slam3d``: 6-DOF HS-SLAM on the 3D clouds (one frame per cloud), seeded by the 2D poses interpolated at
   each cloud's stamp (:meth:`hsmap.trajectory.Trajectory.interpolate`) and started at the 2D pose of the first
   cloud;
3. ``grids``: the floor-level occupancy grid (every scan at its 2D pose, :func:`hsmap.maps.grid.grid_from_scans`)
   and the grid of the 3D map's slice ``z_range`` (every cloud at its 6-DOF pose, :func:`hsmap.maps.fusion.slice_scans`);
4. ``fusion``: the floor grid registered to the slice and overlaid (:func:`hsmap.maps.fusion.align_maps`);
5. ``rooms``: doors, rooms and the room/door graph of the slice and, for the paper's Figure 18 comparison, of
   the floor grid (:func:`hsmap.rooms.segmentation.segment_rooms`, :func:`hsmap.rooms.topology.room_graph`).

A recording with a 3D LiDAR only goes through :func:`hsmap.pipeline.chain3d.map_recording_3d` instead.

Each stage is a folder of :class:`hsmap.pipeline.cache.FolderCache` under ``DIR/.stages/``, keyed on its inputs
(the recording's contents, the reader's options, the configuration, the seed, the stages before it) and on the
code: a second run with the same inputs reads every stage back ("unchanged") and only rewrites the outputs.
Every stage shows a progress bar.

Outputs in ``DIR``, written into a staging folder inside it and moved into place together when all are complete
(``metrics.json`` last, so a folder without it is incomplete; a failure leaves the previous run's outputs as they
were, and the stages kept so far):
``trajectory2d.tum``, ``trajectory3d.tum``; ``floor.pgm``/``floor.yaml`` and ``slice.pgm``/``slice.yaml``
(map_server maps, loadable by Nav2's map_server) with ``floor.png``/``slice.png``; ``overlay.png``; for the
slice ``rooms.png`` (16-bit labels), ``doors.json``, ``topology.json``, ``topology.graphml``,
``segmentation.png``, and the same with the prefix ``floor_`` for the floor grid; ``door_points.json`` (the
points of the 2D and 3D maps in each door's box); ``map2d.ply`` and ``map3d.ply`` (the two HS-SLAM maps);
``figures/*.png``; ``summary.html``; ``map.rrd`` (one rerun recording: both maps, the grids, the rooms, the
graph, the paths); ``metrics.json``.
"""

from __future__ import annotations

import html
import json
import time
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from .. import progress as _progress
from ..config import to_dict
from ..datasets.frames import Dataset, Frame
from ..deskew import deskew_frame
from ..deskew2d import deskew_scan_frame
from ..errors import InputError
from ..io import (
    atomic_path,
    prepare_output_dir,
    staged_outputs,
    sweep_stale_temporaries,
    to_plain,
    write_json,
    write_ply_points,
    write_text,
)
from ..maps.fusion import align_maps, slice_scans
from ..maps.grid import (
    GridGeometry,
    OccupancyGrid,
    grid_from_scans,
    scans_to_points,
    write_label_image,
    write_map,
)
from ..maps.mapping import voxel_downsample
from ..rooms.segmentation import Door, Segmentation, SegmentationConfig, points_in_doors, segment_rooms
from ..rooms.topology import room_graph, topology_line, write_topology
from ..slam import SlamConfig
from ..trajectory import Trajectory, write_tum
from .cache import FolderCache, description_digest
from .runs import cached_slam

__all__ = ["map_recording", "STAGES", "OUTPUTS"]

#: The stages, in order.
STAGES = ("slam2d", "slam3d", "grids", "fusion", "rooms")

#: What ``map_recording`` writes into its output folder (besides ``figures/`` and ``.stages/``).
OUTPUTS = ("trajectory2d.tum", "trajectory3d.tum", "floor.pgm", "floor.yaml", "floor.png", "slice.pgm",
           "slice.yaml", "slice.png", "overlay.png", "rooms.png", "doors.json", "topology.json", "topology.graphml",
           "segmentation.png", "floor_rooms.png", "floor_doors.json", "floor_topology.json",
           "floor_topology.graphml", "floor_segmentation.png", "door_points.json", "map2d.ply", "map3d.ply",
           "summary.html", "map.rrd", "metrics.json")


class _Stages:
    """Progress bars and timings of the stages; a stage read back from its folder says "unchanged"."""

    def __init__(self, progress: bool | None) -> None:
        self.progress = progress
        self.info: dict[str, dict] = {}

    def start(self, name: str, detail: str = "") -> None:
        _progress.stage(name, detail)  # a line for a caller that reports progress, else nothing

    def bar(self, name: str, total: int | None = None, unit: str = "step"):
        return _progress.bar(total, unit=unit, desc=f"{name:<7s}", progress=self.progress, leave=True)

    def done(self, name: str, cached: bool, seconds: float, bar=None) -> None:
        self.info[name] = {"unchanged": bool(cached), "seconds": round(float(seconds), 3)}
        _progress.say(f"{name}: " + ("unchanged, read back" if cached else f"done in {seconds:.1f} s"))
        if bar is not None:
            if cached:
                bar.set_postfix_str("unchanged, skipped")
            if bar.total is not None and bar.n < bar.total:
                bar.update(bar.total - bar.n)
            bar.close()


def _counted(frames: Iterable[Frame], bar) -> Iterator[Frame]:
    for f in frames:
        yield f
        bar.update(1)


def _start_pose(dataset: Dataset) -> np.ndarray | None:
    """The first frame's odometry pose (x, y, yaw), when the input has odometry there."""
    odo = getattr(dataset, "odometry", None)
    if odo is None or not len(dataset):
        return None
    pose, found = odo.at([float(np.asarray(dataset.stamps)[0])], max_dt=1e-3)
    return pose[0] if found[0] else None


def _grid_arrays(prefix: str, g: OccupancyGrid) -> dict[str, np.ndarray]:
    return {f"{prefix}_data": g.data, f"{prefix}_geometry": np.array([g.geometry.resolution, *g.geometry.origin])}


def _grid_from(z, prefix: str) -> OccupancyGrid:
    data = z[f"{prefix}_data"]
    res, ox, oy = (float(v) for v in z[f"{prefix}_geometry"])
    return OccupancyGrid(data, GridGeometry(data.shape, res, (ox, oy)))


def _thin(points: np.ndarray, voxel: float) -> np.ndarray:

    return voxel_downsample(np.asarray(points, dtype=float), voxel)


# --- the stages ---------------------------------------------------------------------------------------------

def _grids_stage(ds2: Dataset, ds3: Dataset, traj2: Trajectory, traj3: Trajectory, z_range, resolution: float,
                 bins: int, stages: _Stages, deskew: bool = True) -> tuple[Callable, Callable]:
    def compute(folder: Path) -> None:

        bar = stages.bar("grids", len(ds2) + len(ds3), "frame")
        scans, poses, ext = [], [], []
        t2 = traj2.as_3dof()
        for f in _counted(ds2.frames(clouds=False), bar):
            pose, ok = t2.at([f.stamp], max_dt=1e-3)
            if ok[0] and f.scan2d is not None:
                scans.append(deskew_scan_frame(f, prior=t2)[0].scan2d if deskew else f.scan2d)
                poses.append(pose[0])
                ext.append(f.extrinsic2d)
        if not scans:
            raise InputError("no 2D scan has a 2D HS-SLAM pose: nothing to make the floor grid of")
        poses_a, ext_a = np.asarray(poses), np.asarray(ext, dtype=float)
        floor = grid_from_scans(scans, poses_a, resolution, extrinsic=ext_a)
        floor_pts = _thin(scans_to_points(scans, poses_a, ext_a), 0.02)
        p3, found = traj3.as_6dof().at(np.asarray(ds3.stamps, dtype=float), max_dt=1e-3)
        wanted = (deskew_frame(f, prior=traj3)[0] if deskew else f
                  for f, ok in zip(_counted(ds3.frames(), bar), found, strict=True) if ok and f.cloud3d is not None)
        sscans, spos = slice_scans(wanted, p3, z_min=z_range[0], z_max=z_range[1], bins=bins)
        bar.close()
        if not sscans:
            raise InputError(f"no 3D cloud has points between {z_range[0]} and {z_range[1]} m above the base frame: "
                             "no slice to map (is the base frame on the floor, and the 3D offset right?)")
        slice_ = grid_from_scans(sscans, spos, resolution)
        slice_pts = _thin(scans_to_points(sscans, spos), 0.02)
        np.savez(folder / "grids.npz", floor_points=floor_pts, slice_points=slice_pts,
                 **_grid_arrays("floor", floor), **_grid_arrays("slice", slice_))

    def load(folder: Path) -> dict:
        with np.load(folder / "grids.npz") as z:
            return {"floor": _grid_from(z, "floor"), "slice": _grid_from(z, "slice"),
                    "floor_points": z["floor_points"], "slice_points": z["slice_points"]}

    return compute, load


def _fusion_stage(grids: dict, seed: int) -> tuple[Callable, Callable]:
    def compute(folder: Path) -> None:

        a = align_maps(grids["floor"], grids["slice"], floor_points=grids["floor_points"],
                       slice_points=grids["slice_points"], rng=seed)
        np.savez(folder / "fusion.npz", transformation=a.transformation, **_grid_arrays("floor", a.floor),
                 **_grid_arrays("slice", a.slice))
        write_json(folder / "fusion.json", a.as_dict())

    def load(folder: Path) -> dict:
        with np.load(folder / "fusion.npz") as z:
            out = {"transformation": z["transformation"], "floor": _grid_from(z, "floor"),
                   "slice": _grid_from(z, "slice")}
        out["summary"] = json.loads((folder / "fusion.json").read_text(encoding="utf-8"))
        return out

    return compute, load


def _door_from(d: dict) -> Door:
    return Door(centre=np.asarray(d["centre"], dtype=float), end_points=np.asarray(d["end_points"], dtype=float),
                width=float(d["width"]), rooms=tuple(int(r) for r in d["rooms"]),
                pixel=tuple(int(v) for v in d["pixel"]), kind=str(d["kind"]))


def _rooms_stage(grids: dict, config: SegmentationConfig) -> tuple[Callable, Callable]:
    def compute(folder: Path) -> None:

        arrays, doors = {}, {}
        for name in ("slice", "floor"):
            seg = segment_rooms(grids[name], config=config)
            arrays[name] = seg.labels.astype(np.int32)
            doors[name] = [d.as_dict() for d in seg.doors]
        np.savez(folder / "rooms.npz", **arrays)
        write_json(folder / "doors.json", doors)

    def load(folder: Path) -> dict[str, Segmentation]:
        doors = json.loads((folder / "doors.json").read_text(encoding="utf-8"))
        with np.load(folder / "rooms.npz") as z:
            return {name: Segmentation(z[name], [_door_from(d) for d in doors[name]], grids[name].geometry, config)
                    for name in ("slice", "floor")}

    return compute, load


# --- the whole chain ----------------------------------------------------------------------------------------

def map_recording(
    dataset: Dataset,
    out: str | Path,
    *,
    seed: int = 0,
    slam2d: SlamConfig | None = None,
    slam3d: SlamConfig | None = None,
    segmentation: SegmentationConfig | None = None,
    z_range: tuple[float, float] = (1.7, 1.8),
    resolution: float = 0.05,
    slice_bins: int = 720,
    door_depth: float = 0.3,
    door_margin: float = 0.15,
    recording: bool = True,
    progress: bool | None = None,
    configuration: str | None = None,
) -> dict:
    """Run the paper's chain on one recording and write its outputs into ``out`` (see the module docstring).

    Parameters
    ----------
    dataset : Dataset
        A recording with 2D scans and 3D clouds (:func:`hsmap.datasets.open.open_dataset`); its
        :meth:`~hsmap.datasets.frames.Dataset.driven_by` views give the 2D and the 6-DOF run their frames.
    out : path
        Output folder (created); ``out/.stages/`` keeps the stages for the next run.
    seed : int
        The seed of every random choice (both HS-SLAM runs, the map registration).
    slam2d, slam3d : SlamConfig, optional
        Default ``SlamConfig(dof=3)`` and ``SlamConfig(dof=6)``.
    segmentation : SegmentationConfig, optional
    z_range : (float, float)
        Heights of the 3D map's slice above the base frame's z = 0 (the paper: 1.7-1.8 m).
    resolution : float
        Metres per cell of both grids.
    slice_bins : int
        Azimuth bins of the virtual slice scans.
    door_depth, door_margin : float
        The box around each door whose map points are the door's (:func:`hsmap.rooms.segmentation.points_in_doors`).
    recording : bool
        Write ``map.rrd``.
    progress : bool or None
        Progress bars (None: on a terminal only).
    configuration : str, optional
        Where the settings came from (a ``--config`` file, flags), said in the summary; None: the defaults.

    Returns
    -------
    dict
        What ``metrics.json`` holds.
    """
    t_start = time.perf_counter()
    slam2d = slam2d or SlamConfig(dof=3)
    slam3d = slam3d or SlamConfig(dof=6)
    if slam2d.dof != 3 or slam3d.dof != 6:
        raise InputError(f"slam2d must be a 3-DOF and slam3d a 6-DOF SlamConfig, got dof {slam2d.dof} and {slam3d.dof}")
    seg_cfg = segmentation or SegmentationConfig()
    z = (float(z_range[0]), float(z_range[1]))
    if not (np.all(np.isfinite(z)) and z[0] < z[1]):
        raise InputError(f"z_range must be two heights low < high (metres), got {z_range}")
    if not (np.isfinite(resolution) and resolution > 0):
        raise InputError(f"resolution must be > 0 metres per cell, got {resolution}")
    out = prepare_output_dir(out)  # a file, or a folder that cannot be written: said now, not after the runs
    sweep_stale_temporaries(out, OUTPUTS)  # what a killed run left (its staging folder, temporaries)
    ds2 = dataset.driven_by("scan")
    ds3 = dataset.driven_by("cloud")
    stages = _Stages(progress)
    root = out / ".stages"
    cache = FolderCache(root)

    # 1-2: the two HS-SLAM runs (in this folder)
    t = time.perf_counter()
    init2 = _start_pose(ds2)
    stages.start("slam2d", f"3-DOF HS-SLAM on {len(ds2)} scans")
    run2 = cached_slam(ds2, slam2d, seed, initial_pose=init2, cache_dir=root / "slam", progress=progress)
    stages.done("slam2d", run2.cached, time.perf_counter() - t,
                stages.bar("slam2d", 1) if run2.cached else None)
    t = time.perf_counter()
    prior = run2.trajectory
    first = float(np.asarray(ds3.stamps)[0])
    p0, ok = prior.interpolate([first], slam3d.sync_tolerance)
    p0 = p0[0] if ok[0] else prior.at([first], max_dt=np.inf)[0][0]
    init3 = np.array([p0[0], p0[1], 0.0, 0.0, 0.0, p0[2]])
    stages.start("slam3d", f"6-DOF HS-SLAM on {len(ds3)} clouds")
    run3 = cached_slam(ds3, slam3d, seed, prior=prior, initial_pose=init3, cache_dir=root / "slam",
                       progress=progress)
    stages.done("slam3d", run3.cached, time.perf_counter() - t,
                stages.bar("slam3d", 1) if run3.cached else None)

    # 3-5: grids, their registration and overlay, rooms and doors
    params = {"z_range": list(z), "resolution": float(resolution), "slice_bins": int(slice_bins), "seed": int(seed)}
    t = time.perf_counter()
    stages.start("grids", "floor grid and the 3D map's slice")
    compute, load = _grids_stage(ds2, ds3, run2.trajectory, run3.trajectory, z, float(resolution), int(slice_bins),
                                 stages, slam3d.deskew)
    got = cache.get("grids", {"slam": [run2.key, run3.key], "params": params}, compute, load)
    grids, keys = got.value, {"grids": got.key}
    stages.done("grids", got.cached, time.perf_counter() - t, stages.bar("grids", 1) if got.cached else None)

    t = time.perf_counter()
    stages.start("fusion", "floor grid registered to the slice")
    bar = stages.bar("fusion", 1)
    compute, load = _fusion_stage(grids, int(seed))
    got = cache.get("fusion", {"grids": keys["grids"], "seed": int(seed)}, compute, load)
    fusion, keys["fusion"] = got.value, got.key
    stages.done("fusion", got.cached, time.perf_counter() - t, bar)

    t = time.perf_counter()
    stages.start("rooms", "doors, rooms and graph of both grids")
    bar = stages.bar("rooms", 1)

    compute, load = _rooms_stage(grids, seg_cfg)
    got = cache.get("rooms", {"grids": keys["grids"], "segmentation": to_dict(seg_cfg)}, compute, load)
    segs, keys["rooms"] = got.value, got.key
    stages.done("rooms", got.cached, time.perf_counter() - t, bar)

    # the outputs: rewritten unless every stage and the output options are unchanged and the folder complete
    options = {"door_depth": float(door_depth), "door_margin": float(door_margin), "recording": bool(recording),
               "z_range": list(z), "configuration": configuration}
    final_key = description_digest({"slam": [run2.key, run3.key], "stages": keys, "options": options})
    previous = _read_metrics(out / "metrics.json")
    complete = all((out / name).is_file() for name in OUTPUTS if recording or name != "map.rrd")
    if previous is not None and previous.get("key") == final_key and complete:
        previous["stages"] = stages.info | {"outputs": {"unchanged": True, "seconds": 0.0}}
        previous["seconds_total"] = round(time.perf_counter() - t_start, 3)
        write_json(out / "metrics.json", previous)
        return previous
    t = time.perf_counter()
    stages.start("outputs", f"maps, figures, summary into {out}")
    bar = stages.bar("outputs", 6)
    # every output is written into a staging folder inside ``out`` and moved into place when all are complete
    # (metrics.json, the marker of a complete folder, last): a failure or an interrupt on the way leaves the
    # previous run's outputs as they were, and the stages' caches in .stages/ for the next run
    with staged_outputs(out, last="metrics.json", folders=True) as stage:
        metrics = _write_outputs(stage, dataset, ds2, ds3, run2, run3, grids, fusion, segs, z, door_depth,
                                 door_margin, recording, bar, configuration)
        stages.done("outputs", False, time.perf_counter() - t, bar)
        metrics["stages"] = stages.info
        metrics["key"] = final_key
        metrics["seconds_total"] = round(time.perf_counter() - t_start, 3)
        write_json(stage / "metrics.json", metrics)
    if not recording:
        (out / "map.rrd").unlink(missing_ok=True)  # not this run's
    return metrics


def _read_metrics(path: Path) -> dict | None:
    try:
        m = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return m if isinstance(m, dict) else None


def _slam_summary(run) -> dict:
    m = run.metrics
    keys = ("frames", "keyframes", "map_points", "seconds_total", "cpu_seconds_total", "real_time_factor",
            "inlier_ratio_median", "frames_retried", "frames_unverified", "loop_closure", "loops_closed", "pair_edges",
            "prior")
    return {k: m.get(k) for k in keys}


def _segmentation_record(seg: Segmentation, graph) -> dict:

    return {"rooms": seg.n_rooms, "doors": len(seg.doors), "method": seg.config.method,
            "room_areas_m2": {f"R{r.label}": round(r.area, 3) for r in seg.rooms},
            "door_list": [d.as_dict() for d in seg.doors],
            "graph": topology_line(graph)}


def _write_outputs(out: Path, dataset: Dataset, ds2: Dataset, ds3: Dataset, run2, run3, grids: dict, fusion: dict,
                   segs: dict, z: tuple[float, float], door_depth: float, door_margin: float, recording: bool,
                   bar, configuration: str | None = None) -> dict:
    from PIL import Image

    from ..viz.colors import segmentation_picture

    # trajectories, maps for Nav2, pictures of them
    write_tum(out / "trajectory2d.tum", run2.trajectory)
    write_tum(out / "trajectory3d.tum", run3.trajectory)
    for name in ("floor", "slice"):
        g = grids[name]
        write_map(out / f"{name}.yaml", g)
        with atomic_path(out / f"{name}.png") as tmp:
            Image.fromarray(g.to_image()).save(tmp, format="PNG")
    with atomic_path(out / "overlay.png") as tmp:
        from ..maps.fusion import overlay_image

        Image.fromarray(overlay_image(fusion["floor"], fusion["slice"])).save(tmp, format="PNG")
    bar.update(1)

    # rooms, doors and graphs of both grids
    graphs, records = {}, {}
    for name, prefix in (("slice", ""), ("floor", "floor_")):
        seg, g = segs[name], grids[name]
        graphs[name] = room_graph(seg)
        write_label_image(out / f"{prefix}rooms.png", seg.labels)
        write_json(out / f"{prefix}doors.json", {
            "map": f"{name}.yaml", "frame": "map (world x, y in metres; map_server origin convention)",
            "resolution": g.geometry.resolution, "origin": list(g.geometry.origin),
            "doors": [d.as_dict() for d in seg.doors]})
        write_topology(graphs[name], out, stem=f"{prefix}topology")
        with atomic_path(out / f"{prefix}segmentation.png") as tmp:
            Image.fromarray(segmentation_picture(seg.labels, g.free, seg.doors, g.geometry)).save(tmp, format="PNG")
        records[name] = _segmentation_record(seg, graphs[name])
    bar.update(1)

    # the two point maps and the doors' points in them
    map2d, map3d = run2.map_points, run3.map_points
    h2 = _sensor_height(ds2)
    _write_ply(out / "map2d.ply", np.column_stack([map2d, np.full(len(map2d), h2)]))
    _write_ply(out / "map3d.ply", map3d)
    doors = segs["slice"].doors
    pts2 = points_in_doors(map2d, doors, depth=door_depth, margin=door_margin)
    pts3 = points_in_doors(map3d, doors, depth=door_depth, margin=door_margin, z_range=(-0.1, z[1] + 1.5))
    write_json(out / "door_points.json", {
        "frame": "map (world x, y[, z] in metres)", "depth": door_depth, "margin": door_margin,
        "doors": [{"door": f"D{k}", "centre": [float(v) for v in d.centre], "points2d": np.round(p2, 4).tolist(),
                   "points3d": np.round(p3, 4).tolist()} for k, (d, p2, p3) in enumerate(zip(doors, pts2, pts3, strict=True), 1)]})
    bar.update(1)

    # figures and the summary page
    figdir = out / "figures"
    figdir.mkdir(exist_ok=True)
    figs = _figures(figdir, ds2, run2, run3, grids, fusion, segs, graphs, doors, pts2, pts3, h2, z)
    bar.update(1)

    info_scan, info_cloud = ds2.describe(), ds3.describe()
    warnings_ = list(dict.fromkeys([*info_scan.get("warnings", []), *info_cloud.get("warnings", [])]))
    fus = fusion["summary"]
    metrics: dict[str, Any] = {
        "input": str(dataset.path),
        "configuration": configuration,
        "input_info": {"scans": info_scan, "clouds": info_cloud},
        "warnings": warnings_,
        "slam2d": _slam_summary(run2),
        "slam3d": _slam_summary(run3),
        "grids": {name: {"shape": list(grids[name].geometry.shape), "resolution": grids[name].geometry.resolution,
                         "origin": list(grids[name].geometry.origin),
                         "occupied_cells": int(grids[name].occupied.sum()),
                         "free_m2": float(grids[name].free.sum() * grids[name].geometry.resolution ** 2)}
                  for name in ("floor", "slice")} | {"z_range": list(z)},
        "fusion": fus,
        "slice": records["slice"],
        "floor": records["floor"],
        "door_points": [{"door": f"D{k}", "points2d": len(p2), "points3d": len(p3)}
                        for k, (p2, p3) in enumerate(zip(pts2, pts3, strict=True), 1)],
        "figures": figs,
    }
    write_text(out / "summary.html", _summary_html(out, metrics))
    bar.update(1)

    if recording:
        from ..viz.replay import record_map  # rerun: only when a recording is asked for

        record_map(out / "map.rrd", run2, run3, grids, fusion, segs["slice"], graphs["slice"], doors, pts2, pts3, h2)
    bar.update(1)
    return to_plain(metrics)


def _sensor_height(ds: Dataset) -> float:
    """Height of the 2D LiDAR above the base frame where the reader knows it (a bag's TF, a simulator's
    description), else 0."""
    if getattr(ds, "height2d", None) is not None:
        return float(ds.height2d)
    sensors = getattr(ds, "sensors", None)
    try:
        return float(sensors["lidar2d"]["mount_height"])
    except (TypeError, KeyError, ValueError):
        return 0.0


def _write_ply(path: Path, points: np.ndarray) -> None:
    write_ply_points(path, np.asarray(points, dtype=float).reshape(-1, 3))


def _figures(figdir: Path, ds2, run2, run3, grids, fusion, segs, graphs, doors, pts2, pts3, h2, z) -> dict:
    import matplotlib.pyplot as plt

    from ..viz import figures, map_figures

    names: dict[str, str] = {}

    def save(fig, name: str, caption: str) -> None:
        with atomic_path(figdir / f"{name}.png") as tmp:
            fig.savefig(tmp, dpi=100, format="png", bbox_inches="tight")
        plt.close(fig)
        names[name] = caption

    ax = figures.plot_trajectories({"2D HS-SLAM": run2.trajectory, "6-DOF HS-SLAM": run3.trajectory}
                                   | ({"odometry": ds2.odometry} if ds2.odometry is not None else {}),
                                   title="the robot's path")
    save(ax.figure, "trajectories", "The 2D and 6-DOF HS-SLAM paths (and the wheel odometry).")
    fig, axes = figures.new_figure(1, 2, size=(14, 5))
    figures.plot_grid(grids["floor"].data, grids["floor"].geometry, ax=axes[0], title="floor-level 2D map")
    figures.plot_grid(grids["slice"].data, grids["slice"].geometry, ax=axes[1],
                      title=f"{z[0]}-{z[1]} m slice of the 3D map")
    save(fig, "grids", "The two occupancy grids (Nav2 maps: floor.yaml, slice.yaml).")
    ax = map_figures.plot_overlay(fusion["floor"], fusion["slice"], title="the 2D map registered to the slice")
    save(ax.figure, "overlay", "The floor-level map registered to the slice and overlaid (the paper's Fig. 13).")
    ax = map_figures.segmentation_figure(grids["slice"], segs["slice"], graphs["slice"],
                                         title=f"{segs['slice'].n_rooms} rooms, {len(segs['slice'].doors)} doors "
                                         "on the slice, and the room/door graph")
    save(ax.figure, "rooms", "Rooms, doors (red) and the room/door graph of the slice (Figs. 12 and 16).")
    fig = map_figures.segmentation_comparison_figure(
        [(grids["floor"], segs["floor"], f"floor-level map: {segs['floor'].n_rooms} rooms, "
                                         f"{len(segs['floor'].doors)} doors"),
         (grids["slice"], segs["slice"], f"slice of the 3D map: {segs['slice'].n_rooms} rooms, "
                                         f"{len(segs['slice'].doors)} doors")],
        title="one segmentation, two maps (the paper's Fig. 18)")
    save(fig, "comparison", "The same segmentation on the floor-level map and on the slice (Fig. 18).")
    if doors and any(len(p) for p in pts3):
        fig = map_figures.door_clouds_figure(doors, pts3, pts2, sensor2d_height=h2,
                                             title="the doors' points in the 3D map (by height) and the 2D map (x)")
        save(fig, "doors", "Each door's points in the 3D and the 2D map, seen from the front (Fig. 15).")
    return names


def _offset_text(value) -> str:
    """A sensor's pose in the base frame, (x, y, yaw) or (x, y, z, roll, pitch, yaw), with its units."""
    v = [float(x) for x in value]
    names = ("x", "y", "yaw") if len(v) == 3 else ("x", "y", "z", "roll", "pitch", "yaw")
    return ", ".join(f"{n} {round(float(np.degrees(x)), 2) + 0.0:.2f} deg" if n in ("roll", "pitch", "yaw")
                     else f"{n} {round(x, 3) + 0.0:.3f} m" for n, x in zip(names, v, strict=False))


def _summary_html(out: Path, m: dict) -> str:
    esc = html.escape

    def rows(d: dict) -> str:
        return "".join(f"<tr><th>{esc(str(k))}</th><td>{esc(str(v))}</td></tr>" for k, v in d.items())

    s2, s3, fus = m["slam2d"], m["slam3d"], m["fusion"]
    prior = s3.get("prior") or {}
    z, grid = m["grids"]["z_range"], m["grids"]["slice"]
    numbers = {
        "input": m["input"],
        "configuration": f"{m.get('configuration') or 'the defaults'}; slice {z[0]:g}-{z[1]:g} m, "
                         f"{grid['resolution']:g} m cells, {m['slice']['method']} door method",
        "2D HS-SLAM": f"{s2['frames']} scans, {s2['keyframes']} keyframes, {s2['loops_closed']} loops closed, "
                      f"{s2['seconds_total']:.1f} s",
        "6-DOF HS-SLAM": f"{s3['frames']} clouds, {s3['keyframes']} keyframes, {s3['loops_closed']} loops closed, "
                         f"{s3['seconds_total']:.1f} s; 2D prior for {prior.get('frames_with_prior')} of "
                         f"{prior.get('frames')} clouds",
        "2D map -> slice": f"({fus['x']:+.3f} m, {fus['y']:+.3f} m, {fus['yaw_deg']:+.2f} deg), overlap "
                           f"{fus['overlap']:.3f}",
        "slice": f"{m['slice']['rooms']} rooms, {m['slice']['doors']} doors; graph {m['slice']['graph']}",
        "floor-level map": f"{m['floor']['rooms']} rooms, {m['floor']['doors']} doors; graph {m['floor']['graph']}",
        "doors (slice)": "; ".join(f"D{k} at ({d['centre'][0]:.2f}, {d['centre'][1]:.2f}) m, {d['width']:.2f} m wide"
                                   for k, d in enumerate(m["slice"]["door_list"], 1)) or "none",
    }
    offsets = {f"{k} LiDAR offset": f"{_offset_text(e['value'])} from {e['source']}"
               for k, e in m["input_info"]["clouds"]["extrinsics"].items()}
    warn = "".join(f"<li>{esc(w)}</li>" for w in m["warnings"])
    figs = "".join(f'<figure><img src="figures/{esc(n)}.png" alt="{esc(n)}"><figcaption>{esc(c)}</figcaption>'
                   "</figure>" for n, c in m["figures"].items())
    files = ", ".join(f'<a href="{esc(f)}">{esc(f)}</a>' for f in OUTPUTS if f != "summary.html")
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>hsmap map: {esc(Path(m['input']).name)}</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:2em auto;padding:0 1em}}
table{{border-collapse:collapse}}th,td{{text-align:left;padding:.25em .8em;border-bottom:1px solid #ddd;vertical-align:top}}
img{{max-width:100%}}figure{{margin:1.5em 0}}.warn{{color:#a40}}</style></head><body>
<h1>{esc(Path(m['input']).name)}: the paper's chain</h1>
<table>{rows(numbers)}{rows(offsets)}</table>
{f'<h2 class="warn">Warnings</h2><ul class="warn">{warn}</ul>' if warn else ''}
{figs}
<h2>Files</h2><p>{files}. Open the recording with <code>rerun map.rrd</code>; load a map in Nav2 with
<code>ros2 run nav2_map_server map_server --ros-args -p yaml_filename:=slice.yaml</code>.</p>
</body></html>
"""
