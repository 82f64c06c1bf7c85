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
import contextlib
import datetime as dt
import json
import logging
import multiprocessing
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from .. import __version__
from ..errors import ConfigError, DependencyError, InputError, OutputError
from ..io import atomic_open, write_json, write_text
from .report import NOTEBOOK_ENV, read_metrics

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

NOTEBOOK_RE = re.compile(r"^(\d{2})-([a-z0-9][a-z0-9_-]*)\.ipynb$")
KERNEL_NAME = "hsmap-python"
#: Parameters every notebook receives.
STANDARD_PARAMETERS = ("quick", "out_dir")
#: Parameters that name a file or folder: a relative one is taken from the caller's working directory (a notebook
#: runs in its own folder), e.g. ``hsmap reproduce -p dataset my-recording.bag``.
PATH_PARAMETERS = ("dataset", "datasets")
_BLAS_VARS = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


#: The study tooling the batch imports, and the distribution each comes from.
STUDY_TOOLING = {"papermill": "papermill", "nbformat": "nbformat", "nbconvert": "nbconvert",
                 "ipykernel": "ipykernel"}


def require_study_tooling() -> None:
    """Raise :class:`~hsmap.errors.DependencyError` (one line: what to install) when the study tooling is
    missing: ``pip install hsmap`` gives the library and the commands without Jupyter."""
    import importlib.util

    missing = [dist for mod, dist in STUDY_TOOLING.items() if importlib.util.find_spec(mod) is None]
    if missing:
        raise DependencyError(
            f"running the study notebooks needs the study tooling, and {', '.join(missing)} "
            f"{'is' if len(missing) == 1 else 'are'} not installed: pip install 'hsmap[study]' "
            "(a checkout's 'make setup' installs it)")


def _lighten_jupyter_imports() -> None:
    """Skip jsonschema's optional RFC 3987 checker (``rfc3987_syntax`` compiles ~40 grammars on import,
    seconds of CPU in every process that imports nbformat); notebooks never use IRI formats."""
    if "jsonschema" not in sys.modules:
        sys.modules.setdefault("rfc3987_syntax", None)  # type: ignore[arg-type]


class _QuietDashComm(logging.Filter):
    """Drop nbclient's "No handler found for comm target 'dash'": importing open3d imports plotly's
    ``dash``, whose Jupyter hook opens a comm that only a live front end answers. Harmless, but it was
    the only line the batch printed besides the results."""

    def filter(self, record: logging.LogRecord) -> bool:
        return "comm target 'dash'" not in record.getMessage()


class _QuietOnceInterrupted(logging.Filter):
    """Drop every record once the batch is interrupted: the kernel is shut down under a cell that is still
    waiting for its reply, and nbclient then logs "Kernel died while waiting for execute reply." and asyncio
    "Task exception was never retrieved ... DeadKernelError" (when the task is collected, later). An
    interrupted batch says one line, ``hsmap: interrupted``."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not _interrupted


def _quiet_papermill_log() -> None:
    for name, quiet in (("papermill", (_QuietDashComm, _QuietOnceInterrupted)),
                        ("asyncio", (_QuietOnceInterrupted,))):
        log = logging.getLogger(name)
        for cls in quiet:
            if not any(isinstance(f, cls) for f in log.filters):
                log.addFilter(cls())


# --- discovery -----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class NotebookSpec:
    """A study notebook ``NN-name.ipynb``.

    Attributes
    ----------
    path : pathlib.Path
    name : str
        File stem, ``"NN-name"``: the report's name.
    number : int
    short : str
        ``"name"`` without the number.
    """

    path: Path
    name: str
    number: int
    short: str

    def matches(self, selector: str) -> bool:
        s = selector.strip()
        s = s[:-6] if s.endswith(".ipynb") else s
        return s in (self.name, self.short, f"{self.number:02d}", str(self.number))

    def title(self) -> str:
        """The first Markdown heading of the notebook (its name when it has none)."""
        try:
            nb = json.loads(self.path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return self.name
        for cell in nb.get("cells", []):
            if cell.get("cell_type") != "markdown":
                continue
            src = cell.get("source", "")
            src = "".join(src) if isinstance(src, list) else src
            for line in src.splitlines():
                if line.startswith("#"):
                    return line.lstrip("#").strip() or self.name
        return self.name


def discover(notebooks_dir: str | os.PathLike) -> list[NotebookSpec]:
    """The study notebooks ``NN-name.ipynb`` in ``notebooks_dir``, in number order.

    Files that do not follow the pattern (scratch notebooks, checkpoints) are not study notebooks.
    """
    d = Path(notebooks_dir)
    if not d.is_dir():
        raise InputError(f"notebooks folder {d} does not exist")
    specs = []
    for p in sorted(d.iterdir()):
        m = NOTEBOOK_RE.match(p.name)
        if m and p.is_file():
            specs.append(NotebookSpec(p.resolve(), p.stem, int(m.group(1)), m.group(2)))
    return sorted(specs, key=lambda s: (s.number, s.name))


def select(specs: Sequence[NotebookSpec], only: Sequence[str] | None) -> list[NotebookSpec]:
    """The notebooks named in ``only`` (full name, name without number, or number); all when empty."""
    if not only:
        return list(specs)
    chosen, unknown = [], []
    for sel in only:
        hits = [s for s in specs if s.matches(sel)]
        if not hits:
            unknown.append(sel)
        for h in hits:
            if h not in chosen:
                chosen.append(h)
    if unknown:
        have = ", ".join(s.name for s in specs) or "none"
        raise InputError(f"no notebook matches {', '.join(map(repr, unknown))}; the notebooks are: {have}")
    return sorted(chosen, key=lambda s: (s.number, s.name))


def inspect_parameters(spec: NotebookSpec | str | os.PathLike) -> dict[str, dict[str, Any]]:
    """The notebook's ``parameters`` cell as papermill reads it: name -> {inferred_type_name, default, help}."""
    require_study_tooling()
    _lighten_jupyter_imports()
    import papermill

    path = spec.path if isinstance(spec, NotebookSpec) else Path(spec)
    return {k: dict(v) for k, v in papermill.inspect_notebook(str(path)).items()}


