import numpy as np
import pytest

from hsmap import geometry as g
from hsmap.errors import InputError, ShapeError


def test_se2_roundtrip_and_compose(rng):
    poses = np.column_stack([rng.uniform(-5, 5, (50, 2)), rng.uniform(-np.pi, np.pi, 50)])
    np.testing.assert_allclose(g.matrix_to_pose(g.pose_to_matrix(poses)), poses, atol=1e-12)
    a, b = poses[0], poses[1]
    ab = g.compose(a, b)
    np.testing.assert_allclose(g.relative(a, ab), b, atol=1e-12)
    np.testing.assert_allclose(g.compose(a, g.invert(a)), np.zeros(3), atol=1e-12)


def test_se3_roundtrip_and_convention(rng):
    poses = np.column_stack([rng.uniform(-5, 5, (50, 3)), rng.uniform(-1.2, 1.2, (50, 2)),
                             rng.uniform(-np.pi, np.pi, 50)])
    poses = poses[:, [0, 1, 2, 3, 4, 5]]
    np.testing.assert_allclose(g.matrix_to_pose(g.pose_to_matrix(poses)), poses, atol=1e-10)
    # yaw of 90 deg maps x onto y
    T = g.pose_to_matrix([1, 2, 3, 0, 0, np.pi / 2])
    np.testing.assert_allclose(g.transform_points(T, np.array([[1.0, 0, 0]])), [[1, 3, 3]], atol=1e-12)


def test_quaternion_roundtrip(rng):
    rpy = rng.uniform(-1, 1, (100, 3))
    R = g.euler_to_matrix(rpy[:, 0], rpy[:, 1], rpy[:, 2])
    q = g.matrix_to_quaternion(R)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0)
    np.testing.assert_allclose(g.quaternion_to_matrix(q), R, atol=1e-12)
    assert g.matrix_to_quaternion(R.reshape(10, 10, 3, 3)).shape == (10, 10, 4)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_quaternion_of_half_turns_and_near_them(axis):
    """Rotations by ~180 deg about x, y or z: the trace is near -1, where a conversion must not divide by the
    small w (Shepperd's method takes the x, y or z branch there)."""
    for angle in (np.pi, np.pi - 1e-7, np.pi - 0.3, -np.pi + 0.2):
        rpy = np.zeros(3)
        rpy[axis] = angle
        R = g.euler_to_matrix(*rpy)
        q = g.matrix_to_quaternion(R)
        assert q[3] >= 0
        want = np.zeros(4)
        want[axis], want[3] = np.sin(angle / 2), np.cos(angle / 2)
        want *= np.sign(want[3]) if want[3] != 0 else 1.0
        np.testing.assert_allclose(q, want, atol=1e-9)
        np.testing.assert_allclose(g.quaternion_to_matrix(q), R, atol=1e-12)


def test_quaternion_to_matrix_normalises_and_rejects_zero():
    np.testing.assert_allclose(g.quaternion_to_matrix([0, 0, 0, 2.0]), np.eye(3), atol=1e-15)
    with pytest.raises(InputError, match="zero"):
        g.quaternion_to_matrix([0, 0, 0, 0.0])
    with pytest.raises(ShapeError):
        g.quaternion_to_matrix([0, 0, 1.0])


def test_batch_transform_matches_single(rng):
    pts = rng.normal(size=(20, 2))
    poses = rng.normal(size=(4, 3))
    T = g.pose_to_matrix(poses)
    batch = g.transform_points_batch(T, pts)
    for i in range(4):
        np.testing.assert_allclose(batch[i], g.transform_points(T[i], pts), atol=1e-12)


def test_wrap_angle():
    np.testing.assert_allclose(g.wrap_angle([np.pi + 0.1, -np.pi - 0.1, 0.5]), [-np.pi + 0.1, np.pi - 0.1, 0.5])


def test_bad_shapes():
    with pytest.raises(ShapeError, match="pose must have 3"):
        g.pose_to_matrix([1, 2])
    with pytest.raises(ShapeError, match=r"points must have shape \(N, 2\)"):
        g.transform_points(np.eye(3), np.zeros((4, 3)))


