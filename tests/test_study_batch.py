"""hsmap reproduce (hsmap.study.batch): a batch of small notebooks (tests/data/notebooks: two good, one that raises, one whose
recording is broken, plus the notebook template) run through the real machinery (papermill, kernels,
nbconvert, rerun rrd verify) into a temporary reports folder; and the conventions of notebooks/."""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from hsmap.cli import main
from hsmap.errors import ConfigError, InputError
from hsmap.study.batch import discover, load_parameters_file, run_notebooks, select
from hsmap.study.discovery import parse_value
from hsmap.study.report import format_duration, format_value, headline_rows, render_index

HERE = Path(__file__).parent
DATA = HERE / "data" / "notebooks"
REPO = HERE.parent
STUDY_NOTEBOOKS = sorted((REPO / "notebooks").glob("*.ipynb"))


def hsmap(*args, timeout=600):
    env = dict(os.environ, RERUN_ANALYTICS="0")
    return subprocess.run([sys.executable, "-m", "hsmap.cli", *map(str, args)], capture_output=True,
                          text=True, env=env, timeout=timeout)


def read_nb(path):
    return json.loads(Path(path).read_text(encoding="utf-8"))


def every_file(folder):
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file())


# --- the batch -------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_batch_runs_every_notebook_and_marks_the_failures(tmp_path):
    nbdir = tmp_path / "notebooks"
    shutil.copytree(DATA, nbdir)
    # the template made into a study notebook as its README says: copied, and its name put in
    template = (REPO / "notebooks" / "template.ipynb").read_text(encoding="utf-8")
    assert template.count('NotebookReport(out_dir, \\"NN-name\\")') == 1
    (nbdir / "05-template.ipynb").write_text(template.replace('\\"NN-name\\"', '\\"05-template\\"'),
                                             encoding="utf-8")
    shutil.copy(DATA / "03-second.ipynb", nbdir / "scratch.ipynb")  # not NN-name: not part of the study
    out = tmp_path / "reports"
    # outputs of an earlier run that must not survive: a failing notebook must never look complete
    (out / "02-fails").mkdir(parents=True)
    (out / "02-fails" / "metrics.json").write_text('{"metrics": {"stale": 1}}')
    (out / "02-fails" / "old-figure.png").write_bytes(b"old")
    (out / "02-fails.html").write_text("<html>an old report that looked complete</html>")
    params = tmp_path / "params.yaml"
    params.write_text("notebooks:\n  good: {repeat: 3}\n")

    r = hsmap("reproduce", "--notebooks", nbdir, "--out", out, "--jobs", "2", "-p", "label", "from-cli",
              "--parameters-file", params)

    # a failing notebook does not stop the others; the command fails at the end and names the failures
    assert r.returncode == 1, r.stdout + r.stderr
    assert "failed: 02-fails, 04-bad-recording" in r.stderr
    index = json.loads((out / "index.json").read_text())
    status = {e["name"]: e["status"] for e in index["notebooks"]}
    assert status == {"01-good": "ok", "02-fails": "failed", "03-second": "ok", "04-bad-recording": "failed",
                      "05-template": "ok"}
    assert index["final"] is True and index["jobs"] == 2 and index["quick"] is False
    entries = {e["name"]: e for e in index["notebooks"]}

    # the good ones: executed notebook, HTML with the figure inline, metrics.json, figures, verified recordings
    for name in ("01-good", "03-second", "05-template"):
        html = (out / f"{name}.html").read_text()
        assert "hsmap-banner ok" in html and "FAILED" not in html
        assert "<details class=\"hsmap-code\">" in html  # code folded
        assert (out / name / "metrics.json").is_file()
        nb = read_nb(out / f"{name}.ipynb")
        assert nb["metadata"]["hsmap"]["status"] == "ok"
        assert entries[name]["duration_s"] > 0 and entries[name]["started"]
    # the template's figure (inline in its HTML, as a PNG beside it) and its recording (verified)
    assert "data:image/png;base64" in (out / "05-template.html").read_text()
    assert entries["05-template"]["figures"] == ["05-template/paths.png"]
    assert (out / "05-template" / "paths.png").read_bytes()[:4] == b"\x89PNG"
    assert entries["05-template"]["recordings"] == ["05-template/paths.rrd"]
    assert not entries["05-template"]["warnings"]

    # parameters: quick and out_dir for all, -p for all, the parameters file for one notebook
    good = json.loads((out / "01-good" / "metrics.json").read_text())["metrics"]
    assert good == {"quick": False, "label": "from-cli", "repeat": 3, "error_m": pytest.approx(0.0375)}
    assert json.loads((out / "03-second" / "metrics.json").read_text())["metrics"]["quick"] is False
    injected = [c for c in read_nb(out / "01-good.ipynb")["cells"]
                if "injected-parameters" in c["metadata"].get("tags", [])]
    assert len(injected) == 1 and f'out_dir = "{out.resolve()}"' in "".join(injected[0]["source"])
    assert entries["01-good"]["parameters"] == {"label": "from-cli", "repeat": 3, "quick": False,
                                                "out_dir": str(out.resolve())}

    # the failing notebook: marked failed everywhere, with its error; nothing stale left
    e = entries["02-fails"]
    assert "RuntimeError: deliberate failure in the test notebook" in e["error"]
    html = (out / "02-fails.html").read_text()
    assert "hsmap-banner failed" in html and "FAILED" in html and "deliberate failure" in html
    assert "looked complete" not in html
    assert html.count('<details class="hsmap-code" open') == 1  # the failing cell's code is shown
    assert read_nb(out / "02-fails.ipynb")["metadata"]["hsmap"]["status"] == "failed"
    assert json.loads((out / "02-fails" / "metrics.json").read_text())["metrics"] == {"before_failure": 1}
    assert not (out / "02-fails" / "old-figure.png").exists()
    assert "does not verify" in entries["04-bad-recording"]["error"]

    # the index: every notebook, status, error, numbers beside the paper's, durations, versions
    index_html = (out / "index.html").read_text()
    for name in status:
        assert f"id='{name}'" in index_html
    assert "scratch" not in index_html
    assert "deliberate failure in the test notebook" in index_html
    from hsmap.study.report import format_value

    # ours beside the paper's, each to the millimetre
    assert f"{format_value(good['error_m'], 'm')} m</td><td>0.030 m" in index_html
    assert "FAILED: 2 of 5 notebooks failed" in index_html
    for key in ("hsmap", "python", "numpy", "open3d", "rerun-sdk"):
        assert index["versions"][key] and key in index_html
    assert index["duration_s"] > 0

    # nothing half-written: no temporaries anywhere
    files = every_file(out)
    assert not [f for f in files if Path(f).name.startswith(".")], files
    assert sorted(f for f in files if "/" not in f) == sorted(
        ["index.html", "index.json"] + [f"{n}.{s}" for n in status for s in ("html", "ipynb")])


