"""The public benchmarks of the study: HS-SLAM on the Freiburg logs (relations metric, Kümmerle et al. 2009) and
room segmentation on the IPA maps (Bormann et al. 2016), beside the published numbers of other methods.

The published numbers live in a data file, ``data/published.yaml`` (:func:`published_references`), with their
sources; nothing here hard-codes them. :func:`freiburg_relations` runs (cached) HS-SLAM on each log and scores
it and the raw odometry; :func:`room_segmentation_benchmark` segments each building's plain and furnished map
and scores it; :func:`real_benchmark_metrics` turns both into notebook 08's metrics, with the published method
the index shows beside each headline number.
"""

from __future__ import annotations

import os
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..config import read_yaml
from ..errors import ConfigError, InputError
from ..segmentation import SegmentationConfig
from ..slam import SlamConfig
from .paths import data_dir
from .runs import SlamRun, cached_slam

__all__ = [
    "published_references",
    "open_freiburg",
    "FREIBURG_LOGS",
    "FreiburgResults",
    "freiburg_relations",
    "BORMANN_BUILDINGS",
    "room_segmentation_benchmark",
    "summarise_segmentation",
    "segmentation_table",
    "real_benchmark_metrics",
]

#: The Freiburg logs of ``$HSMAP_DATASETS/slam2d`` and their laser's forward offset (m) in the robot frame
#: where the bag's TF is wrong (fr079: the TF says +0.04 m, the CARMEN PARAM -0.04 m, and the relations agree
#: with -0.04 m: 0.025 m vs 0.042 m mean error on the first 1500 scans).
FREIBURG_LOGS: dict[str, float | None] = {"intel": None, "fr079": -0.04}

#: The 15 buildings of the ipa_room_segmentation maps in ``$HSMAP_DATASETS`` (Bormann et al. 2016).
BORMANN_BUILDINGS = ("lab_ipa", "lab_c_scan", "Freiburg52_scan", "Freiburg79_scan", "lab_b_scan", "lab_f_scan",
                     "lab_a_scan", "NLB", "office_a", "office_b", "office_d", "office_e", "office_f", "office_h",
                     "office_i")


def published_references(path: str | os.PathLike | None = None) -> dict:
    """The published numbers (``data/published.yaml`` of the repository, or ``path``).

    Returns
    -------
    dict
        ``freiburg_relations`` (``methods``: one entry per log and method with ``translation_m`` and
        ``rotation_deg`` as [mean, std] or None; ``cartographer_wall_clock``) and ``room_segmentation``
        (``methods``: recall and precision in percent per map kind, seconds per map).
    """
    p = Path(path) if path is not None else data_dir() / "published.yaml"
    doc = read_yaml(p, "published numbers")
    for key in ("freiburg_relations", "room_segmentation"):
        if not isinstance(doc, dict) or not isinstance(doc.get(key), dict) or "methods" not in doc[key]:
            raise ConfigError(f"{p}: {key}.methods: missing")
    return doc


# --- Freiburg relations ------------------------------------------------------------------------------------

def open_freiburg(folder: str | os.PathLike, name: str, *, scan_odometry: bool = True,
                  laser_x: float | None = None):
    """A Freiburg benchmark log (``slam2d/NAME/NAME.orig.bag``) with the odometry CARMEN stored with each scan.

    The ``.orig.bag`` has the true (IPC) scan stamps, which the ``.relations`` use; with ``scan_odometry`` its
    frames get, by :func:`hsmap.datasets.rosbag.adopt_odometry`, the per-scan odometry of ``NAME.clf2bag.bag``
    (the bag's own /odom runs at its own rate). ``laser_x`` overrides the laser's forward offset in the robot
    frame (see :data:`FREIBURG_LOGS`).

    Returns
    -------
    RosbagDataset
    """
    from ..datasets.open import open_dataset
    from ..datasets.rosbag import adopt_odometry

    root = Path(folder) / name
    ds = open_dataset(root / f"{name}.orig.bag")
    if scan_odometry:
        adopt_odometry(ds, open_dataset(root / f"{name}.clf2bag.bag"))
    if laser_x is not None:
        ext = np.asarray(ds.extrinsic2d, dtype=float).copy()
        ext[0] = float(laser_x)
        ds.override_extrinsics(extrinsic2d=ext)
    return ds


