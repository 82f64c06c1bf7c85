"""Figures of the public benchmarks (notebook 08): our relations errors on the Freiburg logs beside the
published methods, and our per-map room-segmentation scores beside Bormann et al.'s methods; and of the building
benchmark (notebook 09): floor level vs slice per building, one page per building; and of the real sweeps (notebook
11): every method's aligned track over the reference and its per-DOF errors over time.

Inputs are the plain rows of :mod:`hsmap.study.benchmarks` and the published numbers of ``hsmap/study/published.yaml``
(:func:`hsmap.study.benchmarks.published_references`); drawn with the object API, like :mod:`hsmap.viz.figures`.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib.ticker
import numpy as np
from matplotlib.figure import Figure

from ..errors import InputError
from ..maps.grid import read_label_image, read_map
from ..trajectory import read_tum
from .figures import new_figure

__all__ = ["relations_figure", "relations_dt_figure", "precision_recall_figure", "buildings_gain_figure",
           "building_page_figure", "tracks_figure", "dof_errors_figure"]

#: Line colours of the methods on the real sweeps, in order (matplotlib's tab10 less its blue, which is HS-SLAM's).
_METHOD_COLORS = ["#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf"]
_DOF_UNITS = (("x", "m"), ("y", "m"), ("z", "m"), ("roll", "deg"), ("pitch", "deg"), ("yaw", "deg"))


def _method_colors(names: Sequence[str]) -> dict[str, str]:
    out, k = {}, 0
    for n in names:
        if "hs-slam" in n.lower():
            out[n] = "#1f77b4"
        else:
            out[n] = _METHOD_COLORS[k % len(_METHOD_COLORS)]
            k += 1
    return out


def tracks_figure(reference: Any, tracks: Mapping[str, tuple[Any, int | None]], *, title: str | None = None,
                  margin: float | None = None) -> Figure:
    """Every method's track from above over the reference's: ``tracks`` maps a name to (its poses (N, >= 2) after
    alignment onto the reference, the index into them from which it lost track or None). The view is the
    reference's extent plus ``margin`` metres (default a fifth of the extent, at least 1 m), so a lost track leaves
    it rather than shrinking the others; a lost track's first lost pose is marked with a cross."""
    ref = np.asarray(reference, dtype=float)
    if ref.ndim != 2 or ref.shape[1] < 2 or len(ref) == 0:
        raise InputError(f"reference must be poses (N, >= 2), got shape {ref.shape}")
    fig, ax = new_figure(1, 1, size=(9.0, 7.5))
    ax.plot(ref[:, 0], ref[:, 1], "-", color="0.6", lw=5.0, alpha=0.55, solid_capstyle="round", label="reference",
            zorder=2)
    ax.plot(*ref[0, :2], "o", color="k", ms=6, zorder=5)
    colors = _method_colors(list(tracks))
    for name, (poses, lost) in tracks.items():
        p = np.asarray(poses, dtype=float)
        if p.ndim != 2 or p.shape[1] < 2:
            raise InputError(f"tracks[{name!r}] must be poses (N, >= 2), got shape {p.shape}")
        hs = "hs-slam" in name.lower()
        ax.plot(p[:, 0], p[:, 1], "-", color=colors[name], lw=1.8 if hs else 1.1, label=name, zorder=4 if hs else 3)
        if lost is not None and 0 <= lost < len(p):
            ax.plot(*p[lost, :2], "x", color=colors[name], ms=9, mew=2.0, zorder=6)
    if margin is None:
        margin = max(1.0, 0.2 * float(np.ptp(ref[:, :2], axis=0).max()))
    lo, hi = ref[:, :2].min(axis=0) - margin, ref[:, :2].max(axis=0) + margin
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.grid(True, lw=0.3, alpha=0.5)
    ax.legend(loc="best", fontsize=8)
    if title:
        ax.set_title(title)
    return fig


def dof_errors_figure(series: Mapping[str, tuple[Any, Any]], *, xlabel: str = "sweep", title: str | None = None,
                      linear: Mapping[str, float] | None = None) -> Figure:
    """Per-DOF errors over time of several methods: ``series`` maps a name to (abscissa (N,), errors (N, 6): x, y,
    z in metres, roll, pitch, yaw in radians). One panel per DOF; the axes are symmetric-logarithmic beyond
    ``linear`` (per DOF name, default 0.05 m and 1 deg), so that centimetres and a lost track's metres both
    show."""
    if not series:
        raise InputError("dof_errors_figure needs at least one method")
    lin = {"x": 0.05, "y": 0.05, "z": 0.05, "roll": 1.0, "pitch": 1.0, "yaw": 1.0, **dict(linear or {})}
    fig, axes = new_figure(2, 3, size=(14.0, 6.5))
    axes = np.asarray(axes).ravel()
    colors = _method_colors(list(series))
    largest = np.zeros(6)
    for name, (x, e) in series.items():
        e = np.asarray(e, dtype=float)
        xs = np.asarray(x, dtype=float).reshape(-1)
        if e.ndim != 2 or e.shape[1] != 6 or len(xs) != len(e):
            raise InputError(f"series[{name!r}] must be (x (N,), errors (N, 6)), got {xs.shape} and {e.shape}")
        hs = "hs-slam" in name.lower()
        for i, (ax, (_, unit)) in enumerate(zip(axes, _DOF_UNITS, strict=True)):
            v = e[:, i] if unit == "m" else np.degrees(e[:, i])
            largest[i] = max(largest[i], float(np.abs(v).max(initial=0.0)))
            ax.plot(xs, v, "-", color=colors[name], lw=1.6 if hs else 0.9, label=name, zorder=4 if hs else 3)
    for ax, big, (dof, unit) in zip(axes, largest, _DOF_UNITS, strict=True):
        ax.set_yscale("symlog", linthresh=lin[dof])
        top = lin[dof] * 10.0 ** max(0.0, np.ceil(np.log10(max(big, 1e-12) / lin[dof])))  # a decade of linthresh
        ax.set_ylim(-top, top)
        ax.yaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda v, _: f"{v:g}"))
        ax.axhline(0, color="k", lw=0.5)
        ax.set_ylabel(f"{dof} error [{unit}]")
        ax.set_xlabel(xlabel)
        ax.grid(True, lw=0.3, alpha=0.5)
    axes[0].legend(fontsize=7, loc="best")
    if title:
        fig.suptitle(title)
    return fig


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


