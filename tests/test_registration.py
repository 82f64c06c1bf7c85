"""Harmony-ICP: known-transform recovery in 2D and 3D with no initial guess, determinism, bad input."""

import numpy as np
import pytest

import hsmap
from hsmap.errors import ConfigError, EmptyInputError, InputError, ShapeError
from hsmap.geometry import relative, transform_points, wrap_angle
from hsmap.registration.icp import RegistrationConfig, RegistrationTarget, harmony_icp
from hsmap.testing import raycast_2d, room_cloud_3d, room_segments, scan_points_2d, sensor_cloud

SEGMENTS = room_segments()


def scan_pair_2d(p0, p1, seed):
    """Two 1081-beam scans of the furnished room, taken from p0 (target) and p1 (source), with 1 cm noise."""
    tgt = scan_points_2d(*raycast_2d(SEGMENTS, p0, noise=0.01, rng=seed))
    src = scan_points_2d(*raycast_2d(SEGMENTS, p1, noise=0.01, rng=seed + 1))
    return src, tgt, relative(p0, p1)


def errors(pose, truth):
    d = np.asarray(pose) - truth
    k = len(truth) // 2
    return np.linalg.norm(d[:k]), np.rad2deg(np.abs(wrap_angle(d[k:])).max())


# offsets up to 1 m and 45 deg, in all directions, seen from different places in the room
OFFSETS_2D = [
    ((4.0, 3.0, 0.3), (1.0, 0.0, np.deg2rad(45))),
    ((3.6, 2.8, 2.0), (-0.6, 0.75, np.deg2rad(-45))),
    ((4.4, 3.4, -1.2), (0.0, -1.0, np.deg2rad(30))),
    ((4.2, 2.6, 3.0), (-0.7, -0.7, np.deg2rad(-20))),
    ((3.8, 3.2, -2.6), (0.3, 0.2, np.deg2rad(10))),
]


@pytest.mark.parametrize("start, offset", OFFSETS_2D)
def test_recovers_2d_transform_without_guess(start, offset):
    p0 = np.array(start)
    src, tgt, truth = scan_pair_2d(p0, p0 + np.array(offset), seed=int(10 * start[2]) % 97)
    res = hsmap.harmony_icp(src, tgt, rng=0)
    t_err, r_err = errors(res.pose, truth)
    assert t_err < 0.02 and r_err < 0.5, (t_err, r_err)
    assert res.transformation.shape == (3, 3)
    # the transformation maps source into the target frame: moved source points lie on the target's walls
    moved = transform_points(res.transformation, src)
    d = np.min(np.linalg.norm(moved[::20, None] - tgt[None], axis=2), axis=1)
    assert np.median(d) < 0.02
    assert res.inlier_ratio > 0.8
    assert res.evaluations > 0 and res.dropped == 0


OFFSETS_3D = [
    (0.5, 0.0, 0.02, 2.0, -2.0, 30.0),
    (-0.3, 0.4, -0.03, -3.0, 1.0, -30.0),
    (0.0, -0.5, 0.0, 1.5, 3.0, 15.0),
]


@pytest.mark.parametrize("offset", OFFSETS_3D)
def test_recovers_3d_transform_without_guess(offset):
    p0 = np.array([4.0, 3.0, 1.6, 0.0, 0.0, 0.7])
    off = np.array(offset, dtype=float)
    off[3:] = np.deg2rad(off[3:])
    p1 = p0 + off
    tgt = sensor_cloud(room_cloud_3d(5000, viewpoint=p0[:3], noise=0.01, rng=1), p0)
    src = sensor_cloud(room_cloud_3d(5000, viewpoint=p1[:3], noise=0.01, rng=2), p1)
    truth = relative(p0, p1)
    res = hsmap.harmony_icp(src, tgt, rng=0)
    t_err, r_err = errors(res.pose, truth)
    assert t_err < 0.02 and r_err < 0.5, (t_err, r_err)
    assert res.transformation.shape == (4, 4)
    np.testing.assert_allclose(res.transformation[:3, :3] @ res.transformation[:3, :3].T, np.eye(3), atol=1e-9)


