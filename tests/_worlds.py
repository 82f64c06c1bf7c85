"""Small indoor worlds drawn into grids for the grid, segmentation and topology tests.

The two-rooms world follows the simulator's ``two-rooms`` scenario: two 6 m x 5 m rooms joined by a 2.5 m
corridor (1.6 m between wall centre lines) through two 0.9 m doors at (6, 2.5) and (8.5, 2.5).
"""

from __future__ import annotations

import numpy as np

from hsmap.maps.grid import FREE, OCCUPIED, UNKNOWN, GridGeometry, OccupancyGrid

# (x0, y0, x1, y1, thickness)
TWO_ROOMS_WALLS = [
    (0, 0, 6, 0, 0.2), (6, 0, 6, 5, 0.2), (6, 5, 0, 5, 0.2), (0, 5, 0, 0, 0.2),
    (6, 1.7, 8.5, 1.7, 0.15), (6, 3.3, 8.5, 3.3, 0.15),
    (8.5, 0, 14.5, 0, 0.2), (14.5, 0, 14.5, 5, 0.2), (14.5, 5, 8.5, 5, 0.2), (8.5, 5, 8.5, 0, 0.2),
]
TWO_ROOMS_DOORS = [((6.0, 2.5), 0.9, "y"), ((8.5, 2.5), 0.9, "y")]  # centre, width, axis along the wall
TWO_ROOMS_RECTS = [(0, 0, 6, 5), (6, 1.7, 8.5, 3.3), (8.5, 0, 14.5, 5)]


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(((p - a) @ ab) / max(ab @ ab, 1e-12), 0.0, 1.0)
    return np.hypot(*(p - (a + t[..., None] * ab)).T)


def draw_world(walls, doors, rects, resolution: float = 0.05, margin: float = 0.6,
               furniture=()) -> OccupancyGrid:
    """Occupancy grid of walls (with door gaps), free inside the room rectangles, unknown elsewhere.

    ``furniture``: (x0, y0, x1, y1) boxes drawn occupied.
    """
    xs = [w[0] for w in walls] + [w[2] for w in walls]
    ys = [w[1] for w in walls] + [w[3] for w in walls]
    geo = GridGeometry.covering([min(xs), min(ys)], [max(xs), max(ys)], resolution, margin)
    rc = np.stack(np.meshgrid(np.arange(geo.shape[0]), np.arange(geo.shape[1]), indexing="ij"), -1)
    xy = geo.pixel_to_world(rc.reshape(-1, 2))
    data = np.full(len(xy), UNKNOWN, dtype=np.int8)
    for x0, y0, x1, y1 in rects:
        inside = (xy[:, 0] >= x0) & (xy[:, 0] <= x1) & (xy[:, 1] >= y0) & (xy[:, 1] <= y1)
        data[inside] = FREE
    for x0, y0, x1, y1, th in walls:
        d = _segment_distance(xy, np.array([x0, y0], float), np.array([x1, y1], float))
        data[d <= th / 2] = OCCUPIED
    for (cx, cy), width, axis in doors:
        along = np.abs(xy[:, 1] - cy) if axis == "y" else np.abs(xy[:, 0] - cx)
        across = np.abs(xy[:, 0] - cx) if axis == "y" else np.abs(xy[:, 1] - cy)
        data[(along <= width / 2) & (across <= 0.2)] = FREE
    for x0, y0, x1, y1 in furniture:
        inside = (xy[:, 0] >= x0) & (xy[:, 0] <= x1) & (xy[:, 1] >= y0) & (xy[:, 1] <= y1)
        data[inside] = OCCUPIED
    return OccupancyGrid(data.reshape(geo.shape), geo)


def two_rooms(resolution: float = 0.05, furniture=()) -> OccupancyGrid:
    return draw_world(TWO_ROOMS_WALLS, TWO_ROOMS_DOORS, TWO_ROOMS_RECTS, resolution, furniture=furniture)


