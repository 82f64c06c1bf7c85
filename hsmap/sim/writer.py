"""``simulate``: drive a scenario's route, cast both LiDARs and write a documented dataset folder.

Folder contents (format version :data:`FORMAT_VERSION`; ``README.md`` in the folder says the same):

- ``dataset.yaml``      written last: a folder without it is incomplete. Format, scenario, seed, frame count and
                        rate, sensor descriptions, the file list.
- ``scans2d.npz``       ``stamps (N,)`` float64 s, ``ranges (N, M)`` float32 m (NaN = no return), ``angles (M,)``;
                        with a 2D scan time, ``beam_time (M,)`` float64 s after the stamp of each beam.
- ``clouds3d/NNNNNN.npz`` per frame ``range_mm (C, W)`` uint16 range image (0 = no return), ``stamp`` float64.
- ``groundtruth.tum``, ``odometry.tum``: robot base poses at the scan stamps.
- ``rooms.png`` (16-bit labels, 0 = no room) + ``rooms.yaml`` (resolution, origin, label -> name).
- ``doors.json``        the doors: centre, width, end points, the rooms they join, open/closed.
- ``scenario.yaml``     a copy of the scenario that made the data.

Every file is written atomically; identical scenario and seed give byte-identical files.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import os
import shutil
import time
import zipfile
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from .. import __version__
from ..config import to_dict
from ..datasets.simulated import FORMAT, FORMAT_VERSION, encode_range_image
from ..errors import DatasetError, ScenarioError
from ..geometry import pose_to_matrix
from ..io import atomic_path, staged_outputs, sweep_stale_temporaries, write_json, write_text
from ..trajectory import Trajectory, write_tum
from . import layout
from .catalog import resolve_scenario
from .robot import Motion, mast_matrices, mast_poses, mast_sway, sample_legs, simulate_motion
from .scenario import Scenario, load_scenario
from .world import World, _finish

__all__ = ["FORMAT", "FORMAT_VERSION", "SimulationSummary", "simulate", "save_npz", "motion_for", "noise_rngs",
           "write_sensor_frames", "rolling_scan2d", "rolling_scan3d"]


FILE_DESCRIPTIONS = {
    "dataset.yaml": "this description; written last, a folder without it is incomplete",
    "scans2d.npz": "2D LiDAR: stamps (N,) float64 s, ranges (N, M) float32 m with NaN = no return, "
                   "angles (M,) float64 rad in the 2D sensor frame",
    "clouds3d/": "3D LiDAR, one NNNNNN.npz per frame: range_mm (channels, columns) uint16 millimetres "
                 "(0 = no return), stamp float64 s; row i looks at vertical_angles_deg[i], column j at "
                 "azimuth_min + j * azimuth_increment",
    "groundtruth.tum": "ground-truth robot base poses in the world frame at the scan stamps (TUM: t x y z qx qy qz qw)",
    "odometry.tum": "wheel-odometry robot base poses in the odometry frame (starting at the first ground-truth "
                    "pose) at the scan stamps (TUM)",
    "rooms.png": "16-bit ground-truth room labels (0 = no room: walls, doorways, outside), row 0 at the top",
    "rooms.yaml": "map_server-style metadata of rooms.png (resolution, origin) and label -> room name",
    "doors.json": "ground-truth doors: centre, width, end points, the rooms they join, open/closed",
    "scenario.yaml": "the scenario file that made this dataset",
    "README.md": "human-readable description of this folder",
}


@dataclass
class SimulationSummary:
    """What :func:`simulate` wrote and measured."""

    path: Path
    scenario: str
    seed: int
    frames: int
    duration: float
    path_length: float
    odometry_end_error: float
    odometry_end_yaw_error_deg: float
    timings: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        return {
            "path": str(self.path), "scenario": self.scenario, "seed": self.seed, "frames": self.frames,
            "duration_s": round(self.duration, 3), "path_length_m": round(self.path_length, 3),
            "odometry_end_error_m": round(self.odometry_end_error, 4),
            "odometry_end_yaw_error_deg": round(self.odometry_end_yaw_error_deg, 3),
            "timings_s": {k: round(v, 3) for k, v in self.timings.items()},
        }


def save_npz(path: str | os.PathLike, compresslevel: int = 6, **arrays: np.ndarray) -> None:
    """Write arrays as a compressed ``.npz`` (readable by ``np.load``), atomically and byte-reproducibly
    (fixed zip timestamps, unlike ``np.savez_compressed``)."""
    with atomic_path(path, suffix=".npz") as tmp, zipfile.ZipFile(tmp, "w", allowZip64=True) as zf:
        for name, arr in arrays.items():
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.asanyarray(arr), allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.external_attr = 0o644 << 16
            zf.writestr(info, buf.getvalue(), compress_type=zipfile.ZIP_DEFLATED, compresslevel=compresslevel)


def noise_rngs(seed: int, stream: int, indices) -> list[np.random.Generator]:
    """One generator per frame index, independent of how frames are batched."""
    return [np.random.default_rng([int(seed), int(stream), int(k)]) for k in indices]


def motion_for(scn: Scenario, seed: int | None = None, max_frames: int | None = None) -> Motion:
    """The robot's ground truth and odometry for a scenario (no sensors): cheap, for checks and tests."""
    seed = scn.seed if seed is None else int(seed)
    m = simulate_motion(scn.start, scn.steps, scn.robot, scn.odometry, scn.frame_rate,
                        np.random.default_rng([seed, 1]), scn.start_time)
    if max_frames is not None and max_frames < len(m):
        if max_frames < 1:
            raise ScenarioError(f"max_frames must be >= 1, got {max_frames}")
        m.stamps, m.groundtruth, m.odometry = m.stamps[:max_frames], m.groundtruth[:max_frames], m.odometry[:max_frames]
        keep = m.sample_times <= m.stamps[-1] + 1e-9
        m.sample_times, m.sample_groundtruth, m.sample_odometry = (
            m.sample_times[keep], m.sample_groundtruth[keep], m.sample_odometry[keep])
    return m


