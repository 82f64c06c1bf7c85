"""Worlds from floor plans (hsmap.sim.floorplan): checks of the inputs, the boxes, ray casting, a real building."""

from __future__ import annotations

import _floorplans as fp
import numpy as np
import pytest
from PIL import Image

from hsmap.errors import DataFormatError, DatasetError, HsmapError
from hsmap.sim.floorplan import (
    FloorPlanWorldConfig,
    build_world,
    floor_plan_files,
    list_floor_plans,
    mask_rectangles,
    read_floor_plan,
)


@pytest.fixture
def tiny(tmp_path):
    return read_floor_plan(fp.write(tmp_path) / "tiny.png")


def test_mask_rectangles_cover_the_mask_exactly(rng):
    mask = rng.random((40, 50)) < 0.4
    mask[5:30, 10:14] = True
    rects = mask_rectangles(mask)
    cover = np.zeros(mask.shape, int)
    for r0, c0, r1, c1 in rects:
        cover[r0:r1 + 1, c0:c1 + 1] += 1
    assert np.array_equal(cover, mask.astype(int))  # every pixel once, nothing else


def test_reads_the_triple_and_its_rooms(tiny, tmp_path):
    assert tiny.name == "tiny" and tiny.n_rooms == 3
    assert tiny.geometry.shape == (fp.H, fp.W) and tiny.geometry.resolution == fp.RES
    assert tiny.furniture.sum() == 12 * 20 + 16 * 24
    assert tiny.borders.sum() == 2 * 20 * fp.WALL  # the two doorway lines
    assert list_floor_plans(tmp_path) == ["tiny"]
    assert read_floor_plan(tmp_path, name="tiny").n_rooms == 3


@pytest.mark.parametrize("problem, which, words", [
    ("size", "_furnitures", "same size"),
    ("no free", "", "no free pixel"),
    ("no rooms", "_gt_segmentation", "no ground-truth room"),
])
def test_bad_inputs_are_one_line_errors_naming_the_file(tmp_path, problem, which, words):
    fp.write(tmp_path)
    path = tmp_path / f"tiny{which}.png"
    img = np.asarray(Image.open(path))
    if problem == "size":
        img = img[:-3]
    else:
        img = np.where(img >= 250, 0, img).astype(np.uint8)
    Image.fromarray(img).save(path)
    with pytest.raises(DataFormatError) as exc:
        read_floor_plan(tmp_path / "tiny.png")
    msg = str(exc.value)
    assert str(path) in msg and words in msg and "\n" not in msg


def test_missing_file_names_it(tmp_path):
    fp.write(tmp_path)
    (tmp_path / "tiny_gt_segmentation.png").unlink()
    with pytest.raises(DatasetError, match="tiny_gt_segmentation.png"):
        read_floor_plan(tmp_path / "tiny.png")
    assert list_floor_plans(tmp_path) == []


def test_world_boxes_heights_and_determinism(tiny):
    cfg = FloorPlanWorldConfig()
    w = build_world(tiny, seed=3)
    kinds = np.array(w.kinds)
    walls, lintels = w.boxes[kinds == "wall"], w.boxes[kinds == "lintel"]
    assert len(walls) and np.allclose(walls[:, 5:], [0.0, cfg.ceiling_height])
    assert len(lintels) == 2 and np.allclose(lintels[:, 5:], [cfg.door_height, cfg.ceiling_height])
    furn = w.boxes[np.isin(kinds, ["table", "cabinet"])]
    assert furn[:, 6].max() <= 1.5 + 1e-9 and furn[:, 6].min() > 0  # nothing reaches the 1.7-1.8 m slice
    assert len(w.furniture) == 2
    for piece in w.furniture:
        lo, hi = cfg.table_height if piece.kind == "table" else cfg.solid_height
        assert lo <= piece.height <= hi and 0.4 <= piece.height <= 1.5
    again = build_world(tiny, seed=3)
    assert np.array_equal(again.boxes, w.boxes) and again.kinds == w.kinds
    kinds_by_seed = {tuple(p.kind for p in build_world(tiny, seed=s).furniture) for s in range(8)}
    assert len(kinds_by_seed) > 1  # the seed decides tables and cabinets


def test_rays_pass_the_door_below_the_lintel_and_hit_it_above(tiny):
    world = build_world(tiny, seed=0).world()
    g = tiny.geometry
    start = g.pixel_to_world([50, 60])  # in room A, level with the door at cols 100-103
    d = np.array([[1.0, 0.0, 0.0]])
    for z, far in ((0.2, True), (1.75, True), (2.4, False)):
        t = world.cast([[start[0], start[1], z]], d)[0]
        wall_a = (100 * fp.RES) - start[0]
        assert (t > wall_a + 1.0) == far, (z, t)
    # the 2D scan at 0.2 m sees the cabinet block; the slice at 1.75 m passes over it
    block = g.pixel_to_world([26, 30])
    origin = g.pixel_to_world([26, 70])
    to_block = np.array([[-1.0, 0.0, 0.0]])
    low = world.cast([[origin[0], origin[1], 0.2]], to_block)[0]
    high = world.cast([[origin[0], origin[1], 1.75]], to_block)[0]
    assert low < origin[0] - block[0] < high


def test_real_building_world(datasets_dir):
    folder = datasets_dir / "ipa_room_segmentation"
    plan = read_floor_plan(*floor_plan_files(folder, "Freiburg52_scan"))
    assert plan.n_rooms == 10
    w = build_world(plan, seed=0)
    counts = w.counts()
    assert counts["wall"] > 20 and counts["lintel"] >= 9 and counts.get("table", 0) + counts["cabinet"] > 50
    kinds = np.array(w.kinds)
    furn = w.boxes[np.isin(kinds, ["table", "cabinet"])]
    assert 0.4 <= furn[:, 6].min() and furn[:, 6].max() <= 1.5
    lint = w.boxes[kinds == "lintel"]
    assert np.allclose(lint[:, 5:], [2.05, 2.8])
    # every lintel lies on a ground-truth border between rooms, over free floor of the plain map
    rc = plan.geometry.world_to_index(lint[:, :2])
    assert plan.plain_free[rc[:, 0], rc[:, 1]].all() and (plan.rooms[rc[:, 0], rc[:, 1]] == 0).all()
    assert issubclass(DataFormatError, HsmapError)