def cast_scans(grid: OccupancyGrid, poses: np.ndarray, n_beams: int = 360, max_range: float = 10.0,
               noise: float = 0.0, rng=None) -> tuple[np.ndarray, np.ndarray]:
    """Ranges (M, n_beams) of a planar LiDAR at ``poses`` (M, 3) in ``grid`` (ray marching on its cells);
    NaN where a beam hits nothing within ``max_range``. Returns (ranges, angles)."""
    rng = np.random.default_rng(rng)
    occ = grid.occupied
    geo = grid.geometry
    angles = np.linspace(-np.pi, np.pi, n_beams, endpoint=False)
    step = geo.resolution / 4
    t = np.arange(1, int(max_range / step) + 1) * step
    out = np.full((len(poses), n_beams), np.nan)
    for i, (x, y, yaw) in enumerate(poses):
        d = np.stack([np.cos(angles + yaw), np.sin(angles + yaw)], -1)
        pts = np.array([x, y]) + t[None, :, None] * d[:, None, :]
        idx = geo.world_to_index(pts)
        ok = geo.inside(idx)
        hit = np.zeros(ok.shape, dtype=bool)
        hit[ok] = occ[idx[ok][:, 0], idx[ok][:, 1]]
        any_hit = hit.any(1)
        first = np.argmax(hit, axis=1)
        r = t[first] + (rng.normal(0, noise, n_beams) if noise else 0.0)
        out[i, any_hit] = r[any_hit]
    return out, angles


#: A 4 m x 3 m room and a 1 m route: the smallest scenario the simulator, HS-SLAM and the maps run on.
TINY_SCENARIO = """
name: tiny
frame_rate: 2.0
walls:
  - {name: s, from: [0, 0], to: [4, 0]}
  - {name: e, from: [4, 0], to: [4, 3]}
  - {name: n, from: [4, 3], to: [0, 3]}
  - {name: w, from: [0, 3], to: [0, 0]}
rooms:
  - {name: room, rect: [0, 0, 4, 3]}
route:
  start: [1.0, 1.5, 0]
  steps:
    - [2.0, 1.5]
sensors:
  lidar3d: {channels: 16, columns: 256}
"""
def ring_corridor(opening: float = 2.5, thickness: float = 0.2, resolution: float = 0.05) -> OccupancyGrid:
    """An 18 m x 18 m floor: a ring corridor 2 m wide between the square [4, 14]^2 and a closed core
    [6, 12]^2, and four 14 m x 4 m rooms around it (a pinwheel), each opening onto the corridor through one
    ``opening`` m gap in the middle of a side: (9, 4), (14, 9), (9, 14), (4, 9)."""
    t = thickness
    walls = [(0, 0, 18, 0, t), (18, 0, 18, 18, t), (18, 18, 0, 18, t), (0, 18, 0, 0, t),
             (0, 4, 14, 4, t), (14, 0, 14, 14, t), (18, 14, 4, 14, t), (4, 18, 4, 4, t),
             (6, 6, 12, 6, t), (12, 6, 12, 12, t), (12, 12, 6, 12, t), (6, 12, 6, 6, t)]
    doors = [((9, 4), opening, "x"), ((14, 9), opening, "y"), ((9, 14), opening, "x"), ((4, 9), opening, "y")]
    rects = [(0, 0, 18, 6), (0, 12, 18, 18), (0, 0, 6, 18), (12, 0, 18, 18)]
    return draw_world(walls, doors, rects, resolution)


def corridor_end(corridor: float = 0.9, gap: float = 0.9, thickness: float = 0.2,
                 resolution: float = 0.05) -> OccupancyGrid:
    """A corridor 8 m long (free width ``corridor``, along y = 2.5) ending in a 5 m x 5 m room (x from 8 to 13)
    through a ``gap`` m opening in the room's wall at x = 8."""
    t = thickness
    h = corridor / 2 + t / 2
    walls = [(0, 2.5 - h, 8, 2.5 - h, t), (0, 2.5 + h, 8, 2.5 + h, t), (0, 2.5 - h, 0, 2.5 + h, t),
             (8, 0, 13, 0, t), (13, 0, 13, 5, t), (13, 5, 8, 5, t), (8, 5, 8, 0, t)]
    rects = [(0, 2.5 - h, 8, 2.5 + h), (8, 0, 13, 5)]
    return draw_world(walls, [((8, 2.5), gap, "y")], rects, resolution)


def l_corridor(width: float = 1.8, thickness: float = 0.2, resolution: float = 0.05) -> OccupancyGrid:
    """An L-shaped corridor without doors: 20 m along x, then 12 m along y, ``width`` m wide."""
    t = thickness
    w = width + t
    walls = [(0, 0, 20, 0, t), (20, 0, 20, 12, t), (20 - w, w, 20 - w, 12, t), (0, w, 20 - w, w, t),
             (0, 0, 0, w, t), (20 - w, 12, 20, 12, t)]
    return draw_world(walls, [], [(0, 0, 20, w), (20 - w, 0, 20, 12)], resolution)
