"""3D occupancy maps from posed sweeps: carving, the floor under a path, levelling, OctoMap ``.bt`` files."""

from __future__ import annotations

import numpy as np
import pytest

from hsmap.errors import EmptyInputError, InputError
from hsmap.maps.maps3d import FREE, OCCUPIED, Map3D, read_map3d
from hsmap.maps.occupancy3d import (
    carve_sweeps,
    floor_field,
    floor_under_path,
    level_map,
    sweep_bounds,
    write_octomap,
)

RES = 0.1


def _room(rng, n=30000, x=(0.0, 4.0), y=(0.0, 3.0), floor=0.0, ceiling=2.5):
    """Points on the floor, the ceiling and the four walls of a box room."""
    u = rng.uniform(size=(n, 3)) * [x[1] - x[0], y[1] - y[0], ceiling - floor] + [x[0], y[0], floor]
    face = rng.integers(0, 6, n)
    u[face == 0, 0], u[face == 1, 0] = x[0], x[1]
    u[face == 2, 1], u[face == 3, 1] = y[0], y[1]
    u[face == 4, 2], u[face == 5, 2] = floor, ceiling
    return u


@pytest.fixture(scope="module")
def room_map():
    rng = np.random.default_rng(0)
    sweeps = [(_room(rng), np.array([1.0, 1.5, 1.2])), (_room(rng), np.array([3.0, 1.5, 1.2]))]
    lo, hi = sweep_bounds(sweeps, 30.0)
    return carve_sweeps(sweeps, lo, hi, resolution=RES, max_range=30.0)


def test_carving_marks_returns_occupied_and_the_rays_free(room_map):
    m = room_map
    c = m.counts()
    assert c["occupied"] > 0 and c["free"] > 0
    inside = m.index_of([[2.0, 1.5, 1.2], [0.5, 0.5, 2.0]])
    assert all(m.state[tuple(i)] == FREE for i in inside)
    walls = m.index_of([[RES / 2, 1.5, 1.0], [2.0, 1.5, 2.5 + RES / 4], [2.0, RES / 2, 0.7]])
    assert all(m.state[tuple(i)] == OCCUPIED for i in walls)


def test_a_ray_beyond_max_range_carves_free_space_only():
    pts = np.array([[10.0, 0.0, 0.0]])
    sensor = np.zeros(3)
    lo, hi = sweep_bounds([(pts, sensor)], 2.0)
    assert hi[0] == pytest.approx(2.0)
    m = carve_sweeps([(pts, sensor)], lo, hi, resolution=RES, max_range=2.0)
    assert m.counts()["occupied"] == 0 and m.counts()["free"] >= 19


def test_a_map_too_large_is_refused_before_it_is_allocated():
    with pytest.raises(InputError, match="exceeds the limit of 1000 cells"):
        carve_sweeps([], [0, 0, 0], [10, 10, 10], resolution=RES, max_range=30.0, max_cells=1000)


def test_octomap_file_reads_back_voxel_for_voxel(room_map, tmp_path):
    path = tmp_path / "room.bt"
    nodes = write_octomap(room_map, path)
    back = read_map3d(path)
    assert nodes > 0 and back.resolution == pytest.approx(RES)
    off = np.rint((back.origin - room_map.origin) / RES).astype(int)
    sub = room_map.state[off[0]:off[0] + back.shape[0], off[1]:off[1] + back.shape[1], off[2]:off[2] + back.shape[2]]
    assert np.array_equal(sub, back.state) and back.counts() == room_map.counts()


def test_octomap_of_an_empty_map_is_refused(tmp_path):
    m = Map3D(np.zeros((4, 4, 4), np.uint8), np.zeros(3), RES, "empty")
    with pytest.raises(EmptyInputError, match="no observed voxel"):
        write_octomap(m, tmp_path / "e.bt")
    assert not (tmp_path / "e.bt").exists()


def _two_levels():
    """Two rooms side by side; the second's floor 0.6 m higher; a sensor 1.5 m above each floor."""
    rng = np.random.default_rng(1)
    a = np.array([2.0, 1.5, 1.5])
    b = np.array([6.0, 1.5, 2.1])
    sweeps = [(_room(rng, x=(0.0, 4.0), floor=0.0, ceiling=2.6), a),
              (_room(rng, x=(4.0, 8.0), floor=0.6, ceiling=2.6), b)]
    lo, hi = sweep_bounds(sweeps, 30.0)
    return carve_sweeps(sweeps, lo, hi, resolution=RES, max_range=30.0), np.array([a, b])


def test_floor_under_the_path_takes_each_level_not_the_ceiling():
    m, pos = _two_levels()
    floors = floor_under_path(m, pos, radius=1.5, depth=(0.2, 3.0))
    np.testing.assert_allclose(floors, [0.0, 0.6], atol=RES)


def test_no_floor_below_any_pose_is_an_error():
    m, pos = _two_levels()
    with pytest.raises(EmptyInputError, match="no floor found"):
        floor_under_path(m, pos + [0, 0, 10.0], radius=1.5, depth=(0.2, 3.0))


def test_levelled_map_puts_each_columns_floor_at_zero():
    m, pos = _two_levels()
    floors = floor_under_path(m, pos, radius=1.5, depth=(0.2, 3.0))
    field = floor_field(m, pos, floors)
    lev = level_map(m, field)
    z0 = int(np.floor((0.0 - lev.origin[2]) / RES))  # the layer holding height 0
    for x in (1.0, 7.0):  # a column in each room
        i, j, _ = m.index_of([[x, 1.5, 0.0]])[0]
        assert lev.state[i, j, z0] == OCCUPIED
        assert lev.state[i, j, z0 + 5] == FREE  # 0.5 m above the local floor


def test_floor_field_takes_a_columns_own_floor_within_reach_of_the_nearest_poses():
    """One pose in the low room: the raised room's columns get its floor only with a reach over the step."""
    m, pos = _two_levels()
    floors = floor_under_path(m, pos[:1], radius=1.5, depth=(0.2, 3.0))
    i, j, _ = m.index_of([[7.0, 1.5, 0.0]])[0]
    assert floor_field(m, pos[:1], floors)[i, j] == pytest.approx(floors[0])
    assert floor_field(m, pos[:1], floors, reach=0.7)[i, j] == pytest.approx(0.6, abs=RES)
    assert floor_field(m, pos[:1], floors, reach=0.3)[i, j] == pytest.approx(floors[0])  # out of reach
    i, j, _ = m.index_of([[1.0, 1.5, 0.0]])[0]
    assert floor_field(m, pos[:1], floors, reach=0.7)[i, j] == pytest.approx(0.0, abs=RES)
