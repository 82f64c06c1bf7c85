"""Trajectory metrics against hand-computed values, and their bad inputs."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from hsmap.cli import main
from hsmap.datasets.relations import Relations, read_relations
from hsmap.errors import DataFormatError, EmptyInputError, InputError
from hsmap.evaluation import (
    Alignment,
    DeltaUnit,
    PoseRelation,
    associate,
    ate,
    pose_errors,
    relations_error,
    rpe,
    umeyama,
)
from hsmap.geometry import compose, euler_to_matrix, relative
from hsmap.trajectory import Trajectory, write_tum

WORLD = np.array([10.0, -3.0, 0.7])  # an arbitrary world frame for the estimate


def line(n=10, step=0.5, yaw_rate=0.1):
    k = np.arange(n, dtype=float)
    return Trajectory(k, np.column_stack([step * k, np.zeros(n), yaw_rate * k]))


# -- per-DOF errors (Table 1) ---------------------------------------------------------------------------
def test_pose_errors_relative_to_first_pose_no_alignment():
    gt = line()
    delta = np.array([0.03, -0.05, 0.02])
    rel = gt.poses.copy()
    rel[4] += delta  # one pose off by a known amount (in the frame of the first pose)
    est = Trajectory(gt.stamps, compose(WORLD, rel))  # the estimate lives in another world frame
    res = pose_errors(est, gt)
    assert res.names == ("x", "y", "yaw")
    np.testing.assert_allclose(res.max_abs, np.abs(delta), atol=1e-12)
    np.testing.assert_allclose(res.errors[4], delta, atol=1e-12)
    np.testing.assert_allclose(res.final, 0, atol=1e-12)
    assert res.final_translation == pytest.approx(0, abs=1e-12)
    d = res.as_dict()
    assert d["max_abs_error"]["yaw_deg"] == pytest.approx(math.degrees(0.02))
    assert d["max_abs_error"]["y_m"] == pytest.approx(0.05)


def test_pose_errors_final_pose_and_angle_wrap():
    gt = line()
    gt.poses[:, 2] = np.linspace(0, 3.1, 10)  # ends near +pi
    rel = gt.poses.copy()
    rel[-1] += [0.03, 0.04, 0.1]  # yaw 3.2 wraps to -3.08: the error must still be 0.1
    res = pose_errors(Trajectory(gt.stamps, compose(WORLD, rel)), gt)
    np.testing.assert_allclose(res.final, [0.03, 0.04, 0.1], atol=1e-12)
    assert res.final_translation == pytest.approx(0.05)
    assert res.final_rotation == pytest.approx(0.1)


def test_pose_errors_6dof():
    n = 6
    gt = Trajectory(np.arange(n), np.column_stack([np.arange(n) * 0.4, np.zeros((n, 4)), np.arange(n) * 0.05]))
    rel = gt.poses.copy()
    rel[2] += [0.0, 0.0, 0.01, 0.002, -0.003, 0.0]
    world = np.array([1.0, 2.0, 0.3, 0.0, 0.0, -0.4])
    res = pose_errors(Trajectory(gt.stamps, compose(world, rel)), gt)
    assert res.names == ("x", "y", "z", "roll", "pitch", "yaw")
    np.testing.assert_allclose(res.max_abs, [0, 0, 0.01, 0.002, 0.003, 0], atol=1e-9)
    # a 3-DOF estimate against 6-DOF ground truth compares x, y, yaw
    assert pose_errors(gt.as_3dof(), gt).names == ("x", "y", "yaw")


def test_association_tolerance_and_mismatch():
    gt = line()
    near = Trajectory(gt.stamps + 2e-4, gt.poses)
    assert pose_errors(near, gt).max_abs.max() == 0
    far = Trajectory(gt.stamps + 0.3, gt.poses)
    with pytest.raises(InputError, match=r"10 of 10 estimated stamps have no reference stamp within 0.001 s"):
        pose_errors(far, gt)
    with pytest.raises(InputError, match="duplicate"):
        associate(Trajectory([1.0, 1.0], [[0, 0, 0], [1, 0, 0]]), gt)
    # reference poses without an estimate are ignored; first and last of the estimate are used
    sub = Trajectory(gt.stamps[2:7], gt.poses[2:7])
    assert pose_errors(sub, gt).max_abs.max() == pytest.approx(0, abs=1e-12)
    with pytest.raises(InputError, match="NaN"):
        pose_errors(Trajectory(gt.stamps, np.where(gt.poses == 0.5, np.nan, gt.poses)), gt)
    with pytest.raises(InputError, match="Trajectory"):
        pose_errors(gt.poses, gt)


# -- ATE ----------------------------------------------------------------------------------------------------
def test_ate_known_offset_and_alignments():
    gt = line(n=20, yaw_rate=0.05)
    gt.poses[:, 1] = np.sin(gt.stamps / 3)  # not a straight line, so SE(2)/SE(3) alignment is determined
    est = Trajectory(gt.stamps, gt.poses + [1.0, 2.0, 0.0])  # shifted by (1, 2): every error is sqrt(5)
    r = ate(est, gt)
    assert r.unit == "m" and r.statistics.n == 20
    np.testing.assert_allclose(r.errors, math.sqrt(5))
    assert r.statistics.rmse == pytest.approx(math.sqrt(5))
    assert r.statistics.sse == pytest.approx(20 * 5)
    assert ate(est, gt, relation=PoseRelation.ROTATION_ANGLE).statistics.max == pytest.approx(0, abs=1e-9)
    for al in (Alignment.ORIGIN, Alignment.SE2, Alignment.SE3):
        assert ate(est, gt, alignment=al).statistics.max == pytest.approx(0, abs=1e-9)
    # rotated about the origin by 0.3 rad: the orientation error is 0.3 rad everywhere
    rot = Trajectory(gt.stamps, compose([0.0, 0.0, 0.3], gt.poses))
    np.testing.assert_allclose(ate(rot, gt, relation="rotation_angle_deg").errors, math.degrees(0.3))
    aligned = ate(rot, gt, alignment="se2", relation=PoseRelation.ROTATION_ANGLE)
    assert aligned.statistics.max == pytest.approx(0, abs=1e-7)
    np.testing.assert_allclose(aligned.alignment[:2, :2], [[math.cos(-0.3), -math.sin(-0.3)], [math.sin(-0.3), math.cos(-0.3)]], atol=1e-9)


def test_umeyama_recovers_similarity(rng):
    x = rng.normal(size=(50, 3))
    R = euler_to_matrix(0.1, -0.2, 0.7)
    y = 2.5 * x @ R.T + [1.0, -2.0, 0.5]
    R_, t_, s_ = umeyama(x, y, with_scale=True)
    np.testing.assert_allclose(R_, R, atol=1e-12)
    np.testing.assert_allclose(t_, [1.0, -2.0, 0.5], atol=1e-12)
    assert s_ == pytest.approx(2.5)
    gt = Trajectory(np.arange(50), np.column_stack([y, np.zeros((50, 3))]))
    est = Trajectory(np.arange(50), np.column_stack([x, np.zeros((50, 3))]))
    assert ate(est, gt, alignment=Alignment.SIM3).statistics.max == pytest.approx(0, abs=1e-9)
    with pytest.raises(InputError, match="at least 3 poses"):
        umeyama(x[:2], y[:2])


# -- RPE ----------------------------------------------------------------------------------------------------
def test_rpe_per_frame_hand_computed():
    n = 10
    gt = Trajectory(np.arange(n), np.column_stack([0.25 * np.arange(n), np.zeros(n), np.zeros(n)]))
    est_p = gt.poses.copy()
    est_p[5, 1] = 0.1  # one pose 10 cm to the side: pairs (4, 5) and (5, 6) are each 10 cm off
    est = Trajectory(gt.stamps, compose(WORLD, est_p))
    r = rpe(est, gt)
    expected = np.zeros(n - 1)
    expected[[4, 5]] = 0.1
    np.testing.assert_allclose(r.errors, expected, atol=1e-12)
    assert r.statistics.mean == pytest.approx(0.2 / 9)
    r2 = rpe(est, gt, delta=2)  # pairs (0,2), (2,4), (4,6), (6,8): the side step cancels out
    assert r2.statistics.n == 4 and r2.statistics.max == pytest.approx(0, abs=1e-12)
    assert rpe(est, gt, delta=2, all_pairs=True).statistics.n == 8
    assert rpe(est, gt, relation=PoseRelation.ROTATION_ANGLE).statistics.max == pytest.approx(0, abs=1e-12)
    est_p[5, 2] = 0.05  # pose 5 also turned by 0.05 rad: both pairs through pose 5 are 0.05 rad off
    rot = rpe(Trajectory(gt.stamps, compose(WORLD, est_p)), gt, relation=PoseRelation.ROTATION_ANGLE)
    expected[[4, 5]] = math.degrees(0.05)
    np.testing.assert_allclose(rot.errors, expected, atol=1e-9)


def test_rpe_per_metre_pairs_like_evo():
    n = 17
    gt = Trajectory(np.arange(n), np.column_stack([0.25 * np.arange(n), np.zeros(n), np.zeros(n)]))
    r = rpe(gt, gt, delta=1.0, unit=DeltaUnit.METERS)
    # evo marks the first pose and those where 1 m of path has accumulated (4, 8, 12, 16), pairs consecutive marks
    np.testing.assert_array_equal(r.stamps, [0, 4, 8, 12])
    assert r.statistics.max == 0
    assert rpe(gt, gt, delta=1.0, unit="meters", all_pairs=True).statistics.n == 13  # (i, i + 4), i = 0..12
    with pytest.raises(EmptyInputError, match="no pose pairs 10 meters apart"):
        rpe(gt, gt, delta=10.0, unit=DeltaUnit.METERS)
    with pytest.raises(InputError, match="positive integer"):
        rpe(gt, gt, delta=1.5)


# -- Freiburg relations -----------------------------------------------------------------------------------
GT_POSES = np.array([[0, 0, 0], [1, 0, 0], [1, 0, math.pi / 2], [1, 1, math.pi / 2], [1, 2, math.pi / 2]], float)


def test_relations_hand_computed():
    gt = Trajectory(np.arange(5.0), GT_POSES)
    two_deg = math.radians(2)
    rel = Relations(
        t_i=[0, 1, 2, 0],
        t_j=[1, 2, 4, 4],
        poses=[
            [1.1, 0, 0],  # truth (1, 0, 0): 0.1 m off
            [0, 0, math.pi / 2 + two_deg],  # turn in place, 2 degrees off
            [2, 0.3, 0],  # truth (2, 0, 0): 0.3 m off
            [1, 2, math.pi / 2],  # exact
        ],
    )
    est = Trajectory(gt.stamps, compose(WORLD, GT_POSES))  # frame-independent: relative poses only
    res = relations_error(est, rel)
    np.testing.assert_allclose(res.translation, [0.1, 0, 0.3, 0], atol=1e-12)
    np.testing.assert_allclose(res.rotation, [0, two_deg, 0, 0], atol=1e-12)
    d = res.as_dict()
    assert d["translation_m"]["mean"] == pytest.approx(0.1)
    assert d["translation_m"]["std"] == pytest.approx(math.sqrt(0.02))  # sample standard deviation
    assert d["rotation_deg"]["mean"] == pytest.approx(0.5)
    assert d["rotation_deg"]["std"] == pytest.approx(1.0)
    assert d["translation_squared_m2"]["mean"] == pytest.approx(0.025)
    assert d["translation_squared_m2"]["std"] == pytest.approx(math.sqrt(0.0019))
    assert d["rotation_squared_deg2"]["mean"] == pytest.approx(1.0)
    assert d["rotation_squared_deg2"]["std"] == pytest.approx(2.0)
    assert (d["n_relations"], d["n_skipped"], d["n_interpolated_stamps"]) == (4, 0, 0)


def test_relations_error_definition_is_pose_error_times_inverse_relation():
    # E = (P_i^-1 P_j) R^-1: a rotational error on a relation with a translation also shows up in |t(E)|
    gt = Trajectory([0.0, 1.0], [[0, 0, 0], [1, 0, 0]])
    theta = math.radians(10)
    res = relations_error(gt, Relations([0.0], [1.0], [[1, 0, theta]]))
    assert res.rotation[0] == pytest.approx(theta)
    assert res.translation[0] == pytest.approx(2 * math.sin(theta / 2))


def test_relation_errors_in_2d_and_3d_agree_and_name_bad_shapes():
    """The 2D matrices give what the 3D ones give for the same planar poses: the translation of E = est R^-1
    (compose(est, invert(R)) in pose vectors) and |its yaw|; shapes that are not one kind of matrix are refused."""
    from hsmap.errors import ShapeError
    from hsmap.evaluation.trajectory import relation_errors
    from hsmap.geometry import invert, pose_to_matrix

    rng = np.random.default_rng(3)
    est = np.column_stack([rng.normal(0, 2, (20, 2)), rng.uniform(-3, 3, 20)])
    ref = est + np.column_stack([rng.normal(0, 0.1, (20, 2)), rng.normal(0, 0.2, 20)])
    t2, r2 = relation_errors(pose_to_matrix(est), pose_to_matrix(ref))
    six = np.zeros((2, 20, 6))
    six[..., [0, 1, 5]] = est, ref
    t3, r3 = relation_errors(pose_to_matrix(six[0]), pose_to_matrix(six[1]))
    e = np.array([compose(a, invert(b)) for a, b in zip(est, ref, strict=True)])
    np.testing.assert_allclose(t2, np.hypot(e[:, 0], e[:, 1]), atol=1e-12)
    np.testing.assert_allclose(r2, np.abs(e[:, 2]), atol=1e-12)
    np.testing.assert_allclose(t3, t2, atol=1e-12)
    np.testing.assert_allclose(r3, r2, atol=1e-9)
    with pytest.raises(ShapeError, match="homogeneous matrices"):
        relation_errors(pose_to_matrix(est), pose_to_matrix(six[1]))
    with pytest.raises(ShapeError, match="homogeneous matrices"):
        relation_errors(est, ref)


def test_relations_interpolate_between_stamps():
    t = np.arange(6.0)
    traj = Trajectory(t, np.column_stack([t, np.zeros(6), 0.1 * t]))  # translation and yaw linear in time
    pi, pj = np.array([0.5, 0, 0.05]), np.array([2.5, 0, 0.25])
    res = relations_error(traj, Relations([0.5], [2.5], [relative(pi, pj)]))
    assert res.translation[0] == pytest.approx(0, abs=1e-12) and res.rotation[0] == pytest.approx(0, abs=1e-12)
    assert res.n_interpolated == 2
    # 6-DOF trajectories interpolate rotations by slerp
    res6 = relations_error(traj.as_6dof(), Relations([0.5], [2.5], [relative(pi, pj)]))
    assert res6.translation[0] == pytest.approx(0, abs=1e-12) and res6.rotation[0] == pytest.approx(0, abs=1e-9)


def test_relations_distance_scale_finds_a_trajectory_that_makes_distances_too_long():
    # a winding route; its estimate is the truth with every step 1 % longer and a little heading noise
    rng = np.random.default_rng(3)
    n = 400
    yaw = np.cumsum(rng.normal(0, 0.05, n))
    steps = rng.uniform(0.05, 0.3, n)
    xy = np.cumsum(np.column_stack([steps * np.cos(yaw), steps * np.sin(yaw)]), axis=0)
    truth = np.column_stack([xy, yaw])
    est_xy = np.cumsum(np.column_stack([1.01 * steps * np.cos(yaw), 1.01 * steps * np.sin(yaw)]), axis=0)
    est = Trajectory(np.arange(n, dtype=float), compose(WORLD, np.column_stack([est_xy, yaw])))
    i = rng.integers(0, n - 20, 300)
    j = i + rng.integers(3, 20, 300)
    rel = Relations(i.astype(float), j.astype(float), [relative(truth[a], truth[b]) for a, b in zip(i, j, strict=True)])
    res = relations_error(est, rel)
    assert res.distance_scale() == pytest.approx(1.01, abs=1e-9)
    exact = relations_error(Trajectory(np.arange(n, dtype=float), truth), rel)
    assert exact.distance_scale() == pytest.approx(1.0, abs=1e-12)
    # relations shorter than min_distance do not count; none left: NaN (null in the JSON)
    assert np.isnan(res.distance_scale(min_distance=100.0))
    far = np.linalg.norm(res.reference, axis=1) >= 1.0
    assert res.distance_scale(mask=far) == pytest.approx(1.01, abs=1e-9)


def test_relations_unmatched_and_bad_trajectories():
    gt = Trajectory(np.arange(5.0), GT_POSES)
    rel = Relations([0, 1, 3, 20], [1, 2, 4, 21], [[1, 0, 0], [0, 0, math.pi / 2], [1, 0, 0], [1, 0, 0]])
    with pytest.raises(InputError, match=r"1 of 4 relations could not be matched.*2 relation stamps.*\[0\.000000, 4\.000000\].*\[0\.000000, 21\.000000\]"):
        relations_error(gt, rel)
    res = relations_error(gt, rel, skip_unmatched=True)
    assert res.as_dict()["n_skipped"] == 1 and res.as_dict()["n_relations"] == 3
    shifted = Trajectory(gt.stamps + 1000, gt.poses)
    with pytest.raises(InputError, match="4 of 4 relations could not be matched"):
        relations_error(shifted, rel, skip_unmatched=True)
    dup = Trajectory([0, 1, 1, 2], GT_POSES[:4])
    with pytest.raises(InputError, match="duplicate stamps"):
        relations_error(dup, rel)
    with pytest.raises(EmptyInputError):
        relations_error(gt, Relations([], [], np.zeros((0, 6))))


def test_read_relations(tmp_path):
    p = tmp_path / "x.relations"
    p.write_text("# timestamp1 timestamp2 x y z roll pitch yaw\n\n1.5 2.5 0.1 0.2 0 0 0 0.3\n2.5 3.5 1 0 0 0 0 0\n")
    rel = read_relations(p)
    assert len(rel) == 2
    np.testing.assert_allclose(rel.poses[0], [0.1, 0.2, 0, 0, 0, 0.3])
    p.write_text("1.5 2.5 0.1 0.2 0 0 0 0.3\n2.5 3.5 1 0 0 0 0\n")
    with pytest.raises(DataFormatError, match=r"x\.relations:2: expected 8 values"):
        read_relations(p)
    p.write_text("1.5 2.5 0.1 0.2 0 0 zero 0.3\n")
    with pytest.raises(DataFormatError, match=r":1: not a number"):
        read_relations(p)


# -- the command ---------------------------------------------------------------------------------------------
def test_cli_evaluate_relations_and_trajectory(tmp_path, capsys):
    gt = Trajectory(np.arange(5.0), GT_POSES)
    write_tum(tmp_path / "est.tum", Trajectory(gt.stamps, compose(WORLD, GT_POSES)))
    (tmp_path / "r.relations").write_text("0 1 1.1 0 0 0 0 0\n2 4 2 0.3 0 0 0 0\n")
    assert main(["evaluate", "relations", str(tmp_path / "est.tum"), str(tmp_path / "r.relations")]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["translation_m"]["mean"] == pytest.approx(0.2, abs=1e-6)
    assert out["n_relations"] == 2

    write_tum(tmp_path / "gt.tum", gt)
    write_tum(tmp_path / "shifted.tum", Trajectory(gt.stamps, gt.poses + [1.0, 2.0, 0.0]))
    assert main(["evaluate", "trajectory", str(tmp_path / "shifted.tum"), str(tmp_path / "gt.tum")]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["ate"]["translation_part/none"]["rmse"] == pytest.approx(math.sqrt(5), abs=1e-6)
    assert out["ate"]["translation_part/se3"]["rmse"] == pytest.approx(0, abs=1e-6)
    assert out["pose_errors"]["max_abs_error"]["x_m"] == pytest.approx(0, abs=1e-6)
    assert out["rpe"]["translation_part/1f"]["max"] == pytest.approx(0, abs=1e-6)

    (tmp_path / "late.relations").write_text("100 101 1 0 0 0 0 0\n")
    assert main(["evaluate", "relations", str(tmp_path / "est.tum"), str(tmp_path / "late.relations")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("hsmap: error: 1 of 1 relations could not be matched")
    assert main(["evaluate", "trajectory", str(tmp_path / "est.tum"), str(tmp_path / "missing.tum")]) == 2
    assert "no such trajectory file" in capsys.readouterr().err


# statistics evo 1.38 printed for the trajectory pair below (evo's APE/RPE on the same TUM files)
EVO_REFERENCE = {
    ("ate", Alignment.NONE, PoseRelation.TRANSLATION): (1.1380077129108894, 1.1376804178414024, 1.1889304118739494),
    ("ate", Alignment.NONE, PoseRelation.ROTATION_ANGLE): (1.208611590283272, 1.1064523126691366, 2.305576962900579),
    ("ate", Alignment.SE3, PoseRelation.TRANSLATION): (0.03632990018733299, 0.03351047390788237, 0.07086763581436412),
    ("ate", Alignment.SE3, PoseRelation.ROTATION_ANGLE): (1.259827409975911, 1.163292444097608, 2.268872956525662),
    ("rpe", (1, DeltaUnit.FRAMES, False), PoseRelation.TRANSLATION): (0.0041600622304714015, 0.003803489708362372, 0.009789210273472597),
    ("rpe", (5, DeltaUnit.FRAMES, True), PoseRelation.ROTATION_ANGLE): (0.24589663719548974, 0.21441445706087248, 0.7625500776477452),
    ("rpe", (1.0, DeltaUnit.METERS, False), PoseRelation.TRANSLATION): (0.03435306323231619, 0.03103632885591152, 0.04731421567517824),
    ("rpe", (1.0, DeltaUnit.METERS, True), PoseRelation.ROTATION_ANGLE): (0.559952879162515, 0.5176439141630719, 1.1985310796085733),
}


def test_ate_rpe_match_evo(tmp_path):
    from hsmap.trajectory import read_tum

    rng = np.random.default_rng(3)
    n = 300
    t = np.arange(n) * 0.1
    yaw = np.cumsum(rng.normal(0, 0.05, n))
    x, y = np.cumsum(0.03 * np.cos(yaw)), np.cumsum(0.03 * np.sin(yaw))
    gt = np.column_stack([x, y, 0.01 * np.sin(t), 0.005 * np.sin(t / 2), 0.003 * np.cos(t / 3), yaw])
    est = gt + np.cumsum(rng.normal(0, [0.003, 0.003, 0.001, 0.0005, 0.0005, 0.002], (n, 6)), axis=0)
    est[:, :3] += [1.0, -0.5, 0.1]
    write_tum(tmp_path / "gt.tum", Trajectory(t, gt))
    write_tum(tmp_path / "est.tum", Trajectory(t, est))
    ref, est_t = read_tum(tmp_path / "gt.tum"), read_tum(tmp_path / "est.tum")
    for (kind, how, rel), expected in EVO_REFERENCE.items():
        if kind == "ate":
            s = ate(est_t, ref, alignment=how, relation=rel).statistics
        else:
            delta, unit, all_pairs = how
            s = rpe(est_t, ref, delta=delta, unit=unit, all_pairs=all_pairs, relation=rel).statistics
        np.testing.assert_allclose((s.rmse, s.mean, s.max), expected, rtol=1e-9, err_msg=f"{kind} {how} {rel}")