def parse_value(text: str) -> Any:
    """A ``-p KEY VALUE`` value read as YAML (``true``, ``3``, ``0.5``, ``[1, 2]``; otherwise the string)."""
    import yaml

    from ..limits import load_yaml

    try:
        return load_yaml(text)
    except yaml.YAMLError:
        return text


def load_parameters_file(path: str | os.PathLike) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
    """Read a parameters YAML::

        parameters:            # every notebook
          seed: 1
        notebooks:             # one notebook (full name, short name or number)
          03-slam-6dof: {n_scans: 60}

    Returns (common parameters, per-notebook parameters keyed by selector).
    """
    from ..config import read_yaml

    path = Path(path)
    doc = read_yaml(path, "parameters file")
    if doc is None:
        return {}, {}
    if not isinstance(doc, dict):
        raise ConfigError(f"{path}: expected a mapping with 'parameters' and/or 'notebooks'")
    unknown = sorted(set(doc) - {"parameters", "notebooks"})
    if unknown:
        raise ConfigError(f"{path}: unknown key(s) {unknown}; expected 'parameters' and/or 'notebooks'")
    common = doc.get("parameters") or {}
    per = doc.get("notebooks") or {}
    if not isinstance(common, dict):
        raise ConfigError(f"{path}: 'parameters' must be a mapping of name to value")
    if not isinstance(per, dict) or not all(isinstance(v, dict) for v in per.values()):
        raise ConfigError(f"{path}: 'notebooks' must map a notebook name to a mapping of parameters")
    return dict(common), {str(k): dict(v) for k, v in per.items()}


# --- one notebook ----------------------------------------------------------------------------------------


@dataclass
class NotebookRun:
    """What became of one notebook (also written as ``reports/NAME/run.json``)."""

    name: str
    notebook: str
    title: str = ""
    status: str = "not run"  # "ok", "skipped", "failed", "running", "pending", "not run", "interrupted"
    error: str | None = None
    error_cell: int | None = None
    started: str | None = None
    duration_s: float | None = None
    parameters: dict[str, Any] = field(default_factory=dict)
    html: str | None = None
    ipynb: str | None = None
    figures: list[str] = field(default_factory=list)
    recordings: list[str] = field(default_factory=list)
    metrics: dict[str, Any] | None = None
    warnings: list[str] = field(default_factory=list)
    pid: int | None = None  # of the batch that has it pending or running (a dead one's entry is stale)

    @property
    def ok(self) -> bool:
        """Ran through: "ok", or "skipped" (its inputs are missing, and it said so)."""
        return self.status in ("ok", "skipped")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> NotebookRun:
        known = {f for f in cls.__dataclass_fields__}
        return cls(**{k: v for k, v in d.items() if k in known})


