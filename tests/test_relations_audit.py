"""benchmarks/relations_audit.py's check of a benchmark's relations by two independent sensors."""

import numpy as np
import pytest
from _benchmarks import benchmark_modules

from hsmap.datasets.relations import Relations
from hsmap.geometry import compose, relative
from hsmap.trajectory import Trajectory


@pytest.fixture(scope="module")
def audit():
    with benchmark_modules("relations_audit") as (mod,):
        yield mod


def test_relations_both_sensors_contradict_are_counted_and_only_they(audit):
    """A relation that two sensors agreeing with each other both miss by 3 deg is counted; one that only one sensor
    misses is not (that sensor erred), nor one both miss by less than the threshold; the audited trajectory's error
    is given with and without the counted ones."""
    stamps = np.arange(0.0, 100.0, 0.5)
    truth = np.column_stack([0.1 * stamps, np.sin(0.05 * stamps), 0.02 * stamps])
    ti, tj = stamps[:-10:5], stamps[10::5]
    n = len(ti)
    pi, pj = (truth[np.searchsorted(stamps, t)] for t in (ti, tj))
    rel = relative(pi, pj)
    rel[:3, 2] += np.deg2rad(3.0)  # three wrong relations, as both sensors will say
    rel[3:5, 2] += np.deg2rad(0.5)  # two slightly off: under the threshold
    poses6 = np.zeros((n, 6))
    poses6[:, [0, 1, 5]] = rel
    relations = Relations(ti, tj, poses6)
    odometry = Trajectory(stamps, truth.copy())
    bent = truth.copy()
    k = np.searchsorted(stamps, tj[6])  # the scans alone turn 4 deg wrong at relation 6's end, and stay so
    bent[k:] = compose(bent[k:], [0.0, 0.0, np.deg2rad(4.0)])
    scans = Trajectory(stamps, bent)
    audited = Trajectory(stamps, truth.copy())
    out = audit.contradicted_by_two_sensors("synthetic", audited, odometry, scans, relations, 1.0)
    assert out["contradicted_by_both"] == 3 and out["independent_relations_scored"] == n
    assert out["trajectory_without_them"]["n"] == n - 3
    assert out["trajectory_all"]["all_deg"] == pytest.approx((3 * 3.0 + 2 * 0.5) / n, rel=1e-6)
    assert out["trajectory_without_them"]["all_deg"] == pytest.approx(2 * 0.5 / (n - 3), rel=1e-6)
    with pytest.raises(SystemExit, match="no odometry"):
        audit.contradicted_by_two_sensors("synthetic", audited, None, scans, relations, 1.0)


def _out_and_back():
    """A robot with a 180 deg laser driving through two rooms and a corridor (+x), then 100 s later back along the
    same line (-x): the two ways see opposite sides of every obstacle, so two single scans barely overlap."""
    from hsmap.datasets.frames import Frame, LaserScan2D
    from hsmap.testing import office_segments, raycast_2d

    segs = office_segments()
    xs = np.arange(1.0, 14.0, 0.1)
    out = np.column_stack([xs, np.full_like(xs, 2.0), np.zeros_like(xs)])
    back = np.column_stack([xs[::-1], np.full_like(xs, 2.3), np.full_like(xs, np.pi)])
    truth = np.vstack([out, back])
    stamps = np.concatenate([0.5 * np.arange(len(xs)), 200.0 + 0.5 * np.arange(len(xs))])
    frames = []
    for k, (t, p) in enumerate(zip(stamps, truth, strict=True)):
        r, a = raycast_2d(segs, p, fov=np.pi, beams=181, max_range=8.0)
        frames.append(Frame(stamp=float(t), scan2d=LaserScan2D(r, a), index=k))
    return frames, stamps, truth, len(xs)


