"""A featureless corridor: the scan says nothing along its axis, so the pose must follow the odometry there."""
import numpy as np
import pytest

from hsmap.datasets.frames import Frame, LaserScan2D
from hsmap.geometry import compose, relative
from hsmap.slam import SlamConfig, run_slam
from hsmap.testing import raycast_2d

pytestmark = pytest.mark.slow


def corridor_world():
    """1.6 m wide, 40 m long, closed at both ends, a small recess near each end."""
    return np.array([[[0, 0], [40, 0]], [[0, 1.6], [40, 1.6]], [[0, 0], [0, 1.6]], [[40, 0], [40, 1.6]],
                     [[1.0, 1.6], [1.0, 2.4]], [[1.0, 2.4], [2.0, 2.4]], [[2.0, 2.4], [2.0, 1.6]],
                     [[38.0, 0.0], [38.0, -0.8]], [[38.0, -0.8], [37.0, -0.8]], [[37.0, -0.8], [37.0, 0.0]]], float)


def corridor_run(fov_deg: float, beams: int):
    """Down the corridor in 0.2 m steps, an 8 m laser with 1 cm noise, odometry with 1 % noise per step."""
    rng = np.random.default_rng(0)
    xs = np.arange(0.5, 39.5, 0.2)
    route = np.column_stack([xs, np.full_like(xs, 0.8), np.zeros_like(xs)])
    frames, odom = [], route[0].copy()
    for i, pose in enumerate(route):
        if i:
            st = relative(route[i - 1], pose)
            st[:2] *= 1.0 + rng.normal(0, 0.01)
            st[2] += rng.normal(0, np.deg2rad(0.1))
            odom = compose(odom, st)
        r, a = raycast_2d(corridor_world(), pose, fov=np.deg2rad(fov_deg), beams=beams, max_range=8.0, noise=0.01,
                          rng=rng)
        frames.append(Frame(stamp=0.25 * i, scan2d=LaserScan2D(r, a, 0.05, 8.0), odometry=odom.copy(), index=i))
    return route, run_slam(frames, SlamConfig(), rng=1, progress=False)


def _check(route, res):
    # Along the axis only the odometry knows the motion: its error over the 39 m is about 0.01 * 0.2 * sqrt(195) =
    # 3 cm (1 sigma), so 0.3 m (10 sigma) passes a pose that follows it and fails one the registrations drag
    for traj in (res.tracked, res.trajectory):
        err = relative(traj.poses[0], traj.poses) - relative(route[0], route)
        assert np.abs(err[:, 0]).max() < 0.3
        # no frame-to-frame jumps along the axis beyond the odometry's own step noise (2 mm) many times over
        assert np.abs(np.diff(err[:, 0])).max() < 0.05
    assert abs(res.metrics()["odometry_model"]["bias"][0]) < 1.0  # in sigmas of the configured model


@pytest.mark.parametrize(("fov_deg", "beams"), [(270.0, 541), (180.0, 181)])
def test_corridor_follows_odometry_along_its_axis(fov_deg, beams):
    """Down a featureless corridor the tracking follows the odometry along its axis: the far, sparse wall points
    must not get normals from neighbours on both walls (facing the axis), which would claim millimetres along it
    and teach the odometry a bias of a whole step backwards."""
    _check(*corridor_run(fov_deg, beams))


def test_points_sampled_more_sparsely_than_their_normals_say_are_flagged_and_turned():
    """A wall facing the laser is sampled every r * dtheta; one seen at a grazing angle, sparser by 1 / cos; a
    point whose nearest neighbour lies many times further than its normal and range say (a far point whose
    normal came from both walls of a corridor) is flagged, a grazing wall's far points are not."""
    from hsmap.registration.icp import estimate_normals
    from hsmap.slam import SlamConfig, frame_points, grazing_where_sparse, sampled_as_its_normal_says

    cfg = SlamConfig()
    rng = np.random.default_rng(1)
    pose = np.array([7.0, 0.8, 0.0])
    r, a = raycast_2d(corridor_world(), pose, fov=np.pi, beams=181, max_range=8.0, noise=0.01, rng=rng)
    frame = Frame(stamp=0.0, scan2d=LaserScan2D(r, a, 0.05, 8.0), index=0)
    pts = frame_points(frame, 3, cfg.min_range, cfg.max_range, voxel=cfg.effective_map_voxel())
    normals = estimate_normals(pts)
    keep = sampled_as_its_normal_says(pts, normals, frame, cfg.effective_map_voxel())
    facing_axis = np.abs(normals[:, 0]) >= 0.5  # no surface in this scan faces the corridor's axis
    assert facing_axis.any() and not keep[facing_axis].any()
    assert keep.mean() > 0.95  # the side walls, far points included, stay
    assert keep[np.hypot(*pts.T) < 4.0].all()  # only far, sparse points can be flagged
    # the flagged ones turned across their beams: along this corridor, across it
    fixed = grazing_where_sparse(pts, normals, frame, cfg.effective_map_voxel())
    assert np.all(np.abs(fixed[:, 0]) < 0.5)
    np.testing.assert_array_equal(fixed[keep], normals[keep])
    # a wall facing the laser 6 m ahead, sampled as densely as it should be: every point kept
    room = np.array([[[6.0, -3.0], [6.0, 3.0]]])
    r, a = raycast_2d(room, np.zeros(3), fov=np.pi, beams=181, max_range=8.0, noise=0.01, rng=rng)
    frame = Frame(stamp=0.0, scan2d=LaserScan2D(r, a, 0.05, 8.0), index=0)
    pts = frame_points(frame, 3, cfg.min_range, cfg.max_range, voxel=cfg.effective_map_voxel())
    assert sampled_as_its_normal_says(pts, estimate_normals(pts), frame, cfg.effective_map_voxel()).all()
