"""Harmony Search (Geem et al. 2001), batched and seeded, with the IHS and global-best variants.

The optimiser minimises ``objective(X) -> f`` where ``X`` is an array of shape (B, D) of candidate solutions
("harmonies") and ``f`` has shape (B,): every call evaluates a whole batch, so the objective can be vectorised.

One *iteration* improvises ``batch_size`` new harmonies. Each variable of a new harmony is, independently:

- with probability HMCR, taken from a random harmony of the memory (memory consideration), and then, with
  probability PAR, moved by ``U(-1, 1) * BW * (upper - lower)`` (pitch adjustment);
- otherwise drawn uniformly inside the bounds (random selection).

The memory then keeps the best ``memory_size`` of the old memory and the new batch (for ``batch_size=1`` this is
the classic rule: the new harmony replaces the worst one if it is better). Variants:

- ``classic``: fixed PAR and BW (Geem et al. 2001).
- ``ihs``: improved HS (Mahdavi et al. 2007): PAR grows linearly from ``par_min`` to ``par_max`` and BW shrinks
  exponentially from ``bw_max`` to ``bw_min`` over the iterations.
- ``global-best``: global-best HS (Omran & Mahdavi 2008): pitch adjustment copies the variable from the best
  harmony instead of moving it. (The original copies a random dimension of the best harmony; since our variables
  carry different units, e.g. metres and radians, we copy the same dimension, as most later work does.)

Stopping rules (the first that holds ends the search): ``max_iterations``; the best and the worst harmony in
memory have objective values within ``convergence_tol`` (the paper's rule); no improvement of the best value by more
than ``min_improvement`` for ``patience`` iterations. Given a ``spread`` (a caller's argument, off by default), an
improvement counts only where it moves the best harmony farther than ``spread`` in some variable from where the
last counted one left it: a search whose best only creeps among poses the caller cannot tell apart has settled.

Paper defaults: HMS 30, HMCR 0.7, PAR 0.3, BW 0.05 (of each variable's range), 500 iterations.
"""

from __future__ import annotations

import enum
import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import ConfigError, InputError, ShapeError
from ..limits import quote

#: Most rows of a harmony memory (``memory_size``) or of one batch of new harmonies (``batch_size``).
MAX_HARMONIES = 100_000

__all__ = ["Variant", "StopReason", "HarmonyConfig", "HarmonyResult", "harmony_search", "as_rng"]


class Variant(enum.StrEnum):
    """Harmony Search flavour."""

    CLASSIC = "classic"
    IHS = "ihs"
    GLOBAL_BEST = "global-best"


class StopReason(enum.StrEnum):
    """Why the search ended."""

    MAX_ITERATIONS = "max-iterations"
    CONVERGED = "converged"  # best and worst harmony equal within convergence_tol
    SETTLED = "settled"  # the best moved less than `spread` for `patience` iterations
    NO_IMPROVEMENT = "no-improvement"  # best did not improve for `patience` iterations


def as_rng(rng: int | np.random.Generator | None) -> np.random.Generator:
    """A numpy Generator from a seed, a Generator (returned as is) or None (seed 0: hsmap is deterministic)."""
    if isinstance(rng, np.random.Generator):
        return rng
    if rng is None:
        return np.random.default_rng(0)
    if isinstance(rng, (int, np.integer)) and not isinstance(rng, bool):
        if rng < 0:
            raise InputError(f"rng must be a seed >= 0 (or a numpy Generator, or None), got {int(rng)}")
        return np.random.default_rng(int(rng))
    raise InputError(f"rng must be an int seed >= 0, a numpy Generator or None, got {type(rng).__name__}")


