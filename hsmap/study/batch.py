"""The study batch: every notebook in ``notebooks/`` executed by papermill into ``reports/``.

For each ``notebooks/NN-name.ipynb`` (NAME = its file stem) a run writes:

- ``reports/NAME.ipynb``: the executed notebook (papermill marks a failure in it);
- ``reports/NAME.html``: the same as HTML, code cells folded, figures inline, a banner with the run's status;
- ``reports/NAME/``: what the notebook writes itself through :class:`hsmap.study.report.NotebookReport` (figures as
  PNG, ``metrics.json``, rerun recordings ``*.rrd``), plus ``run.json`` (status, error, duration, parameters);
- ``reports/index.html`` and ``index.json``: every notebook with its status, headline numbers beside the
  paper's, duration and date, the versions, the total duration.

A notebook's status is "ok", "failed", or "skipped" when it ran through but said its inputs were missing
(:meth:`hsmap.study.report.NotebookReport.skip`, e.g. notebook 08 without the public benchmarks: "skipped: no
data (run hsmap data fetch)"); a skipped notebook does not fail the batch. The batch needs the study tooling
(papermill, nbconvert, ipykernel: ``pip install 'hsmap[study]'``), which the library does not.

Each notebook gets the parameters ``quick`` (bool) and ``out_dir`` (the reports folder, absolute) plus any
overrides, runs in a fresh kernel of the current interpreter (with ``RERUN_ANALYTICS=0`` and
``$HSMAP_NOTEBOOK`` = NAME) with the notebook's folder as working directory. A notebook that fails does not
stop the others; :func:`run_notebooks` reports it and the command exits non-zero at the end. Recordings are
checked with ``rerun rrd verify``.

A notebook runs into a hidden, locked staging folder of the reports folder (its ``out_dir`` parameter points
there) and its report replaces the previous one, as a whole, only once it is complete (ok or failed): an
interrupted run (Ctrl-C) or a broken machine leaves the previous report as it was, and nothing of an older run
survives beside a newer one. A killed batch's staging folders are removed by the next batch. The index is
rewritten under the reports folder's lock, merged with what concurrent batches wrote (two ``hsmap
reproduce`` at once keep each other's entries). Kernels run with their stderr in ``NAME/kernel-stderr.txt``
(kept when not empty) and are shut down without the interrupt that made them log errors; Ctrl-C ends the batch
with one line.
"""

from __future__ import annotations

import concurrent.futures as cf
import datetime as dt
import json
import multiprocessing
import os
import platform
import subprocess
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .. import __version__, progress
from ..errors import ConfigError, InputError
from ..io import folder_lock, prepare_output_dir, sweep_stale_temporaries, write_json, write_text
from .discovery import (
    PATH_PARAMETERS,
    STANDARD_PARAMETERS,
    NotebookSpec,
    discover,
    inspect_parameters,
    load_parameters_file,
    select,
)
from .execute import (
    KERNEL_NAME,
    cell_progress,
    environ,
    execute_notebook,
    kernel_env,
    write_kernelspec,
)
from .interrupts import busy, marking_interrupts, stop_workers, worker_signals
from .notebook_html import notebook_to_html
from .notebook_run import NotebookRun, now_text
from .parameters import check_parameters, declared_parameters
from .report import render_index
from .tooling import require_study_tooling

__all__ = [
    "NotebookSpec",
    "NotebookRun",
    "BatchResult",
    "discover",
    "select",
    "inspect_parameters",
    "load_parameters_file",
    "run_notebooks",
    "execute_notebook",
    "notebook_to_html",
    "environment_info",
    "KERNEL_NAME",
    "require_study_tooling",
]

