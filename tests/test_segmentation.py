import dataclasses

import numpy as np
import pytest
from _worlds import (
    TWO_ROOMS_DOORS,
    cast_scans,
    corridor_end,
    draw_world,
    l_corridor,
    ring_corridor,
    two_rooms,
)

from hsmap.config import from_dict
from hsmap.errors import ConfigError, EmptyInputError, InputError, ShapeError
from hsmap.maps.grid import FREE, GridGeometry, OccupancyGrid, grid_from_scans
from hsmap.rooms.segmentation import Door, SegmentationConfig, points_in_doors, segment_rooms

TRUE_DOORS = np.array([c for c, _, _ in TWO_ROOMS_DOORS])


def _match_doors(seg, truth=TRUE_DOORS):
    """Distance from each true door to the nearest detected one."""
    found = np.array([d.centre for d in seg.doors]).reshape(-1, 2)
    return np.array([np.min(np.hypot(*(found - t).T)) if len(found) else np.inf for t in truth])


def _region_at(seg, xy):
    r, c = seg.geometry.world_to_index(np.asarray(xy, float))
    return int(seg.labels[r, c])


def test_corridor_narrowing_gives_a_door():
    # a 2 m wide corridor, 12 m long, narrowed to 0.9 m by wall stubs at x = 5
    walls = [(0, 0, 12, 0, 0.1), (0, 2, 12, 2, 0.1), (0, 0, 0, 2, 0.1), (12, 0, 12, 2, 0.1),
             (5, 0, 5, 2, 0.2)]
    grid = draw_world(walls, [((5.0, 1.0), 0.9, "y")], [(0, 0, 12, 2)])
    seg = segment_rooms(grid)
    assert len(seg.doors) == 1
    d = seg.doors[0]
    assert np.hypot(*(d.centre - [5.0, 1.0])) < 0.1
    assert abs(d.width - 0.9) <= 0.1
    # the door line runs across the corridor (along y) and ends at the stubs
    (x1, y1), (x2, y2) = d.end_points
    assert abs(x1 - 5.0) < 0.15 and abs(x2 - 5.0) < 0.15
    assert sorted([y1, y2]) == pytest.approx([0.55 - 0.025, 1.45 + 0.025], abs=0.06)
    assert seg.n_rooms == 2
    assert _region_at(seg, (2.5, 1.0)) != _region_at(seg, (8.5, 1.0))
    assert set(d.rooms) == {_region_at(seg, (2.5, 1.0)), _region_at(seg, (8.5, 1.0))}


def test_uniform_corridor_has_no_door():
    grid = draw_world([(0, 0, 12, 0, 0.1), (0, 2, 12, 2, 0.1), (0, 0, 0, 2, 0.1), (12, 0, 12, 2, 0.1)],
                      [], [(0, 0, 12, 2)])
    seg = segment_rooms(grid)
    assert seg.doors == [] and seg.n_rooms == 1


@pytest.mark.parametrize("opening", [2.0, 2.5])
def test_ring_corridor_with_rooms_behind_wide_openings(opening):
    # the openings are wider than any door and wider than the 2 m corridor: no narrowing of the clearance,
    # but gaps in the corridor's wall, narrow relative to the spaces on both sides -> five rooms
    seg = segment_rooms(ring_corridor(opening))
    assert seg.n_rooms == 5
    corridor = {_region_at(seg, p) for p in [(5, 9), (9, 5), (13, 9), (9, 13), (5, 5), (13, 13)]}
    rooms = [_region_at(seg, p) for p in [(7, 2), (16, 7), (11, 16), (2, 11)]]
    assert len(corridor) == 1 and 0 not in corridor and len(set(rooms)) == 4 and not corridor & set(rooms)
    openings = np.array([[9, 4], [14, 9], [9, 14], [4, 9]], float)
    assert len(seg.doors) == 4 and np.all(_match_doors(seg, openings) < 0.15)
    assert all(abs(d.width - opening) < 0.15 and set(d.rooms) & corridor for d in seg.doors)
    areas = sorted(r.area for r in seg.rooms)
    assert areas[-1] == pytest.approx(58.5, rel=0.05)  # the corridor (40 m of 2 m, the corners, the gaps)
    assert areas[:4] == pytest.approx([4 * 14 - 3.4] * 4, rel=0.05)


