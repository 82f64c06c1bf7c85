"""HS-SLAM on a synthetic office (exact 2D ray casting): accuracy, seeding, outputs, bad input."""

import dataclasses
import json
import types

import numpy as np
import pytest

from hsmap.datasets.frames import Frame, LaserScan2D
from hsmap.errors import ConfigError, EmptyInputError, HsmapWarning, InputError, UnusableFrameError
from hsmap.geometry import compose, relative, wrap_angle
from hsmap.slam import HsSlam, SlamConfig, run_slam, write_slam_outputs
from hsmap.testing import office_route, office_segments, raycast_2d, room_cloud_3d, sensor_cloud
from hsmap.trajectory import Trajectory, read_tum

SEGMENTS = office_segments()
ROUTE = office_route()


def make_frames(route=ROUTE, odometry_drift=0.0, seed=0):
    """Frames with a 1081-beam scan (1 cm noise) at each pose, and odometry with a heading drift per metre."""
    rng = np.random.default_rng(seed)
    frames, odom = [], route[0].copy()
    for i, pose in enumerate(route):
        if i > 0:
            step = relative(route[i - 1], pose)
            step[2] += odometry_drift * np.hypot(*step[:2]) + rng.normal(0, 0.002)
            step[:2] *= 1.02
            odom = compose(odom, step)
        r, a = raycast_2d(SEGMENTS, pose, noise=0.01, rng=rng)
        frames.append(Frame(stamp=100.0 + 0.5 * i, scan2d=LaserScan2D(r, a, 0.05, 10.0), odometry=odom.copy(),
                            index=i))
    return frames


def relative_errors(est, truth):
    err = relative(est[0], est) - relative(truth[0], truth)
    err[:, 2] = wrap_angle(err[:, 2])
    return err


@pytest.fixture(scope="module")
def frames():
    return make_frames(odometry_drift=np.deg2rad(2.0))


def test_route_is_long_enough():
    assert len(ROUTE) > 150
    assert Trajectory(np.arange(len(ROUTE)), ROUTE).path_length() > 30


@pytest.mark.parametrize("use_odometry", [False, True])
def test_slam_2d_tracks_the_route(frames, use_odometry):
    res = run_slam(frames, SlamConfig(use_odometry=use_odometry), rng=1, progress=False)
    err = relative_errors(res.trajectory.poses, ROUTE)
    assert np.abs(err[:, :2]).max() < 0.03, np.abs(err[:, :2]).max(0)
    assert np.rad2deg(np.abs(err[:, 2]).max()) < 1.0
    np.testing.assert_array_equal(res.trajectory.stamps, [f.stamp for f in frames])
    assert len(res.frames) == len(frames)
    assert 0 < sum(f.keyframe for f in res.frames) < len(frames)
    assert np.median([f.inlier_ratio for f in res.frames[1:]]) > 0.9


def make_noisy_odometry_frames(yaw_sigma, seed=0, n=120):
    """The first ``n`` frames of the office route, odometry with white heading noise of ``yaw_sigma`` per step."""
    rng = np.random.default_rng(seed)
    frames, odom = [], ROUTE[0].copy()
    for i, pose in enumerate(ROUTE[:n]):
        if i > 0:
            step = relative(ROUTE[i - 1], pose)
            step[2] += rng.normal(0, yaw_sigma)
            odom = compose(odom, step)
        r, a = raycast_2d(SEGMENTS, pose, noise=0.01, rng=rng)
        frames.append(Frame(stamp=100.0 + 0.5 * i, scan2d=LaserScan2D(r, a, 0.05, 10.0), odometry=odom.copy(),
                            index=i))
    return frames


def test_odometry_sigma_is_learned_from_the_run():
    """Precise odometry earns a tighter sigma than the loose default, poor odometry a looser one; metrics say so."""
    on = SlamConfig(learn_odometry=True)
    good = run_slam(make_noisy_odometry_frames(np.deg2rad(0.05)), on, rng=1, progress=False)
    bad = run_slam(make_noisy_odometry_frames(np.deg2rad(4.0)), on, rng=1, progress=False)
    g, b = good.metrics()["odometry_model"], bad.metrics()["odometry_model"]
    assert g["learned"] and b["learned"] and g["frames"] == b["frames"] == 119
    assert g["scale_rotation"] < 0.5 < 1.5 < b["scale_rotation"], (g, b)
    assert g["sigma"][2] == pytest.approx(SlamConfig().odometry_sigma[2] * g["scale_rotation"])
    # the retry check never gets tighter than the configured model: slips are what it is for
    slam = HsSlam(SlamConfig())
    configured = np.array(SlamConfig().odometry_sigma)
    slam.odometry.scale = np.array([0.2, 0.3])
    np.testing.assert_allclose(slam.odometry.sigma(gate=True), configured)
    np.testing.assert_allclose(slam.odometry.sigma(), configured * [0.2, 0.2, 0.3, 0.3, 0.3])
    slam.odometry.scale = np.array([2.0, 3.0])
    np.testing.assert_allclose(slam.odometry.sigma(gate=True), configured * [2, 2, 3, 3, 3])
    # both scales learned, from registrations 16 frames apart: the precise odometry's translation too
    assert g["scale_translation"] < 0.5 and g["sigma"][0] == pytest.approx(
        SlamConfig().odometry_sigma[0] * g["scale_translation"])
    fixed = run_slam(make_noisy_odometry_frames(np.deg2rad(4.0))[:30], SlamConfig(learn_odometry=False),
                     rng=1, progress=False).metrics()["odometry_model"]
    assert not fixed["learned"] and fixed["scale_rotation"] == fixed["scale_translation"] == 1.0
    assert SlamConfig().learn_odometry  # on by default


def test_odometry_learning_survives_standing_still_and_gaps():
    """A robot that stands still (zero steps: the model's constant terms keep the variances > 0) and frames without
    odometry (the lagged comparison restarts) leave finite scales; a model without constant terms is refused."""
    frames = make_noisy_odometry_frames(np.deg2rad(0.05), n=100)
    still = [dataclasses.replace(frames[40], stamp=frames[40].stamp + 0.01 * (k + 1), index=0) for k in range(60)]
    seq = frames[:41] + still + frames[41:]
    for k in range(70, 75):
        seq[k] = dataclasses.replace(seq[k], odometry=None)
    seq = [dataclasses.replace(f, index=i) for i, f in enumerate(seq)]
    m = run_slam(seq, SlamConfig(loop_closure={"enabled": False}), rng=1, progress=False).metrics()["odometry_model"]
    assert m["lagged_frames"] > 40 and np.all(np.isfinite(m["sigma"])), m
    assert 0.1 <= m["scale_translation"] < 1 and 0.1 <= m["scale_rotation"] < 1, m
    for bad in ((0.0, 0.05, 0.01, 0.05, 0.01), (0.02, 0.05, 0.0, 0.05, 0.01)):
        with pytest.raises(ConfigError, match="odometry_sigma"):
            SlamConfig(odometry_sigma=bad)


def test_a_slipped_odometry_does_not_pull_the_fused_pose():
    """Precise odometry learned as such, then one step slips 30 cm: the fusion's gate keeps the pose with the scan
    (without it, the tight learned sigmas would pull the pose half-way to the slipped prediction)."""
    frames = make_noisy_odometry_frames(np.deg2rad(0.05))
    for f in frames[90:]:
        f.odometry = compose([0.3, 0.0, 0.0], f.odometry)  # a 30 cm jump, then on as before
    res = run_slam(frames, SlamConfig(loop_closure={"enabled": False}), rng=1, progress=False)
    assert res.metrics()["odometry_model"]["scale_translation"] < 0.5  # the odometry was trusted
    err = relative_errors(res.trajectory.poses, ROUTE[: len(frames)])
    assert np.abs(err[:, :2]).max() < 0.03, np.abs(err[:, :2]).max(0)


def assert_wheel_edges_measure_the_odometry(slam, frames):
    """Each wheel edge measures the raw odometry's motion between its two keyframes' frames (less the bias)."""
    from hsmap.slam.posegraph import EdgeKind

    odom = {f.index: f.odometry for f in frames}
    for e in slam.graph.edges:
        if e.kind != EdgeKind.WHEEL:
            continue
        a, b = odom[slam.keyframes[e.i].frame], odom[slam.keyframes[e.j].frame]
        assert a is not None and b is not None
        raw = relative(np.asarray(a), np.asarray(b))
        np.testing.assert_allclose(e.measurement[:2], raw[:2], atol=0.01)  # the learned bias taken out
        assert abs(wrap_angle(e.measurement[2] - raw[2])) < np.deg2rad(0.5)
        assert np.all(np.linalg.eigvalsh(e.information) > 0)