def test_exact_copy_is_recovered_exactly(rng):
    tgt = scan_points_2d(*raycast_2d(SEGMENTS, np.array([4.0, 3.0, 0.0])))
    truth = np.array([0.4, -0.3, 0.2])
    src = transform_points(np.linalg.inv(hsmap.geometry.pose_to_matrix(truth)), tgt)
    res = hsmap.harmony_icp(src, tgt, rng=1)
    np.testing.assert_allclose(res.pose, truth, atol=1e-4)
    assert res.inlier_ratio == 1.0 and res.rmse < 1e-4


def test_kdtree_backend_and_no_refinement():
    p0 = np.array([4.0, 3.0, 0.5])
    src, tgt, truth = scan_pair_2d(p0, p0 + [0.5, -0.4, 0.3], seed=5)
    res = harmony_icp(src, tgt, config=RegistrationConfig(backend="kdtree"), rng=0)
    assert max(errors(res.pose, truth)[0] / 0.02, errors(res.pose, truth)[1] / 0.5) < 1
    raw = harmony_icp(src, tgt, config=RegistrationConfig(refinement="none", fine_threshold=0.1), rng=0)
    assert not raw.refined
    t_err, r_err = errors(raw.pose, truth)  # Harmony Search alone, with a fine stage: within a few cm
    assert t_err < 0.06 and r_err < 1.5


def test_refinement_improves_precision():
    errs = {}
    for refine in ("none", "point-to-plane", "point-to-point"):
        e = []
        for k, (start, offset) in enumerate(OFFSETS_2D[:3]):
            p0 = np.array(start)
            src, tgt, truth = scan_pair_2d(p0, p0 + np.array(offset), seed=20 + k)
            e.append(errors(harmony_icp(src, tgt, config=RegistrationConfig(refinement=refine), rng=0).pose,
                            truth)[0])
        errs[refine] = np.mean(e)
    assert errs["point-to-plane"] < errs["none"] / 2
    assert errs["point-to-point"] < errs["none"]


def test_initial_guess_far_outside_default_range():
    p0 = np.array([4.0, 3.0, 0.0])
    src, tgt, truth = scan_pair_2d(p0, p0 + [2.5, 1.0, np.deg2rad(100)], seed=3)
    guess = truth + [0.3, -0.3, np.deg2rad(15)]  # e.g. drifting odometry
    res = harmony_icp(src, tgt, initial_guesses=[guess], rng=0)
    t_err, r_err = errors(res.pose, truth)
    assert t_err < 0.02 and r_err < 0.5


def test_explicit_bounds_are_respected():
    p0 = np.array([4.0, 3.0, 0.0])
    src, tgt, truth = scan_pair_2d(p0, p0 + [0.5, 0.0, 0.0], seed=4)
    bounds = [[-0.1, 0.1], [-0.1, 0.1], [-0.1, 0.1]]  # excludes the truth on purpose
    res = harmony_icp(src, tgt, bounds=bounds, config=RegistrationConfig(refinement="none"), rng=0)
    assert np.all(res.pose >= -0.1 - 1e-12) and np.all(res.pose <= 0.1 + 1e-12)


def test_a_target_with_fields_within_a_box_registers_as_the_whole_one():
    """RegistrationTarget(field_within=box): the fields cover the box the moved source stays in, not the whole
    target (here the room and a copy 60 m away), and the registration ends where the whole one does."""
    p0 = np.array([4.0, 3.0, 0.0])
    src, tgt, truth = scan_pair_2d(p0, p0 + [0.3, -0.2, 0.2], seed=8)
    tgt = np.vstack([tgt, tgt + [60.0, 0.0]])
    half = np.array([0.3, 0.3, 0.1])
    bounds = np.column_stack([truth - half, truth + half])
    placed = transform_points(truth, src)
    reach = np.hypot(*half[:2]) + np.sqrt((src**2).sum(axis=1).max()) * half[2] + 0.5
    box = np.array([placed.min(axis=0) - reach, placed.max(axis=0) + reach])
    whole, part = RegistrationTarget(tgt), RegistrationTarget(tgt, field_within=box)
    a = harmony_icp(src, whole, bounds=bounds, rng=3)
    b = harmony_icp(src, part, bounds=bounds, rng=3)
    np.testing.assert_allclose(b.pose, a.pose, atol=1e-9)
    assert b.inlier_ratio == pytest.approx(a.inlier_ratio)
    tau = RegistrationConfig().search_threshold
    assert part.lookup(tau).values.size < 0.2 * whole.lookup(tau).values.size