def buildings_gain_figure(buildings: Sequence[Mapping[str, Any]], paper: Mapping[str, float] | None = None):
    """Per building: floor-level and slice precision/recall (bars) and the recall gain of the slice, the paper's
    Table 2 as lines. ``buildings``: the records of ``results.json`` (failed ones are left out)."""
    ok = [b for b in buildings if b.get("status") == "ok"]
    fig, axes = new_figure(2, 1, size=(max(8.0, 0.7 * len(ok) + 3), 8.0))
    x = np.arange(len(ok))
    names = [b["name"] for b in ok]
    for ax, key in zip(axes, ("recall", "precision"), strict=True):
        ax.bar(x - 0.2, [b["floor"][key] for b in ok], 0.4, label=f"floor-level map {key}", color="#999999")
        ax.bar(x + 0.2, [b["slice"][key] for b in ok], 0.4, label=f"1.7-1.8 m slice {key}", color="#1f77b4")
        if paper:
            ax.axhline(paper[f"floor_{key}"], color="#999999", ls="--", lw=1, label=f"paper floor {key}")
            ax.axhline(paper[f"slice_{key}"], color="#1f77b4", ls="--", lw=1, label=f"paper slice {key}")
        ax.set_xticks(x, names, rotation=40, ha="right")
        ax.set_ylim(0, 1.05)
        ax.set_ylabel(key)
        ax.legend(loc="lower right", fontsize=8)
    for k, b in enumerate(ok):
        gain = b["slice"]["recall"] - b["floor"]["recall"]
        axes[0].text(k, 1.01, f"{gain:+.2f}", ha="center", fontsize=8, color="green" if gain > 0 else "red")
    axes[0].set_title("per-building recall (the slice's gain over the floor level above each pair)")
    axes[1].set_title("per-building precision")
    return fig


def building_page_figure(folder: str | os.PathLike, plan, record: Mapping[str, Any] | None = None):
    """One building of the benchmark on one page: the route over the ground truth, the floor-level map segmented,
    the slice segmented, the ground-truth rooms. ``folder``: the building's folder (``data/``, ``chain/``);
    ``plan``: its :class:`hsmap.sim.floorplan.FloorPlan`."""
    from .figures import plot_labels, plot_trajectories

    folder = Path(folder)
    fig, axes = new_figure(2, 2, size=(14.0, 11.0))
    axes = np.asarray(axes).ravel()
    g = plan.geometry
    base = np.where(plan.plain_free, 254, 0).astype(np.uint8)
    gt = read_tum(folder / "data" / "groundtruth.tum", dof=3)
    est = read_tum(folder / "chain" / "trajectory2d.tum", dof=3)
    plot_labels(np.zeros(g.shape, np.int32), g, base=base, ax=axes[0])
    plot_trajectories({"ground truth": gt, "2D HS-SLAM": est}, ax=axes[0], linewidth=0.8, markers=False)
    title = f"{plan.name}: the route"
    if record:
        title += f" ({record.get('route_m', 0):.0f} m, {record.get('frames', 0)} frames"
        title += f", {len(record['unreachable'])} rooms unreachable)" if record.get("unreachable") else ")"
    axes[0].set_title(title)
    for ax, kind, prefix in ((axes[1], "floor", "floor_"), (axes[2], "slice", "")):
        grid = read_map(folder / "chain" / f"{kind}.yaml")
        labels = read_label_image(folder / "chain" / f"{prefix}rooms.png")
        plot_labels(labels, grid.geometry, base=grid.data, annotate=False, ax=ax)
        what = "floor-level map" if kind == "floor" else "1.7-1.8 m slice"
        score = (f": P {record[kind]['precision']:.2f}, R {record[kind]['recall']:.2f}, "
                 f"{record[kind]['segments']} segments") if record and kind in record else ""
        ax.set_title(f"{what} segmented{score}")
    plot_labels(plan.rooms, g, base=base, annotate=False, ax=axes[3])
    axes[3].set_title(f"ground truth: {plan.n_rooms} rooms")
    for ax in axes:
        ax.set_xlim(*g.extent()[:2])
        ax.set_ylim(*g.extent()[2:])
    return fig
