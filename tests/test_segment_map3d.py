"""hsmap segment MAP3D --band: a 3D map's height band as a map_server grid, segmented into rooms."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hsmap.cli import main
from hsmap.maps.grid import read_label_image, read_map
from hsmap.maps.maps3d import FREE, OCCUPIED, UNKNOWN, Map3D, read_map3d, seen_through
from hsmap.testing import two_rooms_octree

octomap = pytest.importorskip("octomap", reason="octomap-python is not installed")


@pytest.fixture(scope="module")
def geb079() -> Path:
    from hsmap.study.paths import datasets_dir
    from hsmap.study.public_data import missing_data_reason

    root = datasets_dir()
    reason = missing_data_reason(["octomap"], root)
    if reason:
        pytest.skip(reason)
    return root / "octomap" / "geb079.bt"


def _segment(path: Path, band: str, out: Path, *extra: str) -> dict:
    assert main(["segment", str(path), "--band", band, "--out", str(out), *extra]) == 0
    return json.loads((out / "band.json").read_text())


@pytest.mark.parametrize("band", ["1.7,1.8", "0.1,0.35"])
def test_geb079_bands(geb079, tmp_path, band, capsys):
    out = tmp_path / "seg"
    info = _segment(geb079, band, out)
    printed = capsys.readouterr().out
    assert "floor at z = -0.080 m" in printed
    assert abs(info["floor"] + 0.1) < 0.05 and info["floor"] == info["floor_found"]
    # the grid is trinary, on the map's footprint at its resolution
    img = np.asarray(__import__("PIL.Image", fromlist=["Image"]).open(out / "grid.pgm"))
    assert set(np.unique(img)) == {0, 205, 254}
    grid = read_map(out / "grid.yaml")
    assert grid.geometry.resolution == pytest.approx(0.08)
    assert grid.geometry.shape == (187, 487)
    assert int(grid.free.sum()) == info["cells"]["free"] and int(grid.occupied.sum()) == info["cells"]["occupied"]
    labels = read_label_image(out / "rooms.png")
    assert labels.shape == grid.geometry.shape
    # every observed free cell of the band is in a room (but for specks and cracks dropped as such)
    assert (labels[grid.free] > 0).mean() > 0.94
    assert not (labels[grid.occupied] > 0).any()
    n = len(np.unique(labels[labels > 0]))
    # the floor has about 17 rooms as the map saw them; the clutter near the floor cuts it into many more pieces
    assert n == info["rooms"] and (10 <= n <= 35 if band == "1.7,1.8" else 20 <= n <= 80)
    doors = json.loads((out / "doors.json").read_text())["doors"]
    assert len(doors) == info["doors"] >= 4
    topo = json.loads((out / "topology.json").read_text())
    assert topo
    if band == "1.7,1.8":
        # the corridor (about 35 m along x) is one room
        xs = grid.geometry.pixel_to_world(np.argwhere(labels > 0))[:, 0]
        lab = labels[labels > 0]
        spans = [np.ptp(xs[lab == k]) for k in np.unique(lab)]
        assert max(spans) > 20.0


def test_floor_override_and_flags(geb079, tmp_path, capsys):
    info = _segment(geb079, "1.7,1.8", tmp_path / "o", "--floor", "0.0")
    assert info["floor"] == 0.0 and info["floor_source"] == "--floor"
    assert abs(info["band_heights"][0] - 1.6) < 0.09
    assert 0 < info["cells"]["segmented_free"] <= info["cells"]["free"] + info["cells"]["unknown_seen_through"]
    for args, words in ((["--band", "1.8,1.7"], "--band must be LO,HI"), ([], "needs --band LO,HI"),
                        (["--band", "10,11"], "outside"), (["--band", "1,2", "--resolution", "0.1"],
                                                          "--resolution applies to point maps")):
        assert main(["segment", str(geb079), "--out", str(tmp_path / "x"), *args]) == 2
        err = capsys.readouterr().err
        assert words in err and err.count("\n") == 1, err


def test_band_flags_refused_for_images(tmp_path, capsys):
    from PIL import Image

    Image.fromarray(np.full((40, 40), 254, np.uint8)).save(tmp_path / "m.png")
    assert main(["segment", str(tmp_path / "m.png"), "--band", "1,2", "--out", str(tmp_path / "o")]) == 2
    assert "--band and --floor apply to 3D maps" in capsys.readouterr().err


def test_damaged_3d_map_is_a_one_line_error(tmp_path, capsys):
    bad = tmp_path / "half.bt"
    bad.write_bytes(b"# Octomap OcTree binary file\nid OcTree\nsize 100\nres 0.1\ndata\n\xff\xff\x03")
    assert main(["segment", str(bad), "--band", "1,2", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "truncated" in err and err.count("\n") == 1


def test_seen_through_cells():
    # four columns: seen free above the band only; occupied in the band; never seen; free in the band
    state = np.zeros((4, 1, 6), np.uint8)
    state[:, 0, 0] = OCCUPIED
    state[0, 0, 4] = FREE
    state[1, 0, 2] = OCCUPIED
    state[1, 0, 4] = FREE
    state[3, 0, 2] = FREE
    m = Map3D(state, np.zeros(3), 1.0, "synthetic")
    seen = seen_through(m, 1.2, 1.8)          # the band is layer 2
    assert list(seen[0]) == [True, False, False, False]
    # a wall seen just above the band (layer 3) keeps the column unknown when within the margin
    state[0, 0, 3] = OCCUPIED
    assert list(seen_through(m, 1.2, 1.8, wall_margin=1.0)[0]) == [False, False, False, False]
    assert list(seen_through(m, 1.2, 1.8, wall_margin=0.3)[0]) == [True, False, False, False]


def test_segmentation_free_closes_cracks_not_doors():
    from hsmap.maps.maps3d import segmentation_free

    # two 2 x 2 m rooms of 0.1 m voxels, a floor, a wall between them with a 0.1 m crack and a 0.9 m door
    state = np.full((41, 20, 4), FREE, np.uint8)
    state[:, :, 0] = OCCUPIED
    state[20, :, 1:] = OCCUPIED
    state[20, 3, 1:] = FREE                      # the crack
    m = Map3D(state.copy(), np.zeros(3), 0.1, "synthetic")
    free = segmentation_free(m, 0.05, 0.25, min_passage=0.3)
    col = 20                                     # x index 20 is image column 20; y index j is row 19 - j
    assert not free[19 - 3, col]
    assert free[:, col].sum() == 0
    state[20, 8:17, 1:] = FREE                   # a door 0.9 m wide
    m = Map3D(state, np.zeros(3), 0.1, "synthetic")
    free = segmentation_free(m, 0.05, 0.25, min_passage=0.3)
    assert free[19 - 12, col] and not free[19 - 3, col]
    assert segmentation_free(m, 0.05, 0.25)[19 - 3, col]      # no minimum passage: the crack stays


def test_synthetic_octree_two_rooms(tmp_path):
    """Two 4 x 3 m rooms side by side with a 0.9 m door between them, walls 2.5 m high, scanned from one point
    in each room: the band at 1-1.2 m segments into two rooms joined by one door."""
    path = tmp_path / "rooms.bt"
    two_rooms_octree(path)
    m = read_map3d(path)
    assert (m.state == UNKNOWN).any() and (m.state == FREE).any()
    out = tmp_path / "seg"
    info = _segment(path, "1.0,1.2", out)
    assert abs(info["floor"]) < 0.11
    labels = read_label_image(out / "rooms.png")
    grid = read_map(out / "grid.yaml")
    ids = np.unique(labels[labels > 0])
    assert len(ids) == 2
    xs_l = [grid.geometry.pixel_to_world(np.argwhere(labels == k))[:, 0].mean() for k in ids]
    assert sorted(round(x) for x in xs_l) == [2, 6]
    doors = json.loads((out / "doors.json").read_text())["doors"]
    assert len(doors) == 1