def _as_scenario(scenario: Scenario | str | os.PathLike) -> Scenario:
    if isinstance(scenario, Scenario):
        return scenario
    return load_scenario(resolve_scenario(scenario))


def simulate(scenario: Scenario | str | os.PathLike, out: str | os.PathLike, seed: int | None = None, *,
             max_frames: int | None = None, label_resolution: float | None = None,
             batch_frames: int = 8, compresslevel: int = 1) -> SimulationSummary:
    """Simulate a scenario and write its dataset folder.

    Parameters
    ----------
    scenario : Scenario, str or path
        A parsed scenario, a shipped scenario name (``slam-office``, ``two-rooms``) or a YAML file.
    out : path
        Output folder. The dataset is written into a staging folder inside it and replaces the files of a previous
        dataset there when complete; a failed or interrupted run leaves them as they were.
    seed : int, optional
        Seed of all random choices (odometry slip, range noise); default the scenario's ``seed``.
    max_frames : int, optional
        Stop after this many frames (quick runs).
    label_resolution : float, optional
        Metres per pixel of ``rooms.png``; default the scenario's ``label_resolution`` (0.05).
    batch_frames : int
        3D frames ray-cast per open3d call.
    compresslevel : int
        zlib level of the 3D range images (1 is fast and nearly as small as 9 for noisy ranges).

    Returns
    -------
    SimulationSummary
    """

    t_start = time.perf_counter()
    scn = _as_scenario(scenario)
    seed = scn.seed if seed is None else int(seed)
    if seed < 0:
        raise ScenarioError(f"seed must be >= 0, got {seed}")
    final = Path(out)
    with staged_dataset_folder(final) as stage:
        summary = _write_dataset(scn, stage, seed, max_frames=max_frames, label_resolution=label_resolution,
                                 batch_frames=batch_frames, compresslevel=compresslevel, t_start=t_start)
    return dataclasses.replace(summary, path=final)


