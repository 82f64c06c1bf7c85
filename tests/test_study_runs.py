"""hsmap.study runs, datasets, maps and recording: the cached SLAM runner (hit, miss, key, lock, damaged
folders), maps from a dataset and a trajectory, the replayed rerun recording, the shared simulated dataset."""

from __future__ import annotations

import json
import re
import shutil
import threading
from pathlib import Path

import numpy as np
import pytest
from _worlds import TINY_SCENARIO

import hsmap.slam
from hsmap.datasets.frames import Dataset, Frame, LaserScan2D
from hsmap.errors import HsmapError, HsmapWarning, InputError
from hsmap.geometry import compose, relative
from hsmap.slam import SlamConfig
from hsmap.study import (
    cached_slam,
    dataset_fingerprint,
    point_map,
    point_maps,
    record_slam_run,
    scan_grid,
    simulated_dataset,
    slam_key,
)
from hsmap.testing import office_route, office_segments, raycast_2d
from hsmap.trajectory import Trajectory

SEGMENTS = office_segments()
ROUTE = office_route()[:60]  # room A and the door: enough for a real run, a few seconds


class ListDataset(Dataset):
    """An in-memory dataset (no file behind it)."""

    def __init__(self, frames, name="office"):
        self._frames = frames
        self.name = name
        self.path = ""
        self.extrinsic2d = np.zeros(3)
        self.odometry = Trajectory([f.stamp for f in frames], [f.odometry for f in frames])
        self.groundtruth = Trajectory([f.stamp for f in frames], ROUTE[: len(frames)])

    def __len__(self):
        return len(self._frames)

    def frames(self, clouds=True):
        yield from self._frames


def make_dataset(drift_deg_per_m=3.0, seed=0):
    rng = np.random.default_rng(seed)
    frames, odom = [], ROUTE[0].copy()
    for i, pose in enumerate(ROUTE):
        if i > 0:
            step = relative(ROUTE[i - 1], pose)
            step[2] += np.deg2rad(drift_deg_per_m) * np.hypot(*step[:2])
            step[:2] *= 1.03
            odom = compose(odom, step)
        r, a = raycast_2d(SEGMENTS, pose, noise=0.005, rng=rng)
        frames.append(Frame(stamp=50.0 + 0.5 * i, scan2d=LaserScan2D(r, a, 0.05, 10.0), odometry=odom.copy(),
                            index=i))
    return ListDataset(frames)


@pytest.fixture(scope="module")
def dataset():
    return make_dataset()


@pytest.fixture
def count_runs(monkeypatch):
    calls = []
    real = hsmap.slam.run_slam

    def counting(*args, **kwargs):
        calls.append(kwargs.get("max_frames"))
        return real(*args, **kwargs)

    monkeypatch.setattr(hsmap.slam, "run_slam", counting)
    return calls


CFG = SlamConfig(dof=3, use_odometry=False)


def test_miss_then_hit_reads_the_same_run(tmp_path, dataset, count_runs):
    a = cached_slam(dataset, CFG, seed=3, max_frames=40, initial_pose=ROUTE[0], cache_dir=tmp_path)
    assert not a.cached and len(count_runs) == 1
    for name in ("trajectory.tum", "map.ply", "metrics.json", "config.yaml", "cache.json"):
        assert (a.folder / name).is_file(), name
    # the run is real: it tracks the route within centimetres, in the world frame of the initial pose
    assert len(a.trajectory) == 40 and a.trajectory.dof == 3
    assert np.abs(a.trajectory.poses[:, :2] - ROUTE[:40, :2]).max() < 0.05
    assert a.map_points.shape[1] == 2 and len(a.map_points) > 100
    b = cached_slam(dataset, CFG, seed=3, max_frames=40, initial_pose=ROUTE[0], cache_dir=tmp_path)
    assert b.cached and len(count_runs) == 1
    assert b.folder == a.folder and b.key == a.key
    np.testing.assert_allclose(b.trajectory.poses, a.trajectory.poses)
    np.testing.assert_allclose(b.map_points, a.map_points)
    assert b.metrics["seconds_total"] == a.metrics["seconds_total"]  # the stored run's time, not a new one
    assert b.config == CFG
    assert b.keyframes.sum() >= 3 and b.frame_indices.tolist() == list(range(40))
    assert json.loads((a.folder / "cache.json").read_text())["key"] == a.key


