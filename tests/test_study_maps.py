"""hsmap.study.maps: the shared 2D/3D maps of a simulated run are computed once, then read back; bad options fail
with HsmapError. Also the map figures of hsmap.viz.map_figures on those maps."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from hsmap.errors import HsmapError, InputError, ShapeError
from hsmap.maps.grid import OCCUPIED
from hsmap.sim.catalog import resolve_scenario

pytest.importorskip("open3d")

FRAMES = 12


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    """A small two-rooms scenario (short route, small 3D LiDAR) and a private data/generated folder."""
    root = tmp_path_factory.mktemp("study_maps")
    data = yaml.safe_load(Path(resolve_scenario("two-rooms")).read_text())
    data["route"]["steps"] = data["route"]["steps"][:2]
    data["sensors"] = {"lidar3d": {"channels": 64, "columns": 256}}
    scn = root / "tiny-rooms.yaml"
    scn.write_text(yaml.safe_dump(data))
    return scn, root / "generated"


@pytest.fixture(scope="module")
def maps(generated):
    from hsmap.study import two_lidar_maps

    scn, gen = generated
    mp = pytest.MonkeyPatch()
    mp.setenv("HSMAP_GENERATED", str(gen))
    try:
        first = two_lidar_maps(str(scn), 1, max_frames=FRAMES)
        again = two_lidar_maps(str(scn), 1, max_frames=FRAMES)
        gt = two_lidar_maps(str(scn), 1, max_frames=FRAMES, poses="groundtruth")
    finally:
        mp.undo()
    return first, again, gt


def test_computed_once_then_read(maps):
    first, again, _ = maps
    assert not first.cached and again.cached and again.folder == first.folder
    assert first.frames == again.frames == FRAMES
    np.testing.assert_array_equal(first.slam3d.poses, again.slam3d.poses)
    np.testing.assert_array_equal(first.slice.data, again.slice.data)
    assert first.slice.geometry == again.slice.geometry
    assert len(again.slice_scans) == len(again.slice_poses) > 0
    assert (first.folder / "meta.json").is_file()


def test_slam_maps_lie_on_the_true_world(maps):
    first, _, gt = maps
    # the runs start at the true first pose and stay on the ground truth within centimetres
    err = np.hypot(*(first.slam2d.poses[:, :2] - first.groundtruth.poses[:, :2]).T)
    assert err.max() < 0.05
    err3 = np.hypot(*(first.slam3d.poses[:, :2] - first.groundtruth.poses[:, :2]).T)
    assert err3.max() < 0.05
    assert first.map2d.shape[1] == 2 and first.map3d.shape[1] == 3 and len(first.map3d) > 1000
    # the south wall of room-a (its face at y = 0.1) is occupied in both grids, at SLAM and at true poses
    for m in (first, gt):
        for grid in (m.floor, m.slice):
            idx = grid.geometry.world_to_index(np.array([[2.5, y] for y in (0.03, 0.08, 0.13)]))
            assert (grid.data[idx[:, 0], idx[:, 1]] == OCCUPIED).any()
    assert gt.poses == "groundtruth" and len(gt.map2d) == 0 and gt.folder != first.folder
    np.testing.assert_array_equal(gt.slam2d.poses, gt.groundtruth.poses)


def test_bad_options(generated, monkeypatch):
    from hsmap.study import simulated_dataset, two_lidar_maps

    scn, gen = generated
    monkeypatch.setenv("HSMAP_GENERATED", str(gen))
    with pytest.raises(InputError, match="poses must be"):
        two_lidar_maps(str(scn), 1, max_frames=FRAMES, poses="odometry")
    with pytest.raises(InputError, match="every"):
        two_lidar_maps(str(scn), 1, max_frames=FRAMES, every=0)
    with pytest.raises(InputError, match="max_frames"):
        simulated_dataset(str(scn), 1, max_frames=0)
    with pytest.raises(HsmapError, match="no such scenario"):
        simulated_dataset(str(gen / "missing.yaml"), 1)


@pytest.fixture(scope="module")
def aligned(maps):
    from hsmap.maps.fusion import align_maps

    m = maps[0]
    return align_maps(m.floor, m.slice, floor_points=m.floor_points, slice_points=m.slice_points, rng=0)


def test_map_figures_draw(maps, aligned, tmp_path):
    from hsmap.maps.fusion import common_grids
    from hsmap.rooms.segmentation import SegmentationConfig, points_in_doors, segment_rooms
    from hsmap.rooms.topology import room_graph
    from hsmap.viz import map_figures

    m, res = maps[0], aligned
    fig = map_figures.overlap_figure(m.floor, m.slice, res, before=common_grids(m.floor, m.slice))
    assert len(fig.axes) == 4
    fig.savefig(tmp_path / "overlap.png", dpi=30)
    seg = segment_rooms(m.slice, config=SegmentationConfig(method="paper"), keep_steps=True)
    fig = map_figures.voronoi_steps_figure(m.slice, seg)
    assert sum(ax.get_visible() for ax in fig.axes) >= 8
    fig.savefig(tmp_path / "steps.png", dpi=30)
    g = room_graph(seg)
    ax = map_figures.segmentation_figure(m.slice, seg, g)
    ax.figure.savefig(tmp_path / "graph.png", dpi=30)
    pg = map_figures.graph_for_plot(g)
    assert all("centroid" in d for _, d in pg.nodes(data=True))
    if seg.doors:
        c3 = points_in_doors(m.map3d, seg.doors)
        map_figures.door_clouds_figure(seg.doors, c3, points_in_doors(m.map2d, seg.doors)).savefig(
            tmp_path / "doors.png", dpi=30)
    fig = map_figures.segmentation_comparison_figure([(m.floor, segment_rooms(m.floor), "floor"),
                                                      (m.slice, seg, "slice")])
    fig.savefig(tmp_path / "cmp.png", dpi=30)
    assert all((tmp_path / f).stat().st_size > 2_000 for f in ("overlap.png", "steps.png", "graph.png", "cmp.png"))
    with pytest.raises(InputError, match="keep_steps"):
        map_figures.voronoi_steps_figure(m.slice, segment_rooms(m.slice))
    with pytest.raises(ShapeError, match="one cloud per door"):
        map_figures.door_clouds_figure([object()], [])
    with pytest.raises(InputError, match="OccupancyGrid"):
        map_figures.plot_overlay(m.floor.data, m.slice)


def test_log_overlay_verifies(aligned, tmp_path):
    from hsmap.viz import map_figures
    from hsmap.viz import rerun as hr

    res = aligned
    path = tmp_path / "overlay.rrd"
    with hr.open_recording(path) as rec:
        map_figures.log_overlay(rec, res.overlay(), res.floor.geometry)
        with pytest.raises(ShapeError, match="differs from its geometry"):
            map_figures.log_overlay(rec, res.overlay()[:-1], res.floor.geometry)
    hr.verify_rrd(path)
    contents = hr.recording_contents(path)
    assert any(k.endswith("world/map/overlay") for k in contents)
    assert any(k.endswith("map/overlay") and not k.endswith("world/map/overlay") for k in contents)
