"""From a :class:`~hsmap.sim.scenario.Scenario` to solids, footprints, room labels and door records.

Plain numpy (no open3d): the scenario checks, the ground truth and the mesh builder all start here.

- A wall is one box along its centre line, extended by half its thickness past both ends (so corners close),
  cut at its door openings into solid pieces; above each opening a lintel from the door height to the top
  of the wall; a closed door is a 4 cm panel filling its opening.
- Furniture is built from boxes: tables are a top on four legs, desks a top on two side panels with a
  modesty panel, chairs a seat on legs with a backrest, sofas a seat block with a backrest; shelves,
  cabinets, counters, columns and generic boxes are solid.
- Room labels: a pixel belongs to a room when its centre lies inside the room's polygon and outside every
  wall's full footprint (door openings included), so that rooms are cut apart at their doorways. Furniture
  does not change the labels (it stands inside its room).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..errors import ConfigError
from ..limits import check_allocation
from ..maps.grid import GridGeometry
from .model import Door, Furniture, Scenario
from .shapes import box_corners, box_sdf, make_box, points_in_polygon

__all__ = [
    "wall_footprints",
    "door_opening_box",
    "structure_boxes",
    "furniture_footprint",
    "furniture_parts",
    "obstacle_footprints",
    "solid_boxes",
    "bounds",
    "label_grid",
    "rasterize_rooms",
    "door_records",
]

DOOR_PANEL_THICKNESS = 0.04


def wall_footprints(scn: Scenario) -> NDArray[np.float64]:
    """Full footprint boxes (W, 7) of the walls, door openings included."""
    out = []
    for w in scn.walls:
        mid = (w.start + w.end) / 2
        out.append(make_box(mid, (w.length + w.thickness, w.thickness), w.yaw, 0.0, w.height))
    return np.array(out).reshape(-1, 7)


def door_opening_box(scn: Scenario, door: Door) -> NDArray[np.float64]:
    """Box (7,) of a door opening: the door's width along its wall, the wall's thickness across, floor to
    door height."""
    w = scn.walls[door.wall]
    c = w.start + w.direction * door.at
    return make_box(c, (door.width, w.thickness), w.yaw, 0.0, door.height)


def structure_boxes(scn: Scenario) -> tuple[NDArray[np.float64], list[str], list[str]]:
    """Solid boxes (B, 7) of walls, lintels and closed doors, with their kinds and the keys they come from.

    Kinds: ``"wall"``, ``"lintel"``, ``"door"`` (a closed door panel).
    """
    boxes, kinds, names = [], [], []
    for w in scn.walls:
        doors = sorted((d for d in scn.doors if d.wall == w.index), key=lambda d: d.at)
        edges = [-w.thickness / 2]
        for d in doors:
            edges += [d.at - d.width / 2, d.at + d.width / 2]
        edges.append(w.length + w.thickness / 2)
        for s0, s1 in zip(edges[0::2], edges[1::2], strict=True):
            if s1 - s0 > 1e-6:
                c = w.start + w.direction * (s0 + s1) / 2
                boxes.append(make_box(c, (s1 - s0, w.thickness), w.yaw, 0.0, w.height))
                kinds.append("wall")
                names.append(w.where)
        for d in doors:
            c = w.start + w.direction * d.at
            if d.height < w.height - 1e-6:
                boxes.append(make_box(c, (d.width, w.thickness), w.yaw, d.height, w.height))
                kinds.append("lintel")
                names.append(f"{d.where} (lintel)")
            if not d.open:
                boxes.append(make_box(c, (d.width, DOOR_PANEL_THICKNESS), w.yaw, 0.0, d.height))
                kinds.append("door")
                names.append(f"{d.where} (closed)")
    return np.array(boxes).reshape(-1, 7), kinds, names


def furniture_footprint(f: Furniture) -> NDArray[np.float64]:
    """The bounding box (7,) of a piece of furniture."""
    return make_box(f.center, f.size, f.yaw, 0.0, f.height)


def furniture_parts(f: Furniture) -> NDArray[np.float64]:
    """Solid parts (P, 7) of a piece of furniture, in world coordinates."""
    lx, ly = f.size
    h = f.height
    parts: list[tuple[float, float, float, float, float, float]] = []  # local cx, cy, lx, ly, z0, z1
    if f.type == "table":
        top, leg = min(0.04, h / 4), min(0.05, lx / 4, ly / 4)
        parts.append((0, 0, lx, ly, h - top, h))
        for sx in (-1, 1):
            for sy in (-1, 1):
                parts.append((sx * (lx / 2 - 1.5 * leg), sy * (ly / 2 - 1.5 * leg), leg, leg, 0, h - top))
    elif f.type == "desk":
        top, panel = min(0.03, h / 4), min(0.03, lx / 4)
        parts.append((0, 0, lx, ly, h - top, h))
        for sx in (-1, 1):
            parts.append((sx * (lx / 2 - panel / 2), 0, panel, ly, 0, h - top))
        parts.append((0, -(ly / 2 - 0.01), lx - 2 * panel, 0.02, min(0.3, h / 2), h - top))
    elif f.type == "chair":
        seat_z, seat_t, leg = min(0.42, 0.6 * h), 0.05, min(0.03, lx / 4, ly / 4)
        parts.append((0, 0, lx, ly, seat_z, seat_z + seat_t))
        for sx in (-1, 1):
            for sy in (-1, 1):
                parts.append((sx * (lx / 2 - 1.5 * leg), sy * (ly / 2 - 1.5 * leg), leg, leg, 0, seat_z))
        if h > seat_z + seat_t:
            parts.append((-(lx / 2 - 0.025), 0, 0.05, ly, seat_z + seat_t, h))
    elif f.type == "sofa":
        back = min(0.2, ly / 3)
        parts.append((0, back / 2, lx, ly - back, 0, min(0.45, h)))
        parts.append((0, -(ly / 2 - back / 2), lx, back, 0, h))
    else:  # shelf, cabinet, counter, column, box: solid
        parts.append((0, 0, lx, ly, 0, h))
    p = np.array(parts, dtype=float)
    c, s = np.cos(f.yaw), np.sin(f.yaw)
    world_xy = f.center + np.column_stack([p[:, 0] * c - p[:, 1] * s, p[:, 0] * s + p[:, 1] * c])
    return np.column_stack([world_xy, p[:, 2], p[:, 3], np.full(len(p), f.yaw), p[:, 4], p[:, 5]])


def obstacle_footprints(scn: Scenario) -> tuple[NDArray[np.float64], list[str]]:
    """Footprints (B, 7) the robot must keep clear of (walls, closed doors, furniture), with their names."""
    boxes, kinds, names = structure_boxes(scn)
    keep = [i for i, k in enumerate(kinds) if k in ("wall", "door")]
    obst = [boxes[i] for i in keep]
    nm = [names[i] for i in keep]
    for f in scn.furniture:
        obst.append(furniture_footprint(f))
        nm.append(f.where)
    return np.array(obst).reshape(-1, 7), nm


def solid_boxes(scn: Scenario) -> tuple[NDArray[np.float64], list[str]]:
    """Every solid box (B, 7) of the world and its kind (wall, lintel, door or the furniture type)."""
    boxes, kinds, _ = structure_boxes(scn)
    all_boxes = [boxes]
    all_kinds = list(kinds)
    for f in scn.furniture:
        parts = furniture_parts(f)
        all_boxes.append(parts)
        all_kinds += [f.type] * len(parts)
    return np.concatenate(all_boxes, 0), all_kinds


def bounds(scn: Scenario) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(xy_min, xy_max) of the walls' footprints."""

    corners = box_corners(wall_footprints(scn)).reshape(-1, 2)
    return corners.min(0), corners.max(0)


