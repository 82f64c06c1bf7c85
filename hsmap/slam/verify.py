"""A registration checked against the motion prediction (:class:`Verifier`): retried around the prediction
where they disagree, the better-aligned kept, then fused with the prediction by their information."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from ..geometry import compose, pose_to_matrix, relative, transform_points, wrap_angle
from ..registration.icp import RegistrationResult, RegistrationTarget, harmony_icp
from ..registration.information import drop_degenerate
from .config import SlamConfig
from .costs import Costs
from .posegraph import information_with_floor

__all__ = ["Verifier", "residuals", "within_box", "truncated_residual", "matched_share", "at_least_as_good",
           "slip_weight", "STRICT_SIGMAS", "STRICT_MIN_POINTS", "STRICT_MIN_MATCHED"]

#: Standard errors by which a registration's residuals must beat the prediction's to overrule it.
STRICT_SIGMAS = 3.0
#: Points both poses must match for that comparison (a mean's standard error needs a sample).
STRICT_MIN_POINTS = 30
#: Fraction of its scan a registration must match to overrule the prediction (a scan mostly unexplained at either
#: pose, by a changed or unmapped scene, says little about the pose).
STRICT_MIN_MATCHED = 0.6
#: 99.9 % quantiles of chi-square with 3 and 6 degrees of freedom, to 3 decimals: the gate on a prediction
CHI2_999 = {3: 16.266, 6: 22.458}

#: A prediction: the predicted pose (dof,) and its sigmas (translation, rotation), or None
Prediction = tuple[NDArray[np.float64], NDArray[np.float64]] | None


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


def slip_weight(d: NDArray[np.float64], info_a: NDArray[np.float64], info_b: NDArray[np.float64]) -> float:
    """The weight (<= 1) of measurement b where it lies ``d`` (n,) from measurement a: 1 within their joint
    uncertainty, ``gate / m2`` beyond the chi-square 99.9 % quantile, ``m2`` being d's squared Mahalanobis length
    under the information of their difference, I_a (I_a + I_b)^-1 I_b."""
    n = len(d)
    m2 = float(d @ (info_a @ np.linalg.solve(info_a + info_b + 1e-12 * np.eye(n), info_b)) @ d)
    gate = CHI2_999[n]
    return gate / m2 if m2 > gate else 1.0


class Verifier:
    """Checks each registration against the motion prediction, and fuses the two.

    Parameters
    ----------
    config : SlamConfig
    costs : Costs, optional
        Counts the retries' registrations.
    prior : bool
        The predictions come from a prior trajectory (another SLAM run), which does not slip as wheels do: a retry
        that ends beyond the prediction's gate must then align the scan clearly better than the prediction itself.
    """

    def __init__(self, config: SlamConfig, *, costs: Costs | None = None, prior: bool = False) -> None:
        self.config = config
        self.dim = config.dim
        self.costs = costs if costs is not None else Costs()
        self.prior = prior

    def verify(self, scan: NDArray[np.float64], target: RegistrationTarget, res: RegistrationResult,
               predict: Callable[[bool], Prediction], half: NDArray[np.float64], rng: np.random.Generator,
               set_aside: Callable[[RegistrationResult], bool] | None = None,
               overrule: Callable[[RegistrationResult], bool] | None = None
               ) -> tuple[RegistrationResult, bool, bool]:
        """Check a registration ``res`` of ``scan`` (N, dim) against the prediction; retry around the prediction
        when they disagree.

        They disagree where the registration lies further from the prediction than ``verify_sigmas`` of the
        gate's sigmas (``predict(True)``), or, for a registration that matches less than ``STRICT_MIN_MATCHED``
        of its scan, of the learned ones (``predict(False)``). The retry searches the box of the prediction's
        uncertainty (within ``half``, the tracking's box) and the pose that aligns the scan clearly better wins.
        A registration beyond the gate stands as it is where ``set_aside(res)`` sets the odometry step aside
        (:meth:`hsmap.slam.odometry.OdometryModel.set_aside`); it overrules the retry only where ``overrule(res)``
        (default: always; a run seeded by a prior: where the wheels side with it).

        Returns the registration to keep, whether it was retried, and whether its pose is confirmed.
        """
        cfg = self.config
        pred = predict(True)
        if pred is None:
            return res, False, True
        centre, sig = pred
        d = relative(centre, res.pose)
        reg = cfg.registration

        def within(s: NDArray[np.float64], d: NDArray[np.float64] = d) -> bool:
            return bool(np.linalg.norm(d[:2]) <= cfg.verify_sigmas * s[0]
                        and abs(wrap_angle(d[-1])) <= cfg.verify_sigmas * s[1])

        r_first = None  # the scan's residuals at the first registration, computed once
        if within(sig):
            # a registration explaining too little of its scan must stay within the learned model's gate too
            tight = predict(False)
            if tight is None or within(tight[1]):
                return res, False, True
            r_first = residuals(scan, target, res.pose, reg.threshold)
            if matched_share(r_first) >= STRICT_MIN_MATCHED:
                return res, False, True
            sig = tight[1]
        elif set_aside is not None and set_aside(res):
            return res, False, True
        # retry in a box of the prediction's uncertainty, from the prediction, with a longer search
        hs = reg.harmony
        retry_cfg = replace(reg, refine_seeds=1,
                            harmony=replace(hs, max_iterations=2 * hs.max_iterations,
                                            patience=None if hs.patience is None else 2 * hs.patience))
        half = half.copy()
        half[:2] = np.minimum(half[:2], cfg.verify_sigmas * sig[0])
        half[-1] = min(half[-1], cfg.verify_sigmas * sig[1])
        half[:2] = np.maximum(half[:2], 2 * cfg.effective_scan_voxel())
        guesses = centre[None]
        bounds = np.column_stack([centre - half, centre + half])
        alt = harmony_icp(scan, target, bounds=bounds, initial_guesses=guesses, config=retry_cfg, rng=rng)
        self.costs.registration(alt.evaluations)
        self.costs.add(retries=1)
        boxed = within_box(alt, centre, half, self.dim)
        if r_first is None:
            r_first = residuals(scan, target, res.pose, reg.threshold)
        r_alt = residuals(scan, target, boxed.pose, reg.threshold)
        # the prediction itself may stand for the retry: a prior's prediction, which does not slip as wheels do,
        # wherever the retry ended beyond the gate (sliding along a direction the scan hardly constrains, the box
        # being at least two voxels wide) without the evidence the first registration needs or without
        # ``overrule``'s consent; else where the retry slid out of its box (the box's edge is no pose the scan
        # chose) and the prediction aligns the scan better
        consents = overrule if overrule is not None else (lambda _: True)
        out_of_box = boxed is not alt
        beyond = self.prior and not within(sig, relative(centre, boxed.pose))
        at_prediction = False
        if out_of_box or beyond:
            r_centre = residuals(scan, target, centre, reg.threshold)
            if beyond:
                prediction_stands = not (at_least_as_good(r_alt, r_centre, self.dim, strict=True) and consents(boxed))
            else:
                prediction_stands = (truncated_residual(r_centre, reg.threshold)
                                     < truncated_residual(r_alt, reg.threshold))
            if prediction_stands:
                boxed, r_alt = replace(alt, pose=centre.copy(), transformation=pose_to_matrix(centre)), r_centre
                at_prediction = True
        alt = boxed
        # the first registration stands only if it aligns the scan clearly better (the odometry slipped), or,
        # against the prediction itself, explains it at least twice as well
        first_matched = matched_share(r_first)
        if (at_least_as_good(r_first, r_alt, self.dim, strict=True) or (
                at_prediction and first_matched >= STRICT_MIN_MATCHED
                and truncated_residual(r_first, reg.threshold) < 0.5 * truncated_residual(r_alt, reg.threshold))
                ) and consents(res):
            return res, True, True
        # a registration that explains too little of its scan cannot veto the prediction either: the scan sees
        # space the map does not hold
        return alt, True, first_matched < STRICT_MIN_MATCHED or at_least_as_good(r_alt, r_first, self.dim)

    def fuse(self, res: RegistrationResult, pred: Prediction
             ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """The registration fused with the prediction ``pred``, weighted by their information matrices.

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
        if pred is None:
            return res.pose, info_reg, info_reg
        centre, sig = pred
        info_pred = np.zeros(cfg.dof)
        info_pred[: self.dim] = 1.0 / sig[0] ** 2
        info_pred[self.dim:] = 1.0 / sig[1] ** 2
        info_pred = np.diag(info_pred)
        d = relative(res.pose, centre)  # the prediction in the registration's frame
        d[self.dim:] = wrap_angle(d[self.dim:])
        w = slip_weight(d, info_reg, info_pred)
        if w < 1.0:
            info_pred = info_pred * w
        total = info_reg + info_pred
        step = np.linalg.solve(total + 1e-12 * np.eye(cfg.dof), info_pred @ d)
        return compose(res.pose, step), total, info_reg
