"""Harmony-ICP: scan registration by Harmony Search (the paper's Algorithm 1), in 2D (3-DOF) and 3D (6-DOF).

:func:`harmony_icp` searches the pose vector (x, y, yaw) for (N, 2) clouds or (x, y, z, roll, pitch, yaw) for
(N, 3) clouds that minimises the two-term fitness of :mod:`hsmap.registration.fitness`, with the harmony memory seeded by
optional initial guesses and the rest drawn inside the bounds. No initial guess is needed: with none, the search
is centred on the identity. An optional local refinement (point-to-plane or point-to-point ICP, trimmed at the
fitness threshold) polishes the best harmony.

The global search truncates distances at ``search_threshold`` (0.5 m: a broad basin that finds the right
alignment from far away); an optional second Harmony Search stage narrows the box around the best harmony and
uses ``fine_threshold``. The refinement trims correspondences at ``threshold``, the inlier distance of the
reported fitness and inlier ratio.
"""

from __future__ import annotations

import math
import time

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._blas import blas_limited
from .._threads import threads_limited
from ..errors import ConfigError, InputError, ShapeError
from ..geometry import dof_of_dim, pose_to_matrix, relative, transform_points, wrap_angle
from ..maps.mapping import voxel_downsample
from .config import Backend, Refinement, RegistrationConfig, RegistrationResult
from .fitness import DistanceField, FieldObjective, score
from .harmony import HarmonyResult, as_rng, harmony_search
from .information import adjoint, constrained_axes, drop_degenerate
from .normals import estimate_normals, orient_normals
from .refine import (
    _cost_of,
    _information_and_cost,
    _match,
    alignment_cost,
    alignment_information,
    refine_icp,
)
from .target import RegistrationTarget, _check_spread, _clean_cloud, spans_its_space

__all__ = [
    "Backend",
    "Refinement",
    "RegistrationConfig",
    "RegistrationResult",
    "RegistrationTarget",
    "harmony_icp",
    "default_bounds",
    "refine_icp",
    "estimate_normals",
    "orient_normals",
    "alignment_cost",
    "alignment_information",
    "adjoint",
    "constrained_axes",
    "drop_degenerate",
    "spans_its_space",
]


def default_bounds(centres: NDArray[np.float64], cfg: RegistrationConfig) -> NDArray[np.float64]:
    """The box (dof, 2) that :func:`harmony_icp` searches without ``bounds``: the initial guesses ``centres``
    (K, dof) widened by the configured ranges (``translation_range``, ``z_range``, ``roll_pitch_range``,
    ``yaw_range``)."""
    dof = centres.shape[1]
    if dof == 3:
        half = np.array([cfg.translation_range, cfg.translation_range, cfg.yaw_range])
    else:
        half = np.array([cfg.translation_range, cfg.translation_range, cfg.z_range,
                         cfg.roll_pitch_range, cfg.roll_pitch_range, cfg.yaw_range])
    return np.column_stack([centres.min(axis=0) - half, centres.max(axis=0) + half])


def _check_bounds(bounds: ArrayLike, dof: int) -> NDArray[np.float64]:
    try:
        b = np.asarray(bounds, dtype=float)
    except (TypeError, ValueError):
        raise ShapeError(f"bounds must be a numeric array of shape ({dof}, 2)") from None
    if b.shape != (dof, 2):
        raise ShapeError(f"bounds must have shape ({dof}, 2) [lower, upper] for a {dof}-DOF pose, got {b.shape}")
    if all(-1e300 < lo <= hi < 1e300 for lo, hi in b.tolist()):  # a valid box, its widths finite, on floats
        return b
    if not np.all(np.isfinite(b)):
        raise InputError(f"bounds must be finite, got {b.tolist()}")
    bad = np.flatnonzero(b[:, 1] < b[:, 0])
    if bad.size:
        i = int(bad[0])
        raise InputError(f"bounds[{i}] is inverted: lower {b[i, 0]} > upper {b[i, 1]}")
    with np.errstate(over="ignore"):
        wide = np.flatnonzero(~np.isfinite(b[:, 1] - b[:, 0]))
    if wide.size:
        i = int(wide[0])
        raise InputError(f"bounds[{i}] spans {b[i, 0]:g}..{b[i, 1]:g}, wider than a float can hold; expected a "
                         "search box of finite width")
    return b


def _subsample(points: NDArray[np.float64], voxel: float, n: int, gen: np.random.Generator) -> NDArray[np.float64]:
    pts = voxel_downsample(points, voxel)
    if len(pts) > n:
        pts = pts[np.sort(gen.choice(len(pts), n, replace=False))]
    return pts




