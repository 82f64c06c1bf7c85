"""The outputs both chains write (:mod:`hsmap.pipeline.chain`, :mod:`hsmap.pipeline.chain3d`): the staged output
folder with ``metrics.json`` last, the grids as Nav2 maps and pictures, the rooms' files, the doors' points, the
figures and the summary page's frame."""

from __future__ import annotations

import html
import json
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

from ..io import atomic_path, staged_outputs, write_json, write_ply_points
from ..maps.grid import OccupancyGrid, write_label_image, write_map
from ..rooms.segmentation import Door, Segmentation
from ..rooms.topology import room_graph, topology_line, write_topology
from .stages import StageLog

__all__ = ["read_metrics", "write_outputs_once", "write_grids", "write_rooms", "write_door_points", "grid_record",
           "FigureSaver", "summary_page", "write_ply"]

#: The rooms' files of the slice (no prefix) and of the floor-level grid (``floor_``).
ROOM_PREFIXES = (("slice", ""), ("floor", "floor_"))


def read_metrics(path: Path) -> dict | None:
    """A previous run's ``metrics.json``, or None when there is none or it cannot be read."""
    try:
        m = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return m if isinstance(m, dict) else None


def write_outputs_once(out: Path, names: Iterable[str], key: str, recording: bool, log: StageLog,
                       write: Callable[[Path, Any], dict], t_start: float) -> dict:
    """Write the outputs with ``write(folder, bar)`` into a staging folder inside ``out`` and move them into place
    together (``metrics.json``, the marker of a complete folder, last), unless the previous run's ``metrics.json``
    has the same ``key`` and every output in ``names`` is there: then only its stages' timings are updated.

    A failure or an interrupt on the way leaves the previous run's outputs as they were.
    """
    previous = read_metrics(out / "metrics.json")
    complete = all((out / name).is_file() for name in names if recording or name != "map.rrd")
    if previous is not None and previous.get("key") == key and complete:
        previous["stages"] = log.info | {"outputs": {"unchanged": True, "seconds": 0.0}}
        previous["seconds_total"] = round(time.perf_counter() - t_start, 3)
        write_json(out / "metrics.json", previous)
        return previous
    t = time.perf_counter()
    log.start("outputs", f"maps, figures, summary into {out}")
    bar = log.bar("outputs", 6)
    with staged_outputs(out, last="metrics.json", folders=True) as stage:
        metrics = write(stage, bar)
        log.done("outputs", False, time.perf_counter() - t, bar)
        metrics |= {"stages": log.info, "key": key, "seconds_total": round(time.perf_counter() - t_start, 3)}
        write_json(stage / "metrics.json", metrics)
    if not recording:
        (out / "map.rrd").unlink(missing_ok=True)  # not this run's
    return metrics


def write_ply(path: Path, points: np.ndarray) -> None:
    write_ply_points(path, np.asarray(points, dtype=float).reshape(-1, 3))


def write_grids(out: Path, grids: dict[str, OccupancyGrid]) -> None:
    """Each grid as a map_server map (``NAME.yaml``/``NAME.pgm``) and a picture (``NAME.png``)."""
    from PIL import Image

    for name, g in grids.items():
        write_map(out / f"{name}.yaml", g)
        with atomic_path(out / f"{name}.png") as tmp:
            Image.fromarray(g.to_image()).save(tmp, format="PNG")


def grid_record(g: OccupancyGrid) -> dict:
    """A grid's numbers for ``metrics.json``."""
    return {"shape": list(g.geometry.shape), "resolution": g.geometry.resolution, "origin": list(g.geometry.origin),
            "occupied_cells": int(g.occupied.sum()), "free_m2": float(g.free.sum() * g.geometry.resolution ** 2)}


def _segmentation_record(seg: Segmentation, graph) -> dict:
    return {"rooms": seg.n_rooms, "doors": len(seg.doors), "method": seg.config.method,
            "room_areas_m2": {f"R{r.label}": round(r.area, 3) for r in seg.rooms},
            "door_list": [d.as_dict() for d in seg.doors],
            "graph": topology_line(graph)}


