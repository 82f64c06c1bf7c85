"""hsmap.maps.maps3d: OctoMap and point maps as dense voxel grids, the floor, height bands."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hsmap.errors import DataFormatError, DatasetError, EmptyInputError, HsmapError, InputError
from hsmap.maps.grid import FREE as G_FREE
from hsmap.maps.grid import OCCUPIED as G_OCCUPIED
from hsmap.maps.grid import UNKNOWN as G_UNKNOWN
from hsmap.maps.maps3d import FREE, OCCUPIED, UNKNOWN, Map3D, band_grid, floor_height, read_map3d

octomap = pytest.importorskip("octomap", reason="octomap-python is not installed")

RES = 0.1


def _room_tree() -> tuple[object, dict]:
    """A 4 x 3 m room 2.5 m high, floor at z = 0, seen by a sensor at (2, 1.5, 1.2): floor, walls and a ceiling
    inserted as rays from the sensor (free space between), one wall (x = 4) left out."""
    tree = octomap.OcTree(RES)
    pts = []
    step = RES / 2
    xs = np.arange(0.05, 4.0, step)
    ys = np.arange(0.05, 3.0, step)
    zs = np.arange(0.05, 2.5, step)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    pts.append(np.stack([X.ravel(), Y.ravel(), np.full(X.size, -0.05)], 1))       # floor
    pts.append(np.stack([X.ravel(), Y.ravel(), np.full(X.size, 2.55)], 1))        # ceiling
    Y2, Z2 = np.meshgrid(ys, zs, indexing="ij")
    pts.append(np.stack([np.full(Y2.size, -0.05), Y2.ravel(), Z2.ravel()], 1))    # wall x = 0
    X3, Z3 = np.meshgrid(xs, zs, indexing="ij")
    pts.append(np.stack([X3.ravel(), np.full(X3.size, -0.05), Z3.ravel()], 1))    # wall y = 0
    pts.append(np.stack([X3.ravel(), np.full(X3.size, 3.05), Z3.ravel()], 1))     # wall y = 3
    cloud = np.vstack(pts)
    tree.insertPointCloud(cloud, np.array([2.0, 1.5, 1.2]))
    tree.updateInnerOccupancy()
    return tree, {"sensor": (2.0, 1.5, 1.2)}


@pytest.fixture(scope="module")
def room_bt(tmp_path_factory) -> Path:
    tree, _ = _room_tree()
    path = tmp_path_factory.mktemp("maps3d") / "room.bt"
    assert tree.writeBinary(str(path).encode())
    return path


@pytest.fixture(scope="module")
def room_ot(tmp_path_factory) -> Path:
    tree, _ = _room_tree()
    path = tmp_path_factory.mktemp("maps3d") / "room.ot"
    assert tree.write(str(path).encode())
    return path


def _leaf_states(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    tree = octomap.OcTree(str(path).encode())
    c = np.array([it.getCoordinate() for it in tree.begin_leafs()])
    s = np.array([it.getSize() for it in tree.begin_leafs()])
    o = np.array([tree.isNodeOccupied(it) for it in tree.begin_leafs()])
    return c, s, o


def test_bt_voxels_agree_with_every_leaf(room_bt):
    m = read_map3d(room_bt)
    assert m.resolution == pytest.approx(RES)
    assert m.source == str(room_bt)
    c, s, o = _leaf_states(room_bt)
    assert (s > RES * 1.5).any(), "the test tree should hold leaves larger than the finest resolution"
    # each leaf's centre voxel (and for large leaves every covered voxel) carries its state
    idx = m.index_of(c)
    assert (m.state[idx[:, 0], idx[:, 1], idx[:, 2]] == np.where(o, OCCUPIED, FREE)).all()
    k = np.rint(s / RES).astype(int)
    expected_voxels = int((k ** 3).sum())
    assert int((m.state != UNKNOWN).sum()) == expected_voxels
    assert m.counts()["occupied"] == int((k[o] ** 3).sum())
    # occupied centres lie on the inserted surfaces: floor/ceiling heights or a wall
    occ = m.centres(OCCUPIED)
    on_surface = (np.abs(occ[:, 2] + 0.05) < RES) | (np.abs(occ[:, 2] - 2.55) < RES) | \
        (np.abs(occ[:, 0] + 0.05) < RES) | (np.abs(occ[:, 1] + 0.05) < RES) | (np.abs(occ[:, 1] - 3.05) < RES)
    assert on_surface.mean() > 0.99


def test_ot_reads_like_bt(room_bt, room_ot):
    a = read_map3d(room_bt)
    b = read_map3d(room_ot)
    assert a.state.shape == b.state.shape
    np.testing.assert_allclose(a.origin, b.origin)
    assert (a.state == b.state).mean() > 0.999


def test_floor_and_band_grid(room_bt):
    m = read_map3d(room_bt)
    f = floor_height(m)
    assert abs(f - 0.0) < RES + 1e-9
    g = band_grid(m, 1.0, 1.2)
    assert set(np.unique(g.data)) <= {G_FREE, G_OCCUPIED, G_UNKNOWN}
    # the wall at x = 0 is occupied, the room's inside free, beyond the open side (x > 4) unknown
    def at(x, y):
        r, cidx = g.geometry.world_to_index(np.array([x, y]))
        return g.data[r, cidx]

    assert at(-0.05, 1.5) == G_OCCUPIED
    assert at(2.0, 1.5) == G_FREE
    assert at(1.0, 0.5) == G_FREE
    assert at(2.0, -0.05) == G_OCCUPIED
    # the band's grid has the map's footprint and resolution, rows flipped (row 0 at the largest y)
    assert g.geometry.shape == (m.shape[1], m.shape[0])
    assert g.geometry.resolution == pytest.approx(m.resolution)
    # a band above the ceiling is outside the map
    with pytest.raises(InputError, match="outside"):
        band_grid(m, 10.0, 11.0)
    with pytest.raises(InputError, match="LO < HI"):
        band_grid(m, 1.2, 1.0)


def test_band_free_only_where_observed():
    state = np.zeros((3, 1, 4), np.uint8)
    state[:, 0, 0] = OCCUPIED                       # a floor layer
    state[0, 0, 1:] = FREE                          # column 0: observed free
    state[1, 0, 2] = OCCUPIED                       # column 1: occupied in the band
    m = Map3D(state, np.zeros(3), 1.0, "synthetic")  # column 2: never observed above the floor
    g = band_grid(m, 0.5, 2.5)
    assert list(g.data[0]) == [G_FREE, G_OCCUPIED, G_UNKNOWN]
    assert floor_height(m) == pytest.approx(1.0)
    assert list(band_grid(m, 0.0, 0.5, floor=3.0).data[0]) == [G_FREE, G_UNKNOWN, G_UNKNOWN]


def test_budget_refuses_large_grids(room_bt):
    with pytest.raises(InputError, match=r"room\.bt.*exceeds the limit of 1000 cells"):
        read_map3d(room_bt, max_cells=1000)


def _corrupt(tmp_path: Path, src: Path, how: str) -> Path:
    raw = src.read_bytes()
    data = {
        "half": raw[: len(raw) // 2],
        "100 bytes": raw[:100],
        "random": np.random.default_rng(3).bytes(4096),
        "empty": b"",
        "random body": raw[: raw.find(b"data\n") + 5] + np.random.default_rng(4).bytes(len(raw)),
        "trailing": raw + b"\x00\x01",
        "size": raw.replace(b"\nsize ", b"\nsize 1", 1),
    }[how]
    path = tmp_path / f"damaged{src.suffix}"
    path.write_bytes(data)
    return path


@pytest.mark.parametrize("how", ["half", "100 bytes", "random", "empty", "random body", "trailing", "size"])
@pytest.mark.parametrize("kind", ["bt", "ot"])
def test_damaged_files_are_one_line_errors(tmp_path, room_bt, room_ot, how, kind, capfd):
    path = _corrupt(tmp_path, room_bt if kind == "bt" else room_ot, how)
    with pytest.raises(HsmapError) as info:
        read_map3d(path)
    msg = str(info.value)
    assert str(path) in msg and "\n" not in msg
    assert isinstance(info.value, (DataFormatError, EmptyInputError))
    assert "ERROR" not in capfd.readouterr().err, "the damage must be found before OctoMap's reader sees it"


def test_missing_and_unknown_files(tmp_path):
    with pytest.raises(DatasetError, match="no such"):
        read_map3d(tmp_path / "nope.bt")
    other = tmp_path / "map.xyz"
    other.write_text("1 2 3\n")
    with pytest.raises(DataFormatError, match=r"\.bt, \.ot, \.ply or \.pcd"):
        read_map3d(other)


def _write_pcd(path: Path, pts: np.ndarray) -> None:
    head = ("# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
            f"WIDTH {len(pts)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(pts)}\nDATA ascii\n")
    path.write_text(head + "".join(f"{x:.4f} {y:.4f} {z:.4f}\n" for x, y, z in pts))


@pytest.mark.parametrize("suffix", [".ply", ".pcd"])
def test_point_maps_occupied_and_ray_cast_free(tmp_path, suffix):
    from hsmap.io import write_ply_points

    # a wall at x = 2 from y = -1..1, z = 0..1, seen from the origin at z = 0.5
    ys, zs = np.meshgrid(np.arange(-1, 1, 0.05), np.arange(0.02, 1, 0.05), indexing="ij")
    pts = np.stack([np.full(ys.size, 2.0), ys.ravel(), zs.ravel()], 1)
    path = tmp_path / f"wall{suffix}"
    if suffix == ".ply":
        write_ply_points(path, pts)
    else:
        _write_pcd(path, pts)
    bare = read_map3d(path, resolution=0.1)
    assert bare.counts()["free"] == 0
    occ = bare.centres(OCCUPIED)
    assert np.abs(occ[:, 0] - 2.0).max() < 0.1
    seen = read_map3d(path, resolution=0.1, poses=np.array([[0.0, 0.0, 0.5, 0.0, 0.0, 0.0]]))
    assert (seen.state == OCCUPIED).sum() == (bare.state == OCCUPIED).sum()
    assert seen.counts()["free"] > 0
    free = seen.centres(FREE)
    assert free[:, 0].max() < 2.0 and free[:, 0].min() > -0.1    # between the sensor and the wall only
    assert seen.state[tuple(seen.index_of([[1.0, 0.0, 0.5]])[0])] == FREE
    with pytest.raises(InputError, match="poses"):
        read_map3d(path, poses=np.zeros((2, 2)))


def test_geb079_reads_at_the_buildings_size_with_its_floor_and_a_free_slice(datasets_octomap):
    m = read_map3d(datasets_octomap / "geb079.bt")
    assert m.resolution == pytest.approx(0.08)
    size = np.asarray(m.state.shape) * m.resolution
    assert 37 < size[0] < 41 and 13 < size[1] < 17 and 2.8 < size[2] < 3.4
    c = m.counts()
    assert c["occupied"] > 143_729             # the leaves' voxels: larger leaves expand into several
    assert c["free"] > 5 * c["occupied"]
    assert abs(floor_height(m) + 0.1) < 0.05
    g = band_grid(m, 1.7, 1.8)
    frac_free = (g.data == G_FREE).mean()
    assert 0.1 < frac_free < 0.5


@pytest.fixture(scope="module")
def datasets_octomap() -> Path:
    from hsmap.study.paths import datasets_dir
    from hsmap.study.public_data import missing_data_reason

    root = datasets_dir()
    reason = missing_data_reason(["octomap"], root)
    if reason:
        pytest.skip(reason)
    return root / "octomap"