@dataclass
class FreiburgResults:
    """What :func:`freiburg_relations` measured.

    Attributes
    ----------
    rows : list of dict
        One per log and method (``raw odometry``, ``HS-SLAM, <mode>``): ``log``, ``method``, ``mode`` (None for
        the odometry), ``translation_m`` and ``rotation_deg`` ([mean, std]), ``relations``.
    runs : dict of (log, mode) to SlamRun
    max_frames : int or None
    """

    rows: list[dict] = field(default_factory=list)
    runs: dict[tuple[str, str], SlamRun] = field(default_factory=dict)
    max_frames: int | None = None

    def table(self, references: Mapping[str, Any] | None = None) -> str:
        """Ours and the published methods, one line each: translational and rotational error per log."""
        logs = list(dict.fromkeys(r["log"] for r in self.rows))
        cells: dict[str, dict[str, tuple]] = {}
        for r in self.rows:
            cells.setdefault(r["method"], {})[r["log"]] = (r["translation_m"], r["rotation_deg"])
        for m in (references or {}).get("freiburg_relations", {}).get("methods", []):
            if m["log"] in logs:
                cells.setdefault(f"{m['method']} ({m['source']})", {})[m["log"]] = (m["translation_m"],
                                                                                    m["rotation_deg"])

        def fmt(ms) -> str:
            return "-" if ms is None else f"{ms[0]:.3f} ± {ms[1]:.3f}"

        lines = [f"{'method':34s}" + "".join(f"{n + ' trans [m]':>22s}{n + ' rot [deg]':>20s}" for n in logs)]
        for method, by_log in cells.items():
            lines.append(f"{method:34s}" + "".join(f"{fmt(by_log.get(n, (None, None))[0]):>22s}"
                                                   f"{fmt(by_log.get(n, (None, None))[1]):>20s}" for n in logs))
        wall = (references or {}).get("freiburg_relations", {}).get("cartographer_wall_clock", {})
        for (name, mode), run in self.runs.items():
            line = (f"{name:6s} HS-SLAM {mode:12s}: {run.seconds:6.0f} s for {run.metrics['input_duration_s']:.0f} s "
                    f"of data ({run.real_time_factor:.1f}x real time, "
                    f"{1000 * run.metrics['seconds_per_frame_median']:.1f} ms per scan median, 1 core)")
            if name in wall:
                d, w = wall[name]["data_s"], wall[name]["wall_s"]
                line += f"; Cartographer: {w} s for {d} s ({d / w:.1f}x, 6-core Xeon)"
            lines.append(line)
        return "\n".join(lines)


def _relation_row(log: str, method: str, mode: str | None, result: dict) -> dict:
    return {"log": log, "method": method, "mode": mode,
            "translation_m": [result["translation_m"]["mean"], result["translation_m"]["std"]],
            "rotation_deg": [result["rotation_deg"]["mean"], result["rotation_deg"]["std"]],
            "relations": result["n_relations"]}


