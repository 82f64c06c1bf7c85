import numpy as np
import pytest
import yaml
from PIL import Image
from scipy import ndimage as ndi

from hsmap.errors import DataFormatError, DatasetError, EmptyInputError, HsmapError, InputError, ShapeError
from hsmap.maps.grid import (
    FREE,
    OCCUPIED,
    UNKNOWN,
    GridGeometry,
    OccupancyGrid,
    grid_from_point_slice,
    grid_from_scans,
    read_image_gray,
    read_label_image,
    read_map,
    write_label_image,
    write_map,
)


def test_world_pixel_roundtrip(rng):
    g = GridGeometry((40, 60), 0.05, (-1.0, 2.0))
    xy = rng.uniform([-1, 2], [2, 4], (100, 2))
    np.testing.assert_allclose(g.pixel_to_world(g.world_to_pixel(xy)), xy, atol=1e-12)


def test_row_flip_and_origin():
    g = GridGeometry((10, 20), 0.5, (1.0, -2.0))
    # lower-left pixel centre
    np.testing.assert_allclose(g.pixel_to_world([9, 0]), [1.25, -1.75])
    # top-right pixel centre
    np.testing.assert_allclose(g.pixel_to_world([0, 19]), [1.0 + 9.75, -2.0 + 4.75])
    np.testing.assert_array_equal(g.world_to_index([[1.01, -1.99], [10.9, 2.9]]), [[9, 0], [0, 19]])


def test_covering_and_extent():
    g = GridGeometry.covering([0, 0], [3.0, 1.0], 0.1, margin=0.5)
    assert g.shape == (20, 40)
    assert g.extent() == pytest.approx((-0.5, 3.5, -0.5, 1.5))


def test_bad_resolution():
    with pytest.raises(InputError, match="resolution"):
        GridGeometry((10, 10), 0.0)


# ---------------------------------------------------------------------------------------------------------
# occupancy grids: map_server I/O, images, scans, height slices
# ---------------------------------------------------------------------------------------------------------



def _small_grid():
    data = np.full((6, 8), UNKNOWN, dtype=np.int8)
    data[1:5, 1:7] = FREE
    data[0, :] = OCCUPIED
    data[2, 3] = OCCUPIED
    return OccupancyGrid(data, GridGeometry((6, 8), 0.1, (-1.5, 2.0)))


def test_map_server_roundtrip(tmp_path):
    g = _small_grid()
    yml, pgm = write_map(tmp_path / "m.yaml", g)
    assert pgm.name == "m.pgm" and pgm.is_file()
    meta = yaml.safe_load(yml.read_text())
    assert meta["image"] == "m.pgm" and meta["resolution"] == 0.1 and meta["origin"] == [-1.5, 2.0, 0.0]
    with Image.open(pgm) as im:
        img = np.asarray(im)
    assert img[0, 0] == 0 and img[1, 1] == 254 and img[5, 0] == 205
    back = read_map(yml)
    np.testing.assert_array_equal(back.data, g.data)
    assert back.geometry == g.geometry
    # resolution override
    assert read_map(yml, resolution=0.2).geometry.resolution == 0.2
    # no temporary files left behind
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.pgm", "m.yaml"]


def test_map_server_negate_and_thresholds(tmp_path):
    Image.fromarray(np.array([[0, 128, 255]], dtype=np.uint8)).save(tmp_path / "n.png")
    (tmp_path / "n.yaml").write_text("image: n.png\nresolution: 0.5\norigin: [0, 0, 0]\nnegate: 1\n"
                                     "occupied_thresh: 0.65\nfree_thresh: 0.196\n")
    g = read_map(tmp_path / "n.yaml")
    np.testing.assert_array_equal(g.data, [[FREE, UNKNOWN, OCCUPIED]])


