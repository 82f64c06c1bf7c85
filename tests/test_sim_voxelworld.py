"""The voxel world (hsmap.sim.voxelworld), its route (hsmap.sim.route3d) and runs through it (hsmap.sim.voxelrun)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage as ndi

from hsmap.datasets.simulated import SimulatedDataset
from hsmap.sim.route3d import Route3DConfig, plan_route3d, traversable
from hsmap.sim.sensors import Lidar2DConfig, Lidar3DConfig
from hsmap.sim.voxelrun import WorldRunConfig, simulate_world
from hsmap.sim.voxelworld import FREE, OCCUPIED, UNKNOWN, VoxelWorld, ground_surface

RES = 0.1


def _room(unknown_from_x: int | None = None) -> VoxelWorld:
    """A 5 x 4 x 3 m box of free space (walls, floor voxel layer and ceiling occupied), origin (-2, -1.6, -0.1),
    the floor's surface at z = 0; voxels from x index ``unknown_from_x`` on are unknown."""
    st = np.full((50, 40, 30), FREE, np.uint8)
    st[0], st[-1], st[:, 0], st[:, -1], st[:, :, 0], st[:, :, -1] = (OCCUPIED,) * 6
    if unknown_from_x is not None:
        st[unknown_from_x:] = UNKNOWN
    return VoxelWorld(st, (-2.0, -1.6, -0.1), RES, floor=0.0)


def test_hits_at_the_right_range():
    w = _room()
    o = np.array([0.05, 0.05, 1.0])
    dirs = np.array([[-1, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, -1], [0, 0, 1]], float)
    r = w.cast(np.tile(o, (len(dirs), 1)), dirs)
    # faces of the occupied voxels: x -1.9 and 2.9, y 2.3 and -1.5, floor 0, ceiling 2.8
    np.testing.assert_allclose(r, [1.95, 2.85, 2.25, 1.55, 1.0, 1.8], atol=1e-5)
    d = np.array([1.0, 1.0, 0.0]) / np.sqrt(2)  # a diagonal reaches x = 2.9 or y = 2.3 first
    assert w.cast(o[None], d[None])[0] == pytest.approx(2.25 * np.sqrt(2), abs=1e-4)


def test_rays_into_unknown_space_return_nothing():
    w = _room(unknown_from_x=30)  # unknown from x = 1.0 m on
    o = np.array([[0.05, 0.05, 1.0]])
    assert np.isinf(w.cast(o, np.array([[1.0, 0, 0]])))[0]  # the wall at 2.9 lies behind unknown space
    assert np.isfinite(w.cast(o, np.array([[-1.0, 0, 0]])))[0]
    # a ray leaving the grid returns nothing either
    st = np.full((10, 10, 10), FREE, np.uint8)
    assert np.isinf(VoxelWorld(st, (0, 0, 0), RES).cast([[0.5, 0.5, 0.5]], [[0, 0, 1.0]]))[0]
    # the voxel a sensor sits in is passed whatever the map says
    w2 = _room()
    w2.state[w2.voxel_index([0.05, 0.05, 1.0])[0], w2.voxel_index([0.05, 0.05, 1.0])[1], 11] = UNKNOWN
    assert w2.cast([[0.05, 0.05, 1.0]], [[-1.0, 0, 0]])[0] == pytest.approx(1.95, abs=1e-5)
    # a scan sees nothing where the map does not know (NaN), and the walls elsewhere
    img = w.scan3d(np.array([[0.0, 0.0, 0.0]]), Lidar3DConfig(channels=8, columns=64, position=[0, 0, 1.0]))[0]
    az = Lidar3DConfig(channels=8, columns=64).azimuths()
    ahead = np.abs(az) < np.deg2rad(20)
    assert np.isnan(img[:, ahead]).all() and np.isfinite(img[:, ~ahead & (np.abs(az) > np.deg2rad(120))]).all()


def test_ground_surface_is_the_top_of_a_thick_floor():
    st = np.full((20, 20, 20), FREE, np.uint8)
    st[:, :, :3] = UNKNOWN
    st[:, :, 3:5] = OCCUPIED  # a floor two voxels thick: 0.3-0.5 above the origin
    st[5:8, 5:8, 5:9] = OCCUPIED  # clutter on it
    assert ground_surface(st, (0, 0, -1.0), RES, floor=-0.65) == pytest.approx(-0.5)


