"""``hsmap map`` on a recording with a 3D LiDAR only, and ``hsmap segment`` of the run's folder.

The recording: a folder of clouds (KITTI ``.bin``, sensor frame, ``times.txt``) ray-cast in two 6 m x 5 m rooms
joined by a 0.9 m door; the second room's floor is a platform 0.5 m above the first's (two floor levels), and
the sensor is carried 1.6 m above the floor under it along a path through both rooms.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from _cli import run_cli
from PIL import Image

pytest.importorskip("open3d")

PLATFORM = 0.5  # the second room's floor, metres above the first's
SENSOR_HEIGHT = 1.6
DOOR = (6.0, 2.5)



def _world():
    from hsmap.sim.shapes import make_box
    from hsmap.sim.world import World

    h, t = 2.8, 0.2
    boxes = [make_box((6.0, 0.0), (12.0 + t, t), z1=h), make_box((6.0, 5.0), (12.0 + t, t), z1=h),
             make_box((0.0, 2.5), (t, 5.0), z1=h), make_box((12.0, 2.5), (t, 5.0), z1=h),
             make_box((6.0, 1.025), (t, 2.05), z1=h), make_box((6.0, 3.975), (t, 2.05), z1=h),  # door 2.05-2.95
             make_box((9.05, 2.5), (5.9, 4.8), z1=PLATFORM)]  # the second room's raised floor
    return World.from_boxes(np.array(boxes), ["wall"] * 6 + ["platform"], ((0.0, 0.0), (12.0, 5.0)),
                            ceiling_height=h)


def _path(n: int) -> np.ndarray:
    """(n, 4): x, y, sensor z, yaw along a walk from the first room into the second."""
    s = np.linspace(0.0, 1.0, n)
    x = 1.5 + 9.0 * s
    y = 2.5 + 0.6 * np.sin(2 * np.pi * s)
    floor = np.where(x > 6.1, PLATFORM, 0.0)
    yaw = 0.3 * np.sin(3 * np.pi * s)
    return np.column_stack([x, y, floor + SENSOR_HEIGHT, yaw])


def write_clouds(folder, n: int = 24, channels: int = 32, columns: int = 360):
    """The recording: ``n`` clouds in the sensor's frame, 2 Hz; returns the path (n, 4) and the TUM file of the
    true sensor poses."""
    from hsmap.sim import Lidar3DConfig
    from hsmap.trajectory import Trajectory, write_tum

    folder.mkdir(parents=True, exist_ok=True)
    world = _world()
    cfg = Lidar3DConfig(channels=channels, columns=columns, vertical_fov_deg=[-45.0, 45.0], range_max=30.0)
    dirs = cfg.directions().reshape(-1, 3)
    path = _path(n)
    stamps = 100.0 + 0.5 * np.arange(n)
    for k, (x, y, z, yaw) in enumerate(path):
        c, s = np.cos(yaw), np.sin(yaw)
        d = np.column_stack([c * dirs[:, 0] - s * dirs[:, 1], s * dirs[:, 0] + c * dirs[:, 1], dirs[:, 2]])
        r = np.asarray(world.cast(np.tile([x, y, z], (len(d), 1)), d), dtype=float).reshape(-1)
        ok = np.isfinite(r) & (r < cfg.range_max)
        pts = dirs[ok] * r[ok, None]
        np.column_stack([pts, np.zeros(len(pts))]).astype("<f4").tofile(folder / f"{k:06d}.bin")
    np.savetxt(folder / "times.txt", stamps, fmt="%.3f")
    poses = np.column_stack([path[:, :3], np.zeros((n, 2)), path[:, 3]])
    write_tum(folder.parent / "truth.tum", Trajectory(stamps, poses))
    return path, folder.parent / "truth.tum"


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    root = tmp_path_factory.mktemp("map3d")
    path, truth = write_clouds(root / "clouds")
    return root, path, truth


@pytest.fixture(scope="module")
def mapped(recording):
    """The chain on the true poses (the map stages on their own)."""
    root, path, truth = recording
    out = root / "out"
    code, err = run_cli("map", str(root / "clouds"), "--out", str(out), "--poses", str(truth), "--quiet")
    assert code == 0, err
    return out, path


def test_map_of_a_3d_only_recording_writes_the_slice_its_rooms_and_an_octomap(mapped):
    from hsmap.maps.maps3d import read_map3d

    out, _ = mapped
    for name in ("slice.pgm", "slice.yaml", "floor.pgm", "floor.yaml", "rooms.png", "doors.json", "topology.json",
                 "map3d.bt", "map3d.ply", "trajectory3d.tum", "summary.html", "metrics.json", "map.rrd"):
        assert (out / name).is_file(), name
    m = json.loads((out / "metrics.json").read_text())
    bt = read_map3d(out / "map3d.bt")
    assert bt.resolution == pytest.approx(0.1)
    assert bt.counts()["occupied"] == m["voxels"]["voxels"]["occupied"] > 0
    assert bt.counts()["free"] == m["voxels"]["voxels"]["free"] > 0
    # the slice: two rooms and the door between them
    assert m["slice"]["rooms"] == 2, m["slice"]
    doors = m["slice"]["door_list"]
    assert len(doors) == 1 and np.hypot(*(np.asarray(doors[0]["centre"]) - DOOR)) < 0.3, doors
    labels = np.asarray(Image.open(out / "rooms.png"))
    assert labels.shape == np.asarray(Image.open(out / "slice.png")).shape[:2]


def test_map_of_a_3d_only_recording_says_what_it_skipped(mapped):
    out, _ = mapped
    m = json.loads((out / "metrics.json").read_text())
    assert set(m["skipped"]) == {"slam2d", "fusion", "trajectory2d.tum", "map2d.ply", "overlay.png"}
    for name in ("trajectory2d.tum", "map2d.ply", "overlay.png"):
        assert not (out / name).exists()
    html = (out / "summary.html").read_text()
    assert "Skipped (no 2D LiDAR)" in html and "overlay.png" in html


def test_floor_is_found_under_each_pose_on_both_levels(mapped):
    out, path = mapped
    f = json.loads((out / "floor_levels.json").read_text())
    floor = np.asarray(f["floor_z"])
    true = path[:, 2] - SENSOR_HEIGHT
    away = np.abs(path[:, 0] - DOOR[0]) > 1.5  # poses well inside one room
    assert away.sum() > 10 and set(np.round(true[away], 3)) == {0.0, PLATFORM}
    np.testing.assert_allclose(floor[away], true[away], atol=0.1)


def test_map_of_a_3d_only_recording_with_hs_slam(recording, tmp_path):
    root, _, _ = recording
    out = tmp_path / "slam"
    code, err = run_cli("map", str(root / "clouds"), "--out", str(out))
    assert code == 0, err
    assert "skipped (no 2D LiDAR): slam2d, fusion, trajectory2d.tum, map2d.ply, overlay.png" in err
    m = json.loads((out / "metrics.json").read_text())
    assert m["slam3d"]["frames"] == 24 and m["slice"]["rooms"] >= 2
    assert (out / "map3d.bt").is_file()


def test_poses_on_a_recording_with_2d_scans_is_refused(tmp_path):
    from hsmap.sim import Lidar3DConfig
    from hsmap.sim.bag import write_simulated_bag

    bag = write_simulated_bag("two-rooms", tmp_path / "b.mcap", duration=1.0,
                              lidar3d=Lidar3DConfig(channels=4, columns=16))
    (tmp_path / "p.tum").write_text("0 0 0 0 0 0 0 1\n")
    code, err = run_cli("map", str(bag.path), "--out", str(tmp_path / "o"), "--poses", str(tmp_path / "p.tum"))
    assert code == 2 and "--poses applies to recordings with a 3D LiDAR only" in err
    assert len(err.strip().splitlines()) == 1


def test_segment_of_a_run_folder_segments_its_3d_map_with_free_space(mapped, tmp_path):
    out, _ = mapped
    seg = tmp_path / "seg"
    code, err = run_cli("segment", str(out), "--out", str(seg), "--band", "1.7,1.8")
    assert code == 0, err
    band = json.loads((seg / "band.json").read_text())
    assert band["cells"]["segmented_free"] > 0 and band["rooms"] == 2
    assert band["floor_source"].startswith("under the path")


def test_segment_of_a_slam_folder_carves_free_space_from_the_trajectory(mapped, tmp_path):
    """A ``hsmap slam`` folder holds occupied points only (map.ply): the free space comes from the rays to the
    sensor's positions along trajectory.tum, and the floor from under the path, so the band has free cells."""
    import shutil

    out, _ = mapped
    run = tmp_path / "slam"
    run.mkdir()
    shutil.copy(out / "map3d.ply", run / "map.ply")
    shutil.copy(out / "trajectory3d.tum", run / "trajectory.tum")
    code, err = run_cli("segment", str(run), "--out", str(tmp_path / "seg"), "--band", "1.7,1.8", "--resolution",
                        "0.1")
    assert code == 0, err
    band = json.loads((tmp_path / "seg" / "band.json").read_text())
    assert band["map3d"] == "map.ply" and band["cells"]["free"] > 0 and band["rooms"] == 2


