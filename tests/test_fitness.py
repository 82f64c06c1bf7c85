import numpy as np
import pytest

from hsmap.errors import InputError
from hsmap.geometry import pose_to_matrix, transform_points
from hsmap.registration.fitness import DistanceField, KDTreeLookup, field_bounds, score, transform_batch


@pytest.mark.parametrize("dim, res, tau", [(2, 0.02, 0.1), (2, 0.05, 0.5), (3, 0.1, 0.4)])
def test_field_matches_exact_distances(rng, dim, res, tau):
    pts = rng.uniform(0, 5, (800, dim))
    field = DistanceField(pts, res, tau)
    exact = KDTreeLookup(pts, tau)
    q = rng.uniform(-1, 6, (5000, dim))
    err = np.abs(field(q) - exact(q))
    # nodes hold exact distances; multilinear interpolation between them is off by at most about a cell
    assert err.mean() < 0.1 * res
    assert err.max() < 1.0 * res
    # far from everything, the field reads the truncation
    assert field(np.full((1, dim), 100.0))[0] == pytest.approx(tau)


@pytest.mark.parametrize("dim, res, tau", [(2, 0.05, 0.3), (3, 0.1, 0.3), (3, 0.07, 0.25)])
def test_every_node_holds_its_exact_truncated_distance(rng, dim, res, tau):
    """Each node (centre origin + (index + 1/2) res) holds min(distance to the nearest point, truncation), to
    float32's precision: a splat that left out a node it could lower (the 3D splat visits only the ball of the
    truncation) would show here."""
    from scipy.spatial import cKDTree

    pts = rng.uniform(0, 2, (300, dim))
    field = DistanceField(pts, res, tau)
    idx = np.stack(np.meshgrid(*[np.arange(n) for n in field.shape], indexing="ij"), -1).reshape(-1, dim)
    centres = field.origin + (idx + 0.5) * res
    d, _ = cKDTree(pts).query(centres)
    np.testing.assert_allclose(field.values.reshape(-1), np.minimum(d, tau), rtol=0, atol=1e-6)


@pytest.mark.parametrize("dim", [2, 3])
def test_batched_kernel_matches_numpy(rng, dim):
    pts = rng.uniform(0, 4, (500, dim))
    field = DistanceField(pts, 0.05, 0.3)
    src = rng.uniform(0, 4, (200, dim))
    poses = rng.normal(0, 0.2, (7, 3 if dim == 2 else 6))
    mean, inl = field.score_batch(poses, src)
    d = field(transform_batch(poses, src))
    np.testing.assert_allclose(mean, d.mean(1), atol=1e-6)
    np.testing.assert_allclose(inl, (d < 0.3 * (1 - 1e-6)).mean(1))


@pytest.mark.parametrize("dim", [2, 3])
def test_transform_batch_matches_matrices(rng, dim):
    pts = rng.normal(size=(10, dim))
    poses = rng.normal(size=(3, 3 if dim == 2 else 6))
    out = transform_batch(poses, pts)
    for i in range(3):
        np.testing.assert_allclose(out[i], transform_points(pose_to_matrix(poses[i]), pts), atol=1e-12)


def test_fitness_terms(rng):
    tgt = rng.uniform(0, 5, (1000, 2))
    lk = KDTreeLookup(tgt, 0.2)
    perfect = score(np.zeros(3), tgt, lk, inlier_weight=1.0)
    assert perfect.value[0] == pytest.approx(0.0) and perfect.inlier_ratio[0] == 1.0
    far = score(np.array([100.0, 0, 0]), tgt, lk, inlier_weight=0.5)
    assert far.value[0] == pytest.approx(1.5) and far.inlier_ratio[0] == 0.0
    # the field back end gives the same scores
    fl = DistanceField(tgt, 0.02, 0.2)
    poses = np.array([[0.05, -0.02, 0.01], [0.3, 0.1, 0.2]])
    np.testing.assert_allclose(score(poses, tgt, fl).value, score(poses, tgt, lk).value, atol=0.05)


def test_bad_field_parameters(rng):
    with pytest.raises(InputError, match="threshold must be > 0"):
        DistanceField(rng.normal(size=(5, 2)), 0.05, 0.0)
    with pytest.raises(InputError, match="resolution must be > 0"):
        DistanceField(rng.normal(size=(5, 2)), -1.0, 0.2)
    with pytest.raises(InputError, match="threshold must be > 0"):
        KDTreeLookup(rng.normal(size=(5, 2)), -0.1)


