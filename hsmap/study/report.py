"""What a study notebook writes (its :class:`NotebookReport`), and the HTML index of a batch run.

A notebook (see ``notebooks/README.md``) makes one :class:`NotebookReport` and writes everything through it,
into its own folder ``out_dir/NAME/``::

    report = NotebookReport(out_dir, "01-odometry-vs-slam")
    report.savefig(fig, "maps")                       # NAME/maps.png (and shown inline)
    report.metrics({"ate_m": 0.021}, paper={"ate_m": 0.03}, units={"ate_m": "m"},
                   labels={"ate_m": "ATE of HS-SLAM"})  # NAME/metrics.json
    with report.recording("slam") as rec:             # NAME/slam.rrd (a rerun recording)
        ...

A study notebook names itself (its file stem), so that it runs the same under ``hsmap reproduce``, plain
papermill, ``jupyter nbconvert --execute`` and JupyterLab. ``hsmap reproduce`` (:mod:`hsmap.study.batch`) also
sets ``$HSMAP_NOTEBOOK`` to the name it runs the notebook as; when both are there they must agree. An empty
``out_dir`` is the default reports folder (:func:`hsmap.study.paths.reports_dir`). Every file is written
atomically.

A notebook whose inputs are missing (notebook 08 without the public benchmarks) calls :meth:`NotebookReport.skip`:
``metrics.json`` then says ``skipped`` with the reason, and the batch marks the notebook "skipped", not "ok".

``metrics.json`` holds one JSON object::

    {"notebook": NAME, "metrics": {key: value}, "paper": {key: value},
     "reference": {key: {"value": v, "source": "who published it"}}, "headline": [key, ...],
     "units": {key: unit}, "labels": {key: "what it is"}, "notes": "...",
     "skipped": "why the whole notebook did not run" (only then), "skipped_parts": {part: "why"} (only then)}

``paper`` holds the paper's own numbers; ``reference`` other published numbers, each with its source (the
paper has no result on the public benchmarks). ``headline`` lists the keys the index shows, ours beside the
paper's or the reference's, under their label and unit; by default the keys the paper has.
"""

from __future__ import annotations

import html
import json
import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from ..errors import ConfigError, InputError
from ..io import atomic_path, to_plain, write_json
from .metrics_tables import (
    UNIT_DECIMALS,
    HeadlineRow,
    MetricsTable,
    format_value,
    headline_rows,
    read_metrics,
    readable_label,
)

__all__ = [
    "NotebookReport",
    "HeadlineRow",
    "MetricsTable",
    "NOTEBOOK_ENV",
    "format_value",
    "headline_rows",
    "read_metrics",
    "render_index",
    "format_duration",
    "readable_label",
    "UNIT_DECIMALS",
]

#: Environment variable through which ``hsmap reproduce`` tells a notebook its name.
NOTEBOOK_ENV = "HSMAP_NOTEBOOK"

_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


def _check_name(name: str, what: str) -> str:
    if not isinstance(name, str) or not _NAME_RE.match(name) or name.endswith((".png", ".rrd", ".json")):
        raise InputError(
            f"{what} must be a plain file stem (letters, digits, '-', '_', '.'; no folder, no extension), "
            f"got {name!r}"
        )
    return name


def _in_ipython() -> bool:
    try:
        from IPython import get_ipython
    except ImportError:  # pragma: no cover - IPython is a dependency through ipykernel
        return False
    ip = get_ipython()
    return ip is not None and getattr(ip, "kernel", None) is not None


def _quiet_open3d() -> None:
    """Import Open3D (where installed and not yet imported) with its stdout swallowed: in a kernel it prints a
    banner about its web visualiser into whichever cell first imports it."""
    import contextlib
    import io
    import sys

    if "open3d" in sys.modules:
        return
    with contextlib.redirect_stdout(io.StringIO()):
        try:
            import open3d  # noqa: F401
        except ImportError:
            pass


