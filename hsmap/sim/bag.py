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
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..errors import ConfigError, DatasetError
from ..geometry import invert_matrix, matrix_to_pose, matrix_to_quaternion, pose_to_matrix
from ..trajectory import Trajectory
from . import layout
from .robot import Motion, mast_sway, sample_legs, simulate_motion
from .scenario import Scenario
from .sensors import Lidar3DConfig
from .world import World
from .writer import _as_scenario, noise_rngs, rolling_scan2d, rolling_scan3d

__all__ = ["OUSTER_POINT", "BagConfig", "SimulatedBag", "write_simulated_bag", "ouster_cloud_bytes"]

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


@dataclass(frozen=True)
class BagConfig:
    """How :func:`write_simulated_bag` records a run: the sensors' rates and clocks and what it writes.

    Attributes
    ----------
    scan_rate : float
        Hz of the 2D scans.
    cloud_every : int
        One cloud per this many scan periods (4: the 3D LiDAR at a quarter of the 2D rate).
    cloud_offset : float
        Where in its scan period a cloud is taken (0 <= offset < 1).
    odom_rate : float
        Hz of the odometry and its TF.
    tf : bool
        Write the sensors' transforms on ``/tf_static``.
    start_time : float
        Unix time of the first scan.
    duration : float, optional
        Seconds of the route to record (default all of it).
    clock_offset : float
        Seconds the 3D LiDAR's clock runs ahead of the 2D LiDAR's and the odometry's: its clouds are stamped
        that much late (the returned ``clouds`` keep the true times).
    """

    scan_rate: float = 8.0
    cloud_every: int = 4
    cloud_offset: float = 0.4
    odom_rate: float = 20.0
    tf: bool = True
    start_time: float = 1_700_000_000.0
    duration: float | None = None
    clock_offset: float = 0.0

    def check(self, scn: Scenario) -> None:
        """Raise ConfigError, naming the setting, where it cannot record ``scn``."""
        if not np.isfinite(self.clock_offset) or abs(self.clock_offset) > 1.0:
            raise ConfigError(f"clock_offset must be within 1 s, got {self.clock_offset}")
        if (int(self.cloud_every) < 1 or not 0.0 <= self.cloud_offset < 1.0 or not self.scan_rate > 0
                or not self.odom_rate > 0):
            raise ConfigError(f"cloud_every must be >= 1, cloud_offset in [0, 1), rates > 0; got {self.cloud_every}, "
                              f"{self.cloud_offset}, {self.scan_rate}, {self.odom_rate}")
        if scn.lidar2d.scan_time * self.scan_rate > 1.0 + 1e-9:
            raise ConfigError(f"lidar2d.scan_time ({scn.lidar2d.scan_time:g} s) must not outlast the scan period "
                              f"1 / scan_rate = {1.0 / self.scan_rate:g} s")


@dataclass
class _Timeline:
    """The stamps of every message of a recording, with the ground truth and odometry at them."""

    scan_t: NDArray[np.float64]
    scan_gt: NDArray[np.float64]
    cloud_t: NDArray[np.float64]
    cloud_gt: NDArray[np.float64]
    odom_t: NDArray[np.float64]
    odom_xy: NDArray[np.float64]
    odom_yaw: NDArray[np.float64]

    @classmethod
    def of(cls, motion: Motion, cfg: BagConfig) -> _Timeline:
        end = (motion.sample_times[-1] if cfg.duration is None
               else min(motion.sample_times[-1], cfg.start_time + float(cfg.duration)))
        keep = motion.stamps <= end + 1e-9
        scan_t, scan_gt = motion.stamps[keep], motion.groundtruth[keep]
        cloud_t = scan_t[:: int(cfg.cloud_every)] + float(cfg.cloud_offset) / cfg.scan_rate
        cloud_t = cloud_t[cloud_t <= end]
        cloud_gt = sample_legs(motion.legs, cloud_t)
        odom_t = np.arange(motion.sample_times[0], end + 1e-9, 1.0 / cfg.odom_rate)
        odom_xy = np.column_stack([np.interp(odom_t, motion.sample_times, motion.sample_odometry[:, k])
                                   for k in (0, 1)])
        odom_yaw = np.interp(odom_t, motion.sample_times, np.unwrap(motion.sample_odometry[:, 2]))
        return cls(scan_t, scan_gt, cloud_t, cloud_gt, odom_t, odom_xy, odom_yaw)

    def events(self) -> list[tuple[float, str, int]]:
        """Every message in time order: (stamp, kind, index)."""
        events = [(t, "odom", k) for k, t in enumerate(self.odom_t)]
        events += [(t, "scan", k) for k, t in enumerate(self.scan_t)]
        events += [(t, "cloud", k) for k, t in enumerate(self.cloud_t)]
        events.sort(key=lambda e: (e[0], e[1]))
        return events


