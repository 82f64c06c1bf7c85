"""The LiDAR models against geometry we can compute by hand."""

import numpy as np
import pytest

from hsmap.sim import Lidar2DConfig, Lidar3DConfig, parse_scenario
from hsmap.sim.sensors import (
    beam_directions,
    decode_range_image,
    encode_range_image,
    range_image_to_points,
)

W, H, T, CEIL = 8.0, 6.0, 0.2, 2.8  # box room: walls on x = 0, 8 and y = 0, 6 (centre lines), 0.2 m thick


def box_room(furniture=(), **sensors):
    data = {
        "name": "box",
        "wall_thickness": T,
        "wall_height": CEIL,
        "walls": [
            {"from": [0, 0], "to": [W, 0]}, {"from": [W, 0], "to": [W, H]},
            {"from": [W, H], "to": [0, H]}, {"from": [0, H], "to": [0, 0]},
        ],
        "furniture": list(furniture),
        "route": {"start": [2.0, 3.0, 0], "steps": [[2.5, 3.0]]},
        "sensors": sensors,
    }
    return parse_scenario(data, "box.yaml")


def box_distances(origin, dirs):
    """Distance from origin (3,) along unit dirs (..., 3) to the inside of the box room (walls, floor, ceiling)."""
    lo = np.array([T / 2, T / 2, 0.0])
    hi = np.array([W - T / 2, H - T / 2, CEIL])
    with np.errstate(divide="ignore", invalid="ignore"):
        t_hi = (hi - origin) / dirs
        t_lo = (lo - origin) / dirs
    t = np.where(dirs > 0, t_hi, np.where(dirs < 0, t_lo, np.inf))
    return t.min(-1)


@pytest.fixture(scope="module")
def o3d_world():
    pytest.importorskip("open3d")
    from hsmap.sim.world import World

    return World


def test_2d_scan_in_a_box_matches_analytic_ranges(o3d_world):
    cfg = Lidar2DConfig(noise_sigma=0.01, position=[0.15, -0.05], yaw_deg=10.0)
    scn = box_room(lidar2d={"noise_sigma": 0.01, "position": [0.15, -0.05], "yaw_deg": 10.0})
    world = o3d_world(scn)
    poses = np.array([[2.0, 3.0, 0.3], [6.5, 1.2, -2.0], [4.0, 4.5, 3.0]])
    rngs = [np.random.default_rng(k) for k in range(len(poses))]
    ranges = world.scan2d(poses, cfg, rngs)
    assert ranges.shape == (3, 1081) and ranges.dtype == np.float32
    resid = []
    for p, r in zip(poses, ranges, strict=True):
        c, s = np.cos(p[2]), np.sin(p[2])
        origin = np.array([p[0] + c * 0.15 + s * 0.05, p[1] + s * 0.15 - c * 0.05, 0.2])
        ang = p[2] + np.deg2rad(10.0) + cfg.angles()
        dirs = np.stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)], -1)
        expected = box_distances(origin, dirs)
        resid.append(r - expected)
    resid = np.concatenate(resid)
    assert np.all(np.isfinite(resid))
    assert np.abs(resid).max() < 5 * 0.01
    assert abs(resid.mean()) < 0.002
    assert 0.009 < resid.std() < 0.011


def test_2d_scan_without_noise_is_exact_and_masks_out_of_range(o3d_world):
    scn = box_room()
    world = o3d_world(scn)
    cfg = Lidar2DConfig(noise_sigma=0.0, range_max=4.0, position=[0.0, 0.0])
    r = world.scan2d([[2.0, 3.0, 0.0]], cfg)[0]
    a = cfg.angles()
    expected = box_distances(np.array([2.0, 3.0, 0.2]), np.stack([np.cos(a), np.sin(a), 0 * a], -1))
    near = expected < 4.0 - 1e-3
    np.testing.assert_allclose(r[near], expected[near], atol=2e-5)
    assert np.all(np.isnan(r[expected > 4.0 + 1e-3]))  # beyond range_max: no return
    # straight ahead the wall is 8 - 0.1 - 2 = 5.9 m away: too far; to the left 3 - 0.1 = 2.9 m
    assert np.isnan(r[np.argmin(np.abs(a))])
    assert r[np.argmin(np.abs(a - np.pi / 2))] == pytest.approx(2.9, abs=1e-4)


