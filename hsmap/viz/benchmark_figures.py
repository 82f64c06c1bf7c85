"""Figures of the public benchmarks (notebook 08): our relations errors on the Freiburg logs beside the
published methods, and our per-map room-segmentation scores beside Bormann et al.'s methods.

Inputs are the plain rows of :mod:`hsmap.study.benchmarks` and the published numbers of ``hsmap/study/published.yaml``
(:func:`hsmap.study.benchmarks.published_references`); drawn with the object API, like :mod:`hsmap.viz.figures`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from ..errors import InputError
from .figures import new_figure

__all__ = ["relations_figure", "relations_dt_figure", "precision_recall_figure"]


def relations_figure(rows: Sequence[Mapping[str, Any]], published: Sequence[Mapping[str, Any]], *,
                     note: str | None = None) -> Figure:
    """One panel per log: the mean translational relations error of each of our methods (HS-SLAM blue, raw
    odometry red) and of each published method (grey), on a log scale.

    Parameters
    ----------
    rows : sequence of mapping
        :attr:`hsmap.study.benchmarks.FreiburgResults.rows` (``log``, ``method``, ``mode``, ``translation_m``).
    published : sequence of mapping
        ``freiburg_relations.methods`` of the published numbers (``log``, ``method``, ``source``,
        ``translation_m``).
    note : str, optional
        A second title line (e.g. that a quick run scored only the first scans).
    """
    logs = list(dict.fromkeys(r["log"] for r in rows))
    if not logs:
        raise InputError("relations_figure needs at least one row")
    fig, axes = new_figure(1, len(logs), size=(7.5 * len(logs), 5.0))
    for ax, log in zip(np.atleast_1d(axes), logs, strict=True):
        bars = [(r["method"], r["translation_m"][0], "tab:red" if r["mode"] is None else "tab:blue")
                for r in rows if r["log"] == log]
        bars += [(f"{m['method']} ({m['source']})", m["translation_m"][0], "0.5") for m in published
                 if m["log"] == log]
        labels, vals, colors = zip(*bars, strict=True)
        y = np.arange(len(bars))
        ax.barh(y, vals, color=colors)
        for yi, v in zip(y, vals, strict=True):
            ax.text(v * 1.08, yi, f"{v:.3f}", va="center", fontsize=8)
        ax.set_yticks(y, labels, fontsize=8)
        ax.invert_yaxis()
        ax.set_xscale("log")
        ax.set_xlim(min(vals) * 0.5, max(vals) * 4)
        ax.set_xlabel("mean translational error over the relations [m] (log)")
        ax.set_title(f"{log}: ours (blue), raw odometry (red), published (grey)" + (f"\n{note}" if note else ""))
        ax.grid(True, axis="x", lw=0.3)
    return fig


def relations_dt_figure(curves: Mapping[tuple[str, str], tuple], *, cartographer: Mapping[str, float] | None = None,
                        bins: int = 12) -> Figure:
    """One panel per log: the mean translational relations error against the time between the two poses.

    Short relations measure the tracking, long ones the global consistency: without loop closure the error grows
    with dt, with it the curve stays flat.

    Parameters
    ----------
    curves : mapping of (log, method) to (dt, error)
        :attr:`hsmap.study.benchmarks.FreiburgResults.curves`: each relation's dt (s) and translational error (m).
    cartographer : mapping of log to float, optional
        Cartographer's mean error per log, drawn as a grey line.
    bins : int
        Logarithmic dt bins.
    """
    logs = list(dict.fromkeys(k[0] for k in curves))
    if not logs:
        raise InputError("relations_dt_figure needs at least one curve")
    colors = {"HS-SLAM": "tab:blue", "HS-SLAM, no loop closure": "tab:orange", "raw odometry": "tab:red"}
    fig, axes = new_figure(1, len(logs), size=(6.5 * len(logs), 4.8))
    for ax, log in zip(np.atleast_1d(axes), logs, strict=True):
        mine = {m: v for (lg, m), v in curves.items() if lg == log}
        dts = np.concatenate([np.asarray(v[0]) for v in mine.values()])
        if dts.size == 0:
            ax.text(0.5, 0.5, f"{log}: no relations scored", ha="center", transform=ax.transAxes)
            continue
        edges = np.geomspace(max(dts.min(), 0.1), max(dts.max(), 0.2) * 1.001, bins + 1)
        drawn = 0
        for method, (dt, err) in mine.items():
            dt, err = np.asarray(dt), np.asarray(err)
            k = np.digitize(dt, edges) - 1
            centre, mean = [], []
            for b in range(bins):
                m = k == b
                if m.sum() >= 3:
                    centre.append(np.sqrt(edges[b] * edges[b + 1]))
                    mean.append(err[m].mean())
            ax.plot(centre, mean, "o-", color=colors.get(method, "k"), label=method, ms=3)
            drawn += len(centre)
        if not drawn:
            ax.text(0.5, 0.5, f"{log}: too few relations per dt bin", ha="center", transform=ax.transAxes)
            continue
        if cartographer and log in cartographer:
            ax.axhline(cartographer[log], color="0.5", lw=1, ls="--", label="Cartographer, all relations (Hess 2016)")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("time between the relation's poses, dt [s] (log)")
        ax.set_ylabel("mean translational error [m] (log)")
        ax.set_title(f"{log}: relations error against dt")
        ax.grid(True, which="both", lw=0.3)
        ax.legend(fontsize=8)
    return fig


def precision_recall_figure(rows: Sequence[Mapping[str, Any]], summary: Mapping[str, Any],
                            published: Mapping[str, Any]) -> Figure:
    """Recall and precision (%) of each of our maps (plain o, furnished s) and their means, beside the means of
    the published methods (grey).

    Parameters
    ----------
    rows : sequence of mapping
        :func:`hsmap.study.benchmarks.room_segmentation_benchmark` rows.
    summary : mapping
        :func:`hsmap.study.benchmarks.summarise_segmentation` of the rows.
    published : mapping
        ``room_segmentation`` of the published numbers (``methods``, ``maps``, ``source``).
    """
    fig, ax = new_figure(size=(7, 6))
    for kind, marker in (("plain", "o"), ("furnished", "s")):
        r = [x for x in rows if x["kind"] == kind]
        if not r:
            continue
        ax.scatter([100 * x["recall"] for x in r], [100 * x["precision"] for x in r], marker=marker, s=30,
                   label=f"ours, {kind} ({len(r)} maps)", alpha=0.8)
        ax.scatter(100 * summary[kind]["recall"], 100 * summary[kind]["precision"], marker=marker, s=160,
                   facecolors="none", edgecolors="k", lw=2, label=f"ours, {kind}, mean")
    for j, m in enumerate(published["methods"]):
        for kind, marker in (("plain", "P"), ("furnished", "X")):
            xy = (m[kind]["recall_pct"], m[kind]["precision_pct"])
            ax.scatter(*xy, marker=marker, s=90, color="0.45")
            ax.annotate(f"{m['method']} ({kind})", xy, textcoords="offset points", xytext=(5, 3 if j % 2 else -10),
                        fontsize=7, color="0.35")
    ax.set_xlabel("recall [%]")
    ax.set_ylabel("precision [%]")
    ax.set_title(f"Room segmentation: ours per map vs {published.get('source', 'published')} "
                 f"(grey, means over {published.get('maps', '?')} maps)")
    ax.grid(True, lw=0.3)
    ax.legend(fontsize=7, loc="lower left")
    return fig