@pytest.mark.slow
def test_only_runs_the_chosen_and_keeps_the_others_last_results(tmp_path):
    nbdir = tmp_path / "notebooks"
    nbdir.mkdir()
    for name in ("02-fails.ipynb", "03-second.ipynb"):
        shutil.copy(DATA / name, nbdir / name)
    out = tmp_path / "reports"
    lines = []
    first = run_notebooks(nbdir, out, only=["fails"], quick=True, log=lines.append)
    assert not first.ok and [r.name for r in first.failed] == ["02-fails"]
    second = run_notebooks(nbdir, out, only=["03-second"], log=lines.append)
    assert second.ok  # only what ran now decides the outcome
    assert lines[-1].startswith("[1/1] 03-second: ok")
    index = json.loads((out / "index.json").read_text())
    assert index["ran"] == ["03-second"] and index["quick"] is False
    entries = {e["name"]: e for e in index["notebooks"]}
    assert entries["02-fails"]["status"] == "failed"  # from the first run, still shown
    assert entries["02-fails"]["parameters"]["quick"] is True
    assert json.loads((out / "03-second" / "metrics.json").read_text())["metrics"]["quick"] is False
    page = (out / "index.html").read_text()
    assert "(from an earlier run)" in page and "complete: all 1 notebooks ok" in page


