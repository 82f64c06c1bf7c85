"""The 2D box geometry behind the scenario checks, against brute force."""

import numpy as np
import pytest

from hsmap.sim.shapes import (
    box_corners,
    box_sdf,
    boxes_overlap,
    boxes_to_mesh_arrays,
    make_box,
    points_in_polygon,
    segment_box_distance,
)


def test_box_sdf_and_corners():
    b = make_box([1.0, 2.0], [2.0, 1.0], np.pi / 2)  # 2 m along y after turning, 1 m along x
    c = box_corners(b)[0]
    np.testing.assert_allclose(np.sort(c[:, 0]), [0.5, 0.5, 1.5, 1.5], atol=1e-12)
    np.testing.assert_allclose(np.sort(c[:, 1]), [1.0, 1.0, 3.0, 3.0], atol=1e-12)
    d = box_sdf([[1.0, 2.0], [1.0, 4.0], [3.5, 2.0], [2.5, 4.0]], b[None])[:, 0]
    np.testing.assert_allclose(d, [-0.5, 1.0, 2.0, np.hypot(1.0, 1.0)], atol=1e-12)


def test_segment_box_distance_matches_brute_force(rng):
    boxes = np.array([make_box(rng.uniform(-3, 3, 2), rng.uniform(0.1, 2, 2), rng.uniform(-np.pi, np.pi))
                      for _ in range(40)])
    for _ in range(30):
        p0, p1 = rng.uniform(-5, 5, 2), rng.uniform(-5, 5, 2)
        exact = segment_box_distance(p0, p1, boxes)
        t = np.linspace(0, 1, 4001)[:, None]
        brute = np.maximum(box_sdf(p0 + t * (p1 - p0), boxes), 0).min(0)
        assert np.all(exact <= brute + 1e-9)
        np.testing.assert_allclose(exact, brute, atol=5e-3)
    # a degenerate segment (a point)
    assert segment_box_distance([0, 0], [0, 0], make_box([3, 0], [2, 2])[None])[0] == pytest.approx(2.0)


def test_boxes_overlap():
    a = make_box([0, 0], [2, 2])
    assert boxes_overlap(a, make_box([1.9, 0], [2, 2]))
    assert not boxes_overlap(a, make_box([2.0, 0], [2, 2]))  # touching
    assert not boxes_overlap(a, make_box([1.99, 0], [2, 2]), tol=0.02)  # within tolerance
    assert not boxes_overlap(a, make_box([2.3, 2.3], [1.2, 1.2], np.pi / 4))  # corner gap, needs the 2nd axes


def test_points_in_polygon_non_convex():
    L = np.array([[0, 0], [4, 0], [4, 1], [1, 1], [1, 3], [0, 3]], dtype=float)
    pts = np.array([[0.5, 0.5], [3.5, 0.5], [0.5, 2.5], [2.5, 2.0], [5, 0.5], [-0.1, 1]])
    np.testing.assert_array_equal(points_in_polygon(pts, L), [True, True, True, False, False, False])


def test_box_mesh_is_closed():
    v, t = boxes_to_mesh_arrays(np.array([make_box([0, 0], [1, 2], 0.3, 0.5, 1.5)] * 2))
    assert v.shape == (16, 3) and t.shape == (24, 3)
    # every edge of a closed surface is shared by exactly two triangles
    edges = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert np.all(counts == 2)
    # outward normals: volume by the divergence theorem is positive, 1 x 2 x 1 per box
    a, b, c = v[t[:12, 0]], v[t[:12, 1]], v[t[:12, 2]]
    assert np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6 == pytest.approx(2.0)
