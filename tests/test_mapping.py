"""hsmap.maps.mapping: the voxel map and the two voxel thinnings (first point per voxel, voxel centroids)."""

import numpy as np
import pytest

from hsmap.errors import InputError, ShapeError
from hsmap.maps.mapping import VoxelMap, first_per_voxel, voxel_downsample


def test_first_per_voxel_keeps_raw_points_in_input_order():
    pts = np.array([[0.01, 0.01, 0.0], [0.02, 0.02, 0.0], [0.5, 0.0, 0.0], [0.51, 0.01, 0.0], [np.nan, 0, 0]])
    np.testing.assert_array_equal(first_per_voxel(pts, 0.1), pts[[0, 2]])
    with pytest.raises(InputError):
        first_per_voxel(pts, 0.0)


def test_voxel_downsample_gives_centroids_within_the_range_limits():
    pts = np.array([[0.01, 0.01], [0.03, 0.05], [0.5, 0.0], [5.0, 0.0], [np.inf, 0.0]])
    out = voxel_downsample(pts, 0.1, min_range=0.0, max_range=1.0)
    np.testing.assert_allclose(out, [[0.02, 0.03], [0.5, 0.0]])
    with pytest.raises(InputError, match=r"cannot be downsampled .*\[1000000.0, 0.0\]"):
        voxel_downsample(np.array([[1.0, 0.0], [1e6, 0.0]]), 0.1)
    # only the points kept must fit the keys: a far point beyond max_range and a non-finite one are dropped
    np.testing.assert_allclose(voxel_downsample(pts[[0, 1, 3]], 0.1, max_range=10.0), [[0.02, 0.03], [5.0, 0.0]])
    np.testing.assert_allclose(voxel_downsample(np.array([[0.01, 0.01], [1e9, 0.0], [np.inf, 0.0], [-np.inf, 1.0]]),
                                                0.1, max_range=100.0), [[0.01, 0.01]])
    np.testing.assert_allclose(voxel_downsample(np.array([[0.01, 0.01], [np.inf, 0.0]]), 0.1), [[0.01, 0.01]])


def test_voxel_map_keeps_one_point_per_voxel():
    m = VoxelMap(2, 0.1)
    added = m.add([[0.01, 0.01], [0.02, 0.02], [0.31, 0.0]])
    assert len(added) == 2 and len(m) == 2
    assert len(m.add([[0.015, 0.015]])) == 0  # the voxel is taken
    np.testing.assert_array_equal(m.crop([0.3, 0.0], 0.05), [[0.31, 0.0]])
    with pytest.raises(ShapeError):
        m.add(np.zeros((2, 3)))


def test_averaging_voxel_map_holds_the_mean_of_every_point_a_voxel_received():
    m = VoxelMap(2, 0.1, average=True)
    added, normals = m.add([[0.01, 0.01], [0.03, 0.05], [0.31, 0.0]], [[1, 0], [0, 1], [1, 0]], return_normals=True)
    np.testing.assert_allclose(added, [[0.02, 0.03], [0.31, 0.0]])  # new voxels, at their batch's mean
    np.testing.assert_array_equal(normals, [[1, 0], [1, 0]])  # the first point's normal
    assert len(m.add([[0.05, 0.03]])) == 0  # nothing new ...
    np.testing.assert_allclose(m.crop([0.0, 0.0], 0.1), [[0.03, 0.03]])  # ... but the mean of the three moved
    np.testing.assert_array_equal(m.normals[0], [1, 0])


def test_averaging_voxel_map_takes_noise_out_of_a_wall_seen_many_times():
    """A wall at x = 1.025 seen by 50 scans with +/- 2 cm range noise: one scan's point is off by 1 cm on average,
    the mean of 50 by some 0.1 cm; the first-point map keeps the first scan's noise."""
    rng = np.random.default_rng(1)
    y = np.arange(-1.0, 1.0, 0.05) + 0.025
    first, mean = VoxelMap(2, 0.05), VoxelMap(2, 0.05, average=True)
    for _ in range(50):
        scan = np.c_[1.025 + rng.uniform(-0.02, 0.02, len(y)), y]  # within the voxel column [1.0, 1.05)
        first.add(scan)
        mean.add(scan)
    assert len(first) == len(mean) == len(y)
    err_first = np.abs(first.points[:, 0] - 1.025).mean()
    err_mean = np.abs(mean.points[:, 0] - 1.025).mean()
    assert err_mean < 0.003 < err_first


