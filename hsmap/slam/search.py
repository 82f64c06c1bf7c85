"""Where the tracker searches for a frame (:class:`SearchBox`): the box around the seeds, which in 6-DOF runs
without a prior follows the recent motion, the wider searches of a registration that fails the inlier check, and
the one score on which every candidate registration of a frame is compared (:meth:`SearchBox.best`); in 3-DOF
runs, a small search in the box of the prediction's uncertainty where that box is the smaller
(:meth:`SearchBox.tight`)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from ..geometry import relative, wrap_angle
from ..registration.icp import (
    RegistrationConfig,
    RegistrationResult,
    RegistrationTarget,
    default_bounds,
    harmony_icp,
)
from ..registration.refine import alignment_cost
from .config import SlamConfig
from .costs import Costs

__all__ = ["SearchBox", "same_pose", "TIGHT_HARMONY"]

#: The Harmony Search of a tight box (:meth:`SearchBox.tight`): memory size, harmonies per round, rounds without
#: a cell-sized improvement before it stops, and rounds drawn at once (one more than that: a search that stops
#: soon after its last improvement leaves few drawn and unused). The box is a few field cells wide and the
#: refinement's basin holds all of it: the search needs to find the right cell, not to explore.
TIGHT_HARMONY = {"memory_size": 10, "batch_size": 8, "patience": 5, "draw_rounds": 6}


def _median(values: list[float]) -> float:
    """The median of finite floats (at least one), as ``np.median`` gives it: the middle value, or the mean of
    the two middle ones (their sum halved)."""
    s = sorted(values)
    k = len(s) // 2
    return s[k] if len(s) % 2 else (s[k - 1] + s[k]) / 2


def same_pose(a: NDArray[np.float64], b: NDArray[np.float64]) -> bool:
    """Whether two 6-DOF poses lie within 5 cm and 1 deg of each other."""
    d = relative(a, b)
    return bool(np.linalg.norm(d[:3]) <= 0.05 and np.abs(wrap_angle(d[3:])).max() <= np.deg2rad(1.0))


class SearchBox:
    """The half-widths of the search box and the inlier check of a registration.

    The box is the configured one (``registration.*_range``; with a prior, ``prior_*_range``). In 6-DOF runs
    without a prior (:attr:`follows_motion`) it is at least :meth:`motion_spread` wide, and a registration whose
    inlier ratio falls below the recent confirmed frames' (:meth:`inlier_floor`) is searched again
    (:meth:`widened`); the frame keeps the candidate that aligns its scan best (:meth:`best`).
    """

    def __init__(self, config: SlamConfig, costs: Costs, prior: bool = False) -> None:
        self.config = config
        self.costs = costs
        self.follows_motion = config.dof == 6 and not prior
        self._recent: list[tuple[float, bool]] = []  # the last frames' inlier ratios and whether confirmed
        self._inliers: tuple[float | None, float | None] | None = None  # (reference, floor) of _recent, once asked
        self._tight_config: tuple[RegistrationConfig, RegistrationConfig] | None = None

    def tight(self, prediction: tuple[NDArray[np.float64], NDArray[np.float64]] | None, half: NDArray[np.float64]
              ) -> NDArray[np.float64] | None:
        """3-DOF runs: the box (3, 2) around the predicted pose of ``prediction`` (pose, (translation, yaw) gate
        sigmas: :meth:`MotionPrediction.predict` with ``gate``) that the verifier accepts without a retry,
        ``verify_sigmas`` sigmas wide (at least two scan voxels in translation), where it is narrower than the
        configured half-widths ``half`` in every component; else (no prediction, an uncertain one, 6-DOF runs) None:
        the full search."""
        cfg = self.config
        if cfg.dof != 3 or prediction is None:
            return None
        centre, sig = prediction
        # the half-widths (translation, yaw) and the box on floats: the arithmetic of the arrays
        t = max(float(sig[0]) * cfg.verify_sigmas, 2 * cfg.effective_scan_voxel())
        r = float(sig[1]) * cfg.verify_sigmas
        h0, h1, h2 = half.tolist()
        if t >= h0 or t >= h1 or r >= h2:
            return None
        x, y, yaw = centre.tolist()
        return np.array([[x - t, x + t], [y - t, y + t], [yaw - r, yaw + r]])

    def tight_config(self) -> RegistrationConfig:
        """The tracking's registration settings with the small Harmony Search of a tight box
        (:data:`TIGHT_HARMONY`)."""
        reg = self.config.registration
        if self._tight_config is None or self._tight_config[0] is not reg:
            self._tight_config = (reg, replace(reg, harmony=replace(reg.harmony, **TIGHT_HARMONY)))
        return self._tight_config[1]

    def escapes(self, res: RegistrationResult, box: NDArray[np.float64], scan: NDArray[np.float64]) -> bool:
        """Whether a tight box's registration ``res`` of ``scan`` calls for the full search: its search's best lies
        within a search-field cell of the box's edge (in yaw: the angle that moves the scan's typical point, at its
        RMS distance from its centroid, by a cell), where the alignment may lie beyond the box (the odometry
        slipped more than its sigmas say), or it fails the inlier check (:meth:`passes`)."""
        reg = self.config.registration
        cell = reg.field_resolution or max(0.02, reg.search_threshold / 10.0)
        n = len(scan)  # the means as numpy's mean computes them (a sum, then a division)
        radius = math.sqrt(((scan - scan.sum(0) / n) ** 2).sum(1).sum() / n) + 1e-9
        margin = (cell, cell, cell / radius)
        edge = any(g <= lo + m or g >= hi - m for g, (lo, hi), m in zip(res.global_pose.tolist(), box.tolist(),
                                                                        margin, strict=True))
        return edge or not self.passes(res)

    def record(self, inlier_ratio: float, verified: bool) -> None:
        """Remember a tracked frame's inlier ratio and whether it was confirmed."""
        self._recent = [*self._recent, (float(inlier_ratio), bool(verified))][-self.config.motion_window:]
        self._inliers = None

    def ranges(self, poses: Sequence[NDArray[np.float64]], prior: bool) -> NDArray[np.float64]:
        """The box's half-widths (dof,) for the frame after ``poses``."""
        cfg, reg = self.config, self.config.registration
        t = cfg.prior_translation_range if prior else reg.translation_range
        y = cfg.prior_yaw_range if prior else reg.yaw_range
        if cfg.dof == 3:
            return np.array([t, t, y])
        half = np.array([t, t, reg.z_range, reg.roll_pitch_range, reg.roll_pitch_range, y])
        return half if prior else np.maximum(half, self.motion_spread(poses))

    def motion_spread(self, poses: Sequence[NDArray[np.float64]]) -> NDArray[np.float64]:
        """With :attr:`follows_motion`: per pose component, ``verify_sigmas`` times the RMS change between
        consecutive frames' steps of that component over the last ``motion_window`` frames (the constant-velocity
        prediction's error); zeros otherwise or with too few frames."""
        cfg = self.config
        n = min(len(poses), cfg.motion_window + 2)
        if not self.follows_motion or n < 3:
            return np.zeros(cfg.dof)
        steps = np.diff(np.asarray(poses[-n:]), axis=0)
        steps[:, 3:] = wrap_angle(steps[:, 3:])
        change = np.diff(steps, axis=0)
        change[:, 3:] = wrap_angle(change[:, 3:])
        return cfg.verify_sigmas * np.sqrt(np.mean(change ** 2, axis=0))

    def inlier_reference(self) -> float | None:
        """The median inlier ratio of the confirmed ones among the last ``motion_window`` tracked frames (None with
        fewer than three)."""
        return self._inlier_levels()[0]

    def inlier_floor(self) -> float | None:
        """The inlier ratio a registration must reach to pass the check (None with fewer than three recent confirmed
        frames): ``min_inlier_share`` of their median, and, with :attr:`follows_motion`, no further below it than
        ``verify_sigmas`` times their spread (1.4826 times the median absolute deviation), whichever is higher.
        Where the recent ratios hardly vary, a drop they never showed is suspect however small a share it is."""
        return self._inlier_levels()[1]

    def _inlier_levels(self) -> tuple[float | None, float | None]:
        """:meth:`inlier_reference` and :meth:`inlier_floor`, computed once per :meth:`record` (a frame asks for
        them several times)."""
        if self._inliers is not None:
            return self._inliers
        recent = [r for r, ok in self._recent if ok]
        if len(recent) < 3:
            self._inliers = (None, None)
            return self._inliers
        ref = _median(recent)
        floor = self.config.min_inlier_share * ref
        if self.follows_motion:
            spread = 1.4826 * _median([abs(r - ref) for r in recent])
            floor = max(floor, ref - self.config.verify_sigmas * spread)
        self._inliers = (ref, floor)
        return self._inliers

    def lost(self, res: RegistrationResult) -> bool:
        """Whether a registration matches less than ``min_inlier_share`` of the recent confirmed frames' median
        inlier ratio: far enough below it that the search may have lost the frame's yaw altogether."""
        ref = self.inlier_reference()
        return ref is not None and res.inlier_ratio < self.config.min_inlier_share * ref

    def passes(self, res: RegistrationResult) -> bool:
        """Whether a registration reaches the recent confirmed frames' inlier ratio (:meth:`inlier_floor`)."""
        floor = self.inlier_floor()
        return floor is None or res.inlier_ratio >= floor

    def widened(self, scan: NDArray[np.float64], target: RegistrationTarget, res: RegistrationResult,
                guesses: NDArray[np.float64], half: NDArray[np.float64], rng: np.random.Generator
                ) -> tuple[RegistrationResult, bool, bool]:
        """A registration that fails the inlier check (:meth:`passes`) searched again in boxes of ``half`` times
        each of ``widen_factors`` around ``guesses`` (each half-width at most the larger of ``half``'s and the box
        :func:`hsmap.registration.icp.harmony_icp` searches without a guess), with a longer search, until one
        passes, or, for one not :meth:`lost`, until two searches agree (:func:`same_pose`: a scene that changed);
        where every search is lost, with ``global_search``, the rest of the yaw circle (:meth:`_yaw_sectors`).
        Returns the registration that aligns the scan best (:meth:`best`), whether a search was
        repeated, and whether the kept one passes the check or two searches agree on it."""
        cfg = self.config
        if not self.follows_motion or self.passes(res):
            return res, False, True
        hs = cfg.registration.harmony
        wide_cfg = replace(cfg.registration, harmony=replace(
            hs, max_iterations=2 * hs.max_iterations, patience=None if hs.patience is None else 2 * hs.patience))
        tried = [res]
        reach = np.maximum(half, default_bounds(np.zeros((1, 6)), RegistrationConfig())[:, 1])
        bounds = np.column_stack([guesses.min(0), guesses.max(0)])
        for factor in cfg.widen_factors:
            h = np.minimum(half * factor, reach)
            bounds = np.column_stack([guesses.min(0) - h, guesses.max(0) + h])
            tried.append(self._search(scan, target, bounds, guesses, wide_cfg, rng))
            last = tried[-1]
            if self.passes(last) or (not self.lost(last) and any(same_pose(last.pose, r.pose) for r in tried[:-1])):
                break
        if cfg.global_search and all(self.lost(r) for r in tried):
            for box in self._yaw_sectors(bounds):
                centre = guesses.copy()
                centre[:, 5] = box[5].mean()
                tried.append(self._search(scan, target, box, centre, wide_cfg, rng))
        best = self.best(scan, target, tried)
        agree = sum(same_pose(best.pose, r.pose) for r in tried) >= 2
        return best, True, self.passes(best) or agree

    def best(self, scan: NDArray[np.float64], target: RegistrationTarget, candidates: Sequence[RegistrationResult]
             ) -> RegistrationResult:
        """The candidate registration of ``scan`` that aligns it best with ``target``: the lowest mean point-to-plane
        residual of the whole scan, truncated at the registration's threshold
        (:func:`hsmap.registration.refine.alignment_cost`), the earlier on a tie. Candidates compare on it alike:
        the same points against the same target, whatever subset each search scored and refined."""
        threshold = self.config.registration.threshold
        scores = [alignment_cost(scan, target, r.pose, threshold) for r in candidates]
        return candidates[int(np.argmin(scores))]

    def settled(self, scan: NDArray[np.float64], target: RegistrationTarget, searched: RegistrationResult,
                checked: RegistrationResult, verified: bool) -> tuple[RegistrationResult, bool]:
        """Between the box's registration ``searched`` and the one the motion check kept, ``checked`` (confirmed
        or not: ``verified``): with :attr:`follows_motion`, the one that aligns ``scan`` best with ``target``
        (:meth:`best`; the prediction of a sensor carried by hand is no evidence for a pose), confirmed where it
        passes the inlier check, where the two agree (:func:`same_pose`), or, being ``checked``, where the motion
        check confirmed it; else ``checked`` as it is."""
        if not self.follows_motion or checked is searched:
            return checked, verified
        kept = self.best(scan, target, [searched, checked])
        agree = same_pose(searched.pose, checked.pose)
        return kept, self.passes(kept) or agree or (kept is checked and verified)

    def _search(self, scan: NDArray[np.float64], target: RegistrationTarget, bounds: NDArray[np.float64],
                guesses: NDArray[np.float64], config: RegistrationConfig, rng: np.random.Generator
                ) -> RegistrationResult:
        res = harmony_icp(scan, target, bounds=bounds, initial_guesses=guesses, config=config, rng=rng)
        self.costs.registration(res.evaluations)
        self.costs.add(retries=1)
        return res

    @staticmethod
    def _yaw_sectors(bounds: NDArray[np.float64]) -> list[NDArray[np.float64]]:
        """The part of the yaw circle that the box ``bounds`` (6, 2) leaves out, cut into the fewest sectors no
        wider than the box's yaw span, each a box of its own with ``bounds``' other half-widths; none where the
        box spans the circle."""
        lo, hi = bounds[5]
        width = float(hi - lo)
        rest = 2 * np.pi - width
        if rest <= 1e-9 or width <= 0:
            return []
        n = int(np.ceil(rest / width - 1e-9))
        step = rest / n
        out = []
        for k in range(n):
            box = bounds.copy()
            box[5] = [hi + k * step, hi + (k + 1) * step]
            out.append(box)
        return out
