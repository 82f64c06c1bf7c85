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


@pytest.mark.slow
def test_notebook_10_quick(tmp_path, monkeypatch):
    from hsmap.study.public_data import missing_data_reason

    reason = missing_data_reason(["octomap", "freiburg"])
    if reason:
        pytest.skip(reason)
    monkeypatch.setenv("HSMAP_GENERATED", str(tmp_path / "generated"))
    result = run_notebooks(REPO / "notebooks", tmp_path / "reports", only=["10"], quick=True, log=None)
    out = tmp_path / "reports" / "10-real-building-3d"
    run = json.loads((tmp_path / "reports" / "10-real-building-3d" / "run.json").read_text())
    assert result.ok, run.get("error")
    for name in ("bands_segmentation.png", "route.png", "errors.png", "run_slices.png", "fr079_overlay.png"):
        assert (out / name).is_file(), name
    doc = json.loads((out / "metrics.json").read_text())
    m = doc["metrics"]
    assert "skipped" not in doc and m["runs_within_table1"] == m["runs"] == 1
    assert m["run_slice_rooms"][0] >= 1 and m["slice_rooms"] > 5 and m["floor_rooms"] > 0 and m["slice_doors"] > 0
    assert 0.3 < m["fr079_overlap"] <= 1.0
    assert (tmp_path / "generated" / "world-geb079" / "seed1-first30" / "dataset" / "dataset.yaml").is_file()