class _Messages:
    """ROS2 messages of a simulated robot: headers, transforms, odometry, scans and Ouster clouds."""

    def __init__(self, ts) -> None:
        self.T = ts.types
        self.fields = [self.T["sensor_msgs/msg/PointField"](
            name=n, offset=int(OUSTER_POINT.fields[n][1]), datatype=_FIELD_TYPES[OUSTER_POINT.fields[n][0].str],
            count=1) for n in OUSTER_POINT.names]

    def header(self, t: float, frame: str):
        sec = int(math.floor(t))
        stamp = self.T["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((t - sec) * 1e9)) % 1_000_000_000)
        return self.T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

    def quat(self, R):
        q = matrix_to_quaternion(R)
        return self.T["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))

    def vec(self, v, name="geometry_msgs/msg/Vector3"):
        return self.T[name](x=float(v[0]), y=float(v[1]), z=float(v[2]))

    def transform(self, t, parent, child, M):
        tr = self.T["geometry_msgs/msg/Transform"](translation=self.vec(M[:3, 3]), rotation=self.quat(M[:3, :3]))
        return self.T["geometry_msgs/msg/TransformStamped"](header=self.header(t, parent), child_frame_id=child,
                                                             transform=tr)

    def tf(self, transforms):
        return self.T["tf2_msgs/msg/TFMessage"](transforms=transforms)

    def odometry(self, t, x, y, M):
        T = self.T
        pose = T["geometry_msgs/msg/Pose"](position=self.vec([x, y, 0.0], "geometry_msgs/msg/Point"),
                                           orientation=self.quat(M[:3, :3]))
        return T["nav_msgs/msg/Odometry"](
            header=self.header(t, "odom"), child_frame_id="base_link",
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](linear=self.vec([0, 0, 0]), angular=self.vec([0, 0, 0])),
                covariance=np.zeros(36)))

    def scan(self, t, l2, ranges, scan_rate):
        angles = l2.angles()
        return self.T["sensor_msgs/msg/LaserScan"](
            header=self.header(t, "laser"), angle_min=float(angles[0]), angle_max=float(angles[-1]),
            angle_increment=float(angles[1] - angles[0]), time_increment=l2.time_increment,
            scan_time=l2.scan_time if l2.scan_time > 0 else 1.0 / scan_rate,
            range_min=float(l2.range_min), range_max=float(l2.range_max), ranges=ranges,
            intensities=np.zeros(0, dtype=np.float32))

    def cloud(self, t, l3, data):
        W = l3.columns
        return self.T["sensor_msgs/msg/PointCloud2"](
            header=self.header(t, "os_lidar"), height=l3.channels, width=W, fields=self.fields,
            is_bigendian=False, point_step=OUSTER_POINT.itemsize, row_step=OUSTER_POINT.itemsize * W, data=data,
            is_dense=False)


#: The topics of a simulated bag and their message types, in the order the bag lists them.
_TOPICS = {"/tf_static": "tf2_msgs/msg/TFMessage", "/tf": "tf2_msgs/msg/TFMessage", "/odom": "nav_msgs/msg/Odometry",
           "/scan": "sensor_msgs/msg/LaserScan", "/ouster/points": "sensor_msgs/msg/PointCloud2"}


