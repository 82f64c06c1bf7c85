import numpy as np
import pytest

from hsmap.errors import DataFormatError
from hsmap.io import Trajectory, atomic_open, read_tum, write_tum


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


def test_atomic_open_leaves_nothing_on_error(tmp_path):
    target = tmp_path / "out.txt"
    with pytest.raises(RuntimeError), atomic_open(target) as fh:
        fh.write("partial")
        raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []
