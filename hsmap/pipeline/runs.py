"""HS-SLAM runs computed once and read back afterwards (:func:`cached_slam`).

A run is a folder of :class:`hsmap.pipeline.cache.FolderCache`: the readable output of
:func:`hsmap.slam.write_slam_outputs` (``trajectory.tum``, ``map.ply``, ``metrics.json``, ``config.yaml``), keyed on
the dataset's identity (:func:`dataset_fingerprint`), the configuration, the seed, ``max_frames``, the initial pose
and the prior trajectory, and on the code.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .. import slam
from ..config import from_dict, to_dict
from ..datasets.frames import Dataset, Frame
from ..errors import DatasetError, HsmapError, InputError
from ..io import to_plain
from ..slam import SlamConfig
from ..trajectory import Trajectory, read_tum
from .cache import MARKER, FolderCache, description_digest, file_sha256, slug

__all__ = ["SlamRun", "cached_slam", "slam_key", "dataset_fingerprint"]

#: Reader attributes that change the frames a dataset serves (part of its fingerprint when present).
_READER_OPTIONS = ("scan_topic", "cloud_topic", "odom_topic", "order", "base_frame", "no_return",
                   "odom_tolerance", "sync_tolerance", "driver", "cloud_rate", "scan_rate")

#: Files of a SLAM run folder (besides the cache's own ``cache.json``).
_RUN_FILES = ("trajectory.tum", "map.ply", "config.yaml", "metrics.json")


# --- what identifies a dataset ---------------------------------------------------------------------------

def _path_digest(path: str | os.PathLike) -> str:
    """Digest of an input: a file's bytes; a simulated folder's cache key (the code, scenario, seed and frames
    that made it) and ``dataset.yaml`` (written last); any other folder's file names, sizes and times."""
    p = Path(path)
    if p.is_file():
        return file_sha256(p)
    if p.is_dir():
        if (p / "dataset.yaml").is_file():
            parts = [file_sha256(p / "dataset.yaml")]
            if (p / MARKER).is_file():
                parts.append(str(_read_marker_key(p)))
            return hashlib.sha256("\0".join(parts).encode()).hexdigest()
        h = hashlib.sha256()
        for f in sorted(q for q in p.rglob("*") if q.is_file()):
            st = f.stat()
            h.update(f"{f.relative_to(p)}:{st.st_size}:{st.st_mtime_ns}\n".encode())
        return h.hexdigest()
    raise DatasetError(f"{p}: no such file or folder")


def _read_marker_key(folder: Path) -> str | None:
    import json

    try:
        return json.loads((folder / MARKER).read_text(encoding="utf-8")).get("key")
    except (OSError, ValueError, AttributeError):
        return None


def _array_digest(a: Any) -> str | None:
    if a is None:
        return None
    arr = np.ascontiguousarray(np.asarray(a, dtype=np.float64))
    return hashlib.sha256(str(arr.shape).encode() + arr.tobytes()).hexdigest()


def _frames_digest(frames: Iterable[Frame]) -> str:
    h = hashlib.sha256()
    for f in frames:
        h.update(np.float64(f.stamp).tobytes())
        for a in (None if f.scan2d is None else f.scan2d.ranges, None if f.scan2d is None else f.scan2d.angles,
                  f.cloud3d, f.odometry, f.extrinsic2d, f.extrinsic3d):
            h.update((_array_digest(a) or "-").encode())
        if f.scan2d is not None and f.scan2d.times is not None:  # untimed scans keep their digests
            h.update(b"beam times" + _array_digest(f.scan2d.times).encode())
    return h.hexdigest()


def dataset_fingerprint(dataset: Dataset | str | os.PathLike, open_kwargs: Mapping[str, Any] | None = None) -> dict:
    """What identifies a dataset for the cache (a JSON-able dict).

    Parameters
    ----------
    dataset : Dataset or path
        A path is identified by its contents (a file's bytes; a simulated folder's cache key and
        ``dataset.yaml``) and ``open_kwargs`` (the options it will be opened with) without opening it. A
        :class:`~hsmap.datasets.frames.Dataset` object is identified by its type, the contents of its ``path``
        (or, for a dataset without a file, a digest of all its frames), its reader options, its extrinsics and a
        digest of its odometry, so that a dataset whose odometry was replaced
        (:func:`hsmap.datasets.rosbag.adopt_odometry`) or whose extrinsic was overridden gets its own key.
    open_kwargs : mapping, optional
        Keywords of :func:`hsmap.datasets.open.open_dataset` for a dataset given as a path.

    Returns
    -------
    dict
        ``content`` and ``odometry`` name the data; the other entries (kind, name, frames, options,
        extrinsics) name the question and make the cache slot.
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
        extra = [str(p) for p in getattr(dataset, "extra_paths", ()) or ()]  # e.g. a cloud folder's 2D scans
        if extra:
            parts = [fp["content"], *(f"{p}:{_path_digest(p)}" for p in extra)]
            fp["content"] = hashlib.sha256("\0".join(parts).encode()).hexdigest()
    else:
        fp["content"] = _frames_digest(dataset.frames())
    fp["options"] = {k: to_plain(getattr(dataset, k)) for k in _READER_OPTIONS if hasattr(dataset, k)}
    for k in ("extrinsic2d", "extrinsic3d"):
        if getattr(dataset, k, None) is not None:
            fp[k] = [float(v) for v in np.asarray(getattr(dataset, k), dtype=float).reshape(-1)]
    odo = getattr(dataset, "odometry", None)
    fp["odometry"] = None if odo is None else _array_digest(np.column_stack([odo.stamps, odo.poses]))
    return fp


# --- cached HS-SLAM runs ---------------------------------------------------------------------------------

@dataclass
class SlamRun:
    """A SLAM run as stored in its cache folder.

    Attributes
    ----------
    folder : Path
        ``trajectory.tum``, ``map.ply``, ``metrics.json``, ``config.yaml``, ``cache.json``.
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
    config: SlamConfig
    key: str = ""
    cached: bool = False
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
    return np.asarray(o3d.io.read_point_cloud(str(path)).points, dtype=float)