def freiburg_relations(folder: str | os.PathLike, logs: Sequence[str] = tuple(FREIBURG_LOGS), *,
                       modes: Sequence[str] = ("no-odometry",), seed: int = 1, max_frames: int | None = None,
                       laser_x: Mapping[str, float | None] | None = None, log=None) -> FreiburgResults:
    """HS-SLAM (3-DOF, cached runs) on the Freiburg logs, scored with the relations metric beside raw odometry.

    Parameters
    ----------
    folder : path
        ``$HSMAP_DATASETS/slam2d``: ``NAME/NAME.orig.bag``, ``NAME/NAME.clf2bag.bag``, ``NAME/NAME.relations``.
    logs : sequence of str
    modes : sequence of str
        ``"no-odometry"`` (HS-SLAM on the scans alone, the paper's claim) and/or ``"odometry"`` (seeded by the
        per-scan CARMEN odometry).
    seed : int
    max_frames : int, optional
        Only the first frames of each log (quick runs); the relations are then scored inside that time span.
    laser_x : mapping, optional
        Laser forward offset per log (default :data:`FREIBURG_LOGS`).
    log : callable, optional
        Receives one line per run.
    """
    from ..datasets.relations import read_relations
    from ..evaluation import relations_error

    bad = sorted(set(modes) - {"no-odometry", "odometry"})
    if bad:
        raise InputError(f"modes must be 'no-odometry' and/or 'odometry', got {bad}")
    offsets = dict(FREIBURG_LOGS if laser_x is None else laser_x)
    out = FreiburgResults(max_frames=max_frames)
    for name in logs:
        ds = open_freiburg(folder, name, laser_x=offsets.get(name))
        rel = read_relations(Path(folder) / name / f"{name}.relations")
        odo = ds.odometry if max_frames is None else ds.odometry.head(max_frames)
        out.rows.append(_relation_row(name, "raw odometry", None,
                                      relations_error(odo, rel, skip_unmatched=True).as_dict()))
        for mode in modes:
            run = cached_slam(ds, SlamConfig(dof=3, use_odometry=mode == "odometry"), seed, max_frames=max_frames)
            out.runs[(name, mode)] = run
            r = relations_error(run.trajectory, rel, skip_unmatched=max_frames is not None).as_dict()
            out.rows.append(_relation_row(name, f"HS-SLAM, {mode}", mode, r))
            if log is not None:
                log(f"{name:6s} HS-SLAM {mode:12s}: {r['translation_m']['mean']:.3f} ± "
                    f"{r['translation_m']['std']:.3f} m, {r['rotation_deg']['mean']:.2f} ± "
                    f"{r['rotation_deg']['std']:.2f} deg over {r['n_relations']} relations; {len(run.trajectory)} "
                    f"scans in {run.seconds:.0f} s ({run.real_time_factor:.1f}x real time)"
                    + (" (cached)" if run.cached else ""))
    return out


# --- room segmentation -------------------------------------------------------------------------------------

def room_segmentation_benchmark(folder: str | os.PathLike, buildings: Sequence[str] = BORMANN_BUILDINGS, *,
                                config: SegmentationConfig | None = None, resolution: float = 0.05,
                                furnished: bool = True, repeats: int = 1, log=None) -> list[dict]:
    """Segment each building's plain (and furnished) map and score it against its ground truth.

    The benchmark's rules (Bormann et al. 2016): pixels >= 250 are free, 0.05 m per pixel, ground-truth rooms are
    the 8-connected regions of the ground-truth image above 250 larger than 100 px; scores from
    :func:`hsmap.evaluation.segmentation_scores` (per-room mean precision and recall, area-weighted beside).

    Parameters
    ----------
    repeats : int
        Times ``segment_rooms`` runs per map; ``seconds`` is the median.
    log : callable, optional
        Receives one line per map.

    Returns
    -------
    list of dict
        One row per map: building, kind (plain/furnished), map, precision, recall, precision_area, recall_area,
        rooms, segments, doors, seconds (median wall time of ``segment_rooms``, map in memory), times_s, pixels.
    """
    from ..evaluation import segmentation_scores
    from ..grid import read_image_gray
    from ..segmentation import segment_rooms

    if int(repeats) < 1:
        raise InputError(f"repeats must be >= 1, got {repeats}")
    folder = Path(folder)
    rows = []
    for b in buildings:
        gt = read_image_gray(folder / f"{b}_gt_segmentation.png")
        for kind, suffix in (("plain", ""), ("furnished", "_furnitures"))[: 2 if furnished else 1]:
            free = read_image_gray(folder / f"{b}{suffix}.png") >= 250
            times = []
            for _ in range(int(repeats)):
                t0 = time.perf_counter()
                seg = segment_rooms(free, resolution, config=config)
                times.append(time.perf_counter() - t0)
            sc = segmentation_scores(seg.labels, gt)
            rows.append({"building": b, "kind": kind, "map": b + suffix, "precision": sc.precision,
                         "recall": sc.recall, "precision_area": sc.precision_area, "recall_area": sc.recall_area,
                         "rooms": sc.n_rooms, "segments": sc.n_segments, "doors": len(seg.doors),
                         "seconds": float(np.median(times)), "times_s": times, "pixels": int(free.size)})
            if log is not None:
                log(f"{b + suffix:28s} P={sc.precision:.3f} R={sc.recall:.3f} segs={sc.n_segments:3d}/"
                    f"{sc.n_rooms:3d} t={np.median(times):.2f}s")
    return rows