def _refine_reach(cfg: RegistrationConfig, lookup, dim: int) -> float:
    """``cfg.refine_reach``, or its default: the 2D search field's cell, 0 in 3D."""
    if cfg.refine_reach is not None:
        return cfg.refine_reach
    if dim != 2:
        return 0.0
    return lookup.resolution if isinstance(lookup, DistanceField) else max(0.02, cfg.search_threshold / 10)


def _within(a: NDArray[np.float64], b: NDArray[np.float64], reach: NDArray[np.float64], dim: int) -> bool:
    """Whether pose ``b`` lies within ``reach`` (per pose component) of pose ``a``, in ``a``'s frame."""
    moved = np.abs(relative(a, b))
    moved[dim:] = np.abs(wrap_angle(moved[dim:]))
    return bool(np.all(moved <= reach))


def _polish(source: NDArray[np.float64], target: RegistrationTarget, pose: NDArray[np.float64],
            cfg: RegistrationConfig) -> NDArray[np.float64] | None:
    """The final point-to-plane refinement of a 3D ``pose`` (``RegistrationConfig.polish_*``) against the target
    averaged in voxels: the refined pose where it lowers the truncated point-to-plane cost there, else None."""
    voxel = cfg.effective_polish_voxel()
    if voxel <= 0 or cfg.polish_iterations <= 0:
        return None
    fine = target.voxelised(voxel)
    src = voxel_downsample(source, 2 * voxel)
    if len(src) < 6:
        return None
    cand = refine_icp(src, fine, pose, max_distance=cfg.polish_distance, iterations=cfg.polish_iterations,
                      robust_kernel=cfg.polish_kernel)
    at_pose = _match(pose, src, fine, cfg.threshold)
    before = _cost_of(at_pose, fine, cfg.threshold, True)
    after = _cost_of(_match(cand, src, fine, cfg.threshold, at_pose[3]), fine, cfg.threshold, True)
    return cand if after < before else None


@blas_limited
@threads_limited
def harmony_icp(
    source: ArrayLike,
    target: ArrayLike | RegistrationTarget,
    *,
    bounds: ArrayLike | None = None,
    initial_guesses: ArrayLike | None = None,
    config: RegistrationConfig | None = None,
    rng: int | np.random.Generator | None = None,
) -> RegistrationResult:
    """Register ``source`` to ``target`` with Harmony Search (Harmony-ICP).

    Parameters
    ----------
    source : array_like of shape (N, 2) or (N, 3)
        Points to move. NaN/inf rows are dropped (counted in ``result.dropped``).
    target : array_like of shape (M, 2) or (M, 3), or RegistrationTarget
        Reference points (same dimension as ``source``), or a target prepared once for many registrations.
    bounds : array_like of shape (dof, 2), optional
        Absolute [lower, upper] limits of the pose vector (x, y, yaw) or (x, y, z, roll, pitch, yaw). Default: a
        box of the configured ranges around the initial guesses, or around the identity.
    initial_guesses : array_like of shape (K, dof) or (dof,), optional
        Pose vectors seeded into the harmony memory (odometry, previous pose, ...). None needed.
    config : RegistrationConfig, optional
    rng : int or numpy.random.Generator, optional
        Seed or generator for every random choice (default seed 0).
    threads : int, optional
        Compute threads (keyword only; default: the enclosing run's, else ``$HSMAP_THREADS``, else every core):
        a speed setting only, the result is the same for any count (:mod:`hsmap._threads`).

    Returns
    -------
    RegistrationResult
        ``.transformation`` maps ``source`` into the frame of ``target``.
    """
    t0 = time.perf_counter()
    cfg = config or (target.config if isinstance(target, RegistrationTarget) else RegistrationConfig())
    if not isinstance(cfg, RegistrationConfig):
        raise ConfigError(f"config must be a RegistrationConfig, got {type(cfg).__name__}")
    gen = as_rng(rng)
    src, tgt, dropped = _prepared(source, target, cfg)
    dim = src.shape[1]
    dof = dof_of_dim(dim)
    guesses = _checked_guesses(initial_guesses, dof, dim)
    b = default_bounds(guesses if guesses is not None else np.zeros((1, dof)), cfg) if bounds is None else \
        _check_bounds(bounds, dof)
    sample, radius = _search_sample(src, cfg, gen)
    hs, iterations, evaluations, lookup = _global_search(sample, tgt, b, guesses, cfg, gen, radius)
    global_pose = hs.x.copy()
    full = src if len(src) <= cfg.refine_points else src[np.sort(gen.choice(len(src), cfg.refine_points,
                                                                            replace=False))]
    pose, refined, match = _refined(full, tgt, global_pose, guesses, cfg, _refine_reach(cfg, lookup, dim),
                                    radius)
    polished = _polish(src, tgt, pose, cfg) if dim == 3 else None
    if polished is not None:
        pose, refined, match = polished, True, None
    pose = pose.copy()
    pose[dim:] = wrap_angle(pose[dim:])  # the same transform: `match` still holds
    if match is None:
        match = _match(pose, full, tgt, cfg.threshold)
    fitness, inlier_ratio, rmse = _scores(src, full, tgt, pose, match, cfg)
    information, _, _, cost = _information_and_cost(full, tgt, pose, cfg.threshold, cfg.robust_kernel, match=match)
    return RegistrationResult(
        transformation=pose_to_matrix(pose),
        pose=pose,
        fitness=fitness,
        inlier_ratio=inlier_ratio,
        rmse=rmse,
        evaluations=evaluations,
        iterations=iterations,
        dropped=dropped,
        global_pose=global_pose,
        refined=refined,
        stop_reason=hs.stop_reason.value,
        seconds=time.perf_counter() - t0,
        information=information,
        cost=cost,
    )