def test_plain_image_uses_benchmark_rule(tmp_path):
    Image.fromarray(np.array([[255, 254, 250, 249, 205, 0]], dtype=np.uint8)).save(tmp_path / "a.png")
    g = read_map(tmp_path / "a.png")
    assert g.geometry.resolution == 0.05
    np.testing.assert_array_equal(g.free, [[True, True, True, False, False, False]])
    assert g.occupied[0, 5] and not g.occupied[0, 4]
    # RGBA images read as gray like OpenCV's imread(path, 0)
    rgba = np.zeros((2, 2, 4), dtype=np.uint8)
    rgba[..., :3] = 254
    rgba[..., 3] = 255
    Image.fromarray(rgba, "RGBA").save(tmp_path / "b.png")
    assert (read_image_gray(tmp_path / "b.png") == 254).all()


def test_label_image_roundtrip(tmp_path):
    lab = np.zeros((5, 7), dtype=np.int32)
    lab[1:3, 1:4] = 1
    lab[3:, 4:] = 700  # needs 16 bits
    write_label_image(tmp_path / "r.png", lab)
    with Image.open(tmp_path / "r.png") as im:
        assert im.mode.startswith("I")
    np.testing.assert_array_equal(read_label_image(tmp_path / "r.png"), lab)


def test_bad_map_inputs(tmp_path):
    with pytest.raises(DatasetError, match="no such"):
        read_map(tmp_path / "missing.png")
    (tmp_path / "notimage.png").write_text("hello, not a PNG")
    with pytest.raises(DataFormatError, match="not a readable image"):
        read_map(tmp_path / "notimage.png")
    Image.fromarray(np.full((3, 3), 255, np.uint8)).save(tmp_path / "ok.png")
    for bad in (0.0, -0.05, float("nan")):
        with pytest.raises(InputError, match="resolution"):
            read_map(tmp_path / "ok.png", resolution=bad)
    (tmp_path / "m.yaml").write_text("image: nowhere.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n")
    with pytest.raises(DatasetError, match="nowhere.pgm"):
        read_map(tmp_path / "m.yaml")
    (tmp_path / "k.yaml").write_text("image: ok.png\norigin: [0, 0, 0]\n")
    with pytest.raises(DataFormatError, match="resolution"):
        read_map(tmp_path / "k.yaml")
    (tmp_path / "r.yaml").write_text("image: ok.png\nresolution: 0\norigin: [0, 0, 0]\n")
    with pytest.raises(HsmapError, match="resolution"):
        read_map(tmp_path / "r.yaml")


def _square_room_scans(poses, half=2.0, n=720):
    """Exact ranges of a planar LiDAR inside the square room [-half, half]^2."""
    angles = np.linspace(-np.pi, np.pi, n, endpoint=False)
    ranges = []
    for x, y, yaw in poses:
        a = angles + yaw
        c, s = np.cos(a), np.sin(a)
        with np.errstate(divide="ignore"):
            tx = np.where(c > 0, (half - x) / c, np.where(c < 0, (-half - x) / c, np.inf))
            ty = np.where(s > 0, (half - y) / s, np.where(s < 0, (-half - y) / s, np.inf))
        ranges.append(np.minimum(tx, ty))
    return np.array(ranges), angles


