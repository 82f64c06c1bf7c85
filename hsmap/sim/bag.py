"""A simulated run recorded as a robot records it: a ROS2 bag (MCAP or SQLite) of its sensors at their own rates.

What a real multi-LiDAR robot writes, and what ``hsmap map`` is meant to take:

- ``/scan`` (``sensor_msgs/LaserScan``, frame ``laser``): the floor-level 2D LiDAR at ``scan_rate`` Hz, no
  return as ``+inf`` (REP 117); with the scenario's ``sensors.lidar2d.scan_time`` > 0, beam i measured
  ``i * time_increment`` after the stamp (the first beam's, as ROS drivers stamp it) from the pose the robot has
  then, ``scan_time`` the scanner's turn; else every beam at the stamp (``time_increment`` 0, ``scan_time`` the
  scan period);
- ``/ouster/points`` (``sensor_msgs/PointCloud2``, frame ``os_lidar``): the 3D LiDAR every ``cloud_every``-th
  scan period, ``cloud_offset`` of a period after the scan (the two are not synchronised), as an Ouster driver
  publishes it: an organised cloud (``height`` = channels, ``width`` = columns) of 48-byte points (x, y, z,
  intensity, t, reflectivity, ring, ambient, range) with zeros where a beam had no return, in ``os_lidar``,
  which is rotated half a turn about z from ``os_sensor`` and 36 mm above it: two TF hops from ``base_link``;
- ``/odom`` (``nav_msgs/Odometry``, ``odom`` -> ``base_link``) and the same on ``/tf``, at ``odom_rate`` Hz,
  from the simulator's drifting wheel odometry;
- ``/tf_static``: ``base_link`` -> ``laser``, ``base_link`` -> ``os_sensor`` -> ``os_lidar`` (left out with
  ``tf=False``: a bag whose sensor offsets nobody recorded).

Stamps are Unix times (from ``start_time``). :func:`write_simulated_bag` returns the ground truth of both sensors'
stamps and the world's doors and rooms, to check what is made of the bag.
"""

from __future__ import annotations

import math
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..errors import ConfigError, DatasetError
from ..geometry import invert_matrix, matrix_to_pose, matrix_to_quaternion, pose_to_matrix
from ..trajectory import Trajectory
from . import layout
from .robot import mast_sway, sample_legs, simulate_motion
from .scenario import Scenario
from .sensors import Lidar3DConfig
from .world import World
from .writer import _as_scenario, noise_rngs, rolling_scan2d, rolling_scan3d

__all__ = ["OUSTER_POINT", "SimulatedBag", "write_simulated_bag", "ouster_cloud_bytes"]

#: The 48-byte point of an Ouster driver's PointCloud2 (``ouster_ros::Point``), little-endian.
OUSTER_POINT = np.dtype({
    "names": ["x", "y", "z", "intensity", "t", "reflectivity", "ring", "ambient", "range"],
    "formats": ["<f4", "<f4", "<f4", "<f4", "<u4", "<u2", "<u2", "<u2", "<u4"],
    "offsets": [0, 4, 8, 16, 20, 24, 26, 28, 32],
    "itemsize": 48,
})
# sensor_msgs/PointField datatypes of those fields
_FIELD_TYPES = {"<f4": 7, "<u4": 6, "<u2": 4}
#: os_sensor -> os_lidar of an Ouster OS1: 36.18 mm up, half a turn about z.
OS_LIDAR_IN_SENSOR = np.array([0.0, 0.0, 0.03618, 0.0, 0.0, math.pi])


@dataclass
class SimulatedBag:
    """What :func:`write_simulated_bag` wrote.

    Attributes
    ----------
    path : Path
        The bag (a folder with ``metadata.yaml``, or a lone ``.mcap``/``.db3`` file).
    scans, clouds : Trajectory
        Ground-truth robot base poses (x, y, yaw) at the scan and cloud stamps.
    doors : list of dict
        The world's doors (:func:`hsmap.sim.layout.door_records`: ``center``, ``width``, ...).
    rooms : list of str
        The world's room names.
    extrinsic2d, extrinsic3d : ndarray
        The sensors' true offsets in ``base_link`` (the 3D one of ``os_lidar``, the clouds' frame).
    messages : dict
        Messages per topic.
    """

    path: Path
    scans: Trajectory
    clouds: Trajectory
    doors: list[dict]
    rooms: list[str]
    extrinsic2d: NDArray[np.float64]
    extrinsic3d: NDArray[np.float64]
    messages: dict = field(default_factory=dict)


