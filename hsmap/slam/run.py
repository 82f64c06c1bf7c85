"""Running HS-SLAM over a dataset (:func:`run_slam`), its result (:class:`SlamResult`) and its files
(:func:`write_slam_outputs`)."""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._blas import blas_limited
from .._helper_process import cpu_seconds, peak_memory_mb
from .._threads import threads_limited
from ..config import dump_config, to_dict
from ..datasets.frames import Dataset, Frame
from ..errors import EmptyInputError, HsmapError, HsmapWarning, InputError, UnusableFrameError
from ..io import write_json, write_ply_points
from ..maps.mapping import VoxelMap
from ..progress import bar as progress_bar
from ..trajectory import Trajectory, write_tum
from .config import SlamConfig
from .tracker import FrameResult, HsSlam

__all__ = ["SlamResult", "run_slam", "write_slam_outputs", "prior_coverage", "load_kernels"]


@dataclass
class SlamResult:
    """A whole run: the trajectory, the map, per-frame results and totals."""

    trajectory: Trajectory
    map: VoxelMap
    frames: list[FrameResult]
    config: SlamConfig
    seconds: float
    peak_memory_mb: float  # this process's peak resident memory plus the helper process's
    input_name: str = ""
    cpu_seconds: float = float("nan")
    loop_closure: dict = field(default_factory=dict)
    tracked: Trajectory | None = None
    skipped: list[dict] = field(default_factory=list)
    prior: dict = field(default_factory=dict)
    input_info: dict = field(default_factory=dict)
    odometry: dict = field(default_factory=dict)
    smoothing: dict = field(default_factory=dict)
    unsmoothed: Trajectory | None = None  # the graph's trajectory, before the smoothing
    costs: dict = field(default_factory=dict)  # :meth:`hsmap.slam.costs.Costs.as_dict`

    def metrics(self) -> dict:
        """Per-frame and total metrics, JSON-ready."""
        secs = np.array([f.seconds for f in self.frames])
        duration = float(self.trajectory.stamps.max() - self.trajectory.stamps.min()) if len(self.frames) else 0.0
        return {
            "input": self.input_name,
            "dof": self.config.dof,
            "frames": len(self.frames),
            "keyframes": int(sum(f.keyframe for f in self.frames)),
            "map_points": len(self.map),
            "seconds_total": self.seconds,
            "cpu_seconds_total": self.cpu_seconds,
            "seconds_per_frame_median": float(np.median(secs)) if len(secs) else None,
            "seconds_per_frame_p95": float(np.percentile(secs, 95)) if len(secs) else None,
            "input_duration_s": duration,
            "real_time_factor": duration / self.seconds if self.seconds > 0 else None,
            "peak_memory_mb": self.peak_memory_mb,
            "inlier_ratio_median": float(np.median([f.inlier_ratio for f in self.frames])) if self.frames else None,
            "frames_retried": int(sum(f.retried for f in self.frames)),
            "frames_unverified": int(sum(not f.verified for f in self.frames)),
            "odometry_model": self.odometry or None,
            "smoothing": self.smoothing or None,
            "skipped_frames": len(self.skipped),
            "skipped": self.skipped,
            "loop_closure": self.loop_closure.get("status", "disabled"),
            "loops_closed": int(self.loop_closure.get("loops_closed", 0)),
            "pair_edges": int(self.loop_closure.get("pair_edges", 0)),
            "loop_closure_detail": self.loop_closure,
            "prior": self.prior or None,
            "input_info": self.input_info or None,
            "costs": self.costs or None,
            "per_frame": {
                "index": [f.index for f in self.frames],
                "stamp": [f.stamp for f in self.frames],
                "seconds": secs.tolist(),
                "fitness": [f.fitness for f in self.frames],
                "inlier_ratio": [f.inlier_ratio for f in self.frames],
                "rmse": [f.rmse for f in self.frames],
                "evaluations": [f.evaluations for f in self.frames],
                "keyframe": [f.keyframe for f in self.frames],
                "points": [f.points for f in self.frames],
                "retried": [f.retried for f in self.frames],
                "cost": [f.cost for f in self.frames],
            },
        }