def _office() -> VoxelWorld:
    """A corridor (x 0-10 m, y 0-2) with a room (x 3-7, y 2-6) through a 1.2 m door at x 4.4-5.6, a desk block
    (0.3-0.7 m high) in the room, and unknown space east of x = 8.5 in the corridor."""
    nx, ny, nz = 104, 64, 28
    st = np.full((nx, ny, nz), UNKNOWN, np.uint8)
    ix = lambda x: int(round(x / RES)) + 2  # noqa: E731
    st[ix(0):ix(10), ix(0):ix(2), 1:27] = FREE
    st[ix(3):ix(7), ix(2):ix(6), 1:27] = FREE
    st[:, :, 0] = OCCUPIED  # floor
    st[:, :, 27] = OCCUPIED  # ceiling
    wall = np.zeros((nx, ny), bool)
    wall[ix(0) - 1:ix(10) + 1, ix(0) - 1] = wall[ix(0) - 1:ix(3) + 1, ix(2)] = True
    wall[ix(7) - 1:ix(10) + 1, ix(2)] = wall[ix(3):ix(4.4), ix(2)] = wall[ix(5.6):ix(7), ix(2)] = True
    wall[ix(3) - 1, ix(2):ix(6) + 1] = wall[ix(7), ix(2):ix(6) + 1] = wall[ix(3) - 1:ix(7) + 1, ix(6)] = True
    wall[ix(0) - 1, :ix(2)] = wall[ix(10), :ix(2) + 1] = True
    st[wall, 1:27] = OCCUPIED
    st[ix(3.5):ix(4.5), ix(4):ix(5.5), 3:7] = OCCUPIED  # the desk
    st[ix(8.5):ix(10), ix(0):ix(2), 1:27] = UNKNOWN
    return VoxelWorld(st, (-0.2, -0.2, -0.1), RES, floor=0.0, source="office")


def test_route_stays_in_known_free_space_clear_of_clutter():
    w = _office()
    cfg = Route3DConfig()
    r = plan_route3d(w, cfg)
    free = traversable(w, cfg)
    clear = np.where(free, (ndi.distance_transform_edt(free) - 0.5) * RES, 0.0)
    pts = np.vstack([r.route.start[None, :2], r.route.waypoints])
    xs = []
    for a, b in zip(pts[:-1], pts[1:], strict=True):
        t = np.linspace(0, 1, int(np.hypot(*(b - a)) / 0.02) + 2)[:, None]
        xy = a + t * (b - a)
        rc = r.geometry.world_to_index(xy)
        assert clear[rc[:, 0], rc[:, 1]].min() >= cfg.explore.clearance - 1e-9
        xs.append(xy)
    xy = np.vstack(xs)
    assert xy[:, 0].max() < 8.5 - cfg.explore.clearance + 1e-6  # never into the unknown end of the corridor
    assert xy[:, 1].max() > 3.0  # into the room through its door
    desk = (xy[:, 0] > 3.5 - 0.3) & (xy[:, 0] < 4.5 + 0.3) & (xy[:, 1] > 4 - 0.3) & (xy[:, 1] < 5.5 + 0.3)
    assert not desk.any()  # the footprint keeps clear of the desk under the slice
    assert xy[:, 0].min() < 1.5 and xy[:, 0].max() > 6.0  # both ends of the known corridor


def test_a_run_writes_the_simulator_folder(tmp_path):
    cfg = WorldRunConfig(lidar3d=Lidar3DConfig(channels=16, columns=256), lidar2d=Lidar2DConfig())
    run = simulate_world(_office(), tmp_path / "run", seed=3, config=cfg, max_frames=12)
    ds = SimulatedDataset(tmp_path / "run")
    assert len(ds) == run.frames == 12
    gt = ds.trajectory("groundtruth")
    assert ds.range_image(5).shape == (16, 256)
    scan = ds.scan2d(5)
    assert np.isfinite(scan.ranges).mean() > 0.5
    pts = ds.cloud3d(5)
    assert len(pts) > 500
    labels, geo, names = ds.labels()
    assert labels.max() >= 1 and len(names) == labels.max()
    assert np.isfinite(gt.poses).all()
    again = simulate_world(_office(), tmp_path / "again", seed=3, config=cfg, max_frames=12)
    assert again.frames == 12
    for name in ("scans2d.npz", "groundtruth.tum", "odometry.tum", "clouds3d/000007.npz"):
        assert (tmp_path / "run" / name).read_bytes() == (tmp_path / "again" / name).read_bytes()


