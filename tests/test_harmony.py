import numpy as np
import pytest

from hsmap.errors import ConfigError, InputError, ShapeError
from hsmap.registration.harmony import HarmonyConfig, StopReason, Variant, harmony_search


def sphere(X):
    return (X**2).sum(1)


def rosenbrock(X):
    return (100 * (X[:, 1:] - X[:, :-1] ** 2) ** 2 + (1 - X[:, :-1]) ** 2).sum(1)


def rastrigin(X):
    return 10 * X.shape[1] + (X**2 - 10 * np.cos(2 * np.pi * X)).sum(1)


def ackley(X):
    return (-20 * np.exp(-0.2 * np.sqrt((X**2).mean(1))) - np.exp(np.cos(2 * np.pi * X).mean(1)) + 20 + np.e)


CASES = [  # function, half-width of the box, dimension, optimum, tolerance on x
    (sphere, 5.12, 4, np.zeros(4), 0.02),
    (rosenbrock, 2.048, 2, np.ones(2), 0.1),
    (rastrigin, 5.12, 3, np.zeros(3), 0.02),
    (ackley, 32.768, 3, np.zeros(3), 0.05),
]


@pytest.mark.parametrize("variant", [v.value for v in Variant])
@pytest.mark.parametrize("case", CASES, ids=[c[0].__name__ for c in CASES])
def test_reaches_known_optimum(case, variant):
    """Over six seeds: the optimum's value on every one, its position on five at least. Global-best's pitch
    adjustment copies the best harmony's variables, which stalls along Rosenbrock's flat curved valley: there only
    the value is checked."""
    f, half, dim, opt, tol = case
    cfg = HarmonyConfig(variant=variant, batch_size=10, max_iterations=3000, convergence_tol=-1)
    found = 0
    for seed in range(6):
        res = harmony_search(f, [[-half, half]] * dim, config=cfg, rng=seed)
        assert res.fun == pytest.approx(float(f(opt[None])[0]), abs=0.1), seed
        assert res.evaluations == cfg.memory_size + res.iterations * cfg.batch_size
        found += bool(np.all(np.abs(res.x - opt) <= tol))
    assert found >= (0 if (f is rosenbrock and variant == Variant.GLOBAL_BEST.value) else 5), found


def test_classic_one_at_a_time():
    cfg = HarmonyConfig(batch_size=1, max_iterations=6000, convergence_tol=-1)
    res = harmony_search(sphere, [[-5, 5]] * 3, config=cfg, rng=0)
    assert res.fun < 1e-3
    assert res.evaluations == 30 + 6000


def test_deterministic_and_seed_dependent():
    cfg = HarmonyConfig(batch_size=8, max_iterations=200)
    a = harmony_search(rastrigin, [[-5, 5]] * 3, config=cfg, rng=7)
    b = harmony_search(rastrigin, [[-5, 5]] * 3, config=cfg, rng=np.random.default_rng(7))
    c = harmony_search(rastrigin, [[-5, 5]] * 3, config=cfg, rng=8)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.history, b.history)
    assert not np.array_equal(a.x, c.x)


def test_improvements_within_the_spread_do_not_reset_patience():
    """With a spread, a best that only creeps (moves less than the spread) counts as settled: the search ends
    sooner than on every lower value, and its best lies where the patient search's does, within the spread."""
    cfg = HarmonyConfig(batch_size=8, max_iterations=2000, patience=30, convergence_tol=-1, variant="ihs")
    plain = harmony_search(sphere, [[-5, 5]] * 3, config=cfg, rng=2)
    settled = harmony_search(sphere, [[-5, 5]] * 3, config=cfg, rng=2, spread=[0.2] * 3)
    assert plain.stop_reason is StopReason.NO_IMPROVEMENT
    assert settled.stop_reason is StopReason.SETTLED
    assert settled.evaluations < plain.evaluations
    assert np.abs(settled.x - plain.x).max() < 0.4
    # the same random stream: identical up to the earlier stop
    np.testing.assert_array_equal(settled.history, plain.history[: len(settled.history)])
    with pytest.raises(ShapeError, match="spread"):
        harmony_search(sphere, [[-5, 5]] * 3, config=cfg, rng=2, spread=[0.2, 0.2])


