"""The paper's chain on a recording with a 3D LiDAR only (``hsmap map INPUT --out DIR`` without 2D scans).

Stages, each a :class:`hsmap.pipeline.cache.FolderCache` folder under ``DIR/.stages/`` as in
:mod:`hsmap.pipeline.chain`:

1. ``slam3d``: 6-DOF HS-SLAM on the clouds alone (no 2D prior, no odometry), or the poses of a given trajectory
   interpolated at each cloud's stamp (:func:`given_poses`);
2. ``voxels``: the 3D occupancy map, free space carved along every ray from the sensor
   (:func:`hsmap.maps.occupancy3d.carve_sweeps`, at ``grids.voxel``);
3. ``grids``: the floor under each sensor pose (:func:`hsmap.maps.occupancy3d.floor_under_path`; several floor levels),
   the map levelled to it, the floor-level band ``grids.floor_band`` and the slice ``grids.slice`` in heights above
   the local floor: each band's occupancy grid (map_server) and the free space segmented
   (:func:`hsmap.maps.maps3d.segmentation_free`: observed free, or seen through);
4. ``rooms``: doors, rooms and the room/door graph of both bands.

Outputs (the 2D+3D chain's where they make sense): ``trajectory3d.tum``, ``map3d.bt`` (OctoMap), ``map3d.ply``,
``floor.*`` (the floor-level band) and ``slice.*``, ``floor_levels.json``, the slice's ``rooms.png``,
``doors.json``, ``topology.*``, ``segmentation.png`` and the same with the prefix ``floor_``,
``door_points.json``, ``figures/``, ``summary.html``, ``map.rrd``, ``metrics.json`` (last). The 2D chain's
``trajectory2d.tum``, ``map2d.ply``, ``overlay.png`` and its ``slam2d`` and ``fusion`` stages have no input here:
:data:`SKIPPED` says why, and ``metrics.json``, ``summary.html`` and the command say so.
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..config import to_dict
from ..datasets.frames import Dataset
from ..deskew import deskew_frame
from ..errors import InputError
from ..geometry import pose_to_matrix
from ..io import prepare_output_dir, sweep_stale_temporaries, to_plain, write_json, write_text
from ..maps.grid import FREE, OCCUPIED, UNKNOWN, OccupancyGrid, grid_arrays, grid_from_arrays
from ..maps.mapping import voxel_downsample
from ..maps.maps3d import Map3D, band_grid, segmentation_free
from ..maps.occupancy3d import (
    carve_sweeps,
    floor_field,
    floor_under_path,
    level_map,
    sweep_bounds,
    write_octomap,
)
from ..rooms.segmentation import Segmentation, points_in_doors
from ..trajectory import Trajectory, write_tum
from .cache import FolderCache, description_digest
from .config import ChainConfig, GridsConfig
from .outputs import (
    FigureSaver,
    grid_record,
    summary_page,
    write_door_points,
    write_grids,
    write_outputs_once,
    write_ply,
    write_rooms,
)
from .runs import cached_slam, dataset_fingerprint
from .stages import StageLog, cached_stage, rooms_stage, slam_summary

__all__ = ["map_recording_3d", "given_poses", "GivenPoses", "posed_sweep", "carve_map", "band_grids", "levelled_bands",
           "OUTPUTS", "SKIPPED"]

#: What :func:`map_recording_3d` writes (besides ``figures/`` and ``.stages/``).
OUTPUTS = ("trajectory3d.tum", "map3d.bt", "map3d.ply", "floor.pgm", "floor.yaml", "floor.png", "slice.pgm",
           "slice.yaml", "slice.png", "floor_levels.json", "rooms.png", "doors.json", "topology.json",
           "topology.graphml", "segmentation.png", "floor_rooms.png", "floor_doors.json", "floor_topology.json",
           "floor_topology.graphml", "floor_segmentation.png", "door_points.json", "summary.html", "map.rrd",
           "metrics.json")

#: The 2D+3D chain's stages and outputs a 3D-only recording has no input for, and why.
SKIPPED = {
    "slam2d": "no 2D LiDAR: no 2D HS-SLAM run",
    "fusion": "no 2D map to register to the slice",
    "trajectory2d.tum": "no 2D LiDAR: no 2D trajectory",
    "map2d.ply": "no 2D LiDAR: no 2D point map",
    "overlay.png": "no 2D map to overlay on the slice",
}


@dataclass
class GivenPoses:
    """The 6-DOF poses of a trajectory file in place of the HS-SLAM run (the fields :class:`SlamRun` gives the
    chain)."""

    trajectory: Trajectory
    key: str
    metrics: dict
    cached: bool = True
    map_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))


def given_poses(dataset: Dataset, trajectory: Trajectory, source: str, max_dt: float) -> GivenPoses:
    """The poses of ``trajectory`` interpolated at the clouds' stamps (:meth:`Trajectory.interpolate`); clouds
    without a pose are left out.

    Raises
    ------
    InputError
        No cloud's stamp has a pose.
    """
    stamps = np.asarray(dataset.stamps, dtype=float)
    poses, ok = trajectory.as_6dof().interpolate(stamps, max_dt)
    if not ok.any():
        raise InputError(f"{source}: no pose at any of the {len(stamps)} clouds' stamps ({stamps[0]:.3f}-"
                         f"{stamps[-1]:.3f} s); the trajectory spans {trajectory.stamps[0]:.3f}-"
                         f"{trajectory.stamps[-1]:.3f} s")
    traj = Trajectory(stamps[ok], poses[ok])
    digest = hashlib.sha256(np.ascontiguousarray(traj.poses).tobytes() + traj.stamps.tobytes()).hexdigest()
    metrics = {"frames": int(ok.sum()), "poses_from": source, "clouds_without_pose": int((~ok).sum())}
    key = description_digest({"dataset": dataset_fingerprint(dataset), "poses": digest})
    return GivenPoses(traj, key, metrics)


# --- the stages ---------------------------------------------------------------------------------------------

def _sweeps(ds: Dataset, traj: Trajectory, voxel: float, deskew: bool) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Each posed cloud as (world points thinned to ``voxel``, the sensor's world position)."""
    poses, found = traj.as_6dof().at(np.asarray(ds.stamps, dtype=float), max_dt=1e-3)
    for f, pose, ok in zip(ds.frames(), poses, found, strict=True):
        if not ok or f.cloud3d is None:
            continue
        f = deskew_frame(f, prior=traj)[0] if deskew else f
        yield posed_sweep(f.cloud3d, pose_to_matrix(pose) @ pose_to_matrix(f.extrinsic3d), voxel)


