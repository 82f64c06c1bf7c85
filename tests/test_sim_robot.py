"""The differential-drive robot and its drifting wheel odometry."""

import numpy as np
import pytest

from hsmap.errors import ConfigError
from hsmap.geometry import wrap_angle
from hsmap.sim import OdometryConfig, RobotConfig, RouteStep, load_scenario, motion_for, simulate_motion
from hsmap.sim.catalog import resolve_scenario

PERFECT = OdometryConfig.perfect()


def straight(length, odo, seed=0, robot=None):
    return simulate_motion([0.0, 0.0, 0.0], [RouteStep("goto", (length, 0.0))], robot or RobotConfig(), odo,
                           2.0, np.random.default_rng(seed))


def only(**kw):
    return OdometryConfig(**{**{f: 0.0 for f in ("scale_error", "turn_scale_error", "heading_bias_deg_per_m",
                                                  "slip_translation", "slip_rotation_deg",
                                                  "slip_heading_deg_per_m")}, "turn_slip_factor": 1.0, **kw})


def test_route_is_followed_with_limited_speed_and_turn_rate():
    steps = [RouteStep("goto", (4.0, 0.0)), RouteStep("goto", (4.0, 3.0)),
             RouteStep("goto", (4.0, 1.0), reverse=True), RouteStep("turn", angle=2 * np.pi),
             RouteStep("wait", seconds=1.0), RouteStep("face", angle=np.pi)]
    m = simulate_motion([0, 0, 0], steps, RobotConfig(), PERFECT, 2.0, np.random.default_rng(0))
    d = np.diff(m.groundtruth, axis=0)
    assert np.hypot(d[:, 0], d[:, 1]).max() <= 0.25 + 1e-9  # 0.5 m/s at 2 Hz
    assert np.abs(wrap_angle(d[:, 2])).max() <= np.deg2rad(15) + 1e-9  # 30 deg/s at 2 Hz
    np.testing.assert_allclose(m.stamps, np.arange(len(m)) * 0.5)
    np.testing.assert_allclose(m.groundtruth[-1, :2], [4.0, 1.0], atol=1e-9)
    assert abs(wrap_angle(m.groundtruth[-1, 2] - np.pi)) < 1e-9
    # reversing: the robot keeps facing +y while it backs down to y = 1
    back = (m.groundtruth[:, 0] == 4.0) & (np.gradient(m.groundtruth[:, 1]) < -1e-6)
    assert back.any() and np.allclose(m.groundtruth[back, 2], np.pi / 2)
    assert m.path_length() == pytest.approx(4 + 3 + 2, abs=1e-6)
    # a perfect odometry equals the ground truth
    np.testing.assert_allclose(m.odometry[:, :2], m.groundtruth[:, :2], atol=1e-9)
    assert np.abs(wrap_angle(m.odometry[:, 2] - m.groundtruth[:, 2])).max() < 1e-9


def test_odometry_scale_error_grows_linearly_with_distance():
    for L in (5.0, 10.0, 20.0):
        m = straight(L, only(scale_error=0.02))
        assert m.odometry[-1, 0] == pytest.approx(1.02 * L, abs=1e-6)
        assert np.hypot(*(m.odometry[-1, :2] - m.groundtruth[-1, :2])) == pytest.approx(0.02 * L, abs=1e-6)


def test_odometry_heading_bias_bends_a_straight_corridor():
    bias = 0.5  # deg per metre
    errs = {}
    for L in (5.0, 10.0, 20.0):
        m = straight(L, only(heading_bias_deg_per_m=bias))
        errs[L] = m.odometry[-1]
        assert np.rad2deg(m.odometry[-1, 2]) == pytest.approx(bias * L, rel=1e-6)
        # the believed path is an arc: lateral offset ~ L^2 * bias / 2
        assert m.odometry[-1, 1] == pytest.approx(np.deg2rad(bias) * L**2 / 2, rel=0.02)
    assert errs[20.0][1] == pytest.approx(4 * errs[10.0][1], rel=0.02)
    # driving back in reverse undoes a heading bias (unequal wheel radii act on the signed distance)
    steps = [RouteStep("goto", (10.0, 0.0)), RouteStep("goto", (0.0, 0.0), reverse=True)]
    m = simulate_motion([0, 0, 0], steps, RobotConfig(), only(heading_bias_deg_per_m=bias), 2.0,
                        np.random.default_rng(0))
    assert abs(m.odometry[-1, 2]) < 1e-9


