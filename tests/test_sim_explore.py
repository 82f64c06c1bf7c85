"""The exploring route (hsmap.sim.explore) and the simulated run through a floor plan (hsmap.sim.building)."""

from __future__ import annotations

import _floorplans as fp
import numpy as np
import pytest
from scipy import ndimage as ndi

from hsmap.errors import EmptyInputError
from hsmap.sim.building import BuildingRunConfig, building_motion, simulate_building
from hsmap.sim.explore import ExploreConfig, plan_exploration
from hsmap.sim.floorplan import read_floor_plan
from hsmap.sim.sensors import Lidar3DConfig


def _clearance(plan):
    free = plan.furnished_free
    return np.where(free, (ndi.distance_transform_edt(free) - 0.5) * plan.geometry.resolution, 0.0)


def _legs_clear(plan, ex, need):
    clear, g = _clearance(plan), plan.geometry
    pts = np.vstack([ex.start[:2], ex.waypoints])
    for a, b in zip(pts[:-1], pts[1:], strict=True):
        t = np.linspace(0, 1, int(np.hypot(*(b - a)) / 0.01) + 2)[:, None]
        rc = g.world_to_index(a + t * (b - a))
        assert clear[rc[:, 0], rc[:, 1]].min() >= need - 1e-9


def test_visits_every_room_through_the_doors(tmp_path):
    plan = read_floor_plan(fp.write(tmp_path) / "tiny.png")
    cfg = ExploreConfig()
    ex = plan_exploration(plan, cfg)
    assert sorted(ex.order) == [1, 2, 3] and not ex.unreachable
    g = plan.geometry
    for k, xy in ex.goals.items():  # each goal lies in its room
        r, c = g.world_to_index(xy)
        assert plan.rooms[r, c] == k
    _legs_clear(plan, ex, cfg.clearance)  # never closer than the robot's clearance to walls and furniture
    # from B (the most space around its centre) to its nearest neighbour, then on: the legs are about as long
    # as the straight lines between the goals
    assert ex.order[0] == 2
    d = np.linalg.norm(np.diff(np.array([ex.goals[k] for k in ex.order]), axis=0), axis=1).sum()
    assert d - 1e-6 <= ex.path_length < 1.5 * d
    assert plan_exploration(plan, cfg).as_dict() == ex.as_dict()  # deterministic


def test_unreachable_rooms_are_reported(tmp_path):
    plan = read_floor_plan(fp.write(tmp_path, closed_room=True) / "tiny.png")
    ex = plan_exploration(plan)
    assert plan.n_rooms == 4
    assert list(ex.unreachable) == [4] and "not joined" in ex.unreachable[4]
    assert sorted(ex.order) == [1, 2, 3]
    # a robot 1.24 m wide: D (1.2 m wide) does not fit in, the 1 m doors keep A, B and C apart
    narrow = plan_exploration(plan, ExploreConfig(clearance=0.62, preferred_clearance=0.7))
    assert "does not fit" in narrow.unreachable[4]
    assert len(narrow.order) == 1 and all("not joined" in narrow.unreachable[k] for k in (1, 2, 3)
                                          if k not in narrow.order)
    with pytest.raises(EmptyInputError, match="nothing to explore"):
        plan_exploration(plan, ExploreConfig(clearance=5.0, preferred_clearance=5.0))


def test_the_run_drifts_and_is_written_as_a_dataset(tmp_path):
    from hsmap.datasets.simulated import SimulatedDataset

    plan = read_floor_plan(fp.write(tmp_path / "maps") / "tiny.png")
    cfg = BuildingRunConfig(lidar3d=Lidar3DConfig(channels=8, columns=128))
    ex = plan_exploration(plan, cfg.explore)
    m = building_motion(ex, cfg, seed=1)
    assert abs(m.path_length() - ex.path_length) < 0.05
    assert np.linalg.norm(m.odometry[-1, :2] - m.groundtruth[-1, :2]) > 1e-3  # the wheel odometry drifts
    run = simulate_building(plan, tmp_path / "run", seed=1, config=cfg, max_frames=12)
    ds = SimulatedDataset(tmp_path / "run")
    assert len(ds) == run.frames == 12
    labels, geometry, _ = ds.labels()
    assert np.array_equal(labels, plan.rooms) and geometry == plan.geometry
    f = ds.frame(5)
    assert np.isfinite(f.scan2d.ranges).mean() > 0.9 and len(f.cloud3d) > 500