def test_cli_names_a_bad_world(tmp_path, capsys):
    from hsmap.cli import main

    bad = tmp_path / "broken.bt"
    bad.write_bytes(b"# Octomap OcTree binary file\nid OcTree\nsize 9\nres 0.1\ndata\n\x00")
    assert main(["simulate", "--world", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "broken.bt" in capsys.readouterr().err
    assert main(["simulate", "--world", str(bad), "--check"]) == 2


def _geb079() -> Path:
    from hsmap.study.paths import datasets_dir

    p = datasets_dir() / "octomap" / "geb079.bt"
    if not p.is_file():
        pytest.skip(f"no data (run hsmap data fetch octomap): {p} missing")
    return p


def test_geb079_route_and_frames(tmp_path):
    from hsmap.sim.voxelrun import load_voxel_world

    w = load_voxel_world(_geb079())
    cfg = WorldRunConfig(lidar3d=Lidar3DConfig(channels=32, columns=512))
    run = simulate_world(w, tmp_path / "geb", seed=1, config=cfg, max_frames=6)
    assert abs(w.floor) < 0.15  # the floor's surface in the map's frame, near z = 0
    assert run.route.route.path_length > 25.0  # the 35 m corridor
    free = run.route.traversable
    pts = np.vstack([run.route.route.start[None, :2], run.route.route.waypoints])
    rc = run.route.geometry.world_to_index(pts)
    assert free[rc[:, 0], rc[:, 1]].all()
    img = SimulatedDataset(tmp_path / "geb").range_image(3)
    assert 0.2 < (img > 0).mean() < 0.98  # walls and floor return, unknown space does not
    if os.environ.get("HSMAP_SLOW"):
        assert run.frames == 6


def test_route_keeps_the_mast_lidar_out_of_unknown_pockets():
    w = _office()
    ix = lambda x: int(round(x / RES)) + 2  # noqa: E731
    w.state[ix(1.6):ix(2.4), ix(0.6):ix(1.4), 12:20] = UNKNOWN  # blind pocket around the mast at (2, 1)
    r = plan_route3d(w)
    assert r.visible[r.geometry.world_to_index([2.0, 1.0])[0], r.geometry.world_to_index([2.0, 1.0])[1]] < 0.3
    pts = np.vstack([r.route.start[None, :2], r.route.waypoints])
    xy = np.vstack([a + np.linspace(0, 1, 50)[:, None] * (b - a) for a, b in zip(pts[:-1], pts[1:], strict=True)])
    assert not ((np.abs(xy[:, 0] - 2.0) < 0.4) & (np.abs(xy[:, 1] - 1.0) < 0.4)).any()


def test_a_map_with_no_room_for_the_robot_is_a_one_line_error(tmp_path, capsys):
    from hsmap.cli import main

    ply = tmp_path / "points.ply"  # occupied points only: no known free space to drive in
    pts = np.random.default_rng(0).uniform(0, 3, (500, 3))
    ply.write_text("ply\nformat ascii 1.0\nelement vertex 500\nproperty float x\nproperty float y\n"
                   "property float z\nend_header\n" + "\n".join(" ".join(f"{v:.4f}" for v in p) for p in pts) + "\n")
    assert main(["simulate", "--world", str(ply), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "points.ply" in err[0]


def _deepest_y(r) -> float:
    pts = np.vstack([r.route.start[None, :2], r.route.waypoints])
    return float(pts[:, 1].max())


def test_route_enters_a_door_seen_above_its_floor_and_one_only_the_footprint_fits():
    ix = lambda x: int(round(x / RES)) + 2  # noqa: E731
    door = (slice(ix(4.4), ix(5.6)), slice(ix(1.5), ix(2.6)))
    w = _office()
    w.state[door[0], door[1], 1:6] = UNKNOWN  # the door's floor-level voxels unseen, free above, floor seen
    r = plan_route3d(w)
    assert _deepest_y(r) > 3.0  # into the room: unseen floor under an observed-free column on a seen floor
    assert len(r.rooms_entered()) == 2
    w.state[door[0], door[1], 0] = UNKNOWN  # no floor seen under the door either: clutter may stand there
    assert _deepest_y(plan_route3d(w)) < 2.0
    # a door 0.6 m wide (6 voxels): a robot of radius 0.26 m passes with its middle on a voxel face, not when
    # its centre must stand on voxel centres, nor with a radius of 0.30 m
    narrow = _office()
    narrow.state[ix(4.4):ix(4.4) + 3, ix(2), 1:27] = OCCUPIED
    narrow.state[ix(5.6) - 3:ix(5.6), ix(2), 1:27] = OCCUPIED
    assert _deepest_y(plan_route3d(narrow, footprint=0.26)) > 3.0
    assert _deepest_y(plan_route3d(narrow, Route3DConfig(subdivision=1), footprint=0.26)) < 2.0
    assert _deepest_y(plan_route3d(narrow, footprint=0.30)) < 2.0
