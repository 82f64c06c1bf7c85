"""hsmap.viz: rerun recordings (written atomically, verified by `rerun rrd verify`, holding what they should
where they should), matplotlib figures in world metres, the colours they share."""

from __future__ import annotations

import networkx as nx
import numpy as np
import pytest

from hsmap.datasets import Frame, LaserScan2D
from hsmap.errors import DataFormatError, InputError, ShapeError
from hsmap.geometry import quaternion_to_matrix
from hsmap.maps.grid import GridGeometry
from hsmap.trajectory import Trajectory
from hsmap.viz import figures
from hsmap.viz import rerun as hr
from hsmap.viz.colors import label_color, label_colors
from hsmap.viz.occupancy import occupancy_to_image, occupancy_to_ros

needs_rerun_binary = pytest.mark.skipif(hr.rerun_binary() is None,
                                        reason="the rerun command-line tool is not installed")

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def two_rooms():
    """A 4 m x 10 m floor at 5 cm: two rooms split by a wall at x = 5 m with a 1 m doorway."""
    geo = GridGeometry((80, 200), 0.05, (-1.0, -2.0))  # x in [-1, 9], y in [-2, 2]
    occ = np.zeros(geo.shape, bool)
    occ[[0, -1], :] = True
    occ[:, [0, -1]] = True
    wall_col = geo.world_to_index([5.0, 0.0])[1]
    occ[:, wall_col] = True
    r0, r1 = geo.world_to_index([5.0, 0.5])[0], geo.world_to_index([5.0, -0.5])[0]
    occ[r0:r1 + 1, wall_col] = False
    lab = np.zeros(geo.shape, np.uint16)
    lab[1:-1, 1:wall_col] = 1
    lab[1:-1, wall_col + 1:-1] = 2
    g = nx.Graph()
    g.add_node(1, kind="room", centroid=(2.0, 0.0), area=23.0, label=1)
    g.add_node(2, kind="room", centroid=(7.0, 0.0), area=15.0, label=2)
    g.add_node("d1", kind="door", centroid=(5.0, 0.0))
    g.add_edge(1, "d1", distance=3.0)
    g.add_edge("d1", 2, distance=2.0)
    return geo, occ, lab, g


# --- recordings ------------------------------------------------------------------------------------------


def test_recording_appears_only_when_closed(tmp_path):
    path = tmp_path / "run.rrd"
    rec = hr.open_recording(path)
    hr.set_frame_time(rec, 0, 0.0)
    hr.log_robot_pose(rec, [0.0, 0.0, 0.0])
    assert not path.exists(), "a recording must not appear under its name before it is complete"
    assert rec.close() == path and path.stat().st_size > 0
    assert rec.close() == path  # idempotent
    assert [p.name for p in tmp_path.iterdir()] == ["run.rrd"]
    assert oct(path.stat().st_mode & 0o777) != oct(0o600), "reports must be readable like any other file"


def test_recording_aborted_by_an_error_leaves_nothing(tmp_path):
    path = tmp_path / "run.rrd"
    with pytest.raises(RuntimeError), hr.open_recording(path) as rec:
        hr.log_robot_pose(rec, [0.0, 0.0, 0.0])
        raise RuntimeError("stage failed")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(InputError, match=r"\.rrd"):
        hr.Recording(tmp_path / "run.bin")