def test_maps_side_with_whichever_of_trajectory_and_relation_is_true(audit):
    """Long relations between the two ways: where the relations are shifted 0.5 m along the corridor and the
    trajectory is true, the maps align better at the trajectory; where the trajectory's way back is shifted and the
    relations are true, they align better at the relations; relations both meet are neither."""
    frames, stamps, truth, n = _out_and_back()
    i = np.arange(10, n - 10, 10)  # outward frames; the way back passes the same x at frame 2n - 1 - i
    j = 2 * n - 1 - i
    rel6 = np.zeros((len(i), 6))
    rel6[:, [0, 1, 5]] = relative(truth[i], truth[j])
    good = Relations(stamps[i], stamps[j], rel6)
    bad6 = rel6.copy()
    bad6[:, :2] += relative(truth[i], compose(truth[j], [0.5, 0.0, 0.0]))[:, :2] - rel6[:, :2]
    bad = Relations(stamps[i], stamps[j], bad6)
    true_traj = Trajectory(stamps, truth.copy())
    shifted = truth.copy()
    shifted[n:] = compose(shifted[n:], [0.5, 0.0, 0.0])
    wrong_traj = Trajectory(stamps, shifted)

    out = audit.maps_audit("synthetic", frames, true_traj, bad, 5.0, 60.0, 0.3, 0.2, 0.01)
    assert out["relations_scored"] == len(i) and out["missed_by_more_than_min_error"] == len(i)
    assert out["of_which_the_maps_align_better_at_the_trajectory"] == len(i)
    assert out["of_which_the_maps_align_better_at_the_relation"] == 0
    assert out["mean_translation_error_without_the_contradicted_m"] is None
    out = audit.maps_audit("synthetic", frames, wrong_traj, good, 5.0, 60.0, 0.3, 0.2, 0.01)
    assert out["of_which_the_maps_align_better_at_the_relation"] == len(i)
    assert out["of_which_the_maps_align_better_at_the_trajectory"] == 0
    assert out["mean_translation_error_without_the_contradicted_m"] == pytest.approx(0.5)
    out = audit.maps_audit("synthetic", frames, true_traj, good, 5.0, 60.0, 0.3, 0.2, 0.01)
    assert out["missed_by_more_than_min_error"] == 0 and out["mean_translation_error_m"] < 1e-6
    with pytest.raises(SystemExit, match="--maps-window must be positive and under half of --maps-min-dt"):
        audit.maps_audit("synthetic", frames, true_traj, good, 30.0, 60.0, 0.3, 0.2, 0.01)


def test_relations_copied_from_the_odometry_are_counted_and_the_sources_paired(audit):
    """Relations that are the odometry's relative pose to the last millimetre are counted, relations a sensor merely
    agrees with are not; the pairwise errors and the blend say which source the relations follow."""
    rng = np.random.default_rng(3)
    stamps = np.arange(0.0, 200.0, 0.5)
    truth = np.column_stack([0.3 * stamps, 2.0 * np.sin(0.02 * stamps), 0.04 * stamps])
    odo = truth + rng.normal(0.0, [0.02, 0.02, 0.004], truth.shape)  # each pose off by 2 cm / 0.2 deg
    est = truth + rng.normal(0.0, [0.02, 0.02, 0.004], truth.shape)
    ti, tj = stamps[:-6:3], stamps[6::3]  # 3 s apart
    k = np.searchsorted(stamps, ti), np.searchsorted(stamps, tj)
    rel = relative(truth[k[0]], truth[k[1]])
    rel[:20] = relative(odo[k[0][:20]], odo[k[1][:20]])  # 20 copied from the odometry
    rel[20:30] = relative(odo[k[0][20:30]], odo[k[1][20:30]]) + [0.004, 0.0, 0.0]  # near it, not a copy
    poses = np.zeros((len(ti), 6))
    poses[:, [0, 1, 5]] = rel
    relations = Relations(ti, tj, poses)
    out = audit.odometry_copies("synthetic", Trajectory(stamps, est), Trajectory(stamps, odo), relations)
    assert out["odometry_copies"] == 20 and out["odometry_copies_short"] == 20
    # the rotation alone: the 20 copies and the 10 near them (their heading is the odometry's); of the others,
    # 0.3 deg apart by their noise, few fall within 0.02 deg by chance
    assert 30 <= out["odometry_rotation_copies"] <= 33
    assert out["short_relations"] == len(ti) and out["relations_scored"] == len(ti)
    pairs = out["short_pairs_mean_m_deg"]
    # mostly the truth: the trajectory and the odometry each miss it by their own noise, and each other by both
    assert pairs["odometry_trajectory"][0] > max(pairs["relations_odometry"][0], pairs["relations_trajectory"][0])
    blend = out["short_blend_with_odometry_m_deg"]
    assert blend["0.0"] == pytest.approx(pairs["relations_trajectory"])
    assert blend["1.0"] == pytest.approx(pairs["relations_odometry"])
    assert blend["0.5"][0] < min(blend["0.0"][0], blend["1.0"][0])  # two independent estimates: the mean is better
    with pytest.raises(SystemExit, match="no odometry"):
        audit.odometry_copies("synthetic", Trajectory(stamps, est), None, relations)
