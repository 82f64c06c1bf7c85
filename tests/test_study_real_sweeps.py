"""hsmap.study.real_sweeps' map of posed sweeps: the sweeps placed by their poses, and through the 3D-only chain's
stages the floor under the walked trajectory (not a ceiling, not a raised floor beside the walk) and a band's
rooms."""

from __future__ import annotations

import numpy as np
import pytest

from hsmap.geometry import invert_matrix, pose_to_matrix, transform_points
from hsmap.trajectory import Trajectory


def _hall(rng, step=0.05):
    """A 10 x 6 m hall, 4 m high: floor at z = 0 with a raised level (z = 1.0) over x > 8, walls, a ceiling."""
    x, y = np.meshgrid(np.arange(0, 10, step), np.arange(0, 6, step), indexing="ij")
    x, y = x.ravel(), y.ravel()
    floor = np.column_stack([x, y, np.where(x > 8, 1.0, 0.0)])
    ceiling = np.column_stack([x, y, np.full_like(x, 4.0)])
    zs = np.arange(0, 4, step)
    walls = []
    for a in np.arange(0, 10, step):
        walls += [np.column_stack([np.full_like(zs, a), np.zeros_like(zs), zs]),
                  np.column_stack([np.full_like(zs, a), np.full_like(zs, 6.0), zs])]
    for b in np.arange(0, 6, step):
        walls += [np.column_stack([np.zeros_like(zs), np.full_like(zs, b), zs]),
                  np.column_stack([np.full_like(zs, 10.0), np.full_like(zs, b), zs])]
    pts = np.vstack([floor, ceiling, *walls])
    return pts + rng.normal(0, 0.003, pts.shape)


def _walk(n=8):
    """Sensor poses 1.6 m above the lower floor, walking along the hall with some roll, pitch and yaw."""
    s = np.linspace(0, 1, n)
    poses = np.column_stack([1.5 + 5 * s, 3.0 + 0.5 * np.sin(3 * s), np.full(n, 1.6), 0.1 * np.sin(5 * s),
                             -0.08 * s, 2.0 * s])
    return Trajectory(100.0 + 0.5 * np.arange(n), poses)


def _sweeps(world, traj):
    """The world's points as each sensor pose sees them (its own frame), all of them."""
    return [transform_points(invert_matrix(pose_to_matrix(p)), world) for p in traj.poses]


def test_posed_points_put_every_sweep_back_into_the_world(rng):
    from hsmap.study.real_sweeps import posed_points

    world = _hall(rng)
    traj = _walk(4)
    pts = posed_points(_sweeps(world, traj), traj, voxel=0.1)
    occupied = {tuple(k) for k in np.floor(world / 0.1).astype(int)}
    got = {tuple(k) for k in np.floor(pts / 0.1).astype(int)}
    assert len(got) == len(pts)  # one point a voxel
    assert len(got - occupied) < 0.01 * len(got) and len(occupied - got) < 0.01 * len(occupied)
    from hsmap.errors import InputError

    with pytest.raises(InputError, match="one pose a sweep"):
        posed_points(_sweeps(world, traj)[:3], traj)


def test_the_floor_is_the_one_under_the_walk_and_the_slice_is_one_room(rng):
    from hsmap.study.real_sweeps import slice_rooms

    world = _hall(rng)
    traj = _walk()
    sr = slice_rooms(_sweeps(world, traj), traj, (1.2, 1.4), voxel=0.1)
    # under every pose the lower floor's layer, not the raised one nor the ceiling
    assert len(sr.floors) == len(traj.poses) and np.all(np.abs(sr.floors - 0.05) < 0.1)
    assert sr.floor == pytest.approx(0.05, abs=0.1)
    assert sr.rooms.segmentation.n_rooms == 1
    assert sr.rooms.row()["in_rooms_m2"] > 0.6 * 10 * 6
    from hsmap.errors import InputError

    with pytest.raises(InputError, match="one pose a sweep"):
        slice_rooms(_sweeps(world, traj)[:3], traj, (1.2, 1.4))


def test_hs_slam_on_sweeps_does_not_count_reading_them(rng, monkeypatch):
    """``run_hs_slam`` reads the sweeps before its clock starts, as the peers' runs do: a reader that spends
    seconds of CPU time adds none of them to the run's."""
    import time

    from hsmap.datasets.frames import Frame
    from hsmap.study import real_sweeps

    world = _hall(rng, step=0.1)
    traj = _walk(3)
    spin = 3.0

    class SlowReader:
        odometry = None

        def frames(self, clouds=True):
            for k, cloud in enumerate(_sweeps(world, traj)):
                c0 = time.process_time()
                while time.process_time() - c0 < spin / 3:
                    pass
                yield Frame(stamp=float(traj.stamps[k]), cloud3d=cloud, index=k)

    monkeypatch.setattr(real_sweeps, "open_sweeps", lambda folder: SlowReader())
    r = real_sweeps.run_hs_slam("unused", seed=1)
    assert len(r.trajectory) == 3
    assert r.cpu_seconds < spin  # counting the reading would give more than spin
