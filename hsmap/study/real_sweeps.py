"""Notebook 11's steps and the 3D peers benchmark's inputs: real 3D LiDAR sweeps (the BALM benchmark's real-world
hall, ``$HSMAP_DATASETS/balm``: ``full0.pcd`` .. ``full176.pcd`` and ``alidarPose.csv``, see its README).

- :func:`balm_folder`, :func:`sweep_files`, :func:`read_reference`: the sweeps in their natural order (``full2``
  before ``full10``) and the reference poses (one 4x4 pose a sweep whose last cell holds the sweep's Unix time);
- :func:`sweep_folder`: a folder hsmap's cloud reader takes as it stands (``000.pcd`` .. links to the sweeps in
  order and a ``times.txt`` of the reference stamps), so that HS-SLAM and the peers read the same clouds;
- :func:`score_track`: one scoring for every odometry or SLAM on the sweeps (:class:`TrackScore`);
- :func:`run_hs_slam`: HS-SLAM 6-DOF with the command line's defaults (``hsmap slam FOLDER --dof 6``);
- :func:`posed_points`: the posed sweeps as a point map, one point a voxel;
- :func:`slice_rooms`: the posed sweeps through the 3D-only chain's stages (:mod:`hsmap.pipeline.chain3d`, as ``hsmap
  map`` maps a 3D-only recording with ``--poses``): the voxel map carved along the rays, the floor under the walked
  trajectory, a height band above it and its rooms.

Scoring (:func:`score_track`):

- **ATE**: evo's APE after a rigid SE(3) Umeyama alignment of the positions
  (:func:`hsmap.evaluation.trajectory.ate`), translation (m) and rotation angle (deg): RMSE and maximum;
- **per-DOF errors**: the aligned estimate's pose vector minus the reference's, ``x y z`` (m) and ``roll pitch
  yaw`` (deg, wrapped), per sweep, with their largest absolute values and their values at the last sweep;
- **lost track** (rule :data:`LOST_TRACK_M`): the first sweep whose position, with the estimate and the reference
  each taken relative to their first sweep (no alignment, as :func:`hsmap.evaluation.trajectory.pose_errors`), is
  more than 1 m off; None when none is;
- **worst step**: the largest sweep-to-sweep error (evo's RPE, delta one sweep) and the sweep it ends at.
"""

from __future__ import annotations

import itertools
import os
import re
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..errors import DataFormatError, InputError
from ..evaluation.trajectory import (
    Alignment,
    DeltaUnit,
    PoseRelation,
    align,
    associate,
    ate,
    pose_errors,
    rpe,
)
from ..geometry import matrix_to_pose, pose_to_matrix, wrap_angle
from ..io import write_text
from ..trajectory import Trajectory
from .paths import datasets_dir

__all__ = ["BALM_FOLDER", "POSES_FILE", "LOST_TRACK_M", "balm_folder", "missing_balm_reason", "sweep_files",
           "read_reference", "sweep_folder", "open_sweeps", "TrackScore", "score_track", "run_hs_slam", "HsSlamRun",
           "posed_points", "slice_rooms", "SliceRooms"]

#: The sweeps' folder under the datasets folder.
BALM_FOLDER = "balm"
#: The reference poses' file in it.
POSES_FILE = "alidarPose.csv"
#: A track is lost from the first sweep whose position relative to the first sweep is this far off (m).
LOST_TRACK_M = 1.0
_SWEEP = re.compile(r"^full(\d+)\.pcd$")
_DOF = ("x", "y", "z", "roll", "pitch", "yaw")