def test_a_batch_says_when_a_notebook_starts_and_which_cell_runs(tmp_path):
    from hsmap import progress

    nbdir = tmp_path / "notebooks"
    nbdir.mkdir()
    nb = read_nb(DATA / "03-second.ipynb")
    nb["cells"].insert(2, {"cell_type": "code", "id": "sleeps", "metadata": {}, "execution_count": None, "outputs": [],
                           "source": "import time\n\ntime.sleep(4)"})
    (nbdir / "07-slow.ipynb").write_text(json.dumps(nb), encoding="utf-8")
    lines = []
    with progress.reporting(lines.append, interval=0.5):
        result = run_notebooks(nbdir, tmp_path / "reports", log=lines.append, verify_recordings=False)
    assert result.ok, lines
    assert lines[0] == "notebooks: started, 1 to run, 1 at a time"
    assert lines[1] == "[1/1] 07-slow: started"
    assert lines[-1].startswith("[1/1] 07-slow: ok in ")
    beats = lines[2:-1]
    assert beats and all(b.startswith("notebooks: running 07-slow (") and "0 of 1 notebooks done" in b for b in beats)
    # the sleeping cell (after the parameters and the injected parameters), from the notebook papermill saves
    assert any("(cell 3/4, " in b for b in beats), "\n".join(beats)


def test_list_prints_parameters(capsys):
    assert main(["reproduce", "--notebooks", str(DATA), "--list"]) == 0
    out = capsys.readouterr().out
    assert "01-good  (A good test notebook)" in out
    assert "    quick: bool = False" in out
    assert "    repeat: int = 1" in out


def test_bad_invocations_fail_with_one_line(tmp_path, capsys):
    def fails(*args):
        assert main(["reproduce", "--out", str(tmp_path / "r"), *map(str, args)]) == 2
        err = capsys.readouterr().err
        assert err.startswith("hsmap: error:") and err.count("\n") == 1
        return err

    assert "does not exist" in fails("--notebooks", tmp_path / "missing")
    assert "01-good" in fails("--notebooks", DATA, "--only", "99-nothing")  # lists the notebooks there are
    assert "--quick" in fails("--notebooks", DATA, "-p", "quick", "true")
    assert "jobs" in fails("--notebooks", DATA, "--jobs", "0")
    assert "matches no notebook" in fails("--notebooks", DATA, "--parameters-file",
                                          _write(tmp_path / "p.yaml", "notebooks: {nothing: {a: 1}}\n"))
    assert not (tmp_path / "r").exists() or not any((tmp_path / "r").iterdir())


def _write(path, text):
    path.write_text(text)
    return path


# --- pieces ----------------------------------------------------------------------------------------------


def test_discover_and_select(tmp_path):
    for name in ("02-b.ipynb", "01-a.ipynb", "10-c-d.ipynb", "scratch.ipynb", "1-x.ipynb", "03-B.ipynb"):
        (tmp_path / name).write_text("{}")
    specs = discover(tmp_path)
    assert [s.name for s in specs] == ["01-a", "02-b", "10-c-d"]
    assert [s.name for s in select(specs, ["c-d", "1", "02-b.ipynb"])] == ["01-a", "02-b", "10-c-d"]
    assert select(specs, None) == specs
    with pytest.raises(InputError, match="01-a, 02-b, 10-c-d"):
        select(specs, ["zz"])


def test_every_notebook_the_reproduce_help_names_exists():
    from hsmap.cli import build_parser
    from hsmap.study import discovery

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    only = next(a for a in sub.choices["reproduce"]._actions if "--only" in a.option_strings)
    examples = re.findall(r"'([^']+)'", only.help)
    per_notebook = re.findall(r"notebooks:.*\n +(\S+):", discovery.load_parameters_file.__doc__)
    assert len(examples) == 3 and per_notebook
    specs = discover(REPO / "notebooks")
    for name in [*examples, *per_notebook]:
        assert select(specs, [name]), name


