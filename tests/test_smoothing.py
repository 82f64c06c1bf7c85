"""The trajectory smoothed with the wheel odometry (hsmap.slam.smoothing): the noise levels measured from the data, the
poses' white noise taken out, a slipped wheel and a jumped frame told apart."""

import numpy as np
import pytest

from hsmap.errors import ShapeError
from hsmap.geometry import compose, relative
from hsmap.slam.smoothing import MIN_FRAMES, identify_noise, smooth_with_odometry, three_cornered_hat

# one-frame sigmas (x, y m, yaw rad) of fr-clinic's three sources, as the hat measured them (seed 1): the SLAM
# poses' white noise, the odometry's motion, the scan matched against the previous scan
WHITE = np.array([0.0066, 0.0045, np.deg2rad(0.01)])
ODOMETRY = np.array([0.0077, 0.0052, np.deg2rad(0.11)])
SCAN = np.array([0.020, 0.013, np.deg2rad(0.19)])


def _run(n=1000, seed=0, white=WHITE):
    """A robot driving a 1 deg-a-step arc at 0.2 m a step: the truth, the SLAM poses (truth + white noise), the
    odometry's and the scan matches' motions (truth + their noise)."""
    rng = np.random.default_rng(seed)
    steps = np.tile([0.2, 0.0, np.deg2rad(1.0)], (n - 1, 1))
    truth = [np.zeros(3)]
    for s in steps:
        truth.append(compose(truth[-1], s))
    truth = np.array(truth)
    slam = compose(truth, rng.normal(size=(n, 3)) * white)
    odometry = np.full((n, 3), np.nan)
    odometry[1:] = compose(steps, rng.normal(size=(n - 1, 3)) * ODOMETRY)
    scan = np.full((n, 3), np.nan)
    scan[1:] = compose(steps, rng.normal(size=(n - 1, 3)) * SCAN)
    sigma = np.tile(1.5 * ODOMETRY, (n, 1))  # a model on the loose side, as a run learns it
    return truth, slam, odometry, sigma, scan


def _error(truth, poses):
    d = relative(truth, poses)
    return np.hypot(d[:, 0], d[:, 1])


def test_the_hat_recovers_each_sources_noise():
    rng = np.random.default_rng(1)
    n = 20000
    truth = np.zeros((n, 3))
    a, b, c = (truth + rng.normal(size=(n, 3)) * s for s in (WHITE * np.sqrt(2), ODOMETRY, SCAN))
    va, vb, vc = three_cornered_hat(a, b, c)
    # x and y, where each source's noise is a fair share of the sums: recovered, a little low (less two standard
    # errors of the estimate)
    for v, sigma in ((va, WHITE * np.sqrt(2)), (vb, ODOMETRY), (vc, SCAN)):
        assert np.all(np.sqrt(v[:2]) > 0.85 * sigma[:2]) and np.all(np.sqrt(v[:2]) < 1.05 * sigma[:2])
    # yaw: the first source's 0.014 deg is lost in the others' 0.11 and 0.19 deg: read as none, not as noise
    assert va[2] == 0.0


def test_the_hat_reads_no_noise_where_there_is_none():
    rng = np.random.default_rng(3)
    n = 1000
    truth = np.zeros((n, 3))
    va, _, _ = three_cornered_hat(truth, truth + rng.normal(size=(n, 3)) * ODOMETRY,
                                  truth + rng.normal(size=(n, 3)) * SCAN)
    np.testing.assert_array_equal(va, 0.0)


def test_identify_noise_measures_the_poses_white_noise():
    _, slam, odometry, _, scan = _run(n=5000)
    white, v_odo, v_scan, n = identify_noise(slam, odometry, scan)
    assert n == 4999
    # a little low, never high: the smoother takes out only what the data tell from the estimate's noise
    assert np.all(np.sqrt(white[:2]) > 0.7 * WHITE[:2]) and np.all(np.sqrt(white[:2]) < 1.05 * WHITE[:2])
    assert np.all(np.sqrt(v_scan[:2]) > 0.85 * SCAN[:2]) and np.all(np.sqrt(v_scan[:2]) < 1.05 * SCAN[:2])


def test_smoothing_takes_the_white_noise_out():
    truth, slam, odometry, sigma, scan = _run()
    res = smooth_with_odometry(slam, odometry, sigma, scan)
    assert res.status == "ok"
    before, after = _error(truth, slam), _error(truth, res.poses)
    assert np.sqrt((after**2).mean()) < 0.8 * np.sqrt((before**2).mean())
    assert after.max() < before.max()
    assert res.odometry_slipped == 0


def test_poses_without_white_noise_are_left_as_they_are():
    truth, slam, odometry, sigma, scan = _run(white=np.zeros(3))
    res = smooth_with_odometry(slam, odometry, sigma, scan)
    assert res.status == "ok"
    np.testing.assert_array_equal(res.white_sigma, 0.0)
    np.testing.assert_array_equal(res.poses, slam)


def test_a_frame_that_jumped_is_put_back():
    truth, slam, odometry, sigma, scan = _run()
    slam[500] = compose(slam[500], [0.3, 0.1, 0.02])
    res = smooth_with_odometry(slam, odometry, sigma, scan)
    assert _error(truth, slam)[500] > 0.3
    assert _error(truth, res.poses)[500] < 0.03
    assert res.poses_down_weighted >= 1


def test_frames_that_left_the_track_where_the_scans_say_nothing_are_put_back():
    # a featureless stretch: four poses 0.7 m back, the scan matches there unconstrained (NaN: HsSlam passes none)
    truth, slam, odometry, sigma, scan = _run()
    slam[500:504] = compose(slam[500:504], [-0.7, 0.05, 0.0])
    scan[500:505] = np.nan
    res = smooth_with_odometry(slam, odometry, sigma, scan)
    assert _error(truth, res.poses)[500:504].max() < 0.03


def test_a_slipped_wheel_does_not_bend_the_trajectory():
    truth, slam, odometry, sigma, scan = _run()
    odometry[500, 0] += 0.3  # the wheels turned 0.3 m more than the robot moved
    res = smooth_with_odometry(slam, odometry, sigma, scan)
    assert res.odometry_slipped == 1
    after = _error(truth, res.poses)
    assert after[495:506].max() < 0.03
    clean = smooth_with_odometry(*_run()[1:])
    np.testing.assert_allclose(after.max(), _error(truth, clean.poses).max(), atol=5e-3)


def test_a_cut_in_the_odometry_splits_the_chain():
    truth, slam, odometry, sigma, scan = _run()
    odometry[400:450] = np.nan
    res = smooth_with_odometry(slam, odometry, sigma, scan)
    assert res.status == "ok"
    assert np.all(np.isfinite(res.poses))
    assert np.sqrt((_error(truth, res.poses) ** 2).mean()) < np.sqrt((_error(truth, slam) ** 2).mean())


def test_too_few_frames_do_nothing_and_say_so():
    _, slam, odometry, sigma, scan = _run(n=MIN_FRAMES)
    res = smooth_with_odometry(slam, odometry, sigma, scan)
    assert res.status.startswith("skipped:") and str(MIN_FRAMES) in res.status
    np.testing.assert_array_equal(res.poses, slam)


def test_the_same_input_gives_the_same_poses():
    args = _run()[1:]
    np.testing.assert_array_equal(smooth_with_odometry(*args).poses, smooth_with_odometry(*args).poses)


def test_inputs_of_other_shapes_are_refused():
    _, slam, odometry, sigma, scan = _run(n=100)
    with pytest.raises(ShapeError, match="one shape"):
        smooth_with_odometry(slam, odometry[:-1], sigma, scan)