def _worker(spec: NotebookSpec, out_dir: str, parameters: dict[str, Any], env: dict[str, str],
            timeout: float | None, verify: bool, versions: dict[str, str]) -> dict[str, Any]:
    """Process-pool entry point: one notebook in this worker's environment."""
    with environ(env), busy():
        try:
            run = execute_notebook(spec, out_dir, parameters, timeout=timeout, verify_recordings=verify,
                                   versions=versions)
        except Exception as exc:  # the machinery itself failed (disk full, ...): still a result
            run = NotebookRun(name=spec.name, notebook=str(spec.path), title=spec.title(), status="failed",
                              error=f"hsmap reproduce: {type(exc).__name__}: {exc}", started=now_text(),
                              parameters=parameters)
    return run.to_dict()


def _package_version(dist: str) -> str:
    from importlib import metadata

    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return "not installed"


def environment_info(repo_dir: str | os.PathLike | None = None) -> dict[str, str]:
    """Versions of hsmap, Python and the libraries the results depend on; the git commit when known."""
    info = {"hsmap": __version__, "python": platform.python_version()}
    for dist in ("numpy", "scipy", "open3d", "rerun-sdk", "matplotlib", "networkx", "scikit-image",
                 "papermill"):
        info[dist] = _package_version(dist)
    info["platform"] = f"{platform.system()} {platform.machine()}, {os.cpu_count()} cpus"
    if repo_dir is not None:
        try:
            head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=repo_dir, capture_output=True,
                                  text=True, timeout=10)
            if head.returncode == 0:
                dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=repo_dir,
                                       capture_output=True, text=True, timeout=30)
                info["git"] = head.stdout.strip() + ("+changes" if dirty.stdout.strip() else "")
        except (OSError, subprocess.SubprocessError):
            pass
    return info


@dataclass
class BatchResult:
    """A batch run: the notebooks run now (``runs``) and every notebook's latest state (``entries``)."""

    runs: list[NotebookRun]
    entries: list[NotebookRun]
    started: str
    duration_s: float
    quick: bool
    versions: dict[str, str]
    index: Path

    @property
    def ok(self) -> bool:
        """No notebook run now failed (skipped ones did not fail)."""
        return all(r.ok for r in self.runs)

    @property
    def failed(self) -> list[NotebookRun]:
        return [r for r in self.runs if not r.ok]

    @property
    def skipped(self) -> list[NotebookRun]:
        return [r for r in self.runs if r.status == "skipped"]


def _previous_run(out_dir: Path, spec: NotebookSpec) -> NotebookRun | None:
    p = out_dir / spec.name / "run.json"
    try:
        return NotebookRun.from_dict(json.loads(p.read_text(encoding="utf-8")))
    except (OSError, ValueError, TypeError, AttributeError):
        return None


def _read_index(out_dir: Path) -> dict[str, NotebookRun]:
    """The entries of ``out_dir/index.json`` by name (none when it is missing or unreadable)."""
    try:
        doc = json.loads((out_dir / "index.json").read_text(encoding="utf-8"))
        return {e["name"]: NotebookRun.from_dict(e) for e in doc.get("notebooks", [])}
    except (OSError, ValueError, TypeError, KeyError, AttributeError):
        return {}


def _alive(pid: int | None) -> bool:
    if pid is None:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # exists, not ours
        return True
    return True


def _latest(out_dir: Path, spec: NotebookSpec, listed: NotebookRun | None) -> NotebookRun:
    """A notebook another batch (or an earlier one) owns: its index entry while that batch runs it, else the
    newer of its index entry and its run.json, else "not run"."""
    if listed is not None and listed.status in ("pending", "running") and _alive(listed.pid):
        return listed
    if listed is not None and listed.status in ("pending", "running"):
        listed = None  # its batch died
    prev = _previous_run(out_dir, spec)
    candidates = [e for e in (listed, prev) if e is not None]
    if not candidates:
        return NotebookRun(name=spec.name, notebook=str(spec.path), title=spec.title(), status="not run")

    def when(e: NotebookRun) -> dt.datetime:
        try:
            t = dt.datetime.fromisoformat(e.started or "")
            return t if t.tzinfo else t.astimezone()
        except ValueError:
            return dt.datetime.min.replace(tzinfo=dt.UTC)

    return max(candidates, key=when)