def _planar(x, y, yaw, z=0.0):
    return pose_to_matrix([x, y, z, 0.0, 0.0, yaw])


class _Recorder:
    """Simulates each sensor's message of a scenario's run and writes it to a bag."""

    def __init__(self, scn: Scenario, motion: Motion, timeline: _Timeline, cfg: BagConfig, seed: int) -> None:
        self.scn, self.motion, self.tl, self.cfg = scn, motion, timeline, cfg
        self.world = World(scn)
        l3 = scn.lidar3d
        # the frames: the sim's 3D sensor frame S is os_lidar turned back half a turn about z
        T_S_L = pose_to_matrix([0, 0, 0, 0, 0, math.pi])
        self.T_base_L = pose_to_matrix(l3.extrinsic()) @ T_S_L
        self.T_base_os = self.T_base_L @ invert_matrix(pose_to_matrix(OS_LIDAR_IN_SENSOR))
        self.ext2 = scn.lidar2d.extrinsic()
        self.dirs_L = l3.directions() @ T_S_L[:3, :3]  # beam directions in os_lidar (R^T d, row vectors)
        self.scan_rngs = noise_rngs(seed, 2, range(len(timeline.scan_t)))
        self.cloud_rngs = noise_rngs(seed, 3, range(len(timeline.cloud_t)))
        self.sway = None
        if l3.sway_frequency > 0:
            cloud_t = timeline.cloud_t
            self.sway = mast_sway(motion.legs, (cloud_t[:, None] + l3.column_times()[None, :]).reshape(-1),
                                  l3.position[:2], l3.position[2], l3.sway_frequency,
                                  l3.sway_damping).reshape(len(cloud_t), l3.columns, 2)
        self.counts = {"/scan": 0, "/ouster/points": 0, "/odom": 0, "/tf": 0, "/tf_static": 0}

    def scan_ranges(self, t: float, k: int) -> NDArray[np.float32]:
        l2 = self.scn.lidar2d
        if l2.scan_time == 0:
            r = self.world.scan2d(self.tl.scan_gt[k : k + 1], l2, [self.scan_rngs[k]])[0].astype(np.float32)
        else:
            r = rolling_scan2d(self.world, self.motion.legs, [t], l2, [self.scan_rngs[k]])[0]
        r[~np.isfinite(r)] = np.inf
        return r

    def cloud_data(self, t: float, k: int) -> NDArray[np.uint8]:
        l3 = self.scn.lidar3d
        if l3.static:
            img = self.world.scan3d(self.tl.cloud_gt[k : k + 1], l3, [self.cloud_rngs[k]])[0].astype(float)
        else:
            img = rolling_scan3d(self.world, self.motion.legs, [t], l3, [self.cloud_rngs[k]], None,
                                 None if self.sway is None else self.sway[k : k + 1])[0].astype(float)
        return ouster_cloud_bytes(np.nan_to_num(img)[..., None] * self.dirs_L, img,
                                  l3.column_times() if l3.sweep_time > 0 else None)

    def write(self, folder: Path, plugin) -> None:
        from rosbags.rosbag2 import Writer
        from rosbags.typesys import Stores, get_typestore

        ts = get_typestore(Stores.ROS2_HUMBLE)
        m = _Messages(ts)
        with Writer(folder, version=9, storage_plugin=plugin) as w:
            conn = {topic: w.add_connection(topic, msgtype, typestore=ts) for topic, msgtype in _TOPICS.items()}

            def put(topic, t, msg):
                w.write(conn[topic], int(round(t * 1e9)), ts.serialize_cdr(msg, _TOPICS[topic]))
                self.counts[topic] += 1

            self._write_messages(m, put)

    def _write_messages(self, m: _Messages, put) -> None:
        l2, l3, tl, ext2 = self.scn.lidar2d, self.scn.lidar3d, self.tl, self.ext2
        t0 = float(tl.scan_t[0]) - 0.5
        if self.cfg.tf:
            statics = [m.transform(t0, "base_link", "laser", _planar(ext2[0], ext2[1], ext2[2], l2.height)),
                       m.transform(t0, "base_link", "os_sensor", self.T_base_os),
                       m.transform(t0, "os_sensor", "os_lidar", pose_to_matrix(OS_LIDAR_IN_SENSOR))]
            put("/tf_static", t0, m.tf(statics))
        for t, kind, k in tl.events():
            if kind == "odom":
                x, y, yaw = tl.odom_xy[k, 0], tl.odom_xy[k, 1], tl.odom_yaw[k]
                M = _planar(x, y, yaw)
                put("/odom", t, m.odometry(t, x, y, M))
                put("/tf", t, m.tf([m.transform(t, "odom", "base_link", M)]))
            elif kind == "scan":
                put("/scan", t, m.scan(t, l2, self.scan_ranges(t, k), self.cfg.scan_rate))
            else:
                put("/ouster/points", t, m.cloud(t + float(self.cfg.clock_offset), l3, self.cloud_data(t, k)))


