"""A registration checked against the motion prediction (:class:`Verifier`): retried around the prediction
where they disagree, the better-aligned kept, then fused with the prediction by their information."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from ..geometry import compose, pose_to_matrix, relative, transform_points, wrap_angle, wrap_angle_1
from ..registration.icp import RegistrationResult, RegistrationTarget, harmony_icp
from ..registration.information import drop_degenerate
from .config import SlamConfig
from .costs import Costs
from .odometry import INFO_JITTER, slip_weight
from .posegraph import information_with_floor
from .prediction import MotionPrediction

__all__ = ["Verifier", "residuals", "within_box", "truncated_residual", "matched_share", "at_least_as_good",
           "STRICT_SIGMAS", "STRICT_MIN_POINTS", "STRICT_MIN_MATCHED"]

#: Standard errors by which a registration's residuals must beat the prediction's to overrule it.
STRICT_SIGMAS = 3.0
#: Points both poses must match for that comparison (a mean's standard error needs a sample).
STRICT_MIN_POINTS = 30
#: Fraction of its scan a registration must match to overrule the prediction (a scan mostly unexplained at either
#: pose, by a changed or unmapped scene, says little about the pose).
STRICT_MIN_MATCHED = 0.6


def residuals(scan: NDArray[np.float64], target: RegistrationTarget, pose: NDArray[np.float64],
              threshold: float) -> NDArray[np.float64]:
    """Point-to-plane residual (N,) of each scan point (N, dim) at ``pose`` (NaN: no target point within
    ``threshold``)."""
    moved = transform_points(pose_to_matrix(pose), scan)
    d, idx = target.nearest(moved, threshold)
    out = np.full(len(scan), np.nan)
    ok = np.isfinite(d)
    out[ok] = np.abs(np.einsum("ij,ij->i", target.normals[idx[ok]], moved[ok] - target.points[idx[ok]]))
    return out


def within_box(res: RegistrationResult, centre: NDArray[np.float64], half: NDArray[np.float64],
               dim: int) -> RegistrationResult:
    """``res`` with its pose brought back into the box ``centre`` +/- ``half`` (per pose component) where it left
    it: a refinement is free to slide along a direction the scan hardly constrains."""
    off = res.pose - centre
    off[dim:] = wrap_angle(off[dim:])
    if np.all(np.abs(off) <= half):
        return res
    pose = centre + np.clip(off, -half, half)
    pose[dim:] = wrap_angle(pose[dim:])
    return replace(res, pose=pose, transformation=pose_to_matrix(pose))


def truncated_residual(r: NDArray[np.float64], threshold: float) -> float:
    """How well a pose aligns the whole scan: the mean of its :func:`residuals` ``r``, an unmatched point counting
    as ``threshold``."""
    return float(np.where(np.isfinite(r), r, threshold).mean())


def matched_share(r: NDArray[np.float64]) -> float:
    """The share of the scan's points a pose matches, from their :func:`residuals`."""
    return float(np.isfinite(r).mean())


def at_least_as_good(ra: NDArray[np.float64], rb: NDArray[np.float64], dim: int, strict: bool = False) -> bool:
    """Whether pose ``a`` aligns the scan about as well as pose ``b`` (``strict``: clearly better), from the scan's
    :func:`residuals` at the two poses, ``ra`` and ``rb`` (the scan's points in ``dim`` dimensions).

    Judged on the points both match (their mean residual) and on how many each matches. ``strict`` is the
    evidence a registration needs to overrule the prediction: residuals lower by a fifth and by more than
    ``STRICT_SIGMAS`` standard errors over at least ``STRICT_MIN_POINTS`` points, no matches lost, and at least
    ``STRICT_MIN_MATCHED`` of the scan matched.
    """
    both = np.isfinite(ra) & np.isfinite(rb)
    if both.sum() < (STRICT_MIN_POINTS if strict else 3 * dim):
        return False
    ma, mb = float(ra[both].mean()), float(rb[both].mean())
    fa, fb = matched_share(ra), matched_share(rb)
    if strict:
        d = ra[both] - rb[both]
        se = float(d.std(ddof=1)) / np.sqrt(len(d))
        return (ma < 0.8 * mb - 0.002 and fa >= fb - 0.1 and fa >= STRICT_MIN_MATCHED
                and float(d.mean()) < -STRICT_SIGMAS * se)
    return ma <= 1.2 * mb + 0.002 and fa >= fb - 0.1


