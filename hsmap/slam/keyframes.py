"""HS-SLAM's keyframe graph (:class:`KeyframeGraph`): the pose graph of keyframes and its edges (tracking, wheel,
scan-to-scan pairs, loops), the loop closer, when to optimise, and the maps built from the keyframes (the tracking
map, its registration target and search field, the global map)."""

from __future__ import annotations

import warnings

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from ..datasets.frames import Frame
from ..errors import HsmapWarning
from ..geometry import compose, pose_to_matrix, relative, transform_points, wrap_angle
from ..maps.mapping import VoxelMap, voxel_downsample
from ..registration.fitness import DistanceField
from ..registration.icp import (
    Refinement,
    RegistrationConfig,
    RegistrationTarget,
    alignment_information,
    refine_icp,
)
from ..registration.information import drop_degenerate
from ..registration.normals import estimate_normals, load_3d_estimator, orient_normals
from ..trajectory import Trajectory
from .config import SlamConfig
from .costs import Costs
from .frames import frame_points, grazing_where_sparse
from .loopclosure import LoopCloser
from .odometry import OdometryModel
from .posegraph import EdgeKind, PoseGraph, information_with_floor
from .submaps import Keyframe, keyframe_voxel_map

__all__ = ["KeyframeGraph", "pair_match"]


def pair_match(source: NDArray[np.float64], target: RegistrationTarget, guess: NDArray[np.float64],
               registration: RegistrationConfig, iterations: int, min_inlier_ratio: float
               ) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """``source`` (N, dim) refined against one other scan from a close ``guess``: the relative pose and its
    information, or None where less than ``min_inlier_ratio`` of the points overlap."""
    reg = registration
    z = refine_icp(source, target, guess, max_distance=reg.threshold, iterations=iterations,
                   method=reg.refinement, robust_kernel=reg.robust_kernel)
    info, _, n = alignment_information(source, target, z, reg.threshold, reg.robust_kernel)
    if n < min_inlier_ratio * len(source):
        return None
    return z, info


