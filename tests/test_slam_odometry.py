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


def test_window_medians_and_deviations_equal_numpys_as_rows_come_and_go():
    from hsmap.slam.odometry import _Window

    rng = np.random.default_rng(3)
    for size in (1, 2, 7, 40):
        window, rows = _Window(size), []
        for _ in range(3 * size + 5):
            row = tuple(float(v) for v in rng.normal(size=3) * rng.choice([1e-3, 1.0, 1e3]))
            if rng.random() < 0.3:
                row = (np.nan, np.nan, row[2])  # an unconstrained frame: x and y not learned
            if rng.random() < 0.2:
                row = (float(rng.integers(-2, 3)),) * 3  # ties
            window.append(row)
            rows.append(row)
            held = np.array(rows[-size:])
            assert len(window) == len(held)
            for c in range(3):
                col = held[np.isfinite(held[:, c]), c]
                assert window.finite(c) == len(col)
                if len(col):
                    m = np.median(col)
                    assert window.median(c) == m
                    assert window.deviation(c) == np.median(np.abs(col - m))


def test_constrains_xy_decides_as_the_eigenvalues_do_even_at_the_ratio():
    from hsmap.registration.information import constrained_axes
    from hsmap.slam.odometry import constrains_xy

    rng = np.random.default_rng(4)
    for t in range(3000):
        a = rng.normal(size=(3, 3)) * rng.choice([1e-6, 1.0, 1e6])
        info = a @ a.T
        if t % 3 == 0:  # eigenvalues at the ratio to a few parts in 1e12
            v = np.linalg.qr(rng.normal(size=(2, 2)))[0]
            lam = rng.random() * 10
            info[:2, :2] = v @ np.diag([lam, lam * 0.05 * (1 + rng.normal() * 1e-12)]) @ v.T
        if t % 5 == 0:
            info[:2, :2] = 0.0  # no information at all
        assert constrains_xy(info, 0.05) == (constrained_axes(info[:2, :2], 0.05).shape[1] == 2)
    assert not constrains_xy(np.full((3, 3), np.nan), 0.05)
    assert not constrains_xy(None, 0.05)


def test_model_sigmas_of_a_planar_step_use_the_norm_and_the_wrapped_turn():
    from hsmap.geometry import wrap_angle

    model = OdometryModel(SlamConfig(dof=3), learn=False, wheel_edges=False)
    a, b, c, d, e = model.config.odometry_sigma
    rng = np.random.default_rng(5)
    for step in rng.normal(size=(2000, 3)) * rng.choice([1e-3, 1.0, 10.0], size=(2000, 1)):
        dist = float(np.linalg.norm(step[:2]))
        turn = float(np.abs(wrap_angle(step[2:])).max())
        assert model.model_sigmas(step) == (a + b * dist, c + d * turn + e * dist)


def test_slip_weight_is_one_within_the_gate_and_gate_over_m2_beyond():
    from hsmap.slam.odometry import CHI2_999, slip_weight

    rng = np.random.default_rng(6)
    inside = beyond = 0
    for _ in range(3000):
        a = rng.normal(size=(3, 3)) * rng.choice([1.0, 30.0, 1e3])
        info_a = a @ a.T
        info_b = np.diag(1.0 / rng.uniform(0.01, 0.3, 3) ** 2)
        d = rng.normal(size=3) * rng.choice([0.01, 0.1, 1.0])
        m2 = float(d @ (info_a @ np.linalg.solve(info_a + info_b + 1e-12 * np.eye(3), info_b)) @ d)
        expected = CHI2_999[3] / m2 if m2 > CHI2_999[3] else 1.0
        assert slip_weight(d, info_a, info_b) == expected
        inside += expected == 1.0
        beyond += expected < 1.0
    assert inside > 100 and beyond > 100


def test_the_learned_bias_and_scale_are_the_robust_statistics_of_the_recent_disagreements():
    """The bias is the median of the last ``odometry_window`` one-frame disagreements (x and y of constrained frames
    only), the scale the MAD of the lagged ones: recomputed from every frame's own numbers, they agree."""
    from hsmap.geometry import relative, wrap_angle

    cfg = SlamConfig(dof=3, odometry_window=30, odometry_lag=3)
    model = OdometryModel(cfg, learn=True, wheel_edges=False)
    rng = np.random.default_rng(7)
    odom, pose = np.zeros(3), np.zeros(3)
    model.advance(Frame(stamp=0.0, odometry=odom.copy(), index=0))
    rows, hist, lagged, var = [], [], [], np.zeros(2)
    for i in range(1, 150):
        odom = compose(odom, np.array([0.2, 0.01, 0.05]) + rng.normal(0, 0.01, 3))
        frame = Frame(stamp=0.1 * i, odometry=odom.copy(), index=i)
        step = model.step(frame)
        new = compose(pose, step + rng.normal(0, 0.02, 3))
        info = CORRIDOR if rng.random() < 0.3 else CONSTRAINED
        st, sr = model.model_sigmas(step)
        off = relative(compose(pose, step), new)
        ok = info is CONSTRAINED
        rows.append((off[0] / st if ok else np.nan, off[1] / st if ok else np.nan, float(wrap_angle(off[2])) / sr))
        model.learn_bias(frame, _result(new, info), pose)
        r = np.array(rows[-cfg.odometry_window:])
        enough = np.isfinite(r).sum(0) >= 3
        want = [np.median(r[np.isfinite(r[:, c]), c]) if enough[c] else 0.0 for c in range(3)]
        assert model.bias.tolist() == want
        var = var + np.square([st, sr])
        hist.append((new, ok, odom.copy(), var.copy()))
        model.learn_scale(frame, _result(new, info))
        if len(hist) > cfg.odometry_lag and ok and hist[-1 - cfg.odometry_lag][1]:
            p0, _, o0, v0 = hist[-1 - cfg.odometry_lag]
            e = relative(relative(o0, odom), relative(p0, new))
            s = np.sqrt(var - v0)
            lagged.append((e[0] / s[0], e[1] / s[0], float(wrap_angle(e[2])) / s[1]))
        if len(lagged) >= 3:
            q = np.array(lagged[-cfg.odometry_window:])
            spread = 1.4826 * np.median(np.abs(q - np.median(q, axis=0)), axis=0)
            assert model.scale.tolist() == np.clip([max(spread[0], spread[1]), spread[2]], 0.1, 5.0).tolist()
        model.advance(frame)
        pose = new
    assert len(lagged) > cfg.odometry_window  # the window turned over
