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


# -- the 3D peers on real sweeps (benchmarks/peers3d.py, hsmap.study.real_sweeps, hsmap.study.peers3d) -------------
def _route(n=40, seed=3):
    """A 6-DOF route: a smooth walk with turns and a little roll and pitch, one pose a second."""
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, 1.0, n)
    poses = np.column_stack([8 * np.cos(3 * s), 5 * np.sin(4 * s), 0.2 * s, 0.05 * np.sin(9 * s),
                             0.04 * np.cos(7 * s), 3 * s]) + rng.normal(0, 1e-3, (n, 6))
    from hsmap.trajectory import Trajectory

    return Trajectory(1630577758.5 + 0.5 * np.arange(n), poses)


def _moved(traj, pose):
    """``traj`` with every pose seen from another world frame (``pose`` of it in the reference's)."""
    from hsmap.geometry import matrix_to_pose, pose_to_matrix
    from hsmap.trajectory import Trajectory

    return Trajectory(traj.stamps, matrix_to_pose(pose_to_matrix(pose) @ pose_to_matrix(traj.poses)))


def test_scoring_a_moved_copy_of_the_reference_is_exact():
    from hsmap.study.real_sweeps import score_track

    ref = _route()
    s = score_track(_moved(ref, np.array([3.0, -2.0, 0.5, 0.1, -0.2, 1.0])), ref).summary
    assert s["ate_rmse_m"] < 1e-9 and s["ate_rotation_max_deg"] < 1e-6
    assert max(s["max_abs_error"].values()) < 1e-6 and max(s["max_abs_error_from_start"].values()) < 1e-6
    assert s["lost_track_from_sweep"] is None and s["poses"] == s["reference_sweeps"] == len(ref)


def test_scoring_finds_the_sweep_where_a_track_is_lost_and_its_jump():
    from hsmap.study.real_sweeps import score_track
    from hsmap.trajectory import Trajectory

    ref = _route()
    est = ref.poses.copy()
    est[25:, 1] += 1.5  # a 1.5 m jump from sweep 25 on
    est[12:, 5] += np.radians(2.0)  # 2 deg of yaw from sweep 12 on, about the first sweep's origin
    s = score_track(Trajectory(ref.stamps, est), ref).summary
    assert s["lost_track_from_sweep"] == 25
    assert s["worst_step"]["translation_at_sweep"] == 25 and s["worst_step"]["translation_m"] > 1.4
    assert s["worst_step"]["rotation_at_sweep"] == 12 and s["worst_step"]["rotation_deg"] == pytest.approx(2.0, abs=0.01)
    assert s["max_abs_error_from_start"]["yaw_deg"] == pytest.approx(2.0, abs=0.05)
    assert 0.3 < s["ate_rmse_m"] < 1.5 and s["ate_max_m"] >= s["ate_rmse_m"]


def test_scoring_takes_an_estimate_of_some_sweeps_and_names_them():
    from hsmap.study.real_sweeps import score_track
    from hsmap.trajectory import Trajectory

    ref = _route()
    part = Trajectory(ref.stamps[10:30], ref.poses[10:30])
    s = score_track(part, ref)
    assert list(s.sweeps) == list(range(10, 30)) and s.summary["poses"] == 20
    from hsmap.errors import InputError

    with pytest.raises(InputError, match="no reference stamp"):
        score_track(Trajectory(ref.stamps + 0.25, ref.poses), ref)


def _balm_like(folder, n=12):
    """A folder laid out as BALM's: fullN.pcd (tiny clouds) and alidarPose.csv with the stamps in the last cell."""
    from hsmap.geometry import pose_to_matrix

    ref = _route(n)
    folder.mkdir()
    for i in range(n):
        pts = np.random.default_rng(i).normal(0, 3, (20, 3)).astype(np.float32)
        head = (f"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH {len(pts)}\nHEIGHT 1\n"
                f"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(pts)}\nDATA ascii\n")
        (folder / f"full{i}.pcd").write_text(head + "".join(f"{x} {y} {z}\n" for x, y, z in pts))
    M = pose_to_matrix(ref.poses)
    M[:, 3, 3] = ref.stamps
    (folder / "alidarPose.csv").write_text("".join(",".join(f"{v:.6f}" for v in row) + ",\n"
                                                   for m in M for row in m))
    return ref


