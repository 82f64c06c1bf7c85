"""The helper process (hsmap._helper_process) and the smoothing's scan matches made there (hsmap.slam.motions)."""

import math
import time

import numpy as np
import pytest
from test_slam import make_frames

from hsmap import _helper_process as hp
from hsmap._helper_process import HelperProcess, HelperProcessError, helper_cpu_seconds, helper_process
from hsmap.slam import SlamConfig, run_slam
from hsmap.slam import motions as motions_module
from hsmap.slam.costs import Costs
from hsmap.slam.motions import FrameMotions
from hsmap.slam.odometry import OdometryModel


@pytest.fixture
def helper():
    h = HelperProcess()
    yield h
    h.close()


def test_calls_are_answered_in_order(helper):
    futures = [helper.submit(math.hypot, 3.0, float(i)) for i in range(20)]
    assert [f.result(timeout=60) for f in futures] == [math.hypot(3.0, float(i)) for i in range(20)]
    big = np.arange(3_000_000, dtype=float)  # larger than a pipe's buffer
    assert helper.submit(np.sum, big).result(timeout=60) == np.sum(big)


def test_a_call_that_raises_fails_alone(helper):
    bad = helper.submit(math.sqrt, -1.0)
    with pytest.raises(HelperProcessError, match="math.sqrt raised ValueError"):
        bad.result(timeout=60)
    assert helper.submit(math.sqrt, 4.0).result(timeout=60) == 2.0
    unsendable = helper.submit(__import__("importlib").import_module, "math")  # a module cannot be pickled
    with pytest.raises(HelperProcessError, match="cannot be sent back"):
        unsendable.result(timeout=60)
    assert helper.alive and helper.submit(math.sqrt, 9.0).result(timeout=60) == 3.0


def test_a_dead_helper_fails_its_calls_and_is_replaced(monkeypatch):
    first = helper_process()
    assert first is not None and first.submit(math.sqrt, 9.0).result(timeout=60) == 3.0
    first._proc.kill()
    first._proc.wait()
    with pytest.raises(HelperProcessError, match="stopped"):
        first.submit(math.sqrt, 4.0).result(timeout=60)
    second = helper_process()
    assert second is not first and second.submit(math.sqrt, 16.0).result(timeout=60) == 4.0
    monkeypatch.setattr(hp, "_starts", hp.MAX_STARTS)  # as many died as may: no more are started
    second.close()
    assert helper_process() is None
    monkeypatch.setattr(hp, "_starts", 0)
    assert helper_process() is not None


def test_the_helper_reports_its_cpu_time():
    h = helper_process()
    before = helper_cpu_seconds()
    h.submit(time.sleep, 0.0).result(timeout=60)
    spin = np.random.default_rng(0).normal(size=(300, 300))
    for _ in range(3):
        h.submit(np.linalg.eigvalsh, spin).result(timeout=60)
    assert helper_cpu_seconds() > before


def test_the_peak_memory_counts_the_helper_s():
    own = hp._own_peak_memory_mb()
    h = helper_process()
    assert h is not None and h.submit(math.sqrt, 1.0).result(timeout=60) == 1.0
    helper_peak = h.submit(hp._own_peak_memory_mb).result(timeout=60)
    assert helper_peak > 1.0  # a Python with NumPy
    assert hp.peak_memory_mb() >= own + helper_peak - 1e-9


def _motions(frames, helper):
    """FrameMotions fed from a 2D run's own tracking, with or without the helper process."""
    res = run_slam(frames, SlamConfig(), rng=1, progress=False, threads=1)
    cfg = res.config
    fm = FrameMotions(cfg, OdometryModel(cfg, learn=False, wheel_edges=False), Costs(), helper=helper)
    from hsmap.slam.frames import frame_points

    poses = res.trajectory.poses
    for k, f in enumerate(frames):
        scan = frame_points(f, 3, cfg.min_range, cfg.max_range, voxel=cfg.effective_scan_voxel())
        fm.record(f, scan, poses[max(k - 1, 0)], poses[k])
        fm.odometry.advance(f)
    return fm


def test_scan_matches_are_the_same_in_the_helper_and_inline(monkeypatch):
    monkeypatch.setattr(motions_module, "BATCH_FRAMES", 16)  # several batches, one partly filled
    frames = make_frames(odometry_drift=np.deg2rad(2.0))[:70]
    inline, helped = _motions(frames, helper=False), _motions(frames, helper=True)
    assert helped._helper is not None and inline._helper is None
    a, b = inline.arrays(), helped.arrays()
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    assert a[2].shape == (70, 3) and np.isfinite(a[2][1:]).all() and np.isnan(a[2][0]).all()


def test_scan_matches_are_made_here_when_the_helper_fails(monkeypatch):
    monkeypatch.setattr(motions_module, "BATCH_FRAMES", 16)
    frames = make_frames(odometry_drift=np.deg2rad(2.0))[:40]
    expected = _motions(frames, helper=False).arrays()[2]
    gone = HelperProcess()
    gone.close()  # every call it is given fails
    monkeypatch.setattr(motions_module, "helper_process", lambda: gone)
    fm = _motions(frames, helper=True)
    assert fm._helper is gone and any(isinstance(b, tuple) for b in fm._batches)
    np.testing.assert_array_equal(fm.arrays()[2], expected)
