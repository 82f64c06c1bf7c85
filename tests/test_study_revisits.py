"""hsmap.study.revisits: revisit pairs registered directly side with the trajectory whose sweeps line up, and
measure a drifting trajectory's drift."""

from __future__ import annotations

import numpy as np
import pytest

from hsmap.errors import InputError
from hsmap.geometry import invert_matrix, pose_to_matrix, transform_points
from hsmap.study.revisits import register_revisits, revisit_agreement, revisit_pairs
from hsmap.trajectory import Trajectory

pytest.importorskip("small_gicp", reason="small_gicp (the peers extra) registers the revisits")


def _room(rng, n=40000):
    """Points on a 16 x 10 x 4 m room's floor, ceiling and walls, with two pillars and a shelf (so that every
    direction is constrained), sampled at random."""
    boxes = [((-8, -5, 0), (8, 5, 4)), ((-3, -1, 0), (-2, 0, 4)), ((3, 1, 0), (4, 3, 4)), ((-6, 3, 0), (-1, 5, 1.2))]
    pts = []
    for lo, hi in boxes:
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        for axis in range(3):
            for side in (lo[axis], hi[axis]):
                p = lo + rng.random((n // 24, 3)) * (hi - lo)
                p[:, axis] = side
                pts.append(p)
    return np.vstack(pts)


def _walk(n=24):
    """A loop around the room, 1.5 m up, turning and tilting as a hand-held sensor does."""
    s = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.column_stack([5.5 * np.cos(s), 3.0 * np.sin(s), np.full(n, 1.5), 0.05 * np.sin(3 * s),
                            0.04 * np.cos(2 * s), s + 0.3])


def _load(world_rng_seed, truth):
    """Each sweep: a fresh random sample of the room in the sensor's frame (no two sweeps share a point)."""
    T = pose_to_matrix(truth)

    def load(k):
        rng = np.random.default_rng(world_rng_seed + k)
        pts = _room(rng)
        local = transform_points(invert_matrix(T[k]), pts)
        return local + rng.normal(0, 0.005, local.shape)
    return load


def test_revisit_pairs_keeps_distant_sweeps_that_come_back_near():
    pos = np.zeros((10, 6))
    pos[:, 0] = [0, 1, 2, 3, 4, 4, 3, 2, 1, 0]
    pairs = revisit_pairs(Trajectory(np.arange(10.0), pos), min_gap=5, max_distance=1.5, every=1)
    assert pairs.tolist() == [[0, 8], [0, 9], [1, 7], [1, 8], [1, 9], [2, 7], [2, 8]]


def test_revisit_pairs_rejects_a_gap_below_one():
    with pytest.raises(InputError, match="min_gap"):
        revisit_pairs(np.tile(np.eye(4), (3, 1, 1)), min_gap=0)


def test_direct_registrations_side_with_the_trajectory_that_does_not_drift():
    truth = _walk()
    drifted = truth.copy()
    drifted[:, 0] += 0.01 * np.arange(len(truth))  # 1 cm a sweep along x in the world
    drifted[:, 5] += np.deg2rad(0.02) * np.arange(len(truth))
    pairs = revisit_pairs(truth, min_gap=8, max_distance=6.0, every=2)
    assert len(pairs) >= 4
    revisits = register_revisits(_load(7, truth), pairs, [drifted, truth])
    assert revisits.settled.all()
    good = revisit_agreement(truth, revisits)
    bad = revisit_agreement(drifted, revisits)
    assert good["pairs"] == len(pairs)
    assert good["translation_max_m"] < 0.01 and good["rotation_max_deg"] < 0.1
    # the drift between the pairs' sweeps: at least 8 sweeps of 1 cm
    assert bad["translation_mean_m"] > 0.07
    assert bad["translation_mean_m"] > 10 * good["translation_mean_m"]


def test_register_revisits_names_pairs_beyond_the_trajectory():
    with pytest.raises(InputError, match="expected 0..2"):
        register_revisits(lambda k: np.zeros((10, 3)), np.array([[0, 5]]), [np.tile(np.eye(4), (3, 1, 1))])


def test_the_corrected_reference_takes_the_drift_out():
    from hsmap.study.real_sweeps import score_track
    from hsmap.study.revisits import corrected_reference

    truth = _walk()
    drifted = truth.copy()
    drifted[:, 0] += 0.01 * np.arange(len(truth))
    drifted[:, 5] += np.deg2rad(0.02) * np.arange(len(truth))
    stamps = np.arange(len(truth), dtype=float)
    pairs = revisit_pairs(truth, min_gap=8, max_distance=6.0, every=2)
    revisits = register_revisits(_load(7, truth), pairs, [drifted])
    fixed = corrected_reference(Trajectory(stamps, drifted), revisits)
    true = Trajectory(stamps, truth)
    before = score_track(Trajectory(stamps, drifted), true).summary["ate_rmse_m"]
    after = score_track(fixed, true).summary["ate_rmse_m"]
    assert before > 0.03
    assert after < 0.25 * before, (before, after)
