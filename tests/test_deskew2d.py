"""2D scans taken over a scanner's turn: deskewing (:mod:`hsmap.deskew2d`) and HS-SLAM 3-DOF on such scans."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from hsmap.datasets.frames import Frame, LaserScan2D
from hsmap.deskew import constant_velocity_motion
from hsmap.deskew2d import deskew_scan, deskew_scan_frame
from hsmap.errors import ShapeError
from hsmap.geometry import compose, invert_matrix, pose_to_matrix
from hsmap.trajectory import Trajectory

EXT = np.array([0.15, -0.05, 0.1])  # the 2D sensor in the base frame
STEP, DT = np.array([0.5, 0.02, np.deg2rad(30.0)]), 0.5  # 1 m/s, 60 deg/s


def _turning_scan(rng, m=541, scan_time=0.1):
    """Points seen by a scanner turning once in ``scan_time`` on a base moving at constant velocity: the scan as
    measured, the true sensor-frame points at the stamp, and the beam times."""
    times = np.arange(m) * scan_time * 0.5 / 360.0  # 0.5 deg between beams
    world = rng.uniform(-6, 6, (m, 2))
    B0 = np.array([1.0, 2.0, 0.4])
    base = compose(np.broadcast_to(B0, (m, 3)), constant_velocity_motion(STEP, DT, times))
    E = pose_to_matrix(EXT)
    sensor = pose_to_matrix(base) @ E  # (m, 3, 3)
    hom = np.column_stack([world, np.ones(m)])
    p = np.einsum("nij,nj->ni", invert_matrix(sensor), hom)[:, :2]
    truth = (invert_matrix(pose_to_matrix(B0) @ E) @ hom.T).T[:, :2]
    r, a = np.hypot(p[:, 0], p[:, 1]), np.arctan2(p[:, 1], p[:, 0])
    r[::7] = np.nan  # no returns
    return LaserScan2D(r, a, 0.05, 20.0, times), truth, times


def test_deskew_scan_recovers_the_points_at_the_stamp():
    scan, truth, times = _turning_scan(np.random.default_rng(0))
    out = deskew_scan(scan, EXT, constant_velocity_motion(STEP, DT, times))
    assert out.times is None and out.range_min == 0.05
    ok = np.isfinite(scan.ranges)
    np.testing.assert_array_equal(np.isnan(out.ranges), ~ok)
    np.testing.assert_array_equal(out.angles[~ok], scan.angles[~ok])
    np.testing.assert_allclose(out.points(), truth[ok], atol=1e-9)
    assert np.abs(scan.points() - truth[ok]).max() > 0.3  # as measured, the far points are off by decimetres
    with pytest.raises(ShapeError):
        deskew_scan(scan, EXT, np.zeros((3, 3)))


def test_deskew_scan_frame_takes_the_motion_from_the_history():
    scan, truth, times = _turning_scan(np.random.default_rng(1))
    frame = Frame(stamp=10.0, scan2d=scan, extrinsic2d=EXT, index=3)
    out, source = deskew_scan_frame(frame)  # nothing gives the motion: ranges kept, times cleared
    assert source == "none" and out.scan2d.times is None
    np.testing.assert_array_equal(out.scan2d.ranges, scan.ranges)
    prev = [np.zeros(3), STEP]
    out, source = deskew_scan_frame(frame, previous_stamps=[9.0, 9.5], previous_poses=prev)
    assert source == "constant_velocity"
    np.testing.assert_allclose(out.scan2d.points(), truth[np.isfinite(scan.ranges)], atol=1e-9)
    odo = dataclasses.replace(frame, odometry=compose(np.array([3.0, 1.0, 0.2]), STEP))
    out, source = deskew_scan_frame(odo, previous_stamps=[9.5], previous_odometry=np.array([3.0, 1.0, 0.2]))
    assert source == "odometry"
    np.testing.assert_allclose(out.scan2d.points(), truth[np.isfinite(scan.ranges)], atol=1e-9)
    # a trajectory through the beams' times (the odometry track, the 2D run's poses): interpolated at them
    st = 10.0 + np.arange(-4, 5) * 0.05
    track = Trajectory(st, compose(np.broadcast_to(np.array([3.0, 1.0, 0.2]), (9, 3)),
                                   constant_velocity_motion(STEP, DT, st - 10.0)))
    out, source = deskew_scan_frame(frame, prior=track, previous_stamps=[9.5], previous_poses=[np.zeros(3)])
    assert source == "prior"
    np.testing.assert_allclose(out.scan2d.points(), truth[np.isfinite(scan.ranges)], atol=2e-3)
    plain = Frame(stamp=1.0, scan2d=dataclasses.replace(scan, times=None))
    assert deskew_scan_frame(plain, previous_stamps=[0.5], previous_poses=prev)[0] is plain
    assert deskew_scan_frame(Frame(stamp=1.0))[1] == "static"


def test_slam_3dof_on_turning_scans_with_and_without_deskewing(tmp_path):
    """The slam-office start at 1 m/s and 60 deg/s with a scanner turning once in 0.1 s: HS-SLAM 3-DOF deskewed
    keeps closer to the truth than on the scans as measured; scans without beam times are not touched."""
    pytest.importorskip("open3d")
    from hsmap.datasets.simulated import SimulatedDataset
    from hsmap.evaluation.trajectory import pose_errors
    from hsmap.sim import Lidar2DConfig, Lidar3DConfig, simulate
    from hsmap.sim.catalog import resolve_scenario
    from hsmap.sim.robot import RobotConfig
    from hsmap.sim.scenario import load_scenario
    from hsmap.slam import SlamConfig, run_slam

    scn = load_scenario(resolve_scenario("slam-office")).replace(
        lidar2d=Lidar2DConfig(scan_time=0.1), lidar3d=Lidar3DConfig(channels=2, columns=8),
        robot=RobotConfig(max_speed=1.0, max_turn_rate_deg=60.0))
    simulate(scn, tmp_path / "d", seed=1, max_frames=60)
    ds = SimulatedDataset(tmp_path / "d")
    err = {}
    for deskew in (True, False):
        res = run_slam(ds, SlamConfig(dof=3, deskew=deskew), rng=1, progress=False)
        e = pose_errors(res.trajectory, ds.groundtruth).as_dict()["max_abs_error"]
        err[deskew] = (max(e["x_m"], e["y_m"]), e["yaw_deg"])
    assert err[True][1] < 0.3 * err[False][1] and err[True][0] < 0.5 * err[False][0], err
    # scans without beam times: the tracker leaves them as they are
    from hsmap.slam.tracker import HsSlam

    f = next(iter(ds.frames(clouds=False)))
    plain = dataclasses.replace(f, scan2d=dataclasses.replace(f.scan2d, times=None))
    assert HsSlam(SlamConfig(dof=3)).deskewing.deskewed(plain) is plain
    assert HsSlam(SlamConfig(dof=3, deskew=False)).deskewing.deskewed(f) is f