@needs_rerun_binary
def test_full_scene_recording_verifies_and_holds_each_part(tmp_path):
    geo, occ, lab, g = two_rooms()
    n = 25
    stamps = 0.1 * np.arange(n)
    truth = np.column_stack([np.linspace(0, 8, n), 0.3 * np.sin(np.linspace(0, 3, n)), np.linspace(0, 0.5, n)])
    angles = np.linspace(-2.35, 2.35, 1081)
    rng = np.random.default_rng(0)
    with hr.open_recording(tmp_path / "scene.rrd") as rec:
        hr.log_occupancy_grid(rec, occ, geo)
        hr.log_room_labels(rec, lab, geo, names={1: "office", 2: "lab"})
        hr.log_room_graph(rec, g, geometry=geo)
        hr.log_path(rec, "groundtruth", truth)
        hr.log_map2d_path(rec, "groundtruth", truth, geo)
        pm = hr.PointMapLogger(rec, block=10)
        for i in range(n):
            f = Frame(stamp=stamps[i], scan2d=LaserScan2D(np.full(1081, 2.0), angles, 0.1, 10.0),
                      cloud3d=rng.normal(size=(3000, 3)), index=i, extrinsic2d=np.array([0.2, 0.0, 0.0]),
                      extrinsic3d=np.array([0.0, 0.0, 1.6, 0.0, 0.0, 0.0]))
            hr.log_frame(rec, f, truth[i], lidar2d_height=0.2)
            pts = f.scan2d.points()
            pm.add(np.column_stack([pts + truth[i, :2], np.full(len(pts), 0.2)]))
        pm.flush()
        hr.log_trajectory(rec, Trajectory(stamps, truth), name="estimate", robot_entity="world/estimate_robot")
    out = hr.verify_rrd(tmp_path / "scene.rrd")
    assert "verified" in out
    c = hr.recording_contents(tmp_path / "scene.rrd")
    expect = {
        "/world": "ViewCoordinates:xyz",
        "/world/robot": "Transform3D:translation",
        "/world/robot/lidar2d": "Transform3D:translation",
        "/world/robot/lidar2d/scan": "Points3D:positions",
        "/world/robot/lidar3d/cloud": "Points3D:positions",
        "/world/map/occupancy": "GridMap:data",
        "/world/map/rooms": "Mesh3D:albedo_texture_buffer",
        "/world/map/graph/nodes": "Points3D:positions",
        "/world/map/graph/edges": "LineStrips3D:strips",
        "/world/trajectory/groundtruth": "LineStrips3D:strips",
        "/world/trajectory/estimate": "LineStrips3D:strips",
        "/map/occupancy": "Image:buffer",
        "/map/rooms": "SegmentationImage:buffer",
        "/map/paths/groundtruth": "LineStrips2D:strips",
        "/graph": "GraphNodes:node_ids",
    }
    for entity, column in expect.items():
        assert entity in c and column in c[entity]["columns"], f"{entity} lacks {column}"
    assert "AnnotationContext:context" in c["/map/rooms"]["columns"]
    assert "GraphEdges:edges" in c["/graph"]["columns"]
    assert c["/world/robot"]["rows"] >= n  # one pose per scan on the timelines
    assert c["/world/estimate_robot"]["rows"] == n
    blocks = sorted(e for e in c if e.startswith("/world/map/points/"))
    assert blocks == [f"/world/map/points/{k:04d}" for k in range(3)]  # 25 scans in blocks of 10
    assert any(e.startswith("/view/") for e in c), "the default blueprint is stored with the recording"


@needs_rerun_binary
def test_verify_rejects_a_broken_recording(tmp_path):
    bad = tmp_path / "bad.rrd"
    bad.write_bytes(b"not a recording at all")
    with pytest.raises(DataFormatError, match="rrd verify"):
        hr.verify_rrd(bad)
    good = tmp_path / "good.rrd"
    with hr.open_recording(good) as rec:
        hr.log_robot_pose(rec, [1.0, 2.0, 0.3])
    truncated = tmp_path / "truncated.rrd"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(DataFormatError):
        hr.verify_rrd(truncated)
    with pytest.raises(DataFormatError, match="no such"):
        hr.verify_rrd(tmp_path / "missing.rrd")


class Spy:
    """Collects what is logged on a recording stream (and forwards it)."""

    def __init__(self, rec, monkeypatch):
        self.logged = []
        orig = rec.stream.log

        def log(entity, *archetypes, **kw):
            self.logged.append((entity, archetypes, kw))
            return orig(entity, *archetypes, **kw)

        monkeypatch.setattr(rec.stream, "log", log)

    def get(self, entity, cls):
        hits = [a for e, arch, _ in self.logged if e == entity for a in arch if isinstance(a, cls)]
        assert hits, f"nothing of type {cls.__name__} logged at {entity}"
        return hits[-1]