def test_history_is_monotone_and_memory_sorted():
    res = harmony_search(ackley, [[-30, 30]] * 2, config=HarmonyConfig(batch_size=4, max_iterations=300), rng=1)
    assert np.all(np.diff(res.history) <= 0)
    assert np.all(np.diff(res.memory_fun) >= 0)
    assert res.memory.shape == (30, 2)


def test_initial_guess_seeds_memory():
    # a guess at the optimum of a deceptive function is kept: the result is at least as good as the guess
    res = harmony_search(rastrigin, [[-5, 5]] * 4, initial=[[0, 0, 0, 0]], config=HarmonyConfig(max_iterations=1),
                         rng=0)
    assert res.fun == 0.0
    np.testing.assert_array_equal(res.x, np.zeros(4))


def test_guesses_outside_bounds_are_clipped():
    res = harmony_search(sphere, [[1, 2]], initial=[[-10.0]], config=HarmonyConfig(max_iterations=5), rng=0)
    assert 1.0 <= res.x[0] <= 2.0


def test_fixed_variable_and_lhs_init():
    cfg = HarmonyConfig(init="lhs", batch_size=8, max_iterations=500, convergence_tol=-1)
    res = harmony_search(sphere, [[-1, 1], [0.5, 0.5]], config=cfg, rng=0)
    assert res.x[1] == 0.5
    assert abs(res.x[0]) < 0.01


def test_stop_rules():
    conv = harmony_search(lambda X: np.ones(len(X)), [[-1, 1]], config=HarmonyConfig(max_iterations=100), rng=0)
    assert conv.stop_reason is StopReason.CONVERGED and conv.iterations == 1
    stale = harmony_search(sphere, [[-1, 1]] * 2, config=HarmonyConfig(patience=5, convergence_tol=-1,
                                                                       max_iterations=10**6), rng=0)
    assert stale.stop_reason is StopReason.NO_IMPROVEMENT
    assert stale.iterations < 10**6
    maxit = harmony_search(sphere, [[-1, 1]] * 2, config=HarmonyConfig(max_iterations=7, convergence_tol=-1), rng=0)
    assert maxit.stop_reason is StopReason.MAX_ITERATIONS and maxit.iterations == 7


def test_non_finite_objective_values_are_worst():
    def f(X):
        out = sphere(X)
        out[X[:, 0] > 0] = np.nan
        return out

    res = harmony_search(f, [[-1, 1]] * 2, config=HarmonyConfig(batch_size=4, max_iterations=300), rng=0)
    assert res.x[0] <= 0 and np.isfinite(res.fun)


@pytest.mark.parametrize(
    "bounds, exc, match",
    [
        ([[0, 1, 2]], ShapeError, r"bounds must have shape \(D, 2\)"),
        ([[1, 0]], InputError, r"bounds\[0\] is inverted"),
        ([[0, np.inf]], InputError, "finite"),
    ],
)
def test_bad_bounds(bounds, exc, match):
    with pytest.raises(exc, match=match):
        harmony_search(sphere, bounds)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(hmcr=1.5), r"harmony.hmcr must be in \[0, 1\]"),
        (dict(memory_size=0), "harmony.memory_size must be an integer >= 1"),
        (dict(bandwidth=0), "harmony.bandwidth must be > 0"),
        (dict(variant="simulated-annealing"), "harmony.variant must be one of"),
        (dict(patience=0), "harmony.patience"),
        (dict(init="sobol"), "harmony.init"),
    ],
)
def test_bad_config(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        HarmonyConfig(**kwargs)


def test_objective_returning_wrong_size():
    with pytest.raises(ShapeError, match="objective returned 1 values for a batch of 30"):
        harmony_search(lambda X: np.zeros(1), [[0, 1]])


def test_bad_rng():
    with pytest.raises(InputError, match="rng must be"):
        harmony_search(sphere, [[0, 1]], rng="seed")
