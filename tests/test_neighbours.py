"""hsmap.registration.neighbours: exact bounded nearest neighbours on a voxel grid, the KD-tree's answers bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from hsmap._threads import using_threads
from hsmap.errors import InputError, ShapeError
from hsmap.registration.neighbours import NeighbourGrid, grid_fits

PROFILE = dict(deadline=None, derandomize=True, database=None, max_examples=60)


def _same_as_tree(points, queries, cell, bound, threads=1):
    tree = cKDTree(points)
    d0, i0 = tree.query(queries, distance_upper_bound=bound)
    with using_threads(threads):
        d, i = NeighbourGrid(points, cell).query(queries, bound)
    np.testing.assert_array_equal(d, d0)
    np.testing.assert_array_equal(i, i0)
    return d


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("bound_cells", [0.3, 1.0, 2.0, 3.7])
def test_grid_answers_as_the_kdtree(dim, bound_cells):
    """Surface-like clouds (the maps registration queries) and queries near them, inside and far outside the
    grid: the same distances and rows as cKDTree, inf and len(points) where nothing is within the bound."""
    rng = np.random.default_rng(dim)
    pts = rng.uniform(-4, 4, (5000, dim))
    pts[:, -1] = np.round(pts[:, -1])  # planes (lines) a metre apart, many cells empty
    q = np.concatenate([pts[:3000] + rng.normal(0, 0.1, (3000, dim)), rng.uniform(-9, 9, (500, dim))])
    d = _same_as_tree(pts, q, 0.2, 0.2 * bound_cells)
    assert np.isfinite(d).any() and np.isinf(d).any()


@pytest.mark.parametrize("threads", [1, 2])
def test_a_split_query_answers_as_one(threads):
    """A large query is split between the compute threads; the answer does not depend on how many."""
    rng = np.random.default_rng(3)
    pts = rng.uniform(-5, 5, (20000, 3))
    _same_as_tree(pts, rng.uniform(-6, 6, (4567, 3)), 0.2, 0.2, threads=threads)


@settings(**PROFILE)
@given(dim=st.sampled_from([2, 3]), n=st.integers(1, 300), seed=st.integers(0, 2**31),
       cell=st.floats(0.01, 2.0), bound=st.floats(0.001, 3.0), scale=st.floats(0.01, 50.0))
def test_any_cloud_any_bound(dim, n, seed, cell, bound, scale):
    """Property: for any cloud, cell and finite bound (even many cells wide), the grid answers as the tree.
    Duplicated points are left out: which of two equal points is nearest is a tie either may break."""
    rng = np.random.default_rng(seed)
    pts = np.unique(np.round(rng.normal(0, scale, (n, dim)), 6), axis=0)
    if not grid_fits(pts, cell):
        return
    _same_as_tree(pts, rng.normal(0, scale, (200, dim)), cell, bound)


@pytest.mark.parametrize("dim", [2, 3])
def test_of_equally_near_points_the_lowest_row_is_the_answer(dim):
    """Ties are real (a 2D laser's ranges are rounded to the centimetre): the lowest row wins, wherever the
    points lie in the grid, so the answer is one the caller can state."""
    a, b = np.zeros(dim), np.zeros(dim)
    a[0], b[0] = 1.0, -1.0
    for pts in (np.array([a, b]), np.array([b, a]), np.array([a, a + 5, b])):
        d, i = NeighbourGrid(pts, 0.3).query(np.zeros((1, dim)), 1.5)
        assert d[0] == 1.0 and i[0] == 0


def test_queries_that_are_not_finite_find_nothing():
    pts = np.random.default_rng(0).uniform(-1, 1, (100, 3))
    d, i = NeighbourGrid(pts, 0.2).query(np.array([[np.nan, 0, 0], [np.inf, 0, 0], [1e308, -1e308, 0]]), 0.5)
    assert np.isinf(d).all() and (i == 100).all()


def test_bad_input_names_what_was_expected():
    pts = np.zeros((10, 3))
    with pytest.raises(ShapeError, match="grid points"):
        NeighbourGrid(np.zeros((10, 4)), 0.1)
    with pytest.raises(InputError, match="grid cell"):
        NeighbourGrid(pts, 0.0)
    with pytest.raises(InputError, match="finite"):
        NeighbourGrid(np.full((3, 2), np.nan), 0.1)
    with pytest.raises(InputError, match="cells"):
        NeighbourGrid(np.array([[0.0, 0, 0], [1e4, 1e4, 1e4]]), 0.01)
    grid = NeighbourGrid(pts, 0.1)
    with pytest.raises(ShapeError, match=r"\(N, 3\)"):
        grid.query(np.zeros((4, 2)), 0.1)
    with pytest.raises(InputError, match="distance_upper_bound"):
        grid.query(np.zeros((4, 3)), np.inf)


def test_a_target_that_does_not_fit_a_grid_answers_from_its_tree():
    """RegistrationTarget.nearest: a grid where the target fits one, the KD-tree where it does not (a sparse
    cloud over a large box) or the bound is many cells wide; the same answers either way."""
    from hsmap.registration.icp import RegistrationConfig, RegistrationTarget

    rng = np.random.default_rng(5)
    dense = rng.uniform(-3, 3, (4000, 3))
    sparse = np.concatenate([dense, [[400.0, 400.0, 40.0]]])
    q = rng.uniform(-3.5, 3.5, (800, 3))
    for pts, grid in ((dense, True), (sparse, False)):
        tgt = RegistrationTarget(pts, RegistrationConfig(threshold=0.1))
        for bound in (0.1, 0.4, 2.0):
            d, i = tgt.nearest(q, bound)
            d0, i0 = cKDTree(pts).query(q, distance_upper_bound=bound)
            np.testing.assert_array_equal(d, d0)
            np.testing.assert_array_equal(i, i0)
        assert (tgt._grid is not False) == grid


@settings(**PROFILE)
@given(dim=st.sampled_from([2, 3]), n=st.integers(1, 300), seed=st.integers(0, 2**31),
       cell=st.floats(0.01, 2.0), bound=st.floats(0.001, 3.0), scale=st.floats(0.01, 20.0))
def test_a_hint_changes_no_answer(dim, n, seed, cell, bound, scale):
    """Property: hinted rows (the true answer, a near point, a far one, none, out of range; ties included, the
    points on a coarse lattice) narrow the search and leave every answer as it is without them."""
    rng = np.random.default_rng(seed)
    pts = np.round(rng.normal(0, scale, (n, dim)) / (scale / 4)) * (scale / 4)  # exact ties between neighbours
    if not grid_fits(pts, cell):
        return
    grid = NeighbourGrid(pts, cell)
    q = np.concatenate([pts + rng.normal(0, scale / 8, pts.shape), rng.normal(0, scale, (100, dim))])
    plain = grid.query(q, bound)
    for hint in (plain[1], rng.integers(-2, n + 2, len(q)), np.full(len(q), n),
                 cKDTree(pts).query(q, k=min(2, n))[1].reshape(len(q), -1)[:, -1]):
        hinted = grid.query(q, bound, hint)
        np.testing.assert_array_equal(hinted[0], plain[0])
        np.testing.assert_array_equal(hinted[1], plain[1])


def test_a_hint_must_name_rows():
    grid = NeighbourGrid(np.eye(3), 0.5)
    with pytest.raises(ShapeError, match=r"hint must be \(2,\) whole numbers"):
        grid.query(np.zeros((2, 3)), 1.0, hint=np.zeros(2))


@pytest.mark.parametrize("dim", [2, 3])
def test_a_tracked_query_answers_as_the_tree_while_its_points_move(dim):
    """Points moved a little (and now and then far) between queries, with shrinking bounds: the tracked query,
    which searches a point again only when another point could have become its nearest, answers each time as
    the tree searched afresh; and it does search again less than every point every time."""
    from hsmap.registration.neighbours import TrackedQuery

    rng = np.random.default_rng(dim + 10)
    pts = rng.uniform(-4, 4, (4000, dim))
    pts[:, -1] = np.round(pts[:, -1] * 2) / 2  # planes (lines) half a metre apart
    tree = cKDTree(pts)
    tracked = TrackedQuery(tree, 0.02)
    searched = []
    original = tracked.tree
    q = np.concatenate([pts[:1500] + rng.normal(0, 0.05, (1500, dim)), rng.uniform(-6, 6, (300, dim))])
    for step, bound in enumerate([0.3, 0.3, 0.2, 0.2, 0.1, 0.1, 0.1, 0.25]):
        q = q + rng.normal(0, 0.3 if step == 5 else 0.002, q.shape)
        tracked.tree = _Counting(original, searched)
        with using_threads(1):
            d, i = tracked(q, bound)
        d0, i0 = tree.query(q, distance_upper_bound=bound)
        np.testing.assert_array_equal(d, d0)
        np.testing.assert_array_equal(i, i0)
    assert searched[0] == len(q) and min(searched) < len(q) // 2


class _Counting:
    """A KD-tree that counts the points each query asks about."""

    def __init__(self, tree, counts):
        self.tree, self.counts = tree, counts

    def query(self, x, **kw):
        self.counts.append(len(x))
        return self.tree.query(x, **kw)
