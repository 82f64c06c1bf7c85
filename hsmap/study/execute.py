"""One notebook executed by papermill in a fresh kernel into a hidden staging folder of the reports folder,
its report published as a whole once complete (:func:`execute_notebook`); the kernelspec and the study tooling."""

from __future__ import annotations

import contextlib
import json
import os
import platform
import shutil
import sys
import time
from collections.abc import Iterator, Mapping
from html import escape
from pathlib import Path
from typing import Any

from .._blas import blas_threads
from ..errors import HsmapError, OutputError
from ..io import STAGING_PREFIX, atomic_open, folder_lock, locked_staging_folder, write_json, write_text
from .discovery import NotebookSpec
from .interrupts import quiet_papermill_log
from .notebook_html import notebook_to_html
from .notebook_run import NotebookRun, now_text
from .report import NOTEBOOK_ENV, read_metrics
from .tooling import lighten_jupyter_imports

__all__ = ["KERNEL_NAME", "NotebookRun", "execute_notebook", "write_kernelspec"]

KERNEL_NAME = "hsmap-python"
_BLAS_VARS = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def _staging_prefix(name: str) -> str:
    """Prefix of the hidden staging folders of notebook ``name`` in the reports folder."""

    return f"{STAGING_PREFIX}{name}-"


def cell_progress(out_dir: str | os.PathLike, name: str) -> tuple[int, int] | None:
    """How far notebook ``name`` running into ``out_dir`` is: (code cells finished, code cells), read from the
    executed notebook papermill saves into its staging folder at each cell's start and end; None before the first
    save or while a save is half written."""
    def mtime(p: Path) -> float:
        try:
            return p.stat().st_mtime
        except OSError:
            return 0.0

    candidates = sorted(Path(out_dir).glob(f"{_staging_prefix(name)}*/{name}.ipynb"), key=mtime)
    if not candidates:
        return None
    try:
        nb = json.loads(candidates[-1].read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    code = [c for c in nb.get("cells", []) if isinstance(c, dict) and c.get("cell_type") == "code"]
    done = sum(1 for c in code if (c.get("metadata", {}).get("papermill") or {}).get("status") == "completed")
    return done, len(code)


def _publish(stage: Path, out_dir: Path, name: str) -> None:
    """Replace the notebook's report in ``out_dir`` (``NAME/``, ``NAME.ipynb``, ``NAME.html``) by the complete
    one in ``stage``, under the reports folder's lock (a concurrent batch publishing the same notebook waits).

    The previous folder is moved aside (into ``stage``, deleted with it) and the new one renamed into place; the
    two files are replaced by renames. Nothing of the old run survives beside the new one.
    """

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


def kernel_env(name: str, jobs: int) -> dict[str, str]:
    """The environment of a notebook's kernel (hsmap's own process): BLAS on ``$HSMAP_BLAS_THREADS`` threads
    (default 1, see :mod:`hsmap._blas`) and, for parallel kernels, one share of the cores each for the other
    native thread pools; a variable the caller set is left alone."""

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
def environ(updates: Mapping[str, str]) -> Iterator[None]:
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
    lighten_jupyter_imports()
    quiet_papermill_log()
    import nbformat  # noqa: F401 - here: a missing one fails before the staging folder is made
    import papermill  # noqa: F401

    out_dir = Path(out_dir).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    run = NotebookRun(name=spec.name, notebook=str(spec.path), title=spec.title(), status="running",
                      started=now_text(), parameters=dict(parameters))
    # everything is written into a locked staging folder and published when complete: an interrupted or broken
    # run leaves the previous report as it was, and a killed one leaves a folder the next batch removes
    lock_fd, stage = locked_staging_folder(out_dir, _staging_prefix(spec.name))
    folder = stage / spec.name
    tmp_ipynb = stage / f"{spec.name}.ipynb"
    kernel_log = stage / "kernel-stderr.txt"
    staged_parameters = {**parameters, "out_dir": str(stage)} if "out_dir" in parameters else dict(parameters)
    try:
        t0 = time.perf_counter()
        _papermill(run, spec, tmp_ipynb, staged_parameters, kernel_name, timeout, kernel_log)
        run.duration_s = round(time.perf_counter() - t0, 3)
        _collect_outputs(run, folder, stage, kernel_log)
        if run.recordings and verify_recordings:
            _verify_recordings(run, stage, out_dir)
        _write_report(run, spec, stage, out_dir, versions)
        return run
    finally:  # published, or interrupted (Ctrl-C) or the machinery failed: no temporary is left behind
        shutil.rmtree(stage, ignore_errors=True)
        os.close(lock_fd)


def _papermill(run: NotebookRun, spec: NotebookSpec, tmp_ipynb: Path, parameters: Mapping[str, Any],
               kernel_name: str, timeout: float | None, kernel_log: Path) -> None:
    """Execute the notebook with papermill into ``tmp_ipynb`` (the kernel's stderr into ``kernel_log``): ``run``
    says ``ok``, or ``failed`` with the error; a kernel that died before any cell ran is started once more."""
    import papermill

    for attempt in (1, 2):
        try:
            papermill.execute_notebook(
                str(spec.path), str(tmp_ipynb), parameters=parameters, kernel_name=kernel_name,
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


def _collect_outputs(run: NotebookRun, folder: Path, stage: Path, kernel_log: Path) -> None:
    """What the notebook left in ``folder`` (in the staging folder ``stage``) into ``run``: its figures,
    recordings and metrics (a skipped notebook, its skipped parts), the kernel's stderr, warnings for temporary
    files left behind."""
    left = _sweep_temporaries(folder)
    if left:
        run.warnings.append(f"temporary files left behind and removed (an output not closed?): {left}")
    if kernel_log.is_file() and kernel_log.stat().st_size > 0:
        folder.mkdir(exist_ok=True)
        os.replace(kernel_log, folder / kernel_log.name)
        if not run.ok:
            run.warnings.append(f"the kernel wrote to stderr: {run.name}/{kernel_log.name}")
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


def _verify_recordings(run: NotebookRun, stage: Path, out_dir: Path) -> None:
    """Check the run's recordings (in ``stage``, to be published into ``out_dir``) with rerun's verifier (where
    its binary is found) and open them in its viewer: the run fails on the first that does not verify or open."""
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


def _write_report(run: NotebookRun, spec: NotebookSpec, stage: Path, out_dir: Path,
                  versions: Mapping[str, str] | None) -> None:
    """The executed notebook and its HTML, marked with the run's status, and ``run.json``, published from
    ``stage`` into ``out_dir``."""
    import nbformat

    tmp_ipynb, folder = stage / f"{spec.name}.ipynb", stage / spec.name
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
        html = (f"<html><body><h1>{run.name}: FAILED</h1><pre>{escape(run.error or '')}</pre>"
                f"<p>HTML conversion failed too: {escape(str(exc))}</p></body></html>")
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