def _notebook_file_stem() -> str | None:
    """The running notebook's file stem where the front end tells it (VS Code)."""
    try:
        from IPython import get_ipython
    except ImportError:  # pragma: no cover
        return None
    ip = get_ipython()
    vsc = getattr(ip, "user_ns", {}).get("__vsc_ipynb_file__") if ip is not None else None
    return Path(vsc).stem if isinstance(vsc, str) and vsc.endswith(".ipynb") else None


class NotebookReport:
    """Where one study notebook writes its figures, metrics and recordings: ``out_dir/NAME/``.

    Parameters
    ----------
    out_dir : str or path-like
        The reports folder (the notebook's ``out_dir`` parameter); empty or None: the default reports folder
        (:func:`hsmap.study.paths.reports_dir`: a checkout's ``reports/``, else ``./reports``).
    name : str, optional
        The notebook's name, its file stem (``"01-odometry-vs-slam"``). Study notebooks pass it, so that they
        run anywhere (plain papermill and nbconvert tell a kernel nothing about its notebook). Left out, it comes
        from ``$HSMAP_NOTEBOOK`` (set by ``hsmap reproduce``) or from the front end (a Jupyter server, VS
        Code). When given while ``$HSMAP_NOTEBOOK`` is set, the two must agree (a renamed notebook that kept
        its old name would otherwise write where nobody looks).

    Attributes
    ----------
    name : str
    dir : pathlib.Path
        ``out_dir/name``, created.
    """

    def __init__(self, out_dir: str | os.PathLike | None = None, name: str | None = None):
        env = os.environ.get(NOTEBOOK_ENV) or None
        if name is None:
            name = env or _notebook_file_stem()
            if name is None:
                raise ConfigError(
                    "NotebookReport cannot tell the notebook's name here: pass it, "
                    "NotebookReport(out_dir, 'NN-name') with the notebook's file stem"
                )
        _check_name(name, "NotebookReport name")
        if env is not None and env != name:
            raise ConfigError(
                f"this notebook calls itself {name!r} but 'hsmap reproduce' runs it as {env!r}: "
                "make the name in NotebookReport(...) match the file name"
            )
        self.name = name
        if _in_ipython():
            _quiet_open3d()
        if out_dir is None or str(out_dir) == "":
            from .paths import reports_dir

            out_dir = reports_dir()
        self.out_dir = Path(out_dir)
        self.dir = self.out_dir / name
        self.dir.mkdir(parents=True, exist_ok=True)
        self._doc: dict[str, Any] = {"notebook": name, "metrics": {}, "paper": {}, "reference": {}, "headline": [],
                                     "units": {}, "labels": {}}
        self._recordings: list[Any] = []
        self.figures: list[Path] = []

    def __repr__(self) -> str:
        return f"NotebookReport({self.name!r}, dir={str(self.dir)!r})"

    def path(self, filename: str) -> Path:
        """A path inside the notebook's folder (for files the notebook writes itself, atomically)."""
        p = Path(filename)
        if p.is_absolute() or ".." in p.parts:
            raise InputError(f"filename must be relative to the notebook's folder, got {filename!r}")
        out = self.dir / p
        out.parent.mkdir(parents=True, exist_ok=True)
        return out

    # --- figures -----------------------------------------------------------------------------------
    def savefig(self, fig: Any, name: str, *, dpi: int = 120, show: bool = True, close: bool = True) -> None:
        """Save a matplotlib figure as ``NAME/name.png`` (atomically) and show it inline.

        Returns nothing (so that a cell ending with it shows only the figure); the path is
        ``study.dir / f"{name}.png"``, also listed in :attr:`figures`.

        Parameters
        ----------
        fig : matplotlib.figure.Figure
        name : str
            File stem of the PNG.
        dpi : int
        show : bool
            Display the saved PNG in the notebook (the exact file, so the report shows what was saved).
        close : bool
            Close the figure in pyplot, so that the inline backend does not show it a second time.
        """
        _check_name(name, "figure name")
        if not hasattr(fig, "savefig"):
            raise InputError(f"savefig expects a matplotlib Figure, got {type(fig).__name__}")
        path = self.dir / f"{name}.png"
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format="png", dpi=dpi, bbox_inches="tight")
        if path not in self.figures:
            self.figures.append(path)
        if close:
            import sys

            if "matplotlib.pyplot" in sys.modules:
                sys.modules["matplotlib.pyplot"].close(fig)
        if show and _in_ipython():
            from IPython.display import Image, display

            display(Image(filename=str(path)))

    # --- metrics -----------------------------------------------------------------------------------
    def metrics(
        self,
        values: Mapping[str, Any] | None = None,
        paper: Mapping[str, Any] | None = None,
        *,
        reference: Mapping[str, Mapping[str, Any]] | None = None,
        headline: Sequence[str] | None = None,
        units: Mapping[str, str] | None = None,
        labels: Mapping[str, str] | None = None,
        notes: str | None = None,
    ) -> MetricsTable:
        """Record metrics (ours, the paper's and other published ones for the same keys) into
        ``NAME/metrics.json``.

        Calls accumulate: later values update earlier ones key by key, and the file is rewritten each time.

        Parameters
        ----------
        values : mapping of str to JSON-able value
            Our numbers. Scalars are shown in the index; nested values (per-map tables) are kept in the file.
        paper : mapping of str to value, optional
            The paper's number for the same key, where the paper gives one.
        reference : mapping of str to mapping, optional
            Another published number for the same key, ``{"value": v, "source": "who"}``, where the paper has
            none (the public benchmarks).
        headline : sequence of str, optional
            Keys the index shows (default: the keys the paper has).
        units : mapping of str to str, optional
        labels : mapping of str to str, optional
            What a key is, in words (the index shows the label, not the key).
        notes : str, optional
            One line for the reader (e.g. "quick run: 40 scans").

        Returns
        -------
        MetricsTable
            Displays as ours-beside-paper table when it is a cell's last expression.
        """
        for what, m in (("values", values), ("paper", paper), ("reference", reference), ("units", units),
                        ("labels", labels)):
            if m is not None and not isinstance(m, Mapping):
                raise InputError(f"metrics {what} must be a mapping of name to value, got {type(m).__name__}")
        for k, ref in (reference or {}).items():
            if not isinstance(ref, Mapping) or "value" not in ref or not ref.get("source"):
                raise InputError(f"metrics reference {k!r} must be a mapping with 'value' and 'source', got {ref!r}")
        self._doc["metrics"].update(to_plain(dict(values or {})))
        self._doc["paper"].update(to_plain(dict(paper or {})))
        self._doc["reference"].update(to_plain(dict(reference or {})))
        self._doc["units"].update({str(k): str(v) for k, v in (units or {}).items()})
        self._doc["labels"].update({str(k): str(v) for k, v in (labels or {}).items()})
        if headline is not None:
            if isinstance(headline, str):
                headline = [headline]
            known = (self._doc["metrics"], self._doc["paper"], self._doc["reference"])
            missing = [k for k in headline if not any(k in m for m in known)]
            if missing:
                raise InputError(f"headline key(s) {missing} are neither among the metrics nor the references")
            self._doc["headline"] = list(headline)
        if notes is not None:
            self._doc["notes"] = str(notes)
        try:
            json.dumps(self._doc, allow_nan=True)
        except TypeError as exc:
            raise InputError(f"metrics must be JSON-serialisable (numbers, strings, lists, dicts): {exc}") from None
        write_json(self.dir / "metrics.json", self._doc)
        return MetricsTable(self._doc)

    def skip(self, reason: str, part: str | None = None) -> None:
        """Say that the notebook (or one ``part`` of it) did not run for want of its inputs.

        Recorded in ``metrics.json`` (``skipped``, or ``skipped_parts[part]``) and printed. ``hsmap reproduce``
        marks a skipped notebook "skipped: REASON" in its index instead of "ok", and a skipped part as a
        warning. Call it before the notebook's :meth:`metrics` calls or after: the document keeps both.

        Parameters
        ----------
        reason : str
            One line: what is missing and how to get it (e.g. "no data (run hsmap data fetch)").
        part : str, optional
            The part that did not run (e.g. "Freiburg relations"); None: the whole notebook.
        """
        if not isinstance(reason, str) or not reason.strip():
            raise InputError("skip needs a reason: what is missing and how to get it")
        reason = " ".join(reason.split())
        if part is None:
            self._doc["skipped"] = reason
            print(f"SKIPPED: {reason}")
        else:
            self._doc.setdefault("skipped_parts", {})[str(part)] = reason
            print(f"SKIPPED {part}: {reason}")
        write_json(self.dir / "metrics.json", self._doc)

    @property
    def metrics_doc(self) -> dict[str, Any]:
        """The metrics document as written so far."""
        return json.loads(json.dumps(self._doc))

    # --- rerun -------------------------------------------------------------------------------------
    def recording(self, name: str, *, blueprint: Any = None, application_id: str | None = None) -> Any:
        """A rerun recording saved to ``NAME/name.rrd`` (file sink only: no viewer, no network).

        Use it as a context manager, or call ``.close()``: the .rrd appears (renamed from a temporary
        file) when the recording is closed; :meth:`close` closes every recording still open.

        Returns
        -------
        hsmap.viz.rerun.Recording
        """
        from ..viz.rerun import Recording, default_blueprint

        _check_name(name, "recording name")
        rec = Recording(
            self.dir / f"{name}.rrd",
            application_id=application_id or f"hsmap_{self.name}",
            blueprint=default_blueprint() if blueprint is None else blueprint,
        )
        self._recordings.append(rec)
        return rec

    def close(self) -> list[Path]:
        """Close the recordings still open; returns the paths of every recording this study made."""
        for rec in self._recordings:
            rec.close()
        return [r.path for r in self._recordings]