def test_parameters_file(tmp_path):
    p = tmp_path / "p.yaml"
    p.write_text("parameters: {seed: 2}\nnotebooks:\n  03-slam: {n_scans: 60}\n")
    assert load_parameters_file(p) == ({"seed": 2}, {"03-slam": {"n_scans": 60}})
    p.write_text("seed: 2\n")
    with pytest.raises(ConfigError, match="seed"):
        load_parameters_file(p)
    p.write_text("notebooks: {a: 3}\n")
    with pytest.raises(ConfigError, match="notebooks"):
        load_parameters_file(p)
    with pytest.raises(ConfigError, match="cannot read"):
        load_parameters_file(tmp_path / "missing.yaml")
    assert parse_value("true") is True and parse_value("0.5") == 0.5 and parse_value("abc") == "abc"
    assert parse_value("[1, 2]") == [1, 2]


def test_index_escapes_errors_and_shows_states():
    entries = [
        {"name": "01-a", "title": "A", "status": "ok", "duration_s": 75.0, "html": "01-a.html",
         "metrics": {"metrics": {"p": 0.84531, "n": 3}, "paper": {"p": 0.8453}, "units": {}}},
        {"name": "02-b", "status": "failed", "error": "ValueError: <script>alert(1)</script>", "error_cell": 4},
        {"name": "03-c", "status": "not run"},
    ]
    page = render_index(entries, {"started": "2026-01-01T00:00:00", "duration_s": 3700, "final": True,
                                  "ran": ["01-a", "02-b"], "versions": {"hsmap": "0.1.0"}})
    assert "<script>alert" not in page and "&lt;script&gt;" in page
    assert "FAILED: 1 of 2 notebooks failed, 1 ok" in page
    assert "0.8453</td><td>0.8453" in page and "1 min 15 s" in page and "1 h 01 min" in page
    running = render_index(entries[:1], {"final": False, "ran": ["01-a"]})
    assert "in progress" in running and "http-equiv='refresh'" in running
    assert format_duration(None) == "-" and format_value(None) == "-" and format_value(1e-5) == "1.000e-05"
    (row,) = headline_rows({"metrics": {"a": 1, "b": {"x": 1}}, "paper": {}})
    assert (row.key, row.ours, row.paper, row.reference, row.unit) == ("a", 1, None, None, "")


def test_metric_values_are_rounded_to_their_unit():
    assert format_value(0.0123456, "m") == "0.012" and format_value(12.3456789, "m") == "12.346"
    assert format_value(0.00012, "m") == "0.00012"  # small, not shown as zero
    assert format_value(-1e-17, "deg") == "0.00" and format_value(0.31234, "deg") == "0.31"
    assert format_value([0.123456, 1.5], "m") == "[0.123, 1.500]"
    assert format_value(0.0123456) == "0.01235" and format_value(3, "m") == "3"
    page = render_index([{"name": "01-a", "status": "ok", "metrics": {
        "metrics": {"err_m": 0.0234567}, "units": {"err_m": "m"}, "headline": ["err_m"]}}], {"final": True})
    assert "0.023 m" in page and "0.02346" not in page


# --- the study notebooks' conventions --------------------------------------------------------------------