def run_notebooks(
    notebooks_dir: str | os.PathLike = "notebooks",
    out_dir: str | os.PathLike = "reports",
    *,
    only: Sequence[str] | None = None,
    quick: bool = False,
    jobs: int = 1,
    parameters: Mapping[str, Any] | None = None,
    notebook_parameters: Mapping[str, Mapping[str, Any]] | None = None,
    timeout: float | None = None,
    verify_recordings: bool = True,
    log: Callable[[str], None] | None = print,
) -> BatchResult:
    """Execute the study notebooks and write ``out_dir/index.html`` (see module docstring).

    Parameters
    ----------
    notebooks_dir, out_dir : path-like
    only : sequence of str, optional
        Notebooks to run (full name, short name or number); the index still lists the others with their
        last run.
    quick : bool
        Passed to every notebook: small inputs for a smoke run.
    jobs : int
        Notebooks run at once, each in its own process and kernel.
    parameters : mapping, optional
        Extra parameters for every notebook (``quick`` and ``out_dir`` cannot be overridden here).
    notebook_parameters : mapping of selector to mapping, optional
        Extra parameters for single notebooks (selector as in ``only``).
    timeout : float, optional
        Per-cell time limit in seconds.
    log : callable, optional
        Receives one line when each notebook starts and one when it ends. Under
        :func:`hsmap.progress.reporting`, the heartbeat says which notebooks run, at which cell, for how long.

    Returns
    -------
    BatchResult
        ``.ok`` is False when any notebook run now failed.
    """
    require_study_tooling()
    if int(jobs) < 1:
        raise InputError(f"jobs must be >= 1, got {jobs}")
    jobs = int(jobs)
    if timeout is not None and not timeout > 0:
        raise InputError(f"timeout must be > 0 seconds, got {timeout}")
    specs = discover(notebooks_dir)
    if not specs:
        raise InputError(f"no study notebooks (NN-name.ipynb) in {notebooks_dir}")
    chosen = select(specs, only)
    common, per_nb = _notebook_parameters(specs, chosen, parameters, notebook_parameters)
    out = prepare_output_dir(Path(out_dir).resolve(), "reports folder")
    batch = _Batch(out, specs, chosen, quick, jobs, environment_info(Path(notebooks_dir).resolve()), log)
    order = sorted(chosen, key=lambda s: _previous_duration(out, s)) if jobs > 1 else list(chosen)
    # leftovers of a killed batch (staging folders, temporaries) nobody holds any more
    sweep_stale_temporaries(out, ["index.html", "index.json", *(s.name for s in specs)])
    batch.write_index(final=False)
    progress.stage("notebooks", f"{len(chosen)} to run, {jobs} at a time")
    try:
        with progress.describing(batch.status):
            _run_all(batch, order, common, per_nb, timeout, verify_recordings)
    except KeyboardInterrupt:
        batch.interrupted()
        raise
    merged = batch.write_index(final=True)
    return BatchResult(runs=[batch.runs[s.name] for s in chosen], entries=merged, started=batch.started,
                       duration_s=time.perf_counter() - batch.t0, quick=quick, versions=batch.versions,
                       index=batch.index_path)


def _notebook_parameters(specs: list[NotebookSpec], chosen: list[NotebookSpec],
                         parameters: Mapping[str, Any] | None,
                         notebook_parameters: Mapping[str, Mapping[str, Any]] | None
                         ) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
    """The parameters for every chosen notebook and for each one (:func:`run_notebooks`' ``parameters`` and
    ``notebook_parameters``), checked against the names and types the notebooks declare, their relative paths
    made absolute."""
    common = dict(parameters or {})
    clash = sorted(set(common) & set(STANDARD_PARAMETERS))
    if clash:
        raise ConfigError(f"parameters {clash} are set by 'hsmap reproduce' itself (use --quick / --out)")
    per_nb: dict[str, dict[str, Any]] = {s.name: {} for s in chosen}
    for sel, params in (notebook_parameters or {}).items():
        hits = [s for s in specs if s.matches(sel)]
        if not hits:
            raise InputError(f"parameters given for {sel!r}, which matches no notebook")
        bad = sorted(set(params) & set(STANDARD_PARAMETERS))
        if bad:
            raise ConfigError(f"parameters {bad} for {sel!r} are set by 'hsmap reproduce' itself")
        for h in hits:
            if h.name in per_nb:
                per_nb[h.name].update(params)

    if common or any(per_nb.values()):  # each against the names and types the notebooks declare
        check_parameters({s.name: declared_parameters(s) for s in chosen}, common, per_nb)
    return _absolute_paths(common), {k: _absolute_paths(v) for k, v in per_nb.items()}