_WARN_SKIPPED = 10  # skipped frames warned about one by one; the rest are counted


def prior_coverage(prior: Trajectory, stamps, tolerance: float, *, name: str = "prior") -> dict:
    """How many frames (by their ``stamps``) a prior trajectory gives a pose (:meth:`Trajectory.interpolate`).

    Parameters
    ----------
    prior : Trajectory
    stamps : array_like of shape (N,)
        The frames' stamps.
    tolerance : float
        Seconds (``SlamConfig.sync_tolerance``).
    name : str
        What the caller calls the prior (``--prior FILE`` at the command line), for the messages.

    Returns
    -------
    dict
        ``frames``, ``frames_with_prior``, ``coverage`` (their ratio), ``sync_tolerance``.

    Raises
    ------
    InputError
        The prior gives no frame a pose (it would be silently ignored). Partial coverage is warned about
        (:class:`~hsmap.errors.HsmapWarning`).
    """
    t = np.asarray(stamps, dtype=float).reshape(-1)
    if len(prior) == 0:
        raise InputError(f"{name}: the trajectory is empty; expected the poses of a 2D run of the same input")
    if len(t) == 0:
        return {"frames": 0, "frames_with_prior": 0, "coverage": None, "sync_tolerance": float(tolerance)}
    _, found = prior.interpolate(t, tolerance)
    k, n = int(found.sum()), len(t)
    if k == 0:
        raise InputError(
            f"{name}: none of the input's {n} frames ({t.min():.3f}..{t.max():.3f} s) lies between two of its "
            f"{len(prior)} poses ({prior.stamps.min():.3f}..{prior.stamps.max():.3f} s) within the sync tolerance "
            f"of {tolerance:g} s or in a gap of its regular cadence; expected the trajectory.tum of a 2D run of the "
            f"same input (or a larger --sync-tolerance)")
    if k < n:
        warnings.warn(f"{name} gives a pose to {k} of the {n} frames ({100.0 * k / n:.1f} %) within the sync "
                      f"tolerance of {tolerance:g} s; the others are seeded without it", HsmapWarning, stacklevel=3)
    return {"frames": n, "frames_with_prior": k, "coverage": k / n, "sync_tolerance": float(tolerance)}