def _now() -> str:
    return dt.datetime.now().astimezone().isoformat(timespec="seconds")


def _staging_prefix(name: str) -> str:
    """Prefix of the hidden staging folders of notebook ``name`` in the reports folder."""
    from ..io import STAGING_PREFIX

    return f"{STAGING_PREFIX}{name}-"


def _publish(stage: Path, out_dir: Path, name: str) -> None:
    """Replace the notebook's report in ``out_dir`` (``NAME/``, ``NAME.ipynb``, ``NAME.html``) by the complete
    one in ``stage``, under the reports folder's lock (a concurrent batch publishing the same notebook waits).

    The previous folder is moved aside (into ``stage``, deleted with it) and the new one renamed into place; the
    two files are replaced by renames. Nothing of the old run survives beside the new one.
    """
    from ..io import folder_lock

    old, aside = out_dir / name, stage / ".previous"
    with folder_lock(out_dir):
        moved = False
        if old.is_symlink() or old.is_file():
            old.unlink()
        elif old.exists():
            os.rename(old, aside)
            moved = True
        try:
            os.rename(stage / name, old)
        except OSError:
            if moved:
                os.rename(aside, old)
            raise
        for suffix in (".ipynb", ".html"):
            os.replace(stage / f"{name}{suffix}", out_dir / f"{name}{suffix}")


def _kernel_manager_class(stderr_path: Path):
    """The batch's kernel manager: a kernel's stderr goes to ``stderr_path`` (the report keeps it when it is not
    empty) instead of the terminal, and shutting a kernel down does not interrupt it first: jupyter_client sends
    SIGINT before its shutdown request, which a kernel between two messages reports as "[IPKernelApp] ERROR |
    KeyboardInterrupt caught in kernel." after every notebook, and one whose parent was interrupted answers with
    a ZMQ traceback."""
    from jupyter_client.manager import AsyncKernelManager

    class BatchKernelManager(AsyncKernelManager):
        async def _async_interrupt_kernel(self) -> None:
            if self.shutting_down:
                return
            await super()._async_interrupt_kernel()

        async def _async_launch_kernel(self, kernel_cmd, **kw):
            with open(stderr_path, "ab") as err:  # the kernel gets its own copy of the descriptor
                kw["stderr"] = err
                await super()._async_launch_kernel(kernel_cmd, **kw)

    return BatchKernelManager


def _retarget(nb: Any, stage: Path, out_dir: Path) -> Any:
    """The executed notebook with the staging folder's path replaced by the reports folder's (the injected
    ``out_dir`` parameter, any printed path)."""
    import nbformat

    text = nbformat.writes(nb)
    old, new = json.dumps(str(stage))[1:-1], json.dumps(str(out_dir))[1:-1]
    return nbformat.reads(text.replace(old, new), as_version=4) if old in text else nb


def _died_at_start(exc: BaseException) -> bool:
    """Whether the kernel died before it ran anything (jupyter_client's "Kernel died before replying to
    kernel_info"): the notebook itself is not at fault."""
    return "died before replying to kernel_info" in str(exc)


def _error_text(exc: BaseException) -> tuple[str, int | None]:
    from papermill.exceptions import PapermillExecutionError

    if isinstance(exc, PapermillExecutionError):
        evalue = str(exc.evalue).strip()
        return (f"{exc.ename}: {evalue}" if evalue else exc.ename), exc.exec_count
    text = str(exc).strip()
    # nbclient's timeout and dead-kernel messages are long; keep their first lines
    lines = [line for line in text.splitlines() if line.strip()]
    text = " ".join(lines[:3])
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__, None


