"""HS-SLAM's tracker (:class:`HsSlam`): each frame's points (:class:`~hsmap.slam.deskewing.Deskewing`) registered
by Harmony-ICP against the local map from the seeds of the motion prediction
(:class:`~hsmap.slam.prediction.MotionPrediction`), checked and fused with that prediction by the
:class:`~hsmap.slam.verify.Verifier`; keyframes kept by the :class:`~hsmap.slam.keyframes.KeyframeGraph`."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..datasets.frames import Frame
from ..errors import InputError
from ..maps.mapping import VoxelMap
from ..registration.harmony import as_rng
from ..registration.icp import RegistrationResult, harmony_icp
from ..trajectory import Trajectory
from .config import SlamConfig
from .costs import Costs
from .deskewing import Deskewing
from .keyframes import KeyframeGraph
from .loopclosure import Keyframe
from .motions import FrameMotions
from .odometry import OdometryModel
from .posegraph import EdgeKind, PoseGraph
from .prediction import MotionPrediction, mean_pose
from .search import SearchBox
from .verify import Verifier

__all__ = ["HsSlam", "FrameResult", "mean_pose", "FLOOR_SIGMA", "hold_to_floor"]

#: (m, rad): a 6-DOF run seeded by a 2D run holds every keyframe's height, roll and pitch to the first pose's
#: (the floor the 2D run moves on) with these sigmas, a unary prior in the pose graph: a building's floor is level
#: to within them, and the relative edges alone let the tilt and the height wander as a random walk.
FLOOR_SIGMA = (0.02, float(np.deg2rad(0.5)))


@dataclass
class FrameResult:
    """What HS-SLAM did with one frame."""

    index: int
    stamp: float
    pose: NDArray[np.float64]
    fitness: float
    inlier_ratio: float
    rmse: float
    evaluations: int
    seconds: float
    keyframe: bool
    points: int
    map_points: int
    retried: bool = False
    verified: bool = True
    cost: float = float("nan")

    @classmethod
    def of(cls, frame: Frame, pose: NDArray[np.float64], res: RegistrationResult | None, checked: tuple[bool, bool],
           keyframe: bool, sizes: tuple[int, int], started: float) -> FrameResult:
        """The result of ``frame`` tracked at ``pose`` by the registration ``res`` (None: the first frame), whether
        it was retried and confirmed (``checked``), its scan's and the map's sizes, from ``started`` (a
        :func:`time.perf_counter` reading)."""
        fit = (0.0, 1.0, 0.0, 0, 0.0) if res is None else (res.fitness, res.inlier_ratio, res.rmse, res.evaluations,
                                                             res.cost)
        return cls(frame.index, float(frame.stamp), pose, float(fit[0]), float(fit[1]), float(fit[2]), int(fit[3]),
                   time.perf_counter() - started, bool(keyframe), *sizes, *checked, float(fit[4]))


def hold_to_floor(graph: PoseGraph, floor: NDArray[np.float64]) -> None:
    """Hold the newest keyframe's height, roll and pitch near the floor's (``floor``, a 6-DOF pose) with
    :data:`FLOOR_SIGMA`: a unary edge of the pose graph."""
    k = len(graph) - 1
    level = graph.poses[k].copy()
    level[2:5] = floor[2:5]
    info = np.full(6, 1e-9)  # x, y and yaw: nothing said
    info[2] = 1.0 / FLOOR_SIGMA[0] ** 2
    info[3:5] = 1.0 / FLOOR_SIGMA[1] ** 2
    graph.add_edge(k, k, level, np.diag(info), EdgeKind.PRIOR, robust=False)


def _start_pose(config: SlamConfig, initial_pose: NDArray[np.float64] | None, prior: Trajectory | None
                ) -> NDArray[np.float64]:
    """The first frame's pose (``initial_pose``, by default the origin); an InputError for a pose of another dof
    or a prior in a 3-DOF run."""
    pose = np.zeros(config.dof) if initial_pose is None else np.asarray(initial_pose, dtype=float)
    if pose.shape != (config.dof,):
        raise InputError(f"initial_pose must have {config.dof} values, got shape {pose.shape}")
    if prior is not None and config.dof != 6:
        raise InputError("a prior trajectory seeds 6-DOF runs only (dof=6)")
    return pose


class HsSlam:
    """Incremental HS-SLAM: call :meth:`process` with each frame in order, then :meth:`finish`.

    Parameters
    ----------
    config : SlamConfig, optional
    rng : int or numpy.random.Generator, optional
        Seed for every random choice (default 0).
    initial_pose : array_like of shape (dof,), optional
        Pose of the first frame (default: the origin).
    prior : Trajectory, optional
        6-DOF only: (x, y, yaw) poses from a 2D run, looked up by stamp, used as seeds with a narrower range.
    odometry : Trajectory, optional
        3-DOF: the input's wheel odometry (x, y, yaw) at its frame stamps; 2D scans with beam times are deskewed
        with its motion, interpolated at the beams' times (with ``use_odometry``).

    Attributes
    ----------
    poses, stamps : list
        The pose (dof,) and the stamp of every frame as tracked; :attr:`trajectory` gives the current estimate.
    prediction : MotionPrediction
    odometry : OdometryModel
    verifier : Verifier
    keyframe_graph : KeyframeGraph
        The keyframes, their pose graph (:attr:`graph`) and maps (:attr:`map`).
    frame : Frame or None
        The last frame processed, as used (its cloud deskewed).
    """

    def __init__(self, config: SlamConfig | None = None, *, rng: int | np.random.Generator | None = None,
                 initial_pose: NDArray[np.float64] | None = None, prior: Trajectory | None = None,
                 odometry: Trajectory | None = None) -> None:
        self.config = cfg = config or SlamConfig()
        self.rng = as_rng(rng)
        loop_rng = self.rng.spawn(1)[0]  # loop closure's own stream: its searches do not shift the tracking's
        self._initial = _start_pose(cfg, initial_pose, prior)
        self.results: list[FrameResult] = []
        self.frame: Frame | None = None
        self.odometry = OdometryModel(cfg, learn=cfg.learn_odometry and prior is None,
                                      wheel_edges=cfg.dof == 3 and prior is None and cfg.graph.odometry_edges,
                                      prior=prior is not None)
        self.costs = Costs()
        self.search = SearchBox(cfg, self.costs, prior=prior is not None)
        self.prediction = MotionPrediction(cfg, self.odometry, self.search,
                                           None if prior is None else prior.as_3dof())
        self.poses, self.stamps = self.prediction.poses, self.prediction.stamps
        self.deskewing = Deskewing(cfg, self.costs, self.prediction, odometry)
        self.verifier = Verifier(cfg, self.prediction, costs=self.costs)
        self.keyframe_graph = KeyframeGraph(cfg, self.odometry, loop_rng, costs=self.costs)
        self._level_floor = cfg.level_floor and cfg.dof == 6 and prior is not None
        self._not_smoothed = ("off (slam.smoothing: false)" if not cfg.smoothing else "not applicable: 6-DOF"
                              if cfg.dof != 3 else "not applicable: seeded by a prior trajectory" if prior is not None
                              else None)
        self.motions = None if self._not_smoothed else FrameMotions(cfg, self.odometry, self.costs)

    @property
    def graph(self) -> PoseGraph:
        """The pose graph: one node per keyframe."""
        return self.keyframe_graph.graph

    @property
    def keyframes(self) -> list[Keyframe]:
        return self.keyframe_graph.keyframes

    @property
    def map(self) -> VoxelMap:
        """The tracking map (keyframes near the newest one along the graph)."""
        return self.keyframe_graph.map

    def process(self, frame: Frame) -> FrameResult:
        """Register one frame and update the map (and the pose graph); returns what was done."""
        t0 = time.perf_counter()
        kg = self.keyframe_graph
        frame, scan, times = self.deskewing.points(frame)
        self.frame = frame
        self.prediction.start(frame)
        first = not self.poses
        if first:
            pose, res, checked, information, registration_information = self._initial, None, (False, True), None, None
        else:
            res, scan, checked = self._register(scan, times)
            pose, information, registration_information = self.verifier.fuse(res)
        keyframe = first or (checked[1] and (len(self.poses) < self.config.warmup_frames or kg.is_keyframe(pose)))
        if self.motions is not None:
            self.motions.record(frame, scan, self.poses[-1] if self.poses else pose, pose)
        self.poses.append(pose)
        self.stamps.append(float(frame.stamp))
        kg.attach(pose, keyframe)
        if keyframe and kg.add_keyframe(frame, len(self.results), scan, pose, information, registration_information):
            self._reanchor_recent()
        if keyframe and not first and self._level_floor and len(self.graph) >= 2:
            hold_to_floor(self.graph, self.poses[0])
        self.prediction.advance(pose)
        if keyframe:
            # the next frame's target, built in the keyframe's step: the next frame only tracks
            kg.ensure_target(self.poses[-1])
        result = FrameResult.of(frame, pose, res, checked, keyframe, (len(scan), len(kg.map)), t0)
        self.results.append(result)
        if not first:
            self.search.record(result.inlier_ratio, result.verified)
        return result

    def _register(self, scan: NDArray[np.float64], times: NDArray[np.float64] | None
                  ) -> tuple[RegistrationResult, NDArray[np.float64], tuple[bool, bool]]:
        """The frame's registration against the tracking target from the prediction's seeds, widened
        (:meth:`SearchBox.widened`), verified and, with point times, refined over the sweep; the scan (refined with
        it), and whether it was retried and whether its pose is confirmed."""
        target = self.keyframe_graph.ensure_target(self.poses[-1])
        guesses, half = self.prediction.seeds()
        res = self._tight_search(scan, target, guesses, half)
        if res is None:
            bounds = np.column_stack([guesses.min(0) - half, guesses.max(0) + half])
            res = harmony_icp(scan, target, bounds=bounds, initial_guesses=guesses,
                              config=self.config.registration, rng=self.rng)
            self.costs.registration(res.evaluations)
        res, widened, matched = self.search.widened(scan, target, res, guesses, half, self.rng)
        self.prediction.first_registration(res)
        searched = res
        res, retried, verified = self.verifier.verify(scan, target, res, self.rng)
        res, verified = self.search.settled(scan, target, searched, res, verified)
        checked = (retried or widened, verified and (matched or self.search.passes(res)))
        if times is not None:
            res, scan = self.deskewing.refined(scan, times, target, res)
        self.prediction.kept_registration(res)
        return res, scan, checked

    def _tight_search(self, scan: NDArray[np.float64], target, guesses: NDArray[np.float64],
                      half: NDArray[np.float64]) -> RegistrationResult | None:
        """The frame's registration in the tight box of the prediction's uncertainty (:meth:`SearchBox.tight`), with
        a small search, seeded by the prediction and the seeds inside the box; None where there is no tight box
        or the registration escapes it (:meth:`SearchBox.escapes`): then the full search decides."""
        pred = None if self.prediction.prior is not None else self.prediction.predict(True)
        box = self.search.tight(pred, half)
        if box is None:
            return None
        inside = guesses[np.all((guesses >= box[:, 0]) & (guesses <= box[:, 1]), axis=1)]
        seeds = np.vstack([pred[0][None], inside])
        res = harmony_icp(scan, target, bounds=box, initial_guesses=seeds, config=self.search.tight_config(),
                          rng=self.rng)
        self.costs.registration(res.evaluations)
        if self.search.escapes(res, box, scan):
            self.costs.add(full_searches=1)
            return None
        return res

    def _reanchor_recent(self) -> None:
        """Move the recent tracked poses (the seeds' history) with their keyframes."""
        for i in range(max(0, len(self.poses) - self.config.recent_poses - 1), len(self.poses)):
            self.poses[i] = self.keyframe_graph.pose_of(i)

    def finish(self) -> None:
        """Optimise the graph once more if edges are pending, then smooth the trajectory with the odometry
        (``SlamConfig.smoothing``). Call after the last frame."""
        if self.keyframe_graph.finish():
            self._reanchor_recent()
        if self.motions is not None and self.poses:
            self.motions.smooth(self.graph_trajectory.poses)

    # ------------------------------------------------------------------------------------------ results
    def smoothing_summary(self) -> dict:
        """What the smoothing measured and did (JSON-ready), or why it did nothing."""
        return self.motions.summary() if self.motions is not None else {"status": self._not_smoothed}

    def global_map(self) -> VoxelMap:
        """The point map of every keyframe at its current (optimised) pose."""
        return self.keyframe_graph.global_map()

    @property
    def trajectory(self) -> Trajectory:
        """Every frame's pose: after :meth:`finish`, the smoothed one (``SlamConfig.smoothing``); before it, or
        where the smoothing did nothing, :attr:`graph_trajectory`."""
        smoothed = None if self.motions is None else self.motions.result
        if smoothed is not None and smoothed.status == "ok":
            return Trajectory(np.asarray(self.stamps), smoothed.poses.copy())
        return self.graph_trajectory

    @property
    def graph_trajectory(self) -> Trajectory:
        """Every frame's pose at the current estimate of its keyframe (loop closures included)."""
        return self.keyframe_graph.graph_trajectory(np.asarray(self.stamps))

    @property
    def tracked_trajectory(self) -> Trajectory:
        """Every frame's pose from the tracking alone: the keyframes chained by their tracking edges."""
        return self.keyframe_graph.tracked_trajectory(np.asarray(self.stamps))