@blas_limited
@threads_limited
def run_slam(
    dataset: Dataset | Iterable[Frame],
    config: SlamConfig | None = None,
    *,
    rng: int | np.random.Generator | None = None,
    initial_pose: NDArray[np.float64] | None = None,
    prior: Trajectory | None = None,
    max_frames: int | None = None,
    progress: bool | None = None,
    on_frame: Callable[[Frame, FrameResult, HsSlam], None] | None = None,
    strict: bool = False,
    prior_name: str = "prior",
) -> SlamResult:
    """Run HS-SLAM over a dataset (or any iterable of frames).

    Parameters
    ----------
    dataset : Dataset or iterable of Frame
    config : SlamConfig, optional
    rng : int or Generator, optional
    initial_pose : array_like, optional
        Pose of the first frame (default: origin).
    prior : Trajectory, optional
        6-DOF: 2D poses used as seeds, interpolated at each frame's stamp within ``config.sync_tolerance``. When
        ``dataset`` knows its frame stamps, a prior that covers none of them is an :class:`InputError` and
        one that covers only some is warned about, before any frame is processed (:func:`prior_coverage`);
        the coverage goes into the metrics (``prior``).
    max_frames : int, optional
        Stop after this many frames.
    progress : bool or None
        Show a progress bar; None shows it only on a terminal. A caller that is :func:`hsmap.progress.reporting`
        gets heartbeat lines with the frame count whatever this says.
    on_frame : callable, optional
        Called after each frame with (frame, result, slam), e.g. to log to rerun.
    strict : bool
        A frame whose scan or cloud is missing or has too few usable points (:class:`UnusableFrameError`)
        stops the run. By default it is skipped with a warning naming the input and the cause, and counted
        (``SlamResult.skipped``, ``skipped_frames`` in the metrics); its stamp has no pose.
    prior_name : str
        What the caller calls the prior, in messages (``--prior FILE`` at the command line).
    threads : int, optional
        Compute threads (keyword only; default ``$HSMAP_THREADS``, else every core): a speed setting only, the
        result is the same for any count (:mod:`hsmap._threads`).

    The metrics' ``input_info`` is the dataset's :meth:`~hsmap.datasets.frames.Dataset.describe` (topics,
    message counts and rates, frames, the sensor offsets and where they came from, warnings).

    Raises
    ------
    UnusableFrameError
        With ``strict``, the first unusable frame; without, when no frame at all is usable.
    """
    slam = HsSlam(config, rng=rng, initial_pose=initial_pose, prior=prior,
                  odometry=getattr(dataset, "odometry", None) if isinstance(dataset, Dataset) else None)
    prior_info: dict = {}
    stamps = getattr(dataset, "stamps", None)
    if prior is not None and stamps is not None:
        prior_info = prior_coverage(prior, np.asarray(stamps)[:max_frames], slam.config.sync_tolerance,
                                    name=prior_name)
    dof = slam.config.dof
    frames = dataset.frames(clouds=dof == 6) if isinstance(dataset, Dataset) else iter(dataset)
    total = len(dataset) if isinstance(dataset, Dataset) else None
    if max_frames is not None:
        total = min(total, max_frames) if total is not None else max_frames
    if dof == 6:
        load_kernels(slam.config)
    t0, c0 = time.perf_counter(), cpu_seconds()  # the helper process's CPU too
    bar = progress_bar(total, unit="scan" if dof == 3 else "cloud", desc=f"HS-SLAM {dof}-DOF", progress=progress)
    source = str(getattr(dataset, "path", "") or getattr(dataset, "name", "") or "the input")
    try:
        skipped, n_read = _track(slam, frames, max_frames, bar, on_frame, strict, source)
    finally:
        bar.close()
    return _finished(slam, dataset, source, skipped, n_read, prior_info, (t0, c0))


#: The warm-up's sweeps (:func:`load_kernels`): a sensor moving along x in a box room, points on its walls,
#: floor and ceiling and on a pillar, so that every direction is constrained.
_WARM_SWEEPS = 3
_kernels_loaded = False  # whether load_kernels ran in this process


def load_kernels(config: SlamConfig) -> None:
    """Load the compiled kernels a 6-DOF run with ``config`` uses (numba's on-disk caches, and its typing context
    on first use) now, not in the run's first frames: a throwaway tracker registers a few small synthetic sweeps.

    Loading code is start-up, like importing a library: :func:`run_slam` calls this before it starts its clock,
    so that its CPU time is the frames' work. Loaded code stays loaded: this runs once per process. The throwaway
    tracker has its own random stream and its warnings are not shown; nothing of it is kept, and a configuration
    its sweeps do not suit leaves the loading to the run."""
    global _kernels_loaded
    if _kernels_loaded:
        return
    _kernels_loaded = True
    gen = np.random.default_rng(0)
    faces = []
    for axis, (lo, hi) in enumerate(((-6.0, 6.0), (-4.0, 4.0), (-1.5, 1.5))):
        for side in (lo, hi):
            f = gen.uniform([-6.0, -4.0, -1.5], [6.0, 4.0, 1.5], (1500, 3))
            f[:, axis] = side
            faces.append(f)
    pillar = gen.uniform([1.5, 1.0, -1.5], [2.0, 1.5, 1.5], (600, 3))
    pillar[:300, 0] = 1.5
    pillar[300:, 1] = 1.0
    world = np.vstack([*faces, pillar])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # about the synthetic sweeps: none concerns the user's
        try:
            tracker = HsSlam(config, rng=0)
            for k in range(_WARM_SWEEPS):
                sensor = np.array([0.1 * k, 0.0, 0.0])
                tracker.process(Frame(stamp=0.5 * k, cloud3d=world - sensor, index=k))
        except HsmapError:
            pass  # a configuration the synthetic sweeps do not suit (ranges, voxels): the run loads what it uses


