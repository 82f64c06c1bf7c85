"""A route that explores a floor plan: every ground-truth room's free centre, room to room through the doorways.

:func:`plan_exploration` works on the floor plan's furnished map (walls and furniture are obstacles at floor
level), at the images' resolution:

1. clearance: each free pixel's distance to the nearest obstacle; the robot's centre may only be where the
   clearance is at least ``clearance`` (the robot's radius and a margin; a caller may give the robot's own
   radius, ``footprint``, and restrict where the centre may stand, ``stand``, without narrowing the clearance);
2. goals: in each ground-truth room the pixel farthest from the room's border and its furniture (its free
   centre) among those the robot may stand on; the rooms are joined by the largest connected part of that
   space (the one holding most goals); a room with no such pixel in it, or none joined to the others, is
   *unreachable* and reported with the reason;
3. order and paths: from the goal with the most room around it, greedily to the nearest unvisited goal by the
   cost-weighted geodesic distance (:class:`skimage.graph.MCP_Geometric`), where a pixel costs
   ``1 + wall_cost * max(0, 1 - clearance / preferred_clearance)``: paths keep to the middle of corridors and
   doorways;
4. smoothing for a differential drive: each pixel path is cut into straight legs, each as long as the straight
   line keeps at least the clearance the path itself had there (up to ``preferred_clearance``); the robot turns
   on the spot at the leg ends (:mod:`hsmap.sim.robot`).

Every choice is deterministic (no randomness: ties go to the lowest pixel index).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage as ndi

from ..errors import ConfigError, EmptyInputError
from .floorplan import FloorPlan
from .robot import RouteStep

__all__ = ["ExploreConfig", "Exploration", "plan_exploration"]

_EIGHT = np.ones((3, 3), dtype=bool)


@dataclass
class ExploreConfig:
    """How the exploring route is planned (one configuration for every building).

    Attributes
    ----------
    clearance : float
        Least distance of the robot's centre from walls and furniture, metres (the robot's 0.22 m radius and
        8 cm).
    preferred_clearance : float
        Paths keep this far from obstacles where the space allows, metres.
    wall_cost : float
        Extra cost per metre of driving with no room to spare (see the module docstring).
    max_leg : float
        Longest straight leg of the smoothed path, metres.
    """

    clearance: float = 0.30
    preferred_clearance: float = 0.70
    wall_cost: float = 4.0
    max_leg: float = 15.0

    def __post_init__(self) -> None:
        for name in ("clearance", "preferred_clearance", "max_leg"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise ConfigError(f"explore.{name} must be > 0, got {v!r}")
        if not (np.isfinite(self.wall_cost) and self.wall_cost >= 0):
            raise ConfigError(f"explore.wall_cost must be >= 0, got {self.wall_cost!r}")
        if self.preferred_clearance < self.clearance:
            raise ConfigError("explore.preferred_clearance must be at least explore.clearance")


@dataclass
class Exploration:
    """The planned route.

    Attributes
    ----------
    start : ndarray of shape (3,)
        Start pose (x, y, yaw), facing the first leg.
    waypoints : ndarray of shape (K, 2)
        The smoothed path's corners, world metres (the last is the last room's centre).
    order : list of int
        Ground-truth room labels in the order visited.
    goals : dict of int to (float, float)
        Each reachable room's free centre, world metres.
    unreachable : dict of int to str
        Rooms the robot cannot reach at floor level, with the reason.
    path_length : float
        Metres along the waypoints.
    """

    start: NDArray[np.float64]
    waypoints: NDArray[np.float64]
    order: list[int]
    goals: dict[int, tuple[float, float]]
    unreachable: dict[int, str] = field(default_factory=dict)
    path_length: float = 0.0

    def steps(self) -> list[RouteStep]:
        """The route as the simulator's steps (drive to each waypoint in turn)."""
        return [RouteStep("goto", (float(x), float(y)), where=f"waypoint {k}")
                for k, (x, y) in enumerate(self.waypoints)]

    def as_dict(self) -> dict:
        return {"start": [round(float(v), 4) for v in self.start], "waypoints": len(self.waypoints),
                "path_length_m": round(self.path_length, 3), "order": [int(r) for r in self.order],
                "goals": {str(k): [round(v[0], 3), round(v[1], 3)] for k, v in self.goals.items()},
                "unreachable": {str(k): v for k, v in self.unreachable.items()}}