# --- the index of a batch run --------------------------------------------------------------------------

PAPER = ("Multi-LiDAR Mapping for Scene Segmentation in Indoor Environments for Mobile Robots "
         "(Sensors 2022)")

_INDEX_CSS = """
body { font-family: -apple-system, 'Segoe UI', Helvetica, Arial, sans-serif; margin: 2em auto; max-width: 1400px;
       color: #222; padding: 0 1em; }
h1 { margin-bottom: 0.2em; } .paper { color: #555; margin-top: 0; }
.summary { padding: 0.6em 1em; border-radius: 4px; margin: 1em 0; border-left: 6px solid #2e7d32;
           background: #e8f4ea; }
.summary.failed { border-left-color: #c62828; background: #fdecea; }
.summary.running { border-left-color: #f9a825; background: #fff8e1; }
table.notebooks { border-collapse: collapse; width: 100%; }
table.notebooks > thead > tr > th { text-align: left; border-bottom: 2px solid #999; padding: 0.4em; }
table.notebooks > tbody > tr > td { vertical-align: top; border-bottom: 1px solid #ddd; padding: 0.5em 0.4em; }
.status { font-weight: bold; white-space: nowrap; }
.status.ok { color: #2e7d32; } .status.failed, .status.interrupted { color: #c62828; }
.status.pending, .status.running, .status.notrun { color: #888; }
.status.skipped { color: #a66b00; } .skip { color: #a66b00; font-size: 12px; max-width: 30em; }
pre.error { white-space: pre-wrap; color: #c62828; font-size: 12px; max-width: 30em; margin: 0.3em 0; }
.warn { color: #a66b00; font-size: 12px; }
.earlier { color: #888; font-size: 12px; }
table.headline { border-collapse: collapse; font-size: 13px; }
table.headline th { font-weight: normal; color: #666; text-align: left; padding: 0 0.8em 0 0; }
table.headline td { padding: 0 0.8em 0 0; font-variant-numeric: tabular-nums; }
table.headline td.label { color: #333; max-width: 22em; }
.source { color: #888; font-size: 11px; }
.thumbs img { height: 64px; border: 1px solid #ccc; margin: 2px; }
.small { font-size: 12px; color: #666; }
table.env td { padding: 0 1.5em 0 0; font-size: 13px; }
"""