@pytest.mark.parametrize("path", STUDY_NOTEBOOKS, ids=[p.name for p in STUDY_NOTEBOOKS])
def test_study_notebooks_are_committed_clean_with_one_parameters_cell(path):
    nb = read_nb(path)
    code = [c for c in nb["cells"] if c["cell_type"] == "code"]
    with_outputs = [i for i, c in enumerate(code) if c.get("outputs") or c.get("execution_count") is not None]
    assert not with_outputs, f"{path.name}: code cells {with_outputs} have outputs; clear them before committing"
    tagged = [c for c in nb["cells"] if "parameters" in c.get("metadata", {}).get("tags", [])]
    assert len(tagged) == 1, f"{path.name}: {len(tagged)} cells tagged 'parameters', need exactly one"
    assert tagged[0]["cell_type"] == "code"
    src = "".join(tagged[0]["source"])
    assert "quick: bool = False" in src and "out_dir: str = " in src, (
        f"{path.name}: the parameters cell must declare 'quick: bool = False' and 'out_dir: str = ...'")
    first = nb["cells"][0]
    assert first["cell_type"] == "markdown" and "".join(first["source"]).startswith("# "), (
        f"{path.name}: the first cell must be a Markdown title '# NN: ...'")
    if path.stem != "template":
        # it names itself, so that it runs outside 'hsmap reproduce' too (plain papermill, nbconvert, JupyterLab)
        body = "".join("".join(c["source"]) for c in code)
        assert f'NotebookReport(out_dir, "{path.stem}")' in body, (
            f"{path.name}: make its report with NotebookReport(out_dir, \"{path.stem}\")")
    if path.stem[:2] in ("04", "05", "06", "07"):  # the maps' notebooks take a user's recording
        assert 'dataset: str = ""' in src and "dataset=dataset" in "".join("".join(c["source"]) for c in code)


