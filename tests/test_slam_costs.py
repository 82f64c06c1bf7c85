"""HS-SLAM's counted work (:class:`hsmap.slam.Costs`): the counters alone, and a budget on the first intel frames
that a run doing twice the work exceeds."""

import json

import pytest
from _budget import budget, over_budget

from hsmap.slam import Costs, SlamConfig, run_slam, write_slam_outputs

#: Frames of the Intel Research Lab log (seed 1, the default configuration, loop closure on).
FRAMES = 3000
#: The counts of such a run (:meth:`Costs.as_dict`).
REFERENCE = {
    "registrations": 3470,
    "refinements": 4011,
    "harmony_evaluations": 394040,
    "retries": 95,
    "full_searches": 282,
    "loop_searches": 90,
    "far_searches": 7,
    "optimizations": 16,
    "optimization_rounds": 28,
    "optimization_iterations": 193,
    "map_rebuilds": 20,
    "points_inserted": 376127,
}
BUDGET = budget(REFERENCE)


# ---------------------------------------------------------------------------------------------- the counters
def test_costs_start_at_zero_and_add_up():
    c = Costs()
    assert c.as_dict() == dict.fromkeys(Costs.names(), 0)
    c.registration(120)
    c.registration(30)
    c.add(refinements=2, points_inserted=500)
    c.add(points_inserted=1)
    d = c.as_dict()
    assert d["registrations"] == 2 and d["harmony_evaluations"] == 150
    assert d["refinements"] == 2 and d["points_inserted"] == 501
    assert sum(d.values()) == 2 + 150 + 2 + 501
    assert all(type(v) is int for v in d.values())
    assert json.loads(json.dumps(d)) == d


def test_costs_reject_unknown_counters_and_negative_counts():
    c = Costs()
    with pytest.raises(AttributeError, match="no counter 'registration'"):
        c.add(registration=1)
    with pytest.raises(ValueError, match="only grows"):
        c.add(refinements=-1)
    assert c.as_dict() == Costs().as_dict()


def test_budget_names_every_counter():
    assert list(REFERENCE) == Costs.names()
    assert all(BUDGET[k] < 2 * v for k, v in REFERENCE.items() if v >= 10)


# ------------------------------------------------------------------------------------------------- a run
@pytest.fixture
def intel_run(datasets_dir):
    from hsmap.datasets.open import open_dataset

    bag = datasets_dir / "slam2d" / "intel" / "intel.orig.bag"
    if not bag.is_file():
        pytest.skip(f"{bag} is absent (the Freiburg logs: hsmap data fetch)")
    return run_slam(open_dataset(bag), SlamConfig(dof=3), rng=1, max_frames=FRAMES, progress=False, threads=1)


@pytest.mark.slow
def test_intel_run_stays_within_its_cost_budget(intel_run, tmp_path):
    costs = intel_run.costs
    assert len(intel_run.frames) == FRAMES
    # every frame after the first is registered; every keyframe inserts its scan
    assert costs["registrations"] >= FRAMES - 1
    assert costs["harmony_evaluations"] >= costs["registrations"]
    assert costs["points_inserted"] >= sum(f.points for f in intel_run.frames if f.keyframe)
    over = over_budget(costs, REFERENCE)
    assert not over, f"HS-SLAM's work on the first {FRAMES} intel frames grew beyond its budget: {over}"
    paths = write_slam_outputs(intel_run, tmp_path)
    assert json.loads(paths["metrics"].read_text())["costs"] == costs


@pytest.mark.parametrize("solver", ["batch", "incremental"])
def test_graph_optimisation_reports_its_rounds_and_iterations(solver):
    import numpy as np

    from hsmap.slam.posegraph import EdgeKind, PoseGraph

    g = PoseGraph(3, solver=solver)
    for x in range(4):
        g.add_node(np.array([x + 0.1 * x * x, 0.05 * x, 0.0]))
    for i in range(3):
        g.add_edge(i, i + 1, np.array([1.0, 0.0, 0.0]), np.eye(3) * 100.0, EdgeKind.ODOMETRY)
    g.add_edge(0, 3, np.array([3.0, 0.0, 0.0]), np.eye(3) * 100.0, EdgeKind.LOOP)
    out = g.optimize()
    assert out.status == "ok"
    assert 1 <= out.rounds <= 3
    assert out.iterations_total >= out.iterations >= 1


def test_a_6dof_run_loads_its_compiled_kernels_before_its_clock_starts():
    """``load_kernels`` (which ``run_slam`` calls before it reads the clock) leaves the 6-DOF tracking's kernels
    loaded in a fresh process: the run's CPU time is then the frames' work, not numba's start-up."""
    import subprocess
    import sys

    code = ("from hsmap.slam import SlamConfig\n"
            "from hsmap.slam.run import load_kernels\n"
            "from hsmap.registration import _kernels as K\n"
            "from hsmap.maps import _kernels as M\n"
            "kernels = (K.hs_search_field, K.icp_on_grid_3d, K.grid_nearest, K.grid_build, K.splat_field_3d,\n"
            "           M.voxel_centroids, M.voxel_accumulate)\n"
            "assert not any(k.signatures for k in kernels)\n"
            "load_kernels(SlamConfig(dof=6))\n"
            "print(sorted(k.__name__ for k in kernels if not k.signatures))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=True)
    assert out.stdout.strip() == "[]"


def test_loading_the_kernels_never_fails_a_run_whose_ranges_the_warm_up_does_not_suit(monkeypatch):
    """A configuration whose ranges leave the warm-up's synthetic sweeps no points leaves the loading to the run:
    neither an error nor a warning comes of the warm-up."""
    import warnings

    from hsmap.slam import run as run_module

    monkeypatch.setattr(run_module, "_kernels_loaded", False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        run_module.load_kernels(SlamConfig(dof=6, max_range=1.0))
    assert run_module._kernels_loaded