@dataclass
class HarmonyConfig:
    """Harmony Search parameters (defaults: the paper's, plus batching and a no-improvement rule).

    Attributes
    ----------
    memory_size : int
        HMS, harmonies kept in memory.
    hmcr : float
        Harmony memory considering rate, in [0, 1].
    par : float
        Pitch adjusting rate, in [0, 1] (``classic`` and ``global-best``).
    bandwidth : float
        BW as a fraction of each variable's range (``classic``).
    max_iterations : int
        Improvisation rounds; each round improvises ``batch_size`` harmonies.
    batch_size : int
        Harmonies improvised and evaluated together per round (1 = the one-at-a-time classic).
    variant : str
        ``"classic"``, ``"ihs"`` or ``"global-best"``.
    par_min, par_max : float
        IHS: PAR at the first and the last iteration.
    bw_min, bw_max : float
        IHS: BW (fraction of range) at the first (max) and the last (min) iteration.
    convergence_tol : float
        Stop when best and worst objective values in memory differ by at most this (<0 disables).
    patience : int or None
        Stop after this many rounds without an improvement of the best value (None disables).
    min_improvement : float
        Smallest decrease of the best value that counts as an improvement.
    init : str
        How the memory rows not given as initial guesses are drawn: ``"uniform"`` (the classic) or ``"lhs"``
        (Latin hypercube: each variable's range split into HMS strata, one sample per stratum, for an even
        coverage of the box).
    draw_rounds : int
        Rounds whose random numbers are drawn at once (five arrays of rounds x batch x variables, in a fixed
        order; the compiled search and the Python rounds alike): fewer, larger draws; a search that stops early
        leaves some drawn and unused. It picks the random stream, so the searches too.
    """

    memory_size: int = 30
    hmcr: float = 0.7
    par: float = 0.3
    bandwidth: float = 0.05
    max_iterations: int = 500
    batch_size: int = 1
    variant: str = Variant.CLASSIC.value
    par_min: float = 0.01
    par_max: float = 0.99
    bw_min: float = 0.001
    bw_max: float = 0.05
    convergence_tol: float = 1e-9
    patience: int | None = None
    min_improvement: float = 1e-12
    init: str = "uniform"
    draw_rounds: int = 32

    def __post_init__(self) -> None:
        try:
            self.variant = Variant(self.variant).value
        except ValueError:
            raise ConfigError(
                f"harmony.variant must be one of {[v.value for v in Variant]}, got {self.variant!r}"
            ) from None
        for name in ("memory_size", "max_iterations", "batch_size", "draw_rounds"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or v < 1:
                raise ConfigError(f"harmony.{name} must be an integer >= 1, got {quote(v)}")
        for name in ("memory_size", "batch_size"):  # rows of arrays allocated up front
            if getattr(self, name) > MAX_HARMONIES:
                raise ConfigError(f"harmony.{name} must be at most {MAX_HARMONIES} (rows of the harmony memory), "
                                  f"got {getattr(self, name)}")
        for name in ("hmcr", "par", "par_min", "par_max"):
            v = getattr(self, name)
            if not 0.0 <= float(v) <= 1.0:
                raise ConfigError(f"harmony.{name} must be in [0, 1], got {v!r}")
        for name in ("bandwidth", "bw_min", "bw_max"):
            v = getattr(self, name)
            if not float(v) > 0.0:
                raise ConfigError(f"harmony.{name} must be > 0 (a fraction of each variable's range), got {v!r}")
        if self.init not in ("uniform", "lhs"):
            raise ConfigError(f"harmony.init must be 'uniform' or 'lhs', got {self.init!r}")
        if self.patience is not None and self.patience < 1:
            raise ConfigError(f"harmony.patience must be None or >= 1, got {self.patience!r}")


@dataclass
class HarmonyResult:
    """Outcome of :func:`harmony_search`.

    Attributes
    ----------
    x : ndarray of shape (D,)
        Best harmony.
    fun : float
        Its objective value.
    iterations : int
        Improvisation rounds run.
    evaluations : int
        Objective evaluations (harmonies scored), the initial memory included.
    stop_reason : StopReason
    memory : ndarray of shape (HMS, D)
        Final harmony memory, best first.
    memory_fun : ndarray of shape (HMS,)
        Objective values of ``memory``.
    history : ndarray of shape (iterations + 1,)
        Best value after the initial memory and after each round.
    """

    x: NDArray[np.float64]
    fun: float
    iterations: int
    evaluations: int
    stop_reason: StopReason
    memory: NDArray[np.float64]
    memory_fun: NDArray[np.float64]
    history: NDArray[np.float64] = field(repr=False)


def _check_bounds(bounds: ArrayLike, name: str = "bounds") -> NDArray[np.float64]:
    try:
        b = np.asarray(bounds, dtype=float)
    except (TypeError, ValueError):
        raise ShapeError(f"{name} must be a numeric array of shape (D, 2) [lower, upper]") from None
    if b.ndim != 2 or b.shape[1] != 2 or b.shape[0] < 1:
        raise ShapeError(f"{name} must have shape (D, 2) of [lower, upper] per variable, got {b.shape}")
    if all(math.isfinite(lo) and lo <= hi < math.inf for lo, hi in b.tolist()):  # a valid box, on floats
        return b
    if not np.all(np.isfinite(b)):
        raise InputError(f"{name} must be finite, got {b.tolist()}")
    bad = np.flatnonzero(b[:, 1] < b[:, 0])
    if bad.size:
        i = int(bad[0])
        raise InputError(f"{name}[{i}] is inverted: lower {b[i, 0]} > upper {b[i, 1]}")
    return b


def harmony_search(
    objective: Callable[[NDArray[np.float64]], ArrayLike],
    bounds: ArrayLike,
    *,
    initial: ArrayLike | None = None,
    config: HarmonyConfig | None = None,
    rng: int | np.random.Generator | None = None,
    spread: ArrayLike | None = None,
) -> HarmonyResult:
    """Minimise ``objective`` over a box with Harmony Search.

    Parameters
    ----------
    objective : callable
        ``objective(X)`` with ``X`` of shape (B, D) returns B objective values (lower is better). Non-finite values
        are treated as +inf.
    bounds : array_like of shape (D, 2)
        [lower, upper] of each variable. A variable with lower == upper is held fixed.
    initial : array_like of shape (K, D) or (D,), optional
        Initial guesses seeded into the memory (clipped to the bounds); the rest of the memory is drawn uniformly
        inside the bounds. At most ``memory_size`` guesses are used.
    config : HarmonyConfig, optional
        Parameters; defaults to the paper's.
    rng : int or numpy.random.Generator, optional
        Source of every random choice (default: seed 0).
    spread : array_like of shape (D,), optional
        Per variable, the smallest move of the best harmony that counts as an improvement for ``patience`` (a move
        farther than it in any variable counts). None: every lower best value counts.

    Returns
    -------
    HarmonyResult
    """
    cfg = config or HarmonyConfig()
    gen = as_rng(rng)
    b = _check_bounds(bounds)
    lo, hi = b[:, 0], b[:, 1]
    hms = cfg.memory_size
    tol_x = _spread_tolerance(spread, b.shape[0])

    def evaluate(X: NDArray[np.float64]) -> NDArray[np.float64]:
        f = np.asarray(objective(X), dtype=float).reshape(-1)
        if f.shape[0] != X.shape[0]:
            raise ShapeError(f"objective returned {f.shape[0]} values for a batch of {X.shape[0]} harmonies")
        return np.where(np.isfinite(f), f, np.inf)

    memory = _initial_memory(cfg, gen, lo, hi, initial)
    whole = getattr(objective, "run_search", None)
    if whole is not None:
        # a compiled search (see hsmap.registration.fitness.FieldObjective): the same rounds, the same draws
        fun = np.empty(hms)
        it, history, state = _search_compiled(whole, memory, fun, b, cfg, gen, tol_x)
    else:
        fun = evaluate(memory)
        order = np.argsort(fun, kind="stable")
        memory, fun = np.ascontiguousarray(memory[order]), np.ascontiguousarray(fun[order])
        # a compiled fast path for chunks of rounds, else rounds calling `evaluate`
        runner = getattr(objective, "run_chunk", None) or functools.partial(_run_chunk, evaluate)
        it, history, state = _improvise(runner, memory, fun, b, cfg, gen, tol_x)
    stop = {0: StopReason.MAX_ITERATIONS, 1: StopReason.CONVERGED,
            2: StopReason.NO_IMPROVEMENT if spread is None else StopReason.SETTLED}[int(state[2])]
    evaluations = hms + it * cfg.batch_size
    return HarmonyResult(
        x=memory[0].copy(),
        fun=float(fun[0]),
        iterations=it,
        evaluations=evaluations,
        stop_reason=stop,
        memory=memory,
        memory_fun=fun,
        history=np.asarray(history),
    )


def _improvise(runner: Callable, memory: NDArray[np.float64], fun: NDArray[np.float64], b: NDArray[np.float64],
               cfg: HarmonyConfig, gen: np.random.Generator, tol_x: NDArray[np.float64]
               ) -> tuple[int, NDArray[np.float64], NDArray[np.int64]]:
    """The rounds of improvisation on ``memory`` and its values ``fun`` (both updated in place, sorted best
    first), run in chunks by ``runner``: the rounds done, the best value after each round (first: before any) and
    the runner's state (last chunk's rounds, rounds without improvement, stop code)."""
    lo, hi = b[:, 0], b[:, 1]
    span = hi - lo
    hms, dim, batch = cfg.memory_size, b.shape[0], cfg.batch_size
    variant = Variant(cfg.variant)
    anchor = memory[0].copy()  # the best harmony where the last counted improvement left it
    history = np.empty(cfg.max_iterations + 1)
    history[0] = fun[0]
    state = np.zeros(3, dtype=np.int64)  # rounds done in the last chunk, rounds without improvement, stop code
    patience = cfg.patience if cfg.patience is not None else cfg.max_iterations + 1
    it = 0
    while it < cfg.max_iterations and state[2] == 0:
        # the random numbers of draw_rounds rounds at once, in the order the compiled search draws them
        c = min(cfg.draw_rounds, cfg.max_iterations - it)
        par, bw = _round_rates(cfg, variant, np.arange(it, it + c))
        draws = (
            gen.integers(0, hms, size=(c, batch, dim)),
            gen.random((c, batch, dim)) < cfg.hmcr,
            gen.random((c, batch, dim)),
            gen.uniform(-1.0, 1.0, (c, batch, dim)),
            lo + gen.random((c, batch, dim)) * span,
        )
        runner(memory, fun, *draws, par, bw, lo, hi, span, history[it:], state, variant is Variant.GLOBAL_BEST,
               patience, cfg.convergence_tol, cfg.min_improvement, tol_x, anchor)
        it += int(state[0])
    return it, history[: it + 1], state


def _search_compiled(search: Callable, memory: NDArray[np.float64], fun: NDArray[np.float64], b: NDArray[np.float64],
                     cfg: HarmonyConfig, gen: np.random.Generator, tol_x: NDArray[np.float64]
                     ) -> tuple[int, NDArray[np.float64], NDArray[np.int64]]:
    """:func:`_improvise`'s rounds, the first memory's scoring and sorting included, in one compiled call
    ``search`` (:meth:`hsmap.registration.fitness.FieldObjective.run_search`): ``memory`` sorted in place, its
    values written to ``fun``; the rounds done, the best value after each round (first: before any) and the
    state (last chunk's rounds, rounds without improvement, stop code)."""
    lo, hi = b[:, 0], b[:, 1]
    history = np.empty(cfg.max_iterations + 1)
    state = np.zeros(3, dtype=np.int64)
    patience = cfg.patience if cfg.patience is not None else cfg.max_iterations + 1
    par, bw = _all_rates(cfg.variant, cfg.max_iterations, cfg.par, cfg.bandwidth, cfg.par_min, cfg.par_max,
                         cfg.bw_min, cfg.bw_max)
    it = search(gen, memory, fun, cfg.draw_rounds, cfg.batch_size, cfg.hmcr, par, bw, lo, hi, hi - lo, history,
                state, cfg.variant == Variant.GLOBAL_BEST.value, patience, cfg.max_iterations, cfg.convergence_tol,
                cfg.min_improvement, tol_x)
    return it, history[: it + 1], state


@functools.lru_cache(maxsize=64)
def _all_rates(variant: str, max_iterations: int, par: float, bandwidth: float, par_min: float, par_max: float,
               bw_min: float, bw_max: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Every round's pitch adjustment rate and bandwidth (:func:`_round_rates`), read-only (shared by the
    searches of one configuration)."""
    cfg = HarmonyConfig(variant=variant, max_iterations=max_iterations, par=par, bandwidth=bandwidth,
                        par_min=par_min, par_max=par_max, bw_min=bw_min, bw_max=bw_max)
    rates = _round_rates(cfg, Variant(variant), np.arange(max_iterations))
    for r in rates:
        r.flags.writeable = False
    return rates


def _spread_tolerance(spread: ArrayLike | None, dim: int) -> NDArray[np.float64]:
    """``spread`` checked (dim finite values >= 0), or -1 per variable where it is None (every improvement
    counts)."""
    if spread is None:
        return np.full(dim, -1.0)
    tol_x = np.asarray(spread, dtype=float).reshape(-1)
    if tol_x.shape == (dim,) and all(0.0 <= v < math.inf for v in tol_x.tolist()):  # valid, on floats
        return tol_x
    if tol_x.shape != (dim,) or not np.all(np.isfinite(tol_x) & (tol_x >= 0)):
        raise ShapeError(f"spread must hold {dim} finite values >= 0 (one per variable), got {quote(spread)}")
    return tol_x


def _initial_memory(cfg: HarmonyConfig, gen: np.random.Generator, lo: NDArray[np.float64], hi: NDArray[np.float64],
                    initial: ArrayLike | None) -> NDArray[np.float64]:
    """The first harmony memory (memory_size, D): drawn in the box (``init``: Latin hypercube or uniform), its
    first rows replaced by the finite ``initial`` guesses clipped to the box."""
    hms, dim, span = cfg.memory_size, len(lo), hi - lo
    if cfg.init == "lhs":
        strata = np.argsort(gen.random((hms, dim)), axis=0)
        memory = lo + (strata + gen.random((hms, dim))) / hms * span
    else:
        memory = lo + gen.random((hms, dim)) * span
    if initial is not None:
        init = np.atleast_2d(np.asarray(initial, dtype=float))
        if init.ndim != 2 or init.shape[1] != dim:
            raise ShapeError(f"initial guesses must have shape (K, {dim}), got {np.asarray(initial).shape}")
        if not np.isfinite(init).all():
            init = init[np.all(np.isfinite(init), axis=1)]
        init = init[:hms]
        # np.clip's arithmetic (lo <= hi), without its dispatch
        memory[: len(init)] = np.minimum(np.maximum(init, lo), hi)
    return memory


def _round_rates(cfg: HarmonyConfig, variant: Variant, its: NDArray[np.int64]
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The pitch adjustment rate and bandwidth of rounds ``its``: rising and shrinking over the run (IHS), else
    constant."""
    if variant is Variant.IHS:
        frac = its / max(cfg.max_iterations - 1, 1)
        return (cfg.par_min + (cfg.par_max - cfg.par_min) * frac,
                cfg.bw_max * np.exp(np.log(cfg.bw_min / cfg.bw_max) * frac))
    return np.full(len(its), cfg.par), np.full(len(its), cfg.bandwidth)


def _run_chunk(evaluate, memory, fun, pick, consider, adjust_u, step, rand, par, bw, lo, hi, span, history, state,
               global_best, patience, convergence_tol, min_improvement, spread, anchor) -> None:
    """Run up to ``len(pick)`` improvisation rounds in place (the reference for the compiled runners).

    ``memory`` (HMS, D) and ``fun`` (HMS,) are sorted best first and updated in place; ``history[k + 1]`` gets
    the best value after round k; ``state`` = [rounds done, rounds without improvement, stop code (0 running or
    max-iterations, 1 converged, 2 no improvement)] is updated in place; ``anchor`` (D,): the best harmony where the
    last improvement that moved it farther than ``spread`` (negative: any improvement) left it, updated in place.
    """
    hms, dim = memory.shape
    cols = np.arange(dim)
    stale = int(state[1])
    state[0] = 0
    for k in range(len(pick)):
        # improvise a batch: memory consideration, pitch adjustment, random selection, per variable
        new = memory[pick[k], cols]
        adjust = consider[k] & (adjust_u[k] < par[k])
        if global_best:
            new = np.where(adjust, memory[0], new)
        else:
            new = new + adjust * step[k] * (bw[k] * span)
        new = np.where(consider[k], new, rand[k])
        np.clip(new, lo, hi, out=new)
        f_new = evaluate(new)
        # keep the best HMS of memory + batch (stable: ties keep the older harmony)
        all_x = np.concatenate([memory, new])
        all_f = np.concatenate([fun, f_new])
        keep = np.argsort(all_f, kind="stable")[:hms]
        memory[:] = all_x[keep]
        fun[:] = all_f[keep]
        improved = history[k] - fun[0] > min_improvement
        if improved and spread[0] >= 0:
            improved = bool(np.any(np.abs(memory[0] - anchor) > spread))
            if improved:
                anchor[:] = memory[0]
        history[k + 1] = fun[0]
        stale = 0 if improved else stale + 1
        state[0] = k + 1
        state[1] = stale
        if convergence_tol >= 0 and np.isfinite(fun[-1]) and fun[-1] - fun[0] <= convergence_tol:
            state[2] = 1
            return
        if stale >= patience:
            state[2] = 2
            return
