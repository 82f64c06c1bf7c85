"""Notebook 10's study helpers (hsmap.study.real3d) on OctoMap's geb079 map."""

from __future__ import annotations

import numpy as np
import pytest

from hsmap.study import real3d


@pytest.fixture(scope="module")
def geb079():
    from hsmap.maps.maps3d import read_map3d

    p = real3d.map_path()
    if p is None:
        pytest.skip("no data (run hsmap data fetch octomap): octomap/geb079.bt missing")
    return p, read_map3d(p)


def test_the_slice_finds_more_of_the_offices_than_the_floor_band(geb079):
    _, m = geb079
    floor = real3d.band_rooms(m, (0.1, 0.35))
    slc = real3d.band_rooms(m, (1.7, 1.8))
    rf, rs = floor.row(), slc.row()
    assert rs["rooms"] >= 10 and rs["doors"] >= 5
    assert rs["in_rooms_m2"] > rf["in_rooms_m2"]  # above the clutter more of each room is free
    assert slc.segmentation.labels.shape == slc.grid.data.shape == slc.segmented.data.shape
    assert slc.segmented.free.sum() > slc.grid.free.sum()  # seen-through cells add free space
    assert not (slc.segmentation.labels > 0)[~slc.segmented.free].any()


def test_a_short_run_in_the_real_world_keeps_table_1(geb079, tmp_path):
    path, _ = geb079
    runs = real3d.world_runs(path, [2], max_frames=8, root=tmp_path, log=lambda line: None)
    (r,) = runs
    assert r.world["frames"] == 8 and (r.out / "trajectory3d.tum").is_file()
    assert r.within_bounds(), r.errors
    s = real3d.table1_summary(runs)
    assert s["z_m"]["worst"] == pytest.approx(r.errors["z_m"]) and s["z_m"]["within"] == 1
    real3d.write_summary(runs, tmp_path / "runs.json")
    assert (tmp_path / "runs.json").is_file()


def test_points_grid_marks_the_points_occupied():
    pts = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 2.0]])
    g = real3d.points_grid(pts, 0.1)
    assert g.occupied.sum() == 3 and not g.free.any()
    rc = g.geometry.world_to_index(pts)
    assert g.occupied[rc[:, 0], rc[:, 1]].all()