def test_grid_from_scans_square_room():
    from hsmap.datasets.frames import LaserScan2D

    poses = np.array([[0.0, 0.0, 0.0], [0.7, -0.4, 1.0], [-0.8, 0.6, -2.0]])
    ranges, angles = _square_room_scans(poses)
    # scans in the sensor frame; the sensor sits 0.1 m ahead of the robot base
    ext = np.array([0.1, 0.0, 0.0])
    base = poses.copy()
    base[:, 0] -= 0.1 * np.cos(poses[:, 2])
    base[:, 1] -= 0.1 * np.sin(poses[:, 2])
    scans = [LaserScan2D(r, angles, 0.05, 10.0) for r in ranges]
    g = grid_from_scans(scans, base, 0.05, extrinsic=ext)
    geo = g.geometry
    # walls: cells at the wall are occupied, the room's inside is free, the outside unknown
    wall = np.array([[2.0, y] for y in np.linspace(-1.8, 1.8, 10)] + [[x, -2.0] for x in np.linspace(-1.8, 1.8, 10)])
    idx = geo.world_to_index(wall)
    near = ndi.maximum_filter(g.occupied, size=3)  # the wall line lies on a cell border: either side
    assert near[idx[:, 0], idx[:, 1]].all()
    assert g.occupied.sum() < 1.5 * 4 * 4.0 / 0.05  # a thin outline, not a blob
    inside = geo.world_to_index(np.array([[0.0, 0.0], [1.5, 1.5], [-1.7, -1.2], [1.0, -1.8]]))
    assert g.free[inside[:, 0], inside[:, 1]].all()
    outside = geo.world_to_index(np.array([[2.3, 0.0], [0.0, -2.35]]))
    assert (g.data[outside[:, 0], outside[:, 1]] == UNKNOWN).all()
    # nothing is cleared behind the walls (the swept area stops short of the hits)
    fxy = geo.pixel_to_world(np.argwhere(g.free))
    assert (np.abs(fxy).max(1) > 2.0).sum() < 0.01 * len(fxy)
    # the room's free area is about 16 m^2
    assert abs(g.free.sum() * 0.05**2 - 16.0) < 1.0
    # plain (N, 2) end points give the same occupied cells
    pts = [np.column_stack([r * np.cos(angles), r * np.sin(angles)]) for r in ranges]
    g2 = grid_from_scans(pts, base, 0.05, extrinsic=ext, geometry=geo)
    assert (g2.occupied == g.occupied).mean() > 0.999