@pytest.mark.parametrize("corridor", [0.9, 1.2])
def test_room_at_the_end_of_a_narrow_corridor(corridor):
    # a corridor 0.9 m (as wide as the gap: no narrowing along it) or 1.2 m wide ends in a room through a
    # 0.9 m gap -> two rooms, the border in the room's wall
    seg = segment_rooms(corridor_end(corridor, 0.9))
    assert seg.n_rooms == 2 and len(seg.doors) == 1
    assert _region_at(seg, (4.0, 2.5)) != _region_at(seg, (10.5, 2.5))
    (d,) = seg.doors
    assert abs(d.centre[0] - 8.0) < 0.15 and abs(d.centre[1] - 2.5) < 0.1 and abs(d.width - 0.9) < 0.1
    # a narrowing of the 1.2 m corridor is a door; the mouth of the 0.9 m one is an opening in the room's wall
    assert d.kind == ("opening" if corridor == 0.9 else "door")
    areas = {r.label: r.area for r in seg.rooms}
    assert areas[_region_at(seg, (4.0, 2.5))] == pytest.approx(8 * corridor, rel=0.05)


def test_long_corridor_without_doors_stays_one_room():
    for width in (1.2, 1.8):
        seg = segment_rooms(l_corridor(width))
        assert seg.n_rooms == 1 and seg.doors == []


def test_small_nook_is_merged():
    # a 4 m x 4 m room with a 1 m x 1 m nook behind a 0.6 m opening
    walls = [(0, 0, 4, 0, 0.1), (4, 0, 4, 4, 0.1), (4, 4, 0, 4, 0.1), (0, 4, 0, 0, 0.1),
             (4, 1.5, 5, 1.5, 0.1), (5, 1.5, 5, 2.5, 0.1), (5, 2.5, 4, 2.5, 0.1)]
    grid = draw_world(walls, [((4.0, 2.0), 0.6, "y")], [(0, 0, 4, 4), (4, 1.5, 5, 2.5)])
    seg = segment_rooms(grid, keep_steps=True)
    nook, room = (4.5, 2.0), (2.0, 2.0)
    assert seg.steps["regions"].max() >= 2  # the opening was cut...
    assert seg.n_rooms == 1  # ...and the 1 m^2 nook merged into the room
    assert _region_at(seg, nook) == _region_at(seg, room) == 1
    assert seg.doors == []
    # with a smaller merge threshold the nook stays a room of its own
    seg2 = segment_rooms(grid, config=SegmentationConfig(min_room_area=0.5))
    assert seg2.n_rooms == 2 and _region_at(seg2, nook) != _region_at(seg2, room)
    assert len(seg2.doors) == 1 and np.hypot(*(seg2.doors[0].centre - [4.0, 2.0])) < 0.1


def _two_rooms_checks(seg, furniture_area=0.0):
    assert seg.n_rooms == 3
    assert np.all(_match_doors(seg) < 0.10), _match_doors(seg)
    assert len(seg.doors) == 2
    a, c, b = (_region_at(seg, p) for p in [(3.0, 1.0), (7.25, 2.5), (11.5, 4.0)])
    assert len({a, b, c}) == 3 and min(a, b, c) > 0
    pairs = sorted(tuple(sorted(d.rooms)) for d in seg.doors)
    assert pairs == sorted([tuple(sorted((a, c))), tuple(sorted((b, c)))])
    areas = {r.label: r.area for r in seg.rooms}
    assert areas[a] == pytest.approx(5.8 * 4.8 - furniture_area, rel=0.05)
    assert areas[c] == pytest.approx(2.3 * 1.45, rel=0.15)


