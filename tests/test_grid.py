import numpy as np
import pytest

from hsmap.errors import InputError
from hsmap.grid import GridGeometry


def test_world_pixel_roundtrip(rng):
    g = GridGeometry((40, 60), 0.05, (-1.0, 2.0))
    xy = rng.uniform([-1, 2], [2, 4], (100, 2))
    np.testing.assert_allclose(g.pixel_to_world(g.world_to_pixel(xy)), xy, atol=1e-12)


def test_row_flip_and_origin():
    g = GridGeometry((10, 20), 0.5, (1.0, -2.0))
    # lower-left pixel centre
    np.testing.assert_allclose(g.pixel_to_world([9, 0]), [1.25, -1.75])
    # top-right pixel centre
    np.testing.assert_allclose(g.pixel_to_world([0, 19]), [1.0 + 9.75, -2.0 + 4.75])
    np.testing.assert_array_equal(g.world_to_index([[1.01, -1.99], [10.9, 2.9]]), [[9, 0], [0, 19]])


def test_covering_and_extent():
    g = GridGeometry.covering([0, 0], [3.0, 1.0], 0.1, margin=0.5)
    assert g.shape == (20, 40)
    assert g.extent() == pytest.approx((-0.5, 3.5, -0.5, 1.5))


def test_bad_resolution():
    with pytest.raises(InputError, match="resolution"):
        GridGeometry((10, 10), 0.0)