def test_grids_of_scan_prefixes_in_one_pass():
    """The growing map of a recording: each prefix's grid equals grid_from_scans of those scans alone."""
    from hsmap.datasets.frames import LaserScan2D
    from hsmap.maps.grid import grids_from_scan_prefixes

    poses = np.array([[0.0, 0.0, 0.0], [0.7, -0.4, 1.0], [-0.8, 0.6, -2.0], [0.3, 0.3, 2.5]])
    ranges, angles = _square_room_scans(poses)
    ranges[1][::3] = np.inf  # no returns: a scan's swept area goes back to the sensor there
    scans = [LaserScan2D(r, angles, 0.05, 10.0) for r in ranges]
    geo = grid_from_scans(scans, poses, 0.05).geometry
    counts = [0, 1, 1, 3, 4]
    grids = grids_from_scan_prefixes(scans, poses, counts, geometry=geo)
    assert len(grids) == len(counts) and (grids[0].data == UNKNOWN).all()
    for c, g in zip(counts[1:], grids[1:], strict=True):
        np.testing.assert_array_equal(g.data, grid_from_scans(scans[:c], poses[:c], geometry=geo).data)
    assert not np.array_equal(grids[1].data, grids[4].data)
    with pytest.raises(InputError, match="counts"):
        grids_from_scan_prefixes(scans, poses, [2, 1], geometry=geo)
    # max_cells: the same room on a coarser grid that fits, and untouched where 5 cm cells already fit
    small = grids_from_scan_prefixes(scans, poses, [4], 0.05, max_cells=geo.height * geo.width // 4)[0]
    assert small.geometry.height * small.geometry.width <= geo.height * geo.width // 4
    assert 0.1 <= small.geometry.resolution < 0.11
    assert abs(small.free.sum() * small.geometry.resolution**2 - grids[4].free.sum() * 0.05**2) < 1.0
    same = grids_from_scan_prefixes(scans, poses, [4], 0.05, max_cells=geo.height * geo.width)[0]
    assert same.geometry == geo and np.array_equal(same.data, grids[4].data)
    with pytest.raises(InputError, match="max_cells"):
        grids_from_scan_prefixes(scans, poses, [4], max_cells=0)


def test_grid_from_scans_bad_input():
    with pytest.raises(ShapeError):
        grid_from_scans([np.zeros((3, 2))], np.zeros((2, 3)))
    with pytest.raises(ShapeError):
        grid_from_scans([np.zeros((3, 3))], np.zeros((1, 3)))
    with pytest.raises(EmptyInputError):
        grid_from_scans([np.full((3, 2), np.nan)], np.zeros((1, 3)))
    with pytest.raises(InputError, match="resolution"):
        grid_from_scans([np.ones((3, 2))], np.zeros((1, 3)), resolution=0)
    with pytest.raises(ShapeError, match="extrinsic"):
        grid_from_scans([np.ones((3, 2))], np.zeros((1, 3)), extrinsic=np.zeros((2, 3)))


def test_scans_to_points_with_one_or_per_scan_extrinsics():
    from hsmap.datasets.frames import LaserScan2D
    from hsmap.maps.grid import scans_to_points

    scan = LaserScan2D(np.array([1.0, np.nan, 2.0, 50.0]), np.array([0.0, 0.5, np.pi / 2, 1.0]), 0.1, 10.0)
    poses = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, np.pi / 2]])
    pts = scans_to_points([scan, scan], poses, [0.5, 0.0, 0.0])
    # the real returns only (NaN and beyond range_max dropped), sensor 0.5 m ahead of the robot
    np.testing.assert_allclose(pts, [[2.5, 0.0], [1.5, 2.0], [0.0, 1.5], [-2.0, 0.5]], atol=1e-12)
    per_scan = scans_to_points([scan, scan], poses, [[0.5, 0.0, 0.0], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(per_scan[2:], [[0.0, 1.0], [-2.0, 0.0]], atol=1e-12)
    assert scans_to_points([], np.zeros((0, 3))).shape == (0, 2)


def test_grid_from_point_slice(rng):
    # a 4 m x 3 m room: walls 0..2.6 m high, floor points, and a 0.75 m high table that must not show
    n = 20000
    t = rng.uniform(0, 1, n)
    z = rng.uniform(0, 2.6, n)
    side = rng.integers(0, 4, n)
    x = np.where(side == 0, 0.0, np.where(side == 1, 4.0, t * 4.0))
    y = np.where(side == 2, 0.0, np.where(side == 3, 3.0, t * 3.0))
    walls = np.column_stack([x, y, z])
    floor = np.column_stack([rng.uniform(0.05, 3.95, n), rng.uniform(0.05, 2.95, n), rng.normal(0, 0.01, n)])
    table = np.column_stack([rng.uniform(1.5, 2.5, 3000), rng.uniform(1.0, 2.0, 3000), rng.uniform(0.7, 0.75, 3000)])
    g = grid_from_point_slice(np.vstack([walls, floor, table]), z_min=1.7, z_max=1.8, resolution=0.05)
    geo = g.geometry
    wall_idx = geo.world_to_index(np.array([[0.0, 1.5], [4.0, 1.0], [2.0, 0.0], [1.0, 3.0]]))
    assert g.occupied[wall_idx[:, 0], wall_idx[:, 1]].all()
    table_idx = geo.world_to_index(np.array([[2.0, 1.5]]))
    assert g.free[table_idx[:, 0], table_idx[:, 1]].all()  # the table is below the slice
    assert g.occupied.sum() * 0.05 < 2 * (4 + 3) * 1.6  # only the walls' outline
    with pytest.raises(EmptyInputError, match="slice"):
        grid_from_point_slice(floor, z_min=1.7, z_max=1.8)
    with pytest.raises(InputError):
        grid_from_point_slice(walls, z_min=1.8, z_max=1.7)
    with pytest.raises(ShapeError):
        grid_from_point_slice(walls[:, :2])


def test_resample_labels_onto_another_grid():
    from hsmap.maps.grid import GridGeometry, resample_labels

    src = GridGeometry((4, 6), 0.5, (1.0, 2.0))  # x 1..4, y 2..4
    lab = np.arange(24, dtype=np.int32).reshape(4, 6)
    assert np.array_equal(resample_labels(lab, src, src), lab)
    fine = GridGeometry((8, 12), 0.25, (1.0, 2.0))  # the same area, twice as fine
    out = resample_labels(lab, src, fine)
    assert np.array_equal(out, np.repeat(np.repeat(lab, 2, 0), 2, 1))
    shifted = GridGeometry((4, 6), 0.5, (0.0, 2.0))  # one metre to the left: two columns outside
    out = resample_labels(lab, src, shifted)
    assert (out[:, :2] == 0).all() and np.array_equal(out[:, 2:], lab[:, :4])
