"""A notebook's metrics as people read them: values rounded by unit, readable labels, the headline rows of the
index, and ``metrics.json`` read back as a table."""

from __future__ import annotations

import html
import json
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: Decimals of a float in a unit where its digits beyond stop meaning anything (a millimetre, a hundredth of a
#: degree, a tenth of a square metre): the rest get 4 significant digits.
UNIT_DECIMALS = {"m": 3, "cm": 1, "mm": 1, "deg": 2, "m2": 1, "s": 1, "ms": 1}


def format_value(v: Any, unit: str | None = None) -> str:
    """A short human reading of a metric value: a float in a unit of :data:`UNIT_DECIMALS` to those decimals
    (one that rounds to 0 but is not three decades below that, with 2 significant digits), others to 4
    significant digits; ``-`` for missing."""
    if isinstance(v, float) and math.isfinite(v) and unit in UNIT_DECIMALS and abs(v) < 1e7:
        k = UNIT_DECIMALS[unit]
        if round(v, k) == 0 and abs(v) >= 10.0 ** -(k + 3):
            return f"{v:.2g}"
        return f"{round(v, k) + 0.0:.{k}f}"
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            return str(v)
        if v != 0 and (abs(v) >= 1e5 or abs(v) < 1e-3):
            return f"{v:.3e}"
        return f"{v:.4g}"
    if hasattr(v, "item") and getattr(v, "ndim", 1) == 0:  # numpy scalar
        return format_value(v.item(), unit)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(format_value(x, unit) for x in v) + "]"
    return str(v)


@dataclass(frozen=True)
class HeadlineRow:
    """One number of a metrics document as the index shows it.

    Attributes
    ----------
    key : str
    label : str
        What it is, for a reader (the document's ``labels``, else the key made readable).
    ours, paper, reference : object
        Our value, the paper's, another published one (None where there is none).
    source : str
        Who published ``reference``.
    unit : str
    """

    key: str
    label: str
    ours: Any
    paper: Any
    reference: Any
    source: str
    unit: str


_UNIT_SUFFIXES = ("_m", "_deg", "_s", "_ms", "_m2")


def readable_label(key: str) -> str:
    """A key as words: ``hsslam_final_error_m`` -> ``HS-SLAM final error`` (the unit goes in its own column)."""
    k = key
    for suffix in _UNIT_SUFFIXES:
        if k.endswith(suffix) and len(k) > len(suffix):
            k = k[: -len(suffix)]
            break
    words = []
    for w in k.split("_"):
        words.append({"hsslam": "HS-SLAM", "hs3": "HS-SLAM 3-DOF", "hs6": "HS-SLAM 6-DOF", "p95": "95th percentile",
                      "seg": "segmentation", "rot": "rotation", "trans": "translation"}.get(w, w))
    return " ".join(words)


def headline_rows(doc: Mapping[str, Any], limit: int = 8) -> list[HeadlineRow]:
    """The numbers a metrics document puts forward (see module docstring).

    Keys named in ``headline`` come first; without one, the keys the paper has, then (when the paper has
    none) the first scalar metrics, up to ``limit`` rows.
    """
    metrics = doc.get("metrics") or {}
    paper = doc.get("paper") or {}
    reference = doc.get("reference") or {}
    units = doc.get("units") or {}
    labels = doc.get("labels") or {}
    keys = list(doc.get("headline") or [])
    if not keys:
        keys = [k for k in paper]
        if not keys:
            keys = [k for k, v in metrics.items() if not isinstance(v, (Mapping, list))]
    rows = []
    for k in keys[:limit]:
        ref = reference.get(k) or {}
        rows.append(HeadlineRow(k, labels.get(k) or readable_label(k), metrics.get(k), paper.get(k),
                                ref.get("value"), str(ref.get("source") or ""), units.get(k, "")))
    return rows


def read_metrics(path: str | os.PathLike) -> dict[str, Any] | None:
    """The metrics document at ``path``, or None when there is none (or it is not a JSON object)."""
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) else None


class MetricsTable:
    """Our numbers beside the paper's (and other published ones); shows as a table in a notebook
    (``_repr_html_``) and as text."""

    def __init__(self, doc: Mapping[str, Any]):
        self.doc = dict(doc)

    def rows(self) -> list[HeadlineRow]:
        """Every key of the document: ours first, then those only the paper or a reference has."""
        keys = list(dict.fromkeys([*(self.doc.get("metrics") or {}), *(self.doc.get("paper") or {}),
                                   *(self.doc.get("reference") or {})]))
        return headline_rows({**self.doc, "headline": keys}, limit=len(keys))

    def _columns(self) -> tuple[list[str], list[list[str]]]:
        rows = self.rows()
        has_ref = any(r.reference is not None for r in rows)
        head = ["metric", "ours", "paper"] + (["reference"] if has_ref else []) + ["unit"]
        body = []
        for r in rows:
            ref = [f"{format_value(r.reference, r.unit)} ({r.source})" if r.reference is not None else "-"] if has_ref else []
            body.append([r.key, format_value(r.ours, r.unit), format_value(r.paper, r.unit), *ref, r.unit])
        return head, body

    def __repr__(self) -> str:
        head, body = self._columns()
        table = [head, *body]
        w = [max(len(str(r[i])) for r in table) for i in range(len(head))]
        return "\n".join("  ".join(str(c).ljust(w[i]) for i, c in enumerate(r)).rstrip() for r in table)

    def _repr_html_(self) -> str:
        head, body = self._columns()
        th = "".join(f"<th>{html.escape(h)}</th>" for h in head)
        trs = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in body)
        return f"<table class='hsmap-metrics'><tr>{th}</tr>{trs}</table>"
