"""Study notebooks 04 and 06 in quick mode through the real batch (papermill, kernel, nbconvert, rerun rrd verify),
on a freshly simulated prefix of two-rooms in a temporary data folder: they run, share one computation of the
maps, their numbers say what their figures show, and their recordings verify."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hsmap.study.batch import run_notebooks

REPO = Path(__file__).resolve().parent.parent


@pytest.mark.slow
def test_notebooks_04_06_quick(tmp_path, monkeypatch):
    monkeypatch.setenv("HSMAP_GENERATED", str(tmp_path / "generated"))  # cold caches: simulate and run SLAM
    result = run_notebooks(REPO / "notebooks", tmp_path / "reports", only=["04", "06"], quick=True, log=None)
    errors = {n: json.loads((tmp_path / "reports" / n / "run.json").read_text()).get("error")
              for n in ("04-map-overlap", "06-topology-doors")}
    assert result.ok, errors
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
    assert m6["rooms"] >= 1 and m6["frames"] == 30
    # one computation of the maps for both notebooks
    assert len(list((tmp_path / "generated" / "maps").glob("two-rooms-seed1-30f-*/meta.json"))) == 1
    assert (tmp_path / "generated" / "two-rooms-seed1-first30" / "dataset.yaml").is_file()
