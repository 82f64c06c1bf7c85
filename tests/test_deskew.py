"""Rolling sweeps: deskewing (:mod:`hsmap.deskew`), the per-point time fields of the readers, the simulator's
rolling sweep and swaying mast, and HS-SLAM 6-DOF on a rolling-sweep bag."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from hsmap.datasets.frames import Frame, stamp_in_sweep
from hsmap.datasets.rosbag import pointcloud2_points
from hsmap.deskew import constant_velocity_motion, deskew_frame, deskew_points, trajectory_motion
from hsmap.errors import DataFormatError, ScenarioError
from hsmap.geometry import compose, interpolate_poses, invert, pose_to_matrix, transform_points
from hsmap.trajectory import Trajectory

EXT = np.array([-0.1, 0.02, 1.6, 0.01, -0.02, 0.3])  # the sensor in the base frame


def _sweep(step, dt, rng, n=2000, sweep=0.1):
    """A rigid cloud (N, 3) in the sensor frame at the reference pose, its points' times, and the points as a
    sensor measures them while the base moves at the constant velocity that makes ``step`` in ``dt``."""
    rigid = rng.uniform(-8, 8, (n, 3))
    times = np.sort(rng.uniform(0, sweep, n))
    E = pose_to_matrix(EXT)
    world = transform_points(E, rigid)  # base frame at the reference time
    motion = constant_velocity_motion(step, dt, times)  # base pose at each time, relative to the reference
    M6 = np.zeros((n, 6))
    M6[:, :2], M6[:, 5] = motion[:, :2], motion[:, 2]
    S = np.linalg.inv(pose_to_matrix(M6) @ E)  # base-at-reference -> sensor-at-time
    measured = np.einsum("nij,nj->ni", S[:, :3, :3], world) + S[:, :3, 3]
    return rigid, times, measured


def test_deskew_recovers_the_rigid_cloud_under_known_motion():
    rng = np.random.default_rng(0)
    step, dt = np.array([0.5, 0.05, np.deg2rad(30.0)]), 0.5  # 1 m/s, 60 deg/s
    rigid, times, measured = _sweep(step, dt, rng)
    assert np.abs(measured - rigid).max() > 0.3  # the sweep is smeared
    fixed = deskew_points(measured, times, constant_velocity_motion(step, dt, times), EXT)
    np.testing.assert_allclose(fixed, rigid, atol=1e-9)
    # through a frame: motion from a trajectory of the base (a 2D run's poses, one per 0.5 s)
    t0 = 100.0
    poses = interpolate_poses(np.zeros((4, 3)), np.broadcast_to(step, (4, 3)), np.arange(-1, 3) * 1.0)
    traj = Trajectory(t0 + dt * np.arange(-1, 3), poses)
    frame = Frame(stamp=t0, cloud3d=measured, point_times=times, stamp_in_sweep="start", extrinsic3d=EXT)
    out, source = deskew_frame(frame, prior=traj)
    assert source == "prior" and out.point_times is None and out.stamp == t0
    assert np.abs(out.cloud3d - rigid).max() < 5e-3  # a quadratic through three arc poses, 14 m away at most
    # from the odometry increment into the frame, and from the last two tracked poses
    odo = Frame(stamp=t0, cloud3d=measured, point_times=times, odometry=np.array([1.0, 2.0, 0.4]), extrinsic3d=EXT)
    prev = compose(odo.odometry, invert(step))
    out, source = deskew_frame(odo, previous_stamps=[t0 - dt], previous_odometry=prev)
    assert source == "odometry"
    np.testing.assert_allclose(out.cloud3d, rigid, atol=1e-4)  # the times grouped to 10 us
    six = np.array([step[0], step[1], 0.0, 0.0, 0.0, step[2]])
    out, source = deskew_frame(frame, previous_stamps=[t0 - 2 * dt, t0 - dt], previous_poses=[np.zeros(6), six])
    assert source == "constant_velocity"
    np.testing.assert_allclose(out.cloud3d, rigid, atol=1e-4)


def test_frames_without_times_or_motion():
    pts = np.random.default_rng(1).normal(size=(50, 3))
    static = Frame(stamp=1.0, cloud3d=pts)
    same, source = deskew_frame(static, prior=None)
    assert same is static and source == "static"
    timed = Frame(stamp=1.0, cloud3d=pts, point_times=np.linspace(0, 0.1, 50))
    out, source = deskew_frame(timed)  # nothing gives the motion: the points as they are
    assert source == "none" and out.point_times is None
    np.testing.assert_array_equal(out.cloud3d, pts)
    with pytest.raises(Exception, match="point times"):
        deskew_frame(Frame(stamp=1.0, cloud3d=pts, point_times=np.zeros(3)))
    traj = Trajectory(np.array([0.0, 10.0]), np.zeros((2, 3)))
    assert trajectory_motion(traj, 5.0, np.array([0.0, 0.1]), 1.0) is None  # its poses too far from the sweep
    assert stamp_in_sweep(np.array([0.0, 0.05])) == "start"
    assert stamp_in_sweep(np.array([-0.1, 0.0])) == "end"
    assert stamp_in_sweep(np.array([-0.05, 0.05])) == "within"


# -- the readers' per-point time fields -----------------------------------------------------------------
def _cloud(fields, rows, *, stamp=1_700_000_000.5, bigendian=False, pad=0, height=1):
    """A PointCloud2-like message: ``fields`` [(name, numpy code, datatype)], ``rows`` name -> values."""
    end = ">" if bigendian else "<"
    dt = np.dtype({"names": [f[0] for f in fields], "formats": [end + f[1] for f in fields],
                   "offsets": [f[3] for f in fields], "itemsize": fields[-1][4]})
    rec = np.zeros(len(rows["x"]), dtype=dt)
    for f in fields:
        rec[f[0]] = rows[f[0]]
    width = len(rec) // height
    raw = rec.tobytes()
    step = dt.itemsize
    data = b"".join(raw[r * width * step:(r + 1) * width * step] + b"\0" * pad for r in range(height))
    sec = int(stamp)
    return SimpleNamespace(
        header=SimpleNamespace(stamp=SimpleNamespace(sec=sec, nanosec=int(round((stamp - sec) * 1e9)))),
        fields=[SimpleNamespace(name=f[0], offset=f[3], datatype=f[2]) for f in fields],
        is_bigendian=bigendian, point_step=step, row_step=width * step + pad, width=width, height=height,
        data=np.frombuffer(data, np.uint8))


XYZ = [("x", "f4", 7, 0, None), ("y", "f4", 7, 4, None), ("z", "f4", 7, 8, None)]


@pytest.mark.parametrize(("name", "code", "datatype", "values", "expected", "where"), [
    ("t", "u4", 6, [0, 25_000_000, 50_000_000, 99_000_000], [0.0, 0.025, 0.05, 0.099], "start"),  # ouster-ros
    ("time", "f4", 7, [-0.1, -0.05, -0.02, 0.0], [-0.1, -0.05, -0.02, 0.0], "end"),  # velodyne, stamped at the end
    ("offset_time", "u4", 6, [0, 1_000_000, 2_000_000, 3_000_000], [0.0, 0.001, 0.002, 0.003], "start"),  # livox
    ("timestamp", "f8", 8, [1_700_000_000.5 + d for d in (0.0, 0.01, 0.02, 0.03)], [0.0, 0.01, 0.02, 0.03],
     "start"),  # hesai: absolute
])
@pytest.mark.parametrize("bigendian", [False, True])
def test_each_drivers_time_field(name, code, datatype, values, expected, where, bigendian):
    fields = [*XYZ, (name, code, datatype, 16, 32)]  # a padded 32-byte point, the time after a gap
    rows = {"x": [1.0, 0.0, 2.0, 3.0], "y": [1.0, 0.0, 2.0, 3.0], "z": [0.5, 0.0, 0.5, 0.5], name: values}
    msg = _cloud(fields, rows, bigendian=bigendian, pad=8, height=2)  # organised, padded rows
    pts, t, field = pointcloud2_points(msg)
    assert field == name and len(pts) == 3  # the organised cloud's zero point dropped, and its time
    np.testing.assert_allclose(t, np.delete(expected, 1), atol=1e-6)
    assert stamp_in_sweep(t) == where


def test_no_time_field_and_bad_times():
    rows = {"x": [1.0, 2.0], "y": [0.0, 1.0], "z": [0.0, 0.0]}
    pts, t, field = pointcloud2_points(_cloud([*XYZ[:2], ("z", "f4", 7, 8, 16)], rows))
    assert len(pts) == 2 and t is None and field is None
    rows["t"] = [0, 3_000_000_000]  # 3 s into a sweep
    with pytest.raises(DataFormatError, match="'t'"):
        pointcloud2_points(_cloud([*XYZ, ("t", "u4", 6, 12, 16)], rows))


# -- the simulator -----------------------------------------------------------------------------------------
def _small_rolling(**robot):
    from hsmap.sim import Lidar3DConfig
    from hsmap.sim.catalog import resolve_scenario
    from hsmap.sim.robot import RobotConfig
    from hsmap.sim.scenario import load_scenario

    scn = load_scenario(resolve_scenario("two-rooms"))
    l3 = Lidar3DConfig(channels=16, columns=256, sweep_time=0.1, sway_frequency=2.0)
    return scn.replace(lidar3d=l3, robot=RobotConfig(max_speed=1.0, max_turn_rate_deg=60.0, **robot))


def test_simulated_rolling_sweep_times_and_sway(tmp_path):
    pytest.importorskip("open3d")
    from hsmap.datasets.simulated import SimulatedDataset
    from hsmap.sim.robot import mast_sway
    from hsmap.sim.writer import motion_for, simulate

    scn = _small_rolling()
    simulate(scn, tmp_path / "d", seed=1, max_frames=4)
    ds = SimulatedDataset(tmp_path / "d")
    assert ds.describe()["point_time"]["field"] == "column_time"
    f = ds.frame(2)
    assert f.point_times is not None and len(f.point_times) == len(f.cloud3d) and f.stamp_in_sweep == "start"
    img = ds.range_image(2)
    cols = np.broadcast_to(np.arange(256)[None, :], img.shape)[img > 0]
    order = np.argsort(cols, kind="stable")
    assert np.all(np.diff(f.point_times[order]) >= 0)  # monotone in column
    np.testing.assert_allclose(f.point_times, cols * 0.1 / 256)
    # the mast: at rest before the robot moves, a tilt of tenths of a degree when it brakes and speeds up
    m = motion_for(scn, 1)
    sway = np.rad2deg(mast_sway(m.legs, m.sample_times, [-0.1, 0.0], 1.6, 2.0, 0.2))
    assert sway[0].tolist() == [0.0, 0.0] and 0.05 < np.abs(sway).max() < 1.0
    # the mast's truth: the base's pose tilted by the sway about the mast's foot, as the clouds were cast
    from hsmap.sim.robot import mast_poses, sample_legs
    from hsmap.trajectory import read_tum

    truth = read_tum(tmp_path / "d" / "groundtruth3d.tum", dof=6)
    stamps = ds.groundtruth.stamps
    want = mast_poses(m.legs, stamps, [-0.1, 0.0], 1.6, 2.0, 0.2)
    np.testing.assert_allclose(truth.poses, want, atol=1e-6)
    base = sample_legs(m.legs, stamps)
    np.testing.assert_allclose(want[:, [0, 1, 5]], base, atol=2e-3)        # the foot stays put, the top moves
    np.testing.assert_allclose(np.rad2deg(want[:, 3:5]),
                               np.rad2deg(mast_sway(m.legs, stamps, [-0.1, 0.0], 1.6, 2.0, 0.2)), atol=1e-9)
    rigid = mast_poses(m.legs, stamps, [-0.1, 0.0], 1.6, 0.0, 0.2)
    np.testing.assert_allclose(rigid[:, [0, 1, 5]], base, atol=1e-12)
    assert not rigid[:, 2:5].any()


def test_static_scenarios_write_no_times(tmp_path):
    pytest.importorskip("open3d")
    from hsmap.datasets.simulated import SimulatedDataset
    from hsmap.sim.writer import simulate

    scn = _small_rolling().replace(lidar3d=_small_rolling().lidar3d.__class__(channels=16, columns=256))
    simulate(scn, tmp_path / "d", seed=1, max_frames=2)
    ds = SimulatedDataset(tmp_path / "d")
    assert ds.frame(1).point_times is None and ds.describe()["point_time"].startswith("none")
    assert "sweep_time" not in ds.sensors["lidar3d"]


def test_bad_scenario_option_names_the_key(tmp_path):
    from hsmap.sim.catalog import resolve_scenario
    from hsmap.sim.scenario import load_scenario

    p = tmp_path / "s.yaml"
    text = resolve_scenario("two-rooms").read_text()
    p.write_text(text + "\nsensors:\n  lidar3d: {sweep_time: -0.1}\n")
    with pytest.raises(ScenarioError, match="sweep_time"):
        load_scenario(p)
    assert resolve_scenario("slam-office-rolling").is_file()


def test_rolling_bag_mapped_with_and_without_deskew(tmp_path):
    """A short rolling-sweep bag (Ouster-style ``t``, stamped at the sweep's start) at 1 m/s and 60 deg/s: the
    6-DOF run deskewed keeps near the truth, the same run without deskewing does not."""
    pytest.importorskip("open3d")
    pytest.importorskip("rosbags")
    from hsmap.datasets.rosbag import RosbagDataset
    from hsmap.evaluation.trajectory import pose_errors
    from hsmap.sim import Lidar3DConfig
    from hsmap.sim.bag import write_simulated_bag
    from hsmap.slam import SlamConfig, run_slam

    scn = _small_rolling().replace(lidar3d=Lidar3DConfig(channels=32, columns=512, sweep_time=0.1))
    bag = write_simulated_bag(scn, tmp_path / "r.mcap", seed=1, scan_rate=8.0, cloud_every=2, duration=9.0)
    ds = RosbagDataset(bag.path).driven_by("cloud")
    frames = list(ds.frames())
    assert all(f.point_times is not None and f.point_times.max() > 0.09 for f in frames)
    assert ds.describe()["point_time"]["field"] == "t"
    prior = bag.scans  # the 2D run's stand-in: true poses at the scan stamps
    gt = Trajectory(bag.clouds.stamps, np.column_stack([bag.clouds.poses[:, :2], np.zeros((len(bag.clouds), 3)),
                                                        bag.clouds.poses[:, 2]]))
    err = {}
    for deskew in (True, False):
        res = run_slam(frames, SlamConfig(dof=6, use_odometry=False, deskew=deskew), rng=1, prior=prior,
                       initial_pose=gt.poses[0], progress=False)
        e = pose_errors(res.trajectory, gt).as_dict()["max_abs_error"]
        err[deskew] = (max(e["x_m"], e["y_m"]), e["yaw_deg"])
    assert err[True][0] < 0.02 and err[True][1] < 0.5, err
    assert err[False][1] > 2 * err[True][1], err


def test_cloud_folder_time_fields(tmp_path):
    from hsmap.datasets.clouds import CloudFolderDataset, read_points_timed

    pts = np.array([[1.0, 2.0, 0.5], [0.0, 0.0, 0.0], [3.0, -1.0, 0.2]])
    rec = np.zeros(3, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("t", "<u4")])
    rec["x"], rec["y"], rec["z"], rec["t"] = pts[:, 0], pts[:, 1], pts[:, 2], [0, 50_000_000, 90_000_000]
    head = ("# .PCD v0.7\nVERSION 0.7\nFIELDS x y z t\nSIZE 4 4 4 4\nTYPE F F F U\nCOUNT 1 1 1 1\nWIDTH 3\n"
            "HEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 3\nDATA binary\n")
    folder = tmp_path / "c"
    folder.mkdir()
    for k in range(2):
        (folder / f"{k:03d}.pcd").write_bytes(head.encode() + rec.tobytes())
    got, t, field = read_points_timed(folder / "000.pcd")
    assert field == "t" and len(got) == 2  # the zero point dropped with its time
    np.testing.assert_allclose(t, [0.0, 0.09])
    ply = tmp_path / "v.ply"
    ply.write_text("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
                   "property float time\nend_header\n1 2 3 -0.1\n4 5 6 0\n")
    got, t, field = read_points_timed(ply)
    assert field == "time" and stamp_in_sweep(t) == "end"
    np.testing.assert_allclose(got, [[1, 2, 3], [4, 5, 6]])
    ds = CloudFolderDataset(folder, cloud_rate=10.0, extrinsic3d=np.zeros(6))
    f = next(iter(ds.frames()))
    assert f.point_times is not None and ds.describe()["point_time"]["field"] == "t"


def test_bag_clock_offset_between_the_lidars(tmp_path):
    pytest.importorskip("open3d")
    pytest.importorskip("rosbags")
    from hsmap.datasets.rosbag import RosbagDataset
    from hsmap.sim import Lidar3DConfig
    from hsmap.sim.bag import write_simulated_bag

    bag = write_simulated_bag("two-rooms", tmp_path / "b.mcap", duration=2.0, clock_offset=0.03,
                              lidar3d=Lidar3DConfig(channels=4, columns=16))
    ds = RosbagDataset(bag.path).driven_by("cloud")
    np.testing.assert_allclose(ds.stamps, bag.clouds.stamps + 0.03, atol=1e-6)
    assert all(f.point_times is None for f in ds.frames())  # a static sweep: no times


def _room(spacing, rng=None):
    """Points (M, 3) and normals on the six faces of an 8 x 6 x 3 m room around (1.3, -0.7, 0.4), on a grid or
    (``rng``) drawn uniformly."""
    lo, hi = np.array([-2.7, -3.7, -1.1]), np.array([5.3, 2.3, 1.9])
    pts, nrm = [], []
    for axis in range(3):
        u, v = [a for a in range(3) if a != axis]
        if rng is None:
            a, b = np.meshgrid(np.arange(lo[u], hi[u], spacing), np.arange(lo[v], hi[v], spacing))
            a, b = a.ravel(), b.ravel()
        else:
            m = int((hi[u] - lo[u]) * (hi[v] - lo[v]) / spacing**2)
            a, b = rng.uniform(lo[u], hi[u], m), rng.uniform(lo[v], hi[v], m)
        for side in (lo[axis], hi[axis]):
            p = np.zeros((len(a), 3))
            p[:, axis], p[:, u], p[:, v] = side, a, b
            n = np.zeros_like(p)
            n[:, axis] = 1.0
            pts.append(p)
            nrm.append(n)
    return np.vstack(pts), np.vstack(nrm)


def test_refine_sweep_finds_the_planar_motion_the_deskewing_missed():
    from hsmap.deskew import refine_sweep
    from hsmap.registration.icp import RegistrationTarget

    target = RegistrationTarget(*_room(0.1)[:1], normals=_room(0.1)[1])
    rng = np.random.default_rng(3)
    world, _ = _room(0.3, rng)
    times = (np.arctan2(world[:, 1], world[:, 0]) + np.pi) / (2 * np.pi) * 0.1  # a rolling sweep, 0.1 s
    true_v = np.array([0.3, -0.2, 0.5])  # m/s, m/s, rad/s left over by the deskewing
    motion = np.column_stack([true_v[0] * times, true_v[1] * times, true_v[2] * times])
    M6 = np.zeros((len(times), 6))
    M6[:, :2], M6[:, 5] = motion[:, :2], motion[:, 2]
    B = np.linalg.inv(pose_to_matrix(M6))
    measured = np.einsum("nij,nj->ni", B[:, :3, :3], world) + B[:, :3, 3]  # the base at each point's time
    assert np.abs(measured - world).max() > 0.1
    out = refine_sweep(measured, times, target, np.zeros(6), threshold=0.3, robust_kernel=0.07, iterations=10)
    assert out.improved and out.cost_after < 0.5 * out.cost_before
    np.testing.assert_allclose(out.velocity, true_v, atol=0.03)
    assert np.abs(out.pose[:3]).max() < 2e-3 and np.abs(out.pose[3:]).max() < np.deg2rad(0.05)
    assert np.abs(out.points - world).max() < 0.01
    # a cloud its deskewing got right is aligned no better by any motion: the tracker keeps it as it is
    still = refine_sweep(world, times, target, np.zeros(6), threshold=0.3, robust_kernel=0.07)
    assert not still.improved and np.abs(still.velocity).max() < 0.05


def test_timed_points_are_the_frames_points_with_their_mean_times():
    from hsmap.maps.mapping import voxel_downsample_with
    from hsmap.slam.frames import frame_points, timed_cloud_points

    rng = np.random.default_rng(1)
    cloud = rng.uniform(-6, 6, (5000, 3))
    cloud[:3] = [np.nan, 0.0, 0.0], [0.01, 0.0, 0.0], [40.0, 0.0, 0.0]  # not finite, too near, too far
    times = rng.uniform(0, 0.1, len(cloud))
    frame = Frame(stamp=1.0, cloud3d=cloud, point_times=times, extrinsic3d=EXT)
    pts, t = timed_cloud_points(frame, times, 0.1, 30.0, 0.5)
    np.testing.assert_array_equal(pts, frame_points(frame, 6, 0.1, 30.0, voxel=0.5))
    assert len(t) == len(pts) and 0.0 <= t.min() and t.max() <= 0.1
    # one voxel's time is the mean of its points' times
    one, mean = voxel_downsample_with(np.array([[0.1, 0.1, 0.1], [0.2, 0.2, 0.2], [5.0, 5.0, 5.0]]),
                                      np.array([0.02, 0.04, 0.09]), 1.0)
    np.testing.assert_allclose(one, [[0.15, 0.15, 0.15], [5.0, 5.0, 5.0]])
    np.testing.assert_allclose(mean, [0.03, 0.09])
