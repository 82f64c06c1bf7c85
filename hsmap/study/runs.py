"""The study's HS-SLAM runs: :func:`cached_slam` into ``data/generated/slam/`` (the runs of
:mod:`hsmap.pipeline.runs`, shared by every notebook that asks), and :func:`simulated_slam_runs`, the standard pair
of runs of one simulated dataset (3-DOF, and 6-DOF seeded by the 3-DOF poses, as the paper does)."""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from numpy.typing import ArrayLike

from ..datasets.frames import Dataset
from ..datasets.simulated import SimulatedDataset
from ..pipeline import runs as _runs
from ..pipeline.runs import SlamRun, dataset_fingerprint
from ..slam import SlamConfig
from ..trajectory import Trajectory
from .datasets import simulated_dataset
from .paths import generated_dir

__all__ = ["SlamRun", "cached_slam", "slam_key", "dataset_fingerprint", "default_slam_dir", "SimulatedRuns",
           "simulated_slam_runs"]


def default_slam_dir() -> Path:
    """``data/generated/slam`` of the repository (``$HSMAP_GENERATED/slam`` when that is set)."""
    return generated_dir() / "slam"


def cached_slam(dataset: Dataset | str | os.PathLike, config: SlamConfig | None = None, seed: int = 0, *,
                cache_dir: str | os.PathLike | None = None, **kwargs: Any) -> SlamRun:
    """:func:`hsmap.pipeline.runs.cached_slam` with ``cache_dir`` by default :func:`default_slam_dir`."""
    return _runs.cached_slam(dataset, config, seed, cache_dir=cache_dir if cache_dir is not None
                             else default_slam_dir(), **kwargs)


def slam_key(dataset: Dataset | str | os.PathLike, config: SlamConfig, seed: int, *,
             prior: Trajectory | None = None, max_frames: int | None = None, initial_pose: ArrayLike | None = None,
             open_kwargs: Mapping[str, Any] | None = None) -> tuple[str, dict]:
    """The cache key of a SLAM run and the description it hashes (:func:`hsmap.pipeline.runs.slam_key`)."""
    return _runs.slam_key(dataset, config, seed, prior=prior, max_frames=max_frames, initial_pose=initial_pose,
                          open_kwargs=open_kwargs)


# --- the standard runs of a simulated dataset ------------------------------------------------------------

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

    dataset: SimulatedDataset
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
    world frame of the ground truth and the odometry), without odometry unless ``use_odometry``. Callers with
    the same arguments share one computation (:func:`cached_slam`).
    """
    ds = simulated_dataset(scenario, seed, max_frames=max_frames)
    n = len(ds) if max_frames is None else min(int(max_frames), len(ds))
    truth = ds.groundtruth.head(n)
    odometry = ds.odometry.head(n)
    run3 = cached_slam(ds, SlamConfig(dof=3, use_odometry=use_odometry), seed, max_frames=max_frames,
                       initial_pose=truth.poses[0], cache_dir=cache_dir)
    run6 = None
    if dof6:
        run6 = cached_slam(ds, SlamConfig(dof=6, use_odometry=use_odometry), seed, max_frames=max_frames,
                           initial_pose=truth.as_6dof().poses[0], prior=run3.trajectory, cache_dir=cache_dir)
    return SimulatedRuns(ds, truth, odometry, run3, run6, n)
