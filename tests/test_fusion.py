"""2D/3D map alignment (hsmap.maps.fusion): a known offset between the floor map and the slice of a simulated world
is recovered; the slice sees over furniture the floor map sees; bad input raises HsmapError."""

from __future__ import annotations

import numpy as np
import pytest

from hsmap.datasets.simulated import SimulatedDataset
from hsmap.errors import ConfigError, EmptyInputError, HsmapError, InputError, ShapeError
from hsmap.geometry import compose, invert, matrix_to_pose, pose_to_matrix
from hsmap.maps.fusion import (
    FusionConfig,
    align_maps,
    common_grids,
    occupied_points,
    overlap_scores,
    overlay_classes,
    overlay_image,
    resample_grid,
    slice_grid,
    slice_points,
    slice_scan,
    slice_scans,
)
from hsmap.maps.grid import (
    FREE,
    OCCUPIED,
    UNKNOWN,
    GridGeometry,
    OccupancyGrid,
    grid_from_scans,
    scans_to_points,
)

pytest.importorskip("open3d")

FRAMES = 40  # the robot's first 20 s in the two-rooms world: room-a, west and south of the desk bench


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """A short two-rooms run (smaller 3D LiDAR) and its floor map and 1.7-1.8 m slice at the true poses."""
    from hsmap.sim import Lidar3DConfig, load_scenario, simulate
    from hsmap.sim.catalog import resolve_scenario

    scn = load_scenario(resolve_scenario("two-rooms")).replace(lidar3d=Lidar3DConfig(channels=64, columns=512))
    out = tmp_path_factory.mktemp("fusion") / "two-rooms"
    simulate(scn, out, seed=3, max_frames=FRAMES)
    ds = SimulatedDataset(out)
    gt = ds.groundtruth.poses
    floor = grid_from_scans([ds.scan2d(i) for i in range(len(ds))], gt, 0.05, extrinsic=ds.extrinsic2d)
    sl = slice_grid(ds.frames(), gt, z_min=1.7, z_max=1.8, resolution=0.05)
    return ds, floor, sl


def _floor_in_frame(ds, offset):
    """The floor map built in a frame F whose pose in the world is ``offset``: the floor->slice transform is
    then ``offset``."""
    poses = np.array([compose(invert(offset), p) for p in ds.groundtruth.poses])
    scans = [ds.scan2d(i) for i in range(len(ds))]
    grid = grid_from_scans(scans, poses, 0.05, extrinsic=ds.extrinsic2d)
    return grid, scans_to_points(scans, poses, ds.extrinsic2d)


def _error(result_T, offset):
    e = matrix_to_pose(np.linalg.inv(pose_to_matrix(offset)) @ result_T)
    return float(np.hypot(e[0], e[1])), float(np.rad2deg(abs(e[2])))


@pytest.mark.parametrize("offset", [(0.7, -0.45, np.deg2rad(14.0)), (-1.2, 0.8, np.deg2rad(-30.0))])
def test_known_offset_recovered_from_points(world, offset):
    """The floor map's scan points registered to the slice's occupied cells: within 2 cm and 0.5 deg."""
    ds, _, sl = world
    floor, pts = _floor_in_frame(ds, np.array(offset))
    res = align_maps(floor, sl, floor_points=pts, rng=0)  # no initial guess: a global search
    dt, dyaw = _error(res.transformation, offset)
    assert dt < 0.02, f"translation error {dt:.3f} m"
    assert dyaw < 0.5, f"yaw error {dyaw:.2f} deg"


@pytest.mark.parametrize("offset", [(0.7, -0.45, np.deg2rad(14.0)), (-1.2, 0.8, np.deg2rad(-30.0))])
def test_known_offset_recovered_from_grids(world, offset):
    """Cells against cells: the two 5 cm lattices do not line up, so within 3 cm (and 0.5 deg)."""
    ds, _, sl = world
    floor, _ = _floor_in_frame(ds, np.array(offset))
    res = align_maps(floor, sl, rng=0)
    dt, dyaw = _error(res.transformation, offset)
    assert dt < 0.03, f"translation error {dt:.3f} m"
    assert dyaw < 0.5, f"yaw error {dyaw:.2f} deg"
    assert res.floor.geometry == res.slice.geometry
    # aligned, the walls agree: more of the slice lies on the floor map than of the floor map on the slice (the
    # furniture the slice does not see). Not all of the slice: in this furnished room the bookcases on the north
    # wall, the cabinets on the west wall and the sofa on the east wall hide about 40% of the walls' cells from
    # the floor-level LiDAR (before registration the overlap is about 0.1)
    assert res.slice_matched > 0.5
    assert 0.3 < res.floor_matched < res.slice_matched
    assert 0.35 < res.overlap < 1.0


