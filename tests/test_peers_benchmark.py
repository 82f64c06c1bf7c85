"""benchmarks/rawlog.py (MRPT rawlogs from hsmap frames) and benchmarks/peers.py's report of peers that cannot run."""

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from _benchmarks import benchmark_modules

from hsmap.datasets.frames import Frame, LaserScan2D
from hsmap.geometry import relative


@pytest.fixture(scope="module")
def bench():
    with benchmark_modules("rawlog", "peers") as mods:
        yield mods


def _frames(n=4, beams=37, seed=0):
    """Frames a second apart (stamps not on a grid), an off-centre 180 deg fan, some beams without return."""
    rng = np.random.default_rng(seed)
    angles = np.linspace(-np.pi / 2, np.pi / 2, beams) - np.radians(0.25)
    out = []
    for i in range(n):
        r = rng.uniform(0.5, 25.0, beams)
        r[rng.choice(beams, 3, replace=False)] = np.nan
        out.append(Frame(stamp=1216.0 + i + 0.123456 * (i + 1), scan2d=LaserScan2D(r, angles, 0.1, 30.0),
                         odometry=np.array([0.3 * i, -0.1 * i * i, 0.2 * i - 3.0]), index=i,
                         extrinsic2d=np.array([-0.04, 0.01, 0.0])))
    return out


@pytest.mark.parametrize("actions", [False, True])
def test_rawlog_round_trip_keeps_each_stamp_ranges_and_odometry(bench, tmp_path, actions):
    rawlog, _ = bench
    frames = _frames()
    path = tmp_path / "t.rawlog"
    entries = rawlog.write_rawlog(frames, path, actions=actions)
    back = rawlog.read_rawlog(path)
    assert [o.kind for o in back] == [k for k, _ in entries]
    np.testing.assert_allclose([o.stamp for o in back], [t for _, t in entries], atol=1e-6)
    scans = [o for o in back if o.kind == "scan"]
    assert len(scans) == len(frames)
    for f, o in zip(frames, scans, strict=True):
        assert o.stamp == pytest.approx(f.stamp, abs=1e-6)  # its own stamp, to MRPT's 100 ns
        nan = np.isnan(f.scan2d.ranges)
        np.testing.assert_array_equal(np.isnan(o.ranges), nan)
        np.testing.assert_allclose(o.ranges[~nan], f.scan2d.ranges[~nan], rtol=1e-6)
        # the fan's centre goes into the sensor pose; beam angles about it add up to the frame's
        np.testing.assert_allclose(o.angles + o.sensor_pose[2], f.scan2d.angles, atol=1e-6)
        np.testing.assert_allclose(o.sensor_pose[:2], f.extrinsic2d[:2])
    if actions:
        acts = [o for o in back if o.kind == "action"]
        np.testing.assert_allclose(acts[0].pose, 0.0)
        for a, b, o in zip(frames[:-1], frames[1:], acts[1:], strict=True):
            np.testing.assert_allclose(o.pose, relative(a.odometry, b.odometry), atol=1e-12)
            assert o.stamp == pytest.approx(b.stamp, abs=1e-6)
    else:
        odo = [o for o in back if o.kind == "odometry"]
        for f, o in zip(frames, odo, strict=True):
            np.testing.assert_allclose(o.pose, f.odometry)
            assert o.stamp == pytest.approx(f.stamp, abs=1e-6)
    assert len({o.stamp for o in scans}) == len(frames)


@pytest.mark.skipif(shutil.which("rawlog-edit") is None, reason="MRPT's rawlog-edit is not installed (mrpt-apps)")
def test_mrpt_reads_the_rawlog_with_each_stamp(bench, tmp_path):
    rawlog, _ = bench
    frames = _frames()
    path = tmp_path / "t.rawlog"
    rawlog.write_rawlog(frames, path)
    subprocess.run(["rawlog-edit", "--list-timestamps", "-i", str(path), "--text-file-output",
                    str(tmp_path / "ts.txt")], check=True, capture_output=True, cwd=tmp_path)
    rows = [ln.split() for ln in (tmp_path / "ts.txt").read_text().splitlines() if ln.strip()]
    assert [r[1] for r in rows] == ["ODOMETRY", "LASER"] * len(frames)
    np.testing.assert_allclose([float(r[0]) for r in rows[1::2]], [f.stamp for f in frames], atol=1e-5)


def test_rawlog_rejects_uneven_beams(bench, tmp_path):
    rawlog, _ = bench
    f = _frames(1)[0]
    f.scan2d.angles = f.scan2d.angles ** 3
    from hsmap.errors import DataFormatError

    with pytest.raises(DataFormatError, match="evenly spaced"):
        rawlog.write_rawlog([f], tmp_path / "t.rawlog")


def test_a_missing_peer_is_reported_not_dropped(bench, tmp_path, monkeypatch):
    _, peers = bench
    monkeypatch.setitem(peers.MRPT, "icp_slam", {**peers.MRPT["icp_slam"], "exe": "no-such-mrpt-app"})
    r = peers.guarded(peers.run_mrpt, "icp_slam", _frames(), 10.0, tmp_path)
    assert r["status"] == "not installed" and "no-such-mrpt-app" in r["reason"]
    monkeypatch.setitem(sys.modules, "yag_slam", None)  # as if not installed
    r = peers.guarded(peers.run_yag_slam, _frames())
    assert r["status"] == "not installed" and "yag_slam" in r["reason"]

    def broken():
        raise RuntimeError("segmentation fault\nmore")

    assert peers.guarded(broken) == {"status": "failed", "reason": "RuntimeError: segmentation fault"}


def test_mrpt_config_changes_only_the_named_settings(bench, tmp_path):
    _, peers = bench
    stock = tmp_path / "stock.ini"
    stock.write_text("[ICP]\nrawlog_file=keep\n[MappingApplication]\n// c\nrawlog_file=/x.rawlog\nLOG_FREQUENCY=10\n"
                     "insertionLinDistance=1.2\n")
    text = peers.mrpt_config(stock, Path("/in.rawlog"), Path("/out"), {"LOG_FREQUENCY": "0", "SAVE_3D_SCENE": "0"})
    lines = text.splitlines()
    assert "rawlog_file=keep" in lines and "rawlog_file=/in.rawlog" in lines and "logOutput_dir=/out" in lines
    assert "LOG_FREQUENCY=0" in lines and "SAVE_3D_SCENE=0" in lines and "insertionLinDistance=1.2" in lines
