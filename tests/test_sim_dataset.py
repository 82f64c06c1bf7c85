"""``hsmap simulate`` folders: what is written, that it reads back, that a seed reproduces it byte for byte."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from hsmap.datasets import Frame
from hsmap.datasets.simulated import SimulatedDataset, is_simulated_dataset
from hsmap.errors import DatasetError
from hsmap.geometry import pose_to_matrix, transform_points
from hsmap.sim import Lidar3DConfig, load_scenario, simulate
from hsmap.sim.catalog import resolve_scenario
from hsmap.trajectory import read_tum

pytest.importorskip("open3d")

SMALL_3D = Lidar3DConfig(channels=32, columns=256)
N = 8


def small_two_rooms():
    scn = load_scenario(resolve_scenario("two-rooms"))
    return scn.replace(lidar3d=SMALL_3D)


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim") / "two-rooms"
    summary = simulate(small_two_rooms(), out, seed=7, max_frames=N)
    return out, summary


def tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_folder_contents(written):
    out, summary = written
    names = set(tree(out))
    expected = {"dataset.yaml", "scans2d.npz", "groundtruth.tum", "odometry.tum", "rooms.png", "rooms.yaml",
                "doors.json", "scenario.yaml", "README.md"} | {f"clouds3d/{k:06d}.npz" for k in range(N)}
    assert names == expected
    meta = yaml.safe_load((out / "dataset.yaml").read_text())
    assert meta["format"] == "hsmap-simulated-dataset" and meta["format_version"] == 1
    assert meta["scenario"] == "two-rooms" and meta["seed"] == 7 and meta["frames"] == N
    assert meta["frame_rate"] == 2.0
    l2, l3 = meta["sensors"]["lidar2d"], meta["sensors"]["lidar3d"]
    assert l2["beams"] == 1081 and l2["angle_increment"] == pytest.approx(np.deg2rad(0.25))
    assert l2["range_max"] == 10.0 and l2["noise_sigma"] == 0.01 and l2["mount_height"] == 0.2
    assert len(l2["extrinsic"]) == 3
    assert l3["channels"] == 32 and l3["columns"] == 256 and len(l3["vertical_angles_deg"]) == 32
    assert l3["range_max"] == 50.0 and len(l3["extrinsic"]) == 6 and l3["extrinsic"][2] == 1.6
    assert set(meta["files"]) >= {"scans2d.npz", "clouds3d/", "groundtruth.tum", "odometry.tum", "rooms.png"}
    assert summary.frames == N and is_simulated_dataset(out)
    with np.load(out / "scans2d.npz") as z:
        assert z["stamps"].dtype == np.float64 and z["stamps"].shape == (N,)
        assert z["ranges"].dtype == np.float32 and z["ranges"].shape == (N, 1081)
        assert z["angles"].shape == (1081,) and "beam_time" not in z.files  # scans taken at their stamps
    with np.load(out / "clouds3d/000003.npz") as z:
        assert z["range_mm"].dtype == np.uint16 and z["range_mm"].shape == (32, 256)
    gt, odo = read_tum(out / "groundtruth.tum", 3), read_tum(out / "odometry.tum", 3)
    with np.load(out / "scans2d.npz") as z:
        np.testing.assert_allclose(gt.stamps, z["stamps"], atol=1e-9)
        np.testing.assert_allclose(odo.stamps, z["stamps"], atol=1e-9)
    np.testing.assert_allclose(odo.poses[0], gt.poses[0], atol=1e-9)  # odometry starts at the first pose
    doors = json.loads((out / "doors.json").read_text())["doors"]
    assert [d["name"] for d in doors] == ["door-a", "door-b"]
    assert "two-rooms" in (out / "README.md").read_text()


def test_reader_yields_frames_consistent_with_the_world(written):
    out, _ = written
    ds = SimulatedDataset(out)
    assert len(ds) == N and ds.name == "two-rooms"
    frames = list(ds.frames())
    assert len(frames) == N and all(isinstance(f, Frame) for f in frames)
    f = frames[5]
    assert f.index == 5 and f.stamp == pytest.approx(2.5)
    np.testing.assert_allclose(f.odometry, ds.odometry.poses[5])
    np.testing.assert_allclose(f.extrinsic2d, [0.15, 0.0, 0.0])
    np.testing.assert_allclose(f.extrinsic3d, [-0.10, 0.0, 1.6, 0, 0, 0])
    assert f.scan2d.ranges.shape == (1081,) and f.scan2d.range_max == 10.0
    assert f.cloud3d.ndim == 2 and f.cloud3d.shape[1] == 3 and 0.8 * 32 * 256 < len(f.cloud3d) <= 32 * 256
    # the 3D points, moved to the world with the ground-truth pose, lie on walls, floor, ceiling or furniture
    from hsmap.sim.world import World, sensor_poses_3d

    scn = small_two_rooms()
    world = World(scn)
    T = sensor_poses_3d(ds.groundtruth.poses[5:6], scn.lidar3d)[0]
    pw = transform_points(T, f.cloud3d)
    back = pw - T[:3, 3]
    dist = np.linalg.norm(back, axis=1)
    t_hit = world.cast(np.broadcast_to(T[:3, 3], back.shape), back / dist[:, None])
    assert np.percentile(np.abs(t_hit - dist), 99) < 0.04
    assert np.all(pw[:, 2] > -0.05) and np.all(pw[:, 2] < scn.ceiling_height + 0.05)
    # the 2D scan at the ground-truth pose: exactly what a fresh ray cast sees, up to the 1 cm noise
    scan_w = transform_points(pose_to_matrix(ds.groundtruth.poses[5]) @ pose_to_matrix(f.extrinsic2d),
                              f.scan2d.points())
    fresh = world.scan2d(ds.groundtruth.poses[5:6], scn.lidar2d)[0]
    ok = np.isfinite(fresh) & np.isfinite(f.scan2d.ranges)
    assert np.abs(fresh[ok] - f.scan2d.ranges[ok]).max() < 0.06 and ok.mean() > 0.95
    assert len(scan_w) == np.count_nonzero(np.isfinite(f.scan2d.ranges))
    # frames without clouds, slices, indexing
    assert [g.index for g in ds.frames(2, 8, 3, clouds=False)] == [2, 5]
    assert ds[-1].index == N - 1 and ds.frame(0, clouds=False).cloud3d is None
    assert f.scan2d.times is None and ds.describe()["beam_time"].startswith("none")


def test_scan_time_gives_each_beam_its_time(tmp_path):
    """A 2D LiDAR turning once in 0.1 s: the folder stores each beam's time, the reader hands it on, and each
    beam's range is what the world shows from the pose at that time, not from the stamp's pose."""
    from hsmap.sim import Lidar2DConfig
    from hsmap.sim.robot import RobotConfig, sample_legs
    from hsmap.sim.world import World
    from hsmap.sim.writer import motion_for

    scn = small_two_rooms().replace(lidar2d=Lidar2DConfig(scan_time=0.1, noise_sigma=0.0),
                                    robot=RobotConfig(max_speed=1.0, max_turn_rate_deg=60.0))
    simulate(scn, tmp_path / "d", seed=3, max_frames=6)
    meta = yaml.safe_load((tmp_path / "d" / "dataset.yaml").read_text())
    l2 = meta["sensors"]["lidar2d"]
    assert l2["scan_time"] == 0.1 and l2["time_increment"] == pytest.approx(0.1 * 0.25 / 360)
    assert "beam_time" in meta["files"]["scans2d.npz"] and "`beam_time`" in (tmp_path / "d" / "README.md").read_text()
    with np.load(tmp_path / "d" / "scans2d.npz") as z:
        np.testing.assert_array_equal(z["beam_time"], scn.lidar2d.beam_times())
    ds = SimulatedDataset(tmp_path / "d")
    assert ds.describe()["beam_time"]["field"] == "beam_time"
    f = ds.frame(4, clouds=False)
    np.testing.assert_allclose(f.scan2d.times, np.arange(1081) * 0.1 * 0.25 / 360)
    legs, world = motion_for(scn, 3).legs, World(scn)
    at = sample_legs(legs, f.stamp + f.scan2d.times)
    beams = np.arange(0, 1081, 60)
    want = np.array([world.scan2d(at[i : i + 1], scn.lidar2d)[0, i] for i in beams])
    ok = np.isfinite(want)
    np.testing.assert_allclose(f.scan2d.ranges[beams][ok], want[ok], atol=1e-4)
    stamp_only = world.scan2d(at[:1], scn.lidar2d)[0]
    assert np.nanmax(np.abs(f.scan2d.ranges - stamp_only)) > 0.05  # the robot moved during the scan


def test_reader_labels_and_doors(written):
    out, _ = written
    labels, grid, names = SimulatedDataset(out).labels()
    assert labels.dtype == np.uint16 and names == {1: "room-a", 2: "corridor", 3: "room-b"}
    r, c = grid.world_to_index([7.25, 2.5])
    assert labels[r, c] == 2
    assert grid.resolution == 0.05
    doors = SimulatedDataset(out).doors()
    assert doors[1]["rooms"] == ["room-b", "corridor"] or set(doors[1]["rooms"]) == {"room-b", "corridor"}


def test_same_seed_same_bytes_other_seed_other_noise(tmp_path, written):
    out, _ = written
    again = tmp_path / "again"
    simulate(small_two_rooms(), again, seed=7, max_frames=N)
    a, b = tree(out), tree(again)
    assert a.keys() == b.keys()
    differing = [k for k in a if a[k] != b[k]]
    assert differing == []
    other = tmp_path / "other"
    simulate(small_two_rooms(), other, seed=8, max_frames=N)
    c = tree(other)
    assert c["groundtruth.tum"] == a["groundtruth.tum"] and c["rooms.png"] == a["rooms.png"]
    assert c["odometry.tum"] != a["odometry.tum"] and c["scans2d.npz"] != a["scans2d.npz"]
    assert c["clouds3d/000000.npz"] != a["clouds3d/000000.npz"]


def test_incomplete_and_missing_folders(tmp_path, written):
    with pytest.raises(DatasetError, match="no such dataset folder"):
        SimulatedDataset(tmp_path / "nothing")
    out, _ = written
    partial = tmp_path / "partial"
    partial.mkdir()
    for name in ("scans2d.npz", "groundtruth.tum"):
        (partial / name).write_bytes((out / name).read_bytes())
    with pytest.raises(DatasetError, match="incomplete"):
        SimulatedDataset(partial)
    assert not is_simulated_dataset(partial)
    # rewriting a folder removes dataset.yaml first and stale frames at the end
    folder = tmp_path / "rewrite"
    simulate(small_two_rooms(), folder, seed=1, max_frames=5)
    simulate(small_two_rooms(), folder, seed=1, max_frames=3)
    assert sorted(p.name for p in (folder / "clouds3d").iterdir()) == ["000000.npz", "000001.npz", "000002.npz"]
    assert len(SimulatedDataset(folder)) == 3
    (folder / "clouds3d" / "000002.npz").unlink()
    with pytest.raises(DatasetError, match="000002.npz: missing"):
        SimulatedDataset(folder).cloud3d(2)


@pytest.mark.slow
def test_cli_simulate_writes_a_folder(tmp_path):
    out = tmp_path / "cli"
    r = subprocess.run([sys.executable, "-m", "hsmap.cli", "simulate", "two-rooms", "--out", str(out), "--seed",
                        "2", "--max-frames", "3"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    assert summary["frames"] == 3 and summary["seed"] == 2
    ds = SimulatedDataset(out)
    assert len(ds) == 3 and ds.cloud3d(2).shape[1] == 3 and ds.range_image(0).shape == (128, 1024)
    r = subprocess.run([sys.executable, "-m", "hsmap.cli", "simulate", "slam-office", "--check"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    check = json.loads(r.stdout)
    assert check["frames"] >= 177 and check["path_length_m"] >= 100 and check["odometry_end_error_m"] >= 0.2
    r = subprocess.run([sys.executable, "-m", "hsmap.cli", "simulate", "--list"], capture_output=True, text=True)
    assert r.returncode == 0 and {"slam-office", "two-rooms"} <= set(r.stdout.split())
    r = subprocess.run([sys.executable, "-m", "hsmap.cli", "simulate", "two-rooms", "--seed", "-1"],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "--seed" in r.stderr


@pytest.mark.slow
def test_previews_are_written(tmp_path, written):
    out, _ = written
    from hsmap.viz.scenario_figures import preview_dataset

    copy = tmp_path / "copy"
    copy.mkdir()
    for name, data in tree(out).items():
        (copy / name).parent.mkdir(parents=True, exist_ok=True)
        (copy / name).write_bytes(data)
    names = preview_dataset(copy, frame=4)
    for n in names:
        assert (copy / "figures" / n).stat().st_size > 10_000