def test_every_input_of_the_run_changes_the_key(dataset):
    base = slam_key(dataset, CFG, 1)[0]
    prior = Trajectory([50.0, 50.5], [[0, 0, 0], [0.1, 0, 0]])
    variants = [
        slam_key(dataset, CFG, 2)[0],
        slam_key(dataset, SlamConfig(dof=3, use_odometry=True), 1)[0],
        slam_key(dataset, SlamConfig(dof=3, use_odometry=False, keyframe_distance=0.6), 1)[0],
        slam_key(dataset, CFG, 1, max_frames=10)[0],
        slam_key(dataset, CFG, 1, initial_pose=[1.0, 0.0, 0.0])[0],
        slam_key(dataset, SlamConfig(dof=6), 1, prior=prior)[0],
        slam_key(make_dataset(drift_deg_per_m=1.0), CFG, 1)[0],  # other odometry in the frames
    ]
    assert len({base, *variants}) == len(variants) + 1
    assert slam_key(dataset, CFG, 1)[0] == base  # and nothing else does


def test_fingerprint_of_an_open_dataset_covers_odometry_and_extrinsic(tmp_path, dataset):
    f = tmp_path / "x.bag"
    f.write_bytes(b"some bag bytes")
    d = ListDataset(dataset._frames)
    d.path = str(f)
    fp = dataset_fingerprint(d)
    d.extrinsic2d = np.array([-0.04, 0.0, 0.0])
    assert dataset_fingerprint(d) != fp
    d.extrinsic2d = np.zeros(3)
    assert dataset_fingerprint(d) == fp
    d.odometry = Trajectory(d.odometry.stamps, d.odometry.poses + 0.01)
    assert dataset_fingerprint(d) != fp
    # a path is identified by its bytes and the options it will be opened with
    p1 = dataset_fingerprint(f)
    assert dataset_fingerprint(f, {"scan_topic": "/scan"}) != p1
    f.write_bytes(b"other bag bytes")
    assert dataset_fingerprint(f) != p1
    with pytest.raises(InputError, match="open_kwargs"):
        dataset_fingerprint(d, {"scan_topic": "/scan"})
    with pytest.raises(HsmapError, match="no such file"):
        dataset_fingerprint(tmp_path / "missing.bag")


@pytest.mark.parametrize("damage", ["no_metrics", "garbage_metrics", "short_trajectory", "no_map", "wrong_key"])
def test_damaged_folder_is_computed_again(tmp_path, dataset, count_runs, damage):
    a = cached_slam(dataset, CFG, seed=1, max_frames=12, cache_dir=tmp_path)
    ref = a.trajectory.poses.copy()
    if damage == "no_metrics":
        (a.folder / "metrics.json").unlink()
    elif damage == "garbage_metrics":
        (a.folder / "metrics.json").write_text('{"frames": 12, "per_fr')
    elif damage == "short_trajectory":
        lines = (a.folder / "trajectory.tum").read_text().splitlines()
        (a.folder / "trajectory.tum").write_text("\n".join(lines[:-3]) + "\n")
    elif damage == "no_map":
        (a.folder / "map.ply").unlink()
    elif damage == "wrong_key":
        (a.folder / "cache.json").write_text(json.dumps({"key": "0" * 64}))
    if damage == "wrong_key":  # another key's folder: stale, not damaged, replaced without a word
        b = cached_slam(dataset, CFG, seed=1, max_frames=12, cache_dir=tmp_path)
    else:  # damaged: computed again, with a warning naming the file
        with pytest.warns(HsmapWarning, match=rf"cache folder {re.escape(str(a.folder))} is damaged: "
                                              rf"{re.escape(str(a.folder))}/(metrics\.json|trajectory\.tum|map\.ply)"):
            b = cached_slam(dataset, CFG, seed=1, max_frames=12, cache_dir=tmp_path)
    assert not b.cached and len(count_runs) == 2
    np.testing.assert_allclose(b.trajectory.poses, ref, atol=1e-7)  # same seed: the same run again
    c = cached_slam(dataset, CFG, seed=1, max_frames=12, cache_dir=tmp_path)
    assert c.cached and len(count_runs) == 2


