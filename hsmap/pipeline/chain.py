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

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..config import to_dict
from ..datasets.frames import Dataset
from ..errors import InputError
from ..io import prepare_output_dir, sweep_stale_temporaries, to_plain, write_json, write_text
from ..maps.fusion import overlay_image
from ..maps.grid import grid_arrays, grid_from_arrays
from ..rooms.segmentation import Segmentation, points_in_doors
from .cache import FolderCache, description_digest
from .config import ChainConfig
from .outputs import (
    FigureSaver,
    grid_record,
    summary_page,
    write_door_points,
    write_grids,
    write_outputs_once,
)
from .outputs import write_ply as _write_ply
from .outputs import write_rooms as _write_rooms
from .runs import SlamRun
from .stages import (
    ChainGrids,
    StageLog,
    cached_stage,
    chain_grids,
    fuse_grids,
    rooms_stage,
    slam_runs,
    slam_summary,
)

__all__ = ["map_recording", "STAGES", "OUTPUTS"]

#: The stages, in order.
STAGES = ("slam2d", "slam3d", "grids", "fusion", "rooms")

#: What ``map_recording`` writes into its output folder (besides ``figures/`` and ``.stages/``).
OUTPUTS = ("trajectory2d.tum", "trajectory3d.tum", "floor.pgm", "floor.yaml", "floor.png", "slice.pgm",
           "slice.yaml", "slice.png", "overlay.png", "rooms.png", "doors.json", "topology.json", "topology.graphml",
           "segmentation.png", "floor_rooms.png", "floor_doors.json", "floor_topology.json",
           "floor_topology.graphml", "floor_segmentation.png", "door_points.json", "map2d.ply", "map3d.ply",
           "summary.html", "map.rrd", "metrics.json")


# --- the stages ---------------------------------------------------------------------------------------------

def _grids_stage(ds2: Dataset, ds3: Dataset, runs: tuple[SlamRun, SlamRun], config: ChainConfig, log: StageLog):
    def compute(folder: Path) -> None:
        bar = log.bar("grids", len(ds2) + len(ds3), "frame")
        grids = chain_grids(ds2, ds3, runs[0].trajectory, runs[1].trajectory, config.grids,
                            deskew=config.slam3d.deskew, bar=bar)
        bar.close()
        grids.save(folder / "grids.npz")

    return compute, lambda folder: ChainGrids.load(folder / "grids.npz")


def _fusion_stage(grids: ChainGrids, seed: int):
    def compute(folder: Path) -> None:
        a = fuse_grids(grids, seed)
        np.savez(folder / "fusion.npz", transformation=a.transformation, **grid_arrays("floor", a.floor),
                 **grid_arrays("slice", a.slice))
        write_json(folder / "fusion.json", a.as_dict())

    def load(folder: Path) -> dict:
        with np.load(folder / "fusion.npz") as z:
            out = {"transformation": z["transformation"], "floor": grid_from_arrays(z, "floor"),
                   "slice": grid_from_arrays(z, "slice")}
        out["summary"] = json.loads((folder / "fusion.json").read_text(encoding="utf-8"))
        return out

    return compute, load


# --- the whole chain ----------------------------------------------------------------------------------------