def _clear(out: Path, folder: Path) -> None:
    for p in (out, folder):
        if p.is_dir():
            shutil.rmtree(p)
        elif p.exists():
            p.unlink()


def _to_lone_file(folder: Path, out: Path) -> None:
    """Move the one storage file of the bag folder to ``out`` and remove the folder."""
    stores = list(folder.glob(f"*{out.suffix}"))
    if len(stores) != 1:
        raise DatasetError(f"{folder}: expected one {out.suffix} storage file, found {len(stores)}")
    stores[0].rename(out)
    shutil.rmtree(folder)


def write_simulated_bag(
    scenario: Scenario | str | os.PathLike,
    out: str | os.PathLike,
    *,
    seed: int | None = None,
    lidar3d: Lidar3DConfig | None = None,
    config: BagConfig | None = None,
    **settings,
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
    lidar3d : Lidar3DConfig, optional
        The 3D LiDAR instead of the scenario's (a smaller one for quick runs).
    config : BagConfig, optional
        Rates, clocks and what is written (default :class:`BagConfig`'s).
    **settings
        :class:`BagConfig` fields by name (``scan_rate=4.0``, ``duration=2.0``, ...), over ``config``'s.

    Returns
    -------
    SimulatedBag
    """
    from rosbags.rosbag2 import StoragePlugin

    scn = _as_scenario(scenario)
    if lidar3d is not None:
        scn = scn.replace(lidar3d=lidar3d)
    seed = scn.seed if seed is None else int(seed)
    cfg = replace(config or BagConfig(), **settings)
    cfg.check(scn)
    out = Path(out)
    lone = out.suffix in (".mcap", ".db3")
    folder = out.with_name(out.stem + ".bagdir") if lone else out
    _clear(out, folder)
    motion = simulate_motion(scn.start, scn.steps, scn.robot, scn.odometry, cfg.scan_rate,
                             np.random.default_rng([seed, 1]), cfg.start_time)
    tl = _Timeline.of(motion, cfg)
    rec = _Recorder(scn, motion, tl, cfg, seed)
    rec.write(folder, StoragePlugin.SQLITE3 if out.suffix == ".db3" else StoragePlugin.MCAP)
    if lone:
        _to_lone_file(folder, out)
    return SimulatedBag(
        path=out, scans=Trajectory(tl.scan_t, tl.scan_gt), clouds=Trajectory(tl.cloud_t, tl.cloud_gt),
        doors=layout.door_records(scn), rooms=[r.name for r in scn.rooms],
        extrinsic2d=np.asarray(rec.ext2, dtype=float), extrinsic3d=matrix_to_pose(rec.T_base_L),
        messages={k: v for k, v in rec.counts.items() if v})
