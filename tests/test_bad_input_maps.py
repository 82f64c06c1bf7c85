"""Bad 3D and 2D maps given to ``hsmap segment``, ``hsmap align`` and ``hsmap simulate --world``: each is one
line ``hsmap: error: ...`` naming the file or flag and what was expected (exit 2), never a traceback, and never a
wrong result reported as a success."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest
from _cli import error_line, run_cli
from _worlds import two_rooms

octomap = pytest.importorskip("octomap")




@pytest.fixture(scope="module")
def small_bt(tmp_path_factory) -> Path:
    """A 2 x 2 m floor seen from 1 m above it, 0.1 m voxels."""
    tree = octomap.OcTree(0.1)
    g = np.mgrid[0:2:0.05, 0:2:0.05].reshape(2, -1).T
    tree.insertPointCloud(np.c_[g, np.zeros(len(g))], np.array([1.0, 1.0, 1.0]))
    tree.updateInnerOccupancy()
    path = tmp_path_factory.mktemp("maps") / "small.bt"
    assert tree.writeBinary(str(path).encode())
    return path


def with_res(src: Path, dst: Path, res: str) -> Path:
    dst.write_bytes(src.read_bytes().replace(b"\nres 0.1\n", f"\nres {res}\n".encode(), 1))
    return dst


def far_ply(path: Path) -> Path:
    from hsmap.io import write_ply_points

    write_ply_points(path, np.array([[0.0, 0.0, 0.0], [3e38, 0.0, 0.0], [1.0, 1.0, 1.0]]))
    return path


def map_png(path: Path) -> Path:
    from PIL import Image

    img = np.full((60, 60), 254, np.uint8)
    img[10:50, 10] = img[10:50, 50] = img[10, 10:50] = img[50, 10:50] = 0
    Image.fromarray(img).save(path)
    return path


def commands(map3d: Path, tmp_path: Path) -> list[list]:
    return [["segment", map3d, "--band", "0.5,0.6", "--out", tmp_path / "seg"],
            ["align", map_png(tmp_path / "m.png"), map3d, "--out", tmp_path / "al"],
            ["simulate", "--world", map3d, "--out", tmp_path / "sim"]]


# a grid no integer holds ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("command", [0, 1, 2], ids=["segment", "align", "simulate"])
def test_an_octomap_with_an_absurd_resolution_is_one_line(small_bt, tmp_path, command):
    """Before: ``res 1e300`` gave 'ValueError: negative dimensions are not allowed' (a traceback)."""
    bad = with_res(small_bt, tmp_path / "res.bt", "1e300")
    code, err = run_cli(*commands(bad, tmp_path)[command])
    assert code == 2
    line = error_line(err)
    assert line.startswith(f"{bad}: ") and "res 1e+300" in line, line


@pytest.mark.parametrize("command", [0, 1, 2], ids=["segment", "align", "simulate"])
def test_a_point_map_with_a_far_point_is_one_line(tmp_path, command):
    """Before: a PLY point at x = 3e38 gave 'ValueError: negative dimensions are not allowed'."""
    bad = far_ply(tmp_path / "far.ply")
    code, err = run_cli(*commands(bad, tmp_path)[command])
    assert code == 2
    line = error_line(err)
    assert line.startswith(f"{bad}: its voxel grid 6e+39 x ") and "exceeds the limit" in line, line


def test_the_budget_still_names_whole_cell_counts(small_bt):
    from hsmap.errors import InputError
    from hsmap.maps.maps3d import read_map3d

    with pytest.raises(InputError, match=r"small\.bt: its voxel grid \d+ x \d+ x \d+ = \d+ cells exceeds the limit "
                                         r"of 10 cells"):
        read_map3d(small_bt, max_cells=10)


# not a file ------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("command", ["segment", "slam", "map"])
def test_a_symlink_loop_as_input_is_one_line(tmp_path, command):
    """Before: 'RuntimeError: Symlink loop from ...' (a traceback)."""
    loop = tmp_path / "loop.bt"
    os.symlink(loop, loop)
    extra = ["--band", "1,1.2"] if command == "segment" else []
    code, err = run_cli(command, loop, "--out", tmp_path / "o", *extra)
    assert code == 2
    assert error_line(err) == f"{loop}: cannot follow the path (a symbolic link loop)"
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("command", ["segment", "slam"])
def test_a_symlink_loop_as_out_is_one_line(small_bt, tmp_path, command):
    loop = tmp_path / "loop"
    os.symlink(loop, loop)
    code, err = run_cli(command, map_png(tmp_path / "m.png"), "--out", loop)
    assert code == 2
    assert error_line(err) == f"--out {loop}: cannot follow the path (a symbolic link loop)"


def test_a_broken_link_as_out_is_named(tmp_path):
    """Before: 'File exists' after the run, from mkdir."""
    link = tmp_path / "gone"
    os.symlink(tmp_path / "nowhere", link)
    code, err = run_cli("simulate", "two-rooms", "--out", link, "--max-frames", "2")
    assert code == 2
    assert error_line(err).startswith(f"--out {link}: a broken symbolic link")


@pytest.mark.parametrize("kind, words", [("folder", "a folder, not a 3D map file"),
                                         ("fifo", "not a regular file (a FIFO, socket or device)"),
                                         ("missing", "no such 3D map file")])
def test_a_3d_map_that_is_not_a_file_says_what_it_is(tmp_path, kind, words):
    """Before: a folder or a FIFO was 'no such 3D map file'."""
    path = tmp_path / "map.bt"
    if kind == "folder":
        path.mkdir()
    elif kind == "fifo":
        os.mkfifo(path)
    code, err = run_cli("segment", path, "--band", "1,1.2", "--out", tmp_path / "o")
    assert code == 2
    assert error_line(err).startswith(f"{path}: {words}")


# what the messages blame ------------------------------------------------------------------------------------------


def test_a_point_map_band_says_a_point_map_has_no_free_space(tmp_path):
    """Before: '... the map has no free space to segment (no free pixel)', with no word why."""
    from hsmap.io import write_ply_points

    g = np.mgrid[0:3:0.05, 0:2.5:0.05].reshape(2, -1).T
    pts = np.vstack([np.c_[g, np.zeros(len(g))], np.c_[np.zeros(len(g)), g], np.c_[np.full(len(g), 3.0), g]])
    path = tmp_path / "walls.ply"
    write_ply_points(path, pts)
    code, err = run_cli("segment", path, "--band", "1,1.2", "--out", tmp_path / "o")
    assert code == 2
    line = error_line(err)
    assert line.startswith(f"{path}: a point map records occupied voxels only, no free space"), line
    assert "OctoMap" in line
    code, err = run_cli("simulate", "--world", path, "--out", tmp_path / "o")
    assert code == 2
    assert error_line(err).startswith(f"{path}: a point map records occupied voxels only, so there is no known free "
                                      "space to drive through")


def test_a_coarse_octomap_does_not_blame_a_flag_it_refuses(small_bt, tmp_path):
    """Before: 'the default resolution 0.05 (set it with --resolution)', a flag a .bt refuses."""
    coarse = with_res(small_bt, tmp_path / "coarse.bt", "100")
    code, err = run_cli("segment", coarse, "--band", "1,300", "--out", tmp_path / "o")
    assert code == 2
    line = error_line(err)
    assert line.startswith(f"{coarse}: the tree's voxel size 100 m: resolution 100 m/pixel is coarser"), line
    assert "--resolution" not in line


def test_a_3d_map_as_map2d_says_so(small_bt, tmp_path):
    """Before: 'not a readable image'."""
    code, err = run_cli("align", small_bt, small_bt, "--out", tmp_path / "o")
    assert code == 2
    assert error_line(err).startswith(f"MAP2D {small_bt}: an OctoMap 3D map; MAP2D takes a 2D map")


def test_align_checks_its_seed_before_any_work(small_bt, tmp_path):
    """Before: ``--seed -1`` failed after the maps were read and searched (17 s on geb079)."""
    t = time.perf_counter()
    code, err = run_cli("align", map_png(tmp_path / "m.png"), small_bt, "--out", tmp_path / "o", "--seed", "-1")
    assert code == 2 and error_line(err) == "--seed must be >= 0, got -1"
    assert time.perf_counter() - t < 5.0


# a meaningless match ----------------------------------------------------------------------------------------------


def test_align_refuses_a_match_it_cannot_tell_from_another(tmp_path):
    """Before: a 10 x 10 black square onto geb079's band was 'aligned' with exit 0 (overlap 0.027): a blob fits
    any wall. Here a blob onto a two-room map: no unique pose either way, exit 2, nothing written."""
    from PIL import Image

    from hsmap.maps.grid import write_map

    write_map(tmp_path / "rooms.yaml", two_rooms(0.05))
    Image.fromarray(np.zeros((10, 10), np.uint8)).save(tmp_path / "black.png")
    code, err = run_cli("align", tmp_path / "black.png", tmp_path / "rooms.yaml", "--out", tmp_path / "o")
    assert code == 2
    line = error_line(err)
    assert line.startswith(f"{tmp_path / 'black.png'} onto {tmp_path / 'rooms.yaml'}: no unique match"), line
    assert not (tmp_path / "o").exists()


def test_octomap_leaves_with_nan_log_odds_are_refused(tmp_path):
    """Before: a .ot leaf whose log-odds is NaN was read as free space."""
    import struct

    tree = octomap.OcTree(0.1)
    g = np.mgrid[0:1:0.05, 0:1:0.05].reshape(2, -1).T
    tree.insertPointCloud(np.c_[g, np.zeros(len(g))], np.array([0.5, 0.5, 1.0]))
    tree.updateInnerOccupancy()
    path = tmp_path / "nan.ot"
    assert tree.write(str(path).encode())
    raw = bytearray(path.read_bytes())
    assert raw[-1] == 0  # the last node of the depth-first stream is a leaf: float32 log-odds, no children
    raw[-5:-1] = struct.pack("<f", float("nan"))
    path.write_bytes(bytes(raw))
    code, err = run_cli("segment", path, "--band", "0.2,0.4", "--out", tmp_path / "o")
    assert code == 2
    line = error_line(err)
    assert line.startswith(f"{path}: 1 of its ") and line.endswith(" OctoMap leaves have a NaN log-odds occupancy; "
                                                                    "expected numbers"), line


# band edges on voxel faces ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("res, origin_z", [(0.08, float(np.float32(-0.16))), (0.05, -0.1), (0.1, float(np.float32(-0.3)))])
def test_a_band_edge_on_a_voxel_face_takes_no_layer_beyond_it(res, origin_z):
    """Before: on geb079 (0.08 m voxels) ``--band 0,0.001`` took the floor's own layer and ``--band 0.16,0.24``
    two layers where ``0.8,0.88`` took one: an edge on a face took the layer beyond it or not, by rounding."""
    from hsmap.maps.maps3d import OCCUPIED, Map3D, band_layers, floor_height

    state = np.zeros((4, 4, 40), np.uint8)
    state[:, :, 1] = OCCUPIED  # the floor: layer 1, its top face one voxel above the origin's layer
    m = Map3D(state, np.array([0.0, 0.0, origin_z]), res, "test")
    floor = floor_height(m)
    assert band_layers(m, 0.0, 0.001, floor=floor) == slice(2, 3)  # just above the floor's face: the next layer
    for j in range(30):  # one voxel's height from face to face: that voxel alone
        assert band_layers(m, j * res, (j + 1) * res, floor=floor) == slice(2 + j, 3 + j), j
    # a band across a face keeps both layers it overlaps
    assert band_layers(m, 0.5 * res, 1.5 * res, floor=floor) == slice(2, 4)


# simulate --world --------------------------------------------------------------------------------------------------


def test_simulate_refuses_a_scenario_beside_world(small_bt, tmp_path):
    """Before: ``simulate two-rooms --world MAP`` ignored two-rooms without a word."""
    code, err = run_cli("simulate", "two-rooms", "--world", small_bt, "--out", tmp_path / "o")
    assert code == 2
    assert error_line(err) == (f"SCENARIO 'two-rooms' and --world {small_bt} both name the world to simulate; give "
                               "one of them")
    assert not (tmp_path / "o").exists()


def test_a_one_room_map_says_why_the_route_goes_nowhere(tmp_path):
    """Before: 'the route does not move the robot', with no file and no reason."""
    tree = octomap.OcTree(0.1)
    step = 0.05
    xs, ys, zs = np.arange(0.05, 4.0, step), np.arange(0.05, 3.0, step), np.arange(0.05, 2.5, step)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    Y2, Z2 = np.meshgrid(ys, zs, indexing="ij")
    X3, Z3 = np.meshgrid(xs, zs, indexing="ij")
    cloud = np.vstack([
        np.stack([X.ravel(), Y.ravel(), np.full(X.size, -0.05)], 1), np.stack([X.ravel(), Y.ravel(), np.full(X.size, 2.55)], 1),
        np.stack([np.full(Y2.size, -0.05), Y2.ravel(), Z2.ravel()], 1), np.stack([np.full(Y2.size, 4.05), Y2.ravel(), Z2.ravel()], 1),
        np.stack([X3.ravel(), np.full(X3.size, -0.05), Z3.ravel()], 1), np.stack([X3.ravel(), np.full(X3.size, 3.05), Z3.ravel()], 1)])
    tree.insertPointCloud(cloud, np.array([2.0, 1.5, 1.2]))
    tree.updateInnerOccupancy()
    room = tmp_path / "room.bt"
    assert tree.writeBinary(str(room).encode())
    code, err = run_cli("simulate", "--world", room, "--out", tmp_path / "o")
    assert code == 2
    line = error_line(err)
    assert line.startswith(f"{room}: the route has nowhere to drive: the map's 1.7-1.8 m band shows 1 room "), line
    assert "route.cover_spacing" in line