def sweep_files(folder: str | os.PathLike) -> list[Path]:
    """The folder's ``fullN.pcd`` files in the order of N (natural order: ``full2`` before ``full10``).

    Raises
    ------
    InputError
        No ``fullN.pcd`` file in ``folder``, or a number missing between 0 and the largest.
    """
    folder = Path(folder)
    numbered = sorted((int(m.group(1)), p) for p in folder.iterdir() if (m := _SWEEP.match(p.name)))
    if not numbered:
        raise InputError(f"{folder}: no sweep files full0.pcd, full1.pcd, ...")
    missing = sorted(set(range(numbered[-1][0] + 1)) - {n for n, _ in numbered})
    if missing:
        raise InputError(f"{folder}: sweep files missing: {', '.join(f'full{n}.pcd' for n in missing[:5])}"
                         + (f" and {len(missing) - 5} more" if len(missing) > 5 else ""))
    return [p for _, p in numbered]


def balm_folder(root: str | os.PathLike | None = None) -> Path | None:
    """``root/balm`` (default root :func:`hsmap.study.paths.datasets_dir`) when it holds the sweeps and the
    reference poses, else None."""
    p = Path(root if root is not None else datasets_dir()) / BALM_FOLDER
    if not (p / POSES_FILE).is_file():
        return None
    try:
        sweep_files(p)
    except (InputError, OSError):
        return None
    return p


def missing_balm_reason(root: str | os.PathLike | None = None) -> str:
    """Why the BALM sweeps are not there, in the words a skipped notebook shows."""
    where = Path(root if root is not None else datasets_dir()) / BALM_FOLDER
    return f"no data: the BALM sweeps (full0.pcd .. and {POSES_FILE}) are not in {where}"


def read_reference(folder: str | os.PathLike) -> Trajectory:
    """The reference poses of ``folder/alidarPose.csv``: 4 lines of 4 comma-separated numbers a sweep, the rows of
    the sensor's 4x4 pose in the world with the sweep's Unix time in its last cell; a 6-DOF trajectory.

    Raises
    ------
    DataFormatError
        A line without 4 numbers, a count of lines not a multiple of 4, a pose whose last row is not ``0 0 0 t``
        or whose rotation is not one (naming the file and the pose).
    """
    path = Path(folder) / POSES_FILE
    rows = []
    with open(path, encoding="utf-8") as fh:
        for lineno, line in enumerate(fh, 1):
            if not line.strip():
                continue
            vals = [v for v in line.strip().split(",") if v.strip()]
            try:
                nums = [float(v) for v in vals]
            except ValueError:
                raise DataFormatError(f"{path}:{lineno}: expected 4 comma-separated numbers, got {line.strip()!r}") \
                    from None
            if len(nums) != 4:
                raise DataFormatError(f"{path}:{lineno}: expected 4 comma-separated numbers, got {len(nums)}")
            rows.append(nums)
    if not rows or len(rows) % 4:
        raise DataFormatError(f"{path}: {len(rows)} lines of numbers is not a whole number of 4x4 poses")
    M = np.asarray(rows).reshape(-1, 4, 4)
    stamps = M[:, 3, 3].copy()
    bad = np.flatnonzero(np.abs(M[:, 3, :3]).max(axis=1) > 0)
    if bad.size:
        raise DataFormatError(f"{path}: pose {bad[0]}: its last row must be 0 0 0 t")
    R = M[:, :3, :3]
    off = np.abs(np.swapaxes(R, 1, 2) @ R - np.eye(3)).max(axis=(1, 2))
    if (off > 1e-3).any():
        raise DataFormatError(f"{path}: pose {int(np.argmax(off > 1e-3))}: its 3x3 part is not a rotation")
    if not (np.diff(stamps) > 0).all():
        raise DataFormatError(f"{path}: the stamps (last cell of each pose) do not increase")
    M[:, 3, 3] = 1.0
    return Trajectory(stamps, matrix_to_pose(M))