def format_duration(seconds: float | None) -> str:
    """``8.2 s``, ``3 min 05 s``, ``1 h 02 min``."""
    if seconds is None:
        return "-"
    s = float(seconds)
    if s < 60:
        return f"{s:.1f} s"
    if s < 3600:
        return f"{int(s // 60)} min {int(s % 60):02d} s"
    return f"{int(s // 3600)} h {int(s % 3600 // 60):02d} min"


def _headline_html(metrics: Mapping[str, Any] | None, notes: str | None = None) -> str:
    if not metrics:
        return "<span class='small'>no metrics</span>"
    rows = headline_rows(metrics)
    if not rows:
        return "<span class='small'>no headline numbers</span>"
    has_paper = any(r.paper is not None for r in rows)
    has_ref = any(r.reference is not None for r in rows)
    head = ("<tr><th></th><th>ours</th>" + ("<th>paper</th>" if has_paper else "")
            + ("<th>reference</th>" if has_ref else "") + "</tr>")
    body = ""
    for r in rows:
        unit = f" {html.escape(r.unit)}" if r.unit else ""
        cells = f"<td class='label' title='{html.escape(r.key)}'>{html.escape(r.label)}</td>"
        cells += f"<td>{html.escape(format_value(r.ours, r.unit))}{unit}</td>"
        if has_paper:
            cells += f"<td>{html.escape(format_value(r.paper, r.unit))}{unit if r.paper is not None else ''}</td>"
        if has_ref:
            src = f" <span class='source'>{html.escape(r.source)}</span>" if r.reference is not None else ""
            cells += (f"<td>{html.escape(format_value(r.reference, r.unit))}"
                      f"{unit if r.reference is not None else ''}{src}</td>")
        body += f"<tr>{cells}</tr>"
    note = f"<div class='small'>{html.escape(notes)}</div>" if notes else ""
    return f"<table class='headline'>{head}{body}</table>{note}"