def test_sweeps_are_taken_in_natural_order_with_the_reference_stamps(tmp_path):
    from hsmap.study import real_sweeps as rs

    ref = _balm_like(tmp_path / "balm")
    files = rs.sweep_files(tmp_path / "balm")
    assert [f.name for f in files][:3] == ["full0.pcd", "full1.pcd", "full2.pcd"] and files[10].name == "full10.pcd"
    back = rs.read_reference(tmp_path / "balm")
    np.testing.assert_allclose(back.stamps, ref.stamps, atol=1e-6)
    np.testing.assert_allclose(back.poses, ref.poses, atol=1e-5)
    assert rs.balm_folder(tmp_path) == tmp_path / "balm"
    folder = rs.sweep_folder(tmp_path / "balm", tmp_path / "sweeps", max_sweeps=11)
    frames = list(rs.open_sweeps(folder).frames(clouds=True))
    assert len(frames) == 11
    np.testing.assert_allclose([f.stamp for f in frames], ref.stamps[:11], atol=1e-6)
    from hsmap.datasets.clouds import read_points

    np.testing.assert_allclose(frames[10].cloud3d, read_points(files[10]))


def test_a_damaged_pose_file_is_refused_naming_the_line(tmp_path):
    from hsmap.errors import DataFormatError
    from hsmap.study import real_sweeps as rs

    _balm_like(tmp_path / "balm", n=3)
    p = tmp_path / "balm" / "alidarPose.csv"
    lines = p.read_text().splitlines()
    lines[5] = "1,2,x,4,"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataFormatError, match=r"alidarPose.csv:6: expected 4 comma-separated numbers"):
        rs.read_reference(tmp_path / "balm")
    p.write_text("\n".join(lines[:4] + lines[6:9]) + "\n")
    with pytest.raises(DataFormatError, match="not a whole number of 4x4 poses"):
        rs.read_reference(tmp_path / "balm")
    assert rs.balm_folder(tmp_path / "nowhere") is None


def test_a_missing_3d_peer_is_reported_not_dropped(monkeypatch):
    with benchmark_modules("peers3d") as (p3,):
        monkeypatch.setitem(sys.modules, "small_gicp", None)  # as if not installed
        r = p3.guarded(p3.run_peer_entry, "small_gicp", "defaults", [np.zeros((5, 3))], np.zeros(1), _route())
        assert r["status"] == "not installed" and "small_gicp" in r["reason"]
        out = {"runs": {"small_gicp": {"defaults": r}}}
        assert "| small_gicp | defaults | not installed: " in p3.table(out)


def test_seed_summary_gives_mean_spread_and_worst():
    with benchmark_modules("peers3d") as (p3,):
        rows = {f"seed{i}": {"status": "ok", "ate_rmse_m": a, "ate_max_m": 2 * a, "cpu_per_sweep_mean_s": 1.0,
                             "wall_per_sweep_median_s": 1.0, "lost_track_from_sweep": lost}
                for i, (a, lost) in enumerate([(0.1, None), (0.3, 40), (0.2, 7)])}
        rows["seed9"] = {"status": "failed", "reason": "x"}
        s = p3.seed_summary(rows)
        assert s["seeds_ok"] == 3 and s["seeds"] == 4
        assert s["ate_rmse_m"] == pytest.approx({"mean": 0.2, "spread": 0.2, "worst": 0.3})
        assert s["lost_track_runs"] == 2 and s["lost_track_earliest_sweep"] == 7


@pytest.fixture
def balm():
    from hsmap.study.real_sweeps import balm_folder, missing_balm_reason

    folder = balm_folder()
    if folder is None:
        pytest.skip(missing_balm_reason())
    return folder


def test_the_first_real_sweeps_are_scored_within_centimetres_by_a_peer(balm, tmp_path):
    pytest.importorskip("small_gicp")
    from hsmap.geometry import matrix_to_pose
    from hsmap.study.peers3d import run_peer
    from hsmap.study.real_sweeps import open_sweeps, read_reference, score_track, sweep_folder
    from hsmap.trajectory import Trajectory

    frames = list(open_sweeps(sweep_folder(balm, tmp_path / "s", max_sweeps=5)).frames(clouds=True))
    r = run_peer("small_gicp", "defaults", [f.cloud3d for f in frames])
    s = score_track(Trajectory([f.stamp for f in frames], matrix_to_pose(r.poses)), read_reference(balm)).summary
    assert s["poses"] == 5 and s["reference_sweeps"] == 177
    assert s["ate_rmse_m"] < 0.02 and s["lost_track_from_sweep"] is None
    assert r.timing()["cpu_per_sweep_mean_s"] > 0


def test_repeated_runs_report_the_median_run_and_every_time(bench):
    _, peers = bench
    runs = [{"status": "ok", "wall_seconds": w, "cpu_seconds": w / 2, "relations": k} for k, w in
            enumerate([9.0, 3.0, 5.0, 7.0])]
    mid = peers._median_run(runs)
    assert mid["relations"] == 2 and mid["wall_seconds"] == 5.0  # the lower middle of an even count
    assert mid["runs_wall_seconds"] == [9.0, 3.0, 5.0, 7.0] and mid["wall_seconds_median"] == 6.0
    assert peers._median_run(runs[:1]) == runs[0]
    failed = {"status": "failed", "reason": "boom"}
    assert peers._median_run([runs[0], failed]) == failed