def posed_sweep(cloud: np.ndarray, sensor_to_world: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """A cloud in its sensor's frame, thinned to ``voxel``, placed in the world by the (4, 4) ``sensor_to_world``:
    (world points, the sensor's world position), what :func:`carve_map` takes."""
    T = np.asarray(sensor_to_world, dtype=float)
    pts = voxel_downsample(np.asarray(cloud, dtype=float), voxel)
    return pts @ T[:3, :3].T + T[:3, 3], T[:3, 3].copy()


def carve_map(sweeps, grids: GridsConfig, bar=None, source: str = "the posed clouds") -> tuple[Map3D, np.ndarray]:
    """The 3D occupancy map of posed sweeps (:func:`posed_sweep`), free space carved along every ray
    (:func:`hsmap.maps.occupancy3d.carve_sweeps`, ``grids.voxel``, ``grids.max_range``), and the sensor positions.

    ``sweeps`` is read twice (the map's bounds, then the carving): a sequence, or a callable giving a new
    iterator each time.
    """
    def each():
        return sweeps() if callable(sweeps) else iter(sweeps)

    lo, hi = sweep_bounds(_counted(each(), bar), grids.max_range)
    sensors: list[np.ndarray] = []
    m = carve_sweeps(_counted(each(), bar, sensors), lo, hi, resolution=grids.voxel, max_range=grids.max_range,
                     source=source)
    return m, np.asarray(sensors, dtype=float).reshape(-1, 3)


def _voxels_stage(ds: Dataset, traj: Trajectory, cfg: ChainConfig, stages: StageLog):
    g, deskew = cfg.grids, cfg.slam3d.deskew

    def compute(folder: Path) -> None:
        bar = stages.bar("voxels", 2 * len(ds), "cloud")
        m, sensors = carve_map(lambda: _sweeps(ds, traj, g.voxel, deskew), g, bar)
        bar.close()
        np.savez_compressed(folder / "voxels.npz", state=m.state, origin=m.origin, resolution=m.resolution,
                            sensors=sensors)

    def load(folder: Path) -> tuple[Map3D, np.ndarray]:
        with np.load(folder / "voxels.npz") as z:
            return Map3D(z["state"], z["origin"], float(z["resolution"]), "the posed clouds"), z["sensors"]

    return compute, load


def _counted(items, bar, sensors: list | None = None):
    """The sweeps, counted on ``bar``; their sensor positions appended to ``sensors``."""
    for item in items:
        yield item
        if bar is not None:
            bar.update(1)
        if sensors is not None:
            sensors.append(item[1])


def band_grids(m: Map3D, band: tuple[float, float], *, floor: float | None, min_passage: float
               ) -> tuple[OccupancyGrid, OccupancyGrid]:
    """A height band of a 3D map (metres above ``floor``): its occupancy grid as the map knows it
    (:func:`hsmap.maps.maps3d.band_grid`) and the grid to segment, free where
    :func:`hsmap.maps.maps3d.segmentation_free` finds free space."""
    lo, hi = float(band[0]), float(band[1])
    grid = band_grid(m, lo, hi, floor=floor)
    free = segmentation_free(m, lo, hi, floor=floor, min_passage=min_passage)
    data = np.where(free, FREE, np.where(grid.occupied, OCCUPIED, UNKNOWN)).astype(np.int8)
    return grid, OccupancyGrid(data, grid.geometry)


def levelled_bands(m: Map3D, positions: np.ndarray, cfg: ChainConfig) -> dict:
    """The floor under each position, and per band (``floor``, ``slice``) its occupancy grid and the grid
    segmented (:func:`band_grids` of the map levelled to the floor)."""
    g = cfg.grids
    floors = floor_under_path(m, positions, radius=g.floor_radius, depth=g.floor_depth)
    level = level_map(m, floor_field(m, positions, floors, reach=g.floor_reach))
    out: dict[str, Any] = {"floors": floors}
    passage = 2.0 * cfg.segmentation.min_door_half_width
    for name, band in (("floor", g.floor_band), ("slice", g.slice)):
        out[name], out[f"{name}_segmented"] = band_grids(level, band, floor=0.0, min_passage=passage)
    return out


def _grids_stage(m: Map3D, positions: np.ndarray, cfg: ChainConfig):
    names = ("floor", "slice", "floor_segmented", "slice_segmented")

    def compute(folder: Path) -> None:
        bands = levelled_bands(m, positions, cfg)
        arrays = {}
        for name in names:
            arrays |= grid_arrays(name, bands[name])
        np.savez(folder / "grids.npz", floors=bands["floors"], **arrays)

    def load(folder: Path) -> dict:
        with np.load(folder / "grids.npz") as z:
            return {"floors": z["floors"]} | {name: grid_from_arrays(z, name) for name in names}

    return compute, load


# --- the whole chain ----------------------------------------------------------------------------------------

def _run_slam(ds3: Dataset, cfg: ChainConfig, seed: int, poses: GivenPoses | None, root: Path, stages: StageLog,
              progress: bool | None):
    t = time.perf_counter()
    if poses is not None:
        run = poses
    else:
        run = cached_slam(ds3, cfg.slam3d, seed, cache_dir=root / "slam", progress=progress)
    stages.done("slam3d", run.cached, time.perf_counter() - t, stages.bar("slam3d", 1) if run.cached else None)
    return run


def map_recording_3d(dataset: Dataset, out: str | Path, *, config: ChainConfig | None = None, seed: int = 0,
                     poses: GivenPoses | None = None, recording: bool = True, progress: bool | None = None) -> dict:
    """Run the paper's chain on a 3D-only recording and write its outputs into ``out`` (module docstring).

    Parameters
    ----------
    dataset : Dataset
        A recording with 3D clouds (its 2D scans, if any, are not used).
    out : path
        Output folder (created); ``out/.stages/`` keeps the stages for the next run.
    config : ChainConfig, optional
        ``slam3d``, ``grids`` (``voxel``, ``max_range``, ``floor_band``, ``slice``, ``floor_radius``,
        ``floor_depth``, the doors' boxes) and ``segmentation``; ``slam2d`` is not used.
    seed : int
        The seed of the HS-SLAM run.
    poses : GivenPoses, optional
        Poses in place of the HS-SLAM run (:func:`given_poses`).
    recording : bool
        Write ``map.rrd``.
    progress : bool or None
        Progress bars (None: on a terminal only).

    Returns
    -------
    dict
        What ``metrics.json`` holds.
    """
    t_start = time.perf_counter()
    cfg = config or ChainConfig()
    out = prepare_output_dir(out)
    sweep_stale_temporaries(out, OUTPUTS)
    ds3 = dataset.driven_by("cloud")
    stages, root = StageLog(progress), out / ".stages"
    cache = FolderCache(root)
    run = _run_slam(ds3, cfg, int(seed), poses, root, stages, progress)
    g = cfg.grids
    (vox, positions), vkey = cached_stage(cache, stages, "voxels", {"slam": run.key, "voxel": g.voxel,
                                                                    "max_range": g.max_range,
                                                                    "deskew": cfg.slam3d.deskew},
                                          _voxels_stage(ds3, run.trajectory, cfg, stages), own_bar=True)
    grids, gkey = cached_stage(cache, stages, "grids", {"voxels": vkey, "grids": to_dict(g),
                                                        "segmentation": to_dict(cfg.segmentation)},
                               _grids_stage(vox, positions, cfg))
    segmented = {"slice": grids["slice_segmented"], "floor": grids["floor_segmented"]}
    segs, rkey = cached_stage(cache, stages, "rooms", {"grids": gkey, "segmentation": to_dict(cfg.segmentation)},
                              rooms_stage(segmented, cfg.segmentation))
    final_key = description_digest({"stages": [run.key, vkey, gkey, rkey], "recording": bool(recording),
                                    "doors": [g.door_depth, g.door_margin]})
    ctx = _Context(dataset, ds3, run, vox, grids, segs, positions, cfg, recording)
    return write_outputs_once(out, OUTPUTS, final_key, recording, stages,
                              lambda stage, bar: _write_outputs(stage, ctx, bar), t_start)


# --- the outputs ----------------------------------------------------------------------------------------------

@dataclass
class _Context:
    """What the outputs are written from."""

    dataset: Dataset
    ds3: Dataset
    run: Any
    voxels: Map3D
    grids: dict
    segs: dict
    positions: np.ndarray
    config: ChainConfig
    recording: bool


def _write_maps(out: Path, c: _Context, map_points: np.ndarray) -> dict:
    write_tum(out / "trajectory3d.tum", c.run.trajectory)
    nodes = write_octomap(c.voxels, out / "map3d.bt")
    write_ply(out / "map3d.ply", map_points)
    write_grids(out, {name: c.grids[name] for name in ("floor", "slice")})
    floors = c.grids["floors"]
    write_json(out / "floor_levels.json", {
        "frame": "world z of the floor under each sensor pose, metres", "stamps": c.run.trajectory.stamps.tolist(),
        "sensor_z": np.round(c.positions[:, 2], 4).tolist(), "floor_z": np.round(floors, 4).tolist()})
    return {"octomap_nodes": nodes, "resolution": c.voxels.resolution, "shape": list(c.voxels.shape),
            "origin": c.voxels.origin.tolist(), "voxels": c.voxels.counts(),
            "floor_z": {"min": float(floors.min()), "median": float(np.median(floors)), "max": float(floors.max())},
            "sensor_above_floor_median": float(np.median(c.positions[:, 2] - floors))}


def _overlay_picture(seg: Segmentation, g: OccupancyGrid) -> np.ndarray:
    from ..viz.colors import label_overlay

    return label_overlay(seg.labels, g.free, doors=seg.doors)


def _door_points(out: Path, c: _Context, map_points: np.ndarray) -> list:
    g = c.config.grids
    doors = c.segs["slice"].doors
    pts = points_in_doors(map_points, doors, depth=g.door_depth, margin=g.door_margin)
    write_door_points(out, doors, [np.zeros((0, 2))] * len(pts), pts, depth=g.door_depth, margin=g.door_margin,
                      frame="map (world x, y, z in metres)")
    return pts


def _metrics(c: _Context, voxels: dict, records: dict, pts3: list, figs: dict) -> dict[str, Any]:
    info = c.ds3.describe()
    g = c.config.grids
    bands = {"floor": g.floor_band, "slice": g.slice}
    return {
        "input": str(c.dataset.path), "input_info": {"clouds": info},
        "warnings": list(dict.fromkeys(info.get("warnings", []))),
        "recording": "3D LiDAR only",
        "slam3d": slam_summary(c.run) if not isinstance(c.run, GivenPoses) else c.run.metrics,
        "voxels": voxels,
        "grids": {name: grid_record(c.grids[name]) | {"band_above_floor": list(band)} for name, band in bands.items()},
        "slice": records["slice"], "floor": records["floor"],
        "door_points": [{"door": f"D{k}", "points3d": len(p)} for k, p in enumerate(pts3, 1)],
        "skipped": dict(SKIPPED), "figures": figs,
    }


def _write_outputs(out: Path, c: _Context, bar) -> dict:
    pts = np.asarray(c.run.map_points, dtype=float).reshape(-1, 3)
    map_points = pts if len(pts) else c.voxels.centres()
    voxels = _write_maps(out, c, map_points)
    bar.update(1)
    segmented = {name: c.grids[f"{name}_segmented"] for name in ("slice", "floor")}
    graphs, records = write_rooms(out, c.segs, segmented, _overlay_picture)
    bar.update(1)
    pts3 = _door_points(out, c, map_points)
    bar.update(1)
    figs = _figures(FigureSaver(out / "figures"), c, graphs)
    bar.update(1)
    metrics = _metrics(c, voxels, records, pts3, figs)
    write_text(out / "summary.html", _summary_html(metrics))
    bar.update(1)
    if c.recording:
        from ..viz.replay import record_map

        run = c.run if len(pts) else _WithMap(c.run.trajectory, map_points)
        record_map(out / "map.rrd", None, run, {"slice": c.grids["slice_segmented"]}, None, c.segs["slice"],
                   graphs["slice"], c.segs["slice"].doors, [np.zeros((0, 2))] * len(pts3), pts3, 0.0)
    bar.update(1)
    return to_plain(metrics)


@dataclass
class _WithMap:
    trajectory: Trajectory
    map_points: np.ndarray


def _figures(save: FigureSaver, c: _Context, graphs: dict) -> dict:
    from ..viz import figures, map_figures

    g, grids, segs = c.config.grids, c.grids, c.segs
    ax = figures.plot_trajectories({"6-DOF": c.run.trajectory}, title="the sensor's path")
    save(ax.figure, "trajectories", "The sensor's path (6-DOF HS-SLAM, or the poses given).")
    fig, ax = figures.new_figure(1, 1, size=(10, 3.5))
    d = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(c.positions[:, :2], axis=0), axis=1))]
    ax.plot(d, c.positions[:, 2], label="sensor")
    ax.plot(d, grids["floors"], label="floor found below it")
    ax.set(xlabel="distance along the path (m)", ylabel="z (m)", title="the floor under the path")
    ax.legend()
    save(fig, "floor_levels", "The sensor's height and the floor found below it along the path (floor_levels.json).")
    fig, axes = figures.new_figure(1, 2, size=(14, 5))
    for ax, name, band in ((axes[0], "floor", g.floor_band), (axes[1], "slice", g.slice)):
        figures.plot_grid(grids[name].data, grids[name].geometry, ax=ax,
                          title=f"{band[0]:g}-{band[1]:g} m above the floor")
    save(fig, "grids", "The floor-level band and the slice of the 3D map (Nav2 maps: floor.yaml, slice.yaml).")
    s = segs["slice"]
    ax = map_figures.segmentation_figure(grids["slice_segmented"], s, graphs["slice"],
                                         title=f"{s.n_rooms} rooms, {len(s.doors)} doors on the slice, and the "
                                         "room/door graph")
    save(ax.figure, "rooms", "Rooms, doors (red) and the room/door graph of the slice (Figs. 12 and 16).")
    fig = map_figures.segmentation_comparison_figure(
        [(grids[f"{n}_segmented"], segs[n], f"{n}: {segs[n].n_rooms} rooms, {len(segs[n].doors)} doors")
         for n in ("floor", "slice")], title="one segmentation, two bands of the 3D map")
    save(fig, "comparison", "The same segmentation on the floor-level band and on the slice (Fig. 18).")
    return save.names


