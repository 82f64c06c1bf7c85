"""Small analytic scenes for tests and benchmarks of registration (no simulator needed).

- :func:`room_segments` and :func:`raycast_2d`: a furnished room as wall segments and an exact 2D LiDAR
  (Hokuyo-like: 270 deg, 0.25 deg steps, 1081 beams, 10 m) ray-cast against them.
- :func:`room_cloud_3d`: points sampled on the surfaces of a furnished room (walls, floor, boxes) seen from a
  viewpoint, the kind of cloud a 3D LiDAR gives in a room.
- :func:`room_scan_sequence` and :func:`write_scan_bag`: a robot driving through that room as a ROS1 or ROS2 bag
  of ``sensor_msgs/LaserScan`` (and optionally ``sensor_msgs/PointCloud2``) messages, for the readers' and the
  command line's tests.
- :func:`two_rooms_octree`: two rooms joined by a door, scanned into an OctoMap ``.bt`` file (octomap-python).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .geometry import pose_to_matrix, transform_points
from .registration.harmony import as_rng

__all__ = ["two_rooms_octree", "room_segments", "raycast_2d", "scan_points_2d", "room_boxes_3d", "room_cloud_3d", "room_scan_sequence",
           "ScanBagConfig", "write_scan_bag"]


def _box_segments(cx: float, cy: float, w: float, h: float, yaw: float = 0.0) -> NDArray[np.float64]:
    c, s = np.cos(yaw), np.sin(yaw)
    corners = np.array([[-w, -h], [w, -h], [w, h], [-w, h]]) / 2 @ np.array([[c, s], [-s, c]]) + [cx, cy]
    return np.stack([corners, np.roll(corners, -1, axis=0)], 1)


def room_segments() -> NDArray[np.float64]:
    """Segments (K, 2, 2) of an 8 m x 6 m room with a doorway, an alcove and furniture (irregular on purpose)."""
    walls = np.array([
        [[0, 0], [8, 0]], [[8, 0], [8, 2.5]], [[8, 2.5], [9.5, 2.5]], [[9.5, 2.5], [9.5, 4]], [[9.5, 4], [8, 4]],
        [[8, 4], [8, 6]], [[8, 6], [3.9, 6]], [[3.0, 6], [0, 6]], [[0, 6], [0, 0]],
        [[3.0, 6], [3.0, 7.5]], [[3.9, 6], [3.9, 7.5]],  # door to a corridor stub
    ], dtype=float)
    furniture = [
        _box_segments(1.2, 1.0, 1.6, 0.8),  # desk
        _box_segments(6.5, 1.0, 1.2, 0.6, 0.3),  # cabinet, rotated
        _box_segments(1.9, 2.4, 0.5, 0.5),  # chair
        _box_segments(1.0, 4.8, 0.4, 1.8),  # shelf
        _box_segments(6.8, 5.2, 1.0, 0.8, -0.2),  # table
    ]
    return np.concatenate([walls, *furniture])


def raycast_2d(
    segments: NDArray[np.float64],
    pose: NDArray[np.float64],
    *,
    fov: float = np.deg2rad(270.0),
    beams: int = 1081,
    max_range: float = 10.0,
    noise: float = 0.0,
    rng: int | np.random.Generator | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Exact ranges (beams,) and angles of a 2D LiDAR at ``pose`` (x, y, yaw); NaN where nothing is hit."""
    angles = np.linspace(-fov / 2, fov / 2, beams)
    o = np.asarray(pose[:2], dtype=float)
    d = np.column_stack([np.cos(angles + pose[2]), np.sin(angles + pose[2])])  # (B, 2)
    a, b = segments[:, 0], segments[:, 1]  # (K, 2)
    e = b - a
    denom = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]  # (B, K)
    ao = a[None] - o  # (1, K, 2)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        t = (ao[..., 0] * e[None, :, 1] - ao[..., 1] * e[None, :, 0]) / denom
        u = (ao[..., 0] * d[:, None, 1] - ao[..., 1] * d[:, None, 0]) / denom
    hit = (np.abs(denom) > 1e-12) & (t > 1e-9) & (u >= 0) & (u <= 1)
    r = np.where(hit, t, np.inf).min(axis=1)
    r[r > max_range] = np.nan
    if noise > 0:
        r = r + as_rng(rng).normal(0, noise, r.shape)
    return r, angles


