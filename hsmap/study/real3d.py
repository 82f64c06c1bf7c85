"""Notebook 10's steps: a real building in 3D (OctoMap's Freiburg building 079 floor).

- :func:`band_rooms`: the rooms, doors and room/door graph of a height band of a 3D map (the grid of
  :func:`hsmap.maps.maps3d.band_grid` with the free space :func:`hsmap.maps.maps3d.segmentation_free` gives it,
  segmented by :func:`hsmap.rooms.segmentation.segment_rooms` with the defaults, as ``hsmap segment MAP3D --band
  LO,HI`` does): the paper's Table 2 row and Figure 18 for a real building;
- :func:`world_runs`: the simulated robot in the real voxel world (:func:`hsmap.sim.voxelrun.simulate_world`),
  the paper's whole chain on each run (:func:`hsmap.pipeline.chain.map_recording`) and the 6-DOF trajectory's
  per-DOF errors (:func:`hsmap.evaluation.trajectory.pose_errors`, the paper's Table 1) over several seeds;
- :func:`overlay_2d_map`: a 2D HS-SLAM map (the Freiburg fr079 log's) registered onto a band of the 3D map with
  no initial guess (:func:`hsmap.maps.fusion.global_align`, as ``hsmap align`` does): the paper's Figure 13 across
  two real sensors.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..datasets.open import open_dataset
from ..errors import EmptyInputError
from ..evaluation.trajectory import pose_errors
from ..io import write_json
from ..maps.fusion import global_align, occupied_points
from ..maps.grid import OCCUPIED, UNKNOWN, GridGeometry, OccupancyGrid
from ..maps.maps3d import band_grid
from ..pipeline.chain import map_recording
from ..pipeline.chain3d import band_grids
from ..rooms.segmentation import SegmentationConfig, segment_rooms
from ..rooms.topology import room_graph
from ..sim.voxelrun import load_voxel_world, simulate_world
from ..trajectory import read_tum
from .paths import datasets_dir, generated_dir

__all__ = ["TABLE1_BOUNDS", "MAP_FILE", "map_path", "BandRooms", "band_rooms", "WorldRun", "world_runs",
           "table1_summary", "write_summary", "points_grid", "overlay_2d_map"]

#: The paper's Table 1 bounds of the 6-DOF trajectory's largest errors (metres, degrees).
TABLE1_BOUNDS = {"x_m": 0.03, "y_m": 0.05, "z_m": 0.01, "roll_deg": 0.2, "pitch_deg": 0.2, "yaw_deg": 1.5}
#: The map under the datasets folder.
MAP_FILE = "octomap/geb079.bt"


def map_path(root: str | Path | None = None) -> Path | None:
    """geb079.bt under ``root`` (default :func:`hsmap.study.paths.datasets_dir`), or None when it is missing."""

    p = Path(root if root is not None else datasets_dir()) / MAP_FILE
    return p if p.is_file() else None


@dataclass
class BandRooms:
    """The rooms of one height band of a 3D map.

    Attributes
    ----------
    band : (float, float)
        Metres above the floor.
    grid : OccupancyGrid
        The band as the map knows it (free only where observed free in the band).
    segmented : OccupancyGrid
        The grid that was segmented: ``grid`` with :func:`hsmap.maps.maps3d.segmentation_free`'s free space.
    segmentation : Segmentation
    graph : networkx.Graph
        The room/door graph.
    seconds : float
    """

    band: tuple[float, float]
    grid: object
    segmented: object
    segmentation: object
    graph: object
    seconds: float

    def row(self) -> dict:
        """Table 2's row: rooms, doors, the known free area and the area in rooms (m^2)."""
        g, seg = self.segmented, self.segmentation
        px = g.geometry.resolution ** 2
        return {"rooms": int(seg.n_rooms), "doors": len(seg.doors), "free_m2": round(float(self.grid.free.sum() * px), 2),
                "segmented_free_m2": round(float(g.free.sum() * px), 2),
                "in_rooms_m2": round(float((seg.labels > 0).sum() * px), 2), "seconds": round(self.seconds, 2)}


def band_rooms(m, band: tuple[float, float], *, floor: float | None = None, config=None) -> BandRooms:
    """Rooms, doors and graph of a 3D map's height ``band`` (metres above the floor; see the module docstring).

    Parameters
    ----------
    m : hsmap.maps.maps3d.Map3D
    band : (float, float)
    floor : float, optional
        The floor's height in the map's frame (default :func:`hsmap.maps.maps3d.floor_height`).
    config : SegmentationConfig, optional
    """

    t = time.perf_counter()
    cfg = config or SegmentationConfig()
    lo, hi = float(band[0]), float(band[1])
    grid, segmented = band_grids(m, (lo, hi), floor=floor, min_passage=2.0 * cfg.min_door_half_width)
    seg = segment_rooms(segmented, config=cfg)
    return BandRooms((lo, hi), grid, segmented, seg, room_graph(seg), time.perf_counter() - t)


@dataclass
class WorldRun:
    """One simulated run in the real world and the chain's results on it."""

    seed: int
    dataset: Path
    out: Path
    world: dict
    chain: dict
    errors: dict
    seconds: dict = field(default_factory=dict)

    def within_bounds(self) -> bool:
        return all(self.errors[k] <= v for k, v in TABLE1_BOUNDS.items())