def _se2_exp(twist):
    """exp of an se(2) twist (vx, vy, w): the pose after moving at that constant twist for unit time."""
    vx, vy, w = twist
    if abs(w) < 1e-12:
        return np.array([vx, vy, 0.0])
    a, b = np.sin(w) / w, (1 - np.cos(w)) / w
    return np.array([a * vx - b * vy, b * vx + a * vy, w])


def test_interpolate_poses_follows_a_constant_twist(rng):
    # a robot driving at a constant twist: the pose at fraction s is exp(s * twist) after the start, on the arc
    for _ in range(20):
        start = np.array([*rng.uniform(-5, 5, 2), rng.uniform(-np.pi, np.pi)])
        twist = np.array([*rng.uniform(-1, 1, 2), rng.uniform(-2.5, 2.5)])
        end = g.compose(start, _se2_exp(twist))
        for s in (0.0, 0.25, 0.6, 1.0):
            expected = g.compose(start, _se2_exp(s * twist))
            got = g.interpolate_poses(start, end, np.float64(s))
            np.testing.assert_allclose(got[:2], expected[:2], atol=1e-9)
            assert abs(g.wrap_angle(got[2] - expected[2])) < 1e-9
    # straight motion without turning: plain linear interpolation; across +/- pi the short way round
    np.testing.assert_allclose(g.interpolate_poses([0, 0, 0.3], [2, 1, 0.3], np.float64(0.5)), [1, 0.5, 0.3])
    mid = g.interpolate_poses([0, 0, 3.1], [0, 0, -3.1], np.float64(0.5))
    assert abs(abs(mid[2]) - np.pi) < 1e-9


def test_interpolate_poses_3d_batched(rng):
    a = np.column_stack([rng.uniform(-2, 2, (5, 3)), rng.uniform(-0.5, 0.5, (5, 3))])
    b = np.column_stack([rng.uniform(-2, 2, (5, 3)), rng.uniform(-0.5, 0.5, (5, 3))])
    np.testing.assert_allclose(g.interpolate_poses(a, b, np.zeros(5)), a, atol=1e-9)
    np.testing.assert_allclose(g.interpolate_poses(a, b, np.ones(5)), b, atol=1e-9)
    mid = g.interpolate_poses(a, b, np.full(5, 0.5))
    np.testing.assert_allclose(mid[:, :3], 0.5 * (a[:, :3] + b[:, :3]), atol=1e-9)
    # the rotation halfway: the same angle from a as to b
    Ra, Rm, Rb = (g.euler_to_matrix(p[:, 3], p[:, 4], p[:, 5]) for p in (a, mid, b))
    ang = lambda R: np.arccos(np.clip((np.trace(R, axis1=-2, axis2=-1) - 1) / 2, -1, 1))  # noqa: E731
    np.testing.assert_allclose(ang(np.swapaxes(Ra, -1, -2) @ Rm), ang(np.swapaxes(Rm, -1, -2) @ Rb), atol=1e-9)
    with pytest.raises(ShapeError):
        g.interpolate_poses(a, b[:, :3], np.zeros(5))
    with pytest.raises(ShapeError):
        g.interpolate_poses(a, b, np.zeros(4))


