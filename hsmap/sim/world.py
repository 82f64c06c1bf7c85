"""The simulated world: an open3d triangle mesh of the scenario, ray-cast by both LiDARs.

The mesh holds every solid box of :mod:`hsmap.sim.layout` (walls cut at door openings, lintels, closed doors,
furniture parts), a floor plane at z = 0 and, unless the scenario has none, a ceiling. Rays are cast with
``open3d.t.geometry.RaycastingScene`` in one batched call per set of frames.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import ShapeError
from ..geometry import pose_to_matrix
from . import layout
from .scenario import Scenario
from .sensors import Lidar2DConfig, Lidar3DConfig
from .shapes import boxes_to_mesh_arrays

__all__ = ["World", "sensor_poses_3d"]


class World:
    """A scenario built into a mesh and a ray-casting scene.

    Parameters
    ----------
    scenario : Scenario
        A parsed scenario (:func:`hsmap.sim.load_scenario`); :meth:`from_boxes` builds one from boxes instead
        (``scenario`` is then None).

    Attributes
    ----------
    vertices : ndarray of shape (V, 3)
    triangles : ndarray of shape (T, 3)
    triangle_kinds : list of str
        Per solid box: wall, lintel, door, floor, ceiling or the furniture type (12 triangles per box,
        2 per plane).
    """

    def __init__(self, scenario: Scenario):
        self.scenario = scenario
        boxes, kinds = layout.solid_boxes(scenario)
        lo, hi = layout.bounds(scenario)
        self._build(boxes, kinds, lo, hi, scenario.ceiling_height)

    @classmethod
    def from_boxes(cls, boxes: ArrayLike, kinds: list[str], bounds: tuple[ArrayLike, ArrayLike],
                   ceiling_height: float | None) -> World:
        """A world of solid boxes (B, 7) (:mod:`hsmap.sim.shapes`) named by ``kinds`` (B,), a floor plane over
        ``bounds`` ((x, y) low and high corners, metres) plus 2 m and, unless ``ceiling_height`` is None, a
        ceiling over ``bounds`` (the floor-plan worlds of :mod:`hsmap.sim.floorplan`)."""
        world = cls.__new__(cls)
        world.scenario = None
        b = np.asarray(boxes, dtype=float).reshape(-1, 7)
        if len(kinds) != len(b):
            raise ShapeError(f"{len(b)} boxes but {len(kinds)} kinds")
        world._build(b, list(kinds), np.asarray(bounds[0], float), np.asarray(bounds[1], float), ceiling_height)
        return world

    def _build(self, boxes, kinds, lo, hi, ceiling_height) -> None:
        import open3d as o3d

        self.boxes = boxes
        self.box_kinds = kinds
        v, t = boxes_to_mesh_arrays(boxes) if len(boxes) else (np.zeros((0, 3)), np.zeros((0, 3), np.int64))
        planes = [("floor", 0.0, lo - 2.0, hi + 2.0)]
        if ceiling_height is not None:
            planes.append(("ceiling", ceiling_height, lo, hi))
        verts, tris = [v], [t]
        n = len(v)
        for _, z, a, b in planes:
            verts.append(np.array([[a[0], a[1], z], [b[0], a[1], z], [b[0], b[1], z], [a[0], b[1], z]]))
            tris.append(np.array([[n, n + 1, n + 2], [n, n + 2, n + 3]]))
            n += 4
        self.vertices = np.concatenate(verts, 0)
        self.triangles = np.concatenate(tris, 0)
        self.triangle_kinds = [k for k in kinds for _ in range(12)] + [p[0] for p in planes for _ in range(2)]
        self.scene = o3d.t.geometry.RaycastingScene()
        mesh = o3d.t.geometry.TriangleMesh()
        mesh.vertex.positions = o3d.core.Tensor(self.vertices.astype(np.float32))
        mesh.triangle.indices = o3d.core.Tensor(self.triangles.astype(np.uint32))
        self.scene.add_triangles(mesh)

    def cast(self, origins: ArrayLike, directions: ArrayLike, return_kinds: bool = False):
        """Distances (R,) from ray origins (R, 3) along unit directions (R, 3) to the first hit; inf if none.

        With ``return_kinds``, also the index (R,) into :attr:`triangle_kinds` of the hit triangle (-1: none).
        """
        o = np.asarray(origins, dtype=np.float32).reshape(-1, 3)
        d = np.asarray(directions, dtype=np.float32).reshape(-1, 3)
        if o.shape != d.shape:
            raise ShapeError(f"origins {o.shape} and directions {d.shape} must have the same shape")
        rays = np.empty((len(o), 6), dtype=np.float32)
        rays[:, :3] = o
        rays[:, 3:] = d
        return self.cast_rays(rays, return_kinds)

    def cast_rays(self, rays: NDArray[np.float32], return_kinds: bool = False):
        """:meth:`cast` for rays already packed as float32 (R, 6) rows (ox, oy, oz, dx, dy, dz)."""
        import open3d as o3d

        ans = self.scene.cast_rays(o3d.core.Tensor.from_numpy(np.ascontiguousarray(rays, dtype=np.float32)))
        t = ans["t_hit"].numpy()
        if return_kinds:
            ids = ans["primitive_ids"].numpy().astype(np.int64)
            ids[~np.isfinite(t)] = -1
            return t, ids
        return t

    def scan2d(self, base_poses: ArrayLike, config: Lidar2DConfig, rngs=None) -> NDArray[np.float32]:
        """Planar scans (N, M) from robot base poses (N, 3); NaN = no return.

        ``rngs`` is None (no noise) or one numpy Generator per pose (noise and dropout are drawn from it).
        """
        poses = np.atleast_2d(np.asarray(base_poses, dtype=float))
        ext = config.extrinsic()
        yaw = poses[:, 2] + ext[2]
        c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
        sx = poses[:, 0] + c * ext[0] - s * ext[1]
        sy = poses[:, 1] + s * ext[0] + c * ext[1]
        ang = yaw[:, None] + config.angles()[None, :]
        dirs = np.stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)], -1)
        orig = np.broadcast_to(np.stack([sx, sy, np.full_like(sx, config.height)], -1)[:, None, :], dirs.shape)
        r = self.cast(orig.reshape(-1, 3), dirs.reshape(-1, 3)).reshape(len(poses), -1)
        return _finish(r, config.range_min, config.range_max, config.noise_sigma, config.dropout, rngs).astype(
            np.float32
        )

    def scan3d(self, base_poses: ArrayLike, config: Lidar3DConfig, rngs=None,
               directions: NDArray[np.float64] | None = None) -> NDArray[np.float32]:
        """Range images (N, channels, columns) in metres from robot base poses (N, 3); NaN = no return.

        ``rngs``: None (no noise) or one numpy Generator per pose. ``directions`` (channels, columns, 3):
        the sensor-frame beam directions, when the caller has them already.
        """
        poses = np.atleast_2d(np.asarray(base_poses, dtype=float))
        dirs_s = config.directions() if directions is None else np.asarray(directions)
        C, W = dirs_s.shape[:2]
        # the base only turns about z: rotate the beams by the extrinsic once, then by each base yaw
        ext = pose_to_matrix(config.extrinsic())
        d = (dirs_s.reshape(-1, 3) @ ext[:3, :3].T).astype(np.float32)
        T = sensor_poses_3d(poses, config)
        rays = np.empty((len(poses), C * W, 6), dtype=np.float32)
        for k in range(len(poses)):
            c, s = np.float32(np.cos(poses[k, 2])), np.float32(np.sin(poses[k, 2]))
            rays[k, :, :3] = T[k, :3, 3]
            np.subtract(c * d[:, 0], s * d[:, 1], out=rays[k, :, 3])
            np.add(s * d[:, 0], c * d[:, 1], out=rays[k, :, 4])
            rays[k, :, 5] = d[:, 2]
        r = self.cast_rays(rays.reshape(-1, 6)).reshape(len(poses), C, W)
        return _finish(r, config.range_min, config.range_max, config.noise_sigma, config.dropout, rngs)


def sensor_poses_3d(base_poses: ArrayLike, config: Lidar3DConfig) -> NDArray[np.float64]:
    """World poses (N, 4, 4) of the 3D LiDAR for robot base poses (N, 3) on the floor."""
    p = np.atleast_2d(np.asarray(base_poses, dtype=float))
    base = np.zeros((len(p), 6))
    base[:, :2] = p[:, :2]
    base[:, 5] = p[:, 2]
    return pose_to_matrix(base) @ pose_to_matrix(config.extrinsic())


def _finish(r: NDArray, rmin: float, rmax: float, sigma: float, dropout: float, rngs) -> NDArray[np.float32]:
    """Add noise and dropout (per frame, from that frame's generator), then mask out-of-range returns."""
    r = np.array(r, dtype=np.float32)
    if rngs is not None:
        for k, g in enumerate(rngs):
            shape = r[k].shape
            if sigma > 0:
                r[k] += g.standard_normal(shape, dtype=np.float32) * np.float32(sigma)
            if dropout > 0:
                r[k][g.random(shape) < dropout] = np.inf
    bad = ~np.isfinite(r) | (r < rmin) | (r > rmax)
    r[bad] = np.nan
    return r
