"""An executed notebook as one HTML page: code cells folded, figures inline, a banner with the run's status."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from .notebook_run import NotebookRun
from .tooling import lighten_jupyter_imports

__all__ = ["notebook_to_html"]

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
    lighten_jupyter_imports()
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
