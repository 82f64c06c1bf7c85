"""The paper's Table 1 on the simulated slam-office route (seed 1), without odometry: HS-SLAM's maximum errors
over the route within x 3 cm, y 5 cm, yaw 1.5 deg (6-DOF also z 1 cm, roll and pitch 0.2 deg), final pose within
4 cm and 1 deg; each trajectory relative to its first pose, no alignment. And the 6-DOF run's counted work within
its budget."""

import numpy as np
import pytest
from _budget import over_budget

from hsmap.datasets.simulated import SimulatedDataset
from hsmap.evaluation import pose_errors
from hsmap.sim.writer import simulate
from hsmap.slam import SlamConfig, run_slam
from hsmap.trajectory import Trajectory

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def office(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim") / "office"
    simulate("slam-office", out, seed=1)
    return SimulatedDataset(out)


@pytest.fixture(scope="module")
def run2d(office):
    return run_slam(office, SlamConfig(dof=3, use_odometry=False), rng=1, progress=False)


def test_route_is_the_papers(office):
    assert len(office) >= 177 and office.groundtruth.path_length() >= 100


def test_table1_3dof(office, run2d):
    e = pose_errors(run2d.trajectory, office.groundtruth.as_3dof())
    mx = dict(zip(e.names, e.max_abs, strict=True))
    assert mx["x"] < 0.03 and mx["y"] < 0.05 and np.degrees(mx["yaw"]) < 1.5, mx
    assert e.final_translation < 0.04 and np.degrees(e.final_rotation) < 1.0


#: The first clouds of the route (100 s, ~30 m) that the 6-DOF tests run: the whole route is in
#: benchmarks/slam.py and notebook 02.
CLOUDS = 200
#: The counts of that 6-DOF run (:meth:`hsmap.slam.Costs.as_dict`).
REFERENCE_6DOF = {
    "registrations": 200,
    "refinements": 70,
    "harmony_evaluations": 101328,
    "retries": 0,
    "loop_searches": 1,
    "far_searches": 0,
    "optimizations": 2,
    "optimization_rounds": 2,
    "optimization_iterations": 6,
    "map_rebuilds": 2,
    "points_inserted": 744984,
}


@pytest.fixture(scope="module")
def run6d(office, run2d):
    frames = [f for _, f in zip(range(CLOUDS), office.frames(clouds=True), strict=False)]
    return run_slam(frames, SlamConfig(dof=6, use_odometry=False), rng=1, prior=run2d.trajectory, progress=False)


def test_table1_6dof_seeded_by_2d(office, run6d):
    n, res = CLOUDS, run6d
    gt = office.groundtruth.as_6dof()
    e = pose_errors(res.trajectory, Trajectory(gt.stamps[:n], gt.poses[:n]))
    mx = dict(zip(e.names, e.max_abs, strict=True))
    assert mx["x"] < 0.03 and mx["y"] < 0.05 and mx["z"] < 0.01, mx
    assert max(np.degrees(mx["roll"]), np.degrees(mx["pitch"])) < 0.2 and np.degrees(mx["yaw"]) < 1.5, mx
    assert e.final_translation < 0.04 and np.degrees(e.final_rotation) < 1.0


def test_6dof_run_stays_within_its_cost_budget(run6d):
    """The keyframes' spacing, the map's rebuilds, the searches: a change that doubles the work fails here."""
    costs = run6d.costs
    assert costs["registrations"] >= CLOUDS - 1
    assert costs["points_inserted"] >= sum(f.points for f in run6d.frames if f.keyframe)
    over = over_budget(costs, REFERENCE_6DOF)
    assert not over, f"6-DOF HS-SLAM's work on the first {CLOUDS} slam-office clouds grew beyond its budget: {over}"