def _write_dataset(scn: Scenario, out: Path, seed: int, *, max_frames: int | None, label_resolution: float | None,
                   batch_frames: int, compresslevel: int, t_start: float) -> SimulationSummary:
    """Write the dataset folder of :func:`simulate` into the empty folder ``out``."""

    out = Path(out)
    timings: dict[str, float] = {}

    t = time.perf_counter()
    motion = motion_for(scn, seed, max_frames)
    n = len(motion)
    timings["motion"] = time.perf_counter() - t

    t = time.perf_counter()
    world = World(scn)
    timings["world"] = time.perf_counter() - t

    write_sensor_frames(out, world, motion, scn.lidar2d, scn.lidar3d, seed, timings, batch_frames=batch_frames,
                        compresslevel=compresslevel)

    t = time.perf_counter()
    gt, grid = _write_ground_truth(scn, out, motion, label_resolution)
    timings["ground_truth"] = time.perf_counter() - t

    end_err = float(np.hypot(*(motion.odometry[-1, :2] - motion.groundtruth[-1, :2])))
    yaw_err = float(np.rad2deg(np.angle(np.exp(1j * (motion.odometry[-1, 2] - motion.groundtruth[-1, 2])))))
    summary = SimulationSummary(out, scn.name, seed, n, float(motion.stamps[-1] - motion.stamps[0]),
                                gt.path_length(), end_err, yaw_err, timings)
    write_text(out / "README.md", _readme(scn, summary, grid))
    meta = _dataset_meta(scn, seed, motion, summary)
    timings["total"] = time.perf_counter() - t_start
    write_text(out / "dataset.yaml", yaml.safe_dump(meta, sort_keys=False, width=110))
    return summary


def _write_ground_truth(scn: Scenario, out: Path, motion: Motion, label_resolution: float | None):
    """The true and odometry trajectories (and the swaying mast's), the room labels, the doors and the scenario
    file; returns the true trajectory and the labels' grid."""
    gt = Trajectory(motion.stamps, motion.groundtruth)
    odo = Trajectory(motion.stamps, motion.odometry)
    write_tum(out / "groundtruth.tum", gt)
    write_tum(out / "odometry.tum", odo)
    l3 = scn.lidar3d
    if l3.sway_frequency > 0:
        write_tum(out / "groundtruth3d.tum", Trajectory(motion.stamps, mast_poses(
            motion.legs, motion.stamps, l3.position[:2], l3.position[2], l3.sway_frequency, l3.sway_damping)))
    labels, grid, names, _ = layout.rasterize_rooms(scn, label_resolution)
    _write_png16(out / "rooms.png", labels)
    write_text(out / "rooms.yaml", yaml.safe_dump({
        "image": "rooms.png",
        "resolution": grid.resolution,
        "origin": [grid.origin[0], grid.origin[1], 0.0],
        "labels": {int(k): v for k, v in names.items()},
        "convention": "map_server: origin is the world (x, y, yaw) of the lower-left pixel's lower-left corner; "
                      "row 0 of the image is the top; 0 = no room (walls, doorways, outside)",
    }, sort_keys=False))
    write_json(out / "doors.json", {"format_version": FORMAT_VERSION, "frame": "world",
                                    "doors": layout.door_records(scn)})
    if scn.path and Path(scn.path).is_file():
        with atomic_path(out / "scenario.yaml") as tmp:
            shutil.copyfile(scn.path, tmp)
    else:
        write_text(out / "scenario.yaml", yaml.safe_dump(scn.raw, sort_keys=False))
    return gt, grid