def _finished(slam: HsSlam, dataset: Dataset | Iterable[Frame], source: str, skipped: list[dict], n_read: int,
              prior_info: dict, started: tuple[float, float]) -> SlamResult:
    """The run's result once its ``n_read`` frames are tracked (``slam`` finished), from the clock and the CPU
    time when it ``started``; an error where no frame was usable, a warning where more than a few were skipped."""
    t0, c0 = started
    if not slam.poses:
        if skipped:
            raise UnusableFrameError(f"{source}: none of its {n_read} frames could be used; the first: "
                                     f"{skipped[0]['reason']}", skipped[0]["index"], skipped[0]["stamp"])
        raise EmptyInputError("the input has no frames")
    if len(skipped) > _WARN_SKIPPED:
        warnings.warn(f"{source}: {len(skipped)} of {n_read} frames skipped in all", HsmapWarning, stacklevel=3)
    slam.finish()
    peak = peak_memory_mb()  # the helper process's too
    return SlamResult(slam.trajectory, slam.global_map(), slam.results, slam.config, time.perf_counter() - t0,
                      peak, getattr(dataset, "name", ""), cpu_seconds() - c0,
                      loop_closure=slam.keyframe_graph.summary(), tracked=slam.tracked_trajectory, skipped=skipped,
                      prior=prior_info, input_info=dataset.describe() if isinstance(dataset, Dataset) else {},
                      odometry=slam.odometry.summary(), smoothing=slam.smoothing_summary(),
                      unsmoothed=slam.graph_trajectory, costs=slam.costs.as_dict())


def _track(slam: HsSlam, frames: Iterator[Frame], max_frames: int | None, bar: Any,
           on_frame: Callable[[Frame, FrameResult, HsSlam], None] | None, strict: bool, source: str
           ) -> tuple[list[dict], int]:
    """Process ``frames`` in order, the first ``max_frames`` (``on_frame`` after each, the progress ``bar``
    advanced); a frame that is unusable (:class:`UnusableFrameError`) stops them with ``strict``, else is skipped
    with a warning naming ``source``. Returns the skipped frames (index, stamp, reason) and the number read."""
    skipped: list[dict] = []
    n_read = 0
    for k, frame in enumerate(frames):
        if max_frames is not None and k >= max_frames:
            break
        n_read += 1
        try:
            res = slam.process(frame)
            frame = slam.frame
        except UnusableFrameError as exc:
            if strict:
                raise UnusableFrameError(f"{source}: {exc}", exc.index, exc.stamp) from None
            skipped.append({"index": exc.index, "stamp": exc.stamp, "reason": str(exc)})
            if len(skipped) <= _WARN_SKIPPED:
                more = "; later ones are counted in the metrics" if len(skipped) == _WARN_SKIPPED else ""
                warnings.warn(f"{source}: {exc}; frame skipped{more}", HsmapWarning, stacklevel=3)
            bar.update(1)
            continue
        if on_frame is not None:
            on_frame(frame, res, slam)
        bar.update(1)
    return skipped, n_read


def write_slam_outputs(result: SlamResult, out_dir: str | Path) -> dict[str, Path]:
    """Write ``trajectory.tum``, ``map.ply``, ``metrics.json`` and ``config.yaml`` into ``out_dir`` atomically.

    ``metrics.json`` is written last: a folder without it is incomplete.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"trajectory": out / "trajectory.tum", "map": out / "map.ply", "config": out / "config.yaml",
             "metrics": out / "metrics.json"}
    write_tum(paths["trajectory"], result.trajectory)
    pts = result.map.points
    if pts.shape[1] == 2:
        pts = np.column_stack([pts, np.zeros(len(pts))])
    write_ply_points(paths["map"], pts)
    dump_config(result.config, paths["config"])
    metrics = result.metrics()
    metrics["config"] = to_dict(result.config)
    write_json(paths["metrics"], metrics)
    return paths