def test_prepared_target_reused():
    p0 = np.array([4.0, 3.0, 0.0])
    target = None
    for k, off in enumerate([[0.3, 0.1, 0.1], [-0.2, 0.4, -0.3]]):
        src, tgt, truth = scan_pair_2d(p0, p0 + off, seed=40 + 2 * k)
        if target is None:
            target = RegistrationTarget(tgt)
        res = harmony_icp(src, target, rng=0)
        # the second scan pair uses the first target scan: same p0, different noise, still recovered
        t_err, r_err = errors(res.pose, truth)
        assert t_err < 0.02 and r_err < 0.5


def test_deterministic():
    p0 = np.array([4.0, 3.0, 0.0])
    src, tgt, _ = scan_pair_2d(p0, p0 + [0.6, -0.2, 0.4], seed=6)
    a = harmony_icp(src, tgt, rng=11)
    b = harmony_icp(src, tgt, rng=np.random.default_rng(11))
    np.testing.assert_array_equal(a.pose, b.pose)
    np.testing.assert_array_equal(a.global_pose, b.global_pose)
    assert a.evaluations == b.evaluations


def test_nan_points_dropped_and_counted():
    p0 = np.array([4.0, 3.0, 0.0])
    src, tgt, truth = scan_pair_2d(p0, p0 + [0.2, 0.1, 0.1], seed=7)
    src = np.vstack([src, [[np.nan, 1.0], [np.inf, 0.0]]])
    tgt = np.vstack([tgt, [[0.0, -np.inf]]])
    res = harmony_icp(src, tgt, rng=0)
    assert res.dropped == 3
    assert errors(res.pose, truth)[0] < 0.02


@pytest.mark.parametrize(
    "source, target, exc, match",
    [
        (np.zeros((0, 2)), np.ones((5, 2)), EmptyInputError, "source is empty"),
        (np.ones((5, 2)), np.zeros((0, 2)), EmptyInputError, "target is empty"),
        (np.full((4, 2), np.nan), np.ones((5, 2)), EmptyInputError, "source has no finite points"),
        (np.ones((5, 4)), np.ones((5, 4)), ShapeError, r"source must have shape \(N, 2\) or \(N, 3\)"),
        (np.ones(5), np.ones((5, 2)), ShapeError, "source must have shape"),
        (np.ones((5, 2)), np.ones((5, 3)), ShapeError, "target has 3 columns but the other cloud has 2"),
        ("abc", np.ones((5, 2)), ShapeError, "source must be a numeric array"),
    ],
)
def test_bad_clouds(source, target, exc, match):
    with pytest.raises(exc, match=match):
        harmony_icp(source, target)