@pytest.mark.parametrize("dim", [2, 3])
def test_field_grows_incrementally(rng, dim):
    a = rng.uniform(0, 4, (400, dim))
    b = rng.uniform(0, 4, (400, dim))
    bounds = [np.full(dim, -0.5), np.full(dim, 4.5)]
    grown = DistanceField(a, 0.05, 0.3, bounds=bounds)
    grown.add(b)
    whole = DistanceField(np.vstack([a, b]), 0.05, 0.3, bounds=bounds)
    np.testing.assert_allclose(grown.values, whole.values)
    q = rng.uniform(0, 4, (1000, dim))
    np.testing.assert_allclose(grown(q), KDTreeLookup(np.vstack([a, b]), 0.3)(q), atol=0.05)
    assert grown.covers(np.zeros(dim), np.full(dim, 4.0)) and not grown.covers(np.zeros(dim), np.full(dim, 5.0))
    with pytest.raises(InputError, match="field bounds"):
        DistanceField(a, 0.05, 0.3, bounds=[np.ones(dim), np.zeros(dim)])



@pytest.mark.parametrize("dim", [2, 3])
def test_a_field_on_a_recycled_grid_is_a_fresh_one(rng, dim):
    """DistanceField(recycle=old): the same values as a fresh field, in the old grid's memory where it is large
    enough, in new memory where it is not."""
    a, na = rng.uniform(0, 4, (400, dim)), rng.normal(size=(400, dim))
    b, nb = rng.uniform(1, 3, (300, dim)), rng.normal(size=(300, dim))
    near = "nearest" if dim == 2 else "nearest_index"
    old = DistanceField(a, 0.05, 0.3, normals=na)
    stores = dict(old._stores)
    smaller = DistanceField(b, 0.05, 0.3, normals=nb, recycle=old)
    assert all(smaller._stores[k] is stores[k] for k in ("padded", near))
    fresh = DistanceField(b, 0.05, 0.3, normals=nb)
    np.testing.assert_array_equal(smaller.values, fresh.values)
    np.testing.assert_array_equal(getattr(smaller, near), getattr(fresh, near))
    larger = DistanceField(a, 0.04, 0.3, recycle=smaller)  # without normals: no nearest grid
    assert larger._stores["padded"] is not stores["padded"] and larger.keeps_nearest is False
    np.testing.assert_array_equal(larger.values, DistanceField(a, 0.04, 0.3).values)
    q = rng.uniform(0, 4, (200, dim))
    np.testing.assert_array_equal(larger(q), DistanceField(a, 0.04, 0.3)(q))

@pytest.mark.parametrize("dim", [2, 3])
def test_a_field_within_a_box_answers_as_the_whole_one_there(rng, dim):
    """field_bounds(within=box): a corner on the whole field's nodes, inside its volume; that part's nodes hold the
    whole field's distances and nearest points, and look-ups inside the box read the same; a box beside the
    points gives the whole volume."""
    pts, nrm = rng.uniform(0, 6, (1500, dim)), rng.normal(size=(1500, dim))
    res, tau = 0.05, 0.3
    whole_bounds = field_bounds(pts, res, tau)
    lo = pts.min(axis=0) - (tau + 2 * res)
    np.testing.assert_array_equal(whole_bounds, [lo, pts.max(axis=0) + (tau + 2 * res)])
    box = np.array([np.full(dim, 1.23), np.full(dim, 3.1)])
    b = field_bounds(pts, res, tau, box)
    cells = (b[0] - lo) / res
    np.testing.assert_allclose(cells, np.round(cells), atol=1e-9)
    assert np.all(b[0] <= box[0] - 2 * res) and np.all(b[0] > box[0] - 4 * res) and np.all(b[1] <= whole_bounds[1])
    whole = DistanceField(pts, res, tau, normals=nrm)
    part = DistanceField(pts, res, tau, bounds=b, normals=nrm)
    assert part.values.size < 0.3 * whole.values.size
    at = tuple(slice(int(round(c)), int(round(c)) + n) for c, n in zip(cells, part.shape, strict=True))
    np.testing.assert_allclose(part.values, whole.values[at], atol=1e-6)
    if dim == 2:
        np.testing.assert_allclose(part.nearest, whole.nearest[at], atol=1e-12)
    q = rng.uniform(box[0], box[1], (3000, dim))
    np.testing.assert_allclose(part(q), whole(q), atol=1e-6)
    np.testing.assert_array_equal(field_bounds(pts, res, tau, box + 20.0), whole_bounds)