def test_grid_and_labels_are_placed_by_their_geometry(tmp_path, monkeypatch):
    import rerun as rr

    geo, occ, lab, g = two_rooms()
    with hr.open_recording(tmp_path / "grid.rrd") as rec:
        spy = Spy(rec, monkeypatch)
        hr.log_occupancy_grid(rec, occ, geo, z=0.0)
        hr.log_room_labels(rec, lab, geo)
        hr.log_room_graph(rec, g, geometry=geo, scale=10.0)
    gm = spy.get("world/map/occupancy", rr.GridMap)
    # the lower-left corner of the lower-left pixel sits at the grid's origin, one cell = one pixel
    assert gm.translation.pa_array.to_pylist() == [[-1.0, -2.0, 0.0]]
    assert gm.cell_size.pa_array.to_pylist()[0] == pytest.approx(0.05)
    data = np.array(gm.data.pa_array.to_pylist()[0], np.uint8).reshape(geo.shape)
    np.testing.assert_array_equal(data, np.where(occ, 100, 0))  # row 0 = top row, as rerun draws it
    # room colours as a textured quad over the grid's extent (a colour GridMap is flagged by rerun 0.41),
    # texture row 0 (v = 0) on the side of largest y, as the GridMap's row 0
    rooms = spy.get("world/map/rooms", rr.Mesh3D)
    corners = np.array(rooms.vertex_positions.pa_array.to_pylist())
    h, w = geo.shape
    np.testing.assert_allclose(corners[:, :2], [[-1, -2], [-1 + w * 0.05, -2], [-1 + w * 0.05, -2 + h * 0.05],
                                                [-1, -2 + h * 0.05]])
    uv = np.array(rooms.vertex_texcoords.pa_array.to_pylist())
    assert uv[0, 1] == 1.0 and uv[2, 1] == 0.0
    fmt = rooms.albedo_texture_format.pa_array.to_pylist()[0]
    rgba = np.array(rooms.albedo_texture_buffer.pa_array.to_pylist()[0], np.uint8).reshape(
        fmt["height"], fmt["width"], 4)
    up = fmt["height"] // h  # each cell drawn as an up x up block
    assert fmt["width"] == up * w
    np.testing.assert_array_equal(rgba[40 * up, 50 * up, :3], label_color(1))
    np.testing.assert_array_equal(rgba[40 * up, 150 * up, :3], label_color(2))
    assert rgba[0, 0, 3] == 0  # no room: transparent
    ctx = spy.get("map/rooms", rr.AnnotationContext)
    assert "room 2" in str(ctx.context.pa_array.to_pylist())
    seg = spy.get("map/rooms", rr.SegmentationImage)
    assert seg.format.pa_array.to_pylist()[0]["width"] == 200
    # the graph view shows the map from above: world (x, -y) * scale; the door, on the line between its two
    # rooms (2, 0) and (7, 0), is drawn a third of their distance aside so that the labels do not collide
    nodes = spy.get("graph", rr.GraphNodes)
    ids = nodes.node_ids.pa_array.to_pylist()
    pos = dict(zip(ids, nodes.positions.pa_array.to_pylist(), strict=True))
    assert pos["1"] == pytest.approx([20.0, -0.0]) and pos["2"] == pytest.approx([70.0, -0.0])
    assert pos["d1"][0] == pytest.approx(50.0) and abs(pos["d1"][1]) == pytest.approx(50.0 / 3)
    edges = spy.get("graph", rr.GraphEdges).edges.pa_array.to_pylist()
    assert sorted(map(sorted, ([e["first"], e["second"]] if isinstance(e, dict) else e for e in edges))) == [
        ["1", "d1"], ["2", "d1"]]
    # over the 2D map, in pixel coordinates: room 1's centroid (2, 0) is at column 60, row 40
    p2 = spy.get("map/graph/nodes", rr.Points2D).positions.pa_array.to_pylist()
    assert p2[0] == pytest.approx([60.0, 40.0])