def ouster_cloud_bytes(points: NDArray[np.float64], ranges: NDArray[np.float64],
                       column_times: NDArray[np.float64] | None = None) -> NDArray[np.uint8]:
    """An organised cloud's data: ``points`` (C, W, 3) in the sensor frame, ``ranges`` (C, W) in metres (NaN = no
    return, written as zeros), as Ouster points (:data:`OUSTER_POINT`), row-major; ``t`` is each column's
    ``column_times`` (W,) seconds after the stamp in ns (default 0: the cloud taken at its stamp)."""
    C, W = ranges.shape
    rec = np.zeros((C, W), dtype=OUSTER_POINT)
    ok = np.isfinite(ranges)
    for k, name in enumerate("xyz"):
        rec[name] = np.where(ok, points[..., k], 0.0)
    rec["range"] = np.where(ok, np.round(np.nan_to_num(ranges) * 1000.0), 0).astype(np.uint32)
    rec["intensity"] = np.where(ok, 100.0, 0.0)
    rec["ring"] = np.arange(C, dtype=np.uint16)[:, None]
    if column_times is not None:
        rec["t"] = np.rint(np.asarray(column_times, dtype=float) * 1e9).astype(np.uint32)[None, :]
    return np.frombuffer(rec.tobytes(), dtype=np.uint8)