@pytest.mark.parametrize("spread", [None, 0.05])
@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("variant", ["classic", "ihs", "global-best"])
def test_compiled_harmony_rounds_match_the_python_loop(rng, dim, variant, spread):
    from hsmap.registration.fitness import FieldObjective
    from hsmap.registration.harmony import HarmonyConfig, harmony_search

    tgt = rng.uniform(0, 4, (600, dim))
    src = tgt[rng.choice(600, 150, replace=False)] - 0.2
    field = DistanceField(tgt, 0.05, 0.4)
    fast = FieldObjective(src, field, 1.0)
    bounds = [[-0.5, 0.5]] * (3 if dim == 2 else 6)
    cfg = HarmonyConfig(batch_size=8, max_iterations=100, patience=15, variant=variant)
    sp = None if spread is None else [spread] * len(bounds)
    a = harmony_search(fast, bounds, config=cfg, rng=4, spread=sp)
    b = harmony_search(lambda X: fast(X), bounds, config=cfg, rng=4, spread=sp)  # a plain callable: the Python loop
    # the same random stream and decisions; the fitness sums are compiled with fastmath, whose vectorised
    # reductions may add in an order that depends on the arrays' memory alignment: full test runs in fresh
    # clones saw the two paths 1.1e-16 apart in 3-D
    np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.history, b.history, rtol=0, atol=1e-12)
    assert (a.iterations, a.evaluations, a.stop_reason) == (b.iterations, b.evaluations, b.stop_reason)


def test_the_compiled_search_leaves_the_generator_where_the_python_loop_does(rng):
    """The whole search in one compiled call draws the same random numbers as the Python rounds: the caller's
    Generator continues from the same state (the next registration of a run sees the same stream)."""
    from hsmap.registration.fitness import FieldObjective
    from hsmap.registration.harmony import HarmonyConfig, harmony_search

    tgt = rng.uniform(0, 4, (600, 2))
    src = tgt[rng.choice(600, 150, replace=False)] - 0.2
    fast = FieldObjective(src, DistanceField(tgt, 0.05, 0.4), 1.0)
    cfg = HarmonyConfig(batch_size=16, max_iterations=500, patience=15, convergence_tol=1e-6, init="lhs")
    ga, gb = np.random.default_rng(11), np.random.default_rng(11)
    a = harmony_search(fast, [[-0.5, 0.5]] * 3, initial=[[0.1, 0.0, 0.0]], config=cfg, rng=ga, spread=[0.03] * 3)
    b = harmony_search(lambda X: fast(X), [[-0.5, 0.5]] * 3, initial=[[0.1, 0.0, 0.0]], config=cfg, rng=gb,
                       spread=[0.03] * 3)
    assert a.iterations == b.iterations and a.iterations < cfg.max_iterations
    np.testing.assert_array_equal(a.memory, b.memory)
    assert ga.random() == gb.random()


@pytest.mark.parametrize("dim", [2, 3])
def test_parallel_fitness_is_the_same_for_any_number_of_threads(rng, dim):
    """Harmony rounds large enough to be scored in parallel (batch x points above the kernel's threshold) give
    the same search, bit for bit, on one thread and on two: each harmony is summed by one thread."""
    from hsmap._threads import using_threads
    from hsmap.registration import _kernels
    from hsmap.registration.fitness import FieldObjective
    from hsmap.registration.harmony import HarmonyConfig, harmony_search

    tgt = rng.uniform(0, 4, (3000, dim))
    src = tgt[rng.choice(3000, 1200, replace=False)] - 0.2
    field = DistanceField(tgt, 0.05, 0.4)
    fast = FieldObjective(src, field, 1.0)
    cfg = HarmonyConfig(batch_size=32, max_iterations=40, patience=10)
    assert cfg.batch_size * len(src) >= _kernels.PARALLEL_MIN_WORK  # the parallel path
    bounds = [[-0.5, 0.5]] * (3 if dim == 2 else 6)
    poses = rng.uniform(-0.5, 0.5, (64, 3 if dim == 2 else 6))
    out = {}
    for n in (1, 2):
        with using_threads(n):
            out[n] = (harmony_search(fast, bounds, config=cfg, rng=7), field.score_batch(poses, src))
    a, b = out[1][0], out[2][0]
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.history, b.history)
    assert (a.iterations, a.evaluations) == (b.iterations, b.evaluations)
    for x, y in zip(out[1][1], out[2][1], strict=True):
        np.testing.assert_array_equal(x, y)


def test_a_3d_field_splatted_in_slabs_is_the_same_for_any_number_of_threads(rng):
    """A large 3D splat is split into slabs along x between the compute threads: the same field, bit for bit,
    built at once and grown, on one thread and on two; and the same as splatting point by point."""
    from hsmap._threads import using_threads
    from hsmap.registration.fitness import PARALLEL_MIN_SPLAT

    pts = rng.uniform(0, 3, (6000, 3))
    fields = {}
    for n in (1, 2):
        with using_threads(n):
            f = DistanceField(pts[:4000], 0.1, 0.3, bounds=[[-0.5] * 3, [3.5] * 3])
            f.add(pts[4000:])
        fields[n] = f.values
    assert 2000 * (2 * f._radius + 1) ** 3 >= PARALLEL_MIN_SPLAT  # both splats took the parallel path
    np.testing.assert_array_equal(fields[1], fields[2])
    one = DistanceField(pts[:1], 0.1, 0.3, bounds=[[-0.5] * 3, [3.5] * 3])
    for p in pts[1:]:
        one.add(p[None])
    np.testing.assert_array_equal(one.values, fields[2])