def scan_points_2d(ranges: NDArray[np.float64], angles: NDArray[np.float64]) -> NDArray[np.float64]:
    """Valid returns as (K, 2) points in the sensor frame."""
    ok = np.isfinite(ranges)
    return np.column_stack([ranges[ok] * np.cos(angles[ok]), ranges[ok] * np.sin(angles[ok])])


def room_boxes_3d() -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """Axis-aligned boxes (min corner, max corner) of a furnished 8 m x 6 m x 2.8 m room."""
    return [
        (np.array([1.0, 0.5, 0.0]), np.array([2.6, 1.3, 0.75])),  # desk
        (np.array([6.0, 0.5, 0.0]), np.array([7.4, 1.1, 1.9])),  # cabinet
        (np.array([3.7, 2.9, 0.0]), np.array([4.2, 3.4, 0.9])),  # chair
        (np.array([0.2, 3.9, 0.0]), np.array([0.6, 5.7, 2.0])),  # shelf
        (np.array([6.2, 4.6, 0.0]), np.array([7.6, 5.6, 0.75])),  # table
        (np.array([3.0, 5.6, 0.0]), np.array([4.4, 6.0, 1.2])),  # sideboard
    ]


def room_cloud_3d(
    n: int = 5000,
    *,
    viewpoint: NDArray[np.float64] | None = None,
    noise: float = 0.0,
    rng: int | np.random.Generator | None = None,
) -> NDArray[np.float64]:
    """About ``n`` points on the walls, floor and furniture of the room of :func:`room_boxes_3d`.

    Points are sampled uniformly on every surface, then thinned with a density that falls off with the
    distance from ``viewpoint`` (default: room centre at 1.6 m), as a spinning LiDAR's points do.
    """
    gen = as_rng(rng)
    size = np.array([8.0, 6.0, 2.8])
    quads = []  # (origin, edge u, edge v)
    for axis in range(3):
        for side in (0.0, 1.0):
            if axis == 2 and side == 1.0:
                continue  # no ceiling: keeps the problem honest in z
            o = np.zeros(3)
            o[axis] = side * size[axis]
            u_ax, v_ax = [k for k in range(3) if k != axis]
            u = np.zeros(3)
            v = np.zeros(3)
            u[u_ax], v[v_ax] = size[u_ax], size[v_ax]
            quads.append((o, u, v))
    for lo, hi in room_boxes_3d():
        ext = hi - lo
        for axis in range(3):
            for side in (0.0, 1.0):
                if axis == 2 and side == 0.0:
                    continue
                o = lo.copy()
                o[axis] += side * ext[axis]
                u_ax, v_ax = [k for k in range(3) if k != axis]
                u = np.zeros(3)
                v = np.zeros(3)
                u[u_ax], v[v_ax] = ext[u_ax], ext[v_ax]
                quads.append((o, u, v))
    areas = np.array([np.linalg.norm(np.cross(u, v)) for _, u, v in quads])
    m = 4 * n
    counts = gen.multinomial(m, areas / areas.sum())
    pts = np.concatenate([o + gen.random((c, 1)) * u + gen.random((c, 1)) * v for (o, u, v), c in zip(quads, counts, strict=True)])
    vp = np.array([4.0, 3.0, 1.6]) if viewpoint is None else np.asarray(viewpoint, dtype=float)
    dist = np.linalg.norm(pts - vp, axis=1)
    keep_p = 1.0 / np.maximum(dist, 0.5) ** 2
    keep_p *= n / keep_p.sum()
    pts = pts[gen.random(len(pts)) < np.minimum(keep_p, 1.0)]
    if noise > 0:
        pts = pts + gen.normal(0, noise, pts.shape)
    return pts


def sensor_cloud(world_points: NDArray[np.float64], sensor_pose: NDArray[np.float64]) -> NDArray[np.float64]:
    """World points expressed in the frame of a sensor at ``sensor_pose``."""
    T = np.linalg.inv(pose_to_matrix(sensor_pose))
    return transform_points(T, world_points)