@pytest.mark.parametrize(
    "kwargs, exc, match",
    [
        (dict(bounds=np.zeros((6, 2))), ShapeError, r"bounds must have shape \(3, 2\)"),
        (dict(bounds=[[1, -1], [0, 1], [0, 1]]), InputError, r"bounds\[0\] is inverted"),
        (dict(bounds=[[0, np.nan], [0, 1], [0, 1]]), InputError, "bounds must be finite"),
        (dict(initial_guesses=np.zeros((2, 6))), ShapeError, r"initial_guesses must have shape \(K, 3\)"),
        (dict(initial_guesses=[[np.nan, 0, 0]]), InputError, "initial_guesses must be finite"),
    ],
)
def test_bad_bounds_and_guesses(kwargs, exc, match):
    pts = np.random.default_rng(0).uniform(0, 1, (50, 2))
    with pytest.raises(exc, match=match):
        harmony_icp(pts, pts, **kwargs)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(threshold=0.0), r"registration.threshold must be a finite number > 0"),
        (dict(threshold=-0.1), r"registration.threshold must be a finite number > 0"),
        (dict(search_threshold=0.0), r"registration.search_threshold must be a finite number > 0"),
        (dict(fine_threshold=-1.0), "registration.fine_threshold must be None or > 0"),
        (dict(field_resolution=0.0), "registration.field_resolution must be None or > 0"),
        (dict(backend="octree"), "registration.backend must be one of"),
        (dict(refinement="gicp"), "registration.refinement must be one of"),
        (dict(max_points=0), "registration.max_points must be a positive integer"),
    ],
)
def test_bad_config(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        RegistrationConfig(**kwargs)


def test_backend_and_refinement_are_enums_that_dump_as_strings():
    import yaml

    from hsmap.config import from_dict, to_dict
    from hsmap.registration.icp import Backend, Refinement

    cfg = RegistrationConfig(backend="kdtree", refinement="none")
    assert cfg.backend is Backend.KDTREE and cfg.refinement is Refinement.NONE
    assert RegistrationConfig().backend is Backend.FIELD
    plain = to_dict(cfg)
    assert plain["backend"] == "kdtree" and type(plain["backend"]) is str
    assert from_dict(RegistrationConfig, yaml.safe_load(yaml.safe_dump(plain))) == cfg


def test_config_from_yaml_dict():
    from hsmap.config import from_dict

    cfg = from_dict(RegistrationConfig, {"threshold": 0.05, "harmony": {"memory_size": 20, "variant": "ihs"}})
    assert cfg.threshold == 0.05 and cfg.harmony.memory_size == 20 and cfg.harmony.variant == "ihs"
    with pytest.raises(ConfigError, match=r"registration.harmony: unknown key\(s\) \['hms'\]"):
        from_dict(RegistrationConfig, {"harmony": {"hms": 20}}, "registration")


def test_robust_kernel_and_refine_seeds():
    p0 = np.array([4.0, 3.0, 0.0])
    src, tgt, truth = scan_pair_2d(p0, p0 + [0.5, -0.3, 0.3], seed=8)
    cfg = RegistrationConfig(robust_kernel=0.05, refine_seeds=1)
    res = harmony_icp(src, tgt, initial_guesses=[truth + [0.05, 0.0, 0.01]], config=cfg, rng=0)
    t_err, r_err = errors(res.pose, truth)
    assert t_err < 0.02 and r_err < 0.5
    with pytest.raises(ConfigError, match="registration.robust_kernel"):
        RegistrationConfig(robust_kernel=-1.0)
    with pytest.raises(ConfigError, match="registration.refine_seeds"):
        RegistrationConfig(refine_seeds=-1)


def test_refine_reach_keeps_the_refinement_within_the_search_resolution():
    """The refinement's pose is kept when it stays within ``refine_reach`` of the search's, whatever the truncated
    cost says; with a reach of 0 the cost alone decides (then the search's pose may stand)."""
    from hsmap.registration.icp import refine_icp

    p0 = np.array([4.0, 3.0, 0.0])
    src, tgt, truth = scan_pair_2d(p0, p0 + [0.3, -0.2, 0.2], seed=8)
    target = RegistrationTarget(tgt)
    free = harmony_icp(src, target, initial_guesses=[truth], config=RegistrationConfig(refine_reach=10.0), rng=0)
    kept = free.pose  # the refinement from the search's pose
    assert free.refined
    again = refine_icp(np.asarray(src), target, free.global_pose, max_distance=0.1, start_distance=0.5,
                       iterations=30, method="point-to-plane")
    np.testing.assert_allclose(kept, again, atol=1e-9)
    for reach in (None, 0.0):
        res = harmony_icp(src, target, initial_guesses=[truth], config=RegistrationConfig(refine_reach=reach), rng=0)
        t_err, r_err = errors(res.pose, truth)
        assert t_err < 0.02 and r_err < 0.5
    with pytest.raises(ConfigError, match="registration.refine_reach"):
        RegistrationConfig(refine_reach=-0.1)
    with pytest.raises(ConfigError, match="registration.refine_reach"):
        RegistrationConfig(refine_reach=float("nan"))


def test_3d_refinement_on_a_nearest_point_field():
    """A 3D target whose field keeps nearest points (normals given): refine_icp takes its correspondences from
    the field, then polishes on exact ones, and lands where the exact refinement lands."""
    from hsmap.geometry import pose_to_matrix
    from hsmap.registration.fitness import DistanceField
    from hsmap.registration.icp import estimate_normals, refine_icp

    tgt = room_cloud_3d(8000, noise=0.0, rng=3)
    truth = np.array([0.05, -0.04, 0.02, 0.01, -0.01, 0.03])
    src = transform_points(np.linalg.inv(pose_to_matrix(truth)), tgt[::3])
    normals = estimate_normals(tgt)
    field = DistanceField(tgt, 0.1, 0.3, normals=normals)
    with_field = RegistrationTarget(tgt, normals=normals, fields={0.3: field})
    assert with_field.nearest_field(0.2) is field
    exact = RegistrationTarget(tgt, normals=normals)
    kw = dict(max_distance=0.1, start_distance=0.3, iterations=30)
    a = refine_icp(src, with_field, np.zeros(6), **kw)
    b = refine_icp(src, exact, np.zeros(6), **kw)
    np.testing.assert_allclose(a, truth, atol=1e-4)
    np.testing.assert_allclose(a, b, atol=1e-5)


@pytest.mark.parametrize("n", [10, 499, 500, 4001])
@pytest.mark.parametrize("k", [1, 3])
def test_a_split_kdtree_query_answers_as_one_query(n, k):
    """tree_query splits a large query between the compute threads (the caller and a kept pool): the same
    distances and indices, bit for bit, as scipy's single query, whatever the number of threads."""
    from scipy.spatial import cKDTree

    from hsmap._threads import using_threads
    from hsmap.registration.neighbours import tree_query

    rng = np.random.default_rng(n)
    tree = cKDTree(rng.uniform(-5, 5, (3000, 3)))
    q = rng.uniform(-6, 6, (n, 3))
    d0, i0 = tree.query(q, k=k, distance_upper_bound=0.4)
    for threads in (1, 2):
        with using_threads(threads):
            d, i = tree_query(tree, q, k=k, distance_upper_bound=0.4)
        np.testing.assert_array_equal(d, d0)
        np.testing.assert_array_equal(i, i0)


def test_constrained_axes_and_drop_degenerate_keep_what_the_scene_constrains():
    """A corridor along a 30 deg axis: its axis holds 1 % of the information across it, below the 5 % ratio, so
    only the across direction is constrained and drop_degenerate removes the axis (cross terms with the yaw too);
    a room keeps both directions; an information without any keeps none."""
    from hsmap.registration.information import constrained_axes, drop_degenerate

    a = np.deg2rad(30.0)
    along, across = np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)])
    block = 100.0 * np.outer(across, across) + 1.0 * np.outer(along, along)
    axes = constrained_axes(block, 0.05)
    assert axes.shape == (2, 1) and abs(abs(axes[:, 0] @ across) - 1.0) < 1e-12
    assert constrained_axes(block, 0.005).shape == (2, 2)
    assert constrained_axes(np.eye(2), 0.05).shape == (2, 2)
    assert constrained_axes(np.zeros((2, 2)), 0.05).shape == (2, 0)
    info = np.zeros((3, 3))
    info[:2, :2] = block
    info[2, 2] = 50.0
    info[:2, 2] = info[2, :2] = 3.0 * along + 2.0 * across
    kept = drop_degenerate(info, 0.05)
    assert abs(along @ kept[:2, :2] @ along) < 1e-9 and abs(along @ kept[:2, 2]) < 1e-9
    assert np.isclose(across @ kept[:2, :2] @ across, 100.0) and np.isclose(across @ kept[:2, 2], 2.0)
    assert kept[2, 2] == 50.0
    assert not drop_degenerate(np.diag([0.0, 0.0, 5.0]), 0.05).any()


