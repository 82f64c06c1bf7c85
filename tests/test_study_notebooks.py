"""Study notebook 01 in quick mode through the real batch (papermill, kernel, nbconvert, rerun rrd verify), on a
freshly simulated prefix of slam-office in a temporary data folder: it runs, its numbers say what its figures
show (HS-SLAM far better than odometry), and its recording verifies."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hsmap.study.batch import run_notebooks

REPO = Path(__file__).resolve().parent.parent


@pytest.mark.slow
def test_notebook_01_quick(tmp_path, monkeypatch):
    monkeypatch.setenv("HSMAP_GENERATED", str(tmp_path / "generated"))  # cold caches: simulate and run SLAM
    result = run_notebooks(REPO / "notebooks", tmp_path / "reports", only=["01"], quick=True, log=None)
    run = json.loads((tmp_path / "reports" / "01-odometry-vs-hsslam-2d" / "run.json").read_text())
    assert result.ok, run.get("error")
    out = tmp_path / "reports" / "01-odometry-vs-hsslam-2d"
    for name in ("maps.png", "paths.png", "slam.rrd", "metrics.json"):
        assert (out / name).is_file(), name
    m = json.loads((out / "metrics.json").read_text())["metrics"]
    assert m["scans"] == 120
    assert m["hsslam_final_error_m"] < 0.05 < m["odometry_final_error_m"]
    assert m["hsslam_map_error_p95_m"] < 0.05 < m["odometry_map_error_p95_m"]
    # the quick run simulated only the frames it needs, and cached its SLAM run
    assert (tmp_path / "generated" / "slam-office-seed1-first120" / "dataset.yaml").is_file()
    assert len(list((tmp_path / "generated" / "slam").glob("slam-office-3dof-*/metrics.json"))) == 1