class KeyframeGraph:
    """The keyframes of a run: their pose graph, the loop closer, and the maps made of them.

    Parameters
    ----------
    config : SlamConfig
        ``graph`` (edges, searches, optimisation), ``loop_closure`` (the loop closer; off: one global map).
    odometry : OdometryModel
        Gives the wheel edges.
    loop_rng : numpy.random.Generator
        The loop closer's random stream.
    costs : Costs, optional
        Counts the work: loop searches, pair edges, optimisations, points put in the tracking map.

    Attributes
    ----------
    graph : PoseGraph
        One node per keyframe.
    keyframes : list of Keyframe
    map : VoxelMap
        The tracking map (the keyframes near the newest one along the graph, at their current poses).
    target : RegistrationTarget or None
        The next registration's target (None: to be rebuilt, :meth:`ensure_target`).
    """

    def __init__(self, config: SlamConfig, odometry: OdometryModel, loop_rng: np.random.Generator, *,
                 costs: Costs | None = None) -> None:
        self.config = config
        self.costs = costs if costs is not None else Costs()
        cfg, lc = config, config.loop_closure
        self.dim = cfg.dim
        if self.dim == 3:
            load_3d_estimator()  # with the graph, not in its first keyframe's step
        self.odometry = odometry
        self._loop_rng = loop_rng
        self.graph = PoseGraph(cfg.dof, solver=cfg.graph.solver)
        self.keyframes: list[Keyframe] = []
        self.map = VoxelMap(self.dim, cfg.effective_map_voxel(), average=cfg.map_average)
        self.target: RegistrationTarget | None = None
        self._field: DistanceField | None = None
        self._field_centre = np.zeros(self.dim)
        self.last_key: NDArray[np.float64] | None = None
        self._anchor: list[int] = []  # per frame: the keyframe its pose is expressed in
        self._offset: list[NDArray[np.float64]] = []  # per frame: its pose in that keyframe's frame
        self._tracking_chain: list[NDArray[np.float64]] = []  # per keyframe: the tracking edge's measurement
        # a sensor carried by hand (6-DOF, no prior): every loop match confirmed before it becomes an edge
        share = cfg.min_inlier_share if cfg.dof == 6 and not odometry.prior else None
        self.closer = (LoopCloser(lc, cfg.dof, cfg.effective_map_voxel(), map_average=cfg.map_average,
                                  recent_share=share) if lc.enabled else None)
        self._path: NDArray[np.float64] | None = None  # graph distances from the newest keyframe
        self._map_stale = False
        self._pending = 0  # loop and pair edges added since the last optimisation
        self._keyframe_targets: dict[int, RegistrationTarget] = {}  # for pair edges
        self._since_optimized = 0
        self._status = "ok" if lc.enabled else "disabled"
        self._optimizations = 0
        self._rejected = 0
        self._failure = ""

    # ------------------------------------------------------------------------------------------ frames
    def is_keyframe(self, pose: NDArray[np.float64]) -> bool:
        """Whether the robot moved or turned enough since the newest keyframe."""
        cfg = self.config
        d = relative(self.last_key, pose)
        return bool(np.linalg.norm(d[: self.dim]) >= cfg.effective_keyframe_distance()
                    or np.abs(wrap_angle(d[self.dim:])).max() >= cfg.effective_keyframe_angle())

    def attach(self, pose: NDArray[np.float64], keyframe: bool) -> None:
        """Express a new frame's pose in its keyframe's frame: the new keyframe's, or the newest one's."""
        if keyframe:
            self._anchor.append(len(self.keyframes))
            self._offset.append(np.zeros(self.config.dof))
        else:
            k = len(self.keyframes) - 1
            self._anchor.append(k)
            self._offset.append(relative(self.graph.poses[k], pose))

    def pose_of(self, i: int) -> NDArray[np.float64]:
        """Frame ``i``'s pose at its keyframe's current estimate."""
        return compose(self.graph.poses[self._anchor[i]], self._offset[i])

    def add_keyframe(self, frame: Frame, number: int, scan: NDArray[np.float64], pose: NDArray[np.float64],
                     information: NDArray[np.float64] | None,
                     registration_information: NDArray[np.float64] | None = None) -> bool:
        """A new keyframe (the run's frame ``number``): a graph node tied to the previous one, points in the
        tracking map, pair edges and a loop search.

        ``information``: the fused pose's (the tracking edge's); ``registration_information``: the registration's
        alone, which the tracking edge holds instead where a wheel edge carries the odometry. Returns whether the
        graph's poses changed (the caller re-anchors its recent poses).
        """
        cfg = self.config
        dense, normals = keyframe_points(frame, scan, cfg)
        k = self.graph.add_node(pose)
        if k > 0:
            self._tracking_chain.append(_tracking_edges(self.graph, self.odometry, pose, information,
                                                        registration_information))
        self.odometry.restart_wheel(frame)
        self.keyframes.append(Keyframe(number, float(frame.stamp), dense, normals))
        T = pose_to_matrix(pose)
        world = transform_points(T, dense)
        added, added_normals = self.map.add(world, normals @ T[: self.dim, : self.dim].T, return_normals=True)
        self.costs.add(points_inserted=len(world))
        if self._field is not None and len(added):
            self._field.add(added, added_normals if self._field.keeps_nearest else None)
        self.last_key = pose
        self.target = None  # the refinement target (KD-tree) is rebuilt before the next registration
        if self.closer is None:
            return False
        self._pair_edges(k)
        self._path = self.graph.path_distances(k)
        return self._close_loops(k)

    # ------------------------------------------------------------------------------------------- edges
    def _pair_edges(self, k: int) -> None:
        """Scan-to-scan edges from keyframe ``k`` to the earlier keyframes that overlap it."""
        gc, lc = self.config.graph, self.config.loop_closure
        if gc.pair_edges <= 0 or k < 2:
            return
        P = np.asarray(self.graph.poses)
        dist = np.linalg.norm(P[: k - 1, : self.dim] - P[k, : self.dim], axis=1)
        near = np.flatnonzero(dist <= gc.pair_distance)
        if not len(near):
            return
        # the keyframe at the scan voxel, as the tracking registers a scan
        source = self.keyframes[k].points
        if self.config.dof == 6:
            source = voxel_downsample(source, self.config.effective_scan_voxel())
        for i in near[np.argsort(dist[near], kind="stable")][: gc.pair_edges]:
            match = pair_match(source, self.keyframe_target(int(i)), relative(P[i], P[k]),
                               self.config.registration, gc.pair_iterations, lc.min_inlier_ratio)
            self.costs.add(refinements=1)
            if match is None:
                continue  # too little overlap
            z, info = match
            info = information_with_floor(drop_degenerate(info, lc.degenerate_ratio), lc.edge_sigma_translation,
                                          lc.edge_sigma_rotation)
            self.graph.add_edge(int(i), k, z, info, EdgeKind.PAIR)
            self._pending += 1

    def keyframe_target(self, i: int) -> RegistrationTarget:
        """Keyframe ``i``'s points and normals, prepared for registrations against it (built once)."""
        target = self._keyframe_targets.get(i)
        if target is None:
            kf = self.keyframes[i]
            target = self._keyframe_targets[i] = RegistrationTarget(kf.points, self.config.registration,
                                                                    normals=kf.normals)
        return target

    def _close_loops(self, k: int) -> bool:
        """Loop searches from keyframe ``k``; optimise when a closure corrects much or enough edges wait."""
        gc = self.config.graph
        closer = self.closer
        urgent = False
        searches, far, registrations, evaluations = (closer.attempts, closer.far_attempts, closer.registrations,
                                                     closer.evaluations)
        lc = self.config.loop_closure
        search = k % lc.search_every == 0
        for cand in closer.candidates(self.graph, k, self._path)[: lc.attempts_per_keyframe if search else 0]:
            closure = closer.attempt(self.graph, self.keyframes, k, cand, self._loop_rng)
            if closure is None:
                continue
            self.graph.add_edge(closure.i, closure.j, closure.measurement, closure.information, EdgeKind.LOOP)
            self._pending += 1
            urgent |= (closure.correction_translation > gc.optimize_threshold_translation
                       or closure.correction_rotation > gc.optimize_threshold_rotation)
        if k % lc.far_every == 0:
            closure = closer.attempt_far(self.graph, self.keyframes, k,
                                         closer.far_candidates(self.graph, k, self._path), self._path,
                                         self._loop_rng)
            for c in [] if closure is None else closer.corroborate(closure, self.graph):
                self.graph.add_edge(c.i, c.j, c.measurement, c.information, EdgeKind.LOOP, robust=False)
                self._pending += 1
                urgent = True
        self.costs.add(loop_searches=closer.attempts - closer.far_attempts - (searches - far),
                       far_searches=closer.far_attempts - far, registrations=closer.registrations - registrations,
                       harmony_evaluations=closer.evaluations - evaluations)
        self._since_optimized += 1
        if self._pending and (urgent or self._since_optimized >= gc.optimize_every):
            return self.optimize()
        return False

    def optimize(self) -> bool:
        """Optimise the graph and mark the tracking map stale; returns whether the keyframes' poses changed."""
        if self._status == "failed" or len(self.graph) < 2:
            return False
        before = self.graph.poses.copy()
        out = self.graph.optimize()
        self._optimizations += 1
        self.costs.add(optimizations=1, optimization_rounds=out.rounds, optimization_iterations=out.iterations_total)
        self._pending = 0
        self._since_optimized = 0
        if out.status != "ok":
            self._fail(out.message)
            return True
        self._rejected += len(out.rejected)
        after = np.asarray(self.graph.poses)
        moved = after - before
        moved[:, self.dim:] = wrap_angle(moved[:, self.dim:])
        if np.abs(moved).max() < 1e-6:
            return False
        self.closer.forget()
        self.last_key = self.graph.poses[-1].copy()
        self._path = self.graph.path_distances(len(self.graph) - 1)
        self._map_stale = True
        self.target = None
        return True

    def _fail(self, message: str) -> None:
        """The graph could not be optimised: back to the tracking-only poses, no more loop closures."""
        warnings.warn(f"pose graph optimisation failed ({message}); keeping the tracking-only trajectory and "
                      f"closing no more loops", HsmapWarning, stacklevel=4)
        self._status = "failed"
        self._failure = message
        self.closer = None
        self.graph.poses = [p.copy() for p in _chained(self.graph.poses[0].copy(), self._tracking_chain)]
        for e in self.graph.edges:
            if e.kind.matched:
                e.active = False
        self.last_key = self.graph.poses[-1].copy()
        self._path = None
        self._map_stale = True
        self.target = None

    def finish(self) -> bool:
        """Optimise once more if edges are pending; returns whether the keyframes' poses changed."""
        if self.closer is not None and self._pending:
            return self.optimize()
        return False

    def summary(self) -> dict:
        """Loop-closure counts for the metrics: status, closures, attempts, rejections, optimisations."""
        return _summary(self)

    # -------------------------------------------------------------------------------------------- maps
    def _tracking_keyframes(self) -> list[int]:
        if self.closer is None or self._path is None:
            return list(range(len(self.keyframes)))
        near = np.flatnonzero(self._path[: len(self.keyframes)] <= self.config.graph.tracking_path_distance)
        return near.tolist()

    def _rebuild_map(self, centre: NDArray[np.float64]) -> None:
        """The tracking map anew from the tracking keyframes at their current poses, for a target centred here.

        With loop closure only the points that crops within ``local_map_radius`` of poses at most half of it from
        ``centre`` can hold are kept (and a margin of two voxel diagonals); without it the map keeps everything.
        """
        within = None
        if self.closer is not None:
            voxel = self.config.effective_map_voxel()
            within = (centre, 1.5 * self.config.local_map_radius + 2 * voxel * np.sqrt(self.dim))
        which = self._tracking_keyframes()
        self.map = self._keyframe_map(which, within=within)
        self._map_stale = False
        self.costs.add(map_rebuilds=1, points_inserted=sum(len(self.keyframes[k].points) for k in which))

    def _keyframe_map(self, which, within: tuple[NDArray[np.float64], float] | None = None) -> VoxelMap:
        """A voxel map of the given keyframes at their current poses (the first point or the mean per voxel)."""
        which = list(which)
        return keyframe_voxel_map([self.graph.poses[k] for k in which], self.keyframes, which, self.dim,
                                  self.config.effective_map_voxel(), average=self.config.map_average, within=within)

    def ensure_target(self, pose: NDArray[np.float64]) -> RegistrationTarget:
        """The registration target around ``pose``: the local map crop (points, normals) and the search field
        (rebuilt from the map when the robot nears its edge)."""
        if self.target is not None:
            return self.target
        cfg = self.config
        reg = cfg.registration
        centre = pose[: self.dim]
        recentre = self._field is None or np.linalg.norm(centre[:2] - self._field_centre[:2]) > cfg.local_map_radius / 2
        if self._map_stale or (recentre and self.closer is not None):
            self._rebuild_map(centre)
            recentre = True
        pts, normals = self.map.crop_with_normals(centre, cfg.local_map_radius)
        if recentre:
            self._field = search_field(pts, normals, centre, cfg, recycle=self._field)
            self._field_centre = centre.copy()
        self.target = RegistrationTarget(pts, reg, normals=normals, fields={reg.search_threshold: self._field})
        self.target.prepare()
        return self.target

    def global_map(self) -> VoxelMap:
        """The point map of every keyframe at its current (optimised) pose."""
        return self._keyframe_map(range(len(self.keyframes)))

    def graph_trajectory(self, stamps: NDArray[np.float64]) -> Trajectory:
        """Every frame's pose (at ``stamps``) at the current estimate of its keyframe."""
        P = compose(self.graph.poses[np.asarray(self._anchor, dtype=int)], np.asarray(self._offset))
        return Trajectory(np.asarray(stamps), np.asarray(P).reshape(-1, self.config.dof))

    def tracked_trajectory(self, stamps: NDArray[np.float64]) -> Trajectory:
        """Every frame's pose from the tracking alone: the keyframes chained by their tracking edges."""
        chain = _chained(self.graph.poses[0], self._tracking_chain) if self.keyframes else []
        P = compose(np.asarray(chain)[np.asarray(self._anchor, dtype=int)], np.asarray(self._offset))
        return Trajectory(np.asarray(stamps), np.asarray(P).reshape(-1, self.config.dof))