def test_orient_normals_face_the_viewpoint():
    from hsmap.registration.normals import orient_normals

    rng = np.random.default_rng(0)
    pts = rng.uniform(-5, 5, (50, 2))
    n = rng.normal(size=(50, 2))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    for vp in (None, np.array([1.0, -2.0])):
        out = orient_normals(pts, n, vp)
        eye = np.zeros(2) if vp is None else vp
        assert np.all(np.einsum("ij,ij->i", out, eye - pts) >= 0)
        np.testing.assert_array_equal(np.abs(out), np.abs(n))  # the signs alone


def test_the_final_refinement_converges_to_the_pose_from_nearby():
    """The final point-to-plane refinement against the voxel-averaged target lands on a known 3D pose from a
    start a few centimetres and a degree away, and is kept (it lowers the cost there); polish_voxel 0 skips it."""
    from hsmap.registration.icp import _polish

    tgt = room_cloud_3d(20000, noise=0.002, rng=5)
    truth = np.array([0.30, -0.20, 0.05, 0.02, -0.015, 0.4])
    from hsmap.geometry import pose_to_matrix

    src = transform_points(np.linalg.inv(pose_to_matrix(truth)), room_cloud_3d(20000, noise=0.002, rng=6))
    start = truth + np.array([0.04, -0.03, 0.02, np.deg2rad(0.5), np.deg2rad(-0.5), np.deg2rad(1.0)])
    target = RegistrationTarget(tgt)
    pose = _polish(src, target, start, RegistrationConfig())
    assert pose is not None
    d = relative(truth, pose)
    assert np.linalg.norm(d[:3]) < 0.005
    assert np.rad2deg(np.abs(wrap_angle(d[3:]))).max() < 0.1
    assert _polish(src, target, start, RegistrationConfig(polish_voxel=0.0)) is None


