"""benchmarks/motion_filter.py: which scans a motion filter registers, and how the others are placed."""

import numpy as np
import pytest
from _benchmarks import benchmark_modules

from hsmap.geometry import compose


@pytest.fixture(scope="module")
def mf():
    with benchmark_modules("motion_filter") as (mod,):
        yield mod


def test_registered_after_distance_or_angle(mf):
    """Straight at 3 cm a scan, then turning in place at 2 deg a scan: every fourth scan at 0.1 m, every third
    in the turn at 5 deg (the first turn counted from the last scan kept on the straight); the first scan always."""
    straight = np.column_stack([0.03 * np.arange(10), np.zeros(10), np.zeros(10)])
    turn = np.column_stack([np.full(9, 0.27), np.zeros(9), np.deg2rad(2.0) * np.arange(1, 10)])
    keep = mf.registered(np.vstack([straight, turn]), 0.1, 5.0)
    assert keep.tolist() == [0, 4, 8, 12, 15, 18]
    assert mf.registered(np.vstack([straight, turn[:-1]]), 0.1, 5.0).tolist() == [0, 4, 8, 12, 15, 17]  # the last


def test_bridged_keeps_the_registered_and_spreads_the_correction(mf):
    """The kept poses stay; between two, the odometry's motion carried from the first, moved linearly to meet the
    second: odometry that is the truth scaled by 1.1 leaves the bridged poses on the true path, closer to it than
    the odometry's own placing."""
    n = 21
    truth = np.column_stack([0.05 * np.arange(n), 0.01 * np.arange(n) ** 1.5, np.deg2rad(0.5) * np.arange(n)])
    odometry = truth.copy()
    odometry[:, :2] *= 1.1
    keep = np.array([0, 10, 20])
    out = mf.bridged(truth, odometry, keep)
    np.testing.assert_array_equal(out[keep], truth[keep])
    err_bridged = np.abs(out - truth)[:, :2].max()
    # the odometry alone from the last kept scan
    carried = np.array([compose(truth[0], mf.relative(odometry[0], odometry[k])) for k in range(1, 10)])
    err_carried = np.abs(carried - truth[1:10])[:, :2].max()
    assert err_bridged < 0.3 * err_carried
    assert err_bridged < 0.01


def test_bridged_with_every_scan_kept_is_the_input(mf):
    poses = np.random.default_rng(0).normal(size=(12, 3))
    np.testing.assert_array_equal(mf.bridged(poses, poses[::-1].copy(), np.arange(12)), poses)
