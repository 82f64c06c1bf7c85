"""benchmarks/relations_audit.py's check of a benchmark's relations by two independent sensors."""

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from hsmap.datasets.relations import Relations
from hsmap.geometry import compose, relative
from hsmap.trajectory import Trajectory

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def audit():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        spec = importlib.util.spec_from_file_location("relations_audit", ROOT / "benchmarks" / "relations_audit.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        yield mod
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))


def test_relations_both_sensors_contradict_are_counted_and_only_they(audit):
    """A relation that two sensors agreeing with each other both miss by 3 deg is counted; one that only one sensor
    misses is not (that sensor erred), nor one both miss by less than the threshold; the audited trajectory's error
    is given with and without the counted ones."""
    stamps = np.arange(0.0, 100.0, 0.5)
    truth = np.column_stack([0.1 * stamps, np.sin(0.05 * stamps), 0.02 * stamps])
    ti, tj = stamps[:-10:5], stamps[10::5]
    n = len(ti)
    pi, pj = (truth[np.searchsorted(stamps, t)] for t in (ti, tj))
    rel = relative(pi, pj)
    rel[:3, 2] += np.deg2rad(3.0)  # three wrong relations, as both sensors will say
    rel[3:5, 2] += np.deg2rad(0.5)  # two slightly off: under the threshold
    poses6 = np.zeros((n, 6))
    poses6[:, [0, 1, 5]] = rel
    relations = Relations(ti, tj, poses6)
    odometry = Trajectory(stamps, truth.copy())
    bent = truth.copy()
    k = np.searchsorted(stamps, tj[6])  # the scans alone turn 4 deg wrong at relation 6's end, and stay so
    bent[k:] = compose(bent[k:], [0.0, 0.0, np.deg2rad(4.0)])
    scans = Trajectory(stamps, bent)
    audited = Trajectory(stamps, truth.copy())
    out = audit.contradicted_by_two_sensors("synthetic", audited, odometry, scans, relations, 1.0)
    assert out["contradicted_by_both"] == 3 and out["independent_relations_scored"] == n
    assert out["trajectory_without_them"]["n"] == n - 3
    assert out["trajectory_all"]["all_deg"] == pytest.approx((3 * 3.0 + 2 * 0.5) / n, rel=1e-6)
    assert out["trajectory_without_them"]["all_deg"] == pytest.approx(2 * 0.5 / (n - 3), rel=1e-6)
    with pytest.raises(SystemExit, match="no odometry"):
        audit.contradicted_by_two_sensors("synthetic", audited, None, scans, relations, 1.0)