def _summary_html(m: dict) -> str:
    import html

    s3, v = m["slam3d"], m["voxels"]
    run = (f"poses from {s3['poses_from']} ({s3['frames']} clouds)" if "poses_from" in s3 else
           f"{s3['frames']} clouds, {s3['keyframes']} keyframes, {s3['loops_closed']} loops closed, "
           f"{s3['seconds_total']:.1f} s; no 2D prior, no odometry")
    numbers = {
        "input": f"{m['input']} (3D LiDAR only)",
        "6-DOF HS-SLAM": run,
        "3D map": f"{v['shape'][0]} x {v['shape'][1]} x {v['shape'][2]} voxels of {v['resolution']:g} m: "
                  f"{v['voxels']['occupied']} occupied, {v['voxels']['free']} free (map3d.bt, {v['octomap_nodes']} "
                  "OctoMap nodes)",
        "floor under the path": f"z {v['floor_z']['min']:.2f} to {v['floor_z']['max']:.2f} m (median "
                                f"{v['floor_z']['median']:.2f} m), sensor {v['sensor_above_floor_median']:.2f} m "
                                "above it (median)",
        "slice": f"{m['slice']['rooms']} rooms, {m['slice']['doors']} doors; graph {m['slice']['graph']}",
        "floor-level band": f"{m['floor']['rooms']} rooms, {m['floor']['doors']} doors; graph {m['floor']['graph']}",
    }
    skipped = "".join(f"<li><code>{html.escape(k)}</code>: {html.escape(r)}</li>" for k, r in m["skipped"].items())
    return summary_page(m, heading="the paper's chain, 3D LiDAR only", numbers=numbers,
                        sections=f"<h2>Skipped (no 2D LiDAR)</h2><ul>{skipped}</ul>\n", files=OUTPUTS,
                        opening="Open the 3D map with <code>octovis map3d.bt</code>, the recording with\n"
                                "<code>rerun map.rrd</code>; load a map in Nav2 with\n<code>ros2 run nav2_map_server "
                                "map_server --ros-args -p yaml_filename:=slice.yaml</code>.")