def test_a_real_sweep_after_a_sharp_turn_registers_at_gicp_precision():
    """BALM's handheld Ouster sweeps 129 -> 130 (a 41 deg turn with roll): Harmony-ICP with no initial guess lands
    within 1 cm and 0.1 deg of the reference relative pose."""
    import os
    from pathlib import Path

    from hsmap.datasets.clouds import read_points

    root = Path(os.environ.get("HSMAP_DATASETS", "")) / "balm"
    if not os.environ.get("HSMAP_DATASETS") or not (root / "alidarPose.csv").is_file():
        pytest.skip("no data: $HSMAP_DATASETS/balm (the BALM real-world benchmark) not found")
    rows = np.loadtxt(root / "alidarPose.csv", delimiter=",", usecols=range(4)).reshape(-1, 4, 4)
    rows[:, 3, 3] = 1.0
    ref = np.linalg.inv(rows[129]) @ rows[130]
    u, _, vt = np.linalg.svd(ref[:3, :3])
    ref[:3, :3] = u @ vt
    res = harmony_icp(read_points(root / "full130.pcd"), read_points(root / "full129.pcd"), rng=0)
    err = np.linalg.inv(ref) @ res.transformation
    assert np.linalg.norm(err[:3, 3]) < 0.01
    assert np.rad2deg(np.arccos(np.clip((np.trace(err[:3, :3]) - 1) / 2, -1, 1))) < 0.1


def test_a_search_settled_within_a_field_cell_stops_sooner_at_the_same_pose():
    """stop_within_cell counts only improvements that move the search's best pose by more than a field cell: the
    searches end sooner, and after the refinement the poses are the ones the longer searches find."""
    fewer = 0
    for k, (start, offset) in enumerate(OFFSETS_2D):
        p0 = np.array(start)
        src, tgt, truth = scan_pair_2d(p0, p0 + np.array(offset), seed=k)
        a = hsmap.harmony_icp(src, tgt, rng=k, config=RegistrationConfig(stop_within_cell=True))
        b = hsmap.harmony_icp(src, tgt, rng=k, config=RegistrationConfig(stop_within_cell=False))
        assert a.evaluations <= b.evaluations
        fewer += a.evaluations < b.evaluations
        for res in (a, b):
            t_err, r_err = errors(res.pose, truth)
            assert t_err < 0.02 and r_err < 0.5, (t_err, r_err)
    assert fewer >= 3