def sweep_folder(folder: str | os.PathLike, dest: str | os.PathLike, *, max_sweeps: int | None = None) -> Path:
    """A folder hsmap's cloud reader takes as it stands: links ``000.pcd`` .. to the sweeps of ``folder`` in their
    natural order and a ``times.txt`` of the reference stamps (the first ``max_sweeps``). ``dest`` is made or
    refreshed; returns it."""
    files = sweep_files(folder)
    ref = read_reference(folder)
    if len(ref) != len(files):
        raise InputError(f"{folder}: {len(files)} sweep files but {len(ref)} poses in {POSES_FILE}")
    n = len(files) if max_sweeps is None else max(1, min(int(max_sweeps), len(files)))
    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    width = max(3, len(str(len(files) - 1)))
    keep = set()
    for i, f in enumerate(files[:n]):
        link = dest / f"{i:0{width}d}.pcd"
        keep.add(link.name)
        if link.is_symlink() and os.readlink(link) == str(f.resolve()):
            continue
        if link.exists() or link.is_symlink():
            link.unlink()
        link.symlink_to(f.resolve())
    for p in dest.glob("*.pcd"):
        if p.name not in keep:
            p.unlink()
    write_text(dest / "times.txt", "".join(f"{t:.6f}\n" for t in ref.stamps[:n]))
    return dest


def open_sweeps(folder: str | os.PathLike):
    """The sweep folder as hsmap's reader opens it for a 6-DOF run (the clouds drive the frames), the robot base
    taken as the sensor (the sweeps are in the sensor's frame)."""
    from ..datasets.open import open_dataset

    return open_dataset(folder, drive="cloud", extrinsic3d=np.zeros(6))


@dataclass
class TrackScore:
    """One estimate scored against the reference (see the module docstring).

    Attributes
    ----------
    stamps : ndarray of shape (N,)
        The scored sweeps' stamps (the estimate's, each matched to the reference's).
    sweeps : ndarray of shape (N,)
        Their sweep numbers (0 = the reference's first).
    aligned : ndarray of shape (N, 6)
        The estimate after the SE(3) alignment (x, y, z, roll, pitch, yaw).
    errors : ndarray of shape (N, 6)
        ``aligned`` minus the reference (m, rad; angles wrapped).
    summary : dict
        JSON-ready numbers.
    """

    stamps: NDArray[np.float64]
    sweeps: NDArray[np.intp]
    aligned: NDArray[np.float64]
    errors: NDArray[np.float64]
    summary: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        return self.summary


def _per_dof(values) -> dict:
    return {(f"{n}_deg" if i >= 3 else f"{n}_m"): float(np.degrees(v) if i >= 3 else v)
            for i, (n, v) in enumerate(zip(_DOF, values, strict=True))}


def score_track(est: Trajectory, ref: Trajectory, *, lost_m: float = LOST_TRACK_M) -> TrackScore:
    """Score a 6-DOF estimate of the sweeps against the reference (see the module docstring); every estimated stamp
    must be one of the reference's (within 1 ms)."""
    est, q = associate(est.as_6dof(), ref.as_6dof())
    sweeps = np.searchsorted(ref.stamps, q.stamps)
    t = ate(est, q, alignment=Alignment.SE3, relation=PoseRelation.TRANSLATION)
    r = ate(est, q, alignment=Alignment.SE3, relation=PoseRelation.ROTATION_ANGLE)
    P, T, _ = align(est, q, Alignment.SE3)
    aligned = matrix_to_pose(P)
    err = aligned - matrix_to_pose(pose_to_matrix(q.poses))
    err[:, 3:] = wrap_angle(err[:, 3:])
    start = pose_errors(est, q)
    from_start = np.linalg.norm(start.errors[:, :3], axis=1)
    over = np.flatnonzero(from_start > lost_m)
    lost = int(sweeps[over[0]]) if over.size else None
    summary: dict = {
        "poses": len(est), "reference_sweeps": len(ref),
        "ate_rmse_m": t.statistics.rmse, "ate_max_m": t.statistics.max,
        "ate_rotation_rmse_deg": r.statistics.rmse, "ate_rotation_max_deg": r.statistics.max,
        "max_abs_error": _per_dof(np.abs(err).max(axis=0)), "final_error": _per_dof(np.abs(err[-1])),
        "max_abs_error_from_start": start.as_dict()["max_abs_error"],
        "lost_track_rule": f"first sweep more than {lost_m:g} m off, both relative to their first sweep",
        "lost_track_from_sweep": lost, "max_error_from_start_m": float(from_start.max()),
    }
    if len(est) > 1:
        st = rpe(est, q, delta=1, unit=DeltaUnit.FRAMES, relation=PoseRelation.TRANSLATION)
        sr = rpe(est, q, delta=1, unit=DeltaUnit.FRAMES, relation=PoseRelation.ROTATION_ANGLE)
        k = int(np.argmax(st.errors))
        j = int(np.argmax(sr.errors))
        summary["worst_step"] = {"translation_m": float(st.errors[k]), "translation_at_sweep": int(sweeps[k + 1]),
                                 "rotation_deg": float(sr.errors[j]), "rotation_at_sweep": int(sweeps[j + 1])}
    return TrackScore(est.stamps.copy(), sweeps, aligned, err, summary)