def test_segment_of_a_folder_that_is_no_run_is_one_line(tmp_path):
    code, err = run_cli("segment", str(tmp_path), "--out", str(tmp_path / "seg"), "--band", "1.7,1.8")
    assert code == 2 and "nor a run's output folder" in err and len(err.strip().splitlines()) == 1


def test_map_of_a_3d_only_recording_again_reads_every_stage_back(mapped, recording):
    out, _ = mapped
    root, _, truth = recording
    code, err = run_cli("map", str(root / "clouds"), "--out", str(out), "--poses", str(truth), "--quiet")
    assert code == 0, err
    stages = json.loads((out / "metrics.json").read_text())["stages"]
    assert set(stages) == {"slam3d", "voxels", "grids", "rooms", "outputs"}
    assert all(s["unchanged"] for s in stages.values()), stages


def test_segment_of_a_bare_point_map_without_free_space_points_to_the_run_folder(mapped, tmp_path):
    out, _ = mapped
    code, err = run_cli("segment", str(out / "map3d.ply"), "--out", str(tmp_path / "seg"), "--band", "1.7,1.8",
                        "--resolution", "0.1")
    assert code == 2 and "a point map records occupied voxels only, no free space" in err
    assert "the output folder of the hsmap map or hsmap slam run that made it" in err
    assert len(err.strip().splitlines()) == 1