def test_2d_exact_polish_on_the_grid_lands_where_the_python_iterations_do(monkeypatch):
    """The 2D refinement's exact iterations run compiled on the target's neighbour grid; without the grid (the
    KD-tree's answers, iteration by iteration in Python) the refinement lands on the same pose, and the compiled
    truncated cost is the plain one."""
    from hsmap.registration import refine

    p0 = np.array([4.0, 3.0, 0.0])
    src, tgt, truth = scan_pair_2d(p0, p0 + [0.1, -0.05, 0.05], seed=3)
    target = RegistrationTarget(tgt)
    target.lookup(0.5)  # a field keeping nearest points: the refinement's first stage
    start = truth + [0.04, -0.03, 0.01]
    src = np.asarray(src)
    assert target.grid_for(0.1) is not None
    fast = refine.refine_icp(src, target, start, max_distance=0.1, start_distance=0.5, robust_kernel=0.07)
    monkeypatch.setattr(RegistrationTarget, "grid_for", lambda self, bound: None)
    slow = refine.refine_icp(src, target, start, max_distance=0.1, start_distance=0.5, robust_kernel=0.07)
    np.testing.assert_allclose(fast, slow, rtol=0, atol=1e-12)
    assert np.abs(fast[:2] - truth[:2]).max() < 0.01
    _, moved, d, idx = match = refine._match(fast, src, target, 0.1)
    ok = np.isfinite(d)
    r = d.copy()
    r[ok] = np.abs(np.einsum("ij,ij->i", target.normals[idx[ok]], moved[ok] - target.points[idx[ok]]))
    for plane, res in ((True, r), (False, d)):
        plain = np.where(ok, np.minimum(res, 0.1), 0.1).mean() / 0.1
        assert refine._cost_of(match, target, 0.1, plane) == pytest.approx(plain, rel=1e-12)


@pytest.mark.parametrize("kernel", [0.0, 0.1])
def test_3d_exact_iterations_on_the_grid_land_where_the_python_iterations_do(monkeypatch, kernel):
    """The 3D refinement's exact iterations run compiled on the target's neighbour grid, searching again only
    where a point may have a new nearest neighbour; the iterations in Python (the KD-tree's answers, every point
    searched every time) land on the same pose, from a start with a hint and from one without."""
    from hsmap.geometry import pose_to_matrix
    from hsmap.registration import refine
    from hsmap.registration.neighbours import NeighbourGrid

    tgt = room_cloud_3d(20000, noise=0.003, rng=7)
    truth = np.array([0.12, -0.08, 0.03, 0.015, -0.01, 0.2])
    src = transform_points(np.linalg.inv(pose_to_matrix(truth)), room_cloud_3d(6000, noise=0.003, rng=8))
    start = truth + np.array([0.05, -0.04, 0.02, np.deg2rad(0.8), np.deg2rad(-0.6), np.deg2rad(2.0)])
    target = RegistrationTarget(tgt)
    assert target.grid_for(0.3) is not None
    hint = refine._match(start, src, target, 0.1)[3]
    kw = dict(max_distance=0.1, start_distance=0.3, robust_kernel=kernel)
    compiled = []
    icp_3d = NeighbourGrid.icp_3d
    monkeypatch.setattr(NeighbourGrid, "icp_3d", lambda *a: compiled.append(1) or icp_3d(*a))
    fast = [refine.refine_icp(src, target, start, **kw), refine.refine_icp(src, target, start, hint=hint, **kw)]
    assert len(compiled) == 2
    monkeypatch.setattr(RegistrationTarget, "grid_for", lambda self, bound: None)
    slow = refine.refine_icp(src, target, start, **kw)
    for pose in fast:
        np.testing.assert_allclose(pose, slow, rtol=0, atol=1e-12)
    d = relative(truth, fast[0])
    assert np.linalg.norm(d[:3]) < 0.005 and np.rad2deg(np.abs(wrap_angle(d[3:]))).max() < 0.1