def _previous_duration(out: Path, s: NotebookSpec) -> float:
    """The sort key that runs the longest notebooks first (by the previous run's duration, else the notebook's
    metadata ``hsmap.expected_seconds``), which keeps a parallel batch short."""
    prev = _previous_run(out, s)
    if prev and prev.duration_s:
        return -prev.duration_s
    try:
        meta = json.loads(s.path.read_text(encoding="utf-8")).get("metadata", {})
        return -float(meta.get("hsmap", {}).get("expected_seconds", 0.0))
    except (OSError, ValueError, AttributeError):
        return 0.0


class _Batch:
    """One batch of notebooks run into ``out``: its entries in the index, the notebooks running and done, the
    heartbeat's status and the ``log`` lines."""

    def __init__(self, out: Path, specs: list[NotebookSpec], chosen: list[NotebookSpec], quick: bool, jobs: int,
                 versions: dict, log: Callable[[str], None] | None) -> None:
        self.out, self.specs, self.chosen, self.quick, self.jobs = out, specs, chosen, quick, jobs
        self.versions, self.log = versions, log
        self.started = now_text()
        self.t0 = time.perf_counter()
        me = os.getpid()
        self.entries: dict[str, NotebookRun] = {
            s.name: NotebookRun(name=s.name, notebook=str(s.path), title=s.title(), status="pending", pid=me)
            for s in chosen}
        self.index_path = out / "index.html"
        self.runs: dict[str, NotebookRun] = {}
        self.running: dict[str, float] = {}  # notebook -> when it started (monotonic seconds)

    def write_index(self, final: bool) -> list[NotebookRun]:
        """Rewrite the index under the folder's lock, merging what other batches wrote: this batch's entries for
        the notebooks it runs, for the others the newer of the index's entry (unless its batch died) and the
        notebook's run.json."""
        out = self.out
        meta = {"started": self.started, "duration_s": time.perf_counter() - self.t0, "quick": self.quick,
                "jobs": self.jobs, "final": final, "versions": self.versions, "ran": [s.name for s in self.chosen]}
        with folder_lock(out):
            listed = _read_index(out)
            ordered = [self.entries[s.name] if s.name in self.entries else _latest(out, s, listed.get(s.name))
                       for s in self.specs]
            write_text(self.index_path, render_index([e.to_dict() for e in ordered], meta))
            write_json(out / "index.json", {**meta, "notebooks": [e.to_dict() for e in ordered]})
        return ordered

    def notebook_started(self, name: str) -> None:
        if name in self.running or name in self.runs:
            return
        self.running[name] = time.monotonic()
        if self.log is not None:
            self.log(f"[{len(self.runs) + len(self.running)}/{len(self.chosen)}] {name}: started")

    def status(self) -> str:
        now = time.monotonic()
        parts = []
        for name, since in self.running.items():
            cells = cell_progress(self.out, name)
            where = f"cell {min(cells[0] + 1, cells[1])}/{cells[1]}, " if cells and cells[1] else ""
            parts.append(f"{name} ({where}{progress.format_seconds(now - since)})")
        return f"running {', '.join(parts) or 'nothing'}; {len(self.runs)} of {len(self.chosen)} notebooks done"

    def finished(self, run: NotebookRun) -> None:
        self.running.pop(run.name, None)
        self.runs[run.name] = self.entries[run.name] = run
        self.write_index(final=False)
        if self.log is not None:
            msg = f"[{len(self.runs)}/{len(self.chosen)}] {run.name}: {run.status} in {run.duration_s or 0:.1f} s"
            if run.status != "ok" and run.error:
                msg += f": {run.error}"
            for w in run.warnings:
                msg += f"\n    warning: {w}"
            self.log(msg)

    def interrupted(self) -> None:
        """The batch was interrupted: each notebook not done keeps its previous report (with a warning) or is
        marked interrupted, in the final index."""
        for s in self.chosen:
            if s.name not in self.runs:
                prev = _previous_run(self.out, s)
                if prev is not None:  # its previous report is still there, untouched
                    prev.warnings = [*prev.warnings, f"a rerun started {self.started} was interrupted; this is the "
                                                     "previous run"]
                    self.entries[s.name] = prev
                else:
                    self.entries[s.name] = NotebookRun(name=s.name, notebook=str(s.path), title=s.title(),
                                                       status="interrupted", error="the run was interrupted")
                self.runs[s.name] = self.entries[s.name]
        self.write_index(final=True)