def test_an_interrupted_run_leaves_no_temporaries_and_says_so(tmp_path, monkeypatch):
    import papermill

    import hsmap.study.batch as rp

    nbdir = tmp_path / "notebooks"
    nbdir.mkdir()
    for name in ("02-fails.ipynb", "03-second.ipynb"):
        shutil.copy(DATA / name, nbdir / name)
    out = tmp_path / "reports"
    out.mkdir()
    (out / ".03-second.abc.running.ipynb").write_text("{}")  # left by a killed run

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(papermill, "execute_notebook", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run_notebooks(nbdir, out, log=None)
    index = json.loads((out / "index.json").read_text())
    assert index["final"] is True
    assert [e["status"] for e in index["notebooks"]] == ["interrupted", "interrupted"]
    assert "FAILED: 2 of 2 notebooks failed" in (out / "index.html").read_text()
    assert every_file(out) == ["index.html", "index.json"]

    calls = []

    def fake_worker(spec, *args):
        calls.append(spec.name)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return rp.NotebookRun(name=spec.name, notebook=str(spec.path), status="ok", duration_s=1.0).to_dict()

    monkeypatch.setattr(rp, "_worker", fake_worker)
    with pytest.raises(KeyboardInterrupt):
        run_notebooks(nbdir, out, log=None)
    index = json.loads((out / "index.json").read_text())
    assert [e["status"] for e in index["notebooks"]] == ["ok", "interrupted"]


def test_kernels_run_blas_on_hsmap_blas_threads_unless_the_caller_chose(monkeypatch):
    from hsmap.study.execute import kernel_env

    for var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS", "HSMAP_BLAS_THREADS"):
        monkeypatch.delenv(var, raising=False)
    env = kernel_env("01-x", jobs=1)
    assert env["OPENBLAS_NUM_THREADS"] == env["MKL_NUM_THREADS"] == "1" and "OMP_NUM_THREADS" not in env
    monkeypatch.setenv("HSMAP_BLAS_THREADS", "2")
    assert kernel_env("01-x", jobs=1)["OPENBLAS_NUM_THREADS"] == "2"
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "4")
    env = kernel_env("01-x", jobs=2)
    assert "OPENBLAS_NUM_THREADS" not in env and env["OMP_NUM_THREADS"] == str(max(1, (os.cpu_count() or 1) // 2))


# --- notebooks whose inputs are missing ------------------------------------------------------------------


def _notebook(cells: list[str], title: str) -> dict:
    return {"cells": [{"cell_type": "markdown", "id": "c0", "metadata": {}, "source": [f"# {title}"]}]
            + [{"cell_type": "code", "execution_count": None, "id": f"c{k + 1}",
                "metadata": {"tags": ["parameters"]} if k == 0 else {}, "outputs": [], "source": [src]}
               for k, src in enumerate(cells)],
            "metadata": {"kernelspec": {"display_name": "Python 3", "language": "python", "name": "python3"},
                         "language_info": {"name": "python"}}, "nbformat": 4, "nbformat_minor": 5}


@pytest.mark.slow
def test_a_notebook_without_its_data_is_marked_skipped_not_ok(tmp_path, capsys):
    nbdir = tmp_path / "notebooks"
    nbdir.mkdir()
    cells = ['quick: bool = False\nout_dir: str = ""',
             'from hsmap.study import NotebookReport\nreport = NotebookReport(out_dir, "01-needs-data")\n'
             'report.skip("no data (run hsmap data fetch): the maps", part="maps")\n'
             'report.skip("no data (run hsmap data fetch): nothing to show")\n'
             'report.metrics({"datasets_available": False})']
    (nbdir / "01-needs-data.ipynb").write_text(json.dumps(_notebook(cells, "Needs data")), encoding="utf-8")
    out = tmp_path / "reports"
    assert main(["reproduce", "--notebooks", str(nbdir), "--out", str(out), "--no-verify"]) == 0  # not a failure
    assert "0 of 1 notebooks ok, 1 skipped (inputs missing)" in capsys.readouterr().out
    (entry,) = json.loads((out / "index.json").read_text())["notebooks"]
    assert entry["status"] == "skipped" and entry["error"] == "no data (run hsmap data fetch): nothing to show"
    assert entry["warnings"] == ["skipped maps: no data (run hsmap data fetch): the maps"]
    page = (out / "index.html").read_text()
    assert "<span class='status skipped'>skipped</span>" in page and "no data (run hsmap data fetch)" in page
    assert "complete: 0 of 1 notebooks ok, 1 skipped" in page
    assert "hsmap-banner skipped" in (out / "01-needs-data.html").read_text()


def test_reproduce_says_what_to_install_without_the_study_tooling(monkeypatch, capsys):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "papermill" else real(name, *a))
    for args in (["reproduce", "--notebooks", str(DATA), "--list"], ["reproduce", "--notebooks", str(DATA)]):
        assert main(args) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "papermill is not installed: pip install 'hsmap[study]'" in err


def test_a_kernel_that_dies_before_it_starts_gets_one_more_try(tmp_path, monkeypatch):
    import papermill

    from hsmap.study.batch import discover, execute_notebook

    nbdir = tmp_path / "notebooks"
    nbdir.mkdir()
    shutil.copy(DATA / "03-second.ipynb", nbdir / "03-second.ipynb")
    (spec,) = discover(nbdir)
    calls = []

    def flaky(*args, **kwargs):
        calls.append(1)
        if len(calls) <= deaths:
            raise RuntimeError("Kernel died before replying to kernel_info")

    monkeypatch.setattr(papermill, "execute_notebook", flaky)
    deaths = 1
    run = execute_notebook(spec, tmp_path / "reports", {"quick": True}, verify_recordings=False)
    assert run.status == "ok" and len(calls) == 2
    assert any("started again" in w for w in run.warnings)
    calls.clear()
    deaths = 2
    run = execute_notebook(spec, tmp_path / "reports", {"quick": True}, verify_recordings=False)
    assert run.status == "failed" and len(calls) == 2 and "died before replying" in run.error


def test_notebook_reports_swallow_open3d_banner(tmp_path):
    import subprocess
    import sys

    (tmp_path / "open3d.py").write_text("print('Jupyter environment detected. Enabling Open3D WebVisualizer.')\n")
    code = ("import sys; sys.path.insert(0, sys.argv[1]); from hsmap.study.report import _quiet_open3d; "
            "_quiet_open3d(); import open3d; print('after', 'open3d' in sys.modules)")
    p = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True, check=True)
    assert p.stdout == "after True\n", p.stdout
