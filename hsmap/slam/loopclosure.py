"""Loop closure for HS-SLAM: submaps of keyframes, candidate search, Harmony-ICP matching and verification.

A *submap* is a run of ``submap_keyframes`` consecutive keyframes whose points are expressed in the frame of its
first keyframe (the anchor), at the keyframes' current pose estimates. When a new keyframe arrives, older
submaps that may overlap it are loop-closure candidates: a submap qualifies when it is at least
``min_separation`` keyframes older than the newest one (nearer ones are tied to it by tracking already) and one of
its keyframes lies within ``max_distance`` of the new keyframe's estimate, widened by the search window.

The search window grows with the uncertainty of the two places' relative pose, measured by the length of the
shortest path between them in the pose graph (:meth:`hsmap.slam.posegraph.PoseGraph.path_distances`): the window's
half-width is ``window_translation + window_growth * path`` (and the same for the rotation), up to a maximum
(Cartographer searches 7 m x 7 m x 30 deg). Harmony-ICP needs no initial guess inside that window, which is what
closing a loop needs; a wide window seeds the harmony memory with a grid of guesses over it.

A match becomes a loop edge only if it passes every check: enough inliers, not pinned against the window's edge
(the true pose may lie outside), and well constrained in every direction (a corridor's axis is not: the
registration's covariance along it is large). The pose graph's robust kernel and chi-square gate then remove
closures that disagree with the rest of the graph.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from ..errors import ConfigError
from ..geometry import compose, pose_to_matrix, relative, transform_points, wrap_angle
from ..registration.correlative import correlative_match_2d
from ..registration.harmony import HarmonyConfig
from ..registration.icp import (
    RegistrationConfig,
    RegistrationResult,
    RegistrationTarget,
    drop_degenerate,
    harmony_icp,
)
from ..registration.information import safe_inverse
from .posegraph import PoseGraph, information_with_floor
from .submaps import Keyframe, keyframe_voxel_map

__all__ = ["LoopClosureConfig", "Keyframe", "LoopCandidate", "LoopClosure", "LoopCloser", "correlative_match_2d",
           "keyframe_voxel_map", "same_side_share"]


def _loop_registration() -> RegistrationConfig:
    return RegistrationConfig(
        harmony=HarmonyConfig(batch_size=16, max_iterations=500, patience=20, convergence_tol=1e-6, init="lhs"),
        search_threshold=0.5,
        threshold=0.1,
        max_points=300,
        robust_kernel=0.07,
    )


@dataclass
class LoopClosureConfig:
    """Loop-closure candidates, matching and verification (lengths in metres, angles in radians).

    Attributes
    ----------
    enabled : bool
        Search for loop closures and optimise the pose graph (off: tracking only, against one global map).
    attempts_per_keyframe : int
        Loop-closure submaps matched per new keyframe at most (the nearest first).
    search_every : int
        Search for loops at every this many keyframes.
    far_every : int
        Far loop search (``far_search``) at every this many keyframes.
    submap_keyframes : int
        Keyframes per submap (the loop-closure targets).
    source_keyframes : int
        The newest keyframe and up to this many - 1 before it form the source cloud matched against a submap.
    min_separation : int
        A submap is a candidate only if its newest keyframe is at least this many keyframes older than the newest.
    max_distance : float
        A submap is a candidate if one of its keyframes lies within this distance (plus the window's half-width).
    window_translation, window_growth, max_window_translation : float
        Half-width of the search window in x and y: ``window_translation + window_growth * path``, at most
        ``max_window_translation``; ``path`` is the graph distance between the two places.
    window_rotation, window_rotation_growth, max_window_rotation : float
        The same for yaw (radians, radians per metre of path).
    window_z, window_roll_pitch : float
        6-DOF: fixed half-widths in z and in roll/pitch.
    retry_after : int
        A submap that was matched is not tried again before this many more keyframes.
    min_inlier_ratio : float
        A match (and a pair edge) needs at least this fraction of the source points within the registration
        threshold.
    max_sigma_translation, max_sigma_rotation : float
        A match must constrain every direction: its standard deviation along the worst translation (rotation)
        direction at most these.
    degenerate_ratio : float
        Directions with less than this fraction of the best one's information count as unconstrained
        (:func:`hsmap.registration.icp.drop_degenerate`).
    edge_sigma_translation, edge_sigma_rotation : float
        Floors added to the covariance of every edge: registration information counts every point as independent.
    registration : RegistrationConfig
        Harmony-ICP parameters of the loop matches.
    same_side : bool
        2D: a match that would move the graph by more than ``registration.threshold`` counts its inliers only
        where the target was seen from the match's own side (:func:`same_side_share`), rejecting a wall's face
        matched to the face behind it.
    far_search : bool
        2D: also search submaps the regular window cannot cover (a return after a long excursion), exhaustively
        (:func:`correlative_match_2d`) with the recent path as source; kept only when a second far match agrees.
    far_source_path : float
        Graph distance from the newest keyframe within which keyframes form a far search's source.
    max_far_window_translation : float
        Largest half-width of a far search in x and y (a bound on its cost).
    far_window_growth : float
        A far search's half-width in x and y is ``window_translation + far_window_growth * path``.
    far_resolution, far_angle_step : float
        Grid resolution (m) and rotation step (rad) of the exhaustive search.
    far_ambiguity : float
        A far match is ambiguous (a look-alike place) when the best pose more than 2 m from it scores at least
        this fraction of its score.
    far_corroborate_within : int
        A far match becomes a loop edge only when a second far match from a keyframe at most this many keyframes
        apart agrees with it.
    far_agreement_translation, far_agreement_rotation : float
        How closely the two far matches must agree, once both are carried to one keyframe by the tracking.
    """

    enabled: bool = True
    attempts_per_keyframe: int = 1
    search_every: int = 1
    far_every: int = 5
    submap_keyframes: int = 10
    source_keyframes: int = 3
    min_separation: int = 20
    max_distance: float = 3.0
    window_translation: float = 0.3
    window_growth: float = 0.05
    max_window_translation: float = 3.5
    window_rotation: float = float(np.deg2rad(3.0))
    window_rotation_growth: float = float(np.deg2rad(0.3))
    max_window_rotation: float = float(np.deg2rad(30.0))
    window_z: float = 0.1
    window_roll_pitch: float = float(np.deg2rad(2.0))
    retry_after: int = 5
    min_inlier_ratio: float = 0.6
    max_sigma_translation: float = 0.05
    degenerate_ratio: float = 0.05
    max_sigma_rotation: float = float(np.deg2rad(1.0))
    edge_sigma_translation: float = 0.005
    edge_sigma_rotation: float = float(np.deg2rad(0.1))
    registration: RegistrationConfig = field(default_factory=_loop_registration)
    same_side: bool = True
    far_search: bool = True
    max_far_window_translation: float = 100.0
    far_window_growth: float = 0.1
    far_source_path: float = 20.0
    far_resolution: float = 0.2
    far_angle_step: float = float(np.deg2rad(1.0))
    far_ambiguity: float = 0.9
    far_corroborate_within: int = 20
    far_agreement_translation: float = 0.5
    far_agreement_rotation: float = float(np.deg2rad(2.0))

    def __post_init__(self) -> None:
        if isinstance(self.registration, dict):
            from ..config import from_dict

            self.registration = from_dict(RegistrationConfig, self.registration, "slam.loop_closure.registration")
        for name in ("max_distance", "window_translation", "window_growth", "max_window_translation",
                     "window_rotation", "window_rotation_growth", "max_window_rotation", "window_z",
                     "window_roll_pitch", "max_sigma_translation", "max_sigma_rotation", "edge_sigma_translation",
                     "edge_sigma_rotation", "max_far_window_translation",
                     "far_source_path", "far_window_growth",
                     "far_agreement_translation", "far_agreement_rotation"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float, np.floating)) and np.isfinite(v) and v >= 0):
                raise ConfigError(f"slam.loop_closure.{name} must be a finite number >= 0, got {v!r}")
        for name in ("edge_sigma_translation", "edge_sigma_rotation", "far_resolution", "far_angle_step"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float, np.floating)) and np.isfinite(v) and v > 0):
                raise ConfigError(f"slam.loop_closure.{name} must be a finite number > 0, got {v!r}")
        if not 0.0 < self.far_ambiguity <= 1.0:
            raise ConfigError(f"slam.loop_closure.far_ambiguity must be in (0, 1], got {self.far_ambiguity!r}")
        if not 0.0 <= self.min_inlier_ratio <= 1.0:
            raise ConfigError(f"slam.loop_closure.min_inlier_ratio must be in [0, 1], got {self.min_inlier_ratio!r}")
        for name in ("attempts_per_keyframe", "search_every", "far_every", "submap_keyframes", "source_keyframes",
                     "min_separation", "retry_after", "far_corroborate_within"):
            v, low = getattr(self, name), 1
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < low:
                raise ConfigError(f"slam.loop_closure.{name} must be an integer >= {low}, got {v!r}")


@dataclass
class LoopCandidate:
    submap: int
    distance: float  # predicted distance (m) to the nearest keyframe of the submap
    path: float  # graph distance (m)


@dataclass
class LoopClosure:
    """An accepted (verified) loop match: the pose of keyframe ``j`` in the frame of keyframe ``i``."""

    i: int
    j: int
    measurement: NDArray[np.float64]
    information: NDArray[np.float64]
    correction_translation: float  # how far the measurement is from the graph's estimate
    correction_rotation: float
    registration: RegistrationResult


def same_side_share(source: NDArray[np.float64], origins: NDArray[np.float64], target: RegistrationTarget,
                    pose: NDArray[np.float64], threshold: float) -> float:
    """Share of ``source``'s points that, at ``pose``, lie within ``threshold`` of a target point seen from
    their own side.

    ``origins`` holds each source point's sensor position (source frame); ``target``'s normals face the sensors
    that saw them (:func:`hsmap.registration.icp.orient_normals`). A wall's face matched to the face behind it, seen
    from the next room, is matched from the wrong side: a match that slides a scan by a wall's thickness
    explains as much of it as the true one (in simulated offices with a 180 deg laser, ten of ten such false
    closures matched 60-94 % of their scans, 0-54 % from the right side; the 41 true ones lost 0-17 points in
    100, half of them 3 or fewer).
    """
    if not len(source):
        return 0.0
    T = pose_to_matrix(pose)
    moved = transform_points(T, source)
    eye = transform_points(T, origins)
    d, idx = target.nearest(moved, threshold)
    ok = np.isfinite(d)
    q = target.points[idx[ok]]
    same = np.einsum("ij,ij->i", target.normals[idx[ok]], eye[ok] - q) > 0.0
    return float(np.count_nonzero(same)) / len(source)


class LoopCloser:
    """Finds and verifies loop closures between the newest keyframe and older submaps.

    Parameters
    ----------
    config : LoopClosureConfig
    dof : int
        3 or 6.
    map_voxel : float
        Voxel size at which submaps thin their points.
    map_average : bool
        Submaps keep each voxel's mean point (:class:`hsmap.maps.mapping.VoxelMap`), like the tracking map.
    recent_share : float, optional
        Confirm every match that passes the checks before it becomes a loop edge (:meth:`confirmed`): it must
        match at least this share of the inliers that the source matches against the keyframes just before it,
        and a second search of the same window must agree with it. None: no confirmation.
    """

    def __init__(self, config: LoopClosureConfig, dof: int, map_voxel: float, cache_size: int = 48, *,
                 map_average: bool = False, recent_share: float | None = None) -> None:
        self.config = config
        self.dof = dof
        self.dim = 2 if dof == 3 else 3
        self.map_voxel = map_voxel
        self.map_average = map_average
        self.recent_share = recent_share
        self._cache: OrderedDict[int, tuple[NDArray[np.float64], RegistrationTarget]] = OrderedDict()
        self._cache_size = cache_size
        self._last_try: dict[int, int] = {}
        self.attempts = 0
        self.accepted = 0
        self.rejections: dict[str, int] = {}
        self.far_attempts = 0
        self.far_accepted = 0
        self.registrations = 0  # Harmony-ICP registrations, and the candidate poses they scored
        self.evaluations = 0
        self._far_pending: list[LoopClosure] = []

    # ------------------------------------------------------------------------------------------ candidates
    def submap_members(self, s: int, n_keyframes: int) -> range:
        K = self.config.submap_keyframes
        return range(s * K, min((s + 1) * K, n_keyframes))

    def candidates(self, graph: PoseGraph, newest: int, path: NDArray[np.float64]) -> list[LoopCandidate]:
        """Submaps worth matching against keyframe ``newest``, nearest first."""
        cfg = self.config
        K = cfg.submap_keyframes
        last_eligible = newest - cfg.min_separation  # newest keyframe a candidate submap may hold
        n_sub = (last_eligible + 1) // K  # complete submaps only
        if n_sub <= 0:
            return []
        P = np.asarray(graph.poses[: n_sub * K])
        d = np.linalg.norm(P[:, :2] - graph.poses[newest][:2], axis=1).reshape(n_sub, K)
        g = path[: n_sub * K].reshape(n_sub, K)
        g = np.where(np.isfinite(g), g, 1e9)
        dmin = d.min(axis=1)
        gmin = g.min(axis=1)
        reach = cfg.max_distance + self.window(gmin)[0]
        ok = dmin <= reach
        out = []
        for s in np.flatnonzero(ok):
            if newest - self._last_try.get(int(s), -10**9) < cfg.retry_after:
                continue
            out.append(LoopCandidate(int(s), float(dmin[s]), float(gmin[s])))
        out.sort(key=lambda c: c.distance)
        return out

    def window(self, path: NDArray[np.float64] | float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Half-widths (translation, yaw) of the search window for places ``path`` metres apart in the graph."""
        cfg = self.config
        p = np.asarray(path, dtype=float)
        t = np.minimum(cfg.window_translation + cfg.window_growth * p, cfg.max_window_translation)
        return t, np.minimum(_yaw_window(self.config, p), cfg.max_window_rotation)

    # ------------------------------------------------------------------------------------------ matching
    def _submap_target(self, s: int, graph: PoseGraph, keyframes: list[Keyframe]) -> RegistrationTarget:
        members = self.submap_members(s, len(keyframes))
        anchor = graph.poses[members.start]
        rel = relative(anchor, graph.poses[members.start:members.stop])
        hit = self._cache.get(s)
        if hit is not None:
            old_rel, target = hit
            diff = np.abs(rel - old_rel)
            diff[:, self.dim:] = np.abs(wrap_angle(diff[:, self.dim:]))
            if diff[:, : self.dim].max() < 0.01 and diff[:, self.dim:].max() < 0.002:
                self._cache.move_to_end(s)
                return target
        vm = keyframe_voxel_map(rel, keyframes, members, self.dim, self.map_voxel, average=self.map_average)
        target = RegistrationTarget(vm.points, self.config.registration, normals=vm.normals)
        self._cache[s] = (rel, target)
        self._cache.move_to_end(s)
        while len(self._cache) > self._cache_size:
            self._cache.popitem(last=False)
        return target

    def _reject(self, why: str) -> None:
        self.rejections[why] = self.rejections.get(why, 0) + 1

    def attempt(self, graph: PoseGraph, keyframes: list[Keyframe], newest: int, candidate: LoopCandidate,
                rng: np.random.Generator) -> LoopClosure | None:
        """Match keyframe ``newest`` against a candidate submap; the verified closure, or None."""
        cfg = self.config
        self.attempts += 1
        self._last_try[candidate.submap] = newest
        members = self.submap_members(candidate.submap, len(keyframes))
        anchor = members.start
        target = self._submap_target(candidate.submap, graph, keyframes)
        sides = self.dof == 3 and cfg.same_side
        source, origins = _recent_source(graph, keyframes, newest, self.config.source_keyframes, self.dim,
                                         with_origins=sides)
        predicted = relative(graph.poses[anchor], graph.poses[newest])
        wt, wr = (float(v) for v in self.window(candidate.path))
        if self.dof == 3:
            half = np.array([wt, wt, wr])
        else:
            half = np.array([wt, wt, cfg.window_z, cfg.window_roll_pitch, cfg.window_roll_pitch, wr])
        bounds = np.column_stack([predicted - half, predicted + half])
        guesses = [predicted]
        if wt > 1.0:  # a grid of guesses over a wide window
            n = min(int(np.ceil(2 * wt / 1.0)), 5)
            offs = np.linspace(-wt, wt, n + 2)[1:-1]
            for dx in offs:
                for dy in offs:
                    g = predicted.copy()
                    g[0] += dx
                    g[1] += dy
                    guesses.append(g)
        res = harmony_icp(source, target, bounds=bounds, initial_guesses=np.asarray(guesses),
                          config=cfg.registration, rng=rng)
        self.registrations, self.evaluations = self.registrations + 1, self.evaluations + res.evaluations
        closure = self._checked(res, anchor, newest, predicted, predicted, half,
                                sides=(source, origins, target) if sides else None)
        if closure is None or self.recent_share is None:
            return closure
        if not self.confirmed(res, graph, keyframes, newest, source,
                              lambda: harmony_icp(source, target, bounds=bounds, initial_guesses=np.asarray(guesses),
                                                  config=cfg.registration, rng=rng)):
            self.accepted -= 1
            return None
        return closure

    def recent_inliers(self, graph: PoseGraph, keyframes: list[Keyframe], newest: int,
                       source: NDArray[np.float64]) -> float | None:
        """The share of ``source`` (keyframe ``newest``'s frame) within the loop registration's threshold of the
        ``submap_keyframes`` keyframes before the source's own, at the graph's poses: what a match of this source
        against a map of its own place reaches. None where no keyframe precedes the source's."""
        cfg = self.config
        first = max(0, newest - cfg.source_keyframes + 1)
        recent = range(max(0, first - cfg.submap_keyframes), first)
        if not len(recent):
            return None
        P = graph.poses
        vm = keyframe_voxel_map([relative(P[newest], P[k]) for k in recent], keyframes, recent, self.dim,
                                self.map_voxel, average=self.map_average)
        threshold = cfg.registration.threshold
        d, _ = RegistrationTarget(vm.points, cfg.registration, normals=vm.normals).nearest(source, threshold)
        return float(np.mean(d < threshold * (1 - 1e-6)))

    def confirmed(self, res: RegistrationResult, graph: PoseGraph, keyframes: list[Keyframe], newest: int,
                  source: NDArray[np.float64], again) -> bool:
        """Whether a match ``res`` that passed the checks is confirmed (with ``recent_share``): its inlier ratio
        at least ``recent_share`` times :meth:`recent_inliers`, and a second search (``again()``, the same window
        searched with the next random numbers) landing within ``max_sigma_translation`` and
        ``max_sigma_rotation`` of it; else the rejection is counted."""
        cfg = self.config
        reference = self.recent_inliers(graph, keyframes, newest, source)
        if reference is not None and res.inlier_ratio < self.recent_share * reference:
            self._reject("recent_inliers")
            return False
        second = again()
        self.registrations, self.evaluations = self.registrations + 1, self.evaluations + second.evaluations
        d = relative(res.pose, second.pose)
        if not (np.linalg.norm(d[: self.dim]) <= cfg.max_sigma_translation
                and np.abs(wrap_angle(d[self.dim:])).max() <= cfg.max_sigma_rotation):
            self._reject("disagreement")
            return False
        return True

    def _checked(self, res: RegistrationResult, anchor: int, newest: int, predicted: NDArray[np.float64],
                 centre: NDArray[np.float64], half: NDArray[np.float64], prefix: str = "",
                 sides: tuple | None = None) -> LoopClosure | None:
        """The closure if ``res`` passes the checks (inliers, constrained, not on the edge of the box
        ``centre +/- half``; with ``sides`` = (source, its origins, target), inliers seen from their own side:
        :func:`same_side_share`), else None with the rejection counted."""
        cfg = self.config
        if res.inlier_ratio < cfg.min_inlier_ratio:
            self._reject(prefix + "inliers")
            return None
        information = drop_degenerate(res.information, cfg.degenerate_ratio)
        cov = safe_inverse(information)
        st = float(np.sqrt(max(np.linalg.eigvalsh(cov[: self.dim, : self.dim]).max(), 0.0)))
        sr = float(np.sqrt(max(np.linalg.eigvalsh(cov[self.dim:, self.dim:]).max(), 0.0)))
        if not (st <= cfg.max_sigma_translation and sr <= cfg.max_sigma_rotation):
            self._reject(prefix + "unconstrained")
            return None
        off = res.pose - centre
        off[self.dim:] = wrap_angle(off[self.dim:])
        if np.any(np.abs(off) > 0.95 * half):
            self._reject(prefix + "window_edge")
            return None
        corr = relative(predicted, res.pose)
        corr_t = float(np.linalg.norm(corr[: self.dim]))
        # a slide by a wall's thickness moves the graph by more than the registration's inlier distance (walls
        # are thicker than it); a closure that agrees with the graph within it is no such slide
        if (sides is not None and corr_t > cfg.registration.threshold
                and same_side_share(*sides, res.pose, cfg.registration.threshold) < cfg.min_inlier_ratio):
            self._reject(prefix + "other_side")
            return None
        info = information_with_floor(information, cfg.edge_sigma_translation, cfg.edge_sigma_rotation)
        self.accepted += 1
        return LoopClosure(anchor, newest, res.pose.copy(), info, corr_t,
                           float(np.abs(wrap_angle(corr[self.dim:])).max()), res)

    # ------------------------------------------------------------------------------------------ far search
    def far_candidates(self, graph: PoseGraph, newest: int, path: NDArray[np.float64]) -> list[LoopCandidate]:
        """Submaps whose uncertainty relative to keyframe ``newest`` exceeds the regular window and whose
        keyframes lie within the far window's reach, nearest first."""
        cfg = self.config
        if not cfg.far_search or self.dof != 3:
            return []
        K = cfg.submap_keyframes
        n_sub = (newest - cfg.min_separation + 1) // K
        if n_sub <= 0:
            return []
        P = np.asarray(graph.poses[: n_sub * K])
        d = np.linalg.norm(P[:, :2] - graph.poses[newest][:2], axis=1).reshape(n_sub, K).min(axis=1)
        g = path[: n_sub * K].reshape(n_sub, K)
        g = np.where(np.isfinite(g), g, 1e9).min(axis=1)
        wide = cfg.window_translation + cfg.window_growth * g
        ok = (wide > cfg.max_window_translation) & (d <= cfg.max_distance + _far_windows(self.config, g)[0])
        out = [LoopCandidate(int(s_), float(d[s_]), float(g[s_])) for s_ in np.flatnonzero(ok)]
        out.sort(key=lambda c: c.distance)
        return out

    def _far_source(self, graph: PoseGraph, keyframes: list[Keyframe], newest: int,
                    path: NDArray[np.float64]) -> NDArray[np.float64]:
        """The keyframes within ``far_source_path`` of ``newest`` in the graph (none newer), in its frame."""
        near = np.flatnonzero(path[: newest + 1] <= self.config.far_source_path)
        P = graph.poses
        return keyframe_voxel_map([relative(P[newest], P[k]) for k in near], keyframes, near, self.dim,
                                  self.map_voxel, average=self.map_average).points

    def attempt_far(self, graph: PoseGraph, keyframes: list[Keyframe], newest: int,
                    candidates: list[LoopCandidate], path: NDArray[np.float64],
                    rng: np.random.Generator) -> LoopClosure | None:
        """Match the recent path against the far candidates' map, exhaustively, then refine with Harmony-ICP and
        check; the match (not yet an edge) to the old keyframe nearest to it, or None.

        ``path`` holds the graph distances from ``newest`` (:meth:`hsmap.slam.posegraph.PoseGraph.path_distances`).
        """
        cfg = self.config
        if not candidates:
            return None
        self.attempts += 1
        self.far_attempts += 1
        members = [k for c in candidates for k in self.submap_members(c.submap, len(keyframes))]
        P = graph.poses
        vm = keyframe_voxel_map([P[k] for k in members], keyframes, members, self.dim, self.map_voxel,
                                average=self.map_average)  # the old map, world frame
        source = self._far_source(graph, keyframes, newest, path)
        wt, wr = _far_windows(self.config, np.array([c.path for c in candidates]))
        found, _, ambiguity = correlative_match_2d(source, vm.points, P[newest], float(wt.max()), float(wr.max()),
                                                   cfg.far_resolution, cfg.far_angle_step)
        if ambiguity >= cfg.far_ambiguity:
            self._reject("far_ambiguous")
            return None
        # refine and check in the frame of the old keyframe nearest to the match (the edge's other end)
        anchor = members[int(np.argmin([np.linalg.norm(P[k][:2] - found[:2]) for k in members]))]
        to_anchor = np.linalg.inv(pose_to_matrix(P[anchor]))
        centre = relative(P[anchor], found)
        half = np.array([3 * cfg.far_resolution, 3 * cfg.far_resolution, 3 * cfg.far_angle_step])  # a cell or two off
        # the old map's fields only where the source can land (the old map may span the whole building)
        target = RegistrationTarget(transform_points(to_anchor, vm.points), cfg.registration,
                                    normals=vm.normals @ to_anchor[: self.dim, : self.dim].T,
                                    field_within=_reach(source, centre, half, self.dim))
        res = harmony_icp(source, target, bounds=np.column_stack([centre - half, centre + half]),
                          initial_guesses=centre[None], config=cfg.registration, rng=rng)
        self.registrations, self.evaluations = self.registrations + 1, self.evaluations + res.evaluations
        return self._checked(res, anchor, newest, relative(P[anchor], P[newest]), centre, half, prefix="far_")

    def corroborate(self, closure: LoopClosure, graph: PoseGraph) -> list[LoopClosure]:
        """The far matches that ``closure`` and an earlier one now corroborate (both), or [] (kept pending)."""
        cfg = self.config
        self._far_pending = [c for c in self._far_pending if closure.j - c.j <= cfg.far_corroborate_within]
        prev = _agreeing(self._far_pending, closure, graph.poses, cfg, self.dim)
        if prev is not None:
            self._far_pending.remove(prev)
            self.far_accepted += 2
            return [prev, closure]
        self._far_pending.append(closure)
        self._reject("far_uncorroborated")
        return []

    def forget(self) -> None:
        """Drop cached submaps (their keyframes moved)."""
        self._cache.clear()


def _yaw_window(cfg: LoopClosureConfig, path: NDArray[np.float64]) -> NDArray[np.float64]:
    """The yaw half-width for places ``path`` metres apart in the graph, before any cap."""
    return cfg.window_rotation + cfg.window_rotation_growth * path


def _far_windows(cfg: LoopClosureConfig, path: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Half-widths (translation, yaw) of a far search: the translation's grows by ``far_window_growth`` up to
    ``max_far_window_translation``, the yaw's as the regular window's but uncapped (up to 180 deg)."""
    p = np.asarray(path, dtype=float)
    t = np.minimum(cfg.window_translation + cfg.far_window_growth * p, cfg.max_far_window_translation)
    return t, np.minimum(_yaw_window(cfg, p), np.pi)


def _reach(source: NDArray[np.float64], centre: NDArray[np.float64], half: NDArray[np.float64], dim: int
           ) -> NDArray[np.float64]:
    """[lower, upper] corners of a box holding every point of ``source`` at every pose within ``centre +/-
    half``, and a refinement's drift beyond it: the source's bounding box at ``centre``, grown by twice the
    farthest a corner of the window moves a point."""
    placed = transform_points(centre, source)
    radius = float(np.sqrt((source**2).sum(axis=1).max()))
    grow = 2 * (float(np.linalg.norm(half[:dim])) + radius * float(np.abs(half[dim:]).max()))
    return np.array([placed.min(axis=0) - grow, placed.max(axis=0) + grow])


def _agreeing(pending: list[LoopClosure], closure: LoopClosure, P, cfg: LoopClosureConfig, dim: int
              ) -> LoopClosure | None:
    """The newest pending far match that ``closure`` agrees with (graph poses ``P``), or None: the newer
    keyframe in the older match's anchor frame, by the older match and tracking and by the (locally consistent)
    old map and the newer match, within ``far_agreement_translation`` / ``far_agreement_rotation``."""
    for prev in reversed(pending):
        if prev.j == closure.j:
            continue
        a = np.asarray(compose(prev.measurement, relative(P[prev.j], P[closure.j])))
        b = np.asarray(compose(relative(P[prev.i], P[closure.i]), closure.measurement))
        d = relative(a, b)
        if (np.linalg.norm(d[:dim]) <= cfg.far_agreement_translation
                and np.abs(wrap_angle(d[dim:])).max() <= cfg.far_agreement_rotation):
            return prev
    return None


def _recent_source(graph: PoseGraph, keyframes: list[Keyframe], newest: int, count: int, dim: int,
                   with_origins: bool = False) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
    """The newest ``count`` keyframes' points in keyframe ``newest``'s frame, and (``with_origins``) each point's
    keyframe origin there (where the sensor stood, to a mounting offset), else None."""
    first = max(0, newest - count + 1)
    parts, origins = [], []
    for k in range(first, newest + 1):
        rel = relative(graph.poses[newest], graph.poses[k])
        parts.append(transform_points(pose_to_matrix(rel), keyframes[k].points))
        if with_origins:
            origins.append(np.broadcast_to(rel[:dim], parts[-1].shape))
    return np.concatenate(parts), np.concatenate(origins) if with_origins else None