def _absolute_paths(params: dict[str, Any]) -> dict[str, Any]:
    """``params`` with the relative paths of :data:`PATH_PARAMETERS` made absolute (from the working directory)."""
    out = dict(params)
    for k in PATH_PARAMETERS:
        v = out.get(k)
        if isinstance(v, str) and v.strip() and not Path(v).expanduser().is_absolute():
            out[k] = str(Path(v).expanduser().resolve())
    return out


def _run_all(batch: _Batch, order: list[NotebookSpec], common: dict[str, Any], per_nb: dict[str, dict[str, Any]],
             timeout: float | None, verify_recordings: bool) -> None:
    out, quick, jobs, versions, entries = batch.out, batch.quick, batch.jobs, batch.versions, batch.entries
    started, finished, write_index, on_start = batch.started, batch.finished, batch.write_index, batch.notebook_started
    with tempfile.TemporaryDirectory(prefix="hsmap-kernel-") as kdir:
        write_kernelspec(kdir)
        jupyter_path = os.pathsep.join([kdir] + [p for p in [os.environ.get("JUPYTER_PATH")] if p])
        base_env = {"JUPYTER_PATH": jupyter_path, "JUPYTER_PLATFORM_DIRS": "1"}
        tasks = []
        for s in order:
            params = {**common, **per_nb[s.name], "quick": bool(quick), "out_dir": str(out)}
            env = {**base_env, **kernel_env(s.name, jobs)}
            tasks.append((s, str(out), params, env, timeout, verify_recordings, versions))
        if jobs == 1:
            with marking_interrupts():
                for t in tasks:
                    entries[t[0].name].status = "running"
                    on_start(t[0].name)
                    write_index(final=False)
                    finished(NotebookRun.from_dict(_worker(*t)))
        else:
            ctx = multiprocessing.get_context("spawn")
            pool = cf.ProcessPoolExecutor(max_workers=min(jobs, len(tasks)), mp_context=ctx,
                                          initializer=worker_signals)
            try:
                futures = {pool.submit(_worker, *t): t for t in tasks}
                for t in tasks[: min(jobs, len(tasks))]:
                    entries[t[0].name].status = "running"
                    on_start(t[0].name)
                write_index(final=False)
                for fut in cf.as_completed(futures):
                    s, params = futures[fut][0], futures[fut][2]
                    try:
                        run = NotebookRun.from_dict(fut.result())
                    except Exception as exc:  # the worker process died
                        run = NotebookRun(name=s.name, notebook=str(s.path), title=s.title(), status="failed",
                                          error=f"worker process failed: {type(exc).__name__}: {exc}",
                                          started=started, parameters=params)
                    finished(run)
                    waiting = [futures[f][0].name for f in futures if not f.done()]
                    for name in waiting[: jobs]:
                        entries[name].status = "running"
                        on_start(name)
            except BaseException:
                stop_workers(pool)
                raise
            pool.shutdown(wait=True)