def test_wheel_odometry_is_an_edge_of_its_own_between_keyframes():
    """2D with odometry: one wheel edge beside each tracking edge, measuring the odometry's motion between the two
    keyframes' frames; off with ``odometry_edges=False`` (the tracking edges then hold the fused information)."""
    from hsmap.slam.posegraph import EdgeKind

    frames = make_noisy_odometry_frames(np.deg2rad(0.05), n=60)
    slam = HsSlam(SlamConfig(), rng=1)
    for f in frames:
        slam.process(f)
    tracking = [e for e in slam.graph.edges if e.kind == EdgeKind.ODOMETRY]
    wheel = [e for e in slam.graph.edges if e.kind == EdgeKind.WHEEL]
    assert len(tracking) == len(slam.keyframes) - 1 > 10 and [(e.i, e.j) for e in wheel] == [(e.i, e.j) for e in tracking]
    assert_wheel_edges_measure_the_odometry(slam, frames)
    assert slam.keyframe_graph.summary()["wheel_edges"] == len(wheel)
    assert slam.keyframe_graph.summary()["wheel_edges_down_weighted"] == 0  # nothing slipped: the covariance covers the noise
    # single frames without odometry, keyframes among them: no edge into such a keyframe, and none out of it that
    # measures from an older frame's odometry
    gap = make_noisy_odometry_frames(np.deg2rad(0.05), n=60)
    missing = set(range(10, 60, 5))
    for i in missing:
        gap[i].odometry = None
    lost = HsSlam(SlamConfig(), rng=1)
    for f in gap:
        lost.process(f)
    gap_keys = [k for k, kf in enumerate(lost.keyframes) if kf.frame in missing]
    assert len(gap_keys) >= 2
    spans = {(e.i, e.j) for e in lost.graph.edges if e.kind == EdgeKind.WHEEL}
    assert not {(k - 1, k) for k in gap_keys} & spans
    assert_wheel_edges_measure_the_odometry(lost, gap)
    off = HsSlam(SlamConfig(graph={"odometry_edges": False}), rng=1)
    for f in frames:
        off.process(f)
    assert not [e for e in off.graph.edges if e.kind == EdgeKind.WHEEL]


def test_a_slipped_wheel_edge_does_not_bend_the_graph():
    """The slip of the test above inside the pose graph: the wheel edge across it is down-weighted, the optimised
    path keeps to the scans."""
    frames = make_noisy_odometry_frames(np.deg2rad(0.05))
    for f in frames[90:]:
        f.odometry = compose([0.3, 0.0, 0.0], f.odometry)
    res = run_slam(frames, SlamConfig(), rng=1, progress=False)
    assert res.metrics()["loop_closure_detail"]["wheel_edges_down_weighted"] >= 1
    err = relative_errors(res.trajectory.poses, ROUTE[: len(frames)])
    assert np.abs(err[:, :2]).max() < 0.03, np.abs(err[:, :2]).max(0)


def test_the_trajectory_is_smoothed_with_the_odometry_after_the_run(frames):
    """The smoothing is a stage after the graph: the run before it is the run without it, and the metrics say what
    it measured (three sources of each frame's motion) and moved."""
    on = run_slam(frames, SlamConfig(), rng=1, progress=False)
    off = run_slam(frames, SlamConfig(smoothing=False), rng=1, progress=False)
    np.testing.assert_array_equal(on.unsmoothed.poses, off.trajectory.poses)
    sm = on.metrics()["smoothing"]
    assert sm["status"] == "ok"
    assert sm["frames"] == len(frames) - 1  # every frame's motion from the one before
    # dense 1081-beam scans at 1 cm against a 2 %-scale, 2 deg/m odometry: the SLAM poses carry little white noise
    assert max(sm["white_sigma"][:2]) < 0.005
    assert sm["moved_max_m"] < 0.01
    err = relative_errors(on.trajectory.poses, ROUTE)
    assert np.abs(err[:, :2]).max() < 0.03
    assert off.metrics()["smoothing"] == {"status": "off (slam.smoothing: false)"}
    frames3d, _ = _room_frames_3d()
    assert run_slam(frames3d[:3], SlamConfig(dof=6), rng=0, progress=False).metrics()["smoothing"] == {
        "status": "not applicable: 6-DOF"}


def test_odometry_alone_drifts(frames):
    odom = np.array([f.odometry for f in frames])
    err = relative_errors(odom, ROUTE)
    assert np.abs(err[:, :2]).max() > 0.3  # the input is hard enough that the SLAM result above means something


def test_deterministic(frames):
    a = run_slam(frames[:40], SlamConfig(), rng=5, progress=False)
    b = run_slam(frames[:40], SlamConfig(), rng=5, progress=False)
    np.testing.assert_array_equal(a.trajectory.poses, b.trajectory.poses)


def test_seeds_include_odometry_velocity_and_mean(frames):
    slam = HsSlam(SlamConfig(), rng=0)
    for f in frames[:4]:
        slam.process(f)
    slam.prediction.start(frames[4])
    seeds, half = slam.prediction.seeds()
    assert len(seeds) == 4  # previous, constant velocity, odometry, mean of recent
    np.testing.assert_allclose(seeds[0], slam.poses[-1])
    assert half.shape == (3,)
    no_odom = HsSlam(SlamConfig(use_odometry=False), rng=0)
    for f in frames[:4]:
        no_odom.process(f)
    no_odom.prediction.start(frames[4])
    assert len(no_odom.prediction.seeds()[0]) == 3


def test_odometry_step_follows_the_readings_however_often_it_is_asked():
    from hsmap.slam.odometry import OdometryModel

    frames = make_frames(route=ROUTE[:3])
    model = OdometryModel(SlamConfig(), learn=False, wheel_edges=False)
    model.advance(frames[0])
    f = frames[1]
    first = model.step(f)
    np.testing.assert_array_equal(first, relative(frames[0].odometry, f.odometry))
    first[:] = 99.0  # a caller's copy: changing it changes nothing held
    np.testing.assert_array_equal(model.step(f), relative(frames[0].odometry, f.odometry))
    moved = dataclasses.replace(f, odometry=f.odometry + np.array([0.1, 0.0, 0.0]))
    np.testing.assert_array_equal(model.step(moved), relative(frames[0].odometry, moved.odometry))
    model.previous[0] += 0.5  # the previous reading changed in place
    np.testing.assert_array_equal(model.step(f), relative(model.previous, f.odometry))
    model.advance(f)
    np.testing.assert_array_equal(model.step(frames[2]), relative(frames[1].odometry, frames[2].odometry))


def test_initial_pose(frames):
    start = np.array([1.0, 2.0, 0.5])
    res = run_slam(frames[:10], SlamConfig(), rng=0, initial_pose=start, progress=False)
    np.testing.assert_array_equal(res.trajectory.poses[0], start)