@dataclass
class HsSlamRun:
    """HS-SLAM 6-DOF on a sweep folder: the trajectory, the map's points and the time it took."""

    trajectory: Trajectory
    map_points: NDArray[np.float64]
    wall_per_sweep: NDArray[np.float64]
    wall_seconds: float
    cpu_seconds: float
    metrics: dict

    def timing(self) -> dict:
        n = max(len(self.wall_per_sweep), 1)
        return {"wall_seconds": self.wall_seconds, "cpu_seconds": self.cpu_seconds,
                "wall_per_sweep_median_s": float(np.median(self.wall_per_sweep)) if len(self.wall_per_sweep) else None,
                "cpu_per_sweep_mean_s": self.cpu_seconds / n}


def run_hs_slam(folder: str | os.PathLike, *, seed: int = 1, config=None, max_sweeps: int | None = None) -> HsSlamRun:
    """HS-SLAM 6-DOF on a folder of sweeps as ``hsmap slam FOLDER --dof 6 --seed SEED`` runs it (the command line's
    default configuration unless ``config``; the clouds drive the frames). The sweeps are read first, as the
    peers' are (:mod:`hsmap.study.peers3d`), so that neither time counts the reading. CPU time: this process's and
    hsmap's helper process's, all threads."""
    from ..slam import SlamConfig, run_slam

    cfg = config if config is not None else SlamConfig(dof=6)
    ds = open_sweeps(folder)
    if ds.odometry is not None:
        raise InputError(f"{folder}: a sweep folder has no odometry; this one reads as having some")
    frames = list(itertools.islice(ds.frames(clouds=True), max_sweeps))
    t0 = time.perf_counter()
    res = run_slam(frames, cfg, rng=seed, progress=False)
    wall = time.perf_counter() - t0
    pts = np.asarray(res.map.points)
    return HsSlamRun(res.trajectory.as_6dof(), pts, np.array([f.seconds for f in res.frames]), wall,
                     float(res.cpu_seconds), res.metrics())


def _voxel_keys(points: NDArray[np.float64], voxel: float) -> NDArray[np.int64]:
    """One int64 per point naming its voxel (21 bits an axis: +-1e6 voxels)."""
    k = np.floor(points / voxel).astype(np.int64) + (1 << 20)
    if (k < 0).any() or (k >= 1 << 21).any():
        raise InputError(f"points more than {(1 << 20) * voxel:g} m from the origin: too far for {voxel:g} m voxels")
    return (k[:, 0] << 42) | (k[:, 1] << 21) | k[:, 2]