def test_how_far_the_3d_iterations_search_changes_no_pose(monkeypatch):
    """The compiled 3D iterations search a margin beyond each nearest point to know when a point cannot have a
    new nearest neighbour; with no margin every point is searched every iteration, and the pose is the same, bit
    for bit."""
    from hsmap.geometry import pose_to_matrix
    from hsmap.registration import _kernels, refine

    tgt = room_cloud_3d(20000, noise=0.003, rng=9)
    truth = np.array([-0.1, 0.06, -0.02, -0.01, 0.02, -0.3])
    src = transform_points(np.linalg.inv(pose_to_matrix(truth)), room_cloud_3d(5000, noise=0.003, rng=10))
    target = RegistrationTarget(tgt)
    kw = dict(max_distance=0.1, start_distance=0.3, robust_kernel=0.1)
    poses = []
    for margin in (0.0, 0.005, 0.02, 0.1):
        monkeypatch.setattr(_kernels, "CERTIFY_MARGIN", margin)
        poses.append(refine.refine_icp(src, target, truth + [0.06, 0.03, -0.02, 0.01, 0.01, 0.03], **kw))
    for pose in poses[1:]:
        np.testing.assert_array_equal(pose, poses[0])


@pytest.mark.parametrize("kernel", [0.0, 0.07])
def test_information_and_cost_of_a_pose_are_the_point_to_line_sums(kernel):
    """The information and cost at a pose (one compiled pass over the correspondences) are J^T W J of the
    point-to-line residuals over the weighted residual variance, expressed in the source's frame, and the mean
    truncated residual."""
    from hsmap.registration import refine
    from hsmap.registration.information import adjoint

    p0 = np.array([4.0, 3.0, 0.0])
    src, tgt, truth = scan_pair_2d(p0, p0 + [0.1, -0.05, 0.05], seed=5)
    target, src = RegistrationTarget(tgt), np.asarray(src)
    pose = truth + [0.01, -0.005, 0.002]
    info, sigma, n, cost = refine._information_and_cost(src, target, pose, 0.1, kernel)
    T, moved, d, idx = refine._match(pose, src, target, 0.1)
    ok = np.isfinite(d)
    p, q, nq = moved[ok], target.points[idx[ok]], target.normals[idx[ok]]
    r = np.einsum("ij,ij->i", nq, p - q)
    w = np.ones_like(r) if kernel == 0 else kernel**4 / (kernel**2 + r**2) ** 2
    J = np.column_stack([nq, nq[:, 1] * p[:, 0] - nq[:, 0] * p[:, 1]])
    want_sigma = max(np.sqrt((w * r * r).sum() / w.sum()), 1e-3)
    Ad = adjoint(T)
    want = Ad.T @ ((J.T * w) @ J / want_sigma**2) @ Ad
    assert n == ok.sum() and sigma == pytest.approx(want_sigma, rel=1e-12)
    np.testing.assert_allclose(info, want, rtol=1e-10)
    assert cost == pytest.approx((np.minimum(np.abs(r), 0.1).sum() + 0.1 * (len(src) - n)) / (0.1 * len(src)),
                                 rel=1e-12)


def _spans_reference(points, rank):
    """spans_its_space's rule in numpy: the centred scatter's eigenvalue d - rank above 1e-18 of the largest."""
    d = points.shape[1]
    if len(points) < rank + 1:
        return False
    if rank == 0:
        return True
    c = points - points.mean(0)
    scale = np.abs(c).max()
    if not scale > 0 or not np.isfinite(scale):
        return rank == 0
    ev = np.linalg.eigvalsh((c / scale).T @ (c / scale))
    return bool(ev[d - rank] > 1e-18 * ev[-1])


@pytest.mark.parametrize("dim", [2, 3])
def test_spans_its_space_follows_the_scatter_eigenvalue_rule(dim):
    """Random clouds, clouds on a line or a plane, coinciding points and one point: spans_its_space answers as
    the numpy rule does for every rank."""
    from hsmap.registration.icp import spans_its_space
    rng = np.random.default_rng(7)
    clouds = [rng.normal(size=(n, dim)) * rng.uniform(0.01, 100) for n in (1, 2, 5, 40)]
    line = np.outer(rng.normal(size=30), rng.normal(size=dim)) + rng.normal(size=dim)
    clouds += [line, np.ones((6, dim)), np.zeros((1, dim))]
    if dim == 3:
        clouds.append(np.column_stack([rng.normal(size=(20, 2)), np.full(20, 2.5)]))
    for cloud in clouds:
        for rank in range(dim + 1):
            assert spans_its_space(cloud, rank) == _spans_reference(cloud, rank), (cloud.shape, rank)