def write_simulated_bag(
    scenario: Scenario | str | os.PathLike,
    out: str | os.PathLike,
    *,
    seed: int | None = None,
    scan_rate: float = 8.0,
    cloud_every: int = 4,
    cloud_offset: float = 0.4,
    odom_rate: float = 20.0,
    lidar3d: Lidar3DConfig | None = None,
    tf: bool = True,
    start_time: float = 1_700_000_000.0,
    duration: float | None = None,
    clock_offset: float = 0.0,
) -> SimulatedBag:
    """Drive a scenario's route and write a ROS2 bag of it (see the module docstring).

    Parameters
    ----------
    scenario : Scenario, str or path
        A parsed scenario, a shipped scenario name or a YAML file.
    out : path
        ``NAME.mcap`` or ``NAME.db3``: a lone storage file; anything else: a bag folder (MCAP) with
        ``metadata.yaml``. Replaced if it exists.
    seed : int, optional
        Seed of the odometry slip and range noise (default the scenario's).
    scan_rate : float
        Hz of the 2D scans.
    cloud_every : int
        One cloud per this many scan periods (4: the 3D LiDAR at a quarter of the 2D rate).
    cloud_offset : float
        Where in its scan period a cloud is taken (0 <= offset < 1).
    odom_rate : float
        Hz of the odometry and its TF.
    lidar3d : Lidar3DConfig, optional
        The 3D LiDAR instead of the scenario's (a smaller one for quick runs).
    tf : bool
        Write the sensors' transforms on ``/tf_static``.
    start_time : float
        Unix time of the first scan.
    duration : float, optional
        Seconds of the route to record (default all of it).
    clock_offset : float
        Seconds the 3D LiDAR's clock runs ahead of the 2D LiDAR's and the odometry's: its clouds are stamped
        that much late (the returned ``clouds`` keep the true times).

    Returns
    -------
    SimulatedBag
    """
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore


    scn = _as_scenario(scenario)
    if lidar3d is not None:
        scn = scn.replace(lidar3d=lidar3d)
    seed = scn.seed if seed is None else int(seed)
    if not np.isfinite(clock_offset) or abs(clock_offset) > 1.0:
        raise ConfigError(f"clock_offset must be within 1 s, got {clock_offset}")
    if int(cloud_every) < 1 or not 0.0 <= cloud_offset < 1.0 or not scan_rate > 0 or not odom_rate > 0:
        raise ConfigError(f"cloud_every must be >= 1, cloud_offset in [0, 1), rates > 0; got {cloud_every}, "
                          f"{cloud_offset}, {scan_rate}, {odom_rate}")
    if scn.lidar2d.scan_time * scan_rate > 1.0 + 1e-9:
        raise ConfigError(f"lidar2d.scan_time ({scn.lidar2d.scan_time:g} s) must not outlast the scan period "
                          f"1 / scan_rate = {1.0 / scan_rate:g} s")
    out = Path(out)
    lone = out.suffix in (".mcap", ".db3")
    folder = out.with_name(out.stem + ".bagdir") if lone else out
    for p in (out, folder):
        if p.is_dir():
            shutil.rmtree(p)
        elif p.exists():
            p.unlink()

    motion = simulate_motion(scn.start, scn.steps, scn.robot, scn.odometry, scan_rate,
                             np.random.default_rng([seed, 1]), start_time)
    world = World(scn)
    l2, l3 = scn.lidar2d, scn.lidar3d
    end = motion.sample_times[-1] if duration is None else min(motion.sample_times[-1], start_time + float(duration))
    keep = motion.stamps <= end + 1e-9
    scan_t, scan_gt = motion.stamps[keep], motion.groundtruth[keep]
    cloud_t = scan_t[:: int(cloud_every)] + float(cloud_offset) / scan_rate
    cloud_t = cloud_t[cloud_t <= end]
    cloud_gt = sample_legs(motion.legs, cloud_t)
    odom_t = np.arange(motion.sample_times[0], end + 1e-9, 1.0 / odom_rate)
    odom_xy = np.column_stack([np.interp(odom_t, motion.sample_times, motion.sample_odometry[:, k]) for k in (0, 1)])
    odom_yaw = np.interp(odom_t, motion.sample_times, np.unwrap(motion.sample_odometry[:, 2]))

    # the frames: the sim's 3D sensor frame S is os_lidar turned back half a turn about z
    T_base_S = pose_to_matrix(l3.extrinsic())
    T_S_L = pose_to_matrix([0, 0, 0, 0, 0, math.pi])
    T_base_L = T_base_S @ T_S_L
    T_base_os = T_base_L @ invert_matrix(pose_to_matrix(OS_LIDAR_IN_SENSOR))
    ext2 = l2.extrinsic()
    dirs_L = l3.directions() @ T_S_L[:3, :3]  # beam directions in os_lidar (R^T d, row vectors)

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types

    def header(t: float, frame: str):
        sec = int(math.floor(t))
        return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((t - sec) * 1e9)) % 1_000_000_000),
                                        frame_id=frame)

    def quat(R):
        q = matrix_to_quaternion(R)
        return T["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))

    def vec(v, name="geometry_msgs/msg/Vector3"):
        return T[name](x=float(v[0]), y=float(v[1]), z=float(v[2]))

    def transform(t, parent, child, M):
        tr = T["geometry_msgs/msg/Transform"](translation=vec(M[:3, 3]), rotation=quat(M[:3, :3]))
        return T["geometry_msgs/msg/TransformStamped"](header=header(t, parent), child_frame_id=child, transform=tr)

    def planar(x, y, yaw, z=0.0):
        return pose_to_matrix([x, y, z, 0.0, 0.0, yaw])

    fields = [T["sensor_msgs/msg/PointField"](name=n, offset=int(OUSTER_POINT.fields[n][1]),
                                               datatype=_FIELD_TYPES[OUSTER_POINT.fields[n][0].str], count=1)
              for n in OUSTER_POINT.names]
    C, W = l3.channels, l3.columns
    angles = l2.angles()

    # every message in time order: (stamp, kind, index)
    events = [(t, "odom", k) for k, t in enumerate(odom_t)] + [(t, "scan", k) for k, t in enumerate(scan_t)]
    events += [(t, "cloud", k) for k, t in enumerate(cloud_t)]
    events.sort(key=lambda e: (e[0], e[1]))
    counts = {"/scan": 0, "/ouster/points": 0, "/odom": 0, "/tf": 0, "/tf_static": 0}
    scan_rngs = noise_rngs(seed, 2, range(len(scan_t)))
    cloud_rngs = noise_rngs(seed, 3, range(len(cloud_t)))
    sway = None
    if l3.sway_frequency > 0:
        sway = mast_sway(motion.legs, (cloud_t[:, None] + l3.column_times()[None, :]).reshape(-1), l3.position[:2],
                         l3.position[2], l3.sway_frequency, l3.sway_damping).reshape(len(cloud_t), l3.columns, 2)
    plugin = StoragePlugin.SQLITE3 if out.suffix == ".db3" else StoragePlugin.MCAP
    with Writer(folder, version=9, storage_plugin=plugin) as w:
        conn = {topic: w.add_connection(topic, msgtype, typestore=ts) for topic, msgtype in (
            ("/tf_static", "tf2_msgs/msg/TFMessage"), ("/tf", "tf2_msgs/msg/TFMessage"),
            ("/odom", "nav_msgs/msg/Odometry"), ("/scan", "sensor_msgs/msg/LaserScan"),
            ("/ouster/points", "sensor_msgs/msg/PointCloud2"))}

        def put(topic, t, msg, msgtype):
            w.write(conn[topic], int(round(t * 1e9)), ts.serialize_cdr(msg, msgtype))
            counts[topic] += 1

        t0 = float(scan_t[0]) - 0.5
        if tf:
            statics = [transform(t0, "base_link", "laser", planar(ext2[0], ext2[1], ext2[2], l2.height)),
                       transform(t0, "base_link", "os_sensor", T_base_os),
                       transform(t0, "os_sensor", "os_lidar", pose_to_matrix(OS_LIDAR_IN_SENSOR))]
            put("/tf_static", t0, T["tf2_msgs/msg/TFMessage"](transforms=statics), "tf2_msgs/msg/TFMessage")
        for t, kind, k in events:
            if kind == "odom":
                x, y, yaw = odom_xy[k, 0], odom_xy[k, 1], odom_yaw[k]
                M = planar(x, y, yaw)
                pose = T["geometry_msgs/msg/Pose"](position=vec([x, y, 0.0], "geometry_msgs/msg/Point"),
                                                   orientation=quat(M[:3, :3]))
                odo = T["nav_msgs/msg/Odometry"](
                    header=header(t, "odom"), child_frame_id="base_link",
                    pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
                    twist=T["geometry_msgs/msg/TwistWithCovariance"](
                        twist=T["geometry_msgs/msg/Twist"](linear=vec([0, 0, 0]), angular=vec([0, 0, 0])),
                        covariance=np.zeros(36)))
                put("/odom", t, odo, "nav_msgs/msg/Odometry")
                put("/tf", t, T["tf2_msgs/msg/TFMessage"](transforms=[transform(t, "odom", "base_link", M)]),
                    "tf2_msgs/msg/TFMessage")
            elif kind == "scan":
                if l2.scan_time == 0:
                    r = world.scan2d(scan_gt[k : k + 1], l2, [scan_rngs[k]])[0].astype(np.float32)
                else:
                    r = rolling_scan2d(world, motion.legs, [t], l2, [scan_rngs[k]])[0]
                r[~np.isfinite(r)] = np.inf
                msg = T["sensor_msgs/msg/LaserScan"](
                    header=header(t, "laser"), angle_min=float(angles[0]), angle_max=float(angles[-1]),
                    angle_increment=float(angles[1] - angles[0]), time_increment=l2.time_increment,
                    scan_time=l2.scan_time if l2.scan_time > 0 else 1.0 / scan_rate,
                    range_min=float(l2.range_min), range_max=float(l2.range_max), ranges=r,
                    intensities=np.zeros(0, dtype=np.float32))
                put("/scan", t, msg, "sensor_msgs/msg/LaserScan")
            else:
                if l3.static:
                    img = world.scan3d(cloud_gt[k : k + 1], l3, [cloud_rngs[k]])[0].astype(float)
                else:
                    img = rolling_scan3d(world, motion.legs, [t], l3, [cloud_rngs[k]], None,
                                         None if sway is None else sway[k : k + 1])[0].astype(float)
                data = ouster_cloud_bytes(np.nan_to_num(img)[..., None] * dirs_L, img,
                                          l3.column_times() if l3.sweep_time > 0 else None)
                msg = T["sensor_msgs/msg/PointCloud2"](
                    header=header(t + float(clock_offset), "os_lidar"), height=C, width=W, fields=fields, is_bigendian=False,
                    point_step=OUSTER_POINT.itemsize, row_step=OUSTER_POINT.itemsize * W, data=data, is_dense=False)
                put("/ouster/points", t, msg, "sensor_msgs/msg/PointCloud2")
    if lone:
        stores = list(folder.glob(f"*{out.suffix}"))
        if len(stores) != 1:
            raise DatasetError(f"{folder}: expected one {out.suffix} storage file, found {len(stores)}")
        stores[0].rename(out)
        shutil.rmtree(folder)
    return SimulatedBag(
        path=out, scans=Trajectory(scan_t, scan_gt), clouds=Trajectory(cloud_t, cloud_gt),
        doors=layout.door_records(scn), rooms=[r.name for r in scn.rooms],
        extrinsic2d=np.asarray(ext2, dtype=float), extrinsic3d=matrix_to_pose(T_base_L),
        messages={k: v for k, v in counts.items() if v})