def posed_points(sweeps, trajectory: Trajectory, *, voxel: float = 0.1, min_range: float | None = None,
                 max_range: float | None = None) -> NDArray[np.float64]:
    """The sweeps placed at the trajectory's poses (one pose a sweep, in order), each cut to the ranges HS-SLAM
    uses (default :class:`hsmap.slam.SlamConfig`'s ``min_range`` and ``max_range``), thinned to one point a
    ``voxel`` (the first point to land in it)."""
    from ..geometry import transform_points
    from ..slam import SlamConfig

    cfg = SlamConfig()
    lo = cfg.min_range if min_range is None else float(min_range)
    hi = cfg.max_range if max_range is None else float(max_range)
    poses = pose_to_matrix(trajectory.as_6dof().poses)
    sweeps = list(sweeps)
    if len(sweeps) != len(poses):
        raise InputError(f"{len(sweeps)} sweeps but {len(poses)} poses: give one pose a sweep")
    keys, pts = [], []
    for T, s in zip(poses, sweeps, strict=True):
        s = np.asarray(s, dtype=float)
        r = np.linalg.norm(s, axis=1)
        p = transform_points(T, s[(r >= lo) & (r <= hi)])
        k = _voxel_keys(p, voxel)
        _, first = np.unique(k, return_index=True)
        keys.append(k[first])
        pts.append(p[first])
    k, p = np.concatenate(keys), np.vstack(pts)
    _, first = np.unique(k, return_index=True)
    return p[np.sort(first)]


@dataclass
class SliceRooms:
    """The map of the posed sweeps and the rooms of one of its height bands.

    Attributes
    ----------
    map : hsmap.maps.maps3d.Map3D
        The posed sweeps' 3D occupancy map, free space carved along every ray.
    floor : float
        The median of :attr:`floors`.
    floors : ndarray of shape (S,)
        The floor's world height under each sweep's sensor.
    rooms : hsmap.study.real3d.BandRooms
        The band's grids (heights above the floor under the path), rooms and graph.
    seconds : float
    """

    map: object
    floor: float
    floors: NDArray[np.float64]
    rooms: object
    seconds: float


def slice_rooms(sweeps, trajectory: Trajectory, band: tuple[float, float], *, voxel: float = 0.1) -> SliceRooms:
    """The sweeps posed by ``trajectory`` (one pose a sweep, in order) through the 3D-only chain's stages, as
    ``hsmap map`` maps a 3D-only recording with ``--poses``: the voxel map carved along every ray
    (:func:`hsmap.pipeline.chain3d.carve_map`), the floor under each pose and the map levelled to it, the band
    ``band`` (metres above that floor) and its rooms (:func:`hsmap.pipeline.chain3d.levelled_bands`, the chain's
    defaults but ``grids.voxel`` and ``grids.slice``)."""
    from ..pipeline.chain3d import carve_map, levelled_bands, posed_sweep
    from ..pipeline.config import ChainConfig, GridsConfig
    from ..rooms.segmentation import segment_rooms
    from ..rooms.topology import room_graph
    from .real3d import BandRooms

    t0 = time.perf_counter()
    cfg = ChainConfig(grids=GridsConfig(voxel=float(voxel), slice=(float(band[0]), float(band[1]))))
    poses = pose_to_matrix(trajectory.as_6dof().poses)
    sweeps = list(sweeps)
    if len(sweeps) != len(poses):
        raise InputError(f"{len(sweeps)} sweeps but {len(poses)} poses: give one pose a sweep")
    posed = [posed_sweep(s, T, cfg.grids.voxel) for s, T in zip(sweeps, poses, strict=True)]
    m, positions = carve_map(posed, cfg.grids, source="the posed sweeps")
    bands = levelled_bands(m, positions, cfg)
    t = time.perf_counter()
    seg = segment_rooms(bands["slice_segmented"], config=cfg.segmentation)
    rooms = BandRooms(cfg.grids.slice, bands["slice"], bands["slice_segmented"], seg, room_graph(seg),
                      time.perf_counter() - t)
    floors = np.asarray(bands["floors"], dtype=float)
    return SliceRooms(m, float(np.median(floors)), floors, rooms, time.perf_counter() - t0)