def segmentation_table(rows: Sequence[Mapping[str, Any]], references: Mapping[str, Any] | None = None) -> str:
    """Ours per map, then our means beside the published methods' (recall / precision in %, seconds per map)."""
    lines = [f"{'map':30s} {'recall':>7s} {'prec.':>7s} {'rooms':>6s} {'segs':>5s} {'s':>6s}"]
    lines += [f"{r['map']:30s} {r['recall']:7.3f} {r['precision']:7.3f} {r['rooms']:6d} {r['segments']:5d} "
              f"{r['seconds']:6.2f}" for r in rows]
    s = summarise_segmentation(rows)
    lines += ["", f"{'method':36s} {'plain R/P [%]':>16s} {'furnished R/P [%]':>20s} {'s per map':>10s}"]

    def line(name: str, plain, furnished, seconds: float) -> str:
        def rp(v) -> str:
            return "-" if v is None else f"{v[0]:5.1f} / {v[1]:5.1f}"

        return f"{name:36s} {rp(plain):>16s} {rp(furnished):>20s} {seconds:10.2f}"

    ours = {k: (100 * s[k]["recall"], 100 * s[k]["precision"]) if k in s else None for k in ("plain", "furnished")}
    lines.append(line(f"hsmap (ours, {s.get('plain', {}).get('maps', 0)} maps)", ours["plain"], ours["furnished"],
                      s.get("all", {}).get("seconds_median", float("nan"))))
    rs = (references or {}).get("room_segmentation", {})
    for m in rs.get("methods", []):
        lines.append(line(f"{m['method']} ({rs.get('maps', '?')} maps)",
                          (m["plain"]["recall_pct"], m["plain"]["precision_pct"]),
                          (m["furnished"]["recall_pct"], m["furnished"]["precision_pct"]), m["seconds"]))
    return "\n".join(lines)


def summarise_segmentation(rows: Sequence[Mapping[str, Any]]) -> dict:
    """Means over the maps of each kind (precision, recall, both area-weighted, seconds) with the median and the
    largest time per map; ``all``: the times over every map."""
    out: dict[str, dict] = {}
    for kind in ("plain", "furnished"):
        r = [x for x in rows if x["kind"] == kind]
        if r:
            out[kind] = {"maps": len(r), **{k: float(np.mean([x[k] for x in r])) for k in
                                            ("precision", "recall", "precision_area", "recall_area", "seconds")},
                         "seconds_median": float(np.median([x["seconds"] for x in r])),
                         "seconds_max": float(np.max([x["seconds"] for x in r]))}
    if rows:
        t = [x["seconds"] for x in rows]
        out["all"] = {"seconds_median": float(np.median(t)), "seconds_max": float(np.max(t))}
    return out


# --- notebook 08's numbers ---------------------------------------------------------------------------------