def _summary_html(entries: Sequence[Mapping[str, Any]], meta: Mapping[str, Any], ran: set[str]) -> str:
    """The index's summary box: the run's state (in progress, failed, complete), start, duration, mode, jobs."""
    esc = html.escape
    final = bool(meta.get("final"))
    this_run = [e for e in entries if e.get("name") in ran]
    n_ok = sum(e.get("status") == "ok" for e in this_run)
    n_skipped = sum(e.get("status") == "skipped" for e in this_run)
    done = ("failed", "interrupted") if not final else None
    n_failed = sum((e.get("status") in done) if done else (e.get("status") not in ("ok", "skipped"))
                   for e in this_run)
    mode = "quick" if meta.get("quick") else "full"
    skipped = f", {n_skipped} skipped" if n_skipped else ""
    if not final:
        cls, state = "running", f"in progress: {n_ok + n_skipped + n_failed} of {len(this_run)} notebooks done"
    elif n_failed:
        cls, state = "failed", f"FAILED: {n_failed} of {len(this_run)} notebooks failed, {n_ok} ok{skipped}"
    elif n_skipped:
        cls, state = "ok", f"complete: {n_ok} of {len(this_run)} notebooks ok{skipped} (inputs missing)"
    else:
        cls, state = "ok", f"complete: all {len(this_run)} notebooks ok"
    return (f"<div class='summary {cls}'><b>{esc(state)}</b><br>"
            f"run started {esc(str(meta.get('started', '-')))}; "
            f"{'total duration' if final else 'elapsed'} {esc(format_duration(meta.get('duration_s')))}; "
            f"{mode} run; {int(meta.get('jobs', 1))} job(s) at a time</div>")


