"""Helpers for the study notebooks: cached HS-SLAM runs, simulated datasets shared between notebooks, and maps
built from a dataset and a trajectory (the HS-SLAM map, or the odometry-only map: scans placed at odometry
poses).

Several notebooks need the same SLAM run (notebooks 02 and 03 both use the 6-DOF run of ``slam-office``), and
``hsmap reproduce --jobs 2`` runs two of them at once. :func:`cached_slam` runs :func:`hsmap.slam.run_slam` once
per *key* and writes :func:`hsmap.slam.write_slam_outputs` into a folder named after the key; every later call
with the same key reads that folder instead of running again. The key is a SHA-256 of

- the dataset's identity (:func:`dataset_fingerprint`: the file contents of a bag or log, the ``dataset.yaml``
  of a simulated folder, the reader's options, the extrinsics and a digest of the odometry actually served),
- the effective :class:`~hsmap.slam.SlamConfig` (as a dict), the seed, ``max_frames``, ``initial_pose``,
- a digest of the prior trajectory (6-DOF runs seeded by 2D poses),
- the hsmap version and a digest of the source files that decide a SLAM result (:data:`SLAM_SOURCES`), so that
  a change to the SLAM code never reuses a stale result.

A run is published atomically: written into a temporary folder beside the cache folder, then renamed to its
final name; ``metrics.json`` (written last by ``write_slam_outputs``) and ``key.json`` mark a complete folder.
A folder that is incomplete or damaged (unreadable metrics, a trajectory whose length or stamps disagree with
the metrics) is removed and computed again. Two processes asking for the same key at once serialise on an
exclusive ``fcntl`` lock on ``cache_dir/.locks/KEY.lock``: the second waits and then reuses the first's result.

Everything here calls the package; no algorithm lives in the notebooks.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
import time
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import __version__
from .config import from_dict, to_dict
from .datasets.frames import Dataset, Frame
from .errors import DatasetError, HsmapError, InputError
from .geometry import compose, pose_to_matrix, transform_points
from .io import file_lock, to_plain, write_json
from .trajectory import Trajectory, read_tum
from .mapping import VoxelMap

__all__ = [
    "SLAM_SOURCES",
    "SlamRun",
    "cached_slam",
    "slam_key",
    "dataset_fingerprint",
    "default_cache_dir",
    "file_lock",
    "simulated_dataset",
    "SimulatedRuns",
    "simulated_slam_runs",
    "poses_at",
    "point_map",
    "point_maps",
    "scan_grid",
    "map_distances",
    "record_slam_run",
    "datasets_dir",
    "open_freiburg",
    "BORMANN_BUILDINGS",
    "room_segmentation_benchmark",
    "summarise_segmentation",
]

#: Package files (relative to ``hsmap/``) whose contents decide a SLAM result; their digest is part of the key.
SLAM_SOURCES = (
    "slam.py", "registration.py", "harmony.py", "fitness.py", "mapping.py", "_kernels.py", "geometry.py",
    "config.py", "io.py", "datasets/frames.py", "datasets/simulated.py", "datasets/rosbag.py",
    "datasets/carmen.py", "datasets/open.py",
)

#: Files of a cache folder; ``metrics.json`` is written last.
_FILES = ("key.json", "trajectory.tum", "map.ply", "config.yaml", "metrics.json")

_digest_memo: dict[tuple[str, int, int], str] = {}


def default_cache_dir() -> Path:
    """``data/generated/slam`` of the repository (``$HSMAP_GENERATED/slam`` when that is set)."""
    from .sim.catalog import generated_dir

    return generated_dir() / "slam"


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _file_digest(path: Path) -> str:
    st = path.stat()
    memo = (str(path.resolve()), st.st_size, st.st_mtime_ns)
    if memo not in _digest_memo:
        h = hashlib.sha256()
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
        _digest_memo[memo] = h.hexdigest()
    return _digest_memo[memo]


def _path_digest(path: str | os.PathLike) -> str:
    """Digest of an input: a file's bytes; a simulated folder's ``dataset.yaml`` (which names the scenario
    file's hash, the seed and the frame count, and is written last); any other folder's file names, sizes
    and the bytes of its small description files."""
    p = Path(path)
    if p.is_file():
        return _file_digest(p)
    if p.is_dir():
        if (p / "dataset.yaml").is_file():
            return _file_digest(p / "dataset.yaml")
        h = hashlib.sha256()
        for f in sorted(q for q in p.rglob("*") if q.is_file()):
            st = f.stat()
            h.update(f"{f.relative_to(p)}:{st.st_size}:{st.st_mtime_ns}\n".encode())
        return h.hexdigest()
    raise DatasetError(f"{p}: no such file or folder")


def _array_digest(a: Any) -> str | None:
    if a is None:
        return None
    arr = np.ascontiguousarray(np.asarray(a, dtype=np.float64))
    return _sha(str(arr.shape).encode() + arr.tobytes())


def _source_digest(sources: Iterable[str] = SLAM_SOURCES) -> str:
    """SHA-256 of the named package files (paths relative to ``hsmap/``), each with its name."""
    root = Path(__file__).resolve().parent
    h = hashlib.sha256()
    for rel in sources:
        f = root / rel
        if f.is_file():
            h.update(rel.encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()


#: Reader attributes that change the frames a dataset serves (part of its fingerprint when present).
_READER_OPTIONS = ("scan_topic", "cloud_topic", "odom_topic", "order", "base_frame", "no_return",
                   "odom_tolerance", "sync_tolerance")


def _frames_digest(frames: Iterable[Frame]) -> str:
    h = hashlib.sha256()
    for f in frames:
        h.update(np.float64(f.stamp).tobytes())
        for a in (None if f.scan2d is None else f.scan2d.ranges, None if f.scan2d is None else f.scan2d.angles,
                  f.cloud3d, f.odometry, f.extrinsic2d, f.extrinsic3d):
            h.update((_array_digest(a) or "-").encode())
    return h.hexdigest()


def dataset_fingerprint(dataset: Dataset | str | os.PathLike, open_kwargs: Mapping[str, Any] | None = None) -> dict:
    """What identifies a dataset for the cache (a JSON-able dict).

    Parameters
    ----------
    dataset : Dataset or path
        A path is identified by its contents (:func:`_path_digest`) and ``open_kwargs`` (the options it will
        be opened with) without opening it. A :class:`~hsmap.datasets.frames.Dataset` object is identified by
        its type, the contents of its ``path`` (or, for a dataset without a file, a digest of all its frames),
        its reader options, its extrinsics and a digest of its odometry, so that a dataset whose odometry was
        replaced (:func:`hsmap.datasets.rosbag.adopt_odometry`) or whose extrinsic was overridden gets its
        own key.
    """
    if isinstance(dataset, (str, os.PathLike)):
        p = Path(dataset)
        return {"kind": "path", "name": p.name, "content": _path_digest(p),
                "open_kwargs": to_plain(dict(open_kwargs or {}))}
    if not isinstance(dataset, Dataset):
        raise InputError(f"dataset must be a path or an hsmap Dataset, got {type(dataset).__name__}")
    if open_kwargs:
        raise InputError("open_kwargs apply to a dataset given as a path; this one is already open")
    path = getattr(dataset, "path", "") or ""
    fp: dict[str, Any] = {"kind": type(dataset).__name__, "name": str(getattr(dataset, "name", "")),
                          "frames": len(dataset)}
    if path and Path(path).exists():
        fp["content"] = _path_digest(path)
    else:
        fp["content"] = _frames_digest(dataset.frames())
    fp["options"] = {k: to_plain(getattr(dataset, k)) for k in _READER_OPTIONS if hasattr(dataset, k)}
    for k in ("extrinsic2d", "extrinsic3d"):
        if getattr(dataset, k, None) is not None:
            fp[k] = [float(v) for v in np.asarray(getattr(dataset, k), dtype=float).reshape(-1)]
    odo = getattr(dataset, "odometry", None)
    fp["odometry"] = None if odo is None else _array_digest(np.column_stack([odo.stamps, odo.poses]))
    return fp


def slam_key(
    dataset: Dataset | str | os.PathLike,
    config: Any,
    seed: int,
    *,
    prior: Trajectory | None = None,
    max_frames: int | None = None,
    initial_pose: ArrayLike | None = None,
    open_kwargs: Mapping[str, Any] | None = None,
) -> tuple[str, dict]:
    """The cache key (hex SHA-256) of a SLAM run and the description it hashes (see the module docstring)."""
    desc = {
        "dataset": dataset_fingerprint(dataset, open_kwargs),
        "config": to_dict(config),
        "seed": int(seed),
        "max_frames": None if max_frames is None else int(max_frames),
        "initial_pose": None if initial_pose is None else [float(v) for v in np.asarray(initial_pose).reshape(-1)],
        "prior": None if prior is None else _array_digest(np.column_stack([prior.stamps, prior.poses])),
        "hsmap_version": __version__,
        "slam_sources": _source_digest(),
    }
    return _sha(json.dumps(desc, sort_keys=True).encode()), desc


@dataclass
class SlamRun:
    """A SLAM run as stored in its cache folder.

    Attributes
    ----------
    folder : Path
        ``trajectory.tum``, ``map.ply``, ``metrics.json``, ``config.yaml``, ``key.json``.
    trajectory : Trajectory
        (N, 3) poses for a 3-DOF run, (N, 6) for a 6-DOF run, stamps = the input's scan stamps.
    metrics : dict
        ``metrics.json`` (totals, per-frame values, the effective configuration).
    config : SlamConfig
    key : str
    cached : bool
        True when the folder existed (this call ran nothing).
    """

    folder: Path
    trajectory: Trajectory
    metrics: dict
    config: Any
    key: str
    cached: bool
    _map: NDArray[np.float64] | None = field(default=None, repr=False)

    @property
    def dof(self) -> int:
        return int(self.config.dof)

    @property
    def map_points(self) -> NDArray[np.float64]:
        """The SLAM map, (M, 2) for 3-DOF runs, (M, 3) for 6-DOF runs (read from ``map.ply`` once)."""
        if self._map is None:
            self._map = _read_ply_points(self.folder / "map.ply")
            if self.dof == 3:
                self._map = self._map[:, :2]
        return self._map

    @property
    def seconds(self) -> float:
        """Wall time of the SLAM run itself (when it was computed, not when it was read)."""
        return float(self.metrics["seconds_total"])

    @property
    def real_time_factor(self) -> float | None:
        return self.metrics.get("real_time_factor")

    @property
    def keyframes(self) -> NDArray[np.bool_]:
        """(N,) whether each frame was added to the map."""
        return np.asarray(self.metrics["per_frame"]["keyframe"], dtype=bool)

    @property
    def frame_indices(self) -> NDArray[np.int64]:
        """(N,) the input frame index of each pose."""
        return np.asarray(self.metrics["per_frame"]["index"], dtype=np.int64)


def _read_ply_points(path: Path) -> NDArray[np.float64]:
    import open3d as o3d

    if not path.is_file():
        raise DatasetError(f"{path}: missing")
    pts = np.asarray(o3d.io.read_point_cloud(str(path)).points, dtype=float)
    return pts


def _load_run(folder: Path, key: str, cached: bool) -> SlamRun:
    """Read a cache folder; DatasetError (or DataFormatError) when it is incomplete or inconsistent."""
    from .slam import SlamConfig

    for name in _FILES:
        if not (folder / name).is_file():
            raise DatasetError(f"{folder}: incomplete SLAM cache folder (no {name})")
    try:
        metrics = json.loads((folder / "metrics.json").read_text(encoding="utf-8"))
        stored = json.loads((folder / "key.json").read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{folder}: unreadable metrics.json or key.json ({exc})") from None
    if not isinstance(metrics, dict) or not isinstance(stored, dict) or stored.get("key") != key:
        raise DatasetError(f"{folder}: key.json does not name key {key[:16]}")
    try:
        config = from_dict(SlamConfig, metrics["config"], where=f"{folder}/metrics.json config")
        n = int(metrics["frames"])
        stamps = np.asarray(metrics["per_frame"]["stamp"], dtype=float)
    except (KeyError, TypeError, ValueError, HsmapError) as exc:
        raise DatasetError(f"{folder}: metrics.json lacks the run's config or per-frame values ({exc})") from None
    traj = read_tum(folder / "trajectory.tum", dof=6)
    if config.dof == 3:
        traj = traj.as_3dof()
    if len(traj) != n or len(stamps) != n or not np.allclose(traj.stamps, stamps, atol=1e-6, rtol=0):
        raise DatasetError(f"{folder}: trajectory.tum has {len(traj)} poses, metrics.json says {n} frames")
    return SlamRun(folder, traj, metrics, config, key, cached)


def _slug(text: str) -> str:
    s = "".join(c if c.isalnum() or c in "-_" else "-" for c in text).strip("-")
    return s[:40] or "dataset"


def cached_slam(
    dataset: Dataset | str | os.PathLike,
    config: Any = None,
    seed: int = 0,
    *,
    prior: Trajectory | None = None,
    max_frames: int | None = None,
    initial_pose: ArrayLike | None = None,
    cache_dir: str | os.PathLike | None = None,
    open_kwargs: Mapping[str, Any] | None = None,
    lock_timeout: float | None = 3600.0,
    progress: bool | None = False,
) -> SlamRun:
    """HS-SLAM on ``dataset``, computed once per key and read back from the cache afterwards.

    Parameters
    ----------
    dataset : Dataset or path
        A path (simulated folder, bag, CARMEN log) is opened with ``open_dataset(path, **open_kwargs)`` only
        when the run has to be computed. Pass an open :class:`~hsmap.datasets.frames.Dataset` when it was
        modified after opening (adopted odometry, an overridden extrinsic): its fingerprint covers that.
    config : SlamConfig, optional
    seed : int
        The run's ``rng``.
    prior, max_frames, initial_pose :
        As :func:`hsmap.slam.run_slam`.
    cache_dir : path, optional
        Default :func:`default_cache_dir` (``data/generated/slam`` of the repository).
    open_kwargs : mapping, optional
        Keywords of :func:`hsmap.datasets.open.open_dataset` for a dataset given as a path.
    lock_timeout : float or None
        Seconds to wait for another process computing the same key.
    progress : bool or None
        Progress bar of the run (None: on a terminal only).

    Returns
    -------
    SlamRun
        ``.cached`` says whether the folder existed before the call.
    """
    from .slam import SlamConfig, run_slam, write_slam_outputs

    config = config if config is not None else SlamConfig()
    if not isinstance(config, SlamConfig):
        raise InputError(f"config must be a SlamConfig, got {type(config).__name__}")
    if max_frames is not None and int(max_frames) < 1:
        raise InputError(f"max_frames must be >= 1, got {max_frames}")
    key, desc = slam_key(dataset, config, seed, prior=prior, max_frames=max_frames, initial_pose=initial_pose,
                         open_kwargs=open_kwargs)
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    name = desc["dataset"]["name"].split(".")[0]
    folder = cache / f"{_slug(name)}-{config.dof}dof-{key[:16]}"
    with file_lock(cache / ".locks" / f"{key[:32]}.lock", timeout=lock_timeout):
        if folder.exists():
            try:
                return _load_run(folder, key, cached=True)
            except HsmapError:
                shutil.rmtree(folder)  # incomplete or damaged: computed again below
        for stale in cache.glob(f".{folder.name}.tmp-*"):  # left by a killed run (we hold the lock)
            shutil.rmtree(stale, ignore_errors=True)
        ds = dataset
        if not isinstance(ds, Dataset):
            from .datasets.open import open_dataset

            ds = open_dataset(dataset, **dict(open_kwargs or {}))
        result = run_slam(ds, config, rng=int(seed), prior=prior, max_frames=max_frames,
                          initial_pose=None if initial_pose is None else np.asarray(initial_pose, dtype=float),
                          progress=progress)
        tmp = cache / f".{folder.name}.tmp-{os.getpid()}"
        try:
            tmp.mkdir(parents=True)
            write_json(tmp / "key.json", {"key": key, "description": desc})
            write_slam_outputs(result, tmp)  # metrics.json last
            os.rename(tmp, folder)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        return _load_run(folder, key, cached=False)


# --- simulated datasets shared by notebooks ---------------------------------------------------------------

def simulated_dataset(scenario: str | os.PathLike = "slam-office", seed: int = 1, *,
                      max_frames: int | None = None):
    """The simulated dataset of ``scenario`` with ``seed``, generated once and then reused.

    The folder is ``data/generated/<scenario>-seed<seed>``: one folder per seed, so notebooks using different
    seeds never regenerate each other's data. With ``max_frames`` (quick runs) only the first frames are
    needed: the full folder is used when it is already complete, else a prefix folder
    ``<scenario>-seed<seed>-first<N>`` is simulated (the simulator's frames do not depend on how many follow,
    so a prefix holds the same first frames as the full route). Callers still cut their runs at ``max_frames``.
    Generation goes through :func:`hsmap.sim.writer.ensure_dataset`, under the folder's lock, so parallel
    notebooks (and benchmarks) never write one folder twice.

    Returns
    -------
    SimulatedDataset
    """
    from .datasets.simulated import SimulatedDataset
    from .sim.catalog import generated_dir, resolve_scenario
    from .sim.scenario import load_scenario
    from .sim.writer import _is_current, ensure_dataset, folder_lock

    scn = load_scenario(resolve_scenario(scenario))
    seed = int(seed)
    if max_frames is not None and int(max_frames) < 1:
        raise InputError(f"max_frames must be >= 1, got {max_frames}")
    full = generated_dir() / f"{scn.name}-seed{seed}"
    if max_frames is not None:
        with folder_lock(full):
            complete = _is_current(full, scn, seed, None)
        if not complete:
            n = int(max_frames)
            prefix = generated_dir() / f"{scn.name}-seed{seed}-first{n}"
            return SimulatedDataset(ensure_dataset(scn, seed, prefix, max_frames=n))
    return SimulatedDataset(ensure_dataset(scn, seed, full))


@dataclass
class SimulatedRuns:
    """The study's standard HS-SLAM runs of one simulated dataset (see :func:`simulated_slam_runs`).

    Attributes
    ----------
    dataset : SimulatedDataset
    truth, odometry : Trajectory
        (x, y, yaw) ground truth and wheel odometry of the frames used (the first ``frames``).
    run3 : SlamRun
        3-DOF HS-SLAM on the 2D scans.
    run6 : SlamRun or None
        6-DOF HS-SLAM on the 3D clouds, seeded by ``run3``'s poses (``prior=``), as the paper does.
    frames : int
    """

    dataset: Any
    truth: Trajectory
    odometry: Trajectory
    run3: SlamRun
    run6: SlamRun | None
    frames: int


def simulated_slam_runs(scenario: str = "slam-office", seed: int = 1, *, max_frames: int | None = None,
                        dof6: bool = True, use_odometry: bool = False,
                        cache_dir: str | os.PathLike | None = None) -> SimulatedRuns:
    """The simulated dataset and its cached HS-SLAM runs, the same for every notebook that asks.

    3-DOF HS-SLAM on the 2D scans and (``dof6``) 6-DOF HS-SLAM on the 3D clouds seeded by the 3-DOF poses, both
    with ``seed`` as their rng, both starting at the first ground-truth pose (so that maps and paths share the
    world frame of the ground truth and the odometry), without odometry unless ``use_odometry``. Notebooks that
    call this with the same arguments share one computation (:func:`cached_slam`).
    """
    from .slam import SlamConfig

    ds = simulated_dataset(scenario, seed, max_frames=max_frames)
    n = len(ds) if max_frames is None else min(int(max_frames), len(ds))
    truth = Trajectory(ds.groundtruth.stamps[:n], ds.groundtruth.poses[:n])
    odometry = Trajectory(ds.odometry.stamps[:n], ds.odometry.poses[:n])
    run3 = cached_slam(ds, SlamConfig(dof=3, use_odometry=use_odometry), seed, max_frames=max_frames,
                       initial_pose=truth.poses[0], cache_dir=cache_dir)
    run6 = None
    if dof6:
        run6 = cached_slam(ds, SlamConfig(dof=6, use_odometry=use_odometry), seed, max_frames=max_frames,
                           initial_pose=truth.as_6dof().poses[0], prior=run3.trajectory, cache_dir=cache_dir)
    return SimulatedRuns(ds, truth, odometry, run3, run6, n)


# --- maps from a dataset and a trajectory ----------------------------------------------------------------

def poses_at(trajectory: Trajectory, stamps: ArrayLike, *, max_dt: float = 1e-3) -> tuple[NDArray, NDArray]:
    """The trajectory's poses at ``stamps`` (the pose with the nearest stamp within ``max_dt``).

    Returns
    -------
    poses : ndarray of shape (K, dof)
        Poses of the stamps that have one.
    found : ndarray of shape (M,) of bool
        Which of the M stamps have a pose.
    """
    s = np.asarray(stamps, dtype=float).reshape(-1)
    order = np.argsort(trajectory.stamps, kind="stable")
    ts = trajectory.stamps[order]
    if len(ts) == 0:
        raise InputError("the trajectory is empty")
    k = np.clip(np.searchsorted(ts, s), 1, max(len(ts) - 1, 1)) if len(ts) > 1 else np.zeros(len(s), int)
    if len(ts) > 1:
        k = np.where(np.abs(ts[k - 1] - s) <= np.abs(ts[k] - s), k - 1, k)
    found = np.abs(ts[k] - s) <= max_dt
    return trajectory.poses[order[k[found]]], found


def _frames(dataset: Dataset | Iterable[Frame], clouds: bool, every: int, max_frames: int | None) -> Iterator[Frame]:
    it = dataset.frames(clouds=clouds) if isinstance(dataset, Dataset) else iter(dataset)
    for k, f in enumerate(it):
        if max_frames is not None and k >= max_frames:
            return
        if k % every == 0:
            yield f


def point_maps(
    dataset: Dataset | Iterable[Frame],
    trajectories: Mapping[str, Trajectory],
    *,
    dof: int | None = None,
    voxel: float | None = None,
    every: int = 1,
    max_frames: int | None = None,
    min_range: float = 0.1,
    max_range: float = 30.0,
    max_dt: float = 1e-3,
    block: int = 20,
) -> dict[str, NDArray[np.float64]]:
    """Point maps of ``dataset``'s scans (dof 3) or clouds (dof 6) placed at the poses of each trajectory.

    One pass over the data serves every trajectory (3D clouds are read once). With the SLAM trajectory this is
    the SLAM map; with the odometry (``dataset.odometry``) it is the map the odometry alone would make; with the
    ground truth, the reference map. Frames are matched to poses by stamp; frames without a pose in a trajectory
    are left out of that trajectory's map.

    Parameters
    ----------
    trajectories : mapping of name to Trajectory
        3-DOF trajectories place 3D clouds at z = roll = pitch = 0.
    dof : int, optional
        3 (2D scans) or 6 (3D clouds); default 6 when any trajectory is 6-DOF, else 3.
    voxel : float, optional
        One point per voxel of this size (default 0.05 m in 2D, 0.1 m in 3D, like the SLAM maps).
    every : int
        Use every n-th frame.
    block : int
        Frames whose (per-frame thinned) points are merged into the maps at once.

    Returns
    -------
    dict of name to ndarray of shape (M, 2) or (M, 3)
        World points of each map.
    """
    from .mapping import first_per_voxel
    from .slam import frame_points

    if not trajectories:
        raise InputError("point_maps needs at least one trajectory")
    if dof is None:
        dof = 6 if any(t.dof == 6 for t in trajectories.values()) else 3
    dof = int(dof)
    if dof not in (3, 6):
        raise InputError(f"dof must be 3 (2D scans) or 6 (3D clouds), got {dof}")
    if int(every) < 1 or int(block) < 1:
        raise InputError(f"every and block must be >= 1, got {every} and {block}")
    vox = voxel or (0.05 if dof == 3 else 0.1)
    trajs = {k: (t.as_6dof() if dof == 6 else t.as_3dof()) for k, t in trajectories.items()}
    maps = {k: VoxelMap(2 if dof == 3 else 3, vox) for k in trajs}
    pending: dict[str, list[NDArray[np.float64]]] = {k: [] for k in trajs}
    used = dict.fromkeys(trajs, 0)

    def flush() -> None:
        for k, parts in pending.items():
            if parts:
                maps[k].add(np.concatenate(parts))
                parts.clear()

    for n, f in enumerate(_frames(dataset, clouds=dof == 6, every=int(every), max_frames=max_frames)):
        if dof == 6 and f.cloud3d is not None and len(f.cloud3d) > 20000:
            # dense 3D clouds: thin in the sensor frame first (one point per half map voxel), then place
            f = dataclasses.replace(f, cloud3d=first_per_voxel(f.cloud3d, vox / 2))
        pts = frame_points(f, dof, min_range, max_range)
        for k, traj in trajs.items():
            pose, ok = poses_at(traj, [f.stamp], max_dt=max_dt)
            if not ok[0]:
                continue
            w = transform_points(pose_to_matrix(pose[0]), pts)
            pending[k].append(first_per_voxel(w, vox))  # thin per frame, same voxels as the map
            used[k] += 1
        if (n + 1) % int(block) == 0:
            flush()
    flush()
    empty = [k for k, c in used.items() if c == 0]
    if empty:
        raise InputError(f"no frame of the dataset has a pose in trajectory {empty[0]!r} (stamps differ?)")
    return {k: m.points for k, m in maps.items()}


def point_map(
    dataset: Dataset | Iterable[Frame],
    trajectory: Trajectory,
    **kwargs: Any,
) -> NDArray[np.float64]:
    """The point map of ``dataset``'s scans or clouds placed at ``trajectory``'s poses (see :func:`point_maps`).

    Returns
    -------
    ndarray of shape (M, 2) or (M, 3)
    """
    return point_maps(dataset, {"map": trajectory}, **kwargs)["map"]


def scan_grid(
    dataset: Dataset | Iterable[Frame],
    trajectory: Trajectory,
    resolution: float = 0.05,
    *,
    every: int = 1,
    max_frames: int | None = None,
    geometry: Any = None,
    config: Any = None,
    max_dt: float = 1e-3,
):
    """Occupancy grid of ``dataset``'s 2D scans placed at ``trajectory``'s poses (:func:`hsmap.grid.grid_from_scans`).

    Each scan is placed at its robot pose composed with its own 2D extrinsic. With the odometry this is the
    odometry-only map of the paper's Figures 2 and 8 (walls smeared thick by the drift).

    Returns
    -------
    hsmap.grid.OccupancyGrid
    """
    from .grid import grid_from_scans

    if int(every) < 1:
        raise InputError(f"every must be >= 1, got {every}")
    traj = trajectory.as_3dof()
    scans, poses, extrinsics = [], [], []
    for f in _frames(dataset, clouds=False, every=int(every), max_frames=max_frames):
        if f.scan2d is None:
            raise InputError(f"frame {f.index} has no 2D scan")
        pose, ok = traj.at([f.stamp], max_dt=max_dt)
        if ok[0]:
            scans.append(f.scan2d)
            poses.append(pose[0])
            extrinsics.append(f.extrinsic2d)
    if not scans:
        raise InputError("no frame of the dataset has a pose in the trajectory (stamps differ?)")
    return grid_from_scans(scans, np.asarray(poses), resolution, extrinsic=np.asarray(extrinsics, dtype=float),
                           geometry=geometry, config=config)


def map_distances(points: ArrayLike, reference: ArrayLike) -> NDArray[np.float64]:
    """Distance (m) from each point of a map to the nearest point of a reference map (same dimension).

    With the reference built from the ground-truth poses this measures how far a map's walls lie from where
    they are: centimetres for a good SLAM map, metres for an odometry-only map with thick, doubled walls.

    Parameters
    ----------
    points : ndarray of shape (N, 2) or (N, 3)
    reference : ndarray of shape (M, 2) or (M, 3)

    Returns
    -------
    ndarray of shape (N,)
    """
    from scipy.spatial import cKDTree

    p = np.asarray(points, dtype=float)
    r = np.asarray(reference, dtype=float)
    if p.ndim != 2 or r.ndim != 2 or p.shape[1] != r.shape[1] or p.shape[1] not in (2, 3):
        raise InputError(f"points and reference must be (N, 2) or (N, 3) alike, got {p.shape} and {r.shape}")
    if len(r) == 0 or len(p) == 0:
        raise InputError("points and reference must not be empty")
    return cKDTree(r).query(p, k=1)[0]


# --- rerun ---------------------------------------------------------------------------------------------------

def record_slam_run(
    rec: Any,
    dataset: Dataset | Iterable[Frame],
    run: SlamRun,
    *,
    every: int = 1,
    map_block: int = 10,
    map_voxel: float | None = None,
    cloud_voxel: float = 0.25,
    groundtruth: Trajectory | None = None,
    odometry: Trajectory | None = None,
) -> dict:
    """Log a (cached) SLAM run to a rerun recording, frame by frame on the ``scan`` timeline.

    Replays the run from its stored poses, as ``hsmap slam`` logs it live: the robot pose (``world/robot``),
    the current 2D scan and 3D cloud under their sensors, the growing map (the keyframes' points, in blocks of
    ``map_block`` keyframes under ``world/map/points``) and, as static lines, the estimated path and the
    optional ground truth and odometry.

    Parameters
    ----------
    every : int
        Log every n-th frame's pose and scan (the map still gets every keyframe).

    Returns
    -------
    dict
        ``frames`` logged, ``map_blocks``, ``map_points`` logged.
    """
    from .mapping import first_per_voxel
    from .slam import frame_points
    from .viz import rerun as hv

    if int(every) < 1:
        raise InputError(f"every must be >= 1, got {every}")
    dof = run.dof
    cfg = run.config
    index_of = {int(i): k for k, i in enumerate(run.frame_indices)}
    key = run.keyframes
    poses = run.trajectory.poses
    logger = hv.PointMapLogger(rec, block=int(map_block),
                               voxel=map_voxel or (0.05 if dof == 3 else 0.15),
                               z_range=(-0.2, 3.0) if dof == 6 else None)
    logged = 0
    n_frames = len(run.trajectory)
    map_vox = map_voxel or (0.05 if dof == 3 else 0.15)

    thin = first_per_voxel  # one point per voxel; the viewer-side thinning then has little left to do

    for f in (dataset.frames(clouds=dof == 6) if isinstance(dataset, Dataset) else iter(dataset)):
        k = index_of.get(int(f.index))
        if k is None:
            if f.index > run.frame_indices.max():
                break
            continue
        show = k % int(every) == 0 or k == n_frames - 1
        if not (show or key[k]):
            continue
        if dof == 6 and f.cloud3d is not None:
            f = dataclasses.replace(f, cloud3d=thin(np.asarray(f.cloud3d, dtype=float), min(cloud_voxel, map_vox)))
        if show:
            shown = f if dof == 6 else dataclasses.replace(f, cloud3d=None)
            hv.log_frame(rec, shown, poses[k], index=k, cloud_voxel=cloud_voxel)
            logged += 1
        if key[k]:
            if not show:
                hv.set_frame_time(rec, k, f.stamp)
            pts = frame_points(f, dof, cfg.min_range, cfg.max_range)
            logger.add(thin(transform_points(pose_to_matrix(poses[k]), pts), map_vox))
    logger.flush()
    hv.log_path(rec, "estimate", run.trajectory.poses)
    if groundtruth is not None:
        hv.log_path(rec, "groundtruth", groundtruth.poses)
    if odometry is not None:
        hv.log_path(rec, "odometry", odometry.poses)
    return {"frames": logged, "map_blocks": logger.blocks, "map_points": logger.points_logged}


# --- third-party benchmarks ------------------------------------------------------------------------------------

def datasets_dir() -> Path:
    """The third-party datasets folder: ``$HSMAP_DATASETS``, else ``../shared/datasets`` beside the repository."""
    from .sim.catalog import repository_root

    env = os.environ.get("HSMAP_DATASETS")
    return Path(env) if env else (repository_root().parent / "shared" / "datasets").resolve()


def open_freiburg(folder: str | os.PathLike, name: str, *, scan_odometry: bool = True,
                  laser_x: float | None = None):
    """A Freiburg benchmark log (``slam2d/NAME/NAME.orig.bag``) with the odometry CARMEN stored with each scan.

    The ``.orig.bag`` has the true (IPC) scan stamps, which the ``.relations`` use; with ``scan_odometry`` its
    frames get, by :func:`hsmap.datasets.rosbag.adopt_odometry`, the per-scan odometry of ``NAME.clf2bag.bag``
    (the bag's own /odom runs at its own rate). ``laser_x`` overrides the laser's forward offset in the robot
    frame (fr079: the bag's TF says +0.04 m, the CARMEN PARAM -0.04 m, and the relations agree with -0.04).

    Returns
    -------
    RosbagDataset
    """
    from .datasets.open import open_dataset
    from .datasets.rosbag import adopt_odometry

    root = Path(folder) / name
    ds = open_dataset(root / f"{name}.orig.bag")
    if scan_odometry:
        adopt_odometry(ds, open_dataset(root / f"{name}.clf2bag.bag"))
    if laser_x is not None:
        ext = np.asarray(ds.extrinsic2d, dtype=float).copy()
        ext[0] = float(laser_x)
        if hasattr(ds, "override_extrinsics"):  # hsmap's own override (open_dataset(extrinsic2d=) uses it)
            ds.override_extrinsics(extrinsic2d=ext)
        else:  # the same effect on readers without it: frames() hands each frame a copy of this
            ds.extrinsic2d = ext
    return ds


#: The 15 buildings of the ipa_room_segmentation maps in ``$HSMAP_DATASETS`` (Bormann et al. 2016).
BORMANN_BUILDINGS = ("lab_ipa", "lab_c_scan", "Freiburg52_scan", "Freiburg79_scan", "lab_b_scan", "lab_f_scan",
                     "lab_a_scan", "NLB", "office_a", "office_b", "office_d", "office_e", "office_f", "office_h",
                     "office_i")


def room_segmentation_benchmark(folder: str | os.PathLike, buildings=BORMANN_BUILDINGS, *, config: Any = None,
                                resolution: float = 0.05, furnished: bool = True) -> list[dict]:
    """Segment each building's plain (and furnished) map and score it against its ground truth.

    The benchmark's rules (Bormann et al. 2016): pixels >= 250 are free, 0.05 m per pixel, ground-truth rooms are
    the 8-connected regions of the ground-truth image above 250 larger than 100 px; scores from
    :func:`hsmap.evaluation.segmentation_scores` (per-room mean precision and recall, area-weighted beside).

    Returns
    -------
    list of dict
        One row per map: building, kind (plain/furnished), precision, recall, precision_area, recall_area,
        rooms, segments, doors, seconds (wall time of ``segment_rooms``), pixels.
    """
    from .evaluation import segmentation_scores
    from .grid import read_image_gray
    from .segmentation import segment_rooms

    folder = Path(folder)
    rows = []
    for b in buildings:
        gt = read_image_gray(folder / f"{b}_gt_segmentation.png")
        for kind, suffix in (("plain", ""), ("furnished", "_furnitures"))[: 2 if furnished else 1]:
            free = read_image_gray(folder / f"{b}{suffix}.png") >= 250
            t0 = time.perf_counter()
            seg = segment_rooms(free, resolution, config=config)
            dt = time.perf_counter() - t0
            sc = segmentation_scores(seg.labels, gt)
            rows.append({"building": b, "kind": kind, "map": b + suffix, "precision": sc.precision,
                         "recall": sc.recall, "precision_area": sc.precision_area, "recall_area": sc.recall_area,
                         "rooms": sc.n_rooms, "segments": sc.n_segments, "doors": len(seg.doors),
                         "seconds": dt, "pixels": int(free.size)})
    return rows


def summarise_segmentation(rows: list[dict]) -> dict:
    """Means over the maps of each kind (precision, recall, area-weighted both) and the time per map."""
    out = {}
    for kind in ("plain", "furnished"):
        r = [x for x in rows if x["kind"] == kind]
        if r:
            out[kind] = {"maps": len(r), **{k: float(np.mean([x[k] for x in r])) for k in
                                            ("precision", "recall", "precision_area", "recall_area", "seconds")},
                         "seconds_max": float(np.max([x["seconds"] for x in r]))}
    return out