def test_compose_with_covariance_2d_matches_sampling():
    """The first-order covariance of a chain of uncertain 2D steps matches the spread of sampled chains."""
    rng = np.random.default_rng(3)
    steps = [np.array([0.4, 0.05, 0.3]), np.array([0.5, -0.1, -0.2]), np.array([0.3, 0.0, 0.5])]
    Q = np.diag([0.01**2, 0.02**2, np.deg2rad(1.0) ** 2])
    pose, cov = np.zeros(3), np.zeros((3, 3))
    for s in steps:
        pose, cov = g.compose_with_covariance_2d(pose, cov, s, Q)
    np.testing.assert_allclose(pose, g.compose(g.compose(steps[0], steps[1]), steps[2]))
    n = 40000
    sampled = np.zeros((n, 3))
    for s in steps:
        # each step's noise in its own frame (the frame of the pose it starts from), as cov_b is defined
        sampled = g.compose(sampled, s + rng.multivariate_normal(np.zeros(3), Q, size=n))
    d = sampled - pose
    d[:, 2] = g.wrap_angle(d[:, 2])
    scale = np.sqrt(np.outer(np.diag(cov), np.diag(cov)))  # as correlations: off-diagonals to their diagonals' scale
    np.testing.assert_allclose(np.cov(d.T) / scale, cov / scale, atol=0.03)
    # in the pose's own frame: the same spread, rotated (the perturbation delta of pose + delta)
    body = g.relative(np.broadcast_to(pose, sampled.shape), sampled)
    body[:, 2] = g.wrap_angle(body[:, 2])
    bc = g.body_covariance_2d(pose, cov)
    scale = np.sqrt(np.outer(np.diag(bc), np.diag(bc)))
    np.testing.assert_allclose(np.cov(body.T) / scale, bc / scale, atol=0.03)
    assert not np.allclose(bc, cov, rtol=0.2)  # the frames differ: the check above can tell them apart


def test_one_pose_compose_and_relative_match_the_batched_matrices(rng):
    """One 2D pose each takes a written-out path: it agrees with the batched matrix path to rounding, wraps the
    angle to [-pi, pi] and returns a fresh (3,) array."""
    a = np.column_stack([rng.uniform(-50, 50, (500, 2)), rng.uniform(-np.pi, np.pi, 500)])
    b = np.column_stack([rng.uniform(-50, 50, (500, 2)), rng.uniform(-np.pi, np.pi, 500)])
    one_c = np.array([g.compose(p, q) for p, q in zip(a, b, strict=True)])
    one_r = np.array([g.relative(p, q) for p, q in zip(a, b, strict=True)])
    np.testing.assert_allclose(one_c, g.compose(a, b), rtol=0, atol=1e-12)
    np.testing.assert_allclose(one_r, g.relative(a, b), rtol=0, atol=1e-12)
    assert np.all(np.abs(one_c[:, 2]) <= np.pi) and np.all(np.abs(one_r[:, 2]) <= np.pi)
    ints = np.array([1, 2, 0])  # integer poses are read as floats
    np.testing.assert_allclose(g.relative(ints, ints), np.zeros(3), atol=1e-15)



def test_the_float_paths_of_planar_compose_relative_and_wrap_agree_with_the_matrix_and_array_paths(rng):
    poses = np.column_stack([rng.uniform(-50, 50, (500, 2)), rng.uniform(-10, 10, 500)])
    for a, b in zip(poses[:-1], poses[1:], strict=True):
        ab = g.compose_2d(a.tolist(), b.tolist())
        np.testing.assert_allclose(ab[:2], (g.pose_to_matrix(a) @ g.pose_to_matrix(b))[:2, 2], atol=1e-9)
        assert abs(g.wrap_angle(ab[2] - a[2] - b[2])) < 1e-12
        back = g.relative_2d(a.tolist(), list(ab))
        np.testing.assert_allclose(back[:2], b[:2], atol=1e-9)
        assert abs(g.wrap_angle(back[2] - b[2])) < 1e-12
        d = g.relative_2d(a.tolist(), b.tolist())
        np.testing.assert_allclose(g.compose_2d(a.tolist(), d)[:2], b[:2], atol=1e-9)
        assert g.wrap_angle_1(float(a[2])) == float(g.wrap_angle(a[2]))  # the same bits
    for v in (np.pi, -np.pi, 0.0, -0.0, 3 * np.pi, -3 * np.pi, 1e-300, 7.5, -7.5):
        assert g.wrap_angle_1(v) == float(g.wrap_angle(v))
    assert g.single_2d(poses[0], poses[1]) and not g.single_2d(poses[0], poses[:2]) and not g.single_2d([0, 0, 0])