@pytest.mark.parametrize("average", [False, True])
@pytest.mark.parametrize("dim", [2, 3])
def test_voxel_map_is_the_sorted_reduction_of_its_points(dim, average):
    """The map's compiled hash-table insertion against the plain numpy reduction it replaced (np.unique on the
    voxel keys, bincount sums in input order): the same keys, points and normals bit for bit, over batches that
    fall in new voxels and in voxels already held."""
    from hsmap.maps.mapping import voxel_keys

    rng = np.random.default_rng(dim)
    batches = [rng.uniform(-3, 3, (4000, dim)) for _ in range(3)]
    normals = [rng.normal(size=(4000, dim)) for _ in range(3)]
    m = VoxelMap(dim, 0.1, average=average)
    for b, n in zip(batches, normals, strict=True):
        m.add(b, n)
    pts, nrm = np.concatenate(batches), np.concatenate(normals)
    keys, first, inverse, counts = np.unique(voxel_keys(pts, 0.1), return_index=True, return_inverse=True,
                                             return_counts=True)
    np.testing.assert_array_equal(m._keys, keys)
    np.testing.assert_array_equal(m.normals, nrm[first])
    if average:
        # the map sums batch by batch: the same sums in input order when each batch is summed and added
        sums = np.zeros((len(keys), dim))
        for b in batches:
            k = np.searchsorted(keys, voxel_keys(b, 0.1))
            for d in range(dim):
                sums[:, d] += np.bincount(k, weights=b[:, d], minlength=len(keys))
        np.testing.assert_array_equal(m.points, sums / np.bincount(inverse.ravel())[:, None])
    else:
        np.testing.assert_array_equal(m.points, pts[first])
    with pytest.raises(InputError, match="cannot be stored"):
        m.add(np.full((1, dim), 1e9))


def test_a_keyframe_map_within_a_radius_crops_as_the_whole_map():
    """keyframe_voxel_map(within=(c, r)) keeps only the points within r of c; its crops within r less two voxel
    diagonals are the whole map's, bit for bit (every voxel they reach is whole)."""
    from hsmap.slam.loopclosure import Keyframe, keyframe_voxel_map

    rng = np.random.default_rng(0)
    kfs = [Keyframe(i, float(i), rng.uniform(-8, 8, (3000, 3)), rng.normal(size=(3000, 3))) for i in range(6)]
    poses = rng.uniform(-3, 3, (6, 6)) * [1, 1, 0.1, 0.05, 0.05, 1]
    whole = keyframe_voxel_map(poses, kfs, range(6), 3, 0.2, average=True)
    part = keyframe_voxel_map(poses, kfs, range(6), 3, 0.2, average=True, within=([1.0, -1.0, 5.0], 6.0))
    assert len(part) < len(whole)
    for c in ([1.0, -1.0, 0.0], [3.0, 1.0, 0.0]):
        r = 6.0 - 2 * 0.2 * np.sqrt(3) - np.hypot(c[0] - 1.0, c[1] + 1.0)
        a, an = whole.crop_with_normals(c, r)
        b, bn = part.crop_with_normals(c, r)
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(an, bn)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("average", [False, True])
def test_a_map_built_from_parts_is_one_insertion_of_them_all(dim, average):
    """VoxelMap.from_parts: bit for bit the map one add() of the parts concatenated makes, non-finite rows dropped,
    parts without normals NaN, its arrays grown as the voxels come; a point beyond the keys' reach is refused."""
    rng = np.random.default_rng(dim)
    parts = [(rng.normal(0, s, (n, dim)), rng.normal(size=(n, dim))) for n, s in ((0, 1), (7, 1), (3000, 4),
                                                                                  (5000, 9))]
    parts[2][0][11, 0] = np.nan
    parts.append((rng.normal(0, 1, (40, dim)), None))
    built = VoxelMap.from_parts(dim, 0.3, parts, average=average)
    whole = VoxelMap(dim, 0.3, average=average)
    whole.add(np.concatenate([p for p, _ in parts]),
              np.concatenate([np.full(p.shape, np.nan) if n is None else n for p, n in parts]))
    assert len(built) == len(whole) > 1024  # past the first capacity
    np.testing.assert_array_equal(built.points, whole.points)
    np.testing.assert_array_equal(built.normals, whole.normals)
    assert len(built.add(whole.points)) == 0  # the same voxels, sorted the same way
    assert len(VoxelMap.from_parts(dim, 0.3, [])) == 0
    with pytest.raises(InputError, match="cannot be stored"):
        VoxelMap.from_parts(dim, 0.1, [(np.zeros((2, dim)), None), (np.full((1, dim), 1e9), None)])
    with pytest.raises(ShapeError):
        VoxelMap.from_parts(dim, 0.1, [(np.zeros((2, dim + 1)), None)])


@pytest.mark.parametrize("average", [False, True])
def test_a_map_filled_in_batches_is_the_map_filled_at_once(average):
    """New voxels are inserted among the stored ones in key order: batch after batch, the same voxels, points and
    normals as one insertion (means up to rounding)."""
    rng = np.random.default_rng(5)
    pts, nrm = rng.normal(0, 3, (6000, 3)), rng.normal(size=(6000, 3))
    batched, once = VoxelMap(3, 0.4, average=average), VoxelMap(3, 0.4, average=average)
    for part in np.array_split(np.arange(6000), 7):
        batched.add(pts[part], nrm[part])
    once.add(pts, nrm)
    assert np.array_equal(batched._keys, once._keys) and np.all(np.diff(batched._keys) > 0)
    np.testing.assert_allclose(batched.points, once.points, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(batched.normals, once.normals)