def test_rolling_2d_scan_measures_each_beam_from_the_pose_at_its_time(o3d_world):
    """A scanner turning once in 0.1 s on a robot driving and turning: beam i is the beam an instantaneous scan
    from the pose at the beam's time measures; with no scan time, the instantaneous scan."""
    from hsmap.sim.robot import RobotConfig, sample_legs
    from hsmap.sim.writer import motion_for, rolling_scan2d

    cfg = Lidar2DConfig(noise_sigma=0.0, position=[0.15, -0.05], yaw_deg=10.0, scan_time=0.1)
    assert cfg.time_increment == pytest.approx(0.1 * 0.25 / 360)
    bt = cfg.beam_times()
    assert bt[0] == 0.0 and bt[-1] == pytest.approx(0.075) and np.all(np.diff(bt) > 0)
    assert cfg.describe()["time_increment"] == pytest.approx(cfg.time_increment)
    assert "scan_time" not in Lidar2DConfig().describe() and not Lidar2DConfig().beam_times().any()
    scn = box_room().replace(robot=RobotConfig(max_speed=1.0, max_turn_rate_deg=60.0))
    world = o3d_world(scn)
    m = motion_for(scn, 0)
    stamps = m.stamps[:3] + 0.3  # turning on the spot, then driving
    rolled = rolling_scan2d(world, m.legs, stamps, cfg)
    assert rolled.shape == (3, cfg.beams) and rolled.dtype == np.float32
    static = world.scan2d(sample_legs(m.legs, stamps), cfg)
    for k, t0 in enumerate(stamps):
        at = sample_legs(m.legs, t0 + bt)
        assert np.ptp(np.unwrap(at[:, 2])) + np.ptp(at[:, 0]) > 0.01  # the robot moves during the scan
        for i in (0, 300, 700, cfg.beams - 1):
            np.testing.assert_allclose(rolled[k, i], world.scan2d(at[i : i + 1], cfg)[0, i], atol=2e-5)
        assert np.nanmax(np.abs(rolled[k] - static[k])) > 0.02  # not the instantaneous scan
    np.testing.assert_array_equal(rolling_scan2d(world, m.legs, stamps, Lidar2DConfig(noise_sigma=0.0)),
                                  world.scan2d(sample_legs(m.legs, stamps), Lidar2DConfig(noise_sigma=0.0)))


def test_3d_scan_in_a_box_matches_analytic_ranges(o3d_world):
    cfg = Lidar3DConfig(channels=16, columns=90, noise_sigma=0.01, position=[-0.1, 0.05, 1.6],
                        rpy_deg=[2.0, -3.0, 20.0])
    world = o3d_world(box_room())
    pose = np.array([3.0, 2.5, 0.7])
    img = world.scan3d([pose], cfg, [np.random.default_rng(3)])[0]
    assert img.shape == (16, 90)
    from hsmap.sim.world import sensor_poses_3d

    Tm = sensor_poses_3d([pose], cfg)[0]
    dirs = cfg.directions() @ Tm[:3, :3].T
    expected = box_distances(Tm[:3, 3], dirs)
    resid = (img - expected).ravel()
    assert np.all(np.isfinite(resid))  # a closed box: every beam hits
    assert np.abs(resid).max() < 5 * 0.01 and 0.008 < resid.std() < 0.012
    # the cloud from the stored (mm) range image lies on the box surfaces
    pts = range_image_to_points(encode_range_image(img), cfg.directions())
    world_pts = pts @ Tm[:3, :3].T + Tm[:3, 3]
    lo = np.array([T / 2, T / 2, 0.0])
    hi = np.array([W - T / 2, H - T / 2, CEIL])
    dist_to_surface = np.minimum(np.abs(world_pts - lo), np.abs(world_pts - hi)).min(1)
    assert np.percentile(dist_to_surface, 99) < 0.04