def _search_sample(src: NDArray[np.float64], cfg: RegistrationConfig, gen: np.random.Generator
                   ) -> tuple[NDArray[np.float64], float]:
    """The source points the search scores (``voxel_size``, at most ``max_points``) and their RMS distance from
    their centroid (the lever arm that turns an angle into a displacement)."""
    voxel = cfg.voxel_size or (0.05 if src.shape[1] == 2 else 0.1)
    try:
        sample = _subsample(src, voxel, cfg.max_points, gen)
    except InputError as exc:
        raise type(exc)(f"source: {exc}") from None
    n = len(sample)
    return sample, math.sqrt(((sample - sample.sum(0) / n) ** 2).sum(1).sum() / n) + 1e-9


def _prepared(source: ArrayLike, target: ArrayLike | RegistrationTarget, cfg: RegistrationConfig
              ) -> tuple[NDArray[np.float64], RegistrationTarget, int]:
    """The source cloud cleaned and checked for spread, the target (built from ``target``'s points unless it is a
    prepared one) and the number of non-finite rows dropped from both."""
    if isinstance(target, RegistrationTarget):
        tgt = target
        src, dropped = _clean_cloud(source, "source", tgt.dim)
    else:
        src, dropped = _clean_cloud(source, "source")
        _clean_cloud(target, "target", src.shape[1])  # shape check with names before building anything
    _check_spread(src, "source")
    if not isinstance(target, RegistrationTarget):
        tgt = RegistrationTarget(target, cfg)
    return src, tgt, dropped + tgt.dropped


def _checked_guesses(initial_guesses: ArrayLike | None, dof: int, dim: int) -> NDArray[np.float64] | None:
    """``initial_guesses`` as finite pose vectors (K, dof), or None."""
    if initial_guesses is None:
        return None
    try:
        guesses = np.atleast_2d(np.asarray(initial_guesses, dtype=float))
    except (TypeError, ValueError):
        raise ShapeError(f"initial_guesses must be numeric pose vectors of shape (K, {dof})") from None
    if guesses.ndim != 2 or guesses.shape[1] != dof:
        raise ShapeError(f"initial_guesses must have shape (K, {dof}) for {dim}D clouds, "
                         f"got {np.asarray(initial_guesses).shape}")
    if not np.all(np.isfinite(guesses)):
        raise InputError("initial_guesses must be finite (no NaN or inf)")
    return guesses