def _line_ok(a: NDArray, b: NDArray, clear: NDArray[np.float64], need: float) -> bool:
    """Whether every pixel on the straight line between pixels a and b (row, col) has clearance >= need."""
    n = int(np.ceil(np.hypot(*(b - a)) * 2)) + 1
    t = np.linspace(0.0, 1.0, n)[:, None]
    rc = np.rint(a[None, :] + t * (b - a)[None, :]).astype(np.int64)
    return bool(clear[rc[:, 0], rc[:, 1]].min() >= need)


def _smooth(path: NDArray[np.int64], clear: NDArray[np.float64], cfg: ExploreConfig, res: float) -> list[int]:
    """Indices into ``path`` (P, 2) of the corners of its shortcut: each leg keeps the clearance the path had."""
    keep = [0]
    i = 0
    max_px = max(2, int(cfg.max_leg / res))
    while i < len(path) - 1:
        best = i + 1
        lo = clear[path[i, 0], path[i, 1]]
        for j in range(i + 1, min(len(path), i + max_px + 1)):
            lo = min(lo, clear[path[j, 0], path[j, 1]])
            need = min(cfg.preferred_clearance, lo) - 1e-9
            if _line_ok(path[i], path[j], clear, need):
                best = j
        keep.append(best)
        i = best
    return keep


def _room_candidates(plan: FloorPlan, ok: NDArray[np.bool_], need: float
                     ) -> tuple[dict[int, NDArray[np.int64]], dict[int, str]]:
    """Per room, its pixels the robot may stand on, best first (farthest from the room's border); and why the
    rooms without any are unreachable."""
    free = plan.furnished_free
    unreachable: dict[int, str] = {}
    candidates: dict[int, NDArray[np.int64]] = {}
    for k, sl in enumerate(ndi.find_objects(plan.rooms), start=1):
        if sl is None:
            continue
        room = (plan.rooms[sl] == k) & free[sl]
        inner = ndi.distance_transform_edt(np.pad(room, 1))[1:-1, 1:-1]
        inner = np.where(ok[sl] & room, inner, -1.0)
        if inner.max() < 0:
            unreachable[k] = (f"no free pixel {need:g} m clear of walls and furniture at floor level "
                              "(the robot does not fit)")
            continue
        flat = np.flatnonzero(inner.ravel() >= 0)
        order = flat[np.argsort(-inner.ravel()[flat], kind="stable")]
        rr, cc = np.unravel_index(order, inner.shape)
        candidates[k] = np.stack([rr + sl[0].start, cc + sl[1].start], -1)
    return candidates, unreachable


def _main_goals(comp: NDArray, candidates: dict[int, NDArray[np.int64]], unreachable: dict[int, str]
                ) -> tuple[int, dict[int, NDArray[np.int64]]]:
    """The connected part of the free space that holds most rooms' centres (ties: the largest), and each room's
    goal in it: its best pixel there. The rooms outside it are added to ``unreachable``."""
    best_comp = np.array([comp[tuple(c[0])] for c in candidates.values()])
    sizes = np.bincount(comp.ravel())
    ids, votes = np.unique(best_comp, return_counts=True)
    main = int(ids[np.lexsort((-sizes[ids], -votes))[0]])
    goals_rc: dict[int, NDArray[np.int64]] = {}
    for k, c in candidates.items():
        inside = comp[c[:, 0], c[:, 1]] == main
        if inside.any():
            goals_rc[k] = c[np.argmax(inside)]
        else:
            unreachable[k] = "not joined to the other rooms by free space the robot fits through at floor level"
    return main, goals_rc