def _load_run(folder: Path) -> SlamRun:
    """Read a run folder; DatasetError when it is incomplete or inconsistent."""
    import json


    for name in _RUN_FILES:
        if not (folder / name).is_file():
            raise DatasetError(f"{folder}: incomplete SLAM run folder (no {name})")
    try:
        metrics = json.loads((folder / "metrics.json").read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{folder}: unreadable metrics.json ({exc})") from None
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
    return SlamRun(folder, traj, metrics, config)


def _slam_description(dataset, config: SlamConfig, seed: int, prior: Trajectory | None, max_frames: int | None,
                      initial_pose: ArrayLike | None, open_kwargs: Mapping[str, Any] | None) -> dict:

    return {
        "dataset": dataset_fingerprint(dataset, open_kwargs),
        "config": to_dict(config),
        "seed": int(seed),
        "max_frames": None if max_frames is None else int(max_frames),
        "initial_pose": None if initial_pose is None else [float(v) for v in np.asarray(initial_pose).reshape(-1)],
        "prior": None if prior is None else _array_digest(np.column_stack([prior.stamps, prior.poses])),
    }


def _slam_slot(desc: Mapping[str, Any]) -> str:
    """The run's folder name: the dataset's name, the dof and a digest of the question (everything but the
    data's contents and the prior's poses, which change with the code)."""
    question = {k: v for k, v in desc.items() if k != "prior"}
    question["prior"] = desc["prior"] is not None
    question["dataset"] = {k: v for k, v in desc["dataset"].items() if k not in ("content", "odometry")}
    name = str(desc["dataset"]["name"]).split(".")[0]
    return f"{slug(name)}-{desc['config']['dof']}dof-{description_digest(question)[:16]}"


def _compute_run(dataset, config: SlamConfig, seed: int, prior: Trajectory | None, max_frames: int | None,
                 initial_pose: ArrayLike | None, open_kwargs: Mapping[str, Any] | None, progress: bool | None):
    def compute(folder: Path) -> None:
        ds = dataset
        if not isinstance(ds, Dataset):
            from ..datasets.open import open_dataset

            ds = open_dataset(dataset, **dict(open_kwargs or {}))
        result = slam.run_slam(ds, config, rng=int(seed), prior=prior, max_frames=max_frames,
                               initial_pose=None if initial_pose is None else np.asarray(initial_pose, dtype=float),
                               progress=progress)
        slam.write_slam_outputs(result, folder)

    return compute


def slam_key(
    dataset: Dataset | str | os.PathLike,
    config: SlamConfig,
    seed: int,
    *,
    prior: Trajectory | None = None,
    max_frames: int | None = None,
    initial_pose: ArrayLike | None = None,
    open_kwargs: Mapping[str, Any] | None = None,
) -> tuple[str, dict]:
    """The cache key (hex SHA-256) of a SLAM run and the description it hashes beside the code digest."""
    desc = _slam_description(dataset, config, seed, prior, max_frames, initial_pose, open_kwargs)
    compute = _compute_run(dataset, config, seed, prior, max_frames, initial_pose, open_kwargs, False)
    return FolderCache(Path()).key(desc, compute), desc


def cached_slam(
    dataset: Dataset | str | os.PathLike,
    config: SlamConfig | None = None,
    seed: int = 0,
    *,
    prior: Trajectory | None = None,
    max_frames: int | None = None,
    initial_pose: ArrayLike | None = None,
    cache_dir: str | os.PathLike,
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
        The runs' folder (one subfolder per run).
    open_kwargs : mapping, optional
        Keywords of :func:`hsmap.datasets.open.open_dataset` for a dataset given as a path.
    lock_timeout : float or None
        Seconds to wait for another process computing the same run.
    progress : bool or None
        Progress bar of the run (None: on a terminal only).

    Returns
    -------
    SlamRun
        ``.cached`` says whether the folder existed before the call.
    """
    config = config if config is not None else SlamConfig()
    if not isinstance(config, SlamConfig):
        raise InputError(f"config must be a SlamConfig, got {type(config).__name__}")
    if max_frames is not None and int(max_frames) < 1:
        raise InputError(f"max_frames must be >= 1, got {max_frames}")
    desc = _slam_description(dataset, config, seed, prior, max_frames, initial_pose, open_kwargs)
    cache = FolderCache(cache_dir, lock_timeout=lock_timeout)
    got = cache.get(_slam_slot(desc), desc,
                    _compute_run(dataset, config, seed, prior, max_frames, initial_pose, open_kwargs, progress),
                    _load_run)
    return dataclasses.replace(got.value, key=got.key, cached=got.cached)