def _notebook_row(e: Mapping[str, Any], ran: set[str]) -> str:
    """One notebook's row of the index: link, status (with its error, skip reason, warnings), headline numbers,
    duration, start and outputs."""
    esc = html.escape
    name = str(e.get("name", ""))
    status = str(e.get("status", "not run"))
    title = esc(str(e.get("title") or name))
    link = (f"<a href='{esc(str(e['html']))}'>{title}</a>" if e.get("html") else title)
    st_cls = status.replace(" ", "")
    st = f"<span class='status {st_cls}'>{esc('FAILED' if status == 'failed' else status)}</span>"
    if status in ("failed", "interrupted") and e.get("error"):
        err = str(e["error"])
        err = err if len(err) <= 1500 else err[:1500] + " ..."
        cell = f" at cell [{e['error_cell']}]" if e.get("error_cell") else ""
        st += f"<pre class='error'>{esc(err)}{esc(cell)}</pre>"
    if status == "skipped" and e.get("error"):
        st += f"<div class='skip'>{esc(str(e['error']))}</div>"
    for w in e.get("warnings") or []:
        st += f"<div class='warn'>warning: {esc(str(w))}</div>"
    if name not in ran and status not in ("not run",):
        st += "<div class='earlier'>(from an earlier run)</div>"
    metrics = e.get("metrics")
    headline = _headline_html(metrics, (metrics or {}).get("notes")) if status != "not run" else ""
    outs = []
    if e.get("ipynb"):
        outs.append(f"<a href='{esc(str(e['ipynb']))}'>notebook</a>")
    if metrics is not None:
        outs.append(f"<a href='{esc(name)}/metrics.json'>metrics.json</a>")
    recs = e.get("recordings") or []
    if recs:
        outs.append("recordings: " + ", ".join(f"<a href='{esc(r)}'>{esc(Path(r).name)}</a>" for r in recs))
    figs = e.get("figures") or []
    thumbs = "".join(f"<a href='{esc(f)}' title='{esc(Path(f).stem)}'><img src='{esc(f)}' alt='{esc(Path(f).stem)}'></a>"
                     for f in figs)
    outputs = " | ".join(outs) + (f"<div class='thumbs'>{thumbs}</div>" if thumbs else "")
    started = str(e.get("started") or "-")
    return (
        f"<tr id='{esc(name)}'><td>{link}<div class='small'>{esc(name)}</div></td><td>{st}</td>"
        f"<td>{headline}</td><td>{esc(format_duration(e.get('duration_s')))}</td>"
        f"<td class='small'>{esc(started.replace('T', ' '))}</td><td>{outputs}</td></tr>"
    )


def render_index(entries: Sequence[Mapping[str, Any]], meta: Mapping[str, Any]) -> str:
    """The HTML index of a batch run.

    Parameters
    ----------
    entries : sequence of mappings
        One per notebook, the fields of :class:`hsmap.study.batch.NotebookRun`.
    meta : mapping
        ``started`` (ISO date), ``duration_s``, ``quick``, ``jobs``, ``final`` (False while running),
        ``versions`` (name -> version), ``ran`` (names run now).
    """
    ran = set(meta.get("ran") or [])
    final = bool(meta.get("final"))
    summary = _summary_html(entries, meta, ran)
    rows = [_notebook_row(e, ran) for e in entries]
    esc = html.escape
    versions = meta.get("versions") or {}
    env_rows = "".join(f"<tr><td>{esc(str(k))}</td><td>{esc(str(v))}</td></tr>" for k, v in versions.items())
    refresh = "" if final else "<meta http-equiv='refresh' content='10'>"
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">{refresh}<title>hsmap study</title>
<style>{_INDEX_CSS}</style></head>
<body>
<h1>hsmap study</h1>
<p class="paper">Each notebook reproduces a figure or table of <i>{esc(PAPER)}</i> with hsmap;
our numbers stand beside the paper's.</p>
{summary}
<table class="notebooks">
<thead><tr><th>notebook</th><th>status</th><th>headline numbers</th><th>duration</th><th>run</th><th>outputs</th></tr></thead>
<tbody>
{chr(10).join(rows)}
</tbody></table>
<h2>Environment</h2>
<table class="env">{env_rows}</table>
<p class="small">Recordings (.rrd) open in the rerun viewer: <code>.venv/bin/rerun reports/NAME/FILE.rrd</code>.
Reports are regenerated by <code>make reproduce</code> (or <code>hsmap reproduce [--quick] [--only NAME]</code>).</p>
</body></html>
"""
