"""Study notebooks 04-07 in quick mode, on a freshly simulated prefix of two-rooms in a temporary data folder:

- 04 and 06 through the real batch (papermill, kernel, nbconvert, rerun rrd verify): they run, share one
  computation of the maps, their numbers say what their figures show, and their recordings verify;
- 05 under plain papermill, from another working directory and without the batch's environment (what a user
  types): it runs and writes its report;
- 04-07 on a user's recording (a ROS1 bag made from the simulated frames, without ground truth or odometry)
  given as the ``dataset`` parameter: the same figures, nothing scored against a truth there is none of."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from hsmap.study.batch import run_notebooks

REPO = Path(__file__).resolve().parent.parent


def _errors(out: Path, names):
    return {n: json.loads((out / n / "run.json").read_text()).get("error") for n in names
            if (out / n / "run.json").is_file()}


@pytest.mark.slow
def test_notebooks_04_06_quick_and_05_under_plain_papermill(tmp_path, monkeypatch):
    monkeypatch.setenv("HSMAP_GENERATED", str(tmp_path / "generated"))  # cold caches: simulate and run SLAM
    # (their recordings are opened in the viewer by tests/test_viewer.py's run of the quick study)
    result = run_notebooks(REPO / "notebooks", tmp_path / "reports", only=["04", "06"], quick=True,
                           verify_recordings=False, log=None)
    assert result.ok, _errors(tmp_path / "reports", ("04-map-overlap", "06-topology-doors"))
    o4 = tmp_path / "reports" / "04-map-overlap"
    o6 = tmp_path / "reports" / "06-topology-doors"
    for f in (o4 / "overlap.png", o4 / "overlay.png", o4 / "overlap.rrd", o6 / "topology.png", o6 / "topology.rrd",
              o6 / "topology.graphml", o6 / "topology.txt"):
        assert f.is_file(), f
    m4 = json.loads((o4 / "metrics.json").read_text())["metrics"]
    assert m4["frames"] == 30
    # the known offset between the two maps is found, and registered they overlap far more than before (not
    # fully: in the furnished two-rooms world bookcases, cabinets and a sofa along the walls hide about half of
    # the walls from the floor-level LiDAR; about 0.46 after against 0.14 before)
    assert m4["registration_error_m"] < 0.03 and m4["registration_error_deg"] < 0.5
    assert m4["overlap"] > 0.35 > m4["overlap_before"]
    m6 = json.loads((o6 / "metrics.json").read_text())["metrics"]
    assert m6["rooms"] >= 1 and m6["frames"] == 30 and m6["true_doors"] == 2

    # notebook 05 as a user runs it: plain papermill, another working directory, no HSMAP_NOTEBOOK
    env = {k: v for k, v in os.environ.items() if k != "HSMAP_NOTEBOOK"}
    work = tmp_path / "elsewhere"
    work.mkdir()
    r = subprocess.run([sys.executable, "-m", "papermill", str(REPO / "notebooks" / "05-voronoi-steps.ipynb"),
                        "out.ipynb", "-p", "quick", "True", "-p", "out_dir", str(tmp_path / "plain"),
                        "--no-progress-bar"], cwd=work, env=env, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    m5 = json.loads((tmp_path / "plain" / "05-voronoi-steps" / "metrics.json").read_text())["metrics"]
    assert m5["frames"] == 30 and m5["true_doors"] == 2 and m5["rooms"] >= 1
    assert (tmp_path / "plain" / "05-voronoi-steps" / "voronoi_steps.png").is_file()
    # one computation of the maps for all three notebooks
    assert len(list((tmp_path / "generated" / "maps").glob("two-rooms-seed1-30f-*/meta.json"))) == 1
    assert (tmp_path / "generated" / "two-rooms-seed1-first30" / "dataset.yaml").is_file()

    # papermill documents the parameters, the dataset among them
    r = subprocess.run([sys.executable, "-m", "papermill", "--help-notebook",
                        str(REPO / "notebooks" / "05-voronoi-steps.ipynb")], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0 and "dataset: str" in r.stdout and "a recording to map instead" in r.stdout


@pytest.mark.slow
def test_notebooks_04_07_on_a_recording_without_ground_truth(tmp_path, monkeypatch):
    from _bags import simulated_bag

    from hsmap.study import simulated_dataset

    monkeypatch.setenv("HSMAP_GENERATED", str(tmp_path / "generated"))
    ds = simulated_dataset("two-rooms", 1, max_frames=20)
    simulated_bag(ds, tmp_path / "robot.bag", 20)
    monkeypatch.chdir(tmp_path)  # a relative dataset path is taken from the caller's working directory
    out = tmp_path / "reports"
    names = ("04-map-overlap", "05-voronoi-steps", "06-topology-doors", "07-occluded-vs-nonoccluded")
    # (the recordings' checks in rerun, run by the test above, are left out here: they cost minutes of CPU)
    result = run_notebooks(REPO / "notebooks", out, only=["04", "05", "06", "07"], quick=True,
                           parameters={"dataset": "robot.bag"}, verify_recordings=False, log=None)
    assert result.ok and [r.status for r in result.runs] == ["ok"] * 4, _errors(out, names)
    m = {n: json.loads((out / n / "metrics.json").read_text()) for n in names}
    for n in names:
        assert m[n]["metrics"]["frames"] == 20
        assert json.loads((out / n / "run.json").read_text())["parameters"]["dataset"] == str(tmp_path / "robot.bag")
    # the maps are the recording's: registered as the simulated ones are
    assert m["04-map-overlap"]["metrics"]["registration_error_m"] < 0.05
    # doors and rooms found, nothing compared with a ground truth the recording does not have
    m5 = m["05-voronoi-steps"]["metrics"]
    assert m5["rooms"] >= 1 and m5["true_doors"] is None and m5["door_centre_error_max_m"] is None
    assert (out / "05-voronoi-steps" / "segmentation.png").is_file()
    m6 = m["06-topology-doors"]["metrics"]
    assert m6["graph"] and m6["true_rooms"] is None and (out / "06-topology-doors" / "topology.graphml").is_file()
    m7 = m["07-occluded-vs-nonoccluded"]
    assert m7["metrics"]["slice_rooms"] >= 1 and "slice_precision" not in m7["metrics"]
    assert "no ground truth" in m7["notes"] and m7["headline"] == ["floor_rooms", "slice_rooms", "floor_doors",
                                                                    "slice_doors"]
    # the recording's runs and maps are cached like the scenarios' (one 2D and one 6-DOF run, one maps folder)
    assert len(list((tmp_path / "generated" / "slam").glob("robot-3dof-*/metrics.json"))) == 1
    assert len(list((tmp_path / "generated" / "slam").glob("robot-6dof-*/metrics.json"))) == 1
    assert len(list((tmp_path / "generated" / "maps").glob("robot-rec-seed1-20f-*/meta.json"))) == 1