def _dataset_meta(scn: Scenario, seed: int, motion: Motion, summary: SimulationSummary) -> dict:
    """The contents of ``dataset.yaml``: format, scenario, run, frame conventions, sensors, robot, files."""
    files = dict(FILE_DESCRIPTIONS)
    if scn.lidar3d.sway_frequency > 0:
        files["groundtruth3d.tum"] = ("the swaying mast's true poses at the scan stamps (the base's pose tilted "
                                      "about the mast's foot; the 3D LiDAR is at this pose times its extrinsic), TUM")
    if scn.lidar3d.sweep_time > 0:
        files["clouds3d/"] += "; column_time (columns,) float64 s after stamp at which each column was measured"
    if scn.lidar2d.scan_time > 0:
        files["scans2d.npz"] += "; beam_time (M,) float64 s after the stamp at which each beam was measured"
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "hsmap_version": __version__,
        "scenario": scn.name,
        "scenario_sha256": scn.sha256,
        "description": scn.description,
        "seed": seed,
        "frames": summary.frames,
        "frame_rate": float(scn.frame_rate),
        "start_time": float(motion.stamps[0]),
        "duration": round(summary.duration, 6),
        "path_length": round(summary.path_length, 6),
        "odometry_end_error": round(summary.odometry_end_error, 6),
        "frames_conventions": {
            "world": "x, y on the floor, z up, metres; the floor is z = 0",
            "base": "robot base frame on the floor: x forward, y left, z up",
            "lidar2d": "scans in the 2D sensor frame; its pose in the base frame is sensors.lidar2d.extrinsic "
                       "at height sensors.lidar2d.mount_height",
            "lidar3d": "clouds in the 3D sensor frame; its pose in the base frame is sensors.lidar3d.extrinsic",
        },
        "sensors": {"lidar2d": scn.lidar2d.describe(), "lidar3d": scn.lidar3d.describe()},
        "robot": to_dict(scn.robot),
        "odometry_model": to_dict(scn.odometry),
        "files": files,
    }


def write_sensor_frames(out: Path, world, motion: Motion, lidar2d, lidar3d, seed: int, timings: dict, *,
                        batch_frames: int = 8, compresslevel: int = 1) -> np.ndarray:
    """Cast both LiDARs along a motion and write ``scans2d.npz`` and ``clouds3d/`` into ``out`` (atomically, the
    3D frames ray-cast while the previous batch is compressed); the timings go into ``timings``. Returns the 2D
    ranges (N, M). Shared by :func:`simulate` and the floor-plan worlds (:func:`hsmap.sim.building.simulate_building`)."""
    n = len(motion)
    t = time.perf_counter()
    ranges2d = np.empty((n, lidar2d.beams), dtype=np.float32)
    for a in range(0, n, 256):
        b = min(n, a + 256)
        if lidar2d.scan_time == 0:
            ranges2d[a:b] = world.scan2d(motion.groundtruth[a:b], lidar2d, noise_rngs(seed, 2, range(a, b)))
        else:
            ranges2d[a:b] = rolling_scan2d(world, motion.legs, motion.stamps[a:b], lidar2d,
                                           noise_rngs(seed, 2, range(a, b)))
    beam_time = {} if lidar2d.scan_time == 0 else {"beam_time": lidar2d.beam_times()}
    save_npz(out / "scans2d.npz", stamps=motion.stamps, ranges=ranges2d, angles=lidar2d.angles(), **beam_time)
    timings["scan2d"] = time.perf_counter() - t

    t = time.perf_counter()
    cdir = out / "clouds3d"
    cdir.mkdir(exist_ok=True)
    dirs = lidar3d.directions()
    t_cast = 0.0

    col_t = None if lidar3d.static else lidar3d.column_times()
    sway = None
    if lidar3d.sway_frequency > 0:
        times = (motion.stamps[:, None] + col_t[None, :]).reshape(-1)
        sway = mast_sway(motion.legs, times, lidar3d.position[:2], lidar3d.position[2], lidar3d.sway_frequency,
                         lidar3d.sway_damping).reshape(n, lidar3d.columns, 2)

    def write_frame(k: int, img: np.ndarray) -> None:
        extra = {} if col_t is None or lidar3d.sweep_time == 0 else {"column_time": col_t}
        save_npz(cdir / f"{k:06d}.npz", compresslevel, range_mm=encode_range_image(img),
                 stamp=np.float64(motion.stamps[k]), **extra)

    # ray-cast batch i+1 while a writer thread compresses batch i (zlib releases the GIL)
    with ThreadPoolExecutor(max_workers=1) as pool:
        pending: list = []
        for a in range(0, n, batch_frames):
            b = min(n, a + batch_frames)
            tc = time.perf_counter()
            if col_t is None:
                imgs = world.scan3d(motion.groundtruth[a:b], lidar3d, noise_rngs(seed, 3, range(a, b)), dirs)
            else:
                imgs = rolling_scan3d(world, motion.legs, motion.stamps[a:b], lidar3d,
                                      noise_rngs(seed, 3, range(a, b)), dirs, None if sway is None else sway[a:b])
            t_cast += time.perf_counter() - tc
            for f in pending:
                f.result()
            pending = [pool.submit(write_frame, k, imgs[k - a]) for k in range(a, b)]
        for f in pending:
            f.result()
    for stale in cdir.glob("*.npz"):
        if not stale.stem.isdigit() or int(stale.stem) >= n:
            stale.unlink()
    timings["scan3d"] = time.perf_counter() - t
    timings["scan3d_raycast"] = t_cast

    return ranges2d