def _global_search(sample: NDArray[np.float64], tgt: RegistrationTarget, b: NDArray[np.float64],
                   guesses: NDArray[np.float64] | None, cfg: RegistrationConfig, gen: np.random.Generator,
                   radius: float) -> tuple[HarmonyResult, int, int, object]:
    """Harmony Search over the box ``b`` at ``search_threshold``, then (with ``fine_threshold``) again in a box
    narrowed around its best; the last search, the iterations and evaluations of all, and the last look-up."""
    dim = sample.shape[1]
    dof = dof_of_dim(dim)
    iterations = evaluations = 0
    hs: HarmonyResult | None = None
    seeds = guesses
    stages = [cfg.search_threshold] + ([cfg.fine_threshold] if cfg.fine_threshold else [])
    for k, tau in enumerate(stages):
        box = b
        if k > 0 and hs is not None:
            # narrow the box around the first stage's best: +/- a few search thresholds in translation, and the
            # angle that moves the source's typical point by as much
            half_t = cfg.fine_range_factor * cfg.search_threshold
            half = np.full(dof, min(half_t / radius, np.pi))
            half[:dim] = half_t
            box = np.column_stack([np.maximum(hs.x - half, b[:, 0]), np.minimum(hs.x + half, b[:, 1])])
            seeds = hs.memory[: max(1, cfg.harmony.memory_size // 3)]
        lookup = tgt.lookup(tau)
        if isinstance(lookup, DistanceField):
            objective = FieldObjective(sample, lookup, cfg.inlier_weight)  # compiled Harmony Search rounds
        else:
            def objective(X: NDArray[np.float64], lookup=lookup) -> NDArray[np.float64]:
                return score(X, sample, lookup, cfg.inlier_weight).value

        spread = None
        if cfg.stop_within_cell and dim == 2:
            cell = lookup.resolution if isinstance(lookup, DistanceField) else max(0.02, tau / 10.0)
            spread = np.full(dof, cell / radius)
            spread[:dim] = cell
        hs = harmony_search(objective, box, initial=seeds, config=cfg.harmony, rng=gen, spread=spread)
        iterations += hs.iterations
        evaluations += hs.evaluations
    assert hs is not None
    return hs, iterations, evaluations, lookup


def _refined(full: NDArray[np.float64], tgt: RegistrationTarget, global_pose: NDArray[np.float64],
             guesses: NDArray[np.float64] | None, cfg: RegistrationConfig, reach_distance: float, radius: float
             ) -> tuple[NDArray[np.float64], bool, tuple | None]:
    """The search's pose refined (``refinement``) from it and from the first ``refine_seeds`` guesses: the pose
    that aligns ``full`` best by the refinement's own metric, whether a refinement was kept, and the
    correspondences at the pose (None where none were computed)."""
    pose = global_pose.copy()
    if cfg.refinement is Refinement.NONE or cfg.refine_iterations <= 0:
        return pose, False, None
    # Keep a refinement unless it made the alignment worse, judged by its own (point-to-plane) metric: the
    # point-to-point fitness is biased towards poses where the scan's sampling pattern (a LiDAR's rings on
    # the floor) repeats the map's, i.e. towards no motion.
    dim = full.shape[1]
    refined = False
    plane = cfg.refinement is Refinement.POINT_TO_PLANE
    match = _match(pose, full, tgt, cfg.threshold)
    best_cost = _cost_of(match, tgt, cfg.threshold, plane)
    reach = np.full(dof_of_dim(dim), reach_distance)
    reach[dim:] /= radius
    starts = [pose] + ([] if guesses is None else list(guesses[: cfg.refine_seeds]))
    near = match[3]  # the correspondences at the search's pose, near every start and result
    for start in starts:
        cand = refine_icp(full, tgt, start, max_distance=cfg.threshold, start_distance=cfg.search_threshold,
                          iterations=cfg.refine_iterations, method=cfg.refinement,
                          robust_kernel=cfg.robust_kernel, hint=near)
        cand_match = _match(cand, full, tgt, cfg.threshold, near)
        cost = _cost_of(cand_match, tgt, cfg.threshold, plane)
        if cost <= best_cost + 1e-12 or (not refined and reach.any() and _within(global_pose, cand, reach, dim)):
            pose, best_cost, refined, match = cand, cost, True, cand_match
    return pose, refined, match


def _scores(src: NDArray[np.float64], full: NDArray[np.float64], tgt: RegistrationTarget,
            pose: NDArray[np.float64], match: tuple, cfg: RegistrationConfig) -> tuple[float, float, float]:
    """The reported fitness, inlier ratio and inlier RMSE of ``src`` at ``pose`` (distances truncated at
    ``threshold``; ``match``: the correspondences of ``full`` at ``pose``)."""
    if full is src:
        d = np.minimum(match[2], cfg.threshold)
    else:
        d = np.minimum(tgt.nearest(transform_points(pose_to_matrix(pose), src), cfg.threshold)[0], cfg.threshold)
    inl = d < cfg.threshold * (1 - 1e-6)
    # the means as numpy's mean computes them (the sum, then a division), without its dispatch
    n_in = int(np.count_nonzero(inl))
    inlier_ratio = n_in / len(d)
    fitness = float(d.sum() / len(d) / cfg.threshold + cfg.inlier_weight * (1.0 - inlier_ratio))
    rmse = math.sqrt((d[inl] ** 2).sum() / n_in) if n_in else float("nan")
    return fitness, inlier_ratio, rmse
