"""hsmap.mapping: the voxel map and the two voxel thinnings (first point per voxel, voxel centroids)."""

import numpy as np
import pytest

from hsmap.errors import InputError, ShapeError
from hsmap.mapping import VoxelMap, first_per_voxel, voxel_downsample


def test_first_per_voxel_keeps_raw_points_in_input_order():
    pts = np.array([[0.01, 0.01, 0.0], [0.02, 0.02, 0.0], [0.5, 0.0, 0.0], [0.51, 0.01, 0.0], [np.nan, 0, 0]])
    np.testing.assert_array_equal(first_per_voxel(pts, 0.1), pts[[0, 2]])
    with pytest.raises(InputError):
        first_per_voxel(pts, 0.0)


def test_voxel_downsample_gives_centroids_within_the_range_limits():
    pts = np.array([[0.01, 0.01], [0.03, 0.05], [0.5, 0.0], [5.0, 0.0], [np.inf, 0.0]])
    out = voxel_downsample(pts, 0.1, min_range=0.0, max_range=1.0)
    np.testing.assert_allclose(out, [[0.02, 0.03], [0.5, 0.0]])
    with pytest.raises(InputError, match="cannot be downsampled"):
        voxel_downsample(np.array([[1e6, 0.0]]), 0.1)


def test_voxel_map_keeps_one_point_per_voxel():
    m = VoxelMap(2, 0.1)
    added = m.add([[0.01, 0.01], [0.02, 0.02], [0.31, 0.0]])
    assert len(added) == 2 and len(m) == 2
    assert len(m.add([[0.015, 0.015]])) == 0  # the voxel is taken
    np.testing.assert_array_equal(m.crop([0.3, 0.0], 0.05), [[0.31, 0.0]])
    with pytest.raises(ShapeError):
        m.add(np.zeros((2, 3)))