class Verifier:
    """Checks each registration against the motion prediction, and fuses the two.

    Parameters
    ----------
    config : SlamConfig
    prediction : MotionPrediction
        The prediction of the frame being tracked. A prediction from a prior trajectory (another SLAM run) does not
        slip as wheels do: a retry that ends beyond its gate must then align the scan clearly better than the
        prediction itself.
    costs : Costs, optional
        Counts the retries' registrations.
    """

    def __init__(self, config: SlamConfig, prediction: MotionPrediction, *, costs: Costs | None = None) -> None:
        self.config = config
        self.dim = config.dim
        self.prediction = prediction
        self.costs = costs if costs is not None else Costs()

    def verify(self, scan: NDArray[np.float64], target: RegistrationTarget, res: RegistrationResult,
               rng: np.random.Generator) -> tuple[RegistrationResult, bool, bool]:
        """Check a registration ``res`` of ``scan`` (N, dim) against the prediction; retry around the prediction
        when they disagree.

        They disagree where the registration lies further from the prediction than ``verify_sigmas`` of the
        gate's sigmas (:meth:`MotionPrediction.predict` with ``gate``), or, for a registration that matches less
        than ``STRICT_MIN_MATCHED`` of its scan, of the learned ones. The retry searches the box of the
        prediction's uncertainty (within :meth:`MotionPrediction.tracking_box`) and the pose that aligns the scan
        clearly better wins. A registration beyond the gate stands as it is where it sets the odometry step aside
        (:meth:`MotionPrediction.set_aside`); it overrules the retry only where the prediction
        :meth:`~MotionPrediction.consents` (a run seeded by a prior: where the wheels side with it).

        Returns the registration to keep, whether it was retried, and whether its pose is confirmed.
        """
        pred = self.prediction.predict(True)
        if pred is None:
            return res, False, True
        centre, sig = pred
        threshold = self.config.registration.threshold
        stands, sig, r_first = self._stands(scan, target, res, centre, sig)
        if stands:
            return res, False, True
        alt, boxed = self._retry(scan, target, centre, sig, rng)
        if r_first is None:
            r_first = residuals(scan, target, res.pose, threshold)
        r_alt = residuals(scan, target, boxed.pose, threshold)
        alt, r_alt, at_prediction = self._or_prediction(scan, target, alt, boxed, r_alt, centre, sig)
        # the first registration stands only if it aligns the scan clearly better (the odometry slipped), or,
        # against the prediction itself, explains it at least twice as well
        first_matched = matched_share(r_first)
        if (at_least_as_good(r_first, r_alt, self.dim, strict=True) or (
                at_prediction and first_matched >= STRICT_MIN_MATCHED
                and truncated_residual(r_first, threshold) < 0.5 * truncated_residual(r_alt, threshold))
                ) and self.prediction.consents(res):
            return res, True, True
        # a registration that explains too little of its scan cannot veto the prediction either: the scan sees
        # space the map does not hold
        return alt, True, first_matched < STRICT_MIN_MATCHED or at_least_as_good(r_alt, r_first, self.dim)

    def _within(self, d: NDArray[np.float64], sig: NDArray[np.float64]) -> bool:
        """Whether a pose ``d`` from the prediction lies within ``verify_sigmas`` of the sigmas ``sig``."""
        k = self.config.verify_sigmas
        x, y, yaw = float(d[0]), float(d[1]), float(d[-1])  # np.linalg.norm's and wrap_angle's arithmetic
        return bool(math.sqrt(x * x + y * y) <= k * sig[0] and abs(wrap_angle_1(yaw)) <= k * sig[1])

    def _stands(self, scan: NDArray[np.float64], target: RegistrationTarget, res: RegistrationResult,
                centre: NDArray[np.float64], sig: NDArray[np.float64]
                ) -> tuple[bool, NDArray[np.float64], NDArray[np.float64] | None]:
        """Whether the registration ``res`` stands without a retry: within the gate ``sig`` of the prediction
        ``centre`` (one that matches less than ``STRICT_MIN_MATCHED`` of its scan, within the learned model's gate
        too), or beyond the gate where it sets the odometry step aside. Returns that, the sigmas of the retry's box
        and the scan's residuals at ``res`` where they were computed."""
        d = relative(centre, res.pose)
        if not self._within(d, sig):
            return self.prediction.set_aside(res), sig, None
        # a registration explaining too little of its scan must stay within the learned model's gate too
        tight = self.prediction.predict(False)
        if tight is None or self._within(d, tight[1]):
            return True, sig, None
        r_first = residuals(scan, target, res.pose, self.config.registration.threshold)
        return matched_share(r_first) >= STRICT_MIN_MATCHED, tight[1], r_first

    def _retry(self, scan: NDArray[np.float64], target: RegistrationTarget, centre: NDArray[np.float64],
               sig: NDArray[np.float64], rng: np.random.Generator) -> tuple[RegistrationResult, RegistrationResult]:
        """A longer search from the prediction ``centre`` in a box of its uncertainty ``sig`` (within the tracking
        box, at least two scan voxels wide): its result, and that result brought back into the box
        (:func:`within_box`)."""
        cfg = self.config
        reg = cfg.registration
        hs = reg.harmony
        retry_cfg = replace(reg, refine_seeds=1,
                            harmony=replace(hs, max_iterations=2 * hs.max_iterations,
                                            patience=None if hs.patience is None else 2 * hs.patience))
        half = self.prediction.tracking_box().copy()
        half[:2] = np.minimum(half[:2], cfg.verify_sigmas * sig[0])
        half[-1] = min(half[-1], cfg.verify_sigmas * sig[1])
        half[:2] = np.maximum(half[:2], 2 * cfg.effective_scan_voxel())
        guesses = centre[None]
        bounds = np.column_stack([centre - half, centre + half])
        alt = harmony_icp(scan, target, bounds=bounds, initial_guesses=guesses, config=retry_cfg, rng=rng)
        self.costs.registration(alt.evaluations)
        self.costs.add(retries=1)
        return alt, within_box(alt, centre, half, self.dim)

    def _or_prediction(self, scan: NDArray[np.float64], target: RegistrationTarget, alt: RegistrationResult,
                       boxed: RegistrationResult, r_alt: NDArray[np.float64], centre: NDArray[np.float64],
                       sig: NDArray[np.float64]) -> tuple[RegistrationResult, NDArray[np.float64], bool]:
        """The retry (``alt``, ``boxed`` into its box, the scan's residuals ``r_alt`` there) or the prediction
        ``centre`` standing for it: a prior's prediction, which does not slip as wheels do, wherever the retry
        ended beyond the gate ``sig`` (sliding along a direction the scan hardly constrains, the box being at least
        two voxels wide) without the evidence the first registration needs or without the prediction's consent;
        else where the retry slid out of its box (the box's edge is no pose the scan chose) and the prediction
        aligns the scan better. Returns the registration, its residuals and whether it is the prediction."""
        threshold = self.config.registration.threshold
        out_of_box = boxed is not alt
        beyond = self.prediction.prior is not None and not self._within(relative(centre, boxed.pose), sig)
        if not (out_of_box or beyond):
            return boxed, r_alt, False
        r_centre = residuals(scan, target, centre, threshold)
        if beyond:
            stands = not (at_least_as_good(r_alt, r_centre, self.dim, strict=True) and self.prediction.consents(boxed))
        else:
            stands = truncated_residual(r_centre, threshold) < truncated_residual(r_alt, threshold)
        if not stands:
            return boxed, r_alt, False
        return replace(alt, pose=centre.copy(), transformation=pose_to_matrix(centre)), r_centre, True

    def fuse(self, res: RegistrationResult) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """The registration fused with the prediction (:meth:`MotionPrediction.predict`), weighted by their
        information matrices.

        Along a direction the scene does not constrain (a corridor's axis, z where the 3D LiDAR sees walls only)
        the prediction carries the pose; a prediction beyond the chi-square gate (a wheel slip) is down-weighted.
        Returns the pose (dof,), its information (dof, dof; body frame) and the registration's information as
        fused (floored).
        """
        cfg = self.config
        lc = cfg.loop_closure
        info_reg = (information_with_floor(drop_degenerate(res.information, cfg.degenerate_ratio),
                                           lc.edge_sigma_translation, lc.edge_sigma_rotation)
                    if res.information is not None else np.zeros((cfg.dof, cfg.dof)))
        pred = self.prediction.predict()
        if pred is None:
            return res.pose, info_reg, info_reg
        centre, sig = pred
        it, ir = 1.0 / sig[0] ** 2, 1.0 / sig[1] ** 2
        info_pred = np.diag([it] * self.dim + [ir] * (cfg.dof - self.dim))
        d = relative(res.pose, centre)  # the prediction in the registration's frame
        d[self.dim:] = wrap_angle(d[self.dim:])
        w = slip_weight(d, info_reg, info_pred)
        if w < 1.0:
            info_pred = info_pred * w
        total = info_reg + info_pred
        step = np.linalg.solve(total + INFO_JITTER[cfg.dof], info_pred @ d)
        return compose(res.pose, step), total, info_reg