def keyframe_points(frame: Frame, scan: NDArray[np.float64], cfg: SlamConfig
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A keyframe's points and normals in its own frame: the ``scan`` in 2D (normals grazing where the scan is
    sparse, turned to the laser for the loop closer's same-side check), the frame's dense points in 3D."""
    dense = scan if cfg.dof == 3 else frame_points(frame, cfg.dof, cfg.min_range, cfg.max_range,
                                                   voxel=cfg.effective_map_voxel())
    if cfg.dof == 3:
        tree = cKDTree(dense)  # the normals' neighbours and the sampling check's nearest ones
        normals = estimate_normals(dense, tree=tree)
        if frame.scan2d is not None:
            normals = grazing_where_sparse(dense, normals, frame, cfg.effective_map_voxel(), tree)
        if cfg.loop_closure.same_side:
            # facing the laser: a loop match then tells a wall's face from the face behind it
            normals = orient_normals(dense, normals, frame.extrinsic2d[:2])
    else:
        normals = estimate_normals(dense)
    return dense, normals


def search_field(pts: NDArray[np.float64], normals: NDArray[np.float64], centre: NDArray[np.float64],
                 cfg: SlamConfig, *, recycle: DistanceField | None = None) -> DistanceField:
    """The tracking's search field of the local map crop ``pts`` around ``centre``: ``local_map_radius`` plus the
    search threshold each way (and the crop's heights and a metre in 3D), reusing ``recycle``'s memory."""
    reg, dim = cfg.registration, cfg.dim
    half = cfg.local_map_radius + reg.search_threshold
    lo = np.r_[centre[:2] - half, pts[:, 2].min() - 1.0] if dim == 3 else centre[:2] - half
    hi = np.r_[centre[:2] + half, pts[:, 2].max() + 1.0] if dim == 3 else centre[:2] + half
    res = reg.field_resolution or (max(0.02, reg.search_threshold / 10) if dim == 2
                                   else reg.search_threshold / 3)
    # 2D: nearest points for the refinement; 3D refines on exact correspondences
    plane = dim == 2 and reg.refinement is Refinement.POINT_TO_PLANE
    return DistanceField(pts, res, reg.search_threshold, bounds=[lo, hi], normals=normals if plane else None,
                         recycle=recycle)


def _chained(first: NDArray[np.float64], steps: list[NDArray[np.float64]]) -> list[NDArray[np.float64]]:
    """``first`` and the poses that composing ``steps`` one after the other reaches from it."""
    chain = [first]
    for z in steps:
        chain.append(compose(chain[-1], z))
    return chain


def _summary(kg: KeyframeGraph) -> dict:
    """A keyframe graph's loop-closure counts for the metrics: status, closures, attempts, rejections,
    optimisations."""
    closer = kg.closer
    loops = kg.graph.loop_edges(active_only=True)
    return {
        "status": kg._status,
        "loops_closed": len(loops),
        "pair_edges": sum(e.kind == EdgeKind.PAIR and e.active for e in kg.graph.edges),
        "wheel_edges": sum(e.kind == EdgeKind.WHEEL for e in kg.graph.edges),
        "wheel_edges_down_weighted": kg.odometry.wheel_gated,
        "attempts": 0 if closer is None else closer.attempts,
        "rejected_by_checks": {} if closer is None else dict(closer.rejections),
        "far_attempts": 0 if closer is None else closer.far_attempts,
        "far_closures": 0 if closer is None else closer.far_accepted,
        "rejected_by_graph": kg._rejected,
        "optimizations": kg._optimizations,
        "keyframes": len(kg.keyframes),
        "message": kg._failure,
    }


def _tracking_edges(graph: PoseGraph, odometry: OdometryModel, pose: NDArray[np.float64],
                    information: NDArray[np.float64] | None,
                    registration_information: NDArray[np.float64] | None) -> NDArray[np.float64]:
    """The edges from the graph's previous node to its newest one, at ``pose``: the tracking edge (the fused
    pose's ``information``, or the registration's alone where a wheel edge carries the odometry) and the wheel
    edge where the odometry gives one. Returns the tracking edge's measurement."""
    k = len(graph) - 1
    z = relative(graph.poses[k - 1], pose)
    info = information if information is not None else np.zeros((graph.dof,) * 2)
    wheel = None
    if registration_information is not None and odometry.wheel_motion is not None:
        wheel = odometry.wheel_edge(z, registration_information)
    if wheel is not None:
        # the wheels are a sensor of their own: the tracking edge keeps the registration's information
        info = registration_information
    graph.add_edge(k - 1, k, z, info, EdgeKind.ODOMETRY)
    if wheel is not None:
        graph.add_edge(k - 1, k, *wheel, EdgeKind.WHEEL)
    return z