def rolling_scan2d(world, legs, stamps, lidar2d, rngs=None) -> np.ndarray:
    """Planar scans (N, M) in metres (NaN = no return) of scans starting at ``stamps`` (N,): beam i cast at
    ``stamps + lidar2d.beam_times()[i]`` from the robot's pose along ``legs`` then. ``rngs``: None or one
    Generator per scan (noise and dropout as :meth:`hsmap.sim.world.World.scan2d`)."""

    stamps = np.asarray(stamps, dtype=float).reshape(-1)
    bt = lidar2d.beam_times()
    M = len(bt)
    poses = sample_legs(legs, (stamps[:, None] + bt[None, :]).reshape(-1)).reshape(len(stamps), M, 3)
    ext = lidar2d.extrinsic()
    c, s = np.cos(poses[..., 2]), np.sin(poses[..., 2])
    ang = poses[..., 2] + ext[2] + lidar2d.angles()[None, :]
    rays = np.empty((len(stamps), M, 6), dtype=np.float32)
    rays[..., 0] = poses[..., 0] + c * ext[0] - s * ext[1]
    rays[..., 1] = poses[..., 1] + s * ext[0] + c * ext[1]
    rays[..., 2] = lidar2d.height
    rays[..., 3], rays[..., 4], rays[..., 5] = np.cos(ang), np.sin(ang), 0.0
    r = world.cast_rays(rays.reshape(-1, 6)).reshape(len(stamps), M)
    return _finish(r, lidar2d.range_min, lidar2d.range_max, lidar2d.noise_sigma, lidar2d.dropout, rngs).astype(
        np.float32)


def rolling_scan3d(world, legs, stamps, lidar3d, rngs=None, directions=None, sway=None) -> np.ndarray:
    """Range images (N, channels, columns) in metres (NaN = no return) of sweeps starting at ``stamps`` (N,):
    column j cast at ``stamps + lidar3d.column_times()[j]`` from the robot's pose along ``legs`` then, the mast
    tilted by ``sway`` (N, columns, 2) roll and pitch about its foot (:func:`hsmap.sim.robot.mast_sway`).
    ``rngs``: None or one Generator per sweep (noise and dropout as :meth:`hsmap.sim.world.World.scan3d`)."""

    dirs_s = lidar3d.directions() if directions is None else np.asarray(directions)
    C, W = dirs_s.shape[:2]
    stamps = np.asarray(stamps, dtype=float).reshape(-1)
    col_t = lidar3d.column_times()
    E = pose_to_matrix(lidar3d.extrinsic())
    foot = lidar3d.position[:2]
    rays = np.empty((len(stamps), C, W, 6), dtype=np.float32)
    for k, t0 in enumerate(stamps):
        T = mast_matrices(legs, t0 + col_t, foot, None if sway is None else sway[k]) @ E
        rays[k, :, :, :3] = T[None, :, :3, 3]
        rays[k, :, :, 3:] = np.einsum("wij,cwj->cwi", T[:, :3, :3], dirs_s)
    r = world.cast_rays(rays.reshape(-1, 6)).reshape(len(stamps), C, W)
    return _finish(r, lidar3d.range_min, lidar3d.range_max, lidar3d.noise_sigma, lidar3d.dropout, rngs)