def test_poses_become_transforms(tmp_path, monkeypatch):
    import rerun as rr

    with hr.open_recording(tmp_path / "p.rrd") as rec:
        spy = Spy(rec, monkeypatch)
        hr.log_robot_pose(rec, [1.0, 2.0, np.pi / 2])
        hr.log_sensor_rig(rec, extrinsic2d=[0.3, 0.0, 0.0], extrinsic3d=[0.0, 0.1, 1.6, 0.0, 0.0, np.pi],
                          lidar2d_height=0.2)
    t = spy.get("world/robot", rr.Transform3D)
    assert t.translation.pa_array.to_pylist() == [[1.0, 2.0, 0.0]]
    q = np.array(t.quaternion.pa_array.to_pylist()[0])
    R = quaternion_to_matrix(q)
    np.testing.assert_allclose(R @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-6)  # yaw 90 deg: x -> y
    l2 = spy.get("world/robot/lidar2d", rr.Transform3D)
    assert l2.translation.pa_array.to_pylist()[0] == pytest.approx([0.3, 0.0, 0.2])
    l3 = spy.get("world/robot/lidar3d", rr.Transform3D)
    assert l3.translation.pa_array.to_pylist()[0] == pytest.approx([0.0, 0.1, 1.6])


def test_bad_inputs_are_named(tmp_path):
    geo, occ, lab, g = two_rooms()
    with hr.open_recording(tmp_path / "x.rrd") as rec:
        with pytest.raises(ShapeError, match="GridGeometry"):
            hr.log_occupancy_grid(rec, occ[:-1], geo)
        with pytest.raises(ShapeError, match="pose"):
            hr.log_robot_pose(rec, [1.0, 2.0])
        with pytest.raises(InputError, match="NaN"):
            hr.log_robot_pose(rec, [np.nan, 0.0, 0.0])
        with pytest.raises(ShapeError, match="points"):
            hr.log_scan2d(rec, np.zeros((5, 4)))
        g2 = g.copy()
        g2.add_node("d9", kind="door")
        with pytest.raises(InputError, match="d9.*centroid"):
            hr.log_room_graph(rec, g2)
        with pytest.raises(InputError, match="convention"):
            hr.log_occupancy_grid(rec, occ.astype(np.int32), geo)
        with pytest.raises(InputError, match="networkx"):
            hr.log_room_graph(rec, {"a": 1})
    with pytest.raises(Exception, match="closed"):
        hr.log_robot_pose(rec, [0.0, 0.0, 0.0])


def test_unix_stamps_use_a_timestamp_timeline(tmp_path, monkeypatch):
    calls = []
    with hr.open_recording(tmp_path / "t.rrd") as rec:
        monkeypatch.setattr(rec.stream, "set_time", lambda name, **kw: calls.append((name, kw)))
        hr.set_frame_time(rec, 3, 12.5)
        hr.set_frame_time(rec, 4, 1.7e9)
    assert calls == [("scan", {"sequence": 3}), ("time", {"duration": 12.5}),
                     ("scan", {"sequence": 4}), ("time", {"timestamp": 1.7e9})]


def test_point_map_logger_block():
    with pytest.raises(InputError, match="block"):
        hr.PointMapLogger(None, block=0)


def test_occupancy_conventions_agree():
    occ = np.array([[True, False]])
    prob = np.array([[1.0, 0.0], [np.nan, 0.5]])
    img = np.array([[0, 254], [205, 127]], np.uint8)
    ros = np.array([[100, 0], [-1, 50]], np.int8)
    np.testing.assert_array_equal(occupancy_to_ros(occ), [[100, 0]])
    np.testing.assert_array_equal(occupancy_to_ros(prob), [[100, 0], [255, 50]])
    np.testing.assert_array_equal(occupancy_to_ros(img), [[100, 0], [255, 50]])
    np.testing.assert_array_equal(occupancy_to_ros(ros), [[100, 0], [255, 50]])
    np.testing.assert_array_equal(occupancy_to_image(ros), [[0, 254], [205, 127]])
    with pytest.raises(InputError, match=r"\[0, 1\]"):
        occupancy_to_ros(np.array([[1.5]]))
    with pytest.raises(InputError, match="-1..100"):
        occupancy_to_ros(np.array([[101]], np.int8))