def test_interrupted_run_publishes_nothing(tmp_path, dataset, monkeypatch):
    def broken(result, out):
        Path(out, "trajectory.tum").write_text("half")
        raise KeyboardInterrupt

    monkeypatch.setattr(hsmap.slam, "write_slam_outputs", broken)
    with pytest.raises(KeyboardInterrupt):
        cached_slam(dataset, CFG, seed=1, max_frames=5, cache_dir=tmp_path)
    assert [p.name for p in tmp_path.iterdir()] == [".locks"]  # no folder, no temporary left


def test_stale_temporary_folder_is_swept(tmp_path, dataset):
    first = cached_slam(dataset, CFG, seed=1, max_frames=5, cache_dir=tmp_path)
    assert first.folder.name.startswith("office-3dof-")
    shutil.rmtree(first.folder)
    stale = tmp_path / f".{first.folder.name}.tmp-99999"
    stale.mkdir(parents=True)
    (stale / "trajectory.tum").write_text("left by a killed run")
    run = cached_slam(dataset, CFG, seed=1, max_frames=5, cache_dir=tmp_path)
    assert not stale.exists() and run.folder == first.folder and not run.cached


def test_two_callers_at_once_compute_once(tmp_path, dataset, count_runs):
    results, errors = [], []

    def call():
        try:
            results.append(cached_slam(dataset, CFG, seed=2, max_frames=15, cache_dir=tmp_path))
        except Exception as exc:  # pragma: no cover - reported below
            errors.append(exc)

    threads = [threading.Thread(target=call) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert len(count_runs) == 1
    assert sorted(r.cached for r in results) == [False, True]
    assert results[0].folder == results[1].folder
    np.testing.assert_allclose(results[0].trajectory.poses, results[1].trajectory.poses)


def _distance_to_segments(points, segments):
    a, b = segments[:, 0], segments[:, 1]
    ab = b - a
    t = np.clip(((points[:, None] - a) * ab).sum(-1) / (ab * ab).sum(-1), 0, 1)
    closest = a + t[..., None] * ab
    return np.linalg.norm(points[:, None] - closest, axis=-1).min(axis=1)


def test_point_map_at_true_poses_lies_on_the_walls_and_odometry_smears_it(dataset):
    truth = point_map(dataset, dataset.groundtruth, voxel=0.05)
    odo = point_map(dataset, dataset.odometry, voxel=0.05)
    d_truth = _distance_to_segments(truth, SEGMENTS)
    d_odo = _distance_to_segments(odo, SEGMENTS)
    assert np.percentile(d_truth, 99) < 0.03
    assert np.percentile(d_odo, 90) > 0.10  # the odometry-only map: walls doubled and smeared
    assert len(odo) > len(truth)  # thick walls fill more voxels
    sub = point_map(dataset, dataset.groundtruth, every=5, max_frames=20)
    assert 0 < len(sub) < len(truth)
    both = point_maps(dataset, {"truth": dataset.groundtruth, "odometry": dataset.odometry}, voxel=0.05, block=7)
    np.testing.assert_array_equal(both["truth"], truth)  # one pass, the same maps
    np.testing.assert_array_equal(both["odometry"], odo)
    with pytest.raises(InputError, match="no frame"):
        point_map(dataset, Trajectory([0.0], [[0, 0, 0]]))


def test_scan_grid_walls_where_the_segments_are(dataset):
    grid = scan_grid(dataset, dataset.groundtruth, 0.05)
    occ = grid.geometry.pixel_to_world(np.argwhere(grid.occupied))
    assert len(occ) > 200
    assert np.percentile(_distance_to_segments(occ, SEGMENTS), 95) < 0.06
    # the robot's own positions are free space
    rc = grid.geometry.world_to_index(ROUTE[:40, :2])
    assert grid.free[rc[:, 0], rc[:, 1]].mean() > 0.95
    odo = scan_grid(dataset, dataset.odometry, 0.05)
    occ_odo = odo.geometry.pixel_to_world(np.argwhere(odo.occupied))
    assert np.percentile(_distance_to_segments(occ_odo, SEGMENTS), 90) > 0.1


def test_recording_of_a_cached_run_verifies(tmp_path, dataset):
    from hsmap.viz import rerun as hv

    run = cached_slam(dataset, CFG, seed=1, max_frames=20, cache_dir=tmp_path)
    with hv.open_recording(tmp_path / "slam.rrd", blueprint=hv.default_blueprint(graph=False)) as rec:
        info = record_slam_run(rec, dataset, run, every=2, groundtruth=dataset.groundtruth,
                               odometry=dataset.odometry)
    assert info["frames"] == 11 and info["map_blocks"] >= 1 and info["map_points"] > 100
    hv.verify_rrd(tmp_path / "slam.rrd")
    contents = hv.recording_contents(tmp_path / "slam.rrd")
    for entity in ("/world/robot", "/world/robot/lidar2d/scan", "/world/map/points/0000",
                   "/world/trajectory/estimate", "/world/trajectory/groundtruth"):
        assert any(e.rstrip("/") == entity or e == entity.lstrip("/") for e in contents), (entity, list(contents))


def test_simulated_dataset_is_generated_once(tmp_path, monkeypatch):
    scn = tmp_path / "tiny.yaml"
    scn.write_text(TINY_SCENARIO)
    monkeypatch.setenv("HSMAP_GENERATED", str(tmp_path / "generated"))
    # a quick run needs only the first frames: a prefix folder with exactly those
    q = simulated_dataset(scn, seed=4, max_frames=2)
    assert Path(q.path).name == "tiny-seed4-first2" and len(q) == 2
    a = simulated_dataset(scn, seed=4)
    assert Path(a.path) == tmp_path / "generated" / "tiny-seed4" and len(a) > 2
    np.testing.assert_array_equal(np.asarray(a.ranges2d)[:2], np.asarray(q.ranges2d))  # the same first frames
    stamp = (Path(a.path) / "dataset.yaml").stat().st_mtime_ns
    b = simulated_dataset(scn, seed=4)
    assert (Path(b.path) / "dataset.yaml").stat().st_mtime_ns == stamp
    assert Path(simulated_dataset(scn, seed=4, max_frames=2).path) == Path(a.path)  # the full one serves too
    c = simulated_dataset(scn, seed=5)
    assert Path(c.path).name == "tiny-seed5"
    assert not np.array_equal(np.asarray(a.ranges2d), np.asarray(c.ranges2d), equal_nan=True)


@pytest.mark.datasets
def test_open_freiburg_as_the_command_line_does(datasets_dir):
    from hsmap.study import open_freiburg

    folder = datasets_dir / "slam2d"
    ds = open_freiburg(folder, "fr079")
    assert len(ds) == 4934
    frame = next(ds.frames())
    np.testing.assert_allclose(frame.extrinsic2d, [-0.04, 0.0, 0.0])  # --extrinsic2d -0.04,0,0
    assert ds.odometry is not None and len(ds.odometry) == len(ds)
    plain = open_freiburg(folder, "fr079", extrinsic2d=[0.04, 0.0, 0.0])
    fps = {json.dumps(dataset_fingerprint(d), sort_keys=True) for d in (ds, plain)}
    assert len(fps) == 2  # the offset identifies the dataset
    with pytest.raises(InputError, match="unknown Freiburg log"):
        open_freiburg(folder, "aces")


def test_every_freiburg_log_has_cartographer_beside_it():
    """Notebook 08 puts Cartographer beside each log it runs; a standard deviation nobody checked prints as "?"."""
    from hsmap.study import FREIBURG_LOGS, published_references
    from hsmap.study.benchmarks import FreiburgResults

    refs = published_references()
    carto = {m["log"]: m for m in refs["freiburg_relations"]["methods"] if m["method"] == "Cartographer"}
    assert set(carto) == set(FREIBURG_LOGS)
    for m in carto.values():
        assert len(m["translation_m"]) == 2 and 0 < m["translation_m"][0] < 1
        assert len(m["rotation_deg"]) == 2 and 0 < m["rotation_deg"][0] < 2
    row = {"log": "fr-clinic", "method": "HS-SLAM", "mode": "loop_closure", "seeds": [1, 2],
           "translation_m": [0.12, 0.001], "rotation_deg": [0.8, 0.01], "worst_m": 0.121, "short_m": 0.09,
           "long_m": 0.47, "distance_scale": 1.01, "loops_closed": 27.0, "real_time_factor": 40.0, "relations": 2820}
    lines = FreiburgResults(rows=[row]).table(refs).splitlines()
    assert re.search(r"Cartographer \(Hess 2016\)\s+0\.1078 ± \?\s+0\.747 ± \?", lines[2]), lines


@pytest.mark.datasets
def test_freiburg_relations_over_seeds(datasets_dir, tmp_path, monkeypatch):
    from hsmap.study import freiburg_relations

    monkeypatch.setenv("HSMAP_GENERATED", str(tmp_path))
    res = freiburg_relations(datasets_dir / "slam2d", ["fr079"], seeds=[1, 2], max_frames=150)
    rows = {r["method"]: r for r in res.rows}
    assert set(rows) == {"raw odometry", "HS-SLAM", "HS-SLAM, no loop closure"}
    ours = rows["HS-SLAM"]
    assert ours["seeds"] == [1, 2] and ours["worst_m"] >= ours["translation_m"][0]
    assert ours["translation_m"][0] < 0.1 and ours["translation_m"][0] < rows["raw odometry"]["translation_m"][0]
    assert rows["HS-SLAM, no loop closure"]["seeds"] == [1]
    assert ("fr079", "HS-SLAM") in res.curves
    table = res.table({"freiburg_relations": {"methods": [
        {"log": "fr079", "method": "Cartographer", "source": "Hess 2016", "translation_m": [0.0452, 0.0354],
         "rotation_deg": [0.538, 0.718]}]}})
    assert "Cartographer (Hess 2016)" in table and "HS-SLAM, no loop closure" in table
    # how long each makes the relations' distances (the odometry's wheels and the laser need not agree on scale)
    assert all(0.9 < r["distance_scale"] < 1.1 for r in rows.values()), rows
    assert "scale" in table.splitlines()[0]


@pytest.mark.datasets
def test_room_segmentation_benchmark_scores_a_building(datasets_dir):
    from hsmap.study import room_segmentation_benchmark, summarise_segmentation

    rows = room_segmentation_benchmark(datasets_dir / "ipa_room_segmentation", ["Freiburg52_scan"])
    assert [r["kind"] for r in rows] == ["plain", "furnished"]
    assert rows[0]["rooms"] == 10  # the README's count for this building
    for r in rows:
        assert r["precision"] > 0.85 and r["recall"] > 0.8, r
    summary = summarise_segmentation(rows)
    assert summary["plain"]["maps"] == 1 and summary["furnished"]["recall"] == rows[1]["recall"]


def test_simulated_slam_runs_are_shared(tmp_path, monkeypatch, count_runs):
    from hsmap.study import simulated_slam_runs

    scn = tmp_path / "tiny.yaml"
    scn.write_text(TINY_SCENARIO)
    monkeypatch.setenv("HSMAP_GENERATED", str(tmp_path / "generated"))
    a = simulated_slam_runs(scn, seed=3)
    assert len(count_runs) == 2 and not a.run3.cached and not a.run6.cached
    assert a.run3.dof == 3 and a.run6.dof == 6 and a.frames == len(a.dataset)
    # both start at the true first pose: the paths lie in the ground truth's world frame
    np.testing.assert_allclose(a.run3.trajectory.poses[0], a.truth.poses[0])
    np.testing.assert_allclose(a.run6.trajectory.poses[0, [0, 1, 5]], a.truth.poses[0])
    assert np.abs(a.run6.trajectory.poses[:, :2] - a.truth.poses[:, :2]).max() < 0.15  # a bare room, 16 beams
    b = simulated_slam_runs(scn, seed=3)  # another notebook asking the same: nothing computed
    assert len(count_runs) == 2 and b.run3.cached and b.run6.cached and b.run6.folder == a.run6.folder
    c = simulated_slam_runs(scn, seed=3, dof6=False)
    assert c.run6 is None and c.run3.folder == a.run3.folder