def world_runs(map_file: str | Path, seeds, *, max_frames: int | None = None, root: str | Path | None = None,
               log=print) -> list[WorldRun]:
    """Simulate the run through a 3D map for each seed, run the paper's chain on it and measure Table 1.

    Parameters
    ----------
    map_file : path
        The 3D map (:func:`hsmap.maps.maps3d.read_map3d`).
    seeds : iterable of int
    max_frames : int, optional
        A short route (quick runs).
    root : path, optional
        Where the datasets and the chain's outputs go (default ``generated_dir()/world-STEM``); the chain keeps
        its stages there, so a second call with the same inputs reads them back.
    log : callable
        Receives one line per run.
    """

    stem = Path(map_file).stem
    root = Path(root) if root is not None else generated_dir() / f"world-{stem}"
    world = load_voxel_world(map_file)
    runs = []
    for seed in seeds:
        tag = f"seed{int(seed)}" + (f"-first{max_frames}" if max_frames else "")
        data, out = root / tag / "dataset", root / tag / "map"
        t = time.perf_counter()
        sim = simulate_world(world, data, seed=int(seed), max_frames=max_frames)
        t_sim = time.perf_counter() - t
        t = time.perf_counter()
        chain = map_recording(open_dataset(data), out, seed=int(seed), recording=False, progress=False)
        t_map = time.perf_counter() - t
        est, gt = read_tum(out / "trajectory3d.tum"), read_tum(data / "groundtruth.tum")
        e = pose_errors(est, gt).as_dict()["max_abs_error"]
        run = WorldRun(int(seed), data, out, sim.as_dict(), chain, e, {"simulate": t_sim, "map": t_map})
        log(f"seed {seed}: {sim.frames} frames, {sim.motion.path_length():.1f} m; simulate {t_sim:.0f} s, "
            f"map {t_map:.0f} s; largest errors " + ", ".join(
                f"{k} {v * 100:.2f} cm" if k.endswith("_m") else f"{k} {v:.3f}" for k, v in e.items()))
        runs.append(run)
    return runs


def table1_summary(runs: list[WorldRun]) -> dict:
    """Per DOF over the runs: mean, spread (standard deviation) and worst of the largest errors, the bound and
    how many runs keep it."""
    out = {}
    for k, bound in TABLE1_BOUNDS.items():
        v = np.array([r.errors[k] for r in runs], dtype=float)
        out[k] = {"mean": float(v.mean()), "spread": float(v.std()), "worst": float(v.max()), "bound": bound,
                  "within": int((v <= bound).sum()), "runs": len(v)}
    return out


def write_summary(runs: list[WorldRun], path: str | Path) -> None:
    """The runs' numbers as JSON (seeds, frames, route, Table 1 errors, timings, slice rooms)."""

    write_json(path, {"runs": [{"seed": r.seed, "frames": r.world["frames"], "route_m": r.world["route_m"],
                                "errors": r.errors, "seconds": r.seconds,
                                "slice_rooms": r.chain.get("slice", {}).get("rooms"),
                                "slice_doors": r.chain.get("slice", {}).get("doors")} for r in runs],
                      "table1": table1_summary(runs)})


def points_grid(points, resolution: float = 0.05):
    """A 2D point map (N, 2+) as an occupancy grid: the points' cells occupied, the rest unknown (as ``hsmap
    align`` reads a point map)."""

    pts = np.asarray(points, dtype=float)[:, :2]
    if len(pts) < 3:
        raise EmptyInputError(f"a 2D point map needs at least 3 points, got {len(pts)}")
    geo = GridGeometry.covering(pts.min(axis=0), pts.max(axis=0), resolution, margin=0.5)
    data = np.full(geo.shape, UNKNOWN, dtype=np.int8)
    rc = geo.world_to_index(pts)
    data[rc[:, 0], rc[:, 1]] = OCCUPIED
    return OccupancyGrid(data, geo)


def overlay_2d_map(points2d, m, band: tuple[float, float] = (1.7, 1.8), *, seed: int = 1,
                   resolution: float = 0.05) -> dict:
    """Register a 2D point map (N, 2) onto a 3D map's band with no initial guess (:func:`hsmap.maps.fusion.global_align`).

    Returns
    -------
    dict
        ``alignment`` (the MapAlignment: 2D map frame -> 3D map frame), ``candidates`` (the search's),
        ``transform`` (x, y, yaw_deg), ``overlap``, ``covered`` (the part of the 2D map's occupied cells inside
        the 3D map's box, and that part's extent in the 2D map's frame) and ``seconds``.
    """

    t = time.perf_counter()
    pts = np.asarray(points2d, dtype=float)[:, :2]
    grid2d = points_grid(pts, resolution)
    target = band_grid(m, float(band[0]), float(band[1]))
    al, candidates = global_align(grid2d, target, floor_points=pts, rng=seed)
    T = al.transformation
    occ = occupied_points(grid2d)
    moved = occ @ T[:2, :2].T + T[:2, 2]
    x0, x1, y0, y1 = target.geometry.extent()
    inside = (moved[:, 0] >= x0) & (moved[:, 0] <= x1) & (moved[:, 1] >= y0) & (moved[:, 1] <= y1)
    covered = {"share_of_2d_map": float(inside.mean())}
    if inside.any():
        lo, hi = occ[inside].min(axis=0), occ[inside].max(axis=0)
        covered["extent_in_2d_frame"] = {"x": [float(lo[0]), float(hi[0])], "y": [float(lo[1]), float(hi[1])]}
    return {"alignment": al, "candidates": candidates, "seconds": time.perf_counter() - t,
            "transform": {"x": float(al.pose[0]), "y": float(al.pose[1]), "yaw_deg": float(np.rad2deg(al.pose[2]))},
            "overlap": {"overlap": float(al.overlap), "map2d_matched": float(al.floor_matched),
                        "map3d_matched": float(al.slice_matched)},
            "covered": covered}