def label_grid(scn: Scenario, resolution: float, margin: float = 0.5) -> GridGeometry:
    """The grid of the ground-truth label image: covers the walls plus ``margin``, origin on a multiple of
    ``resolution``."""
    lo, hi = bounds(scn)
    lo = np.floor((lo - margin) / resolution) * resolution
    hi = np.ceil((hi + margin) / resolution) * resolution
    shape = np.maximum(np.rint((hi - lo) / resolution).astype(int), 1)
    return GridGeometry((int(shape[1]), int(shape[0])), float(resolution), (float(lo[0]), float(lo[1])))


def rasterize_rooms(scn: Scenario, resolution: float | None = None, margin: float = 0.5,
                    report_overlap: bool = False):
    """Ground-truth room labels.

    Returns
    -------
    labels : ndarray of shape (H, W), uint16
        0 = no room (walls, doorways, outside); room ``k`` of the scenario has label ``k + 1``.
    grid : GridGeometry
        Where the image lies in the world (row 0 at the top).
    names : dict of int to str
        Label -> room name.
    overlap : tuple of int or None
        With ``report_overlap``, the indices (a, b) of the first two rooms found to share more than two
        pixels outside walls; otherwise None.
    """
    res = float(resolution if resolution is not None else scn.label_resolution)
    grid = label_grid(scn, res, margin)
    H, W = grid.shape

    check_allocation(float(H) * W * 64, f"{scn.path}: label_resolution {res} m: a {H} x {W} room raster",
                     ConfigError)
    rc = np.stack(np.meshgrid(np.arange(H), np.arange(W), indexing="ij"), -1).reshape(-1, 2)
    xy = grid.pixel_to_world(rc)
    free = np.ones(len(xy), dtype=bool)
    for box in wall_footprints(scn):
        free &= box_sdf(xy, box[None, :])[:, 0] > 0
    labels = np.zeros(len(xy), dtype=np.uint16)
    overlap = None
    for room in scn.rooms:
        inside = points_in_polygon(xy, room.polygon) & free
        if report_overlap and overlap is None:
            taken = labels[inside]
            if np.count_nonzero(taken) > 2:
                overlap = (int(np.bincount(taken[taken > 0]).argmax()) - 1, room.index)
        labels[inside & (labels == 0)] = room.label
    names = {r.label: r.name for r in scn.rooms}
    return labels.reshape(H, W), grid, names, overlap


def room_at(scn: Scenario, xy: NDArray[np.float64]) -> int | None:
    """Index of the first room whose polygon contains the point, or None."""
    for room in scn.rooms:
        if points_in_polygon(xy, room.polygon)[0]:
            return room.index
    return None


def door_records(scn: Scenario) -> list[dict]:
    """One record per door: name, centre, width, height, end points, wall, the rooms on both sides, open."""
    out = []
    for d in scn.doors:
        w = scn.walls[d.wall]
        c = w.start + w.direction * d.at
        ends = [c - w.direction * d.width / 2, c + w.direction * d.width / 2]
        sides = [room_at(scn, c + sgn * w.normal * (w.thickness / 2 + 0.1)) for sgn in (1, -1)]
        out.append({
            "name": d.name or f"door-{d.index}",
            "index": d.index,
            "center": [round(float(v), 6) for v in c],
            "width": float(d.width),
            "height": float(d.height),
            "endpoints": [[round(float(v), 6) for v in e] for e in ends],
            "yaw": round(float(w.yaw), 9),
            "wall": w.index,
            "wall_name": w.name,
            "wall_thickness": float(w.thickness),
            "rooms": [scn.rooms[s].name if s is not None else None for s in sides],
            "labels": [scn.rooms[s].label if s is not None else 0 for s in sides],
            "open": bool(d.open),
        })
    return out