def test_label_colours_are_stable_and_transparent_on_background():
    lab = np.array([[0, 1, 2, 21]])
    rgba = label_colors(lab)
    assert rgba[0, 0, 3] == 0 and np.all(rgba[0, 1:, 3] == 255)
    assert tuple(rgba[0, 1, :3]) == label_color(1) != label_color(2)
    assert label_color(21) == label_color(1)  # the palette cycles after 20 labels
    with pytest.raises(InputError):
        label_colors(np.array([[0.5]]))


def test_blueprint_views():
    import rerun.blueprint as rrb

    assert isinstance(hr.default_blueprint(), rrb.Blueprint)
    assert isinstance(hr.default_blueprint(map2d=False, graph=False), rrb.Blueprint)
    with pytest.raises(InputError):
        hr.default_blueprint(view3d=False, map2d=False, graph=False)


# --- figures ---------------------------------------------------------------------------------------------


def _png_size(path):
    from PIL import Image

    with Image.open(path) as im:
        return im.size


def test_paths_named_alike_get_distinct_colours():
    t = np.linspace(0, 1, 10)
    path = Trajectory(t, np.column_stack([t, t, t]))
    names = ["2D HS-SLAM", "6-DOF HS-SLAM", "odometry", "a", "b", "c", "d"]
    ax = figures.plot_trajectories(dict.fromkeys(names, path))
    lines = {line.get_label(): line.get_color() for line in ax.get_lines()}
    colours = [tuple(np.round(lines[n], 3)) for n in names]
    assert len(set(colours)) == len(names)
    assert figures.series_colors(names)["odometry"] == figures.SERIES_COLORS["odometry"]
    assert figures.series_colors(names)["2D HS-SLAM"] == figures.SERIES_COLORS["slam"]


def test_figures_render_in_world_metres(tmp_path):
    geo, occ, lab, g = two_rooms()
    t = np.linspace(0, 2 * np.pi, 50)
    truth = Trajectory(t, np.column_stack([3 * np.cos(t), 1.5 * np.sin(t), t]))
    odo = truth.poses + [0.2, 0.1, 0.0]
    ax = figures.plot_trajectories({"odometry": odo, "HS-SLAM": truth}, groundtruth=truth, title="paths")
    assert [line.get_label() for line in ax.get_lines() if not line.get_label().startswith("_")] == [
        "ground truth", "odometry", "HS-SLAM", "start", "end (in the path's colour)"]
    ax.figure.savefig(tmp_path / "paths.png")

    ax = figures.plot_labels(lab, geo, base=occ, names={1: "office"})
    assert ax.images[0].get_extent() == pytest.approx(list(geo.extent()))
    texts = sorted(t.get_text() for t in ax.texts)
    assert texts == ["2", "office"]
    x, y = next(t.get_position() for t in ax.texts if t.get_text() == "office")
    assert x == pytest.approx(2.0, abs=0.1) and y == pytest.approx(0.0, abs=0.1)  # centre of room 1
    figures.plot_graph(g, ax=ax)
    figures.plot_segments([[[5.0, -0.5], [5.0, 0.5]]], ax=ax, labels=["door"])
    ax.figure.savefig(tmp_path / "rooms.png")

    ax = figures.plot_grid(occ, geo, title="grid")
    img = ax.images[0].get_array()
    assert img[0, 0] == 0 and img[40, 50] == 254  # wall black, free white
    ax.figure.savefig(tmp_path / "grid.png")

    rng = np.random.default_rng(1)
    cloud = np.column_stack([rng.uniform(0, 10, 5000), rng.uniform(0, 4, 5000), rng.uniform(0, 2.5, 5000)])
    fig = figures.plot_cloud_views(cloud, views=("top", "side"), title="map")
    assert [a.get_title() for a in fig.axes[:2]] == ["top view", "side view"]
    fig.savefig(tmp_path / "cloud.png")

    fig = figures.plot_errors({"x": rng.normal(0, 0.01, 30), "yaw": rng.normal(0, 0.5, 30)},
                              units={"x": "m", "yaw": "deg"}, limits={"x": 0.03})
    fig.savefig(tmp_path / "errors.png")
    ax = figures.plot_points2d(cloud, title="points")
    ax.figure.savefig(tmp_path / "points.png")
    for name in ("paths", "rooms", "grid", "cloud", "errors", "points"):
        p = tmp_path / f"{name}.png"
        assert p.read_bytes()[:8] == PNG_MAGIC
        w, h = _png_size(p)
        assert w > 200 and h > 150