def _write_png16(path: Path, labels: np.ndarray) -> None:
    from PIL import Image

    with atomic_path(path) as tmp:
        Image.fromarray(np.ascontiguousarray(labels.astype(np.uint16))).save(tmp, format="PNG")


def _timing(l2, l3) -> str:
    """The README's sentence on when the LiDARs measure."""
    if l3.static and l2.scan_time == 0:
        return ("Both LiDARs take each frame's scan\ninstantaneously at the frame's ground-truth pose (no motion "
                "distortion); the robot moves on a flat floor.")
    if l2.scan_time == 0:
        first = "The 2D LiDAR takes each scan at the frame's stamp"
    else:
        first = (f"The 2D LiDAR turns once in {l2.scan_time:g} s from the stamp, beam i\nmeasured `beam_time[i]` "
                 "after it from the pose the robot has then")
    if l3.static:
        return f"{first}; the 3D LiDAR takes each cloud at the stamp; the robot moves on a flat floor."
    sway = (f", its {l3.position[2]:g} m mast swaying at {l3.sway_frequency:g} Hz (damping {l3.sway_damping:g}) "
            "with the base's acceleration" if l3.sway_frequency > 0 else "")
    return (f"{first}; the 3D LiDAR sweeps over {l3.sweep_time:g} s from "
            f"the stamp,\ncolumn j at `column_time[j]` after it, from the pose the robot has then{sway}; the robot "
            "moves on a flat floor.")


def _beam_time_line(l2) -> str:
    """The README's line on ``beam_time`` (empty for scans taken at one instant)."""
    if l2.scan_time == 0:
        return ""
    return (f"\n  `beam_time` ({l2.beams},) float64 s: beam i is measured i * {l2.time_increment:g} s after the "
            f"stamp\n  (one turn of the scanner takes {l2.scan_time:g} s: `sensors.lidar2d.scan_time`).")


