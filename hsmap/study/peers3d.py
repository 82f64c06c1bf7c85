"""Other LiDAR odometries on the same 3D sweeps as HS-SLAM, each with its defaults and with the settings its makers
document for a 64-beam sensor (the 3D peers benchmark, ``benchmarks/peers3d.py``, and notebook 11).

Each peer takes the sweeps one by one (points in the sensor frame, float64) and gives the sensor's 4x4 pose in the
first sweep's frame. The sweeps have no per-point time, so every deskewing is off. The settings (:data:`SETTINGS`):

- ``kiss_icp`` (KISS-ICP 1.3, PyPI ``kiss-icp``):
  ``defaults``: its ``KISSConfig()`` as ``load_config(None)`` completes it (max_range 100 m, min_range 0, voxel
  max_range / 100 = 1 m, 20 points a voxel, adaptive threshold), deskew off;
  ``ouster``: Ouster's own KISS-ICP integration for its sensors (ouster-sdk, ``ouster.sdk.mapping.slam.KissBackend``:
  max_range 150 m, min_range 1 m, the voxel sized from the first sweep: the mean of its ranges between the 92nd
  and 96th percentiles over 46, times (pixels a sweep / (1024 x 128)) ** 0.25, with the sweep's pixels at least
  2048 x 64 since a sweep holds more points than 1024 x 64 (the factor then is 1)), deskew off.
- ``genz_icp`` (GenZ-ICP 0.3.2, PyPI ``genz-icp``):
  ``defaults``: ``load_config(None)`` (max_range 100 m, min_range 0.3 m, voxel 0.3 m: the same numbers as its
  ``pretuned/indoor.yaml``);
  ``ouster``: its ``pretuned/newer_college.yaml`` (the Newer College dataset's handheld Ouster OS1-64: voxel
  0.6 m, 3000 voxelized points, 3 points a voxel, min_range 0.5 m, max_range 120 m), deskew off.
- ``small_gicp`` (small_gicp 1.0.1, PyPI ``small-gicp``), the two odometries of its
  ``src/example/kitti_odometry.py``:
  ``defaults``: scan-to-scan GICP, ``preprocess_points`` at its 0.25 m and ``align`` with its defaults
  (``GICP``, 1 m correspondences, 20 iterations), the last motion as the guess, one thread (its functions'
  default);
  ``model``: scan-to-model, the example's ``-m``: each sweep (0.25 m) against a ``GaussianVoxelMap(1.0)`` with LRU
  (horizon 100, clear cycle 10) of the sweeps placed so far (VGICP), every core (the example's ``--num_threads``
  set to the machine's).

:func:`run_peer` runs one and times it: wall seconds of each sweep's registration, CPU seconds of the whole run
(``time.process_time``: every thread of this process); reading the sweeps is not counted.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError

__all__ = ["SETTINGS", "PeerRun", "run_peer", "make_peer", "ouster_voxel_size", "version_of"]

#: Peer name -> its settings' names.
SETTINGS = {"kiss_icp": ("defaults", "ouster"), "genz_icp": ("defaults", "ouster"),
            "small_gicp": ("defaults", "model")}
_DIST = {"kiss_icp": "kiss-icp", "genz_icp": "genz-icp", "small_gicp": "small-gicp"}


def version_of(peer: str) -> str | None:
    """The installed version of a peer's package, None when it is not installed."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(_DIST.get(peer, peer))
    except PackageNotFoundError:
        return None


def ouster_voxel_size(points: NDArray[np.float64], pixels: int = 2048 * 64) -> float:
    """Ouster's KISS-ICP voxel size for a sweep: the mean range between the 92nd and 96th percentiles over 46,
    times (``pixels`` / (1024 x 128)) ** 0.25 (ouster-sdk's ``KissBackend.get_voxel_size``)."""
    r = np.linalg.norm(np.asarray(points, dtype=float), axis=1)
    r = r[r > 0]
    if r.size == 0:
        raise InputError("a sweep without points has no range to size KISS-ICP's voxels from")
    lo, hi = np.percentile(r, 92.0), np.percentile(r, 96.0)
    sel = r[(r >= lo) & (r <= hi)]
    return float(sel.mean() / 46.0 * (pixels / (1024 * 128)) ** 0.25)


def _kiss(setting: str, first: NDArray[np.float64]):
    from kiss_icp.config import load_config
    from kiss_icp.kiss_icp import KissICP

    cfg = load_config(None)
    if setting == "ouster":
        cfg.data.max_range, cfg.data.min_range = 150.0, 1.0
        cfg.mapping.voxel_size = ouster_voxel_size(first)
    cfg.data.deskew = False
    odo = KissICP(cfg)

    def register(pts):
        odo.register_frame(pts, np.zeros(len(pts)))
        return np.asarray(odo.last_pose)

    info = {"max_range": cfg.data.max_range, "min_range": cfg.data.min_range, "deskew": False,
            "voxel_size": cfg.mapping.voxel_size, "max_points_per_voxel": cfg.mapping.max_points_per_voxel,
            "max_num_threads": cfg.registration.max_num_threads}
    return register, info