def _visit(comp: NDArray, main: int, clear: NDArray[np.float64], goals_rc: dict[int, NDArray[np.int64]],
           cfg: ExploreConfig) -> tuple[list[int], list[NDArray[np.int64]]]:
    """The rooms in visiting order (from the one with most space around its goal, then always the cheapest to
    reach next) and the pixel path of each leg, its costs keeping to the middle of corridors and doorways."""
    from skimage.graph import MCP_Geometric

    rows, cols = np.nonzero(comp == main)
    r0, r1, c0, c1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
    sub = comp[r0:r1, c0:c1] == main
    cost = 1.0 + cfg.wall_cost * np.maximum(0.0, 1.0 - clear[r0:r1, c0:c1] / cfg.preferred_clearance)
    cost = np.where(sub, cost, np.inf)
    off = np.array([r0, c0])
    rooms = sorted(goals_rc)
    first = max(rooms, key=lambda k: (clear[tuple(goals_rc[k])], -k))
    order, todo = [first], [k for k in rooms if k != first]
    pieces: list[NDArray[np.int64]] = []
    mcp = MCP_Geometric(cost, fully_connected=True)
    while todo:
        cur = goals_rc[order[-1]] - off
        costs, _ = mcp.find_costs([tuple(cur)])
        dist = np.array([costs[tuple(goals_rc[k] - off)] for k in todo])
        nxt = todo[int(np.argmin(dist))]
        path = np.asarray(mcp.traceback(tuple(goals_rc[nxt] - off)), dtype=np.int64) + off
        pieces.append(path)
        order.append(nxt)
        todo.remove(nxt)
    return order, pieces


def plan_exploration(plan: FloorPlan, config: ExploreConfig | None = None, *, footprint: float | None = None,
                     stand: NDArray[np.bool_] | None = None) -> Exploration:
    """Plan the route through every reachable ground-truth room (see the module docstring).

    Parameters
    ----------
    plan : FloorPlan
        What is read: ``geometry``, ``furnished_free`` (H, W) bool, ``rooms`` (H, W) int labels, ``files``.
    config : ExploreConfig, optional
    footprint : float, optional
        Least clearance of the robot's centre, metres, in place of ``config.clearance`` (the robot's own radius:
        paths still keep ``preferred_clearance`` where the space allows, through the costs).
    stand : ndarray of shape (H, W), bool, optional
        Where the robot's centre may be besides the clearance (default everywhere); the clearance is measured
        from ``furnished_free`` alone.

    Raises
    ------
    EmptyInputError
        No room is reachable (no free space with the clearance the robot needs).
    """
    cfg = config or ExploreConfig()
    g = plan.geometry
    res = g.resolution
    free = plan.furnished_free
    clear = np.where(free, (ndi.distance_transform_edt(free) - 0.5) * res, 0.0)
    need = cfg.clearance if footprint is None else float(footprint)
    ok = clear >= need
    if stand is not None:
        ok &= stand
    comp, _ = ndi.label(ok, structure=_EIGHT)
    candidates, unreachable = _room_candidates(plan, ok, need)
    if not candidates:
        raise EmptyInputError(f"{plan.files.get('furnished', plan.name)}: no ground-truth room has free space "
                              f"{need:g} m clear of walls and furniture: nothing to explore")
    main, goals_rc = _main_goals(comp, candidates, unreachable)
    order, pieces = _visit(comp, main, clear, goals_rc, cfg)
    waypoints_rc = [goals_rc[order[0]]]
    legs_clear = clear if stand is None else np.where(stand, clear, 0.0)  # legs stay where the robot may stand
    for path in pieces:
        idx = _smooth(path, legs_clear, cfg, res)
        waypoints_rc.extend(path[i] for i in idx[1:])
    wp = g.pixel_to_world(np.asarray(waypoints_rc, dtype=float))
    if len(wp) > 1:
        d = wp[1] - wp[0]
        yaw = float(np.arctan2(d[1], d[0]))
        legs = np.linalg.norm(np.diff(wp, axis=0), axis=1)
        length = float(legs.sum())
    else:
        yaw, length = 0.0, 0.0
    goals = {int(k): tuple(float(v) for v in g.pixel_to_world(goals_rc[k])) for k in sorted(goals_rc)}
    return Exploration(np.array([wp[0, 0], wp[0, 1], yaw]), wp[1:] if len(wp) > 1 else wp, [int(k) for k in order],
                       goals, dict(sorted(unreachable.items())), length)
