"""The public benchmarks of the study: HS-SLAM on the Freiburg logs (relations metric, Kümmerle et al. 2009) and
room segmentation on the IPA maps (Bormann et al. 2016), beside the published numbers of other methods.

The published numbers live in a data file shipped with the package, ``hsmap/study/published.yaml``
(:func:`published_references`), with their sources; nothing here hard-codes them. :func:`freiburg_relations` runs (cached) HS-SLAM on each log and scores
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
from ..datasets.open import open_dataset
from ..datasets.relations import read_relations
from ..errors import ConfigError, InputError
from ..evaluation import relations_error, segmentation_scores
from ..maps.grid import read_image_gray
from ..rooms.segmentation import SegmentationConfig, segment_rooms
from ..slam import SlamConfig
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

#: The Freiburg logs of ``$HSMAP_DATASETS/slam2d`` (``NAME/BAG``, ``NAME/NAME.relations``) and the laser pose
#: (x, y, yaw) the user states where the bag's TF is wrong: fr079's TF says +0.04 m, the CARMEN PARAM -0.04 m,
#: and the relations agree with -0.04 m (0.025 m vs 0.042 m mean error on the first 1500 scans), so the
#: command line is given ``--extrinsic2d -0.04,0,0`` for it.
FREIBURG_LOGS: dict[str, dict[str, Any]] = {
    "intel": {"bag": "intel.orig.bag", "extrinsic2d": None},
    "fr079": {"bag": "fr079.orig.bag", "extrinsic2d": (-0.04, 0.0, 0.0)},
    "fr-clinic": {"bag": "fr-clinic_robotlaser.orig.bag", "extrinsic2d": None},
}

#: The 15 buildings of the ipa_room_segmentation maps in ``$HSMAP_DATASETS`` (Bormann et al. 2016).
BORMANN_BUILDINGS = ("lab_ipa", "lab_c_scan", "Freiburg52_scan", "Freiburg79_scan", "lab_b_scan", "lab_f_scan",
                     "lab_a_scan", "NLB", "office_a", "office_b", "office_d", "office_e", "office_f", "office_h",
                     "office_i")


def published_references(path: str | os.PathLike | None = None) -> dict:
    """The published numbers (``published.yaml`` of this package, or ``path``).

    Returns
    -------
    dict
        ``freiburg_relations`` (``methods``: one entry per log and method with ``translation_m`` and
        ``rotation_deg`` as [mean, std] or None, the std None where it was not checked; ``cartographer_wall_clock``)
        and ``room_segmentation`` (``methods``: recall and precision in percent per map kind, seconds per map).
    """
    if path is None:
        from importlib import resources

        with resources.as_file(resources.files(__package__).joinpath("published.yaml")) as p:
            return published_references(p)
    p = Path(path)
    doc = read_yaml(p, "published numbers")
    for key in ("freiburg_relations", "room_segmentation"):
        if not isinstance(doc, dict) or not isinstance(doc.get(key), dict) or "methods" not in doc[key]:
            raise ConfigError(f"{p}: {key}.methods: missing")
    return doc


# --- Freiburg relations ------------------------------------------------------------------------------------

def open_freiburg(folder: str | os.PathLike, name: str, *, extrinsic2d: Sequence[float] | None = None):
    """A Freiburg benchmark log as the command line opens it: ``slam2d/NAME/BAG`` (:data:`FREIBURG_LOGS`), its
    odometry from the bag's /odom, ``extrinsic2d`` (default: the log's entry in :data:`FREIBURG_LOGS`) replacing
    the bag's laser pose.

    Returns
    -------
    RosbagDataset
    """

    if name not in FREIBURG_LOGS:
        raise InputError(f"unknown Freiburg log {name!r}; expected one of {sorted(FREIBURG_LOGS)}")
    spec = FREIBURG_LOGS[name]
    ext = extrinsic2d if extrinsic2d is not None else spec["extrinsic2d"]
    return open_dataset(Path(folder) / name / spec["bag"], extrinsic2d=ext)


#: How the relations are split by the time between their two poses (seconds): short-range accuracy (tracking)
#: and long-range consistency (loop closure).
SHORT_DT, LONG_DT = 10.0, 60.0


def _relations_numbers(traj, rel, skip_unmatched: bool) -> dict:

    r = relations_error(traj, rel, skip_unmatched=skip_unmatched)
    dt = np.abs(rel.t_j - rel.t_i)[r.used]
    rot = np.degrees(r.rotation)

    def part(m):
        return {"translation_m": float(r.translation[m].mean()) if m.any() else None,
                "rotation_deg": float(rot[m].mean()) if m.any() else None, "relations": int(m.sum())}

    out = {"all": part(dt >= 0), "short": part(dt <= SHORT_DT), "long": part(dt > LONG_DT),
           "translation_std_m": float(r.translation.std(ddof=1)) if r.translation.size > 1 else 0.0,
           "rotation_std_deg": float(rot.std(ddof=1)) if rot.size > 1 else 0.0}
    scale = r.distance_scale(mask=dt <= SHORT_DT)  # a long relation of a drifted run says nothing of scale
    out["distance_scale"] = float(scale) if np.isfinite(scale) else None
    out["dt_s"], out["errors_m"] = dt, r.translation
    return out


@dataclass
class FreiburgResults:
    """What :func:`freiburg_relations` measured.

    Attributes
    ----------
    rows : list of dict
        One per log and method (``raw odometry``, ``HS-SLAM``, ``HS-SLAM, no loop closure``): ``log``, ``method``,
        ``mode`` (None for the odometry), ``seeds``, ``translation_m`` and ``rotation_deg`` as [mean over the
        seeds of the per-seed mean error, sd over the seeds], ``worst_m`` / ``worst_deg`` (the worst seed),
        ``short_m`` / ``long_m`` (relations with dt <= 10 s / > 60 s, mean over the seeds), ``distance_scale``
        (:meth:`hsmap.evaluation.trajectory.RelationsResult.distance_scale` over the relations with dt <= 10 s, mean
        over the seeds), ``loops_closed``,
        ``frames_retried``, ``real_time_factor`` (mean over the seeds), ``relations``.
    runs : dict of (log, mode, seed) to SlamRun
    curves : dict of (log, method) to (dt, error) arrays of the first seed, for the error-against-dt figure
    max_frames : int or None
    """

    rows: list[dict] = field(default_factory=list)
    runs: dict[tuple[str, str, int], SlamRun] = field(default_factory=dict)
    curves: dict[tuple[str, str], tuple] = field(default_factory=dict)
    max_frames: int | None = None

    def table(self, references: Mapping[str, Any] | None = None) -> str:
        """Ours (mean ± sd over seeds, worst seed, dt splits) beside Cartographer, one line per log and method."""
        carto = {m["log"]: m for m in (references or {}).get("freiburg_relations", {}).get("methods", [])
                 if m["method"] == "Cartographer"}
        lines = [f"{'log':10s}{'method':28s}{'seeds':>6s}{'trans [m] mean ± sd':>22s}{'worst':>8s}"
                 f"{'rot [deg]':>18s}{'dt<=10s':>9s}{'dt>60s':>9s}{'scale':>8s}{'loops':>7s}{'x real time':>12s}"]
        for r in self.rows:
            t, a = r["translation_m"], r["rotation_deg"]
            lines.append(f"{r['log']:10s}{r['method']:28s}{len(r['seeds']) or '-':>6}"
                         f"{t[0]:>13.4f} ± {t[1]:.4f}{r['worst_m']:>8.4f}{a[0]:>10.3f} ± {a[1]:.3f}"
                         f"{_f(r['short_m']):>9s}{_f(r['long_m']):>9s}{_f(r.get('distance_scale')):>8s}"
                         f"{_f(r['loops_closed'], '.0f'):>7s}"
                         f"{_f(r['real_time_factor'], '.1f'):>12s}")
            c = carto.get(r["log"])
            if c is not None and r["method"] == "HS-SLAM":
                lines.append(f"{r['log']:10s}{'Cartographer (' + c['source'] + ')':28s}{'':>6s}"
                             f"{_mean_sd(c['translation_m'], 13, '.4f')}{'':>8s}"
                             + (_mean_sd(c["rotation_deg"], 10, ".3f") if c.get("rotation_deg") else f"{'-':>18s}"))
        return "\n".join(lines)


def _mean_sd(v: Sequence, width: int, fmt: str) -> str:
    """A published [mean, sd] as the table prints it; an sd that could not be checked (None) as "?"."""
    sd = "?" + " " * (len(format(0.0, fmt)) - 1) if v[1] is None else format(v[1], fmt)
    return f"{format(v[0], fmt):>{width}s} ± {sd}"


def _mean_scale(per) -> float | None:
    v = [n["distance_scale"] for _, _, n in per if n["distance_scale"] is not None]
    return float(np.mean(v)) if v else None


def _f(v, fmt: str = ".4f") -> str:
    return "-" if v is None else format(v, fmt)


def freiburg_relations(folder: str | os.PathLike, logs: Sequence[str] = tuple(FREIBURG_LOGS), *,
                       seeds: Sequence[int] = (1, 2, 3, 4, 5), max_frames: int | None = None,
                       compare_without_loop_closure: bool = True, log=None) -> FreiburgResults:
    """HS-SLAM (3-DOF, the command line's configuration, cached runs) on the Freiburg logs over several seeds,
    scored with the relations metric beside raw odometry (and, on the first seed, without loop closure).

    Parameters
    ----------
    folder : path
        ``$HSMAP_DATASETS/slam2d`` (``NAME/BAG`` and ``NAME/NAME.relations``, see :data:`FREIBURG_LOGS`).
    logs : sequence of str
    seeds : sequence of int
        One run per seed; the rows give the mean, sd and worst over them.
    max_frames : int, optional
        Only the first frames of each log (quick runs); the relations are then scored inside that time span.
    compare_without_loop_closure : bool
        Also run the first seed with loop closure off (tracking only), for the maps before and after.
    log : callable, optional
        Receives one line per run.
    """

    seeds = [int(s) for s in seeds]
    if not seeds:
        raise InputError("seeds must name at least one seed")
    out = FreiburgResults(max_frames=max_frames)
    skip = max_frames is not None
    for name in logs:
        ds = open_freiburg(folder, name)
        rel = read_relations(Path(folder) / name / f"{name}.relations")
        odo = ds.odometry if max_frames is None else ds.odometry.head(max_frames)
        o = _relations_numbers(odo, rel, skip_unmatched=True)
        out.rows.append({"log": name, "method": "raw odometry", "mode": None, "seeds": [],
                         "translation_m": [o["all"]["translation_m"], o["translation_std_m"]],
                         "rotation_deg": [o["all"]["rotation_deg"], o["rotation_std_deg"]],
                         "worst_m": o["all"]["translation_m"], "worst_deg": o["all"]["rotation_deg"],
                         "short_m": o["short"]["translation_m"], "long_m": o["long"]["translation_m"],
                         "loops_closed": None, "frames_retried": None, "real_time_factor": None,
                         "distance_scale": o["distance_scale"], "relations": o["all"]["relations"]})
        out.curves[(name, "raw odometry")] = (o["dt_s"], o["errors_m"])
        modes = [("loop closure", seeds)] + ([("no loop closure", seeds[:1])] if compare_without_loop_closure else [])
        for mode, mode_seeds in modes:
            cfg = SlamConfig(dof=3)
            cfg.loop_closure.enabled = mode == "loop closure"
            per = []
            for seed in mode_seeds:
                t0 = time.perf_counter()
                run = cached_slam(ds, cfg, seed, max_frames=max_frames)
                out.runs[(name, mode, seed)] = run
                n = _relations_numbers(run.trajectory, rel, skip)
                per.append((seed, run, n))
                if seed == mode_seeds[0]:
                    out.curves[(name, "HS-SLAM" if mode == "loop closure" else "HS-SLAM, no loop closure")] = (
                        n["dt_s"], n["errors_m"])
                if log is not None:
                    log(f"{name:9s} {mode:15s} seed {seed}: {n['all']['translation_m']:.4f} m, "
                        f"{n['all']['rotation_deg']:.3f} deg (dt<=10 s {_f(n['short']['translation_m'])} m, "
                        f"dt>60 s {_f(n['long']['translation_m'])} m), {run.metrics.get('loops_closed', 0)} loops, "
                        f"{run.real_time_factor:.1f}x real time" + (" (cached)" if run.cached
                                                                     else f" ({time.perf_counter() - t0:.0f} s)"))
            t = np.array([n["all"]["translation_m"] for _, _, n in per])
            a = np.array([n["all"]["rotation_deg"] for _, _, n in per])

            def mean_of(key, part, per=per):
                v = [n[part][key] for _, _, n in per if n[part][key] is not None]
                return float(np.mean(v)) if v else None

            out.rows.append({
                "log": name, "method": "HS-SLAM" if mode == "loop closure" else "HS-SLAM, no loop closure",
                "mode": mode, "seeds": [s for s, _, _ in per],
                "translation_m": [float(t.mean()), float(t.std(ddof=1)) if t.size > 1 else 0.0],
                "rotation_deg": [float(a.mean()), float(a.std(ddof=1)) if a.size > 1 else 0.0],
                "worst_m": float(t.max()), "worst_deg": float(a.max()),
                "short_m": mean_of("translation_m", "short"), "long_m": mean_of("translation_m", "long"),
                "loops_closed": float(np.mean([r.metrics.get("loops_closed", 0) for _, r, _ in per])),
                "frames_retried": float(np.mean([r.metrics.get("frames_retried", 0) for _, r, _ in per])),
                "real_time_factor": float(np.mean([r.real_time_factor for _, r, _ in per])),
                "distance_scale": _mean_scale(per),
                "relations": per[0][2]["all"]["relations"]})
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
    largest time per map, segments and ground-truth rooms summed; ``all``: the times over every map."""
    out: dict[str, dict] = {}
    for kind in ("plain", "furnished"):
        r = [x for x in rows if x["kind"] == kind]
        if r:
            out[kind] = {"maps": len(r), **{k: float(np.mean([x[k] for x in r])) for k in
                                            ("precision", "recall", "precision_area", "recall_area", "seconds")},
                         "seconds_median": float(np.median([x["seconds"] for x in r])),
                         "seconds_max": float(np.max([x["seconds"] for x in r])),
                         "segments": int(sum(x["segments"] for x in r)), "rooms": int(sum(x["rooms"] for x in r)),
                         "maps_with_fewer_segments_than_rooms": int(sum(x["segments"] < x["rooms"] for x in r))}
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
    for r in (slam.rows if slam else []):
        tag = {"raw odometry": "odometry", "HS-SLAM": "hsslam", "HS-SLAM, no loop closure": "hsslam_nolc"}[r["method"]]
        k = f"{r['log'].replace('-', '_')}_{tag}"
        seeds = f", {len(r['seeds'])} seeds" if len(r["seeds"]) > 1 else ""
        values.update({f"{k}_trans_m": r["translation_m"][0], f"{k}_trans_sd_m": r["translation_m"][1],
                       f"{k}_trans_worst_m": r["worst_m"], f"{k}_rot_deg": r["rotation_deg"][0],
                       f"{k}_trans_short_m": r["short_m"], f"{k}_trans_long_m": r["long_m"],
                       f"{k}_relations": r["relations"], f"{k}_seeds": r["seeds"]})
        units.update({f"{k}_trans_m": "m", f"{k}_trans_sd_m": "m", f"{k}_trans_worst_m": "m", f"{k}_rot_deg": "deg",
                      f"{k}_trans_short_m": "m", f"{k}_trans_long_m": "m"})
        labels.update({f"{k}_trans_m": f"{r['log']}: {r['method']}, relations translation error (mean{seeds})",
                       f"{k}_trans_worst_m": f"{r['log']}: {r['method']}, worst seed",
                       f"{k}_rot_deg": f"{r['log']}: {r['method']}, relations rotation error (mean{seeds})",
                       f"{k}_trans_long_m": f"{r['log']}: {r['method']}, relations over dt > 60 s"})
        if r["mode"] is not None:
            values.update({f"{k}_loops_closed": r["loops_closed"], f"{k}_frames_retried": r["frames_retried"],
                           f"{k}_real_time_factor": r["real_time_factor"]})
            units[f"{k}_real_time_factor"] = "x real time"
            labels[f"{k}_real_time_factor"] = f"{r['log']}: {r['method']} speed, one core"
        carto = published.get((r["log"], "Cartographer"))
        if carto and tag == "hsslam":
            src = f"Cartographer ({carto['source']})"
            reference[f"{k}_trans_m"] = {"value": carto["translation_m"][0], "source": src}
            if carto["rotation_deg"] is not None:
                reference[f"{k}_rot_deg"] = {"value": carto["rotation_deg"][0], "source": src}
            wall = frel.get("cartographer_wall_clock", {}).get(r["log"])
            if wall:
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
    headline = [k for k in ("intel_hsslam_trans_m", "intel_hsslam_rot_deg", "fr079_hsslam_trans_m",
                            "fr079_hsslam_rot_deg", "fr_clinic_hsslam_trans_m", "fr_clinic_hsslam_rot_deg",
                            "intel_hsslam_real_time_factor", "seg_plain_recall", "seg_furnished_recall",
                            "seg_furnished_precision") if k in values]
    return {"values": values, "reference": {k: v for k, v in reference.items() if k in values}, "units": units,
            "labels": labels, "headline": headline}