def test_identity_when_maps_share_a_frame(world):
    ds, floor, sl = world
    pts = scans_to_points([ds.scan2d(i) for i in range(len(ds))], ds.groundtruth.poses, ds.extrinsic2d)
    res = align_maps(floor, sl, floor_points=pts, rng=2)
    dt, dyaw = _error(res.transformation, np.zeros(3))
    assert dt < 0.02 and dyaw < 0.5


def test_slice_scans_and_points(world):
    ds, _, sl = world
    scans, spos = slice_scans(ds.frames(stop=5), ds.groundtruth.poses[:5])
    assert len(scans) == 5 and spos.shape == (5, 3)
    # the virtual sensor sits at the 3D LiDAR: 0.10 m behind the base
    np.testing.assert_allclose(spos[0], compose(ds.groundtruth.poses[0], [ds.extrinsic3d[0], ds.extrinsic3d[1],
                                                                          ds.extrinsic3d[5]]), atol=1e-9)
    pts = scans_to_points(scans, spos)
    idx = sl.geometry.world_to_index(pts)
    ok = sl.geometry.inside(idx)
    # most land on occupied cells; not all: the north wall's face (y = 4.9) lies on a cell border, and its hits
    # (1 cm noise) that fall in the cell before it are cleared by other poses' rays ending just behind the border
    assert ok.all() and (sl.data[idx[:, 0], idx[:, 1]] == OCCUPIED).mean() > 0.9


def test_slice_sees_over_furniture(world):
    """The 1.1 m cabinet at (0.36, 1.2) and the 1.5 m bookcase at (1.2, 4.73) stand in the floor map; the slice
    sees over both to the walls behind them; the west wall where no furniture stands is in both maps."""
    _, floor, sl = world
    f2, s2 = common_grids(floor, sl)
    geo = f2.geometry
    cls = overlay_classes(f2, s2, tolerance=0.1)
    cabinet = geo.world_to_index(np.array([[0.62, 1.2], [0.62, 1.0], [0.62, 1.4]]))  # its front face
    assert (f2.data[cabinet[:, 0], cabinet[:, 1]] == OCCUPIED).any()
    assert not (s2.data[cabinet[:, 0], cabinet[:, 1]] == OCCUPIED).any()
    assert 3 in cls[cabinet[:, 0], cabinet[:, 1]]  # "floor only"
    # the slice: free in front of the west wall behind the cabinet, occupied at the wall
    assert s2.data[tuple(geo.world_to_index([0.3, 1.2]))] == FREE
    wall = geo.world_to_index(np.array([[x, 1.2] for x in (0.02, 0.07, 0.12)]))  # its face is at x = 0.1
    assert (s2.data[wall[:, 0], wall[:, 1]] == OCCUPIED).any()
    # the bookcase's front face (y = 4.58) is in the floor map only; the slice sees the north wall (face at
    # y = 4.9) behind it, which the floor map does not
    xs = np.arange(0.7, 1.75, 0.1)
    face = np.stack([geo.world_to_index(np.array([[x, y] for x in xs])) for y in (4.56, 4.6)])  # (2, X, 2)
    face_cls = cls[face[..., 0], face[..., 1]]
    assert ((face_cls == 3).any(axis=0)).mean() > 0.6  # "floor only"
    assert not (s2.data[face[..., 0], face[..., 1]] == OCCUPIED).any()
    behind = np.stack([geo.world_to_index(np.array([[x, y] for x in xs])) for y in (4.88, 4.93)])
    assert ((cls[behind[..., 0], behind[..., 1]] == 4).any(axis=0)).mean() > 0.6  # "slice only"
    # the west wall north of the cabinets, seen by both
    west = np.stack([geo.world_to_index(np.array([[x, y] for y in np.arange(2.7, 4.3, 0.1)])) for x in (0.07, 0.12)])
    assert ((cls[west[..., 0], west[..., 1]] == 2).any(axis=0)).mean() > 0.6  # "both"
    rgb = overlay_image(f2, s2)
    assert rgb.shape == f2.data.shape + (3,) and rgb.dtype == np.uint8