def _genz(setting: str, first: NDArray[np.float64]):
    from genz_icp.config import load_config
    from genz_icp.genz_icp import GenZICP

    cfg = load_config(None)
    if setting == "ouster":  # pretuned/newer_college.yaml
        cfg.data.max_range, cfg.data.min_range = 120.0, 0.5
        cfg.mapping.voxel_size = 0.6
        cfg.mapping.desired_num_voxelized_points = 3000
        cfg.mapping.planarity_threshold = 0.2
        cfg.mapping.max_points_per_voxel = 3
    cfg.data.deskew = False
    odo = GenZICP(cfg)

    def register(pts):
        odo.register_frame(pts, np.zeros(len(pts)))
        return np.asarray(odo.last_pose)

    info = {"max_range": cfg.data.max_range, "min_range": cfg.data.min_range, "deskew": False,
            "voxel_size": cfg.mapping.voxel_size,
            "desired_num_voxelized_points": cfg.mapping.desired_num_voxelized_points,
            "max_points_per_voxel": cfg.mapping.max_points_per_voxel}
    return register, info


def _small_gicp(setting: str, first: NDArray[np.float64]):
    import small_gicp

    res = 0.25
    if setting == "defaults":
        state = {"target": None, "T": np.eye(4), "last": np.eye(4)}

        def register(pts):
            cloud, tree = small_gicp.preprocess_points(pts, res)
            if state["target"] is not None:
                r = small_gicp.align(state["target"][0], cloud, state["target"][1], state["last"])
                state["last"] = np.asarray(r.T_target_source)
                state["T"] = state["T"] @ state["last"]
            state["target"] = (cloud, tree)
            return state["T"].copy()

        return register, {"odometry": "scan-to-scan", "registration_type": "GICP", "downsampling_resolution": res,
                          "max_correspondence_distance": 1.0, "num_threads": 1}
    threads = os.cpu_count() or 1
    vmap = small_gicp.GaussianVoxelMap(1.0)
    vmap.set_lru(horizon=100, clear_cycle=10)
    state = {"T": np.eye(4), "last": np.eye(4)}

    def register(pts):
        cloud, _ = small_gicp.preprocess_points(pts, res, num_threads=threads)
        if vmap.size() == 0:
            vmap.insert(cloud)
            return state["T"].copy()
        r = small_gicp.align(vmap, cloud, state["T"] @ state["last"], num_threads=threads)
        T = np.asarray(r.T_target_source)
        state["last"] = np.linalg.inv(state["T"]) @ T
        state["T"] = T
        vmap.insert(cloud, T)
        return T.copy()

    return register, {"odometry": "scan-to-model", "registration_type": "VGICP", "voxel_map": 1.0,
                      "lru_horizon": 100, "lru_clear_cycle": 10, "downsampling_resolution": res,
                      "num_threads": threads}


_MAKERS = {"kiss_icp": _kiss, "genz_icp": _genz, "small_gicp": _small_gicp}


def make_peer(peer: str, setting: str, first: NDArray[np.float64]) -> tuple[Callable, dict]:
    """``(register, settings)``: ``register(points) -> 4x4`` pose of the sensor in the first sweep's frame, and the
    settings it runs with. ``first``: the first sweep (Ouster's KISS-ICP voxel is sized from it).

    Raises
    ------
    InputError
        An unknown peer or setting. A peer's missing package raises its ModuleNotFoundError.
    """
    if peer not in SETTINGS or setting not in SETTINGS[peer]:
        raise InputError(f"unknown peer {peer}/{setting}; expected one of "
                         f"{', '.join(f'{p}/{s}' for p, ss in SETTINGS.items() for s in ss)}")
    return _MAKERS[peer](setting, np.ascontiguousarray(first, dtype=np.float64))


@dataclass
class PeerRun:
    """One peer over the sweeps: the sensor's 4x4 poses and the time it took."""

    peer: str
    setting: str
    poses: NDArray[np.float64]
    wall_per_sweep: NDArray[np.float64]
    cpu_seconds: float
    settings: dict = field(default_factory=dict)

    def timing(self) -> dict:
        n = max(len(self.wall_per_sweep), 1)
        return {"wall_seconds": float(np.sum(self.wall_per_sweep)), "cpu_seconds": self.cpu_seconds,
                "wall_per_sweep_median_s": float(np.median(self.wall_per_sweep)),
                "cpu_per_sweep_mean_s": self.cpu_seconds / n}


def run_peer(peer: str, setting: str, sweeps: Iterable[NDArray[np.float64]]) -> PeerRun:
    """Run one peer with one of its settings over ``sweeps`` (each (N, 3), sensor frame); see the module
    docstring."""
    it = iter(sweeps)
    try:
        first = np.ascontiguousarray(next(it), dtype=np.float64)
    except StopIteration:
        raise InputError("no sweeps to run a peer on") from None
    register, settings = make_peer(peer, setting, first)
    poses, walls = [], []
    cpu = 0.0

    def one(pts):
        nonlocal cpu
        c0, t0 = time.process_time(), time.perf_counter()
        T = register(pts)
        walls.append(time.perf_counter() - t0)
        cpu += time.process_time() - c0
        poses.append(np.asarray(T, dtype=float))

    one(first)
    for pts in it:
        one(np.ascontiguousarray(pts, dtype=np.float64))
    return PeerRun(peer, setting, np.asarray(poses), np.asarray(walls), cpu,
                   {"version": version_of(peer), **settings})
