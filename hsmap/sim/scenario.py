"""Scenario files: the YAML description of a simulated world, its route and its sensors.

A scenario file (see ``hsmap/sim/scenarios/*.yaml`` and ``hsmap/sim/scenarios/README.md``) has these top-level keys::

    name, description, seed, frame_rate, start_time,
    wall_height, wall_thickness, door_width, door_height, ceiling_height, label_resolution,
    walls, doors, rooms, furniture, route, robot, odometry, sensors

Lengths are metres, angles in the file are degrees. :func:`load_scenario` parses and checks a file; every
problem is a :class:`~hsmap.errors.ScenarioError` naming the file, the key (``walls[3].thickness``,
``route.steps[5]``) and what is wrong: unknown keys, wrong types, walls overlapping along their length, a door
wider than its wall or running past its end, doors overlapping or blocked by another wall, overlapping rooms,
furniture inside a wall, and a route that passes through (or within the robot's radius of) a wall, a closed
door or furniture.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from ..config import from_dict
from ..errors import ConfigError, InputError, ScenarioError
from ..limits import load_yaml, quote, read_bounded
from . import layout
from .model import FURNITURE_TYPES, Door, Furniture, Room, Scenario, Wall
from .robot import OdometryConfig, RobotConfig, RouteStep, plan_legs
from .sensors import Lidar2DConfig, Lidar3DConfig
from .shapes import boxes_overlap, segment_box_distance

__all__ = ["Wall", "Door", "Room", "Furniture", "Scenario", "load_scenario", "parse_scenario",
           "FURNITURE_TYPES"]


TOP_KEYS = {
    "name", "description", "seed", "frame_rate", "start_time", "wall_height", "wall_thickness", "door_width",
    "door_height", "ceiling_height", "label_resolution", "walls", "doors", "rooms", "furniture", "route",
    "robot", "odometry", "sensors",
}


class _Parser:
    """Parses one scenario mapping; every error names ``self.file`` and the key path."""

    def __init__(self, file: str):
        self.file = file

    def error(self, key: str, problem: str) -> ScenarioError:
        return ScenarioError(f"{self.file}: {key}: {problem}" if key else f"{self.file}: {problem}")

    def mapping(self, value: Any, key: str, allowed: set[str], required: set[str] = frozenset()) -> dict:
        if not isinstance(value, dict):
            raise self.error(key, f"expected a mapping with keys {sorted(allowed)}, got {type(value).__name__}")
        unknown = sorted(str(k) for k in value if k not in allowed)
        if unknown:
            raise self.error(key, f"unknown key(s) {unknown}; allowed: {sorted(allowed)}")
        missing = sorted(required - set(value))
        if missing:
            raise self.error(key, f"missing required key(s) {missing}")
        return value

    def number(self, value: Any, key: str, *, positive: bool = False, nonneg: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
            raise self.error(key, f"expected a finite number, got {quote(value)}")
        if positive and value <= 0:
            raise self.error(key, f"must be > 0, got {value}")
        if nonneg and value < 0:
            raise self.error(key, f"must be >= 0, got {value}")
        return float(value)

    def point(self, value: Any, key: str, n: int = 2) -> NDArray[np.float64]:
        if not isinstance(value, (list, tuple)) or len(value) != n:
            raise self.error(key, f"expected a list of {n} numbers, got {quote(value)}")
        return np.array([self.number(v, f"{key}[{i}]") for i, v in enumerate(value)])

    def string(self, value: Any, key: str) -> str:
        if not isinstance(value, str):
            raise self.error(key, f"expected a string, got {quote(value)}")
        return value

    def sequence(self, value: Any, key: str) -> list:
        if value is None:
            return []
        if not isinstance(value, list):
            raise self.error(key, f"expected a list, got {type(value).__name__}")
        return value

    def config(self, cls: type, value: Any, key: str):
        try:
            return from_dict(cls, value, key)
        except ConfigError as exc:
            msg = str(exc)
            raise ScenarioError(f"{self.file}: {msg if msg.startswith(key) else f'{key}: {msg}'}") from None


#: Highest scenario frame rate, Hz (a LiDAR's scan rate).
MAX_FRAME_RATE = 1000.0


def _frame_rate(P: _Parser, value: Any) -> float:
    rate = P.number(value, "frame_rate", positive=True)
    if rate > MAX_FRAME_RATE:
        raise P.error("frame_rate", f"must be at most {MAX_FRAME_RATE:g} Hz (a LiDAR's scan rate), got {rate:g}")
    return rate


@dataclasses.dataclass(frozen=True)
class _Defaults:
    """The scenario-wide sizes that walls, doors and furniture take unless they give their own."""

    wall_height: float
    wall_thickness: float
    door_width: float
    door_height: float
    ceiling_height: float | None


def _defaults(P: _Parser, data: dict) -> _Defaults:
    wall_h = P.number(data.get("wall_height", 2.8), "wall_height", positive=True)
    wall_t = P.number(data.get("wall_thickness", 0.15), "wall_thickness", positive=True)
    door_w = P.number(data.get("door_width", 0.85), "door_width", positive=True)
    door_h = P.number(data.get("door_height", 2.05), "door_height", positive=True)
    ceiling = data.get("ceiling_height", wall_h)
    if ceiling is not None:
        ceiling = P.number(ceiling, "ceiling_height", positive=True)
    return _Defaults(wall_h, wall_t, door_w, door_h, ceiling)


def _parse_walls(P: _Parser, data: dict, scn: Scenario, dflt: _Defaults) -> dict[str, int]:
    """Append the walls to ``scn``; returns the index of each named wall."""
    names: dict[str, int] = {}
    for i, w in enumerate(P.sequence(data["walls"], "walls")):
        key = f"walls[{i}]"
        w = P.mapping(w, key, {"name", "from", "to", "thickness", "height"}, {"from", "to"})
        wall = Wall(
            index=i,
            name=P.string(w.get("name", ""), f"{key}.name"),
            start=P.point(w["from"], f"{key}.from"),
            end=P.point(w["to"], f"{key}.to"),
            thickness=P.number(w.get("thickness", dflt.wall_thickness), f"{key}.thickness", positive=True),
            height=P.number(w.get("height", dflt.wall_height), f"{key}.height", positive=True),
        )
        if wall.length < 1e-6:
            raise P.error(f"{key}", f"the wall has zero length (from == to == {wall.start.tolist()})")
        if wall.name:
            if wall.name in names:
                raise P.error(f"{key}.name", f"duplicate wall name {wall.name!r} (also walls[{names[wall.name]}])")
            names[wall.name] = i
        scn.walls.append(wall)
    if not scn.walls:
        raise P.error("walls", "a scenario needs at least one wall")
    return names


def _parse_doors(P: _Parser, data: dict, scn: Scenario, dflt: _Defaults, names: dict[str, int]) -> None:
    for i, d in enumerate(P.sequence(data.get("doors"), "doors")):
        key = f"doors[{i}]"
        d = P.mapping(d, key, {"name", "wall", "at", "center", "width", "height", "open"})
        width = P.number(d.get("width", dflt.door_width), f"{key}.width", positive=True)
        height = P.number(d.get("height", dflt.door_height), f"{key}.height", positive=True)
        is_open = d.get("open", True)
        if not isinstance(is_open, bool):
            raise P.error(f"{key}.open", f"expected true or false, got {quote(is_open)}")
        wall_idx, at = _door_position(P, scn, d, key, names)
        scn.doors.append(Door(i, P.string(d.get("name", ""), f"{key}.name"), wall_idx, at, width, height, is_open))


def _room_polygon(P: _Parser, r: dict, key: str) -> NDArray[np.float64]:
    if ("rect" in r) == ("polygon" in r):
        raise P.error(key, "give exactly one of 'rect: [xmin, ymin, xmax, ymax]' or 'polygon: [[x, y], ...]'")
    if "rect" in r:
        x0, y0, x1, y1 = P.point(r["rect"], f"{key}.rect", 4)
        if not (x1 > x0 and y1 > y0):
            raise P.error(f"{key}.rect", f"expected [xmin, ymin, xmax, ymax] with max > min, got {r['rect']}")
        return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    pts = P.sequence(r["polygon"], f"{key}.polygon")
    if len(pts) < 3:
        raise P.error(f"{key}.polygon", f"a polygon needs at least 3 points, got {len(pts)}")
    poly = np.array([P.point(p, f"{key}.polygon[{k}]") for k, p in enumerate(pts)])
    if abs(_polygon_area(poly)) < 1e-6:
        raise P.error(f"{key}.polygon", "the polygon has zero area")
    return poly


def _parse_rooms(P: _Parser, data: dict, scn: Scenario) -> None:
    room_names: set[str] = set()
    for i, r in enumerate(P.sequence(data.get("rooms"), "rooms")):
        key = f"rooms[{i}]"
        r = P.mapping(r, key, {"name", "rect", "polygon"}, {"name"})
        rname = P.string(r["name"], f"{key}.name")
        if rname in room_names:
            raise P.error(f"{key}.name", f"duplicate room name {quote(rname)}")
        room_names.add(rname)
        scn.rooms.append(Room(i, rname, _room_polygon(P, r, key)))


def _parse_furniture(P: _Parser, data: dict, scn: Scenario, dflt: _Defaults) -> None:
    for i, f in enumerate(P.sequence(data.get("furniture"), "furniture")):
        key = f"furniture[{i}]"
        f = P.mapping(f, key, {"type", "name", "center", "size", "yaw", "height"}, {"type", "center"})
        ftype = P.string(f["type"], f"{key}.type")
        if ftype not in FURNITURE_TYPES:
            raise P.error(f"{key}.type", f"unknown furniture type {quote(ftype)}; known: {sorted(FURNITURE_TYPES)}")
        dsize, dheight = FURNITURE_TYPES[ftype]
        if dheight is None and ftype == "column":
            dheight = dflt.ceiling_height if dflt.ceiling_height is not None else dflt.wall_height
        if "size" not in f and dsize is None:
            raise P.error(f"{key}.size", f"a {ftype} needs an explicit size [lx, ly]")
        if "height" not in f and dheight is None:
            raise P.error(f"{key}.height", f"a {ftype} needs an explicit height")
        size = P.point(f["size"], f"{key}.size") if "size" in f else np.array(dsize, dtype=float)
        if np.any(size <= 0):
            raise P.error(f"{key}.size", f"both sizes must be > 0, got {size.tolist()}")
        scn.furniture.append(Furniture(
            index=i, type=ftype, name=P.string(f.get("name", ""), f"{key}.name"),
            center=P.point(f["center"], f"{key}.center"), size=size,
            yaw=np.deg2rad(P.number(f.get("yaw", 0.0), f"{key}.yaw")),
            height=P.number(f.get("height", dheight), f"{key}.height", positive=True),
        ))


def _parse_route(P: _Parser, data: dict, scn: Scenario) -> None:
    route = P.mapping(data["route"], "route", {"start", "steps"}, {"start", "steps"})
    start = route["start"]
    if not isinstance(start, (list, tuple)) or len(start) not in (2, 3):
        raise P.error("route.start", f"expected [x, y] or [x, y, yaw_deg], got {quote(start)}")
    s = P.point(list(start) + [0.0] * (3 - len(start)), "route.start", 3)
    scn.start = np.array([s[0], s[1], np.deg2rad(s[2])])
    scn.steps = _parse_steps(P, route["steps"], "route.steps")
    if not any(st.kind == "goto" for st in scn.steps):
        raise P.error("route.steps", "the route has no waypoint to drive to")


def _parse_robot_and_sensors(P: _Parser, data: dict, scn: Scenario) -> None:
    """The robot, odometry and sensors (dataclass configs), and how the sensors fit the frame rate and ceiling."""
    scn.robot = P.config(RobotConfig, data.get("robot"), "robot")
    scn.odometry = P.config(OdometryConfig, data.get("odometry"), "odometry")
    sensors = P.mapping(data.get("sensors") or {}, "sensors", {"lidar2d", "lidar3d"})
    scn.lidar2d = P.config(Lidar2DConfig, sensors.get("lidar2d"), "sensors.lidar2d")
    scn.lidar3d = P.config(Lidar3DConfig, sensors.get("lidar3d"), "sensors.lidar3d")
    if scn.lidar2d.scan_time * scn.frame_rate > 1.0 + 1e-9:
        raise P.error("sensors.lidar2d.scan_time", f"one turn of {scn.lidar2d.scan_time:g} s outlasts the frame "
                      f"period 1 / frame_rate = {1.0 / scn.frame_rate:g} s")
    if scn.ceiling_height is not None and scn.lidar3d.position[2] >= scn.ceiling_height:
        raise P.error("sensors.lidar3d.position", f"the 3D LiDAR at z = {scn.lidar3d.position[2]} m is not "
                      f"below the ceiling at {scn.ceiling_height} m")


def parse_scenario(data: Any, file: str = "<scenario>", check: bool = True) -> Scenario:
    """Build a :class:`Scenario` from a parsed YAML mapping; ``file`` names it in error messages.

    With ``check`` (default), the geometric checks of :func:`check_scenario` run too.
    """
    P = _Parser(file)
    data = P.mapping(data, "", TOP_KEYS, {"name", "walls", "route"})
    name = P.string(data["name"], "name")
    dflt = _defaults(P, data)
    seed = data.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise P.error("seed", f"expected a non-negative integer, got {quote(seed)}")
    scn = Scenario(
        name=name,
        description=str(data.get("description", "") or "").strip(),
        path=file,
        seed=seed,
        frame_rate=_frame_rate(P, data.get("frame_rate", 2.0)),
        start_time=P.number(data.get("start_time", 0.0), "start_time", nonneg=True),
        wall_height=dflt.wall_height,
        ceiling_height=dflt.ceiling_height,
        label_resolution=P.number(data.get("label_resolution", 0.05), "label_resolution", positive=True),
        raw=data,
    )
    names = _parse_walls(P, data, scn, dflt)
    _parse_doors(P, data, scn, dflt, names)
    _parse_rooms(P, data, scn)
    _parse_furniture(P, data, scn, dflt)
    _parse_route(P, data, scn)
    _parse_robot_and_sensors(P, data, scn)
    if check:
        check_scenario(scn)
    return scn


def _door_position(P: _Parser, scn: Scenario, d: dict, key: str, names: dict[str, int]) -> tuple[int, float]:
    """(wall index, distance along the wall) of a door given by ``wall`` + ``at`` or by ``center``."""
    if "wall" in d:
        ref = d["wall"]
        if isinstance(ref, str):
            if ref not in names:
                raise P.error(f"{key}.wall", f"no wall named {quote(ref)}; named walls: {sorted(names)}")
            idx = names[ref]
        elif isinstance(ref, int) and not isinstance(ref, bool):
            if not 0 <= ref < len(scn.walls):
                raise P.error(f"{key}.wall", f"wall index {ref} out of range (0..{len(scn.walls) - 1})")
            idx = ref
        else:
            raise P.error(f"{key}.wall", f"expected a wall name or index, got {quote(ref)}")
    else:
        idx = None
    wall = scn.walls[idx] if idx is not None else None
    if ("at" in d) == ("center" in d):
        raise P.error(key, "give exactly one of 'at' (metres along the wall, with 'wall') or 'center: [x, y]'")
    if "at" in d:
        if wall is None:
            raise P.error(f"{key}.at", "'at' needs 'wall' to say which wall it is measured along")
        return idx, P.number(d["at"], f"{key}.at")
    c = P.point(d["center"], f"{key}.center")
    candidates = [wall] if wall is not None else scn.walls
    best = None
    for w in candidates:
        along = float((c - w.start) @ w.direction)
        off = abs(float((c - w.start) @ w.normal))
        if off <= w.thickness / 2 + 1e-6 and -1e-6 <= along <= w.length + 1e-6:
            if best is not None and wall is None:
                raise P.error(f"{key}.center", f"{c.tolist()} lies on both {best[0].where} and {w.where}; "
                              "add 'wall' to say which")
            best = (w, along)
    if best is None:
        where = wall.where if wall is not None else "any wall"
        raise P.error(f"{key}.center", f"{c.tolist()} is not on {where} (door centres lie on a wall's centre line)")
    return best[0].index, best[1]


def _parse_steps(P: _Parser, steps: Any, key: str, depth: int = 0) -> list[RouteStep]:
    out: list[RouteStep] = []
    for i, st in enumerate(P.sequence(steps, key)):
        k = f"{key}[{i}]"
        if isinstance(st, (list, tuple)):
            out.append(RouteStep("goto", tuple(P.point(st, k)), where=k))
            continue
        if not isinstance(st, dict):
            raise P.error(k, f"expected [x, y] or a mapping (goto/turn/face/wait/repeat), got {quote(st)}")
        kinds = [x for x in ("goto", "turn", "face", "wait", "repeat") if x in st]
        if len(kinds) != 1:
            raise P.error(k, f"a step needs exactly one of goto, turn, face, wait, repeat; got keys {sorted(st)}")
        kind = kinds[0]
        if kind == "goto":
            st = P.mapping(st, k, {"goto", "reverse", "speed"})
            rev = st.get("reverse", False)
            if not isinstance(rev, bool):
                raise P.error(f"{k}.reverse", f"expected true or false, got {quote(rev)}")
            speed = P.number(st["speed"], f"{k}.speed", positive=True) if "speed" in st else None
            out.append(RouteStep("goto", tuple(P.point(st["goto"], f"{k}.goto")), reverse=rev, speed=speed, where=k))
        elif kind in ("turn", "face"):
            st = P.mapping(st, k, {kind})
            out.append(RouteStep(kind, angle=np.deg2rad(P.number(st[kind], f"{k}.{kind}")), where=k))
        elif kind == "wait":
            st = P.mapping(st, k, {"wait"})
            out.append(RouteStep("wait", seconds=P.number(st["wait"], f"{k}.wait", nonneg=True), where=k))
        else:
            st = P.mapping(st, k, {"repeat", "steps"}, {"steps"})
            n = st["repeat"]
            if isinstance(n, bool) or not isinstance(n, int) or n < 1 or depth > 3:
                raise P.error(f"{k}.repeat", f"expected a positive integer (nesting at most 4 deep), got {quote(n)}")
            inner = _parse_steps(P, st["steps"], f"{k}.steps", depth + 1)
            out.extend(dataclasses.replace(s) for _ in range(n) for s in inner)
    return out


def _polygon_area(poly: NDArray[np.float64]) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def check_scenario(scn: Scenario) -> None:
    """The geometric checks (walls, doors, rooms, furniture, route); raises ScenarioError naming the key."""

    P = _Parser(scn.path)
    # walls overlapping along their length (parallel, closer than their thickness, sharing more than a joint)
    for i, a in enumerate(scn.walls):
        for b in scn.walls[i + 1:]:
            ua, ub = a.direction, b.direction
            if abs(float(ua[0] * ub[1] - ua[1] * ub[0])) > np.sin(np.deg2rad(1.0)):
                continue
            tol = (a.thickness + b.thickness) / 2
            offs = [abs(float((p - a.start) @ a.normal)) for p in (b.start, b.end)]
            if max(offs) >= tol - 1e-9:
                continue
            sa = (-a.thickness / 2, a.length + a.thickness / 2)
            pb = sorted(float((p - a.start) @ a.direction) for p in (b.start, b.end))
            sb = (pb[0] - b.thickness / 2, pb[1] + b.thickness / 2)
            overlap = min(sa[1], sb[1]) - max(sa[0], sb[0])
            if overlap > max(a.thickness, b.thickness) + 1e-6:
                raise P.error(b.where, f"overlaps {a.where} along {overlap:.2f} m (parallel walls "
                              f"{max(offs):.2f} m apart, thinner than their thickness); merge or separate them")

    # doors: inside their wall, not overlapping each other, not blocked by another wall
    for d in scn.doors:
        w = scn.walls[d.wall]
        if d.width > w.length:
            raise P.error(f"doors[{d.index}].width", f"the door ({d.width} m) is wider than its wall {w.where} "
                          f"({w.length:.2f} m long)")
        if d.at - d.width / 2 < -1e-9 or d.at + d.width / 2 > w.length + 1e-9:
            raise P.error(f"doors[{d.index}]", f"the door ({d.width} m wide, centred {d.at:.2f} m along "
                          f"{w.where}) runs past the end of the wall (0..{w.length:.2f} m)")
        if d.height > w.height:
            raise P.error(f"doors[{d.index}].height", f"the door ({d.height} m) is taller than {w.where} "
                          f"({w.height} m)")
    for i, d in enumerate(scn.doors):
        for e in scn.doors[i + 1:]:
            if e.wall == d.wall and abs(e.at - d.at) < (d.width + e.width) / 2:
                raise P.error(e.where, f"overlaps {d.where} in {scn.walls[d.wall].where}")
    walls_full = layout.wall_footprints(scn)
    for d in scn.doors:
        opening = layout.door_opening_box(scn, d)
        for w in scn.walls:
            if w.index != d.wall and boxes_overlap(opening, walls_full[w.index], tol=1e-3):
                raise P.error(d.where, f"the opening is blocked by {w.where}")

    # rooms must not overlap (outside walls)
    if len(scn.rooms) > 1:
        labels, _, _, overlap = layout.rasterize_rooms(scn, 0.05, report_overlap=True)
        if overlap is not None:
            a, b = overlap
            raise P.error(f"rooms[{b}]", f"room {scn.rooms[b].name!r} overlaps room {scn.rooms[a].name!r}")

    # furniture must not stand in a wall
    for f in scn.furniture:
        fb = layout.furniture_footprint(f)
        for w in scn.walls:
            if boxes_overlap(fb, walls_full[w.index], tol=0.02):
                raise P.error(f.where, f"stands inside {w.where}")

    # the route must keep the robot's radius from walls, closed doors and furniture
    obstacles, names = layout.obstacle_footprints(scn)
    r = scn.robot.radius
    start_d = segment_box_distance(scn.start[:2], scn.start[:2], obstacles)
    if start_d.min() < r - 1e-6:
        k = int(np.argmin(start_d))
        raise P.error("route.start", f"the robot (radius {r} m) starts {start_d[k]:.2f} m from {names[k]}")
    for leg in plan_legs(scn.start, scn.steps, scn.robot):
        if leg.kind != "drive":
            continue
        a, b = leg.start[:2], leg.end[:2]
        dist = segment_box_distance(a, b, obstacles)
        k = int(np.argmin(dist))
        if dist[k] < r - 1e-6:
            how = (f"passes through {names[k]}" if dist[k] == 0 else
                   f"passes {dist[k]:.2f} m from {names[k]}, closer than the robot radius {r} m")
            raise P.error(leg.where, f"the leg from ({a[0]:.2f}, {a[1]:.2f}) to ({b[0]:.2f}, {b[1]:.2f}) {how}")


def load_scenario(path: str | os.PathLike, check: bool = True) -> Scenario:
    """Read and check a scenario YAML file (see the module docstring for its keys)."""
    path = Path(path)
    try:
        text = read_bounded(path, "scenario file")
    except InputError as exc:
        raise ScenarioError(str(exc)) from None
    except FileNotFoundError:
        raise ScenarioError(f"{path}: no such scenario file") from None
    except OSError as exc:
        raise ScenarioError(f"{path}: cannot read: {exc}") from None
    try:
        data = load_yaml(text.decode("utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        from ..config import yaml_error_text

        raise ScenarioError(f"{path}: not valid YAML: {yaml_error_text(exc)}") from None
    scn = parse_scenario(data, str(path), check=check)
    scn.sha256 = hashlib.sha256(text).hexdigest()
    return scn
