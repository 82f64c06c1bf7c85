"""hsmap.study.report: what a notebook writes through its NotebookReport (figures, metrics beside the paper's and
other published numbers, recordings), and the headline rows the index shows."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from hsmap.errors import ConfigError, InputError
from hsmap.study.report import NOTEBOOK_ENV, NotebookReport, headline_rows, readable_label, render_index
from hsmap.viz import figures
from hsmap.viz import rerun as hr

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture
def no_notebook_env(monkeypatch):
    monkeypatch.delenv(NOTEBOOK_ENV, raising=False)


def test_report_writes_metrics_beside_the_paper(tmp_path, no_notebook_env):
    report = NotebookReport(tmp_path, "07-occlusion")
    assert report.dir == tmp_path / "07-occlusion" and report.dir.is_dir()
    table = report.metrics({"precision": np.float64(0.84), "recall": 0.5}, paper={"precision": 0.8453},
                          units={"precision": ""})
    report.metrics({"recall": 0.61, "per_map": {"a": [1, 2]}}, paper={"recall": 0.4838}, notes="quick")
    doc = json.loads((report.dir / "metrics.json").read_text())
    assert doc["metrics"] == {"precision": 0.84, "recall": 0.61, "per_map": {"a": [1, 2]}}
    assert doc["paper"] == {"precision": 0.8453, "recall": 0.4838}
    assert doc["notes"] == "quick" and doc["notebook"] == "07-occlusion"
    assert doc["reference"] == {} and doc["labels"] == {}
    assert "0.8453" in table._repr_html_() and "precision" in repr(table)
    with pytest.raises(InputError, match="headline"):
        report.metrics(headline=["nonexistent"])
    with pytest.raises(InputError, match="JSON"):
        report.metrics({"bad": object()})
    assert [p.name for p in report.dir.iterdir()] == ["metrics.json"]  # nothing half-written


def test_report_name_comes_from_the_runner_and_must_agree(tmp_path, no_notebook_env, monkeypatch):
    with pytest.raises(ConfigError, match="name"):
        NotebookReport(tmp_path)
    monkeypatch.setenv(NOTEBOOK_ENV, "03-slam-6dof")
    assert NotebookReport(tmp_path).name == "03-slam-6dof"
    assert NotebookReport(tmp_path, "03-slam-6dof").name == "03-slam-6dof"
    with pytest.raises(ConfigError, match="03-slam-6dof"):
        NotebookReport(tmp_path, "03-old-name")
    monkeypatch.setenv(NOTEBOOK_ENV, "05-voronoi-steps")
    assert NotebookReport(tmp_path).name == "05-voronoi-steps"
    with pytest.raises(InputError):
        NotebookReport(tmp_path, "../escape")


def test_report_savefig_and_recording(tmp_path, no_notebook_env):
    report = NotebookReport(tmp_path, "01-x")
    fig, ax = figures.new_figure()
    ax.plot([0, 1], [1, 0])
    assert report.savefig(fig, "curve") is None
    assert (report.dir / "curve.png").read_bytes()[:8] == PNG_MAGIC
    assert report.figures == [report.dir / "curve.png"]
    with pytest.raises(InputError):
        report.savefig(fig, "curve.png")
    rec = report.recording("run")
    hr.log_robot_pose(rec, [0.0, 0.0, 0.0])
    assert not (report.dir / "run.rrd").exists()
    assert report.close() == [report.dir / "run.rrd"]
    assert (report.dir / "run.rrd").stat().st_size > 0
    assert rec.application_id == "hsmap_01-x"
    assert sorted(p.name for p in report.dir.iterdir()) == ["curve.png", "run.rrd"]
    assert os.access(report.dir / "curve.png", os.R_OK)


def test_reference_numbers_carry_their_source_and_labels_reach_the_index(tmp_path, no_notebook_env):
    report = NotebookReport(tmp_path, "08-bench")
    table = report.metrics({"intel_trans_m": 0.027, "hs6_max_roll_deg": 0.05},
                           reference={"intel_trans_m": {"value": 0.0229, "source": "Cartographer (Hess 2016)"}},
                           units={"intel_trans_m": "m", "hs6_max_roll_deg": "deg"},
                           labels={"intel_trans_m": "Intel: relations translation error"},
                           headline=["intel_trans_m", "hs6_max_roll_deg"])
    assert "Cartographer (Hess 2016)" in repr(table) and "0.023" in table._repr_html_()
    rows = headline_rows(report.metrics_doc)
    assert [(r.label, r.ours, r.reference, r.source, r.unit) for r in rows] == [
        ("Intel: relations translation error", 0.027, 0.0229, "Cartographer (Hess 2016)", "m"),
        ("HS-SLAM 6-DOF max roll", 0.05, None, "", "deg"),
    ]
    page = render_index([{"name": "08-bench", "status": "ok", "metrics": report.metrics_doc, "html": "08.html"}],
                        {"final": True, "ran": ["08-bench"]})
    assert "Intel: relations translation error" in page and "HS-SLAM 6-DOF max roll" in page
    assert "hs6_max_roll_deg</td>" not in page  # the raw key only as a tooltip
    assert "0.023 m <span class='source'>Cartographer (Hess 2016)</span>" in page
    with pytest.raises(InputError, match="source"):
        report.metrics(reference={"intel_trans_m": {"value": 0.02}})


def test_readable_label():
    assert readable_label("hsslam_final_error_m") == "HS-SLAM final error"
    assert readable_label("odometry_map_error_p95_m") == "odometry map error 95th percentile"
    assert readable_label("rooms") == "rooms"


def test_report_defaults_to_the_reports_folder_and_records_skips(tmp_path, no_notebook_env, monkeypatch, capsys):
    from hsmap.study import paths

    monkeypatch.setattr(paths, "reports_dir", lambda: tmp_path / "default-reports")
    report = NotebookReport("", "08-real-benchmarks")  # the notebooks' default out_dir
    assert report.dir == tmp_path / "default-reports" / "08-real-benchmarks" and report.dir.is_dir()
    report.skip("no data (run hsmap data fetch):\n  freiburg", part="relations")
    report.metrics({"datasets_available": False})
    report.skip("no data (run hsmap data fetch)")
    doc = json.loads((report.dir / "metrics.json").read_text())
    assert doc["skipped"] == "no data (run hsmap data fetch)"
    assert doc["skipped_parts"] == {"relations": "no data (run hsmap data fetch): freiburg"}  # one line
    assert doc["metrics"] == {"datasets_available": False}
    assert "SKIPPED: no data (run hsmap data fetch)" in capsys.readouterr().out
    with pytest.raises(InputError, match="reason"):
        report.skip("  ")
