"""The odometry model alone: which odometry steps it sets aside against the scan match (a spike in the wheels,
not a scan match that slides)."""

import warnings

import numpy as np
import pytest

from hsmap.datasets.frames import Frame
from hsmap.geometry import compose, pose_to_matrix
from hsmap.registration.icp import RegistrationResult
from hsmap.slam import SlamConfig
from hsmap.slam.odometry import OdometryModel

CONSTRAINED = np.diag([1e4, 1e4, 1e4])  # a scene constraining x, y and yaw
CORRIDOR = np.diag([1e4, 1.0, 1e4])  # a corridor along x: its axis hardly constrained


def _result(pose, information=CONSTRAINED):
    pose = np.asarray(pose, dtype=float)
    return RegistrationResult(transformation=pose_to_matrix(pose), pose=pose, fitness=0.0, inlier_ratio=1.0,
                              rmse=0.01, evaluations=0, iterations=0, dropped=0, global_pose=pose,
                              refined=True, stop_reason="test", seconds=0.0, information=information)


def _drive(wheel_steps, match_steps, information=CONSTRAINED):
    """Track frames whose odometry moves by ``wheel_steps`` while the scan match (beyond the odometry's gate, as the
    caller of set_aside checked) moves by ``match_steps``; returns the frames whose step was set aside."""
    model = OdometryModel(SlamConfig(dof=3), learn=False, wheel_edges=False)
    odom, poses = np.zeros(3), [np.zeros(3)]
    model.advance(Frame(stamp=0.0, odometry=odom.copy(), index=0))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for i, (w, m) in enumerate(zip(wheel_steps, match_steps, strict=True), start=1):
            odom = compose(odom, w)
            frame = Frame(stamp=0.1 * i, odometry=odom.copy(), index=i)
            pose = compose(poses[-1], m)
            model.set_aside(frame, _result(pose, information), poses)
            poses.append(pose)
            model.advance(frame, m)
    return model.outliers


STEP = np.array([0.2, 0.0, 0.0])


def test_a_single_jump_of_the_wheels_that_stays_is_set_aside_once():
    wheels = [STEP] * 10 + [np.array([5.2, 0.0, 0.0])] + [STEP] * 10
    assert _drive(wheels, [STEP] * 21) == [11]


def test_a_single_reading_of_the_wheels_far_off_is_set_aside_once():
    wheels = [STEP] * 10 + [np.array([5.2, 0.0, 0.0]), np.array([-4.8, 0.0, 0.0])] + [STEP] * 9
    assert _drive(wheels, [STEP] * 21) == [11]


@pytest.mark.parametrize("wheel", [np.array([0.8, 0.0, 0.0]), np.array([0.0, 0.0, np.deg2rad(40.0)])])
def test_a_scan_match_that_slides_while_the_wheels_stay_steady_is_never_believed_over_them(wheel):
    """The match slows to a standstill (a corridor, a glass wall, a crowd moving along) while the wheels keep their
    pace: its previous motion, made of its own output, soon agrees with it, but the wheels never jump, so no step
    is set aside."""
    matches = [wheel] * 5 + [wheel * max(0.0, 1.0 - k / 3) for k in range(1, 17)]
    assert _drive([wheel] * 21, matches) == []


def test_a_jump_against_a_poorly_constrained_match_is_not_set_aside():
    wheels = [STEP] * 10 + [np.array([5.2, 0.0, 0.0])] + [STEP] * 10
    assert _drive(wheels, [STEP] * 21, CORRIDOR) == []


def test_steps_are_never_set_aside_on_consecutive_frames():
    wheels = [STEP] * 10 + [np.array([5.2, 0.0, 0.0]), np.array([2.2, 0.0, 0.0])] + [STEP] * 9
    assert _drive(wheels, [STEP] * 21) == [11]