def test_slice_scan_keeps_the_nearest_point_per_bin():
    # a level sensor 1.6 m up at (1, 2) facing +y; a round wall 3 m away and a post 1 m away to its +x side
    az = np.linspace(-np.pi, np.pi, 360, endpoint=False) + np.pi / 360  # one per 1-degree bin, at its middle
    heights = np.linspace(-1.5, 1.2, 28)  # sensor frame: world z = 1.6 + h
    wall = np.array([[3 * np.cos(a), 3 * np.sin(a), h] for a in az for h in heights])
    post = np.array([[1.0, 0.0, h] for h in heights])
    sensor = np.array([1.0, 2.0, 1.6, 0.0, 0.0, np.pi / 2])
    scan, pose = slice_scan(np.vstack([wall, post]), sensor, z_min=1.7, z_max=1.8, bins=360)
    np.testing.assert_allclose(pose, [1.0, 2.0, np.pi / 2])
    r = np.hypot(scan[:, 0], scan[:, 1])
    assert len(scan) == 360
    assert np.sum(np.isclose(r, 1.0)) == 1 and np.sum(np.isclose(r, 3.0)) == 359
    ang = np.arctan2(scan[:, 1], scan[:, 0])
    assert np.all(np.diff(np.unwrap(ang)) > 0)  # azimuth order
    # the post is at the sensor's +x: in the world it lies at (1, 3), 1 m along +y
    world = scan[np.isclose(r, 1.0)][0] @ pose_to_matrix(pose)[:2, :2].T + pose[:2]
    np.testing.assert_allclose(world, [1.0, 3.0], atol=1e-9)


def test_slice_scan_marks_what_it_did_not_see():
    """A sensor in a corridor sees the near wall at the slice height only over part of its azimuths (a LiDAR
    with few channels crosses the slice at some distances only) and a far wall through a gap: no free space is
    claimed across the unseen azimuths between them."""
    sensor = np.array([0.0, 0.0, 1.6, 0.0, 0.0, 0.0])
    near = np.array([[1.0, np.tan(a), 0.15] for a in np.deg2rad(np.arange(-30, 0) + 0.5)])  # wall x = 1, -30..0 deg
    far = np.array([[4 * np.cos(a), 4 * np.sin(a), 0.15] for a in np.deg2rad(np.arange(40, 70) + 0.5)])
    scan, pose = slice_scan(np.vstack([near, far]), sensor, bins=360)
    gaps = np.flatnonzero(np.isnan(scan[:, 0]))
    assert len(scan) == 61 and gaps.tolist() == [30]  # one NaN row between the two seen arcs
    grid = grid_from_scans([scan], pose[None], 0.05)
    geo = grid.geometry
    seen = geo.world_to_index(np.array([[0.5, -0.1], [2.0, 2.5]]))  # in front of the near wall; before the far one
    assert all(grid.data[r, c] == FREE for r, c in seen)
    unseen = geo.world_to_index(np.array([[2.0, 1.5], [2.5, 2.0]]))  # between the arcs, behind x = 1
    assert all(grid.data[r, c] == UNKNOWN for r, c in unseen)
    # the old chord from (1, 0) to the far arc would have cleared them
    dense = slice_scan(np.vstack([near, far]), sensor, bins=360)[0]
    joined = grid_from_scans([dense[np.isfinite(dense[:, 0])]], pose[None], 0.05, geometry=geo)
    assert any(joined.data[r, c] == FREE for r, c in unseen)


def test_resample_grid_shift_and_identity():
    geo = GridGeometry((20, 30), 0.1, (0.0, 0.0))
    data = np.full(geo.shape, FREE, dtype=np.int8)
    data[5, 7] = OCCUPIED
    g = OccupancyGrid(data, geo)
    same = resample_grid(g, target=geo)
    np.testing.assert_array_equal(same.data, data)
    moved = resample_grid(g, target=geo, transform=[0.3, -0.2, 0.0])  # 3 cells right, 2 cells down
    assert moved.data[7, 10] == OCCUPIED and moved.data[5, 7] == FREE
    assert (moved.data[:2, :] == UNKNOWN).all() and (moved.data[:, :3] == UNKNOWN).all()
    arr = resample_grid(data.astype(np.int32), geo, geo, fill=-5)
    assert arr.dtype == np.int32 and np.array_equal(arr, data)


