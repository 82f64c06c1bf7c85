"""A ROS1 bag made from a simulated dataset, as a robot would record it: /scan (LaserScan), /points (PointCloud2,
x y z float32) and /tf_static (base_link -> laser, base_link -> velodyne), no ground truth and no odometry. For
tests of what hsmap does with a user's recording."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from rosbags.rosbag1 import Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from hsmap.datasets.simulated import SimulatedDataset
from hsmap.geometry import euler_to_matrix, matrix_to_quaternion


def simulated_bag(ds: SimulatedDataset, path: Path, frames: int, t_offset: float = 1000.0) -> Path:
    """Write the first ``frames`` frames of ``ds`` to a ROS1 bag at ``path``, stamps moved by ``t_offset``
    seconds (a bag's times are positive)."""
    ts = get_typestore(Stores.ROS1_NOETIC)
    ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"))
    T = ts.types

    def header(t: float, frame: str, seq: int = 0):
        sec = int(math.floor(t))
        stamp = T["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((t - sec) * 1e9)))
        return T["std_msgs/msg/Header"](seq=seq, stamp=stamp, frame_id=frame)

    def transform(parent: str, child: str, t: float, x, y, z, roll, pitch, yaw):
        q = matrix_to_quaternion(euler_to_matrix(roll, pitch, yaw))
        tr = T["geometry_msgs/msg/Transform"](translation=T["geometry_msgs/msg/Vector3"](x=x, y=y, z=z),
                                              rotation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2],
                                                                                          w=q[3]))
        return T["geometry_msgs/msg/TransformStamped"](header=header(t, parent), child_frame_id=child, transform=tr)

    s2 = ds.sensors["lidar2d"]
    e2, e3 = ds.extrinsic2d, ds.extrinsic3d
    angles = ds.angles
    inc = float(angles[1] - angles[0])
    PF = T["sensor_msgs/msg/PointField"]
    fields = [PF(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate("xyz")]
    t0 = float(ds.stamps[0]) + t_offset
    with Writer(path) as w:
        c_tf = w.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=ts)
        c_scan = w.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=ts)
        c_pts = w.add_connection("/points", "sensor_msgs/msg/PointCloud2", typestore=ts)
        tf = T["tf2_msgs/msg/TFMessage"](transforms=[
            transform("base_link", "laser", t0, float(e2[0]), float(e2[1]), float(s2["mount_height"]), 0.0, 0.0,
                      float(e2[2])),
            transform("base_link", "velodyne", t0, *map(float, e3)),
        ])
        w.write(c_tf, int((t0 - 0.5) * 1e9), ts.serialize_ros1(tf, "tf2_msgs/msg/TFMessage"))
        for k in range(frames):
            t = float(ds.stamps[k]) + t_offset
            scan = ds.scan2d(k)
            msg = T["sensor_msgs/msg/LaserScan"](
                header=header(t, "laser", k), angle_min=float(angles[0]), angle_max=float(angles[-1]),
                angle_increment=inc, time_increment=0.0, scan_time=0.0, range_min=float(scan.range_min),
                range_max=float(scan.range_max), ranges=np.nan_to_num(scan.ranges, nan=np.inf).astype(np.float32),
                intensities=np.zeros(0, dtype=np.float32))
            w.write(c_scan, int(t * 1e9) + 1000, ts.serialize_ros1(msg, "sensor_msgs/msg/LaserScan"))
            pts = ds.cloud3d(k).astype(np.float32)
            cloud = T["sensor_msgs/msg/PointCloud2"](
                header=header(t, "velodyne", k), height=1, width=len(pts), fields=fields, is_bigendian=False,
                point_step=12, row_step=12 * len(pts), data=np.frombuffer(pts.tobytes(), dtype=np.uint8),
                is_dense=True)
            w.write(c_pts, int(t * 1e9) + 2000, ts.serialize_ros1(cloud, "sensor_msgs/msg/PointCloud2"))
    return path