def test_two_rooms_drawn_map():
    _two_rooms_checks(segment_rooms(two_rooms()))


def test_two_rooms_from_simulated_scans():
    grid = two_rooms()
    path = np.array([[1.5, 1.2, 0], [3.0, 1.0, 0.3], [4.5, 1.2, 1], [4.5, 3.8, 2], [2, 4, 3], [1.2, 2.5, -1],
                     [5.0, 2.5, 0], [7.25, 2.5, 0], [9.5, 2.5, 0], [12, 3.5, 0.5], [13.5, 1.2, 2], [10, 1, 3]])
    ranges, angles = cast_scans(grid, path, noise=0.01, rng=3)
    from hsmap.datasets.frames import LaserScan2D

    scans = [LaserScan2D(r, angles, 0.05, 10.0) for r in ranges]
    scan_grid = grid_from_scans(scans, path, 0.05)
    _two_rooms_checks(segment_rooms(scan_grid))


def test_paper_method_finds_doors_in_the_band():
    # 0.8 m doors: half width 0.40 m, the middle of the paper's 40 +/- 5 cm band
    walls = [(0, 0, 5, 0, 0.2), (5, 0, 5, 4, 0.2), (5, 4, 0, 4, 0.2), (0, 4, 0, 0, 0.2),
             (5, 0, 10, 0, 0.2), (10, 0, 10, 4, 0.2), (10, 4, 5, 4, 0.2)]
    grid = draw_world(walls, [((5.0, 2.0), 0.8, "y")], [(0, 0, 5, 4), (5, 0, 10, 4)])
    cfg = SegmentationConfig(method="paper")
    seg = segment_rooms(grid, config=cfg)
    assert seg.n_rooms == 2 and len(seg.doors) == 1
    assert np.hypot(*(seg.doors[0].centre - [5.0, 2.0])) < 0.1
    # a band that excludes 0.4 m finds nothing
    seg = segment_rooms(grid, config=dataclasses.replace(cfg, door_half_width=0.6, door_half_width_tolerance=0.05))
    assert seg.n_rooms == 1 and seg.doors == []


def test_wide_opening_is_no_door():
    # two 5 m x 4 m halves of a hall joined by a 3.6 m opening in the 4 m wall between them (0.2 m stubs left):
    # not narrow relative to the space on either side -> one region
    walls = [(0, 0, 10, 0, 0.2), (10, 0, 10, 4, 0.2), (10, 4, 0, 4, 0.2), (0, 4, 0, 0, 0.2), (5, 0, 5, 4, 0.2)]
    grid = draw_world(walls, [((5.0, 2.0), 3.6, "y")], [(0, 0, 10, 4)])
    seg = segment_rooms(grid)
    assert seg.n_rooms == 1 and seg.doors == []
    # a 3 m opening (three quarters of the wall) is a room border, as the benchmark's ground truth draws one
    # across rooms that open onto a corridor almost over their full width (lab_c_scan, lab_a_scan)
    seg = segment_rooms(draw_world(walls, [((5.0, 2.0), 3.0, "y")], [(0, 0, 10, 4)]))
    assert seg.n_rooms == 2 and len(seg.doors) == 1 and abs(seg.doors[0].width - 3.0) < 0.15


def test_furniture_assignment_and_steps():
    table = (2.0, 1.8, 3.5, 3.0)
    grid = two_rooms(furniture=[table])
    seg = segment_rooms(grid, keep_steps=True)
    _two_rooms_checks(seg, furniture_area=1.5 * 1.2)
    r, c = grid.geometry.world_to_index(np.array([2.75, 2.4]))
    assert seg.labels[r, c] == 0
    full = segment_rooms(grid, config=SegmentationConfig(assign_furniture=True))
    assert full.labels[r, c] == _region_at(full, (1.0, 1.0))
    # walls stay unlabelled
    wr, wc = grid.geometry.world_to_index(np.array([0.0, 2.0]))
    assert full.labels[wr, wc] == 0
    for key in ("free", "filtered", "distance", "skeleton", "product", "candidates", "door_lines", "regions"):
        assert seg.steps[key].shape == grid.data.shape
    assert seg.steps["skeleton"].any() and (seg.steps["product"][seg.steps["skeleton"]] > 0).all()