def map_recording(dataset: Dataset, out: str | Path, config: ChainConfig | None = None, *, seed: int = 0,
                  recording: bool = True, progress: bool | None = None, configuration: str | None = None) -> dict:
    """Run the paper's chain on one recording and write its outputs into ``out`` (see the module docstring).

    Parameters
    ----------
    dataset : Dataset
        A recording with 2D scans and 3D clouds (:func:`hsmap.datasets.open.open_dataset`); its
        :meth:`~hsmap.datasets.frames.Dataset.driven_by` views give the 2D and the 6-DOF run their frames.
    out : path
        Output folder (created); ``out/.stages/`` keeps the stages for the next run.
    config : ChainConfig, optional
        Every setting: both HS-SLAM runs, the grids (the slice ``grids.slice``, the cells, the slice's bins, the
        doors' boxes) and the segmentation; default ``ChainConfig()``.
    seed : int
        The seed of every random choice (both HS-SLAM runs, the map registration).
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
    cfg = ChainConfig() if config is None else config
    if not isinstance(cfg, ChainConfig):
        raise InputError(f"config must be a ChainConfig, got {type(cfg).__name__}")
    seed = int(seed)
    out = prepare_output_dir(out)  # a file, or a folder that cannot be written: said now, not after the runs
    sweep_stale_temporaries(out, OUTPUTS)  # what a killed run left (its staging folder, temporaries)
    ds2, ds3 = dataset.driven_by("scan"), dataset.driven_by("cloud")
    log, root = StageLog(progress), out / ".stages"
    cache = FolderCache(root)
    runs = slam_runs(ds2, ds3, cfg, seed, cache_dir=root / "slam", progress=progress, log=log)
    g = cfg.grids
    params = {"z_range": list(g.slice), "resolution": float(g.resolution), "slice_bins": int(g.slice_bins),
              "seed": seed}
    keys: dict[str, str] = {}
    grids, keys["grids"] = cached_stage(cache, log, "grids", {"slam": [r.key for r in runs], "params": params},
                                        _grids_stage(ds2, ds3, runs, cfg, log),
                                        detail="floor grid and the 3D map's slice", own_bar=True)
    fusion, keys["fusion"] = cached_stage(cache, log, "fusion", {"grids": keys["grids"], "seed": seed},
                                          _fusion_stage(grids, seed), detail="floor grid registered to the slice")
    segs, keys["rooms"] = cached_stage(cache, log, "rooms", {"grids": keys["grids"],
                                                             "segmentation": to_dict(cfg.segmentation)},
                                       rooms_stage({"slice": grids.slice, "floor": grids.floor}, cfg.segmentation),
                                       detail="doors, rooms and graph of both grids")
    # the outputs: rewritten unless every stage and the output options are unchanged and the folder complete
    options = {"door_depth": float(g.door_depth), "door_margin": float(g.door_margin), "recording": bool(recording),
               "z_range": list(g.slice), "configuration": configuration}
    final_key = description_digest({"slam": [r.key for r in runs], "stages": keys, "options": options})
    chain = _Chain(dataset, ds2, ds3, runs, grids, fusion, segs, cfg, recording, configuration)
    return write_outputs_once(out, OUTPUTS, final_key, recording, log,
                              lambda stage, bar: _write_outputs(stage, chain, bar), t_start)


# --- the outputs ----------------------------------------------------------------------------------------------

@dataclass
class _Chain:
    """What the outputs are written from."""

    dataset: Dataset
    ds2: Dataset
    ds3: Dataset
    runs: tuple[SlamRun, SlamRun]
    grids: ChainGrids
    fusion: dict
    segs: dict[str, Segmentation]
    config: ChainConfig
    recording: bool
    configuration: str | None

    @property
    def grid_dict(self) -> dict:
        return {"floor": self.grids.floor, "slice": self.grids.slice}


def _segmentation_picture(seg: Segmentation, g) -> np.ndarray:
    from ..viz.colors import segmentation_picture

    return segmentation_picture(seg.labels, g.free, seg.doors, g.geometry)


def _write_maps(out: Path, c: _Chain) -> None:
    """Trajectories, maps for Nav2, pictures of them, the overlay."""
    from PIL import Image

    from ..io import atomic_path
    from ..trajectory import write_tum

    write_tum(out / "trajectory2d.tum", c.runs[0].trajectory)
    write_tum(out / "trajectory3d.tum", c.runs[1].trajectory)
    write_grids(out, c.grid_dict)
    with atomic_path(out / "overlay.png") as tmp:
        Image.fromarray(overlay_image(c.fusion["floor"], c.fusion["slice"])).save(tmp, format="PNG")


def _door_points(out: Path, c: _Chain) -> tuple[float, list, list]:
    """The two point maps and the doors' points in them: the 2D LiDAR's height, the points of each door."""
    g = c.config.grids
    map2d, map3d = c.runs[0].map_points, c.runs[1].map_points
    h2 = _sensor_height(c.ds2)
    _write_ply(out / "map2d.ply", np.column_stack([map2d, np.full(len(map2d), h2)]))
    _write_ply(out / "map3d.ply", map3d)
    doors = c.segs["slice"].doors
    pts2 = points_in_doors(map2d, doors, depth=g.door_depth, margin=g.door_margin)
    pts3 = points_in_doors(map3d, doors, depth=g.door_depth, margin=g.door_margin, z_range=(-0.1, g.slice[1] + 1.5))
    write_door_points(out, doors, pts2, pts3, depth=g.door_depth, margin=g.door_margin,
                      frame="map (world x, y[, z] in metres)")
    return h2, pts2, pts3


def _metrics(c: _Chain, records: dict, pts2: list, pts3: list, figs: dict) -> dict[str, Any]:
    info_scan, info_cloud = c.ds2.describe(), c.ds3.describe()
    return {
        "input": str(c.dataset.path),
        "configuration": c.configuration,
        "input_info": {"scans": info_scan, "clouds": info_cloud},
        "warnings": list(dict.fromkeys([*info_scan.get("warnings", []), *info_cloud.get("warnings", [])])),
        "slam2d": slam_summary(c.runs[0]),
        "slam3d": slam_summary(c.runs[1]),
        "grids": {name: grid_record(g) for name, g in c.grid_dict.items()} | {"z_range": list(c.config.grids.slice)},
        "fusion": c.fusion["summary"],
        "slice": records["slice"],
        "floor": records["floor"],
        "door_points": [{"door": f"D{k}", "points2d": len(p2), "points3d": len(p3)}
                        for k, (p2, p3) in enumerate(zip(pts2, pts3, strict=True), 1)],
        "figures": figs,
    }


def _write_outputs(out: Path, c: _Chain, bar) -> dict:
    _write_maps(out, c)
    bar.update(1)
    graphs, records = _write_rooms(out, c.segs, c.grid_dict, _segmentation_picture)
    bar.update(1)
    h2, pts2, pts3 = _door_points(out, c)
    bar.update(1)
    figs = _figures(FigureSaver(out / "figures"), c, graphs, (pts2, pts3, h2))
    bar.update(1)
    metrics = _metrics(c, records, pts2, pts3, figs)
    write_text(out / "summary.html", _summary_html(out, metrics))
    bar.update(1)
    if c.recording:
        from ..viz.replay import record_map  # rerun: only when a recording is asked for

        record_map(out / "map.rrd", c.runs[0], c.runs[1], c.grid_dict, c.fusion, c.segs["slice"], graphs["slice"],
                   c.segs["slice"].doors, pts2, pts3, h2)
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


def _figures(save: FigureSaver, c: _Chain, graphs: dict, door_points: tuple) -> dict:
    from ..viz import figures, map_figures

    run2, run3 = c.runs
    grids, segs, z = c.grid_dict, c.segs, c.config.grids.slice
    ax = figures.plot_trajectories({"2D HS-SLAM": run2.trajectory, "6-DOF HS-SLAM": run3.trajectory}
                                   | ({"odometry": c.ds2.odometry} if c.ds2.odometry is not None else {}),
                                   title="the robot's path")
    save(ax.figure, "trajectories", "The 2D and 6-DOF HS-SLAM paths (and the wheel odometry).")
    fig, axes = figures.new_figure(1, 2, size=(14, 5))
    figures.plot_grid(grids["floor"].data, grids["floor"].geometry, ax=axes[0], title="floor-level 2D map")
    figures.plot_grid(grids["slice"].data, grids["slice"].geometry, ax=axes[1],
                      title=f"{z[0]}-{z[1]} m slice of the 3D map")
    save(fig, "grids", "The two occupancy grids (Nav2 maps: floor.yaml, slice.yaml).")
    ax = map_figures.plot_overlay(c.fusion["floor"], c.fusion["slice"], title="the 2D map registered to the slice")
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
    pts2, pts3, h2 = door_points
    doors = segs["slice"].doors
    if doors and any(len(p) for p in pts3):
        fig = map_figures.door_clouds_figure(doors, pts3, pts2, sensor2d_height=h2,
                                             title="the doors' points in the 3D map (by height) and the 2D map (x)")
        save(fig, "doors", "Each door's points in the 3D and the 2D map, seen from the front (Fig. 15).")
    return save.names


def _offset_text(value) -> str:
    """A sensor's pose in the base frame, (x, y, yaw) or (x, y, z, roll, pitch, yaw), with its units."""
    v = [float(x) for x in value]
    names = ("x", "y", "yaw") if len(v) == 3 else ("x", "y", "z", "roll", "pitch", "yaw")
    return ", ".join(f"{n} {round(float(np.degrees(x)), 2) + 0.0:.2f} deg" if n in ("roll", "pitch", "yaw")
                     else f"{n} {round(x, 3) + 0.0:.3f} m" for n, x in zip(names, v, strict=False))


def _summary_html(out: Path, m: dict) -> str:
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
    return summary_page(m, heading="the paper's chain", numbers=numbers | offsets, sections="", files=OUTPUTS,
                        opening="Open the recording with <code>rerun map.rrd</code>; load a map in Nav2 with\n"
                                "<code>ros2 run nav2_map_server map_server --ros-args -p "
                                "yaml_filename:=slice.yaml</code>.")