def test_figure_inputs_are_checked():
    geo, occ, lab, g = two_rooms()
    with pytest.raises(ShapeError, match="GridGeometry"):
        figures.plot_labels(lab[:, :-1], geo)
    with pytest.raises(ShapeError):
        figures.plot_cloud_views(np.zeros((10, 2)))
    with pytest.raises(InputError, match="views"):
        figures.plot_cloud_views(np.zeros((10, 3)), views=("bottom",))
    with pytest.raises(ShapeError, match=r"\(N, 2, 2\)"):
        figures.plot_segments(np.zeros((3, 2)))
    with pytest.raises(InputError):
        figures.plot_errors({})


def test_label_overlay_uses_the_room_palette():
    from types import SimpleNamespace

    from hsmap.viz.colors import label_overlay

    labels = np.array([[0, 1, 1], [0, 2, 2], [0, 0, 0]])
    free = np.array([[True, True, True], [False, True, True], [True, True, True]])
    rgb = label_overlay(labels, free, door_lines=np.eye(3, dtype=bool))
    assert rgb.shape == (3, 3, 3) and rgb.dtype == np.uint8
    assert tuple(rgb[0, 1]) == label_color(1) and tuple(rgb[1, 2]) == label_color(2)  # as in figures and rerun
    assert tuple(rgb[1, 0]) == (60, 60, 60)  # occupied, no room
    assert tuple(rgb[0, 0]) == (220, 30, 30)  # a door line on a free pixel
    assert tuple(rgb[2, 0]) == (255, 255, 255)  # free, no room
    with_door = label_overlay(labels, free, doors=[SimpleNamespace(pixel=(2, 2))])
    assert (with_door[1:, 1:] == 0).all() and tuple(with_door[0, 1]) == label_color(1)  # a 3x3 square at its centre
    with pytest.raises(ShapeError):
        label_overlay(labels, free[:2])


@needs_rerun_binary
def test_frame_logger_logs_what_log_frame_logs(tmp_path):
    """The frames logged in blocks as columns hold the same entities, components and rows as log_frame's,
    including a frame without a scan and the last, partial block."""
    n = 23
    angles = np.linspace(-2.35, 2.35, 361)
    rng = np.random.default_rng(0)
    frames = [Frame(stamp=100.0 + 0.1 * i, scan2d=None if i == 5 else LaserScan2D(np.full(361, 2.0), angles, 0.1,
                                                                                    10.0),
                    cloud3d=rng.normal(size=(500, 3)), index=i, extrinsic2d=np.array([0.2, 0.0, 0.0]),
                    extrinsic3d=np.array([0.0, 0.0, 1.6, 0.0, 0.0, 0.0])) for i in range(n)]
    poses = np.column_stack([0.1 * np.arange(n), np.zeros(n), 0.01 * np.arange(n)])
    with hr.open_recording(tmp_path / "rows.rrd") as rec:
        for f, p in zip(frames, poses, strict=True):
            hr.log_frame(rec, f, p, cloud_voxel=0.25)
    with hr.open_recording(tmp_path / "columns.rrd") as rec:
        fl = hr.FrameLogger(rec, block=10, cloud_voxel=0.25)
        for f, p in zip(frames, poses, strict=True):
            fl.add(f, p)
        fl.flush()
        assert fl.frames_logged == n
    hr.verify_rrd(tmp_path / "columns.rrd")
    rows, cols = (hr.recording_contents(tmp_path / name) for name in ("rows.rrd", "columns.rrd"))
    for entity in ("/world/robot", "/world/robot/lidar2d", "/world/robot/lidar2d/scan", "/world/robot/lidar3d/cloud"):
        assert cols[entity]["rows"] == rows[entity]["rows"], entity
        assert rows[entity]["columns"] <= cols[entity]["columns"] | {"log_tick", "log_time"}, entity
    # the robot: one pose a frame and the rig's static axes; the scan: every frame but the one without
    assert cols["/world/robot"]["rows"] == n + 1 and cols["/world/robot/lidar2d/scan"]["rows"] == n - 1
    with pytest.raises(InputError, match="block"):
        hr.FrameLogger(None, block=0)