def test_thread_count_from_the_environment(monkeypatch):
    import numba

    from hsmap._threads import compute_threads, using_threads
    from hsmap.errors import ConfigError

    most = numba.config.NUMBA_NUM_THREADS
    monkeypatch.delenv("HSMAP_THREADS", raising=False)
    assert compute_threads() == most
    monkeypatch.setenv("HSMAP_THREADS", "1")
    assert compute_threads() == 1
    assert compute_threads(most + 5) == most
    before = numba.get_num_threads()
    with using_threads() as n:
        assert n == 1 and numba.get_num_threads() == 1
        with using_threads() as inner:  # an inner block keeps the outer count
            assert inner == 1 and numba.get_num_threads() == 1
            with using_threads(most) as explicit, using_threads() as innermost:
                assert explicit == innermost == most and numba.get_num_threads() == most
            assert numba.get_num_threads() == 1
        assert numba.get_num_threads() == 1
    assert numba.get_num_threads() == before
    for bad in ("0", "two"):
        monkeypatch.setenv("HSMAP_THREADS", bad)
        with pytest.raises(ConfigError, match="HSMAP_THREADS"):
            compute_threads()


def test_3d_field_keeps_each_nodes_nearest_point(rng):
    """With normals, a 3D field keeps per node the index of the point nearest to the node's centre (the
    correspondences of a point-to-plane refinement at one look-up), also for points added later."""
    a, b = rng.uniform(0, 2, (300, 3)), rng.uniform(0, 2, (200, 3))
    na, nb = rng.normal(size=(300, 3)), rng.normal(size=(200, 3))
    f = DistanceField(a, 0.1, 0.3, bounds=[np.zeros(3), np.full(3, 2.0)], normals=na)
    assert f.keeps_nearest and f.nearest is None and f.nearest_index.dtype == np.int32
    f.add(b, nb)
    pts, nrm = np.vstack([a, b]), np.vstack([na, nb])
    np.testing.assert_array_equal(f.nearest_points, pts)
    np.testing.assert_array_equal(f.nearest_normals, nrm)
    cells = np.argwhere(f.nearest_index >= 0)
    assert len(cells) > 0.5 * f.nearest_index.size
    centres = f.origin + (cells + 0.5) * f.resolution
    d = np.linalg.norm(centres[:, None, :] - pts[None], axis=2)
    got = f.nearest_index[tuple(cells.T)]
    np.testing.assert_allclose(d[np.arange(len(cells)), got], d.min(axis=1), atol=1e-6)
    np.testing.assert_allclose(f.values[tuple(cells.T)], d.min(axis=1), atol=1e-6)  # float32
    with pytest.raises(InputError, match="normals"):
        f.add(b)


_SCORES = """
import sys
import numpy as np
from hsmap.registration.fitness import DistanceField, FieldObjective
from hsmap.registration.harmony import HarmonyConfig, harmony_search
rng = np.random.default_rng(0)
out = []
for dim in (2, 3):
    pts = rng.uniform(0, 5, (3000, dim))
    field = DistanceField(pts, 0.05 if dim == 2 else 0.1, 0.3)
    for n in (16, 400):
        out.append(field.score_batch(rng.uniform(-0.3, 0.3, (n, 3 if dim == 2 else 6)),
                                     rng.uniform(0, 5, (150, dim)))[0])
    src = pts[rng.choice(3000, 150)] - 0.1
    hs = harmony_search(FieldObjective(src, field, 1.0), [[-0.5, 0.5]] * (3 if dim == 2 else 6),
                        config=HarmonyConfig(batch_size=16, max_iterations=100), rng=3)
    out.append(np.r_[hs.x, hs.history])
np.save(sys.argv[1], np.concatenate(out))
"""


def test_a_run_that_compiles_the_kernels_scores_as_one_that_loads_them(tmp_path):
    """The same seed gives the same result on the first run after an install (numba compiles the kernels) and on
    the next (it loads them from its cache): the field scores and a Harmony Search, bit for bit, in two fresh
    processes sharing an empty cache. With fastmath's 'reassoc' on the inlined scoring function they differed in
    the last bit (687 of 700 values here), which a SLAM run turns into another trajectory."""
    import os
    import subprocess
    import sys

    script = tmp_path / "scores.py"
    script.write_text(_SCORES)
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    for run in ("compiled", "cached"):
        subprocess.run([sys.executable, str(script), str(tmp_path / f"{run}.npy")], env=env, check=True,
                       timeout=600)
    assert any((tmp_path / "cache").rglob("*.nbi"))  # the second run had a cache to load
    np.testing.assert_array_equal(np.load(tmp_path / "compiled.npy"), np.load(tmp_path / "cached.npy"))