def test_labels_follow_the_grid_geometry():
    grid = two_rooms()
    shifted = OccupancyGrid(grid.data, GridGeometry(grid.geometry.shape, 0.05, (100.0, -50.0)))
    seg = segment_rooms(shifted)
    d = sorted(d.centre[0] for d in seg.doors)
    dx = 100.0 - grid.geometry.origin[0]
    assert d == pytest.approx([6.0 + dx, 8.5 + dx], abs=0.1)


def test_bool_mask_input_and_resolution():
    grid = two_rooms(resolution=0.05)
    seg = segment_rooms(grid.free, 0.05)
    assert seg.n_rooms == 3
    # the same mask read at twice the resolution: doors are twice as wide, beyond the default maximum
    seg2 = segment_rooms(grid.free, 0.1)
    assert all(d.width > 1.5 for d in seg2.doors)


def test_bad_input():
    with pytest.raises(EmptyInputError, match="no free"):
        segment_rooms(np.zeros((20, 20), dtype=bool))
    with pytest.raises(InputError, match="boolean"):
        segment_rooms(np.full((20, 20), 255, dtype=np.uint8))
    with pytest.raises(ShapeError):
        segment_rooms(np.ones((4, 4, 3), dtype=bool))
    with pytest.raises(InputError, match="resolution"):
        segment_rooms(np.ones((4, 4), dtype=bool), 0.0)
    with pytest.raises(ConfigError):
        SegmentationConfig(method="voronoi")
    with pytest.raises(ConfigError):
        SegmentationConfig(min_door_half_width=1.0, max_door_half_width=0.5)
    with pytest.raises(ConfigError, match="gap_ratio"):
        SegmentationConfig(gap_ratio=1.5)
    with pytest.raises(ConfigError, match="max_gap_width"):
        SegmentationConfig(max_gap_width=0.0)
    with pytest.raises(ConfigError, match="corner_angle"):
        SegmentationConfig(corner_angle=-10.0)
    with pytest.raises(ConfigError, match="unknown"):
        from_dict(SegmentationConfig, {"door_width": 0.9})
    # free cells with unknown all around (no wall) still make a room; an isolated free speck under
    # min_room_area does not
    data = np.full((60, 60), -1, np.int8)
    data[5:45, 5:45] = FREE
    data[50:55, 50:55] = FREE
    seg = segment_rooms(OccupancyGrid(data, GridGeometry((60, 60), 0.05)))
    assert seg.n_rooms == 1 and (seg.labels > 0).sum() == 40 * 40
    # an isolated pocket of 0.3 m^2 (>= min_isolated_area) is a room of its own, though under min_room_area
    data[50:58, 5:20] = FREE
    seg = segment_rooms(OccupancyGrid(data, GridGeometry((60, 60), 0.05)))
    assert seg.n_rooms == 2 and (seg.labels == seg.labels[52, 10]).sum() == 8 * 15


def test_points_in_doors(rng):
    door = Door(np.array([6.0, 2.5]), np.array([[6.0, 2.05], [6.0, 2.95]]), 0.9)
    pts2 = np.vstack([rng.uniform([5.9, 2.1], [6.1, 2.9], (50, 2)),  # in the doorway
                      rng.uniform([0, 0], [5, 5], (200, 2))])  # in the room, away from it
    (inside,) = points_in_doors(pts2, [door], depth=0.3)
    assert len(inside) == 50
    pts3 = np.column_stack([pts2, np.r_[np.linspace(0, 2.5, 50), np.zeros(200)]])
    (inside3,) = points_in_doors(pts3, [door], depth=0.3, z_range=(0.0, 2.0))
    assert inside3.shape[1] == 3 and 35 <= len(inside3) < 50 and (inside3[:, 2] <= 2.0).all()
    with pytest.raises(ShapeError):
        points_in_doors(np.zeros((3, 4)), [door])