@needs_rerun_binary
def test_map2d_robots_in_one_call_log_what_one_per_time_logs(tmp_path):
    geo = GridGeometry((80, 200), 0.05, (-1.0, -2.0))
    poses = np.column_stack([np.linspace(0, 8, 12), np.zeros(12), np.linspace(0, 1, 12)])
    stamps = 0.5 * np.arange(12)
    with hr.open_recording(tmp_path / "rows.rrd") as rec:
        for i, p in enumerate(poses):
            hr.set_frame_time(rec, i, stamps[i])
            hr.log_map2d_robot(rec, p, geo)
    with hr.open_recording(tmp_path / "columns.rrd") as rec:
        hr.log_map2d_robots(rec, poses, geo, np.arange(12), stamps)
    hr.verify_rrd(tmp_path / "columns.rrd")
    rows, cols = (hr.recording_contents(tmp_path / name)["/map/robot"] for name in ("rows.rrd", "columns.rrd"))
    assert cols["rows"] == rows["rows"] == 12
    assert rows["columns"] <= cols["columns"] | {"log_tick", "log_time"}
    with pytest.raises(ShapeError, match="as many"):
        hr.log_map2d_robots(None, poses, geo, np.arange(3), stamps)


def test_segmentation_picture_draws_doors_apart_from_walls_and_a_key():
    from _worlds import two_rooms as two_rooms_grid

    from hsmap.rooms.segmentation import segment_rooms
    from hsmap.viz.colors import DOOR_COLOR, ROOM_PALETTE, WALL_GREY, segmentation_picture

    grid = two_rooms_grid()
    seg = segment_rooms(grid)
    assert seg.doors
    pic = segmentation_picture(seg.labels, grid.free, seg.doors, grid.geometry)
    H, W = seg.labels.shape
    assert pic.shape[0] > H and pic.shape[1] >= W  # the key below the map
    door = np.all(pic[:H, :W] == DOOR_COLOR, axis=-1)
    assert door.sum() >= 2 * seg.doors[0].width / grid.geometry.resolution
    assert tuple(DOOR_COLOR) not in {tuple(c) for c in ROOM_PALETTE} and DOOR_COLOR != (WALL_GREY,) * 3
    key = pic[H:]
    for colour in (DOOR_COLOR, label_color(1), label_color(seg.n_rooms)):
        assert np.all(key == colour, axis=-1).sum() > 50  # a swatch of each
    plain = segmentation_picture(seg.labels, grid.free, seg.doors, grid.geometry, legend=False)
    assert plain.shape[:2] == (H, W)