_HTML_TEMPLATE = r"""
{%- extends 'lab/index.html.j2' -%}
{% block extra_css %}
{{ super() }}
<style>
  .hsmap-banner { margin: 0 0 1.2em 0; padding: 0.7em 1em; border-radius: 4px; font-family: sans-serif;
                  font-size: 14px; background: #e8f4ea; border-left: 6px solid #2e7d32; }
  .hsmap-banner.failed { background: #fdecea; border-left-color: #c62828; }
  .hsmap-banner.skipped { background: #fff8e1; border-left-color: #a66b00; }
  .hsmap-banner h2 { margin: 0 0 0.3em 0; font-size: 18px; }
  .hsmap-banner pre { white-space: pre-wrap; margin: 0.4em 0; }
  .hsmap-banner table td { padding: 0 1em 0 0; }
  details.hsmap-code > summary { cursor: pointer; color: #777; font-family: monospace; font-size: 12px;
                                 margin-left: 64px; }
  details.hsmap-code[open] > summary { margin-bottom: 0.3em; }
</style>
{% endblock extra_css %}
{#- no widgets or diagrams in our reports: do not fetch require.js and mermaid from a CDN -#}
{%- block html_head_js_requirejs -%}{%- endblock html_head_js_requirejs -%}
{%- block html_head_js_mermaidjs -%}{%- endblock html_head_js_mermaidjs -%}
{% block body_header %}
{{ super() }}
{%- set h = resources.hsmap -%}
<div class="hsmap-banner {{ h.status }}">
  <h2>{{ h.title | e }} &mdash; {% if h.status == 'ok' %}ok{% elif h.status == 'skipped' %}skipped{% else %}FAILED{% endif %}</h2>
  {% if h.status == 'skipped' %}<pre>{{ h.error | e }}</pre>
  <p>The notebook ran, but its inputs are missing: it shows nothing.</p>
  {% elif h.status != 'ok' %}<pre>{{ h.error | e }}</pre>
  <p>{% if h.error_cell %}The notebook stopped at cell [{{ h.error_cell }}]: this report is incomplete.
  {%- else %}Its results are not to be trusted.{% endif %}</p>{% endif %}
  <table>
    <tr><td>notebook</td><td>{{ h.name | e }}</td></tr>
    <tr><td>run</td><td>{{ h.started | e }}, {{ '%.1f' % h.duration_s }} s</td></tr>
    <tr><td>parameters</td><td><code>{{ h.parameters_text | e }}</code></td></tr>
    <tr><td>versions</td><td>{{ h.versions_text | e }}</td></tr>
  </table>
  <p><a href="index.html">&larr; all notebooks</a></p>
</div>
{% endblock body_header %}
{% block input_group scoped %}
{#- the cell that failed shows its code -#}
<details class="hsmap-code"{% if cell.outputs | selectattr('output_type', 'equalto', 'error') | list %} open{% endif %}><summary>code</summary>
{{ super() }}
</details>
{% endblock input_group %}
"""


def notebook_to_html(nb: Any, run: NotebookRun, versions: Mapping[str, str] | None = None) -> str:
    """HTML of an executed notebook: code folded under "code", outputs and figures inline, a status banner."""
    _lighten_jupyter_imports()
    import jinja2
    from nbconvert import HTMLExporter

    exporter = HTMLExporter(
        template_name="lab",
        extra_loaders=[jinja2.DictLoader({"hsmap_report.html.j2": _HTML_TEMPLATE})],
        template_file="hsmap_report.html.j2",
    )
    resources = {
        "hsmap": {
            "title": run.title or run.name,
            "name": run.name,
            "status": run.status,
            "error": run.error or "",
            "error_cell": run.error_cell,
            "started": run.started or "",
            "duration_s": float(run.duration_s or 0.0),
            "parameters_text": ", ".join(f"{k}={v!r}" for k, v in run.parameters.items()),
            "versions_text": ", ".join(f"{k} {v}" for k, v in (versions or {}).items()),
        },
        "metadata": {"name": run.title or run.name},
    }
    body, _ = exporter.from_notebook_node(nb, resources=resources)
    return body