def write_rooms(out: Path, segs: dict[str, Segmentation], grids: dict[str, OccupancyGrid],
                picture: Callable[[Segmentation, OccupancyGrid], np.ndarray]) -> tuple[dict, dict]:
    """Rooms, doors and graphs of the slice and the floor-level grid: ``[floor_]rooms.png`` (16-bit labels),
    ``doors.json``, ``topology.json``/``.graphml`` and ``segmentation.png`` (``picture(seg, grid)``).

    Returns
    -------
    (graphs, records)
        Per grid name the room/door graph and its numbers for ``metrics.json``.
    """
    from PIL import Image

    graphs, records = {}, {}
    for name, prefix in ROOM_PREFIXES:
        seg, g = segs[name], grids[name]
        graphs[name] = room_graph(seg)
        write_label_image(out / f"{prefix}rooms.png", seg.labels)
        write_json(out / f"{prefix}doors.json", {
            "map": f"{name}.yaml", "frame": "map (world x, y in metres; map_server origin convention)",
            "resolution": g.geometry.resolution, "origin": list(g.geometry.origin),
            "doors": [d.as_dict() for d in seg.doors]})
        write_topology(graphs[name], out, stem=f"{prefix}topology")
        with atomic_path(out / f"{prefix}segmentation.png") as tmp:
            Image.fromarray(picture(seg, g)).save(tmp, format="PNG")
        records[name] = _segmentation_record(seg, graphs[name])
    return graphs, records


def write_door_points(out: Path, doors: list[Door], pts2: list, pts3: list, *, depth: float, margin: float,
                      frame: str) -> None:
    """``door_points.json``: the points of the 2D and the 3D map in each door's box."""
    write_json(out / "door_points.json", {
        "frame": frame, "depth": depth, "margin": margin,
        "doors": [{"door": f"D{k}", "centre": [float(v) for v in d.centre], "points2d": np.round(p2, 4).tolist(),
                   "points3d": np.round(p3, 4).tolist()}
                  for k, (d, p2, p3) in enumerate(zip(doors, pts2, pts3, strict=True), 1)]})


class FigureSaver:
    """Figures saved as ``figdir/NAME.png`` (atomically, closed after), their captions kept in :attr:`names`."""

    def __init__(self, figdir: Path) -> None:
        self.figdir = figdir
        self.figdir.mkdir(exist_ok=True)
        self.names: dict[str, str] = {}

    def __call__(self, fig, name: str, caption: str) -> None:
        import matplotlib.pyplot as plt

        with atomic_path(self.figdir / f"{name}.png") as tmp:
            fig.savefig(tmp, dpi=100, format="png", bbox_inches="tight")
        plt.close(fig)
        self.names[name] = caption


def summary_page(m: dict, *, heading: str, numbers: dict, sections: str, files: Iterable[str], opening: str) -> str:
    """The summary page of a chain's run: ``heading`` (HTML), a table of ``numbers``, ``sections`` (HTML), the warnings,
    the figures of ``m["figures"]``, links to ``files`` and how to open them (``opening``, HTML)."""
    esc = html.escape

    def rows(d: dict) -> str:
        return "".join(f"<tr><th>{esc(str(k))}</th><td>{esc(str(v))}</td></tr>" for k, v in d.items())

    warn = "".join(f"<li>{esc(w)}</li>" for w in m["warnings"])
    figs = "".join(f'<figure><img src="figures/{esc(n)}.png" alt="{esc(n)}"><figcaption>{esc(c)}</figcaption>'
                   "</figure>" for n, c in m["figures"].items())
    links = ", ".join(f'<a href="{esc(f)}">{esc(f)}</a>' for f in files if f != "summary.html")
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>hsmap map: {esc(Path(m['input']).name)}</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:2em auto;padding:0 1em}}
table{{border-collapse:collapse}}th,td{{text-align:left;padding:.25em .8em;border-bottom:1px solid #ddd;vertical-align:top}}
img{{max-width:100%}}figure{{margin:1.5em 0}}.warn{{color:#a40}}</style></head><body>
<h1>{esc(Path(m['input']).name)}: {heading}</h1>
<table>{rows(numbers)}</table>
{sections}{f'<h2 class="warn">Warnings</h2><ul class="warn">{warn}</ul>' if warn else ''}
{figs}
<h2>Files</h2><p>{links}. {opening}</p>
</body></html>
"""