def test_real_sweep_figures_draw_each_method_and_refuse_bad_shapes():
    from hsmap.viz.benchmark_figures import dof_errors_figure, tracks_figure

    ref = np.column_stack([np.linspace(0, 10, 20), np.linspace(0, 5, 20), np.zeros((20, 4))])
    lost = ref.copy()
    lost[12:, 0] += 40.0
    fig = tracks_figure(ref, {"HS-SLAM 6-DOF": (ref, None), "kiss_icp defaults": (lost, 12)})
    ax = fig.axes[0]
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["reference", "HS-SLAM 6-DOF", "kiss_icp defaults"]
    assert ax.get_xlim()[1] == pytest.approx(12.0)  # the reference's extent and a fifth of it, not the lost track's
    fig = dof_errors_figure({"HS-SLAM 6-DOF": (np.arange(20), np.zeros((20, 6))),
                             "x": (np.arange(20), np.ones((20, 6)))})
    assert len([a for a in fig.axes if a.get_visible()]) == 6
    with pytest.raises(InputError, match="errors \\(N, 6\\)"):
        dof_errors_figure({"a": (np.arange(3), np.zeros((3, 3)))})
    with pytest.raises(InputError, match="poses"):
        tracks_figure(np.zeros(3), {})


def test_compared_segmentations_colour_a_room_as_its_reference_room():
    from hsmap.viz.map_figures import matched_labels, segmentation_comparison_figure

    geo = GridGeometry((20, 40), 0.1)
    ref = np.zeros((20, 40), dtype=np.int32)
    ref[:, :20], ref[:, 20:] = 1, 2
    ours = np.zeros((20, 40), dtype=np.int32)
    ours[:, :21], ours[:, 21:35], ours[:, 35:] = 2, 1, 3  # the same two rooms numbered the other way, and a third
    shown = matched_labels(ours, geo, ref, geo)
    assert shown[0, 0] == 1 and shown[0, 25] == 2 and shown[0, 38] == 3
    # a finer grid over the same place matches in world coordinates
    fine = GridGeometry((40, 80), 0.05)
    assert matched_labels(np.repeat(np.repeat(ours, 2, 0), 2, 1), fine, ref, geo)[0, 50] == 2
    fig = segmentation_comparison_figure([(None, (ours, geo), "ours"), (None, (ref, geo), "truth")], reference=1)
    img = fig.axes[0].images[0].get_array()
    truth_img = fig.axes[1].images[0].get_array()
    assert np.allclose(img[10, 5], truth_img[10, 5]) and np.allclose(img[10, 25], truth_img[10, 25])
    assert sorted(t.get_text() for t in fig.axes[0].texts) == ["1", "2", "3"]  # each room keeps its number


def test_voronoi_panel_says_why_fewer_doors_than_lines():
    from hsmap.viz.map_figures import _final_title

    assert _final_title(3, 2, 2) == "(h) segmentation: 3 rooms, 2 doors"
    assert _final_title(3, 2, 3) == ("(h) segmentation: 3 rooms, 2 doors (3 lines drawn:\n"
                                     "a line is a door only between two final rooms, one per passage)")


def test_a_block_of_scans_gives_each_scans_own_finite_points():
    """The frame logger's 2D scan points, computed for a block at once, are each scan's own valid returns in order
    (NaN, short and long readings dropped, scans of different sizes and range limits)."""
    from hsmap.viz.rerun_loggers import _scan_points

    rng = np.random.default_rng(4)
    scans = []
    for m, lo, hi in ((361, 0.1, 10.0), (180, 0.5, 4.0), (90, 0.0, np.inf), (50, 0.2, 1.0)):
        r = rng.uniform(0.0, 12.0, m)
        r[rng.random(m) < 0.1] = np.nan
        scans.append(LaserScan2D(r, np.linspace(-2.0, 2.0, m), lo, hi))
    scans[-1].ranges[:] = 5.0  # nothing within its limits
    pts, counts = _scan_points(scans)
    each = [s.points() for s in scans]
    assert counts.tolist() == [len(p) for p in each] and counts[-1] == 0
    assert np.array_equal(pts[:, :2], np.concatenate(each)) and not pts[:, 2].any()


def test_the_slam_recorder_does_not_import_matplotlib():
    """``hsmap slam``'s recording needs rerun only: importing the recorder leaves matplotlib unloaded (a second of
    start-up a run)."""
    import subprocess
    import sys

    code = "import sys, hsmap.viz.replay, hsmap.slam; print('matplotlib' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