def office_segments() -> NDArray[np.float64]:
    """Segments of two furnished 5 m x 4 m rooms joined by a 1.5 m wide corridor through two 0.9 m doors."""
    walls = np.array([
        # room A: x 0..5, y 0..4, door on its east wall at y 1.55..2.45
        [[0, 0], [5, 0]], [[0, 0], [0, 4]], [[0, 4], [5, 4]], [[5, 0], [5, 1.55]], [[5, 2.45], [5, 4]],
        # corridor: x 5..9, y 1.25..2.75
        [[5, 1.25], [9, 1.25]], [[5, 2.75], [9, 2.75]],
        # room B: x 9..15, y -1..5, door on its west wall at y 1.55..2.45
        [[9, -1], [15, -1]], [[15, -1], [15, 5]], [[9, 5], [15, 5]], [[9, -1], [9, 1.55]], [[9, 2.45], [9, 5]],
    ], dtype=float)
    furniture = [
        _box_segments(1.0, 3.2, 1.4, 0.8),
        _box_segments(3.8, 0.6, 1.2, 0.6, 0.2),
        _box_segments(11.0, 4.0, 2.0, 0.8),
        _box_segments(13.8, 0.5, 0.8, 1.6, -0.3),
        _box_segments(12.0, 1.0, 0.6, 0.6),
    ]
    return np.concatenate([walls, *furniture])


def office_route(step: float = 0.2, turn_step: float = np.deg2rad(10)) -> NDArray[np.float64]:
    """Poses (x, y, yaw) every ``step`` metres (and ``turn_step`` when turning on the spot) through
    :func:`office_segments`: round room A, through the corridor, round room B and back to the corridor."""
    waypoints = np.array([[1.5, 1.5], [3.5, 2.0], [3.5, 3.0], [2.0, 2.0], [4.5, 2.0], [7.0, 2.0], [10.5, 2.0],
                          [13.0, 2.5], [13.0, 3.8], [10.5, 3.0], [10.0, 1.0], [12.5, 2.0], [10.0, 2.0], [7.0, 2.0]])
    poses = [np.array([*waypoints[0], np.arctan2(*(waypoints[1] - waypoints[0])[::-1])])]
    for a, b in zip(waypoints[:-1], waypoints[1:], strict=True):
        yaw = np.arctan2(b[1] - a[1], b[0] - a[0])
        cur = poses[-1][2]
        dyaw = (yaw - cur + np.pi) % (2 * np.pi) - np.pi
        for k in range(1, int(np.ceil(abs(dyaw) / turn_step)) + 1):  # turn on the spot
            poses.append(np.array([a[0], a[1], cur + dyaw * min(1.0, k * turn_step / abs(dyaw))]))
        n = int(np.ceil(np.linalg.norm(b - a) / step))
        for k in range(1, n + 1):
            p = a + (b - a) * k / n
            poses.append(np.array([p[0], p[1], yaw]))
    out = np.asarray(poses)
    out[:, 2] = (out[:, 2] + np.pi) % (2 * np.pi) - np.pi
    return out


