"""hsmap.trajectory: the Trajectory type, its one nearest-stamp look-up, TUM files."""

import numpy as np
import pytest

from hsmap.errors import DataFormatError, InputError, ShapeError
from hsmap.trajectory import Trajectory, nearest_index, read_tum, write_tum


def test_at_matches_stamps_within_max_dt():
    tr = Trajectory([0.0, 1.0, 2.0, 3.0], np.arange(12.0).reshape(4, 3))
    poses, found = tr.at([2.0, 0.0004, 1.5, 5.0, 3.0])
    assert found.tolist() == [True, True, False, False, True]
    np.testing.assert_array_equal(poses, tr.poses[[2, 0, 3]])
    poses, found = tr.at([1.5, 5.0], max_dt=0.5)
    assert found.tolist() == [True, False]
    np.testing.assert_array_equal(poses, tr.poses[[1]])  # a tie goes to the earlier stamp


def test_at_on_unsorted_stamps_and_an_empty_trajectory():
    tr = Trajectory([3.0, 1.0, 2.0], [[3, 0, 0], [1, 0, 0], [2, 0, 0]])
    poses, found = tr.at([1.0, 2.0, 3.0, 2.9], max_dt=0.2)
    assert found.all()
    np.testing.assert_array_equal(poses[:, 0], [1, 2, 3, 3])
    with pytest.raises(InputError, match="empty"):
        Trajectory(np.empty(0), np.empty((0, 3))).at([0.0])


def test_nearest_index_is_brute_force_nearest(rng):
    stamps = rng.uniform(0, 100, 200)
    query = np.r_[rng.uniform(-5, 105, 300), stamps[:5]]
    got = nearest_index(stamps, query)
    want = np.argmin(np.abs(stamps[None] - query[:, None]), axis=1)
    np.testing.assert_array_equal(got, want)
    far = nearest_index(stamps, query, max_dt=0.05)
    d = np.abs(stamps[want] - query)
    np.testing.assert_array_equal(far, np.where(d <= 0.05, want, -1))
    assert nearest_index([], [1.0, 2.0]).tolist() == [-1, -1]
    assert nearest_index([5.0, 5.0], [5.0]).tolist() == [0]  # equal stamps: the first listed
    assert nearest_index([1.0], [np.nan]).tolist() == [-1]


def test_shapes_are_checked():
    with pytest.raises(ShapeError):
        Trajectory([0.0, 1.0], np.zeros((2, 4)))
    with pytest.raises(ShapeError):
        Trajectory([0.0], np.zeros((2, 3)))


def test_head_and_dof_conversions():
    tr = Trajectory([0.0, 1.0, 2.0], [[0, 0, 0], [1, 0, 0.5], [2, 1, 1.0]])
    assert len(tr.head(2)) == 2 and len(tr.head(10)) == 3
    six = tr.as_6dof()
    assert six.dof == 6 and np.array_equal(six.as_3dof().poses, tr.poses)
    assert tr.path_length() == pytest.approx(1 + np.sqrt(2))


def test_tum_roundtrip(tmp_path, rng):
    poses = np.column_stack([rng.normal(size=(30, 3)), rng.uniform(-0.5, 0.5, (30, 2)), rng.uniform(-3, 3, 30)])
    traj = Trajectory(np.arange(30) * 0.1 + 1e9, poses)
    write_tum(tmp_path / "t.tum", traj)
    back = read_tum(tmp_path / "t.tum")
    np.testing.assert_allclose(back.stamps, traj.stamps, atol=1e-9)
    np.testing.assert_allclose(back.poses, poses, atol=1e-7)


def test_tum_2d(tmp_path):
    traj = Trajectory([0.0, 1.0], [[0, 0, 0], [1, 2, 0.5]])
    write_tum(tmp_path / "t.tum", traj)
    np.testing.assert_allclose(read_tum(tmp_path / "t.tum", dof=3).poses, traj.poses, atol=1e-8)


def test_tum_bad_line_names_line(tmp_path):
    p = tmp_path / "bad.tum"
    p.write_text("0 0 0 0 0 0 0 1\n1 0 0 0 0 0\n")
    with pytest.raises(DataFormatError, match=r"bad.tum:2: expected 8 values"):
        read_tum(p)


def test_tum_zero_quaternion_names_the_file(tmp_path):
    p = tmp_path / "zero.tum"
    p.write_text("0 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 0\n")
    with pytest.raises(DataFormatError, match=r"zero.tum: quaternion .* zero"):
        read_tum(p)


def test_interpolate_between_poses_within_the_tolerance():
    # 2D poses every 0.1 s of a robot turning on an arc; queries between them
    t = np.arange(0, 1.01, 0.1)
    # 0.5 m/s forward while turning at 0.8 rad/s
    poses = np.array([[np.sin(0.8 * s) / 0.8 * 0.5, (1 - np.cos(0.8 * s)) / 0.8 * 0.5, 0.8 * s] for s in t])
    traj = Trajectory(t, poses)
    q = np.array([0.05, 0.2, 0.34, 1.0, 1.04, -0.01, 0.5004])
    got, found = traj.interpolate(q, max_dt=0.065)
    assert found.tolist() == [True, True, True, True, False, False, True]
    expected = np.array([[np.sin(0.8 * s) / 0.8 * 0.5, (1 - np.cos(0.8 * s)) / 0.8 * 0.5, 0.8 * s]
                         for s in q[found]])
    expected[-1] = poses[5]  # within 1 ms of a pose: that pose
    np.testing.assert_allclose(got, expected, atol=1e-12)
    # between two poses of the regular cadence: a pose, whatever the tolerance
    assert traj.interpolate([0.34], max_dt=0.05)[1][0]
    # in a gap where poses are missing (0.3 and 0.4), farther than the tolerance from either side: no pose
    gap = Trajectory(np.delete(t, [3, 4]), np.delete(poses, [3, 4], axis=0))
    assert not gap.interpolate([0.34], max_dt=0.05)[1][0]
    assert not gap.interpolate([0.36], max_dt=0.05)[1][0]
    # unordered stamps are sorted first; 6-DOF poses interpolate too
    shuffled = Trajectory(t[::-1], poses[::-1])
    np.testing.assert_allclose(shuffled.interpolate([0.33], 0.06)[0], traj.interpolate([0.33], 0.06)[0])
    six, ok = traj.as_6dof().interpolate([0.25], 0.06)
    assert ok[0] and six.shape == (1, 6)
    np.testing.assert_allclose(six[0, [0, 1, 5]], traj.interpolate([0.25], 0.06)[0][0], atol=2e-3)
    with pytest.raises(InputError, match="max_dt"):
        traj.interpolate([0.3], max_dt=-1.0)
    with pytest.raises(InputError, match="empty"):
        Trajectory(np.zeros(0), np.zeros((0, 3))).interpolate([0.0], 0.1)