@pytest.mark.datasets
def test_benchmark_map(datasets_dir):
    from hsmap.evaluation import segmentation_scores
    from hsmap.maps.grid import read_image_gray, read_map

    folder = datasets_dir / "ipa_room_segmentation"
    gt = read_image_gray(folder / "Freiburg52_scan_gt_segmentation.png")
    for name, p_min, r_min in (("Freiburg52_scan", 0.9, 0.95), ("Freiburg52_scan_furnitures", 0.9, 0.85)):
        seg = segment_rooms(read_map(folder / f"{name}.png"))
        s = segmentation_scores(seg.labels, gt)
        assert s.precision >= p_min and s.recall >= r_min, (name, s)
        assert 8 <= seg.n_rooms <= 12 and len(seg.doors) >= 8


def test_office_floor_rooms_and_doors():
    # the simulator's slam-office layout: 8 rooms (3 offices, corridor, meeting room, kitchen, office 4,
    # open area with two columns) and 10 open 0.9 m doors
    t = 0.15
    walls = [(0, 0, 21, 0, 0.25), (21, 0, 21, 13.6, 0.25), (21, 13.6, 0, 13.6, 0.25), (0, 13.6, 0, 0, 0.25),
             (0, 6, 15, 6, t), (0, 7.8, 15, 7.8, t), (15, 0, 15, 13.6, 0.2), (5, 0, 5, 6, t), (10, 0, 10, 6, t),
             (7, 7.8, 7, 13.6, t), (10.5, 7.8, 10.5, 13.6, t)]
    doors = [((3.8, 6), 0.9, "x"), ((8.8, 6), 0.9, "x"), ((13.8, 6), 0.9, "x"), ((1.2, 7.8), 0.9, "x"),
             ((5.8, 7.8), 0.9, "x"), ((8.8, 7.8), 0.9, "x"), ((13.8, 7.8), 0.9, "x"), ((15, 6.9), 0.9, "y"),
             ((15, 2.0), 0.9, "y"), ((15, 11.0), 0.9, "y")]
    columns = [(17.8, 4.3, 18.2, 4.7), (17.8, 9.3, 18.2, 9.7)]
    grid = draw_world(walls, doors, [(0, 0, 21, 13.6)], furniture=columns)
    seg = segment_rooms(grid)
    assert seg.n_rooms == 8 and len(seg.doors) == 10
    assert np.all(_match_doors(seg, np.array([c for c, _, _ in doors])) < 0.1)
    corridor = _region_at(seg, (7.5, 6.9))
    assert sum(corridor in d.rooms for d in seg.doors) == 8


def test_thin_free_standing_partition_is_a_wall_not_clutter():
    # an 8 m x 4 m hall split at x = 4 by a free-standing partition one pixel thick, with 0.9 m gaps to
    # the outer walls at both ends: two rooms, two doors; a chair-sized blob is clutter and changes nothing
    walls = [(0, 0, 8, 0, 0.1), (8, 0, 8, 4, 0.1), (8, 4, 0, 4, 0.1), (0, 4, 0, 0, 0.1), (4.0, 0.95, 4.0, 3.05, 0.05)]
    grid = draw_world(walls, [], [(0, 0, 8, 4)], furniture=[(1.8, 1.8, 2.2, 2.2)])
    assert grid.occupied[:, grid.geometry.world_to_index([4.0, 2.0])[1]].sum() < 50  # the partition is thin
    seg = segment_rooms(grid)
    assert seg.n_rooms == 2 and len(seg.doors) == 2
    assert np.all(_match_doors(seg, np.array([[4.0, 0.5], [4.0, 3.5]])) < 0.15)
    assert _region_at(seg, (2.0, 3.0)) != _region_at(seg, (6.0, 3.0))