def test_furniture_below_the_mast_is_seen_in_2d_not_by_the_3d_horizontal_ring(o3d_world):
    # a 1.1 m cabinet and a 0.75 m table 2 m ahead of the robot; a 1.9 m shelf to its left
    furniture = [
        {"type": "cabinet", "center": [4.4, 3.0], "size": [0.5, 0.8], "height": 1.1},
        {"type": "table", "center": [4.3, 1.6], "size": [0.8, 0.8]},
        {"type": "shelf", "center": [2.0, 5.2], "size": [1.0, 0.4], "height": 1.9},
    ]
    scn = box_room(furniture)
    world = o3d_world(scn)
    pose = np.array([2.0, 3.0, 0.0])
    l2 = Lidar2DConfig(noise_sigma=0.0, position=[0.0, 0.0])
    l3 = Lidar3DConfig(columns=360, noise_sigma=0.0, position=[0.0, 0.0, 1.6])
    r2 = world.scan2d([pose], l2)[0]
    img = world.scan3d([pose], l3)[0]
    ring = int(np.argmin(np.abs(l3.vertical_angles())))  # the channel closest to horizontal
    assert abs(np.rad2deg(l3.vertical_angles()[ring])) < 0.2
    col_ahead = int(np.argmin(np.abs(l3.azimuths())))
    beam_ahead = int(np.argmin(np.abs(l2.angles())))
    # straight ahead: the 2D LiDAR hits the cabinet face at x = 4.15, the 3D ring the wall at x = 7.9
    assert r2[beam_ahead] == pytest.approx(2.15, abs=1e-3)
    assert img[ring, col_ahead] == pytest.approx(5.9, abs=0.02)
    # towards the table: the 2D LiDAR hits a leg (closer than the far wall), the ring passes above
    a_leg = np.arctan2(1.925 - 3.0, 3.975 - 2.0)  # the nearest leg (5 cm square) is centred at (3.975, 1.925)
    b2 = int(np.argmin(np.abs(l2.angles() - a_leg)))
    wall = box_distances(np.array([2.0, 3.0, 0.2]), np.array([np.cos(l2.angles()[b2]), np.sin(l2.angles()[b2]), 0]))
    assert r2[b2] < wall - 0.5
    # to the left: the 1.9 m shelf is taller than the mast: both LiDARs see it
    left2 = int(np.argmin(np.abs(l2.angles() - np.pi / 2)))
    left3 = int(np.argmin(np.abs(l3.azimuths() - np.pi / 2)))
    assert r2[left2] == pytest.approx(5.0 - 3.0, abs=1e-3)
    assert img[ring, left3] == pytest.approx(2.0, abs=0.02)
    # the whole 1.7-1.8 m slice of the 3D cloud has no point on the low furniture, the 2D scan has many
    pts = range_image_to_points(img, l3.directions()) + np.array([2.0, 3.0, 1.6])
    band = pts[(pts[:, 2] > 1.7) & (pts[:, 2] < 1.8)]
    scan = np.column_stack([r2 * np.cos(l2.angles()), r2 * np.sin(l2.angles())])[np.isfinite(r2)] + [2.0, 3.0]
    from hsmap.sim.layout import furniture_footprint
    from hsmap.sim.shapes import box_sdf

    low = np.array([furniture_footprint(f) for f in scn.furniture if f.height < 1.6])
    assert len(band) > 100
    assert np.all(box_sdf(band[:, :2], low) > 0.02)
    assert np.count_nonzero((box_sdf(scan, low) < 0.02).any(1)) > 20


def test_range_image_encoding_roundtrip_and_beam_geometry():
    r = np.array([[1.2344, np.nan], [0.0004, 65.0]])
    enc = encode_range_image(r)
    assert enc.dtype == np.uint16
    np.testing.assert_array_equal(enc, [[1234, 0], [0, 65000]])
    dec = decode_range_image(enc)
    assert np.isnan(dec[0, 1]) and np.isnan(dec[1, 0]) and dec[0, 0] == pytest.approx(1.234)
    d = beam_directions(np.deg2rad([30.0, 0.0]), [0.0, np.pi / 2])
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0)
    np.testing.assert_allclose(d[0, 0], [np.cos(np.deg2rad(30)), 0, 0.5], atol=1e-12)
    np.testing.assert_allclose(d[1, 1], [0, 1, 0], atol=1e-12)
    cfg = Lidar3DConfig()
    va = cfg.vertical_angles()
    assert len(va) == 128 and np.rad2deg(va[0]) == pytest.approx(22.5) and np.rad2deg(va[-1]) == pytest.approx(-22.5)
    assert cfg.azimuths()[0] == pytest.approx(-np.pi) and len(cfg.azimuths()) == 1024
    l2 = Lidar2DConfig()
    assert l2.beams == 1081 and np.rad2deg(l2.angles()[[0, -1]]) == pytest.approx([-135, 135])


@pytest.mark.parametrize(
    "cls, kwargs, match",
    [
        (Lidar2DConfig, {"angle_increment_deg": 0}, "angle_increment_deg"),
        (Lidar2DConfig, {"range_min": 5, "range_max": 4}, "range_min"),
        (Lidar2DConfig, {"position": [1, 2, 3]}, "position"),
        (Lidar2DConfig, {"scan_time": 1.5}, "scan_time"),
        (Lidar2DConfig, {"scan_time": "fast"}, "scan_time"),
        (Lidar3DConfig, {"channels": 0}, "channels"),
        (Lidar3DConfig, {"range_max": 100}, "range_max"),
        (Lidar3DConfig, {"vertical_angles_deg": [1, 2]}, "vertical_angles_deg"),
    ],
)
def test_bad_sensor_configs(cls, kwargs, match):
    from hsmap.errors import ConfigError

    with pytest.raises(ConfigError, match=match):
        cls(**kwargs)
