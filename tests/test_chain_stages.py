"""The chain's stages are one code for ``hsmap map`` and the study: a notebook's grids of a recording are
``hsmap map``'s grids of it, byte for byte, on a recording whose 3D LiDAR sweeps while the robot drives (so the
clouds need deskewing)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("open3d")

FRAMES = 10


@pytest.fixture(scope="module")
def rolling(tmp_path_factory):
    """A short two-rooms run at 1 m/s with a rolling 16 x 256 sweep of 0.1 s and a swaying mast."""
    from hsmap.sim import Lidar3DConfig
    from hsmap.sim.catalog import resolve_scenario
    from hsmap.sim.robot import RobotConfig
    from hsmap.sim.scenario import load_scenario
    from hsmap.sim.writer import simulate

    scn = load_scenario(resolve_scenario("two-rooms"))
    scn = scn.replace(lidar3d=Lidar3DConfig(channels=16, columns=256, sweep_time=0.1, sway_frequency=2.0),
                      robot=RobotConfig(max_speed=1.0, max_turn_rate_deg=60.0))
    folder = tmp_path_factory.mktemp("chain") / "rolling"
    simulate(scn, folder, seed=1, max_frames=FRAMES)
    return folder


def test_a_notebooks_grids_of_a_recording_are_hsmap_maps_byte_for_byte(rolling, tmp_path, monkeypatch):
    from hsmap.datasets.open import open_dataset
    from hsmap.maps.grid import write_map
    from hsmap.pipeline import map_recording
    from hsmap.study.maps import recording_maps

    assert open_dataset(rolling).frame(3).point_times is not None  # the clouds are rolling sweeps
    monkeypatch.setenv("HSMAP_GENERATED", str(tmp_path / "generated"))
    map_recording(open_dataset(rolling), tmp_path / "map", seed=1, recording=False, progress=False)
    maps = recording_maps(rolling, 1, cache_dir=tmp_path / "maps")
    (tmp_path / "notebook").mkdir()
    for name, grid in (("floor", maps.floor), ("slice", maps.slice)):
        write_map(tmp_path / "notebook" / f"{name}.yaml", grid)
        for suffix in (".pgm", ".yaml"):
            assert (tmp_path / "notebook" / f"{name}{suffix}").read_bytes() == \
                (tmp_path / "map" / f"{name}{suffix}").read_bytes(), f"{name}{suffix}"
    # and read back from the study's cache as they were made
    again = recording_maps(rolling, 1, cache_dir=tmp_path / "maps")
    assert again.cached and again.slice.geometry == maps.slice.geometry
    np.testing.assert_array_equal(again.slice.data, maps.slice.data)
    assert len(again.slice_scans) == len(again.slice_poses) > 0