def _readme(scn: Scenario, s: SimulationSummary, grid) -> str:
    l2, l3 = scn.lidar2d, scn.lidar3d
    return f"""# Simulated dataset: {scn.name}

{scn.description}

Written by `hsmap simulate` (hsmap {__version__}), seed {s.seed}: {s.frames} frames at {scn.frame_rate:g} Hz
over {s.duration:.1f} s, a route of {s.path_length:.1f} m; the wheel odometry ends {s.odometry_end_error:.2f} m
and {s.odometry_end_yaw_error_deg:.1f} deg off the ground truth. Same scenario and seed: byte-identical files.
Read it with `hsmap.datasets.simulated.SimulatedDataset(folder)`.

## Frames and units
Metres, seconds, radians (degrees only where a key says `_deg`). The world frame has z up and the floor at
z = 0. The robot base frame lies on the floor (x forward, y left). Poses are (x, y, yaw); 3D poses
(x, y, z, roll, pitch, yaw) with R = Rz(yaw) Ry(pitch) Rx(roll). {_timing(l2, l3)}

## Files
- `dataset.yaml`: format `{FORMAT}` version {FORMAT_VERSION}, scenario, seed, frame count and rate, the
  sensors, robot and odometry model, the file list. Written last: without it the folder is incomplete.
- `scans2d.npz`: `stamps` (N,) float64 s; `ranges` (N, {l2.beams}) float32 m, NaN = no return; `angles`
  ({l2.beams},) rad. The 2D LiDAR scans a horizontal plane {l2.height:g} m above the floor from
  {l2.angle_min_deg:g} to {l2.angle_max_deg:g} deg in {l2.angle_increment_deg:g} deg steps, ranges
  {l2.range_min:g}..{l2.range_max:g} m, Gaussian noise sigma {l2.noise_sigma:g} m; its pose in the base
  frame is `sensors.lidar2d.extrinsic` (x, y, yaw).{_beam_time_line(l2)}
- `clouds3d/NNNNNN.npz` (one per frame, NNNNNN = frame index): `range_mm` ({l3.channels}, {l3.columns})
  uint16 millimetres, 0 = no return; `stamp` float64 s. Row i looks at elevation
  `sensors.lidar3d.vertical_angles_deg[i]` (top beam first), column j at azimuth -pi + j * 2 pi / {l3.columns}
  (counter-clockwise from the sensor's x axis). The point of pixel (i, j) in the sensor frame is
  r * (cos el cos az, cos el sin az, sin el). Ranges {l3.range_min:g}..{l3.range_max:g} m, noise sigma
  {l3.noise_sigma:g} m; the sensor's pose in the base frame is `sensors.lidar3d.extrinsic`
  (x, y, z, roll, pitch, yaw), {l3.position[2]:g} m above the floor.
- `groundtruth.tum`: true robot base poses in the world frame, one per frame, stamps equal to the scans'.
- `odometry.tum`: wheel odometry of the robot base (odometry frame = world frame at the first pose), same
  stamps. Error model: scale {scn.odometry.scale_error:+g}, rotation scale {scn.odometry.turn_scale_error:+g},
  heading bias {scn.odometry.heading_bias_deg_per_m:g} deg/m, random slip (stronger when turning on the spot).
- `rooms.png` + `rooms.yaml`: ground-truth room labels, {grid.shape[0]} x {grid.shape[1]} pixels of
  {grid.resolution:g} m, 16-bit, 0 = no room (walls, doorways, outside), label k = room k of the scenario;
  `rooms.yaml` gives the resolution, the map_server origin (world x, y of the lower-left corner of the
  lower-left pixel) and the label names. Furniture does not change the labels.
- `doors.json`: per door its name, centre (x, y), width, height, end points, wall, the rooms on both sides
  (`null` = outside) and whether it is open.
- `scenario.yaml`: the scenario that made this dataset.
"""


DATASET_OUTPUTS = [name.rstrip("/") for name in FILE_DESCRIPTIONS] + ["figures", "world.json", "building.json"]
"""Every file and folder a simulator writes into a dataset folder (a rerun of another kind leaves none of an
earlier run's beside its own)."""


@contextlib.contextmanager
def staged_dataset_folder(out: str | os.PathLike) -> Iterator[Path]:
    """Yield an empty staging folder inside the dataset folder ``out`` (created; a file there is a
    :class:`DatasetError`); when the ``with`` block ends without an error, its files replace those of the dataset
    there, ``dataset.yaml`` last (:func:`hsmap.io.staged_outputs`). A failed or interrupted run leaves a previous
    dataset as it was, and a folder it created empty is removed."""
    final = Path(out)
    if final.exists() and not final.is_dir():
        raise DatasetError(f"{final}: exists and is not a folder")
    created = not final.exists()
    final.mkdir(parents=True, exist_ok=True)
    sweep_stale_temporaries(final, DATASET_OUTPUTS)  # left by a killed run
    try:
        with staged_outputs(final, last="dataset.yaml", folders=True, replaces=DATASET_OUTPUTS) as stage:
            yield stage
    except BaseException:
        if created:
            with contextlib.suppress(OSError):
                final.rmdir()  # only when empty
        raise