def test_overlap_scores_counts():
    a = np.zeros((10, 10), bool)
    b = np.zeros((10, 10), bool)
    a[2, 2:8] = True  # 6 cells
    b[3, 2:5] = True  # 3 cells, one row off: within 0.1 m of a at 0.1 m per cell
    b[8, 8] = True  # far from a
    s = overlap_scores(a, b, 0.1, tolerance=0.1)
    assert s["a_matched"] == pytest.approx(3 / 6)
    assert s["b_matched"] == pytest.approx(3 / 4)
    assert s["overlap"] == pytest.approx(6 / 10)
    assert overlap_scores(a, a, 0.1, 0.0)["overlap"] == 1.0


def test_slice_points():
    pts = np.array([[0, 0, 1.69], [1, 1, 1.7], [2, 2, 1.75], [3, 3, 1.8], [np.nan, 0, 1.75]])
    np.testing.assert_array_equal(slice_points(pts), [[1, 1], [2, 2]])


def test_occupied_points_are_cell_centres():
    geo = GridGeometry((4, 5), 0.5, (10.0, 20.0))
    data = np.full(geo.shape, FREE, dtype=np.int8)
    data[3, 0] = OCCUPIED  # the lower-left cell
    np.testing.assert_allclose(occupied_points(OccupancyGrid(data, geo)), [[10.25, 20.25]])


# ---------------------------------------------------------------------------------------------- bad input


def _grid(occupied: bool = True) -> OccupancyGrid:
    data = np.full((10, 10), FREE, dtype=np.int8)
    if occupied:
        data[2, :] = OCCUPIED
        data[:, 3] = OCCUPIED
    return OccupancyGrid(data, GridGeometry((10, 10), 0.1))


def test_bad_input_raises_hsmap_errors(world):
    ds, floor, sl = world
    with pytest.raises(InputError, match="floor must be an hsmap.maps.grid.OccupancyGrid"):
        align_maps(np.zeros((10, 10)), sl)
    with pytest.raises(InputError, match="slice_"):
        align_maps(floor, "map.pgm")
    with pytest.raises(EmptyInputError, match="floor map has no occupied cell"):
        align_maps(_grid(False), sl)
    with pytest.raises(EmptyInputError, match="slice has no occupied cell"):
        align_maps(floor, _grid(False))
    with pytest.raises(ShapeError, match="floor_points"):
        align_maps(floor, sl, floor_points=np.zeros((5, 3)))
    with pytest.raises(ShapeError, match="initial_guesses"):
        align_maps(floor, sl, initial_guess=[0.0, 0.0])
    with pytest.raises(ConfigError, match="z_min"):
        FusionConfig(z_min=1.8, z_max=1.7)
    with pytest.raises(ConfigError, match="resolution"):
        FusionConfig(resolution=0.0)
    with pytest.raises(ShapeError, match="frames but"):
        slice_grid(ds.frames(stop=3), ds.groundtruth.poses[:5])
    with pytest.raises(ShapeError, match="more frames"):
        slice_grid(ds.frames(stop=5), ds.groundtruth.poses[:3])
    with pytest.raises(InputError, match="no 3D cloud"):
        slice_grid(ds.frames(stop=2, clouds=False), ds.groundtruth.poses[:2])
    with pytest.raises(EmptyInputError, match="no 3D cloud has points in the slice"):
        slice_grid(ds.frames(stop=2), ds.groundtruth.poses[:2], z_min=5.0, z_max=6.0)
    with pytest.raises(ShapeError, match="share one geometry"):
        overlay_classes(_grid(), OccupancyGrid(_grid().data, GridGeometry((10, 10), 0.2)))
    with pytest.raises(InputError, match="needs its geometry"):
        resample_grid(np.zeros((3, 3)), target=GridGeometry((3, 3), 0.1))
    with pytest.raises(ShapeError, match="transform"):
        resample_grid(_grid(), target=GridGeometry((3, 3), 0.1), transform=np.eye(4))
    with pytest.raises(EmptyInputError, match="both maps"):
        overlap_scores(np.zeros((4, 4), bool), np.ones((4, 4), bool), 0.1)
    with pytest.raises(ShapeError, match="points must have shape"):
        slice_points(np.zeros((4, 2)))
    with pytest.raises(ShapeError, match="sensor_pose"):
        slice_scan(np.zeros((4, 3)), np.zeros(4))
    for exc in (InputError, EmptyInputError, ShapeError, ConfigError):
        assert issubclass(exc, HsmapError)