def room_scan_sequence(n: int = 40, step: float = 0.05, *, beams: int = 541, fov: float = np.deg2rad(270.0),
                       start: tuple[float, float, float] = (2.5, 3.0, 0.0)
                       ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """A robot driving straight ahead (+x) through :func:`room_segments`, ``step`` metres per scan.

    Returns
    -------
    ranges : ndarray of shape (n, beams)
        Metres, NaN where nothing is hit within 10 m.
    angles : ndarray of shape (beams,)
        Radians, evenly spaced over ``fov`` centred on the sensor's x axis.
    poses : ndarray of shape (n, 3)
        The true (x, y, yaw) of each scan.
    """
    segs = room_segments()
    poses = np.array([[start[0] + k * step, start[1], start[2]] for k in range(n)])
    ranges, angles = [], None
    for p in poses:
        r, angles = raycast_2d(segs, p, fov=fov, beams=beams)
        ranges.append(r)
    return np.asarray(ranges), np.asarray(angles), poses


@dataclass(frozen=True)
class ScanBagConfig:
    """How :func:`write_scan_bag` writes: the scans' range fields, the bag's format, its topics and TF.

    Attributes
    ----------
    range_min, range_max : float
        The LaserScan range fields of every message.
    time_increment : float
        The LaserScan ``time_increment`` of every message, seconds between beams.
    ros2 : bool
        Write a ROS2 (sqlite3) bag instead of a ROS1 one.
    scan_topic, cloud_topic : str
        Where the scans and the clouds go.
    tf : bool
        Write the sensors' (identity) offsets on ``/tf_static``.
    """

    range_min: float = 0.05
    range_max: float = 10.0
    time_increment: float = 0.0
    ros2: bool = False
    scan_topic: str = "/scan"
    cloud_topic: str = "/points"
    tf: bool = True


class _ScanBagMessages:
    """The messages of :func:`write_scan_bag` in a ROS1 or ROS2 type store."""

    def __init__(self, ros2: bool) -> None:
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        self.ros2 = ros2
        self.ts = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)
        if not ros2 and "tf2_msgs/msg/TFMessage" not in self.ts.types:
            self.ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms",
                                                "tf2_msgs/msg/TFMessage"))
        self.T = self.ts.types

    def serialize(self, msg, msgtype: str):
        return self.ts.serialize_cdr(msg, msgtype) if self.ros2 else self.ts.serialize_ros1(msg, msgtype)

    def header(self, t: float, frame: str, seq: int):
        T = self.T
        sec = int(math.floor(t))
        stamp = T["builtin_interfaces/msg/Time"](sec=sec, nanosec=min(int(round((t - sec) * 1e9)), 999_999_999))
        if self.ros2:
            return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)
        return T["std_msgs/msg/Header"](seq=seq, stamp=stamp, frame_id=frame)

    def cloud(self, t: float, seq: int, pts: NDArray[np.float64]):
        T = self.T
        PF = T["sensor_msgs/msg/PointField"]
        data = np.ascontiguousarray(np.asarray(pts, dtype="<f4").reshape(-1, 3))
        fields = [PF(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate("xyz")]
        return T["sensor_msgs/msg/PointCloud2"](
            header=self.header(t, "lidar", seq), height=1, width=len(data), fields=fields, is_bigendian=False,
            point_step=12, row_step=12 * len(data), data=np.frombuffer(data.tobytes(), dtype=np.uint8),
            is_dense=False)

    def identity(self, t: float, child: str):
        T = self.T
        V, Q = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
        tr = T["geometry_msgs/msg/Transform"](translation=V(x=0.0, y=0.0, z=0.0), rotation=Q(x=0.0, y=0.0, z=0.0,
                                                                                              w=1.0))
        return T["geometry_msgs/msg/TransformStamped"](header=self.header(t, "base_link", 0), child_frame_id=child,
                                                      transform=tr)

    def scan(self, t: float, seq: int, ranges: NDArray[np.float32], angle_min: float, angle_increment: float,
             cfg: ScanBagConfig):
        return self.T["sensor_msgs/msg/LaserScan"](
            header=self.header(t, "laser", seq), angle_min=float(angle_min),
            angle_max=float(angle_min + angle_increment * (len(ranges) - 1)),
            angle_increment=float(angle_increment), time_increment=float(cfg.time_increment), scan_time=0.1,
            range_min=float(cfg.range_min), range_max=float(cfg.range_max), ranges=ranges,
            intensities=np.zeros(0, dtype=np.float32))


def write_scan_bag(
    path,
    ranges: NDArray[np.float64],
    stamps: NDArray[np.float64],
    *,
    angle_min: float,
    angle_increment: float,
    clouds: list[NDArray[np.float64]] | None = None,
    config: ScanBagConfig | None = None,
    **settings,
):
    """Write a bag of ``sensor_msgs/LaserScan`` messages (one per row of ``ranges``) with ``rosbags``.

    The scans' header frame is ``laser`` (the clouds' ``lidar``); with ``tf`` a ``/tf_static`` message puts both
    at the origin of ``base_link`` (without it the readers assume that, with a warning).
    Every field is written as given (no checks: the readers' tests feed it bad geometry on purpose).

    Parameters
    ----------
    path : path-like
        A ``.bag`` file (ROS1) or, with ``ros2``, a bag folder to create.
    ranges : array_like of shape (N, M)
        Float32 ranges of each scan (NaN and inf allowed).
    stamps : array_like of shape (N,)
        Header stamps, seconds (>= 0).
    angle_min, angle_increment : float
        The LaserScan angle fields of every message.
    clouds : list of ndarray of shape (K, 3), optional
        One ``sensor_msgs/PointCloud2`` (float32 x, y, z) per scan, on ``cloud_topic``, frame ``lidar``.
    config : ScanBagConfig, optional
        Range fields, format, topics and TF (default :class:`ScanBagConfig`'s).
    **settings
        :class:`ScanBagConfig` fields by name (``ros2=True``, ``range_max=30.0``, ...), over ``config``'s.

    Returns
    -------
    pathlib.Path
    """
    from dataclasses import replace
    from pathlib import Path

    cfg = replace(config or ScanBagConfig(), **settings)
    path = Path(path)
    m = _ScanBagMessages(cfg.ros2)
    ranges = np.asarray(ranges, dtype=np.float32)
    stamps = np.asarray(stamps, dtype=float)
    n = ranges.shape[0]
    if cfg.ros2:
        from rosbags.rosbag2 import Writer

        writer = Writer(path, version=9)
    else:
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
    scan_type, cloud_type, tf_type = "sensor_msgs/msg/LaserScan", "sensor_msgs/msg/PointCloud2", "tf2_msgs/msg/TFMessage"
    with writer as w:
        if cfg.tf and n:
            t_tf = max(float(stamps[0]) - 0.5, 0.0)
            edges = [m.identity(t_tf, "laser")] + ([m.identity(t_tf, "lidar")] if clouds is not None else [])
            w.write(w.add_connection("/tf_static", tf_type, typestore=m.ts), int(round(t_tf * 1e9)),
                    m.serialize(m.T[tf_type](transforms=edges), tf_type))
        conn = w.add_connection(cfg.scan_topic, scan_type, typestore=m.ts)
        cconn = w.add_connection(cfg.cloud_topic, cloud_type, typestore=m.ts) if clouds is not None else None
        for k in range(n):
            msg = m.scan(float(stamps[k]), k, ranges[k], angle_min, angle_increment, cfg)
            t_ns = int(round(float(stamps[k]) * 1e9)) + 1
            w.write(conn, t_ns, m.serialize(msg, scan_type))
            if cconn is not None:
                w.write(cconn, t_ns + 1, m.serialize(m.cloud(float(stamps[k]), k, clouds[k]), cloud_type))
    return path


def two_rooms_octree(path, resolution: float = 0.1) -> None:
    """Write an OctoMap ``.bt`` of two 4 x 3 m rooms side by side (x 0-4 and 4-8 m, y 0-3 m), walls 2.5 m high,
    a 0.9 m wide, 2 m high door between them, floor at z = 0 and a ceiling, each room scanned from (2 or 6, 1.5,
    1.2) m: occupied, free and unknown voxels as a real map has them. Needs octomap-python."""
    import octomap

    tree = octomap.OcTree(resolution)
    step = resolution / 2
    xs, ys, zs = np.arange(0.0, 8.0 + 1e-9, step), np.arange(0.0, 3.0 + 1e-9, step), np.arange(0.05, 2.5, step)
    walls = []
    for y in (0.0, 3.0):
        X, Z = np.meshgrid(xs, zs, indexing="ij")
        walls.append(np.stack([X.ravel(), np.full(X.size, y), Z.ravel()], 1))
    for x in (0.0, 4.0, 8.0):
        Y, Z = np.meshgrid(ys, zs, indexing="ij")
        keep = ~((x == 4.0) & (Y.ravel() > 1.05) & (Y.ravel() < 1.95) & (Z.ravel() < 2.0))
        walls.append(np.stack([np.full(Y.size, x), Y.ravel(), Z.ravel()], 1)[keep])
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    floor = np.stack([X.ravel(), Y.ravel(), np.full(X.size, -0.05)], 1)
    ceiling = np.stack([X.ravel(), Y.ravel(), np.full(X.size, 2.55)], 1)
    cloud = np.vstack([*walls, floor, ceiling])
    for origin in ((2.0, 1.5, 1.2), (6.0, 1.5, 1.2)):
        near = np.abs(cloud[:, 0] - origin[0]) <= 2.05  # each sensor sees its own room and through the door
        tree.insertPointCloud(cloud[near], np.array(origin))
    tree.updateInnerOccupancy()
    if not tree.writeBinary(str(path).encode()):
        raise OSError(f"{path}: octomap could not write the file")