def real_benchmark_metrics(slam: FreiburgResults | None, segmentation: Sequence[Mapping[str, Any]] | None,
                           references: Mapping[str, Any]) -> dict:
    """Notebook 08's metrics document: ours, each headline beside a published method, labels and units.

    The paper has no results on these benchmarks, so the reference beside our relations errors is Cartographer
    (Hess 2016: errors, and its real-time factor from Table V's wall clock) and beside our room scores Bormann
    et al.'s Voronoi method.

    Returns
    -------
    dict
        Keyword arguments of :meth:`hsmap.study.report.NotebookReport.metrics`: ``values``, ``reference``,
        ``units``, ``labels``, ``headline``.
    """
    values: dict[str, Any] = {}
    units: dict[str, str] = {}
    labels: dict[str, str] = {}
    reference: dict[str, dict] = {}
    frel = references["freiburg_relations"]
    published = {(m["log"], m["method"]): m for m in frel["methods"]}
    first = None
    for r in (slam.rows if slam else []):
        tag = "odometry" if r["mode"] is None else "hsslam_" + r["mode"].replace("-", "")
        what = "raw odometry" if r["mode"] is None else f"HS-SLAM ({r['mode']})"
        k = f"{r['log']}_{tag}"
        values.update({f"{k}_trans_m": r["translation_m"][0], f"{k}_trans_std_m": r["translation_m"][1],
                       f"{k}_rot_deg": r["rotation_deg"][0], f"{k}_rot_std_deg": r["rotation_deg"][1],
                       f"{k}_relations": r["relations"]})
        units.update({f"{k}_trans_m": "m", f"{k}_trans_std_m": "m", f"{k}_rot_deg": "deg", f"{k}_rot_std_deg": "deg"})
        labels.update({f"{k}_trans_m": f"{r['log']}: {what}, relations translation error (mean)",
                       f"{k}_rot_deg": f"{r['log']}: {what}, relations rotation error (mean)"})
        if r["mode"] is not None:
            first = first or tag
            carto = published.get((r["log"], "Cartographer"))
            if carto and tag == first:
                src = f"Cartographer ({carto['source']})"
                reference[f"{k}_trans_m"] = {"value": carto["translation_m"][0], "source": src}
                if carto["rotation_deg"] is not None:
                    reference[f"{k}_rot_deg"] = {"value": carto["rotation_deg"][0], "source": src}
    for (name, mode), run in (slam.runs.items() if slam else []):
        k = f"{name}_hsslam_{mode.replace('-', '')}"
        values.update({f"{k}_seconds": run.seconds, f"{k}_real_time_factor": run.real_time_factor,
                       f"{k}_scans": len(run.trajectory)})
        units[f"{k}_seconds"] = "s"
        units[f"{k}_real_time_factor"] = "x real time"
        labels[f"{k}_real_time_factor"] = f"{name}: HS-SLAM ({mode}) speed, one core"
        wall = frel.get("cartographer_wall_clock", {}).get(name)
        if wall and k.endswith(first or ""):
            reference[f"{k}_real_time_factor"] = {"value": wall["data_s"] / wall["wall_s"],
                                                  "source": "Cartographer (Hess 2016), 6 cores"}
    if segmentation:
        summary = summarise_segmentation(segmentation)
        voronoi = next((m for m in references["room_segmentation"]["methods"] if m["method"] == "Voronoi"), None)
        for kind in ("plain", "furnished"):
            if kind not in summary:
                continue
            for k in ("recall", "precision", "recall_area", "precision_area", "seconds"):
                values[f"seg_{kind}_{k}"] = summary[kind][k]
            units[f"seg_{kind}_seconds"] = "s"
            for k in ("recall", "precision"):
                labels[f"seg_{kind}_{k}"] = f"room segmentation, {kind} maps: {k} (per-room mean)"
                if voronoi:
                    reference[f"seg_{kind}_{k}"] = {
                        "value": voronoi[kind][f"{k}_pct"] / 100,
                        "source": f"Bormann 2016 Voronoi ({references['room_segmentation'].get('maps', '?')} maps)"}
        values["seg_maps"] = [dict(r) for r in segmentation]
    first = first or ""
    headline = [k for k in (f"intel_{first}_trans_m", f"intel_{first}_rot_deg", f"fr079_{first}_trans_m",
                            f"fr079_{first}_rot_deg", f"intel_{first}_real_time_factor", "seg_plain_recall",
                            "seg_furnished_recall", "seg_furnished_precision") if k in values]
    return {"values": values, "reference": {k: v for k, v in reference.items() if k in values}, "units": units,
            "labels": labels, "headline": headline}
