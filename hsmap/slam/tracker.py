"""HS-SLAM's tracker (:class:`HsSlam`): each frame registered by Harmony-ICP against the local map, seeded by the
motion predictions, checked and fused by the :class:`~hsmap.slam.verify.Verifier`, its odometry learned by the
:class:`~hsmap.slam.odometry.OdometryModel`, keyframes kept by the :class:`~hsmap.slam.keyframes.KeyframeGraph`."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from ..datasets.frames import Frame
from ..deskew import deskew_frame, refine_sweep
from ..deskew2d import deskew_scan_frame
from ..errors import InputError, UnusableFrameError
from ..geometry import compose, pose_to_matrix, relative, wrap_angle
from ..maps.mapping import VoxelMap
from ..registration.harmony import as_rng
from ..registration.icp import RegistrationResult, RegistrationTarget, harmony_icp, spans_its_space
from ..trajectory import Trajectory
from .config import SlamConfig
from .costs import Costs
from .frames import frame_points, timed_cloud_points, unusable_reason
from .keyframes import KeyframeGraph
from .loopclosure import Keyframe
from .motions import FrameMotions
from .odometry import OdometryModel
from .posegraph import EdgeKind, PoseGraph
from .search import SearchBox
from .smoothing import SmoothingResult, smooth_with_odometry
from .verify import Prediction, Verifier

__all__ = ["HsSlam", "FrameResult", "mean_pose", "FLOOR_SIGMA"]

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


def mean_pose(poses: NDArray[np.float64]) -> NDArray[np.float64]:
    """The mean of poses (K, dof), angles averaged on the circle."""
    dim = 2 if poses.shape[1] == 3 else 3
    out = poses.mean(axis=0)
    ang = poses[:, dim:]
    out[dim:] = np.arctan2(np.sin(ang).mean(0), np.cos(ang).mean(0))
    return out


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
    poses : list of ndarray of shape (dof,)
        The pose of every frame as tracked; :attr:`trajectory` gives the current estimate of all of them.
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
        self.config = config or SlamConfig()
        cfg = self.config
        self.rng = as_rng(rng)
        loop_rng = self.rng.spawn(1)[0]  # loop closure's own stream: its searches do not shift the tracking's
        self.dim = cfg.dim
        self.poses: list[NDArray[np.float64]] = []
        self.stamps: list[float] = []
        self.results: list[FrameResult] = []
        self.frame: Frame | None = None
        self._initial = None if initial_pose is None else np.asarray(initial_pose, dtype=float)
        if self._initial is not None and self._initial.shape != (cfg.dof,):
            raise InputError(f"initial_pose must have {cfg.dof} values, got shape {self._initial.shape}")
        self._odometry_track = odometry if cfg.dof == 3 and cfg.use_odometry and odometry is not None else None
        self._prior = None
        self._prior_at: dict[float, NDArray[np.float64] | None] = {}  # the prior's (x, y, yaw) at recent stamps
        if prior is not None:
            if cfg.dof != 6:
                raise InputError("a prior trajectory seeds 6-DOF runs only (dof=6)")
            self._prior = prior.as_3dof()
        self.odometry = OdometryModel(cfg, learn=cfg.learn_odometry and prior is None,
                                      wheel_edges=cfg.dof == 3 and prior is None and cfg.graph.odometry_edges,
                                      prior=prior is not None)
        self.costs = Costs()
        self.verifier = Verifier(cfg, costs=self.costs, prior=prior is not None)
        self.search = SearchBox(cfg, self.costs, prior=prior is not None)
        self.keyframe_graph = KeyframeGraph(cfg, self.odometry, loop_rng, costs=self.costs)
        self._smooth = cfg.smoothing and cfg.dof == 3 and prior is None
        self.motions = FrameMotions(cfg, self.odometry, self.costs) if self._smooth else None  # the smoothing's
        self._smoothing: SmoothingResult | None = None

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

    # --------------------------------------------------------------------------------------------- seeds
    def _prior_pose(self, stamp: float) -> NDArray[np.float64] | None:
        """The prior's (x, y, yaw) at ``stamp`` with the previous pose's height, roll and pitch, or None."""
        if self._prior is None:
            return None
        planar = self._prior_at.get(stamp, False)
        if planar is False:  # a frame asks for its own stamp and the previous frame's several times
            poses, found = self._prior.interpolate([stamp], self.config.sync_tolerance)
            planar = poses[0] if found[0] else None
            self._prior_at = {k: v for k, v in self._prior_at.items() if k in self.stamps[-1:]} | {stamp: planar}
        if planar is None:
            return None
        (x, y, yaw), prev = planar, self.poses[-1]
        return np.array([x, y, prev[2], prev[3], prev[4], yaw])

    def seeds(self, frame: Frame) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Initial guesses (K, dof) for ``frame`` and the half-widths (dof,) of the box around them: the previous
        pose, the last motion repeated, the odometry's prediction, the recent poses' mean, a prior's pose."""
        cfg = self.config
        prev = self.poses[-1]
        seeds = [prev]
        if len(self.poses) >= 2:
            seeds.append(compose(prev, relative(self.poses[-2], prev)))
        step = self.odometry.step(frame)
        if step is not None:
            seeds.append(compose(prev, step))
        if len(self.poses) >= 2:
            seeds.append(mean_pose(np.asarray(self.poses[-cfg.recent_poses:])))
        half = self._ranges(prior=False)
        prior = self._prior_pose(frame.stamp)
        if prior is not None:
            seeds = [prior, *seeds]
            half = self._ranges(prior=True)
        s = np.asarray(seeds)
        # unwrap angles next to the previous pose so that the box is continuous across +/- pi
        s[:, self.dim:] = prev[self.dim:] + wrap_angle(s[:, self.dim:] - prev[self.dim:])
        return s, half

    def _ranges(self, prior: bool) -> NDArray[np.float64]:
        return self.search.ranges(self.poses, prior)

    def prediction(self, frame: Frame, gate: bool = False, use_prior: bool = True) -> Prediction:
        """The predicted pose of ``frame`` and the sigmas (translation, yaw) of its x/y and yaw, or None.

        The previous pose moved by: (6-DOF, ``use_prior``) the prior trajectory's motion (``prior_sigma``); else
        the odometry increment (``odometry_sigma``, learned; ``gate``: never tighter than configured); else the
        last motion repeated (``motion_sigma``). None for the first two frames with none of these. A frame whose
        wheels contradict the prior (:meth:`_prior_contradicted`) is predicted without it.
        """
        cfg = self.config
        prev = self.poses[-1]
        step, model = None, None
        prior_now = self._prior_pose(frame.stamp) if use_prior else None
        prior_prev = self._prior_pose(self.stamps[-1]) if prior_now is not None else None
        if prior_now is not None and prior_prev is not None:
            step, model = relative(prior_prev, prior_now), cfg.prior_sigma
            step[2:5] = 0.0  # the prior knows x, y and yaw only
        elif (odo := self.odometry.step(frame)) is not None:
            step, model = self.odometry.corrected(odo), self.odometry.sigma(gate)
        elif len(self.poses) >= 2:
            step, model = relative(self.poses[-2], prev), cfg.motion_sigma
        if step is None:
            return None
        pred = compose(prev, step)
        sig = np.array(self.odometry.model_sigmas(step, model))
        pred = pred.copy()
        pred[self.dim:] = prev[self.dim:] + wrap_angle(pred[self.dim:] - prev[self.dim:])
        return pred, sig

    def _prior_contradicted(self, frame: Frame, res: RegistrationResult) -> bool:
        """A run seeded by a prior: whether the frame's odometry step contradicts the prior's prediction and
        confirms the registration ``res`` instead (the prior's own step jumped, as a 2D run's may along a corridor);
        the odometry then predicts the frame."""
        if self._prior is None:
            return False
        pred = self.prediction(frame)
        if pred is None:
            return False
        prev = self.poses[-1]
        return not self.odometry.confirms(frame, prev, pred[0]) and self.odometry.confirms(frame, prev, res.pose)

    # ---------------------------------------------------------------------------------------------- loop
    def _verify(self, frame: Frame, scan: NDArray[np.float64], res: RegistrationResult, use_prior: bool = True
                ) -> tuple[RegistrationResult, bool, bool]:
        """:meth:`Verifier.verify` of a registration of ``frame`` against the current target. In a run seeded by a
        prior, a registration beyond the prior's gate overrules it only where the wheel odometry confirms it: two
        agreeing sources outweigh a scan that aligns better by aliasing (a wall seen through a door, a scene not yet
        mapped), while a prior whose own step jumped is overruled."""
        overrule = None
        if self._prior is not None:
            def overrule(r: RegistrationResult) -> bool:
                return self.odometry.confirms(frame, self.poses[-1], r.pose)
        return self.verifier.verify(scan, self.keyframe_graph.target, res,
                                    lambda gate: self.prediction(frame, gate, use_prior), self._ranges(prior=False),
                                    self.rng,
                                    lambda r: self.odometry.set_aside(frame, r, self.poses), overrule)

    def process(self, frame: Frame) -> FrameResult:
        """Register one frame and update the map (and the pose graph); returns what was done."""
        t0 = time.perf_counter()
        cfg = self.config
        kg = self.keyframe_graph
        times = frame.point_times if self._deskews(frame) else None
        frame = self.frame = self.deskewed(frame)
        if times is None:
            scan = frame_points(frame, cfg.dof, cfg.min_range, cfg.max_range, voxel=cfg.effective_scan_voxel())
        else:
            scan, times = timed_cloud_points(frame, np.asarray(times, dtype=float).reshape(-1), cfg.min_range,
                                             cfg.max_range, cfg.effective_scan_voxel())
        if len(scan) < 3 * cfg.dim or not spans_its_space(scan):
            raise UnusableFrameError(unusable_reason(frame, cfg.dof, cfg.min_range, cfg.max_range, scan),
                                     frame.index, frame.stamp)
        first = not self.poses
        fitness = inlier = rmse = 0.0
        evaluations = 0
        retried, verified, cost = False, True, 0.0
        registration_information = None
        if first:
            pose = self._initial if self._initial is not None else np.zeros(cfg.dof)
            fitness, inlier, rmse = 0.0, 1.0, 0.0
        else:
            target = kg.ensure_target(self.poses[-1])
            guesses, half = self.seeds(frame)
            bounds = np.column_stack([guesses.min(0) - half, guesses.max(0) + half])
            res = harmony_icp(scan, target, bounds=bounds, initial_guesses=guesses,
                              config=cfg.registration, rng=self.rng)
            self.costs.registration(res.evaluations)
            res, widened, matched = self.search.widened(scan, target, res, guesses, half, self.rng)
            self.odometry.learn_bias(frame, res, self.poses[-1])
            use_prior = not self._prior_contradicted(frame, res)
            checked, retried, verified = self._verify(frame, scan, res, use_prior)
            res, verified = self.search.settled(res, checked, verified)
            retried, verified = retried or widened, verified and (matched or self.search.passes(res))
            if times is not None:
                res, scan = self._refine_sweep(scan, times, target, res)
            self.odometry.learn_scale(frame, res)
            self.odometry.accumulate_wheel(frame)  # with the bias and scale the prediction below uses
            pred = self.prediction(frame, use_prior=use_prior)
            pose, information, registration_information = self.verifier.fuse(res, pred)
            fitness, inlier, rmse, evaluations, cost = (res.fitness, res.inlier_ratio, res.rmse, res.evaluations,
                                                        res.cost)
        keyframe = first or (verified and (len(self.poses) < cfg.warmup_frames or kg.is_keyframe(pose)))
        if self.motions is not None:
            self.motions.record(frame, scan, self.poses[-1] if self.poses else pose, pose)
        self.poses.append(pose)
        self.stamps.append(float(frame.stamp))
        kg.attach(pose, keyframe)
        if keyframe and kg.add_keyframe(frame, len(self.results), scan, pose, None if first else information,
                                        registration_information):
            self._reanchor_recent()
        if keyframe and not first:
            self._floor_prior()
        self.odometry.advance(frame, relative(self.poses[-2], pose) if len(self.poses) >= 2 else None)
        if keyframe:
            # the next frame's target, built in the keyframe's step: the next frame only tracks
            kg.ensure_target(self.poses[-1])
        result = FrameResult(frame.index, float(frame.stamp), pose, float(fitness), float(inlier), float(rmse),
                             int(evaluations), time.perf_counter() - t0, bool(keyframe), len(scan), len(kg.map),
                             retried, verified, float(cost))
        self.results.append(result)
        if not first:
            self.search.record(result.inlier_ratio, result.verified)
        return result

    def _floor_prior(self) -> None:
        """6-DOF runs seeded by a prior (``level_floor``): the newest keyframe's height, roll and pitch held near the
        first pose's (:data:`FLOOR_SIGMA`), a unary edge of the pose graph."""
        if not self.config.level_floor or self.config.dof != 6 or self._prior is None or len(self.graph) < 2:
            return
        k = len(self.graph) - 1
        level = self.graph.poses[k].copy()
        level[2:5] = self.poses[0][2:5]
        info = np.full(6, 1e-9)  # x, y and yaw: nothing said
        info[2] = 1.0 / FLOOR_SIGMA[0] ** 2
        info[3:5] = 1.0 / FLOOR_SIGMA[1] ** 2
        self.graph.add_edge(k, k, level, np.diag(info), EdgeKind.PRIOR, robust=False)

    def _deskews(self, frame: Frame) -> bool:
        return self.config.deskew and self.config.dof == 6 and frame.point_times is not None

    def _refine_sweep(self, scan: NDArray[np.float64], times: NDArray[np.float64], target: RegistrationTarget,
                      res: RegistrationResult) -> tuple[RegistrationResult, NDArray[np.float64]]:
        """The registration and the scan (N, 3) refined with the motion over the sweep
        (:func:`hsmap.deskew.refine_sweep`) where that aligns the scan better; else both as they are."""
        reg = self.config.registration
        ref = refine_sweep(scan, times, target, res.pose, threshold=reg.threshold, robust_kernel=reg.robust_kernel)
        self.costs.add(refinements=1)
        if not ref.improved:
            return res, scan
        pose = ref.pose.copy()
        pose[3:] = res.pose[3:] + wrap_angle(pose[3:] - res.pose[3:])
        return replace(res, pose=pose, transformation=pose_to_matrix(pose)), ref.points

    def deskewed(self, frame: Frame) -> Frame:
        """The frame with its cloud (6-DOF) or its 2D scan (3-DOF) moved to its stamp, with ``deskew``
        (:func:`hsmap.deskew.deskew_frame`, :func:`hsmap.deskew2d.deskew_scan_frame`; a 2D scan's motion from
        the input's odometry track where there is one); frames without point or beam times are returned as they
        are."""
        if not self.config.deskew:
            return frame
        odom = self.odometry.previous if self.config.use_odometry else None
        if self.config.dof == 3:
            if frame.scan2d is None or frame.scan2d.times is None:
                return frame
            return deskew_scan_frame(frame, prior=self._odometry_track, previous_stamps=self.stamps[-2:],
                                     previous_poses=self.poses[-2:], previous_odometry=odom)[0]
        if frame.point_times is None:
            return frame
        return deskew_frame(frame, prior=self._prior, previous_stamps=self.stamps[-2:],
                            previous_poses=self.poses[-2:], previous_odometry=odom)[0]

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
            odometry, sigma, scan = self.motions.arrays()
            t0 = time.perf_counter()
            self._smoothing = smooth_with_odometry(self.graph_trajectory.poses, odometry, sigma, scan)
            self.motions.seconds += time.perf_counter() - t0

    # ------------------------------------------------------------------------------------------ results
    def odometry_summary(self) -> dict:
        """The learned odometry model (JSON-ready)."""
        return self.odometry.summary()

    def loop_summary(self) -> dict:
        """Loop-closure counts (JSON-ready)."""
        return self.keyframe_graph.summary()

    def smoothing_summary(self) -> dict:
        """What the smoothing measured and did (JSON-ready), or why it did nothing."""
        if self._smoothing is not None:
            return self._smoothing.as_dict() | {"seconds": self.motions.seconds}
        cfg = self.config
        why = ("off (slam.smoothing: false)" if not cfg.smoothing else "not applicable: 6-DOF" if cfg.dof != 3
               else "not applicable: seeded by a prior trajectory" if self._prior is not None
               else "not run (finish() was not called)")
        return {"status": why}

    def global_map(self) -> VoxelMap:
        """The point map of every keyframe at its current (optimised) pose."""
        return self.keyframe_graph.global_map()

    @property
    def trajectory(self) -> Trajectory:
        """Every frame's pose: after :meth:`finish`, the smoothed one (``SlamConfig.smoothing``); before it, or
        where the smoothing did nothing, :attr:`graph_trajectory`."""
        if self._smoothing is not None and self._smoothing.status == "ok":
            return Trajectory(np.asarray(self.stamps), self._smoothing.poses.copy())
        return self.graph_trajectory

    @property
    def graph_trajectory(self) -> Trajectory:
        """Every frame's pose at the current estimate of its keyframe (loop closures included)."""
        return self.keyframe_graph.graph_trajectory(np.asarray(self.stamps))

    @property
    def tracked_trajectory(self) -> Trajectory:
        """Every frame's pose from the tracking alone: the keyframes chained by their tracking edges."""
        return self.keyframe_graph.tracked_trajectory(np.asarray(self.stamps))