def test_outputs_written(tmp_path, frames):
    res = run_slam(frames[:30], SlamConfig(), rng=0, progress=False)
    paths = write_slam_outputs(res, tmp_path)
    traj = read_tum(paths["trajectory"], dof=3)
    np.testing.assert_allclose(traj.poses, res.trajectory.poses, atol=1e-6)
    metrics = json.loads(paths["metrics"].read_text())
    assert metrics["frames"] == 30 and len(metrics["per_frame"]["seconds"]) == 30
    assert metrics["config"]["dof"] == 3 and metrics["peak_memory_mb"] > 0
    import open3d as o3d

    assert len(o3d.io.read_point_cloud(str(paths["map"])).points) == metrics["map_points"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["config.yaml", "map.ply", "metrics.json",
                                                           "trajectory.tum"]


def _room_frames_3d(n: int = 14):
    rng = np.random.default_rng(0)
    truth = []
    frames = []
    for i in range(n):
        pose = np.array([2.5 + 0.25 * i, 2.0 + 0.1 * np.sin(i / 3), 0.0, 0.0, 0.0, 0.3 + 0.05 * i])
        sensor = compose(pose, np.array([0.0, 0.0, 1.6, 0.0, 0.0, 0.0]))
        cloud = sensor_cloud(room_cloud_3d(6000, viewpoint=sensor[:3], noise=0.01, rng=rng), sensor)
        frames.append(Frame(stamp=float(i), cloud3d=cloud, index=i, extrinsic3d=np.array([0, 0, 1.6, 0, 0, 0.0])))
        truth.append(pose)
    return frames, truth


def test_slam_6dof_in_a_room():
    frames, truth = _room_frames_3d()
    res = run_slam(frames, SlamConfig(dof=6), rng=0, progress=False)
    est, truth = res.trajectory.poses, np.asarray(truth)
    err = relative(est[0], est) - relative(truth[0], truth)
    err[:, 3:] = wrap_angle(err[:, 3:])
    assert np.abs(err[:, :3]).max() < 0.03
    assert np.rad2deg(np.abs(err[:, 3:]).max()) < 0.5


def test_the_number_of_threads_changes_nothing(monkeypatch):
    """6-DOF HS-SLAM on one thread and on two, every KD-tree query split between the threads: the same
    trajectory, bit for bit (the parallel harmony batches: tests/test_fitness.py)."""
    from hsmap.registration import neighbours

    monkeypatch.setattr(neighbours, "TREE_PARALLEL_MIN_QUERIES", 1)
    frames, _ = _room_frames_3d(6)
    one, two = (run_slam(frames, SlamConfig(dof=6), rng=0, progress=False, threads=t) for t in (1, 2))
    np.testing.assert_array_equal(one.trajectory.poses, two.trajectory.poses)
    assert [f.fitness for f in one.frames] == [f.fitness for f in two.frames]


def test_prior_seeds_6dof():
    prior = Trajectory([0.0, 1.0], [[0, 0, 0], [0.5, 0.1, 0.2]])
    slam = HsSlam(SlamConfig(dof=6), prior=prior)
    slam.poses.append(np.zeros(6))
    slam.prediction.start(Frame(stamp=1.0, cloud3d=np.zeros((10, 3))))
    seeds, half = slam.prediction.seeds()
    np.testing.assert_allclose(seeds[0], [0.5, 0.1, 0, 0, 0, 0.2])
    assert half[0] == SlamConfig().prior_translation_range
    with pytest.raises(InputError, match="prior trajectory seeds 6-DOF runs only"):
        HsSlam(SlamConfig(dof=3), prior=prior)
    # a cloud between two prior poses (a 2D LiDAR runs faster than the 3D one): their SE(2) interpolation
    wide = HsSlam(SlamConfig(dof=6, sync_tolerance=0.5), prior=prior)
    wide.poses.append(np.zeros(6))
    wide.prediction.start(Frame(stamp=0.5, cloud3d=np.zeros((10, 3))))
    seeds, _ = wide.prediction.seeds()
    np.testing.assert_allclose(seeds[0][[0, 1, 5]], prior.interpolate([0.5], 0.5)[0][0])
    assert slam.prediction.prior_pose(0.5) is not None  # 0.5 s from both: two poses of the prior's cadence
    gap = Trajectory([0.0, 0.1, 0.2, 1.2, 1.3], np.zeros((5, 3)))  # poses every 0.1 s, none in 0.2 .. 1.2 s
    slam = HsSlam(SlamConfig(dof=6), prior=gap)
    slam.poses.append(np.zeros(6))
    assert slam.prediction.prior_pose(0.7) is None and slam.prediction.prior_pose(0.15) is not None


class _Stamped:
    """Frames that know their stamps up front, as readers do."""

    def __init__(self, frames):
        self._frames = frames
        self.stamps = np.array([f.stamp for f in frames])
        self.name = "stamped"

    def __iter__(self):
        return iter(self._frames)


def test_prior_coverage_is_checked_before_the_run(frames):
    from hsmap.errors import HsmapWarning
    from hsmap.slam import prior_coverage

    stamps = np.arange(10) * 0.1
    prior = Trajectory(np.arange(0, 0.45, 0.05), np.zeros((9, 3)))  # covers 0.0 .. 0.4 s
    with pytest.warns(HsmapWarning, match=r"--prior p.tum gives a pose to 5 of the 10 frames \(50.0 %\)"):
        info = prior_coverage(prior, stamps, 0.1, name="--prior p.tum")
    assert info == {"frames": 10, "frames_with_prior": 5, "coverage": 0.5, "sync_tolerance": 0.1}
    far = Trajectory(stamps + 100.0, np.zeros((10, 3)))
    with pytest.raises(InputError, match=r"--prior p.tum: none of the input's 10 frames .* sync tolerance of 0.1 s"):
        prior_coverage(far, stamps, 0.1, name="--prior p.tum")
    # run_slam checks a dataset that knows its stamps before it processes any frame
    ds = _Stamped([dataclasses.replace(f, cloud3d=np.zeros((5, 3))) for f in frames[:3]])
    with pytest.raises(InputError, match="prior: none of the input's 3 frames"):
        run_slam(ds, SlamConfig(dof=6), prior=Trajectory(ds.stamps + 50, np.zeros((3, 3))), progress=False)


def test_bad_inputs(frames):
    with pytest.raises(InputError, match="has no 2D scan"):
        run_slam([Frame(stamp=0.0)], SlamConfig(), progress=False, strict=True)
    with pytest.raises(InputError, match="has no 3D cloud"):
        run_slam(frames[:2], SlamConfig(dof=6), progress=False, strict=True)
    empty = Frame(stamp=0.0, scan2d=LaserScan2D(np.full(10, np.nan), np.linspace(-1, 1, 10)))
    with pytest.raises(UnusableFrameError, match=r"frame 0 .* has 0 usable points \(of its 10 readings, 10 are NaN"):
        run_slam([empty], SlamConfig(), progress=False, strict=True)
    # not strict: every frame skipped is still an error, naming the first one's cause
    with pytest.warns(HsmapWarning, match="frame skipped"), \
            pytest.raises(UnusableFrameError, match="none of its 2 frames could be used; the first: frame 0"):
        run_slam([empty, empty], SlamConfig(), progress=False)
    with pytest.raises(EmptyInputError, match="the input has no frames"):
        run_slam([], SlamConfig(), progress=False)
    with pytest.raises(InputError, match="initial_pose must have 3 values"):
        HsSlam(SlamConfig(), initial_pose=np.zeros(6))


def test_unusable_frames_are_skipped_counted_and_named(frames):
    """One all-NaN scan, one scan whose points coincide and one frame without a scan in the middle of a run: each
    is skipped with a warning giving the cause, counted in the metrics, and the other frames are tracked as
    well as without them; strict=True stops at the first one instead."""
    bad = dict(enumerate(frames[:40]))
    n = len(frames[20].scan2d.ranges)
    bad[20] = dataclasses.replace(frames[20], scan2d=LaserScan2D(np.full(n, np.nan), frames[20].scan2d.angles))
    bad[25] = dataclasses.replace(frames[25], scan2d=LaserScan2D(np.full(n, 2.0), np.zeros(n)))
    bad[30] = dataclasses.replace(frames[30], scan2d=None)
    with pytest.warns(HsmapWarning) as caught:
        res = run_slam(list(bad.values()), SlamConfig(), rng=1, progress=False)
    messages = [str(w.message) for w in caught]
    assert len(messages) == 3 and all(m.endswith("frame skipped") for m in messages)
    assert "frame 20 (stamp 110.0) has 0 usable points (of its 1081 readings, 1081 are NaN" in messages[0]
    assert "frame 25 (stamp 112.5) has 1 usable points" in messages[1]
    assert "frame 30 (stamp 115.0) has no 2D scan" in messages[2]
    m = res.metrics()
    assert m["skipped_frames"] == 3 and [k["index"] for k in m["skipped"]] == [20, 25, 30]
    assert m["frames"] == 37
    kept = [i for i in range(40) if i not in (20, 25, 30)]
    np.testing.assert_array_equal(res.trajectory.stamps, [frames[i].stamp for i in kept])
    err = relative_errors(res.trajectory.poses, ROUTE[kept])
    assert np.abs(err[:, :2]).max() < 0.03, np.abs(err[:, :2]).max(0)
    with pytest.raises(UnusableFrameError, match="frame 20 .* has 0 usable points") as info:
        run_slam(list(bad.values()), SlamConfig(), rng=1, progress=False, strict=True)
    assert info.value.index == 20 and info.value.stamp == 110.0


def test_points_on_one_line_are_unusable():
    """A scan with plenty of points, all on one straight line (a beam geometry gone wrong), is not registered."""
    n = 200
    line = Frame(stamp=1.0, scan2d=LaserScan2D(np.linspace(1.0, 5.0, n), np.full(n, 0.3)), index=1)
    with pytest.raises(UnusableFrameError, match="all on one line"):
        HsSlam(SlamConfig()).process(line)


@pytest.mark.parametrize("kwargs, match", [
    (dict(dof=4), "slam.dof must be 3"),
    (dict(keyframe_distance=-1.0), "slam.keyframe_distance must be a finite number >= 0"),
    (dict(keyframe_angle=float("inf")), "slam.keyframe_angle must be a finite number >= 0"),
    (dict(max_range=0.05), r"slam.max_range \(0.05\) must exceed slam.min_range"),
    (dict(warmup_frames=0), "slam.warmup_frames must be an integer >= 1"),
    (dict(map_voxel=0.0), "slam.map_voxel must be None or > 0"),
    (dict(odometry_scale_bounds=(2.0, 1.0)), "slam.odometry_scale_bounds must be two numbers 0 < low <= high"),
    (dict(odometry_window=0), "slam.odometry_window must be an integer >= 1"),
    (dict(graph={"pair_edges": -1}), "slam.graph.pair_edges must be an integer >= 0"),
    (dict(graph={"pair_edges": 2.5}), "slam.graph.pair_edges must be a whole number"),
    (dict(graph={"pair_distance": float("nan")}), "slam.graph.pair_distance must be a number"),
])
def test_bad_config(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        SlamConfig(**kwargs)
    with pytest.raises(ConfigError, match=match):  # a changed copy is validated too (hsmap slam --dof)
        dataclasses.replace(SlamConfig(), **kwargs)


def test_keyframe_spacing_defaults_by_dof_and_a_set_value_wins():
    assert (SlamConfig(dof=3).effective_keyframe_distance(), SlamConfig(dof=6).effective_keyframe_distance()) == (0.5, 1.0)
    assert np.rad2deg([SlamConfig(dof=3).effective_keyframe_angle(),
                       SlamConfig(dof=6).effective_keyframe_angle()]) == pytest.approx([15.0, 30.0])
    cfg = SlamConfig(dof=6, keyframe_distance=0.3, keyframe_angle=0.1)
    assert (cfg.effective_keyframe_distance(), cfg.effective_keyframe_angle()) == (0.3, 0.1)
    assert SlamConfig(dof=3, keyframe_distance=0.0).effective_keyframe_distance() == 0.0  # every frame


def test_one_search_box_knob_the_tracking_registration_config():
    from hsmap.config import from_dict
    from hsmap.registration.icp import RegistrationConfig

    cfg = SlamConfig(dof=3)
    assert cfg.registration.translation_range == 0.4  # the tracking box, not harmony_icp's 1.5 m default
    slam = HsSlam(SlamConfig(dof=3, registration=RegistrationConfig(translation_range=0.7)))
    slam.poses.append(np.zeros(3))
    slam.prediction.start(Frame(stamp=0.0, scan2d=None))
    _, half = slam.prediction.seeds()
    assert half[0] == half[1] == 0.7
    with pytest.raises(ConfigError, match=r"unknown key\(s\) \['translation_range'\]"):
        from_dict(SlamConfig, {"translation_range": 0.5}, "slam")


def write_carmen(path, route, odometry_drift=0.0):
    """A CARMEN log of FLASER lines (180 beams over 180 deg, robot pose = odometry) along ``route``."""
    rng = np.random.default_rng(0)
    lines = ["# synthetic office", "PARAM robot_front_laser_max 10.0 0 host 0"]
    for i, pose in enumerate(route):
        r, _ = raycast_2d(SEGMENTS, pose, fov=np.pi, beams=180, noise=0.01, rng=rng)
        r = np.where(np.isfinite(r), r, 81.83)  # no return
        odom = pose + [0.0, 0.0, odometry_drift * i]
        t = 1000.0 + 0.2 * i
        lines.append("FLASER 180 " + " ".join(f"{v:.3f}" for v in r) + f" {odom[0]:.4f} {odom[1]:.4f} {odom[2]:.5f}"
                     f" {odom[0]:.4f} {odom[1]:.4f} {odom[2]:.5f} {t:.6f} host {t:.6f}")
    path.write_text("\n".join(lines) + "\n")


def test_cli_slam_on_a_carmen_log(tmp_path):
    import subprocess
    import sys

    log = tmp_path / "office.log"
    route = ROUTE[:60]
    write_carmen(log, route, odometry_drift=np.deg2rad(0.3))
    out = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "hsmap.cli", "slam", str(log), "--out", str(out), "--quiet",
                        "--seed", "3"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    traj = read_tum(out / "trajectory.tum", dof=3)
    np.testing.assert_allclose(traj.stamps, 1000.0 + 0.2 * np.arange(len(route)), atol=1e-6)
    err = relative_errors(traj.poses, route)
    assert np.abs(err[:, :2]).max() < 0.05 and np.rad2deg(np.abs(err[:, 2]).max()) < 1.0
    assert (out / "slam.rrd").stat().st_size > 0 and (out / "map.ply").is_file()
    from hsmap.viz.rerun import rerun_binary, verify_rrd

    if rerun_binary() is not None:
        verify_rrd(out / "slam.rrd")
        from hsmap.viz.rerun import recording_contents

        # the blueprint's 2D map view has its map (not an empty view): the grid and the path
        entities = recording_contents(out / "slam.rrd")
        assert "/map/occupancy" in entities and "/map/paths/estimate" in entities
        assert "/world/map/occupancy" in entities
    # bad input: one line, no traceback, exit 2
    r = subprocess.run([sys.executable, "-m", "hsmap.cli", "slam", str(tmp_path / "missing.bag"), "--out",
                        str(out)], capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr.startswith("hsmap: error:") and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("flag, value, match", [
    ("--extrinsic2d", "0.1,0", "--extrinsic2d must be 3 comma-separated"),
    ("--extrinsic2d", "a,b,c", "--extrinsic2d must be 3 comma-separated numbers"),
    ("--extrinsic2d", "0,nan,0", "--extrinsic2d must be 3 comma-separated finite numbers"),
    ("--extrinsic3d", "0,0,1.6", "--extrinsic3d must be 6 comma-separated"),
])
def test_cli_slam_bad_extrinsic(tmp_path, flag, value, match):
    from hsmap.cli import main

    log = tmp_path / "office.log"
    write_carmen(log, ROUTE[:3])
    import contextlib
    import io

    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        assert main(["slam", str(log), "--out", str(tmp_path / "o"), flag, value, "--quiet"]) == 2
    assert match in err.getvalue() and len(err.getvalue().strip().splitlines()) == 1


def test_cli_slam_extrinsic_and_no_loop_closure(tmp_path):
    from hsmap.cli import main

    log = tmp_path / "office.log"
    write_carmen(log, ROUTE[:25])
    out = tmp_path / "o"
    assert main(["slam", str(log), "--out", str(out), "--extrinsic2d", "0.1,0,0", "--no-loop-closure",
                 "--no-recording", "--quiet"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["loop_closure"] == "disabled" and m["config"]["loop_closure"]["enabled"] is False
    assert "frames_retried" in m and m["loops_closed"] == 0


def test_interrupted_cli_run_leaves_the_previous_outputs_as_they_were(tmp_path, monkeypatch):
    """A run stopped half-way (here: Ctrl-C in the middle of the frames) publishes nothing: the previous run's
    files are left as they were and no temporary file is left behind."""
    import hsmap.slam as slam_mod
    from hsmap.cli import main

    log = tmp_path / "office.log"
    write_carmen(log, ROUTE[:20])
    out = tmp_path / "run"
    out.mkdir()
    (out / "metrics.json").write_text("{}")  # a previous run's
    real = slam_mod.HsSlam.process

    def failing(self, frame):
        if frame.index == 10:
            raise KeyboardInterrupt
        return real(self, frame)

    monkeypatch.setattr(slam_mod.HsSlam, "process", failing)
    assert main(["slam", str(log), "--out", str(out), "--quiet"]) == 130
    assert sorted(p.name for p in out.iterdir()) == ["metrics.json"]
    assert (out / "metrics.json").read_text() == "{}"


def test_6dof_keeps_the_height_where_the_scene_says_nothing_about_it():
    """The room's four walls alone (no floor, ceiling or furniture): a cloud fixes x, y, yaw, roll and pitch, not
    z. The height follows the prediction (the 2D prior's planar motion), and every tracking edge of the pose
    graph keeps some information in every direction: an edge with none in z would leave the graph free to move
    whole stretches of a building up or down when a loop closes."""
    from hsmap.slam.posegraph import EdgeKind

    rng = np.random.default_rng(3)
    frames, truth = [], []
    for i in range(12):
        pose = np.array([2.5 + 0.3 * i, 2.5 + 0.1 * np.sin(i / 3), 0.0, 0.0, 0.0, 0.2 + 0.04 * i])
        sensor = compose(pose, np.array([0.0, 0.0, 1.6, 0.0, 0.0, 0.0]))
        world = room_cloud_3d(12000, viewpoint=sensor[:3], noise=0.005, rng=rng)
        near_wall = np.minimum(np.minimum(world[:, 0], 8.0 - world[:, 0]), np.minimum(world[:, 1], 6.0 - world[:, 1]))
        world = world[(near_wall < 0.02) & (world[:, 2] > 0.3) & (world[:, 2] < 2.5)]
        frames.append(Frame(stamp=float(i), cloud3d=sensor_cloud(world, sensor), index=i,
                            extrinsic3d=np.array([0, 0, 1.6, 0, 0, 0.0])))
        truth.append(pose)
    truth = np.asarray(truth)
    prior = Trajectory(np.arange(12.0), truth[:, [0, 1, 5]])
    slam = HsSlam(SlamConfig(dof=6), rng=1, initial_pose=truth[0], prior=prior)
    for f in frames:
        slam.process(f)
    slam.finish()
    assert np.abs(slam.trajectory.poses[:, 2]).max() < 0.01
    edges = [e for e in slam.graph.edges if e.kind == EdgeKind.ODOMETRY]
    assert edges and all(np.linalg.eigvalsh(e.information).min() > 0 for e in edges)


def test_a_retried_registration_stays_in_the_box_it_searched(monkeypatch):
    """In a corridor the retry's refinement may slide along the axis the walls leave free; what it returns is
    kept within the prediction's box, so the odometry, not the slide, carries the pose along the corridor. A
    retry that left its box stands at the box's edge only if that aligns the scan better than the prediction
    itself: the edge is no pose the scan chose."""
    from hsmap.registration.icp import RegistrationTarget, harmony_icp
    from hsmap.slam import frame_points
    from hsmap.slam import verify as slam_module

    walls = np.array([((-20.0, y), (20.0, y)) for y in (-0.8, 0.8)])
    truth = np.array([0.0, 0.0, 0.0])
    rng = np.random.default_rng(3)
    r, a = raycast_2d(walls, truth, noise=0.005, rng=rng)
    frame = Frame(stamp=1.0, scan2d=LaserScan2D(r, a, 0.05, 10.0), odometry=truth.copy(), index=1)
    scan = frame_points(frame, 3, 0.1, 30.0, 0.03)
    slam = HsSlam(SlamConfig(), rng=0)
    slam.keyframe_graph.target = RegistrationTarget(np.vstack([np.column_stack([np.linspace(-15, 15, 601), np.full(601, y)])
                                                 for y in (-0.8, 0.8)]), slam.config.registration)
    sig = np.array([0.02, np.deg2rad(1.0)])
    predicted = truth.copy()
    monkeypatch.setattr(slam.prediction, "predict", lambda gate=False: (predicted.copy(), sig))
    slam.prediction.start(frame)
    first = harmony_icp(scan, slam.keyframe_graph.target, initial_guesses=[[0.9, 0.0, 0.0]], config=slam.config.registration,
                        rng=1)
    first = dataclasses.replace(first, pose=np.array([0.9, first.pose[1], first.pose[2]]))  # 0.9 m along
    slid = dataclasses.replace(first, pose=np.array([0.5, 0.002, 0.0005]))  # the retry's refinement slid too
    monkeypatch.setattr(slam_module, "harmony_icp", lambda *a, **k: slid)
    half = np.array([3 * sig[0], 3 * sig[0], 3 * sig[1]])
    # the prediction aligns the scan better than the box's edge (which is 2 mm and 0.03 deg off the walls): kept
    kept, retried, verified = slam.verifier.verify(scan, slam.keyframe_graph.target, first, slam.rng)
    assert retried and verified
    np.testing.assert_allclose(kept.pose, predicted)
    np.testing.assert_allclose(kept.transformation[:2, 2], predicted[:2])
    # a prediction 4 cm off the corridor's centre line aligns it worse: the edge stands, x at the box's edge, y and
    # yaw as the retry found them
    predicted = np.array([0.0, 0.04, 0.0])
    kept, retried, _ = slam.verifier.verify(scan, slam.keyframe_graph.target, first, slam.rng)
    assert retried
    np.testing.assert_allclose(kept.pose, [half[0], 0.002, 0.0005])
    np.testing.assert_allclose(kept.transformation[:2, 2], kept.pose[:2])
    # a result inside the box is returned as it is
    inside = dataclasses.replace(first, pose=np.array([0.03, -0.01, 0.01]))
    assert slam_module.within_box(inside, truth, half, 2) is inside
    # the box is the search's, in world axes, and yaw wraps
    out = slam_module.within_box(dataclasses.replace(first, pose=np.array([1.0, -1.0, np.pi - 0.01])),
                                  np.array([0.0, 0.0, -np.pi + 0.01]), np.array([0.1, 0.2, 0.05]), 2)
    np.testing.assert_allclose(out.pose, [0.1, -0.2, np.pi - 0.01])


def _corridor_scan(cfg):
    """A scan from the middle of a 1.6 m corridor along x (its pose, the origin), its points and the walls as a
    registration target."""
    from hsmap.registration.icp import RegistrationTarget
    from hsmap.slam import frame_points

    walls = np.array([((-20.0, y), (20.0, y)) for y in (-0.8, 0.8)])
    truth = np.array([0.0, 0.0, 0.0])
    r, a = raycast_2d(walls, truth, noise=0.005, rng=np.random.default_rng(3))
    frame = Frame(stamp=1.0, scan2d=LaserScan2D(r, a, 0.05, 10.0), odometry=truth.copy(), index=1)
    scan = frame_points(frame, 3, 0.1, 30.0, cfg.effective_scan_voxel())
    target = RegistrationTarget(np.vstack([np.column_stack([np.linspace(-15, 15, 601), np.full(601, y)])
                                           for y in (-0.8, 0.8)]), cfg.registration)
    return truth, scan, target


class _FixedPrediction:
    """A motion prediction (:class:`hsmap.slam.prediction.MotionPrediction`) that predicts ``pose`` with ``sigma``
    (translation, rotation), a tracking box of ``half``, from a prior trajectory (``prior``) or the wheels, whose
    wheels consent to overrule it (``consent``) and set no step aside."""

    def __init__(self, pose, sigma, half, *, prior, consent=True):
        self.pose, self.sigma, self.half, self.consent = pose, sigma, half, consent
        self.prior = Trajectory([0.0], [[0.0, 0.0, 0.0]]) if prior else None

    def predict(self, gate=False):
        return self.pose.copy(), self.sigma

    def tracking_box(self):
        return self.half.copy()

    def set_aside(self, res):
        return False

    def consents(self, res):
        return self.consent


def test_a_prior_s_prediction_stands_against_a_retry_that_slid_beyond_its_gate(monkeypatch):
    """A prediction from a prior trajectory (another SLAM run) does not slip as wheels do. In a corridor the
    retry's refinement slides along the free axis, inside its box (at least two voxels wide) but beyond the
    prediction's gate: with a prior the prediction stands unless the slide aligns the scan clearly better; with
    wheel odometry the slide stands."""
    from hsmap.geometry import pose_to_matrix
    from hsmap.registration.icp import harmony_icp
    from hsmap.slam import verify as slam_module

    cfg = SlamConfig()
    truth, scan, target = _corridor_scan(cfg)
    sig = np.array([0.005, np.deg2rad(0.5)])  # a gate of verify_sigmas x 5 mm, a box of two voxels
    gate, box = cfg.verify_sigmas * sig[0], 2 * cfg.effective_scan_voxel()
    assert gate < 0.04 < box
    first = harmony_icp(scan, target, initial_guesses=[[0.9, 0.0, 0.0]], config=cfg.registration, rng=1)
    first = dataclasses.replace(first, pose=np.array([0.9, first.pose[1], first.pose[2]]))  # 0.9 m along
    slid = dataclasses.replace(first, pose=np.array([0.04, 0.0, 0.0]),  # in the box, beyond the gate
                               transformation=pose_to_matrix(np.array([0.04, 0.0, 0.0])))
    monkeypatch.setattr(slam_module, "harmony_icp", lambda *a, **k: slid)
    half = np.array([0.3, 0.3, np.deg2rad(4.0)])
    for prior, expected in ((True, truth), (False, slid.pose)):
        verifier = slam_module.Verifier(cfg, _FixedPrediction(truth, sig, half, prior=prior))
        kept, retried, verified = verifier.verify(scan, target, first, np.random.default_rng(0))
        assert retried and verified
        np.testing.assert_allclose(kept.pose, expected, atol=1e-12)
        np.testing.assert_allclose(kept.transformation[:2, 2], expected[:2], atol=1e-12)


def test_a_prior_s_prediction_is_overruled_only_with_the_wheels_consent(monkeypatch):
    """In a run seeded by a prior, a pose beyond the prediction's gate that aligns the scan clearly better, the
    retry's or the first registration's, stands only where ``overrule`` (the wheels) confirms it."""
    from hsmap.geometry import pose_to_matrix
    from hsmap.slam import verify as slam_module

    cfg = SlamConfig()
    truth, scan, target = _corridor_scan(cfg)
    predicted = np.array([0.0, 0.05, 0.0])  # 5 cm off the corridor's centre line: the truth aligns clearly better
    sig = np.array([0.005, np.deg2rad(0.5)])
    half = np.array([0.3, 0.3, np.deg2rad(4.0)])

    def result(pose):
        return dataclasses.replace(_registration_at(scan, target, cfg), pose=np.asarray(pose, dtype=float),
                                   transformation=pose_to_matrix(np.asarray(pose, dtype=float)))

    # the retry ends at the truth, beyond the gate; or it confirms the prediction and the first registration, at
    # the truth, aligns the scan clearly better: either stands with the wheels' consent, else the prediction
    for retry in (truth, predicted):
        monkeypatch.setattr(slam_module, "harmony_icp", lambda *a, retry=retry, **k: result(retry))
        for consent, expected in ((True, truth), (False, predicted)):
            verifier = slam_module.Verifier(cfg, _FixedPrediction(predicted, sig, half, prior=True, consent=consent))
            kept, retried, _ = verifier.verify(scan, target, result(truth), np.random.default_rng(0))
            assert retried
            np.testing.assert_allclose(kept.pose, expected, atol=1e-12)


def _registration_at(scan, target, cfg):
    from hsmap.registration.icp import harmony_icp

    return harmony_icp(scan, target, initial_guesses=[[0.0, 0.0, 0.0]], config=cfg.registration, rng=1)


def test_the_wheels_replace_a_prior_s_step_that_jumped():
    """A 6-DOF run seeded by a prior: where the frame's odometry step contradicts the prior's and confirms the
    registration, the odometry predicts the frame; where it confirms the prior, or the frame has none, the prior
    does."""
    prior = Trajectory([0.0, 1.0, 2.0], [[0, 0, 0], [0.5, 0, 0], [1.2, 0, 0]])  # the second step jumped 0.2 m
    slam = HsSlam(SlamConfig(dof=6), prior=prior)
    slam.poses += [np.zeros(6), np.array([0.5, 0, 0, 0, 0, 0])]
    slam.stamps += [0.0, 1.0]
    slam.odometry.previous = np.array([10.0, 0.0, 0.0])

    def registered(x):  # a registration's pose is all the check reads
        return types.SimpleNamespace(pose=np.array([x, 0, 0, 0, 0, 0.0]))

    def frame(odometry):
        return Frame(stamp=2.0, cloud3d=np.zeros((10, 3)), odometry=odometry, index=2)

    def contradicted(frame, res):
        motion.start(frame)
        motion.first_registration(res)
        return not motion.use_prior

    motion = slam.prediction
    wheels = frame(np.array([10.5, 0.0, 0.0]))  # the wheels moved 0.5 m, as the robot did
    assert contradicted(wheels, registered(1.0))
    np.testing.assert_allclose(motion.predict()[0], [1.0, 0, 0, 0, 0, 0], atol=1e-12)  # the wheels predict
    assert not contradicted(wheels, registered(1.2))  # the registration sides with the prior
    np.testing.assert_allclose(motion.predict()[0], [1.2, 0, 0, 0, 0, 0], atol=1e-12)
    assert not contradicted(frame(np.array([10.7, 0.0, 0.0])), registered(1.0))  # wheels agree
    assert not contradicted(frame(None), registered(1.0))


def test_a_registration_overrules_the_prediction_only_on_evidence():
    """The first registration stands against the motion prediction only if its residuals are lower beyond
    chance, over enough points: a few points fitting better, or a handful of matches, do not overrule the
    odometry."""
    from hsmap.slam import verify as slam_module

    def decide(ra, rb, n=100):  # residuals of a 2D scan of n points at the registration's pose and the other's
        assert len(ra) == len(rb) == n
        return slam_module.at_least_as_good(ra, rb, 2, strict=True)

    rng = np.random.default_rng(0)
    noise = rng.normal(0.0, 0.002, 100)
    assert decide(0.010 + noise, 0.020 + noise)  # every point fits better: clearly better
    # five points of a hundred fit much better, the rest alike: lower by half on average, but not beyond chance
    ra, rb = np.full(100, 0.001), np.full(100, 0.001)
    rb[:5] = 0.09
    assert rb.mean() > 2 * ra.mean()
    assert not decide(ra, rb)
    # better everywhere, but on 20 points: too few to tell
    assert not decide((0.010 + noise)[:20], (0.020 + noise)[:20], n=20)
    # better everywhere it matches, but half the scan matches at neither pose: the scan says too little
    ra_half, rb_half = 0.010 + noise, 0.020 + noise
    ra_half[:50] = rb_half[:50] = np.nan
    assert not decide(ra_half, rb_half)
    # points the first pose matches and the other does not (NaN) are not compared
    rb_lost = 0.020 + noise
    rb_lost[:80] = np.nan
    assert not decide(0.010 + noise, rb_lost)


def test_a_registration_that_explains_little_of_its_scan_cannot_veto_the_prediction(monkeypatch):
    """The robot drives out of the mapped part of a corridor: at the prediction (the truth) few of the scan's points
    have map beside them; the first registration, pulled back onto the mapped part, matches more, but still not
    the 60 % it needs to overrule the prediction. It cannot veto it either: the prediction's pose is confirmed, so
    it can become a keyframe and extend the map. Where the registration explains most of its scan and the
    prediction's pose aligns it worse, the prediction stays unconfirmed (no keyframe) as before."""
    from hsmap.registration.icp import RegistrationTarget, harmony_icp
    from hsmap.slam import frame_points
    from hsmap.slam import verify as slam_module

    walls = np.array([((-20.0, y), (20.0, y)) for y in (-1.0, 1.0)])
    truth = np.array([0.0, 0.0, 0.0])
    r, a = raycast_2d(walls, truth, fov=2 * np.pi, noise=0.005, rng=np.random.default_rng(3))
    frame = Frame(stamp=1.0, scan2d=LaserScan2D(r, a, 0.05, 10.0), odometry=truth.copy(), index=1)
    scan = frame_points(frame, 3, 0.1, 30.0, 0.03)

    def verify(mapped_to):
        """The verifier's check with the map holding the corridor's walls up to x = ``mapped_to``, the first registration
        2 m back along it and the retry returning the prediction."""
        slam = HsSlam(SlamConfig(), rng=0)
        xs = np.arange(-15.0, mapped_to, 0.05)
        slam.keyframe_graph.target = RegistrationTarget(np.vstack([np.column_stack([xs, np.full(len(xs), y)]) for y in (-1.0, 1.0)]),
                                          slam.config.registration)
        monkeypatch.setattr(slam.prediction, "predict", lambda gate=False: (truth.copy(), np.array([0.02, 0.02])))
        found = harmony_icp(scan, slam.keyframe_graph.target, initial_guesses=[truth], config=slam.config.registration, rng=1)
        back = dataclasses.replace(found, pose=np.array([-2.0, 0.0, 0.0]))
        monkeypatch.setattr(slam_module, "harmony_icp", lambda *a, **k: dataclasses.replace(found, pose=truth.copy()))
        fractions = [float(np.isfinite(slam_module.residuals(scan, slam.keyframe_graph.target, p, 0.1)).mean())
                     for p in (back.pose, truth)]
        slam.prediction.start(frame)
        return slam.verifier.verify(scan, slam.keyframe_graph.target, back, slam.rng), fractions

    (kept, retried, confirmed), (f_back, f_truth) = verify(mapped_to=-3.0)
    assert f_truth + 0.1 < f_back < slam_module.STRICT_MIN_MATCHED  # more matches 2 m back, but under 60 %
    assert retried and confirmed
    np.testing.assert_allclose(kept.pose, truth)
    # mapped up to the robot: 2 m back explains most of the scan and the prediction far less (half of it): the
    # prediction is not confirmed
    (kept, retried, confirmed), (f_back, f_truth) = verify(mapped_to=0.0)
    assert f_back >= slam_module.STRICT_MIN_MATCHED and f_truth + 0.1 < f_back
    assert retried and not confirmed


def test_a_registration_that_explains_little_of_its_scan_stays_within_the_learned_odometry(monkeypatch):
    """A registration inside the configured odometry model's gate, but further from the prediction than the
    odometry as this run has learned it allows, is retried around the prediction when it explains less than
    ``STRICT_MIN_MATCHED`` of its scan (a scan entering an unmapped room); a registration explaining most of its
    scan stands."""
    from hsmap.registration.icp import RegistrationTarget, harmony_icp
    from hsmap.slam import frame_points
    from hsmap.slam import verify as slam_module

    walls = np.array([((-20.0, y), (20.0, y)) for y in (-1.0, 1.0)] + [((-20.0, -1.0), (-20.0, 1.0))])
    truth = np.array([0.0, 0.0, 0.0])
    r, a = raycast_2d(walls, truth, fov=2 * np.pi, noise=0.005, rng=np.random.default_rng(3))
    frame = Frame(stamp=1.0, scan2d=LaserScan2D(r, a, 0.05, 10.0), odometry=truth.copy(), index=1)
    scan = frame_points(frame, 3, 0.1, 30.0, 0.03)
    configured, learned = np.array([0.05, np.deg2rad(1.5)]), np.array([0.01, np.deg2rad(0.2)])

    def verify(mapped_to):
        slam = HsSlam(SlamConfig(), rng=0)
        xs = np.arange(-15.0, mapped_to, 0.05)
        slam.keyframe_graph.target = RegistrationTarget(np.vstack([np.column_stack([xs, np.full(len(xs), y)]) for y in (-1.0, 1.0)]),
                                          slam.config.registration)
        monkeypatch.setattr(slam.prediction, "predict",
                            lambda gate=False: (truth.copy(), (configured if gate else learned).copy()))
        found = harmony_icp(scan, slam.keyframe_graph.target, initial_guesses=[truth], config=slam.config.registration, rng=1)
        turned = dataclasses.replace(found, pose=np.array([0.0, 0.06, np.deg2rad(1.8)]))  # inside the wide gate
        monkeypatch.setattr(slam_module, "harmony_icp", lambda *a, **k: dataclasses.replace(found, pose=truth.copy()))
        share = float(np.isfinite(slam_module.residuals(scan, slam.keyframe_graph.target, turned.pose, 0.1)).mean())
        slam.prediction.start(frame)
        return slam.verifier.verify(scan, slam.keyframe_graph.target, turned, slam.rng), share, turned

    (kept, retried, confirmed), share, _ = verify(mapped_to=-3.0)
    assert share < slam_module.STRICT_MIN_MATCHED
    assert retried and confirmed
    np.testing.assert_allclose(kept.pose, truth)
    (kept, retried, confirmed), share, turned = verify(mapped_to=15.0)
    assert share >= slam_module.STRICT_MIN_MATCHED
    assert not retried and confirmed and kept is turned


def test_a_run_seeded_by_a_2d_run_keeps_its_keyframes_on_the_floor():
    """Seeded by a 2D run (a robot on one floor), every keyframe but the first gets a unary edge holding its
    height, roll and pitch to the first pose's, and none on x, y, yaw; a run without a prior gets none."""
    from hsmap.slam.posegraph import EdgeKind
    from hsmap.slam.tracker import FLOOR_SIGMA

    frames, truth = _room_frames_3d(6)
    truth = np.asarray(truth)
    start = truth[0] + np.array([0.0, 0.0, 0.05, 0.01, -0.02, 0.0])  # the floor's plane, as the run starts on it
    slam = HsSlam(SlamConfig(dof=6), rng=0, initial_pose=start,
                  prior=Trajectory(np.arange(6.0), truth[:, [0, 1, 5]]))
    for f in frames:
        slam.process(f)
    floor = [e for e in slam.graph.edges if e.kind == EdgeKind.PRIOR and e.i > 0]
    assert len(floor) == len(slam.keyframes) - 1 >= 2 and all(e.i == e.j for e in floor)
    for e in floor:
        np.testing.assert_allclose(e.measurement[2:5], start[2:5])
        np.testing.assert_allclose(np.diag(e.information)[2:5], 1.0 / np.array(FLOOR_SIGMA)[[0, 1, 1]] ** 2)
        assert np.diag(e.information)[[0, 1, 5]].max() < 1e-6
    plain = HsSlam(SlamConfig(dof=6), rng=0)
    for f in frames:
        plain.process(f)
    assert not [e for e in plain.graph.edges if e.kind == EdgeKind.PRIOR and e.i > 0]


def test_level_floor_off_adds_no_floor_edges():
    """``level_floor: false`` (ramps, several floors): a run seeded by a 2D run holds no keyframe to the floor."""
    from hsmap.slam.posegraph import EdgeKind

    frames, truth = _room_frames_3d(6)
    truth = np.asarray(truth)
    slam = HsSlam(SlamConfig(dof=6, level_floor=False), rng=0, initial_pose=truth[0],
                  prior=Trajectory(np.arange(6.0), truth[:, [0, 1, 5]]))
    for f in frames:
        slam.process(f)
    assert len(slam.keyframes) >= 3
    assert not [e for e in slam.graph.edges if e.kind == EdgeKind.PRIOR and e.i > 0]


def test_a_handheld_turn_with_roll_is_tracked_without_a_prior():
    """A sensor carried by hand (no odometry, no prior): smooth steps, then one sweep turned 35 deg in yaw with
    10 deg of roll and 8 deg of pitch, far outside the configured box around the constant-velocity prediction.
    The failed registration is searched again in wider boxes, and every frame is tracked to within 5 cm and
    1 deg."""
    rng = np.random.default_rng(4)
    poses = []
    for i in range(9):
        turn = 1.0 if i >= 5 else 0.0
        poses.append(np.array([2.5 + 0.2 * i, 2.0 + 0.05 * i, 1.5 + 0.02 * np.sin(i), np.deg2rad(10.0) * turn
                               + np.deg2rad(1.0) * np.sin(i), np.deg2rad(-8.0) * turn, 0.1 + 0.03 * i
                               + np.deg2rad(35.0) * turn]))
    frames = [Frame(stamp=float(i), index=i, extrinsic3d=np.zeros(6),
                    cloud3d=sensor_cloud(room_cloud_3d(6000, viewpoint=p[:3], noise=0.01, rng=rng), p))
              for i, p in enumerate(poses)]
    slam = HsSlam(SlamConfig(dof=6, use_odometry=False), rng=0, initial_pose=poses[0])
    for f in frames:
        slam.process(f)
    assert slam.results[5].retried
    for est, truth in zip(slam.poses, poses, strict=True):
        d = relative(truth, est)
        assert np.linalg.norm(d[:3]) < 0.05
        assert np.rad2deg(np.abs(wrap_angle(d[3:]))).max() < 1.0


def _handheld_run(turn_deg: float, **config) -> tuple[HsSlam, list[np.ndarray]]:
    """A sensor carried by hand through the room (no odometry, no prior): five smooth steps, then a
    sweep turned by ``turn_deg`` in yaw with 6 deg of roll."""
    rng = np.random.default_rng(4)
    poses = []
    for i in range(6):
        turn = 1.0 if i >= 5 else 0.0
        poses.append(np.array([2.5 + 0.2 * i, 2.0 + 0.05 * i, 1.5 + 0.02 * np.sin(i),
                               np.deg2rad(6.0) * turn + np.deg2rad(1.0) * np.sin(i), 0.0,
                               0.1 + 0.03 * i + np.deg2rad(turn_deg) * turn]))
    frames = [Frame(stamp=float(i), index=i, extrinsic3d=np.zeros(6),
                    cloud3d=sensor_cloud(room_cloud_3d(3000, viewpoint=p[:3], noise=0.01, rng=rng), p))
              for i, p in enumerate(poses)]
    slam = HsSlam(SlamConfig(dof=6, use_odometry=False, **config), rng=0, initial_pose=poses[0])
    for f in frames:
        slam.process(f)
    return slam, poses


def test_a_handheld_turn_beyond_the_widest_box_is_found_on_the_yaw_circle():
    """A 110 deg turn in one sweep lies beyond every widened box around the constant-velocity prediction: the
    search over the rest of the yaw circle finds it, and every frame is tracked to within 5 cm and 1 deg; without
    that search the turn is lost."""
    slam, poses = _handheld_run(110.0)
    assert slam.results[5].retried and slam.results[5].verified
    for est, truth in zip(slam.poses, poses, strict=True):
        d = relative(truth, est)
        assert np.linalg.norm(d[:3]) < 0.05
        assert np.rad2deg(np.abs(wrap_angle(d[3:]))).max() < 1.0
    lost, _ = _handheld_run(110.0, global_search=False)
    d = relative(poses[5], lost.poses[5])
    assert np.rad2deg(np.abs(wrap_angle(d[5]))) > 5.0


def test_the_yaw_sectors_cover_the_circle_beyond_the_box():
    """The sectors a box leaves of the yaw circle: contiguous from its upper yaw bound around to its lower one,
    none wider than the box, the other bounds as the box's; none where the box spans the circle."""
    from hsmap.slam.search import SearchBox

    box = np.column_stack([-np.ones(6), np.ones(6)])
    box[5] = [0.2, 0.2 + np.deg2rad(100.0)]
    sectors = SearchBox._yaw_sectors(box)
    assert len(sectors) == 3
    np.testing.assert_allclose(sectors[0][5, 0], box[5, 1])
    np.testing.assert_allclose(sectors[-1][5, 1], box[5, 0] + 2 * np.pi)
    for a, b in zip(sectors[:-1], sectors[1:], strict=True):
        np.testing.assert_allclose(a[5, 1], b[5, 0])
    for s in sectors:
        assert s[5, 1] - s[5, 0] <= np.deg2rad(100.0) + 1e-9
        np.testing.assert_array_equal(s[:5], box[:5])
    box[5] = [-np.pi, np.pi]
    assert SearchBox._yaw_sectors(box) == []


def _search_box(ratios=(0.8,) * 5, **kw):
    """A SearchBox that has seen confirmed frames of the inlier ``ratios``."""
    from hsmap.slam.costs import Costs
    from hsmap.slam.search import SearchBox

    b = SearchBox(SlamConfig(dof=kw.pop("dof", 6)), Costs(), **kw)
    for r in ratios:
        b.record(r, True)
    return b


def _room_target(pose):
    """A room's cloud as a registration target and the cloud seen from ``pose`` (its sensor frame)."""
    from hsmap.registration.icp import RegistrationTarget

    rng = np.random.default_rng(3)
    room = room_cloud_3d(6000, viewpoint=pose[:3], noise=0.005, rng=rng)
    target = RegistrationTarget(room, SlamConfig(dof=6).registration)
    return target, sensor_cloud(room_cloud_3d(3000, viewpoint=pose[:3], noise=0.005, rng=rng), pose)


def test_a_hand_held_frame_keeps_the_candidate_that_aligns_its_scan_best():
    """A sensor carried by hand: between the box's registration and the motion check's retry around the
    prediction, both passing the inlier check, the frame keeps the one that aligns its scan best with the target,
    whichever came first, and confirms it; a ground robot (3-DOF, or seeded by a 2D run) keeps what the motion
    check left."""
    truth = np.array([2.5, 2.0, 1.5, 0.02, -0.01, 0.3])
    target, scan = _room_target(truth)
    off = compose(truth, np.array([0.05, -0.08, 0.0, 0.0, 0.0, np.deg2rad(3.0)]))
    good, bad = (types.SimpleNamespace(pose=p, inlier_ratio=0.8) for p in (truth, off))
    assert _search_box().settled(scan, target, good, bad, False) == (good, True)
    assert _search_box().settled(scan, target, bad, good, False) == (good, True)
    assert _search_box().settled(scan, target, good, good, False) == (good, False)
    assert _search_box(prior=True).settled(scan, target, good, bad, False) == (bad, False)
    assert _search_box(dof=3).settled(scan, target, good, bad, False) == (bad, False)


def test_a_hand_held_candidate_that_fails_the_inlier_check_is_not_confirmed_for_scoring_best():
    """The candidate that aligns the scan best is confirmed only where it passes the inlier check, the motion
    check confirmed it, or the two candidates agree."""
    truth = np.array([2.5, 2.0, 1.5, 0.0, 0.0, 0.1])
    target, scan = _room_target(truth)
    off = compose(truth, np.array([0.3, 0.0, 0.0, 0.0, 0.0, np.deg2rad(8.0)]))
    weak, worse = (types.SimpleNamespace(pose=p, inlier_ratio=0.5) for p in (truth, off))
    assert _search_box().settled(scan, target, weak, worse, True) == (weak, False)
    assert _search_box().settled(scan, target, worse, weak, True) == (weak, True)


def test_a_hand_held_inlier_drop_beyond_the_recent_spread_fails_the_check():
    """A sensor carried by hand: where the recent frames' inlier ratios hardly vary, a registration well below
    them fails the check even above ``min_inlier_share`` of their median; where they vary widely, or for a ground
    robot, ``min_inlier_share`` alone decides."""
    tight = (0.80, 0.81, 0.79, 0.80, 0.805, 0.795)
    loose = (0.80, 0.95, 0.65, 0.90, 0.70, 0.85)
    drop = types.SimpleNamespace(inlier_ratio=0.72)  # 0.9 of the median
    assert not _search_box(tight).passes(drop)
    assert _search_box(tight).passes(types.SimpleNamespace(inlier_ratio=0.79))
    assert _search_box(loose).passes(drop)
    assert _search_box(tight, prior=True).passes(drop)
    assert _search_box(tight, dof=3).passes(drop)
    assert not _search_box(loose).passes(types.SimpleNamespace(inlier_ratio=0.6))


def test_a_hand_held_prediction_seeds_the_walk_at_the_held_orientation():
    """A sensor carried by hand: besides the last step repeated, the seeds hold the previous orientation and
    repeat the last step's translation in the world (the carrier walks on while the hand turns); a ground robot's
    seeds do not."""
    from hsmap.slam.odometry import OdometryModel
    from hsmap.slam.prediction import MotionPrediction

    a = np.array([0.0, 0.0, 1.5, 0.0, 0.0, 0.0])
    b = np.array([0.6, 0.1, 1.45, np.deg2rad(-10.0), 0.0, np.deg2rad(-40.0)])
    walk = np.array([1.2, 0.2, 1.4, b[3], b[4], b[5]])

    def seeds(**kw):
        cfg = SlamConfig(dof=6, use_odometry=False)
        pred = MotionPrediction(cfg, OdometryModel(cfg, learn=False, wheel_edges=False, prior=False),
                                _search_box(**kw))
        pred.poses.extend([a, b])
        pred.stamps.extend([0.0, 0.5])
        pred.start(Frame(stamp=1.0, index=2, extrinsic3d=np.zeros(6), cloud3d=np.zeros((10, 3))))
        return pred.seeds()[0]

    assert np.any(np.all(np.isclose(seeds(), walk), axis=1))
    assert not np.any(np.all(np.isclose(seeds(prior=True), walk), axis=1))


def test_a_hand_held_search_stops_where_two_searches_agree_short_of_a_lost_frame():
    """A registration a little below the recent inlier ratios is searched again until two searches agree (a
    scene that changed) and never over the yaw circle; one far below them (lost) goes on through every widened
    box and the yaw circle."""
    from hsmap.slam.costs import Costs
    from hsmap.slam.search import SearchBox

    calls = []

    class Box(SearchBox):
        def _search(self, scan, target, bounds, guesses, config, rng):
            calls.append(bounds)
            return types.SimpleNamespace(pose=np.zeros(6), inlier_ratio=ratio)

        def best(self, scan, target, candidates):
            return candidates[0]

    box = Box(SlamConfig(dof=6), Costs())
    for r in (0.80, 0.81, 0.79, 0.80, 0.805):
        box.record(r, True)
    guesses, half = np.zeros((2, 6)), np.full(6, 0.1)
    ratio = 0.74  # below the recent spread, above min_inlier_share of the median
    first = types.SimpleNamespace(pose=np.zeros(6), inlier_ratio=ratio)
    _, widened, confirmed = box.widened(None, None, first, guesses, half, np.random.default_rng(0))
    assert widened and confirmed and len(calls) == 1
    calls.clear()
    ratio = 0.5
    first = types.SimpleNamespace(pose=np.zeros(6), inlier_ratio=ratio)
    box.widened(None, None, first, guesses, half, np.random.default_rng(0))
    assert len(calls) > len(SlamConfig().widen_factors)


def test_the_tight_box_follows_the_prediction_s_uncertainty():
    """3-DOF: the tight box is the prediction +/- verify_sigmas gate sigmas (at least two scan voxels), where it is
    narrower than the configured box in every component; none without a prediction, with an uncertain one, or in
    6-DOF runs. A registration whose search ends at its edge, or short of the recent inliers, escapes it."""
    from hsmap.slam.costs import Costs
    from hsmap.slam.search import SearchBox

    cfg = SlamConfig()
    half = np.array([0.4, 0.4, np.deg2rad(20.0)])
    box = SearchBox(cfg, Costs())
    centre = np.array([1.0, 2.0, 0.5])
    tight = box.tight((centre, np.array([0.02, np.deg2rad(1.0)])), half)
    np.testing.assert_allclose(tight[:, 1] - centre, [0.06, 0.06, np.deg2rad(3.0)])
    np.testing.assert_allclose(centre - tight[:, 0], tight[:, 1] - centre)
    small = box.tight((centre, np.array([0.001, np.deg2rad(1.0)])), half)
    np.testing.assert_allclose(small[:2, 1] - centre[:2], 2 * cfg.effective_scan_voxel())
    assert box.tight((centre, np.array([0.2, np.deg2rad(1.0)])), half) is None  # 0.6 m > 0.4 m
    assert box.tight((centre, np.array([0.02, np.deg2rad(10.0)])), half) is None
    assert box.tight(None, half) is None
    assert SearchBox(SlamConfig(dof=6), Costs()).tight((np.zeros(6), np.array([0.01, 0.01])), np.ones(6)) is None
    scan = np.random.default_rng(0).uniform(-3, 3, (300, 2))
    inside = types.SimpleNamespace(global_pose=centre + [0.02, -0.01, 0.01], inlier_ratio=0.9)
    edge = types.SimpleNamespace(global_pose=centre + [0.055, 0.0, 0.0], inlier_ratio=0.9)
    for _ in range(5):
        box.record(0.9, True)
    assert not box.escapes(inside, tight, scan)
    assert box.escapes(edge, tight, scan)
    assert box.escapes(types.SimpleNamespace(global_pose=inside.global_pose, inlier_ratio=0.5), tight, scan)


def test_good_odometry_gets_the_tight_search_and_a_slip_the_full_one():
    """Precise odometry: most frames are registered by the small search in the tight box of the prediction; the
    step that slips 30 cm leaves that box and is searched again in the full one, and the run stays on the route."""
    frames = make_noisy_odometry_frames(np.deg2rad(0.05))
    for f in frames[90:]:
        f.odometry = compose([0.3, 0.0, 0.0], f.odometry)
    slam = HsSlam(SlamConfig(loop_closure={"enabled": False}), rng=1)
    escaped = []
    for f in frames:
        before = slam.costs.full_searches
        slam.process(f)
        escaped.append(slam.costs.full_searches > before)
    slam.finish()
    costs = slam.costs.as_dict()
    assert escaped[90]
    assert 1 <= costs["full_searches"] < 0.2 * len(frames)
    assert costs["harmony_evaluations"] < 200 * costs["registrations"]  # the full search alone: 300 or more
    err = relative_errors(slam.trajectory.poses, ROUTE[: len(frames)])
    assert np.abs(err[:, :2]).max() < 0.03, np.abs(err[:, :2]).max(0)


def test_the_inlier_check_follows_every_frame_recorded_after_it_was_asked():
    """The recent frames' inlier reference and floor, asked for several times a frame, change with each frame
    recorded: a drop that fails against high ratios passes once the recent ratios have fallen."""
    box = _search_box((0.8,) * 5, dof=3)
    drop = types.SimpleNamespace(inlier_ratio=0.5)
    assert not box.passes(drop) and box.inlier_reference() == pytest.approx(0.8)
    for _ in range(10):
        box.record(0.55, True)
    assert box.passes(drop) and box.inlier_reference() == pytest.approx(0.55)
    for _ in range(10):
        box.record(0.9, False)  # unconfirmed frames leave no reference
    assert box.inlier_reference() is None and box.inlier_floor() is None and box.passes(drop)


def test_the_inlier_levels_take_numpy_s_median():
    """The search box's median of recent inlier ratios is np.median's, bit for bit, for odd and even counts."""
    from hsmap.slam.search import _median

    rng = np.random.default_rng(5)
    for n in range(1, 25):
        for _ in range(20):
            values = rng.uniform(0.0, 1.0, n).tolist()
            assert _median(values) == float(np.median(values))