def _kernel_env(name: str, jobs: int) -> dict[str, str]:
    """The environment of a notebook's kernel (hsmap's own process): BLAS on ``$HSMAP_BLAS_THREADS`` threads
    (default 1, see :mod:`hsmap._blas`) and, for parallel kernels, one share of the cores each for the other
    native thread pools; a variable the caller set is left alone."""
    from .._blas import blas_threads

    env = {NOTEBOOK_ENV: name, "RERUN_ANALYTICS": "0", "PYTHONHASHSEED": os.environ.get("PYTHONHASHSEED", "0")}
    for var in _BLAS_VARS:
        if var not in os.environ:
            env[var] = str(blas_threads())
    if jobs > 1:  # parallel kernels share the cores: one native thread pool each
        per = str(max(1, (os.cpu_count() or 1) // jobs))
        if "OMP_NUM_THREADS" not in os.environ:
            env["OMP_NUM_THREADS"] = per
    return env


@contextlib.contextmanager
def _environ(updates: Mapping[str, str]) -> Iterator[None]:
    old = {k: os.environ.get(k) for k in updates}
    os.environ.update(updates)
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _sweep_temporaries(folder: Path) -> list[str]:
    """Delete temporary files (``.name.XXXX...``) left in a notebook's folder; returns their names."""
    left = []
    if folder.is_dir():
        for p in sorted(folder.rglob(".*")):
            if p.is_file():
                left.append(str(p.relative_to(folder)))
                p.unlink()
    return left


def _open_recordings_in_viewer(run: NotebookRun, folder: Path, out_dir: Path | None = None) -> None:
    """Open each recording (``run.recordings``, relative to ``folder``: the notebook's staging folder) in the
    headless viewer (where a graphics stack allows): a view that reports an error, or that should show something
    and is empty, fails the notebook, naming the recording where it is published (under ``out_dir``). Where the
    viewer cannot run, the run says so in its warnings."""
    from ..errors import HsmapError
    from ..viz.viewer import HeadlessViewer, viewer_unavailable

    reason = viewer_unavailable()
    if reason is not None:
        run.warnings.append(f"recordings not opened in the viewer: {reason}")
        return
    try:
        viewer = HeadlessViewer()
    except HsmapError as exc:  # the viewer itself did not start: not the notebook's fault
        run.warnings.append(f"recordings not opened in the viewer: {exc}")
        return
    with viewer:
        for rel in run.recordings:
            try:
                check = viewer.screenshots(folder / rel, None, positions=("end",))
                errors = check.errors
            except Exception as exc:  # noqa: BLE001 - a recording the viewer cannot open fails the notebook
                errors = [f"{type(exc).__name__}: {exc}"]
            if out_dir is not None:
                errors = [e.replace(str(folder), str(out_dir)) for e in errors]
            if errors:
                run.status, run.error = "failed", f"recording {rel} in the viewer: {'; '.join(errors)}"
                return


def execute_notebook(
    spec: NotebookSpec,
    out_dir: str | os.PathLike,
    parameters: Mapping[str, Any],
    *,
    kernel_name: str = KERNEL_NAME,
    timeout: float | None = None,
    verify_recordings: bool = True,
    versions: Mapping[str, str] | None = None,
) -> NotebookRun:
    """Execute one notebook with papermill into ``out_dir`` and collect its outputs (see module docstring).

    The caller provides the kernel (``kernel_name`` must be findable by jupyter) and the environment
    (``$HSMAP_NOTEBOOK``); :func:`run_notebooks` does both. Never raises for a failing notebook: the returned
    run says ``failed`` with the error.
    """
    _lighten_jupyter_imports()
    _quiet_papermill_log()
    import nbformat
    import papermill

    from ..io import locked_staging_folder

    out_dir = Path(out_dir).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    run = NotebookRun(name=spec.name, notebook=str(spec.path), title=spec.title(), status="running",
                      started=_now(), parameters=dict(parameters))
    # everything is written into a locked staging folder and published when complete: an interrupted or broken
    # run leaves the previous report as it was, and a killed one leaves a folder the next batch removes
    lock_fd, stage = locked_staging_folder(out_dir, _staging_prefix(spec.name))
    folder = stage / spec.name
    tmp_ipynb = stage / f"{spec.name}.ipynb"
    kernel_log = stage / "kernel-stderr.txt"
    staged_parameters = {**parameters, "out_dir": str(stage)} if "out_dir" in parameters else dict(parameters)
    try:
        t0 = time.perf_counter()
        for attempt in (1, 2):
            try:
                papermill.execute_notebook(
                    str(spec.path), str(tmp_ipynb), parameters=staged_parameters, kernel_name=kernel_name,
                    language="python", cwd=str(spec.path.parent), progress_bar=False, log_output=False,
                    execution_timeout=timeout, kernel_manager_class=_kernel_manager_class(kernel_log),
                )
                run.status = "ok"
            except Exception as exc:  # the notebook failed (or its kernel died): record it, carry on
                if attempt == 1 and _died_at_start(exc):
                    # no cell ran: a kernel that could not start (on a busy machine, parallel kernels can race
                    # for the same ports) gets one more try
                    run.warnings.append(f"the kernel died before it started ({exc}); started again")
                    continue
                run.status = "failed"
                run.error, run.error_cell = _error_text(exc)
            break
        run.duration_s = round(time.perf_counter() - t0, 3)

        left = _sweep_temporaries(folder)
        if left:
            run.warnings.append(f"temporary files left behind and removed (an output not closed?): {left}")
        if kernel_log.is_file() and kernel_log.stat().st_size > 0:
            folder.mkdir(exist_ok=True)
            os.replace(kernel_log, folder / kernel_log.name)
            if not run.ok:
                run.warnings.append(f"the kernel wrote to stderr: {spec.name}/{kernel_log.name}")
        if folder.is_dir():
            run.figures = sorted(str(p.relative_to(stage)) for p in folder.rglob("*.png"))
            run.recordings = sorted(str(p.relative_to(stage)) for p in folder.rglob("*.rrd"))
        run.metrics = read_metrics(folder / "metrics.json")
        if run.ok and run.metrics is None:
            run.warnings.append("the notebook wrote no metrics.json (study.metrics(...))")
        if run.ok and run.metrics is not None:
            if run.metrics.get("skipped"):
                run.status, run.error = "skipped", str(run.metrics["skipped"])
            for part, why in (run.metrics.get("skipped_parts") or {}).items():
                run.warnings.append(f"skipped {part}: {why}")
        if run.recordings and verify_recordings:
            from ..viz.rerun import rerun_binary, verify_rrd

            if rerun_binary() is None:
                run.warnings.append("rerun binary not found: recordings not verified")
            else:
                for rel in run.recordings:
                    try:
                        verify_rrd(stage / rel)
                    except Exception as exc:
                        if run.ok:
                            msg = str(exc).replace(f"{stage / rel}: ", "")
                            run.status, run.error = "failed", f"recording {rel} does not verify: {msg}"
            if run.ok:
                _open_recordings_in_viewer(run, stage, out_dir)  # not published yet: in the staging folder

        # the executed notebook and its HTML, marked with the run's status
        nb = None
        if tmp_ipynb.exists() and tmp_ipynb.stat().st_size > 0:
            try:
                nb = _retarget(nbformat.read(str(tmp_ipynb), as_version=4), stage, out_dir)
            except Exception as exc:  # papermill died before writing a whole notebook
                run.warnings.append(f"executed notebook unreadable: {exc}")
        if nb is None:
            nb = nbformat.read(str(spec.path), as_version=4)
        nb.metadata["hsmap"] = {k: v for k, v in run.to_dict().items() if k != "metrics"}
        try:
            html = notebook_to_html(nb, run, versions)
        except Exception as exc:
            if run.ok:
                run.status = "failed"
                run.error = f"HTML conversion failed: {type(exc).__name__}: {exc}"
            html = (f"<html><body><h1>{run.name}: FAILED</h1><pre>{_escape(run.error or '')}</pre>"
                    f"<p>HTML conversion failed too: {_escape(str(exc))}</p></body></html>")
        nb.metadata["hsmap"]["status"] = run.status
        nb.metadata["hsmap"]["error"] = run.error
        run.ipynb, run.html = f"{spec.name}.ipynb", f"{spec.name}.html"
        try:
            with atomic_open(tmp_ipynb, "w", encoding="utf-8") as fh:
                nbformat.write(nb, fh)
            write_text(stage / f"{spec.name}.html", html)
            write_json(folder / "run.json", run.to_dict())
            _publish(stage, out_dir, spec.name)
        except OSError as exc:  # name the report where it was to appear, not its staging copy
            if not isinstance(exc, OutputError):
                exc = OutputError(f"{out_dir / spec.name}: cannot publish the report ({exc.strerror or exc})")
            raise OutputError(str(exc).replace(str(stage), str(out_dir))) from None
        return run
    finally:  # published, or interrupted (Ctrl-C) or the machinery failed: no temporary is left behind
        shutil.rmtree(stage, ignore_errors=True)
        os.close(lock_fd)


def _escape(s: str) -> str:
    import html

    return html.escape(s)


_busy = False  # a batch worker is running a notebook
_interrupted = False  # this process's batch was interrupted: the notebook machinery's last words are dropped


def _interrupt(signum=None, frame=None) -> None:
    """Mark this process's batch interrupted, then raise KeyboardInterrupt (a signal handler)."""
    global _interrupted
    _interrupted = True
    raise KeyboardInterrupt


def _on_sigterm(signum, frame) -> None:
    if _busy:
        _interrupt()  # execute_notebook shuts the kernel down and removes its staging folder
    os._exit(128 + signum)  # idle: nothing to clean up, and no traceback from the pool's queue


@contextlib.contextmanager
def _marking_interrupts():
    """Ctrl-C in a batch that runs its notebooks in this process marks the interruption before it raises, so
    that the notebook machinery's reports of the kernel it then shuts down are dropped (see
    :class:`_QuietOnceInterrupted`). Only the main thread can take signals, and only where Ctrl-C raises
    KeyboardInterrupt (Python's default) is it taken over; elsewhere this does nothing."""
    import signal

    global _interrupted
    _interrupted = False
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGINT) is not signal.default_int_handler):
        yield  # a process that handles or ignores Ctrl-C its own way keeps its way
        return

    previous = signal.signal(signal.SIGINT, _interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _worker_signals() -> None:
    """A batch worker: Ctrl-C in the terminal is the batch's to handle (the worker would print a traceback of
    its own); SIGTERM from the batch interrupts it so that it shuts its kernel down and removes its staging
    folder."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _on_sigterm)


def _stop_workers(pool: cf.ProcessPoolExecutor) -> None:
    """Cancel what has not started and interrupt the workers (SIGTERM: they clean up), then wait for them."""
    import signal

    procs = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        try:
            if p.is_alive():
                os.kill(p.pid, signal.SIGTERM)
        except (OSError, ValueError, AttributeError):
            pass
    for p in procs:
        try:
            p.join(timeout=30)
            if p.is_alive():
                p.kill()
        except (OSError, ValueError, AssertionError, AttributeError):
            pass


def _worker(spec: NotebookSpec, out_dir: str, parameters: dict[str, Any], env: dict[str, str],
            timeout: float | None, verify: bool, versions: dict[str, str]) -> dict[str, Any]:
    """Process-pool entry point: one notebook in this worker's environment."""
    global _busy
    with _environ(env):
        _busy = True
        try:
            run = execute_notebook(spec, out_dir, parameters, timeout=timeout, verify_recordings=verify,
                                   versions=versions)
        except Exception as exc:  # the machinery itself failed (disk full, ...): still a result
            run = NotebookRun(name=spec.name, notebook=str(spec.path), title=spec.title(), status="failed",
                              error=f"hsmap reproduce: {type(exc).__name__}: {exc}", started=_now(),
                              parameters=parameters)
        finally:
            _busy = False
    return run.to_dict()


# --- the batch -------------------------------------------------------------------------------------------


def write_kernelspec(root: str | os.PathLike) -> Path:
    """A jupyter kernelspec ``hsmap-python`` for the current interpreter under ``root/kernels/``.

    Its kernels run with analytics off, the inline matplotlib backend (the Makefile's ``MPLBACKEND=Agg``
    would hide inline figures) and no IPython history database (parallel kernels would contend for it).
    """
    d = Path(root) / "kernels" / KERNEL_NAME
    d.mkdir(parents=True, exist_ok=True)
    spec = {
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}",
                 "--HistoryManager.enabled=False", "--IPKernelApp.log_level=ERROR"],
        "display_name": f"hsmap (Python {platform.python_version()})",
        "language": "python",
        "env": {"RERUN_ANALYTICS": "0", "MPLBACKEND": "module://matplotlib_inline.backend_inline"},
        "metadata": {"debugger": False},
    }
    (d / "kernel.json").write_text(json.dumps(spec, indent=1), encoding="utf-8")
    return d


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
        Receives one line per finished notebook.

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
        from .parameters import check_parameters, declared_parameters

        check_parameters({s.name: declared_parameters(s) for s in chosen}, common, per_nb)
    common = _absolute_paths(common)
    per_nb = {k: _absolute_paths(v) for k, v in per_nb.items()}
    from ..io import folder_lock, prepare_output_dir, sweep_stale_temporaries

    out = prepare_output_dir(Path(out_dir).resolve(), "reports folder")
    versions = environment_info(Path(notebooks_dir).resolve())
    started = _now()
    t0 = time.perf_counter()
    me = os.getpid()

    entries: dict[str, NotebookRun] = {
        s.name: NotebookRun(name=s.name, notebook=str(s.path), title=s.title(), status="pending", pid=me)
        for s in chosen}
    index_path = out / "index.html"

    def write_index(final: bool) -> list[NotebookRun]:
        """Rewrite the index under the folder's lock, merging what other batches wrote: this batch's entries for
        the notebooks it runs, for the others the newer of the index's entry (unless its batch died) and the
        notebook's run.json."""
        from .report import render_index

        meta = {"started": started, "duration_s": time.perf_counter() - t0, "quick": quick, "jobs": jobs,
                "final": final, "versions": versions, "ran": [s.name for s in chosen]}
        with folder_lock(out):
            listed = _read_index(out)
            ordered = [entries[s.name] if s.name in entries else _latest(out, s, listed.get(s.name)) for s in specs]
            write_text(index_path, render_index([e.to_dict() for e in ordered], meta))
            write_json(out / "index.json", {**meta, "notebooks": [e.to_dict() for e in ordered]})
        return ordered

    # longest first (by the previous run's duration, else the notebook's metadata hsmap.expected_seconds) keeps
    # the parallel batch short
    def previous_duration(s: NotebookSpec) -> float:
        prev = _previous_run(out, s)
        if prev and prev.duration_s:
            return -prev.duration_s
        try:
            meta = json.loads(s.path.read_text(encoding="utf-8")).get("metadata", {})
            return -float(meta.get("hsmap", {}).get("expected_seconds", 0.0))
        except (OSError, ValueError, AttributeError):
            return 0.0

    order = sorted(chosen, key=previous_duration) if jobs > 1 else list(chosen)
    runs: dict[str, NotebookRun] = {}
    # leftovers of a killed batch (staging folders, temporaries) nobody holds any more
    sweep_stale_temporaries(out, ["index.html", "index.json", *(s.name for s in specs)])
    write_index(final=False)

    def finished(run: NotebookRun) -> None:
        runs[run.name] = entries[run.name] = run
        write_index(final=False)
        if log is not None:
            msg = f"[{len(runs)}/{len(chosen)}] {run.name}: {run.status} in {run.duration_s or 0:.1f} s"
            if run.status != "ok" and run.error:
                msg += f": {run.error}"
            for w in run.warnings:
                msg += f"\n    warning: {w}"
            log(msg)

    try:
        _run_all(order, out, common, per_nb, quick, jobs, timeout, verify_recordings, versions, entries,
                 started, finished, write_index)
    except KeyboardInterrupt:
        for s in chosen:
            if s.name not in runs:
                prev = _previous_run(out, s)
                if prev is not None:  # its previous report is still there, untouched
                    prev.warnings = [*prev.warnings, f"a rerun started {started} was interrupted; this is the "
                                                     "previous run"]
                    entries[s.name] = prev
                else:
                    entries[s.name] = NotebookRun(name=s.name, notebook=str(s.path), title=s.title(),
                                                  status="interrupted", error="the run was interrupted")
                runs[s.name] = entries[s.name]
        write_index(final=True)
        raise

    merged = write_index(final=True)
    return BatchResult(
        runs=[runs[s.name] for s in chosen],
        entries=merged,
        started=started,
        duration_s=time.perf_counter() - t0,
        quick=quick,
        versions=versions,
        index=index_path,
    )