def test_odometry_random_slip_grows_with_the_square_root_of_distance():
    odo = only(slip_translation=0.01)
    ends = {L: np.array([straight(L, odo, seed).odometry[-1, 0] - L for seed in range(150)]) for L in (4.0, 16.0)}
    for L, e in ends.items():
        assert abs(e.mean()) < 3 * 0.01 * np.sqrt(L) / np.sqrt(150)
        assert e.std() == pytest.approx(0.01 * np.sqrt(L), rel=0.2)
    assert ends[16.0].std() / ends[4.0].std() == pytest.approx(2.0, rel=0.3)


def test_turning_on_the_spot_slips_more():
    def spin_error(factor, seed):
        m = simulate_motion([0, 0, 0], [RouteStep("turn", angle=2 * np.pi), RouteStep("goto", (0.1, 0.0))],
                            RobotConfig(), only(slip_rotation_deg=0.5, turn_slip_factor=factor), 2.0,
                            np.random.default_rng(seed))
        return wrap_angle(m.odometry[-1, 2] - m.groundtruth[-1, 2])

    s1 = np.std([spin_error(1.0, s) for s in range(100)])
    s3 = np.std([spin_error(3.0, s) for s in range(100)])
    assert s1 == pytest.approx(np.deg2rad(0.5) * np.sqrt(2 * np.pi), rel=0.25)
    assert s3 / s1 == pytest.approx(3.0, rel=0.25)
    # turn scale error: a full turn measured 2 % too large
    m = simulate_motion([0, 0, 0], [RouteStep("turn", angle=2 * np.pi), RouteStep("goto", (1.0, 0.0))],
                        RobotConfig(), only(turn_scale_error=0.02), 2.0, np.random.default_rng(0))
    assert wrap_angle(m.odometry[-1, 2]) == pytest.approx(0.02 * 2 * np.pi, abs=1e-6)


def test_same_seed_same_odometry_other_seed_other_odometry():
    a = straight(10.0, OdometryConfig(), seed=4)
    b = straight(10.0, OdometryConfig(), seed=4)
    c = straight(10.0, OdometryConfig(), seed=5)
    np.testing.assert_array_equal(a.odometry, b.odometry)
    assert not np.allclose(a.odometry, c.odometry)
    np.testing.assert_array_equal(a.groundtruth, c.groundtruth)


def test_slam_office_route_meets_the_paper_run():
    """Acceptance: >= 177 poses over >= 100 m, odometry ending >= 0.2 m off, <= 0.25 m / 15 deg per frame."""
    scn = load_scenario(resolve_scenario("slam-office"))
    m = motion_for(scn)
    assert len(m) >= 177
    assert m.path_length() >= 100.0
    assert np.hypot(*(m.odometry[-1, :2] - m.groundtruth[-1, :2])) >= 0.2
    d = np.diff(m.groundtruth, axis=0)
    assert np.hypot(d[:, 0], d[:, 1]).max() <= 0.25 + 1e-9
    assert np.abs(wrap_angle(d[:, 2])).max() <= np.deg2rad(15) + 1e-9
    # the route has turns on the spot, reversing and a full spin
    kinds = [leg.kind for leg in m.legs]
    assert kinds.count("turn") >= 10
    assert any(leg.kind == "drive" and leg.amount < 0 for leg in m.legs)
    assert any(leg.kind == "turn" and abs(leg.amount) >= 2 * np.pi - 1e-9 for leg in m.legs)


@pytest.mark.parametrize("kw, match", [({"max_speed": 0}, "max_speed"), ({"radius": -1}, "radius"),
                                       ({"internal_rate": float("nan")}, "internal_rate")])
def test_bad_robot_config(kw, match):
    with pytest.raises(ConfigError, match=match):
        RobotConfig(**kw)


def test_bad_odometry_config():
    with pytest.raises(ConfigError, match="turn_slip_factor"):
        OdometryConfig(turn_slip_factor=0.5)
    with pytest.raises(ConfigError, match="slip_translation"):
        OdometryConfig(slip_translation=-0.1)