def _absolute_paths(params: dict[str, Any]) -> dict[str, Any]:
    """``params`` with the relative paths of :data:`PATH_PARAMETERS` made absolute (from the working directory)."""
    out = dict(params)
    for k in PATH_PARAMETERS:
        v = out.get(k)
        if isinstance(v, str) and v.strip() and not Path(v).expanduser().is_absolute():
            out[k] = str(Path(v).expanduser().resolve())
    return out


def _run_all(order, out, common, per_nb, quick, jobs, timeout, verify_recordings, versions, entries, started,
             finished, write_index) -> None:
    with tempfile.TemporaryDirectory(prefix="hsmap-kernel-") as kdir:
        write_kernelspec(kdir)
        jupyter_path = os.pathsep.join([kdir] + [p for p in [os.environ.get("JUPYTER_PATH")] if p])
        base_env = {"JUPYTER_PATH": jupyter_path, "JUPYTER_PLATFORM_DIRS": "1"}
        tasks = []
        for s in order:
            params = {**common, **per_nb[s.name], "quick": bool(quick), "out_dir": str(out)}
            env = {**base_env, **_kernel_env(s.name, jobs)}
            tasks.append((s, str(out), params, env, timeout, verify_recordings, versions))
        if jobs == 1:
            with _marking_interrupts():
                for t in tasks:
                    entries[t[0].name].status = "running"
                    write_index(final=False)
                    finished(NotebookRun.from_dict(_worker(*t)))
        else:
            ctx = multiprocessing.get_context("spawn")
            pool = cf.ProcessPoolExecutor(max_workers=min(jobs, len(tasks)), mp_context=ctx,
                                          initializer=_worker_signals)
            try:
                futures = {pool.submit(_worker, *t): t for t in tasks}
                for t in tasks[: min(jobs, len(tasks))]:
                    entries[t[0].name].status = "running"
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
            except BaseException:
                _stop_workers(pool)
                raise
            pool.shutdown(wait=True)
