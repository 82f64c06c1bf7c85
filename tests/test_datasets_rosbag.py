"""ROS1/ROS2 bag reader: bags written here with rosbags' writers, and the Freiburg bags when available."""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pytest
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

import hsmap.datasets.rosbag as rosbag_mod
from hsmap.datasets.open import open_dataset
from hsmap.datasets.rosbag import FrameOrder, RosbagDataset, adopt_odometry, pointcloud2_xyz
from hsmap.errors import ConfigError, DataFormatError, DatasetError, HsmapWarning, InputError, ShapeError
from hsmap.geometry import euler_to_matrix, matrix_to_quaternion, pose_to_matrix, transform_points

# The synthetic recording: the robot moves with constant velocity, so linear interpolation of odometry is exact.
V = np.array([0.5, 0.2, 0.3])  # x, y (m/s), yaw (rad/s)
T0 = 100.0
SCAN_DT, ODOM_DT, N_SCANS = 0.1, 0.04, 12
ANGLE_MIN, ANGLE_INC = -1.5, 0.5  # 7 beams from -1.5 to 1.5 rad
LASER_EXT = (0.1, 0.05, 0.2)  # x, y, yaw of the laser on base_link
CLOUD_EXT = (0.0, 0.0, 0.5, 0.01, -0.02, 0.1)  # x, y, z, roll, pitch, yaw of the 3D lidar
# one scan's ranges: valid, NaN, +inf, the SICK "no return" 81.83, below range_min, exactly 80 (no return), valid
RANGES = np.array([1.0, np.nan, np.inf, 81.83, 0.05, 80.0, 2.5], dtype=np.float32)
VALID = np.array([True, False, False, False, False, False, True])


def pose_at(t: float) -> np.ndarray:
    return V * (t - T0)


def cloud_points(k: int) -> np.ndarray:
    pts = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.5], [np.nan, 1.0, 1.0], [3.0, -1.0, float(k)]], dtype=np.float32)
    return pts


def _typestore(ros2: bool):
    if ros2:
        return get_typestore(Stores.ROS2_HUMBLE)
    ts = get_typestore(Stores.ROS1_NOETIC)
    ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"))
    return ts


class _Msgs:
    """Builds messages for one typestore (ROS1 headers have a seq, ROS2 ones do not)."""

    def __init__(self, ts, ros2: bool) -> None:
        self.ts, self.ros2 = ts, ros2

    def header(self, t: float, frame: str, seq: int = 0):
        T = self.ts.types
        sec = int(math.floor(t))
        stamp = T["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((t - sec) * 1e9)))
        if self.ros2:
            return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)
        return T["std_msgs/msg/Header"](seq=seq, stamp=stamp, frame_id=frame)

    def quat(self, roll, pitch, yaw):
        q = matrix_to_quaternion(euler_to_matrix(roll, pitch, yaw))
        return self.ts.types["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3])

    def vec(self, x, y, z, name="geometry_msgs/msg/Vector3"):
        return self.ts.types[name](x=float(x), y=float(y), z=float(z))

    def scan(self, t, seq, ranges=RANGES):
        return self.ts.types["sensor_msgs/msg/LaserScan"](
            header=self.header(t, "laser", seq),
            angle_min=ANGLE_MIN,
            angle_max=ANGLE_MIN + ANGLE_INC * (len(ranges) - 1),
            angle_increment=ANGLE_INC,
            time_increment=0.0,
            scan_time=0.1,
            range_min=0.1,
            range_max=80.0,
            ranges=np.asarray(ranges, dtype=np.float32),
            intensities=np.zeros(0, dtype=np.float32),
        )

    def odom(self, t, seq, offset=0.0, late=0.0):
        T = self.ts.types
        x, y, yaw = pose_at(t) + offset
        pose = T["geometry_msgs/msg/Pose"](position=self.vec(x, y, 0, "geometry_msgs/msg/Point"), orientation=self.quat(0, 0, yaw))
        twist = T["geometry_msgs/msg/Twist"](linear=self.vec(*V[:2], 0), angular=self.vec(0, 0, V[2]))
        return T["nav_msgs/msg/Odometry"](
            header=self.header(t + late, "odom", seq),
            child_frame_id="base_link",
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)),
        )

    def tf(self, t, edges):
        T = self.ts.types
        out = []
        for parent, child, pose in edges:
            x, y, z = pose[:3]
            if len(pose) == 7:  # a quaternion as given (x, y, z, qx, qy, qz, qw)
                rot = self.ts.types["geometry_msgs/msg/Quaternion"](x=pose[3], y=pose[4], z=pose[5], w=pose[6])
            else:
                rot = self.quat(*pose[3:])
            tr = T["geometry_msgs/msg/Transform"](translation=self.vec(x, y, z), rotation=rot)
            out.append(T["geometry_msgs/msg/TransformStamped"](header=self.header(t, parent), child_frame_id=child, transform=tr))
        return T["tf2_msgs/msg/TFMessage"](transforms=out)

    def cloud(self, t, seq, pts):
        T = self.ts.types
        PF = T["sensor_msgs/msg/PointField"]
        # x, y, z float32 and an intensity float32 after a 4-byte gap: point_step 20
        rec = np.zeros(len(pts), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("pad", "<f4"), ("i", "<f4")])
        rec["x"], rec["y"], rec["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
        fields = [PF(name=n, offset=o, datatype=7, count=1) for n, o in (("x", 0), ("y", 4), ("z", 8), ("intensity", 16))]
        return T["sensor_msgs/msg/PointCloud2"](
            header=self.header(t, "velodyne", seq),
            height=1,
            width=len(pts),
            fields=fields,
            is_bigendian=False,
            point_step=20,
            row_step=20 * len(pts),
            data=np.frombuffer(rec.tobytes(), dtype=np.uint8),
            is_dense=False,
        )


def write_bag(
    path: Path,
    *,
    odom_offset: float = 0.0,
    ros2: bool = False,
    scan_stamps=None,
    clouds: bool = True,
    static_tf: bool = True,
    extra_scan_topic: bool = False,
    mcap: bool = False,
    laser_roll: float = 0.0,
    laser_quaternion: tuple[float, float, float, float] | None = None,
    nan_odom: tuple[int, ...] = (),
    sensor_tf: bool = True,
    odom_late: dict[int, float] | None = None,
) -> Path:
    """A small bag: /scan (LaserScan), /odom (Odometry at its own rate), /tf_static, /tf, /points (PointCloud2).

    ``scan_stamps`` (in seq order) default to a regular 10 Hz sequence; ROS1 seq is the scan's position.
    ``laser_quaternion`` replaces the laser's rotation in the TF (as given, unnormalised); the odometry messages
    numbered in ``nan_odom`` get a NaN x; odometry message k of ``odom_late`` is stamped that many seconds after
    the time of its pose (a receive stamp of a message delivered late).
    """
    ts = _typestore(ros2)
    m = _Msgs(ts, ros2)
    if scan_stamps is None:
        scan_stamps = T0 + SCAN_DT * np.arange(N_SCANS)
    records = []  # (bag time, topic, msgtype, message)
    odom_t = np.arange(T0 - 0.2, T0 + SCAN_DT * N_SCANS + 0.2, ODOM_DT)
    for k, t in enumerate(odom_t):
        offset = np.array([np.nan, 0.0, 0.0]) if k in nan_odom else odom_offset
        late = (odom_late or {}).get(k, 0.0)
        records.append((t + late, "/odom", "nav_msgs/msg/Odometry", m.odom(t, k, offset, late)))
        records.append((t, "/tf", "tf2_msgs/msg/TFMessage", m.tf(t, [("odom", "base_link", (*pose_at(t)[:2], 0, 0, 0, pose_at(t)[2]))])))
    edges = [
        ("base_link", "laser", (LASER_EXT[0], LASER_EXT[1], 0.3, laser_roll, 0, LASER_EXT[2])
                               if laser_quaternion is None else (LASER_EXT[0], LASER_EXT[1], 0.3, *laser_quaternion)),
        ("base_link", "velodyne", CLOUD_EXT),
    ]
    if not sensor_tf:
        pass
    elif static_tf:
        records.append((T0 - 1.0, "/tf_static", "tf2_msgs/msg/TFMessage", m.tf(T0 - 1.0, edges)))
    else:  # extrinsics only on /tf, published once
        records.append((T0 - 0.5, "/tf", "tf2_msgs/msg/TFMessage", m.tf(T0 - 0.5, edges)))
    for k, t in enumerate(scan_stamps):
        # the bag stores messages at their receive time: scan k is received in seq order
        recv = T0 + SCAN_DT * k + 0.001
        records.append((recv, "/scan", "sensor_msgs/msg/LaserScan", m.scan(t, k)))
        if extra_scan_topic:
            records.append((recv, "/scan2", "sensor_msgs/msg/LaserScan", m.scan(t, k)))
        if clouds and k != 5:  # no cloud near scan 5
            records.append((recv + 0.0005, "/points", "sensor_msgs/msg/PointCloud2", m.cloud(t + 0.002, k, cloud_points(k))))
    records.sort(key=lambda r: r[0])
    if ros2:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.MCAP if mcap else StoragePlugin.SQLITE3
        writer, serialize = Writer(path, version=9, storage_plugin=plugin), ts.serialize_cdr
    else:
        from rosbags.rosbag1 import Writer

        writer, serialize = Writer(path), ts.serialize_ros1
    conns = {}
    with writer as w:
        for t, topic, msgtype, msg in records:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, msgtype, typestore=ts)
            w.write(conns[topic], int(round(t * 1e9)), serialize(msg, msgtype))
    return path


@pytest.fixture(params=["ros1", "ros2-sqlite3", "ros2-mcap"])
def bag(request, tmp_path) -> Path:
    ros2 = request.param.startswith("ros2")
    return write_bag(tmp_path / ("small" if ros2 else "small.bag"), ros2=ros2, mcap=request.param.endswith("mcap"))


def test_reads_scans_odometry_extrinsics_and_clouds(bag):
    ds = open_dataset(bag, sync_tolerance=0.05)
    assert isinstance(ds, RosbagDataset)
    assert (ds.scan_topic, ds.cloud_topic, ds.odom_topic) == ("/scan", "/points", "/odom")
    frames = list(ds.frames())
    assert len(frames) == len(ds) == N_SCANS
    stamps = T0 + SCAN_DT * np.arange(N_SCANS)
    np.testing.assert_allclose([f.stamp for f in frames], stamps, atol=1e-9)
    assert [f.index for f in frames] == list(range(N_SCANS))
    for f in frames:
        # odometry interpolated at the scan stamp between 25 Hz messages: exact for constant velocity
        np.testing.assert_allclose(f.odometry, pose_at(f.stamp), atol=1e-9)
        np.testing.assert_allclose(f.extrinsic2d, LASER_EXT, atol=1e-9)
        np.testing.assert_allclose(f.extrinsic3d, CLOUD_EXT, atol=1e-9)
        s = f.scan2d
        np.testing.assert_allclose(s.angles, ANGLE_MIN + ANGLE_INC * np.arange(7), atol=1e-6)
        np.testing.assert_array_equal(np.isfinite(s.ranges), VALID)
        np.testing.assert_allclose(s.ranges[VALID], RANGES[VALID])
        assert s.range_max == pytest.approx(79.95)
        assert s.points().shape == (2, 2)
    np.testing.assert_allclose(frames[0].scan2d.points(), [[np.cos(-1.5), np.sin(-1.5)], [2.5 * np.cos(1.5), 2.5 * np.sin(1.5)]], atol=1e-6)
    # clouds: the NaN point dropped; none attached to scan 5 (no cloud within the sync tolerance)
    for k, f in enumerate(frames):
        if k == 5:
            assert f.cloud3d is None
        else:
            np.testing.assert_allclose(f.cloud3d, cloud_points(k)[[0, 1, 3]])
    assert ds.odometry is not None and len(ds.odometry) == N_SCANS
    if bag.is_dir():  # a ROS2 bag also opens from its storage file
        (storage,) = [f for f in bag.iterdir() if f.suffix in (".db3", ".mcap")]
        assert len(open_dataset(storage)) == N_SCANS
        alone = bag.parent / f"alone{storage.suffix}"  # and alone, without its folder
        storage.rename(alone)
        assert len(open_dataset(alone)) == N_SCANS


def test_ros1_and_ros2_give_the_same_frames(tmp_path):
    a = list(RosbagDataset(write_bag(tmp_path / "a.bag")).frames())
    b = list(RosbagDataset(write_bag(tmp_path / "b", ros2=True)).frames())
    assert len(a) == len(b)
    for fa, fb in zip(a, b, strict=True):
        assert fa.stamp == pytest.approx(fb.stamp, abs=1e-9)
        np.testing.assert_array_equal(fa.scan2d.ranges, fb.scan2d.ranges)
        np.testing.assert_allclose(fa.odometry, fb.odometry)


def test_fast_ros1_decoding_matches_rosbags_deserializer(tmp_path, monkeypatch):
    path = write_bag(tmp_path / "a.bag")
    fast = list(RosbagDataset(path).frames())
    monkeypatch.setattr(rosbag_mod, "_ROS1_SCAN_MD5", "disabled")
    monkeypatch.setattr(rosbag_mod, "_ROS1_ODOM_MD5", "disabled")
    slow = list(RosbagDataset(path).frames())
    for f, s in zip(fast, slow, strict=True):
        assert f.stamp == s.stamp
        np.testing.assert_array_equal(f.scan2d.ranges, s.scan2d.ranges)
        np.testing.assert_array_equal(f.scan2d.angles, s.scan2d.angles)
        np.testing.assert_array_equal(f.odometry, s.odometry)


def test_frames_follow_ros1_seq_when_stamps_go_backwards(tmp_path):
    # like the intel log: scan 3 was stamped late, after scan 4
    stamps = T0 + SCAN_DT * np.arange(N_SCANS)
    stamps[3] += 0.15
    path = write_bag(tmp_path / "jitter.bag", scan_stamps=stamps, clouds=False)
    ds = RosbagDataset(path)
    assert ds.order is FrameOrder.SEQ
    np.testing.assert_allclose(ds.stamps, stamps, atol=1e-9)  # seq order, original stamps kept
    f3 = list(ds.frames())[3]
    # its odometry is taken at the time it was made, not at its late stamp: a message was made before the next
    # one was received (stamped 0.4 s), and after the one before (0.2 s): the middle of the two, 0.3 s
    np.testing.assert_allclose(f3.odometry, pose_at(T0 + 3 * SCAN_DT), atol=1e-9)
    by_stamp = RosbagDataset(path, order="stamp")
    assert by_stamp.order is FrameOrder.STAMP
    np.testing.assert_allclose(by_stamp.stamps, np.sort(stamps), atol=1e-9)
    ros2 = RosbagDataset(write_bag(tmp_path / "jitter2", scan_stamps=stamps, clouds=False, ros2=True))
    assert ros2.order is FrameOrder.STAMP  # ROS2 headers have no seq
    with pytest.raises(DatasetError, match="seq"):
        RosbagDataset(tmp_path / "jitter2", order="seq")


def test_odometry_stamped_late_is_taken_in_the_order_it_was_made(tmp_path):
    """Like the intel log's /odom: receive stamps, some late, so that sorting the messages by stamp makes the
    robot jump back and forth (intel: 37 frame-to-frame odometry steps over 0.3 m and a 585 m path, against none
    and 508 m for the odometry CARMEN stored with each scan; with the messages in seq order at the times they
    were made, 4 steps and 508 m). In seq order, each made no later than the next was received, the poses are
    the smooth path."""
    # odometry every 0.04 s from T0 - 0.2; message 20 (the pose at T0 + 0.6) is stamped T0 + 0.81, after the
    # messages of T0 + 0.64 ... 0.8; 12 and 13 arrive in one burst with 14
    late = {12: 0.09, 13: 0.05, 20: 0.21}
    scans = T0 + SCAN_DT * np.arange(N_SCANS)
    scans[8] = T0 + 0.805  # between the late message's stamp and the one before it
    ds = RosbagDataset(write_bag(tmp_path / "late.bag", clouds=False, odom_late=late, scan_stamps=scans))
    for f in ds.frames():  # by stamp, scan 8 would get a pose halfway back to T0 + 0.6
        np.testing.assert_allclose(f.odometry, pose_at(f.stamp), atol=1e-9)


def test_production_times_are_the_stamps_when_in_order_and_bounded_by_later_receipts():
    from hsmap.datasets.rosbag import _monotone

    t = np.array([1.0, 1.1, 1.2, 1.3])
    np.testing.assert_array_equal(_monotone(t), t)  # in order: unchanged
    late = np.array([1.0, 1.1, 1.35, 1.3, 1.4, 1.2, 1.6])  # 1.35 came late; 1.2 was a burst's late stamp
    got = _monotone(late)
    assert (np.diff(got) >= 0).all() and (got <= late).all()
    # a message was made before every later one was received: 1.35 -> at most 1.3, the 1.4 and 1.3 made before
    # the receipt stamped 1.2, spread back to the 1.1 before them
    np.testing.assert_allclose(got, [1.0, 1.1, 1.125, 1.15, 1.175, 1.2, 1.6])


def test_extrinsics_from_dynamic_tf_when_no_static(tmp_path):
    ds = RosbagDataset(write_bag(tmp_path / "a.bag", static_tf=False))
    np.testing.assert_allclose(ds.extrinsic2d, LASER_EXT, atol=1e-9)
    np.testing.assert_allclose(ds.extrinsic3d, CLOUD_EXT, atol=1e-9)
    assert all(ds.extrinsic_found.values())


def test_adopt_odometry_of_the_same_scans(tmp_path):
    stamps = T0 + SCAN_DT * np.arange(N_SCANS)
    stamps[3] += 0.15
    orig = RosbagDataset(write_bag(tmp_path / "orig.bag", scan_stamps=stamps, clouds=False))
    other = RosbagDataset(write_bag(tmp_path / "other.bag", clouds=False, odom_offset=np.array([5.0, -2.0, 0.5])))  # other stamps
    adopt_odometry(orig, other)
    np.testing.assert_allclose(orig.stamps, stamps, atol=1e-9)  # own stamps kept
    np.testing.assert_allclose(orig.odometry.poses, [pose_at(t) + [5.0, -2.0, 0.5] for t in T0 + SCAN_DT * np.arange(N_SCANS)], atol=1e-9)
    np.testing.assert_allclose(list(orig.frames())[3].odometry, other.odometry.poses[3])
    fewer = RosbagDataset(write_bag(tmp_path / "fewer.bag", scan_stamps=stamps[:-1], clouds=False))
    with pytest.raises(DatasetError, match="not the same scans"):
        adopt_odometry(orig, fewer)
    ts = _typestore(False)
    m = _Msgs(ts, False)
    from rosbags.rosbag1 import Writer

    path = tmp_path / "different.bag"
    with Writer(path) as w:
        c = w.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=ts)
        for k, t in enumerate(stamps):
            w.write(c, int(t * 1e9), ts.serialize_ros1(m.scan(t, k, ranges=RANGES + (k == 7)), "sensor_msgs/msg/LaserScan"))
    with pytest.warns(HsmapWarning, match="no base frame"):  # a bare scan topic: no TF, no odometry
        different = RosbagDataset(path)
    with pytest.raises(DatasetError, match="frame 7 .* have different scans"):
        adopt_odometry(orig, different)


def test_upside_down_laser(tmp_path):
    ds = RosbagDataset(write_bag(tmp_path / "a.bag", clouds=False, laser_roll=math.pi))
    f = next(ds.frames())
    # beam end points through the full 3D mount, projected on the floor, equal the 2D frame's
    R = euler_to_matrix(math.pi, 0, LASER_EXT[2])
    a = ANGLE_MIN + ANGLE_INC * np.arange(7)
    sensor = np.column_stack([RANGES * np.cos(a), RANGES * np.sin(a), np.zeros(7)])[VALID]
    expected = (sensor @ R.T)[:, :2] + LASER_EXT[:2]
    np.testing.assert_allclose(transform_points(f.extrinsic2d, f.scan2d.points()), expected, atol=1e-6)


def test_topic_selection(tmp_path):
    path = write_bag(tmp_path / "a.bag", extra_scan_topic=True)
    with pytest.raises(DatasetError, match=r"several sensor_msgs/msg/LaserScan topics.*choose one with scan_topic"):
        RosbagDataset(path)
    # the messages name the caller's options (the command line's flags)
    with pytest.raises(DatasetError, match=r"choose one with --scan-topic \(or --scan-topic '' for none\)"):
        RosbagDataset(path, cloud_topic="/points", option_names={"scan_topic": "--scan-topic"})
    # topics are chosen independently: naming the scan topic keeps the (one) cloud topic
    ds = RosbagDataset(path, scan_topic="/scan2", odom_topic="", sync_tolerance=0.05)
    assert ds.scan_topic == "/scan2" and ds.cloud_topic == "/points" and ds.odom_topic is None
    frames = list(ds.frames())
    assert all(f.odometry is None for f in frames)
    assert [f.cloud3d is None for f in frames] == [k == 5 for k in range(N_SCANS)]
    assert ds.odometry is None
    no_clouds = RosbagDataset(path, scan_topic="/scan2", cloud_topic="")
    assert no_clouds.cloud_topic is None and all(f.cloud3d is None for f in no_clouds.frames())
    clouds_only = RosbagDataset(path, scan_topic="", cloud_topic="/points")
    assert clouds_only.scan_topic is None and len(clouds_only) == N_SCANS - 1
    f = next(clouds_only.frames())
    assert f.scan2d is None and f.cloud3d.shape == (3, 3)


def test_missing_topic_lists_the_bag_topics(bag):
    with pytest.raises(DatasetError) as err:
        open_dataset(bag, scan_topic="/front_scan")
    msg = str(err.value)
    assert "/front_scan" in msg
    for topic in ("/scan", "/odom", "/points", "/tf_static"):
        assert topic in msg
    with pytest.raises(DatasetError, match="is nav_msgs/msg/Odometry, expected sensor_msgs/msg/LaserScan"):
        RosbagDataset(bag, scan_topic="/odom")


def test_bag_without_sensor_topic(tmp_path):
    from rosbags.rosbag1 import Writer

    ts = _typestore(False)
    m = _Msgs(ts, False)
    path = tmp_path / "odom_only.bag"
    with Writer(path) as w:
        c = w.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=ts)
        w.write(c, 1, ts.serialize_ros1(m.odom(T0, 0), "nav_msgs/msg/Odometry"))
    with pytest.raises(DatasetError, match=r"no sensor_msgs/msg/LaserScan or sensor_msgs/msg/PointCloud2.*/odom"):
        RosbagDataset(path)


def test_corrupted_and_missing_bags(tmp_path):
    bad = tmp_path / "garbage.bag"
    bad.write_bytes(b"#ROSBAG V2.0\n" + bytes(range(256)) * 4)
    with pytest.raises(DatasetError, match="cannot read as a ROS1/ROS2 bag"):
        open_dataset(bad)
    with pytest.raises(DatasetError, match="no such"):
        open_dataset(tmp_path / "missing.bag")
    for suffix in (".mcap", ".db3"):  # lone ROS2 storage files: damaged ones name the file
        bad = tmp_path / f"garbage{suffix}"
        bad.write_bytes(bytes(range(256)) * 4)
        with pytest.raises(DatasetError, match=rf"garbage\{suffix}: cannot read as a ROS1/ROS2 bag"):
            open_dataset(bad)
    good = write_bag(tmp_path / "good.bag", clouds=False)
    truncated = tmp_path / "truncated.bag"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises((DatasetError, DataFormatError)):
        RosbagDataset(truncated)


def test_damaged_bags_raise_hsmap_errors_only(tmp_path, rng):
    """Random byte damage anywhere in a bag: either it still reads, or a DatasetError/DataFormatError."""
    data = write_bag(tmp_path / "good.bag", clouds=False).read_bytes()
    outcomes = set()
    for k in range(16):
        b = bytearray(data)
        off, n = int(rng.integers(0, len(b) - 64)), int(rng.integers(1, 64))
        b[off : off + n] = rng.integers(0, 256, size=n, dtype=np.uint8).tobytes()
        p = tmp_path / f"damaged{k}.bag"
        p.write_bytes(bytes(b))
        try:
            for _ in RosbagDataset(p).frames():
                pass
            outcomes.add("read")
        except (DatasetError, DataFormatError) as exc:
            outcomes.add(type(exc).__name__)
    assert {"DatasetError", "DataFormatError"} <= outcomes  # both kinds of damage were exercised


@pytest.mark.parametrize("q", [(0.0, 0.0, 0.0, 0.0), (0.0, 0.0, float("nan"), 1.0)])
def test_a_tf_quaternion_that_is_zero_or_not_finite_is_one_error_naming_bag_topic_and_frames(tmp_path, capsys, q):
    """An all-zero or non-finite quaternion in TF is one DataFormatError naming the bag, the topic and the frames,
    with no numpy warning before it (the suite turns warnings into errors), and one line from the command line."""
    from hsmap.cli import main

    b = write_bag(tmp_path / "q.bag", laser_quaternion=q)
    want = f"{b}: /tf_static transform base_link -> laser: rotation quaternion "
    with pytest.raises(DataFormatError, match="is zero or not finite$") as err:
        open_dataset(b)
    assert str(err.value).startswith(want), err.value
    assert main(["slam", str(b), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    assert capsys.readouterr().err.startswith(f"hsmap: error: {want}")


def test_odometry_messages_with_a_non_finite_pose_are_ignored_with_a_warning(tmp_path):
    from hsmap.errors import HsmapWarning

    b = write_bag(tmp_path / "o.bag", nan_odom=(3, 4))
    with pytest.warns(HsmapWarning, match=r"o\.bag: 2 /odom message\(s\) have a non-finite pose or stamp and are "
                                          "ignored"):
        ds = open_dataset(b)
    assert np.isfinite(ds.odometry.poses).all()
    np.testing.assert_allclose([f.odometry for f in ds.frames()], [pose_at(t) for t in ds.stamps], atol=1e-9)


def test_pointcloud2_with_row_padding_and_big_endian():
    ts = _typestore(True)
    T = ts.types
    PF = T["sensor_msgs/msg/PointField"]
    pts = np.arange(12, dtype=np.float64).reshape(2, 2, 3)  # height 2, width 2
    rows = []
    for r in range(2):
        rec = np.zeros(2, dtype=[("x", ">f8"), ("y", ">f8"), ("z", ">f8")])
        rec["x"], rec["y"], rec["z"] = pts[r, :, 0], pts[r, :, 1], pts[r, :, 2]
        rows.append(rec.tobytes() + b"\x00" * 8)  # row padding
    msg = T["sensor_msgs/msg/PointCloud2"](
        header=_Msgs(ts, True).header(1.0, "x"), height=2, width=2,
        fields=[PF(name=n, offset=8 * i, datatype=8, count=1) for i, n in enumerate("xyz")],
        is_bigendian=True, point_step=24, row_step=56, data=np.frombuffer(b"".join(rows), np.uint8), is_dense=True,
    )
    np.testing.assert_array_equal(pointcloud2_xyz(msg), pts.reshape(-1, 3))
    msg.fields = msg.fields[:2]
    with pytest.raises(DataFormatError, match="no field"):
        pointcloud2_xyz(msg)


# -- the Freiburg bags -------------------------------------------------------------------------------
@pytest.mark.datasets
@pytest.mark.parametrize(
    ("name", "bag", "n_scans", "expected"),
    [
        # README: raw odometry scored against the relations (mean, sample sd): m, deg
        pytest.param("intel", "intel/intel.orig.bag", 13631, (7.37, 14.46, 39.2, 53.8), marks=pytest.mark.slow),
        ("fr079", "fr079/fr079.orig.bag", 4934, (6.54, 13.66, 30.3, 45.5)),
    ],
)
def test_freiburg_odometry_baseline(datasets_dir, name, bag, n_scans, expected):
    from hsmap.datasets.relations import read_relations
    from hsmap.evaluation import relations_error

    root = datasets_dir / "slam2d"
    t = time.perf_counter()
    ds = open_dataset(root / bag)
    elapsed = time.perf_counter() - t
    assert len(ds) == n_scans and ds.order is FrameOrder.SEQ
    assert len(ds.odometry) == n_scans
    res = relations_error(ds.odometry, read_relations(root / name / f"{name}.relations")).as_dict()
    got = (res["translation_m"]["mean"], res["translation_m"]["std"], res["rotation_deg"]["mean"], res["rotation_deg"]["std"])
    # the README's figures use the odometry stored with each scan; /odom interpolated at the times the scans
    # were made gives intel 7.376 m / 39.27 deg (0.1 % and 0.2 % off), fr079 within 0.2 %
    np.testing.assert_allclose(got, expected, rtol=0.003)
    assert res["n_relations"] == len(read_relations(root / name / f"{name}.relations"))
    print(f"{name}: read {n_scans} scans in {elapsed:.2f} s; odometry {got}")


@pytest.mark.datasets
@pytest.mark.slow
def test_intel_scan_odometry_from_clf2bag_reproduces_the_readme(datasets_dir):
    """The README's odometry figures come from the odometry stored with each scan (clf2bag), joined by seq."""
    from hsmap.datasets.relations import read_relations
    from hsmap.evaluation import relations_error

    root = datasets_dir / "slam2d" / "intel"
    ds = adopt_odometry(open_dataset(root / "intel.orig.bag"), open_dataset(root / "intel.clf2bag.bag"))
    res = relations_error(ds.odometry, read_relations(root / "intel.relations")).as_dict()
    got = (res["translation_m"]["mean"], res["translation_m"]["std"], res["rotation_deg"]["mean"], res["rotation_deg"]["std"])
    np.testing.assert_allclose(got[:2], (7.37, 14.46), atol=0.005)  # the README's rounding
    np.testing.assert_allclose(got[2:], (39.2, 53.8), atol=0.05)
    steps = np.linalg.norm(np.diff(ds.odometry.poses[:, :2], axis=0), axis=1)
    assert steps.max() < 0.3  # no jumps from jittered stamps


@pytest.mark.datasets
def test_freiburg_bags_scan_content(datasets_dir):
    root = datasets_dir / "slam2d"
    ds = open_dataset(root / "fr-clinic" / "fr-clinic_robotlaser.orig.bag")
    assert len(ds) == 6917
    np.testing.assert_allclose(ds.extrinsic2d, [0.22, 0, 0], atol=1e-6)
    n_beams, masked, total = set(), 0, 0
    for f in ds.frames():
        n_beams.add(len(f.scan2d.ranges))
        masked += int(np.isnan(f.scan2d.ranges).sum())
        total += len(f.scan2d.ranges)
        assert np.nanmax(f.scan2d.ranges, initial=0) < 80.0
    assert n_beams == {180, 181}
    assert 0.12 < masked / total < 0.13  # README: 12.5 % of readings >= 81.8 m


def test_frames_driven_by_the_clouds(tmp_path):
    """A 6-DOF run wants one frame per cloud: the same bag seen from its clouds, the nearest scan attached."""
    ds = RosbagDataset(write_bag(tmp_path / "b", ros2=True, mcap=True))
    assert ds.driver == "scan" and len(ds) == N_SCANS
    clouds = ds.driven_by("cloud")
    assert clouds.driver == "cloud" and ds.driver == "scan"  # a view; the original is unchanged
    assert clouds.driven_by("cloud") is clouds and clouds.driven_by("scan").driver == "scan"
    cloud_stamps = T0 + SCAN_DT * np.delete(np.arange(N_SCANS), 5) + 0.002
    np.testing.assert_allclose(clouds.stamps, cloud_stamps, atol=1e-9)
    frames = list(clouds.frames())
    assert len(frames) == N_SCANS - 1
    for f, k in zip(frames, np.delete(np.arange(N_SCANS), 5), strict=True):
        np.testing.assert_allclose(f.cloud3d, cloud_points(k)[[0, 1, 3]])
        np.testing.assert_array_equal(np.isfinite(f.scan2d.ranges), VALID)  # the scan 2 ms before
        np.testing.assert_allclose(f.odometry, pose_at(f.stamp), atol=1e-9)  # odometry at the cloud's stamp
    # with the scans far apart, a cloud may have no scan: it is still a frame
    tight = RosbagDataset(ds.path, drive="cloud", sync_tolerance=0.001)
    assert len(tight) == N_SCANS - 1 and all(f.scan2d is None for f in tight.frames(clouds=False))
    info = clouds.describe()
    assert info["driven_by"] == "cloud" and info["frames"] == N_SCANS - 1 and info["frames_with_scan"] == N_SCANS - 1
    assert info["topics"]["scan"] == {"topic": "/scan", "type": "sensor_msgs/msg/LaserScan", "messages": N_SCANS,
                                      "frame_id": "laser", "rate_hz": pytest.approx(1 / SCAN_DT)}
    assert info["topics"]["cloud"]["messages"] == N_SCANS - 1 and info["topics"]["cloud"]["frame_id"] == "velodyne"
    assert info["topics"]["odom"]["rate_hz"] == pytest.approx(1 / ODOM_DT) and info["base_frame"] == "base_link"
    assert info["extrinsics"]["3d"] == {"value": pytest.approx(list(CLOUD_EXT)), "source": "tf"}
    assert info["tf_chains"] == {"2d": "base_link -> laser", "3d": "base_link -> velodyne"}
    assert info["warnings"] == []
    with pytest.raises(InputError, match="sensor must be 'scan' or 'cloud'"):
        ds.driven_by("lidar")
    no_clouds = RosbagDataset(ds.path, cloud_topic="", option_names={"cloud_topic": "--cloud-topic"})
    with pytest.raises(DatasetError, match="frames made by the clouds need a 3D cloud .* --cloud-topic"):
        no_clouds.driven_by("cloud")


def test_missing_transforms_warn_and_are_recorded(tmp_path):
    path = write_bag(tmp_path / "notf", ros2=True, sensor_tf=False)
    names = {"extrinsic2d": "--extrinsic2d", "extrinsic3d": "--extrinsic3d", "base_frame": "--base-frame"}
    with pytest.warns(HsmapWarning) as caught:
        ds = RosbagDataset(path, option_names=names)
    messages = [str(w.message) for w in caught]
    assert len(messages) == 2
    assert "no transform from the base frame 'base_link' to 'laser'" in messages[0]
    assert "give it with --extrinsic2d X,Y,YAW" in messages[0]
    assert "'velodyne' (the 3D clouds of /points)" in messages[1] and "--extrinsic3d X,Y,Z,ROLL,PITCH,YAW" in messages[1]
    np.testing.assert_array_equal(ds.extrinsic3d, np.zeros(6))
    info = ds.describe()
    assert info["extrinsics"]["2d"]["source"] == info["extrinsics"]["3d"]["source"] == "default"
    assert info["warnings"] == messages and info["tf_chains"] == {}
    # an offset given by the caller overrides TF, is recorded as such, and is not warned about
    with pytest.warns(HsmapWarning) as caught:
        given = RosbagDataset(path, extrinsic3d=CLOUD_EXT, option_names=names)
    assert len(caught) == 1 and "'laser'" in str(caught[0].message)
    assert given.describe()["extrinsics"]["3d"] == {"value": pytest.approx(list(CLOUD_EXT)), "source": "--extrinsic3d"}
    assert all(np.allclose(f.extrinsic3d, CLOUD_EXT) for f in given.frames(clouds=False))
    with pytest.raises(ShapeError, match=r"--extrinsic3d must be 6 finite numbers"):
        RosbagDataset(path, extrinsic2d=LASER_EXT, extrinsic3d=[0, 0, 1], option_names=names)


def test_base_frame(tmp_path):
    path = write_bag(tmp_path / "a", ros2=True)
    ds = RosbagDataset(path, base_frame="laser")  # any frame of TF: the offsets are relative to it
    np.testing.assert_allclose(ds.extrinsic2d, 0.0, atol=1e-12)
    assert ds.describe()["tf_chains"] == {"2d": "laser", "3d": "laser -> base_link -> velodyne"}
    T = np.linalg.inv(pose_to_matrix([LASER_EXT[0], LASER_EXT[1], 0.3, 0, 0, LASER_EXT[2]])) @ pose_to_matrix(CLOUD_EXT)
    np.testing.assert_allclose(pose_to_matrix(ds.extrinsic3d), T, atol=1e-9)
    with pytest.raises(DatasetError, match=r"--base-frame bse_link: no such frame .*: base_link, laser, odom, velodyne"):
        RosbagDataset(path, base_frame="bse_link", option_names={"base_frame": "--base-frame"})
    with pytest.raises(InputError, match="--sync-tolerance must be a number of seconds >= 0"):
        RosbagDataset(path, sync_tolerance=-1, option_names={"sync_tolerance": "--sync-tolerance"})


def test_two_tf_hops_and_ouster_zero_points(tmp_path):
    """An Ouster-style organised cloud (zeros where no return) in a frame two TF hops from the base."""
    ts = _typestore(True)
    m = _Msgs(ts, True)
    T = ts.types
    PF = T["sensor_msgs/msg/PointField"]
    pts = np.array([[1.0, 0.0, 0.5], [0.0, 0.0, 0.0], [2.0, 1.0, -0.2], [0.0, 0.0, 0.0]], dtype=np.float32)
    rec = np.zeros(4, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("pad", "<f4"), ("intensity", "<f4"),
                             ("t", "<u4"), ("reflectivity", "<u2"), ("ring", "<u2"), ("ambient", "<u2"),
                             ("pad2", "<u2"), ("range", "<u4"), ("pad3", "u1", (12,))])
    assert rec.dtype.itemsize == 48
    rec["x"], rec["y"], rec["z"] = pts.T
    fields = [PF(name=n, offset=o, datatype=d, count=1) for n, o, d in
              (("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 16, 7), ("t", 20, 6), ("reflectivity", 24, 4),
               ("ring", 26, 4), ("ambient", 28, 4), ("range", 32, 6))]
    cloud = T["sensor_msgs/msg/PointCloud2"](
        header=m.header(T0, "os_lidar"), height=2, width=2, fields=fields, is_bigendian=False, point_step=48,
        row_step=96, data=np.frombuffer(rec.tobytes(), dtype=np.uint8), is_dense=False)
    hops = [("base_link", "os_sensor", (-0.1, 0.0, 1.5, 0, 0, 0)), ("os_sensor", "os_lidar", (0, 0, 0.036, 0, 0, np.pi))]
    from rosbags.rosbag2 import StoragePlugin, Writer

    path = tmp_path / "ouster.mcap"
    with Writer(tmp_path / "bagdir", version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c_tf = w.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=ts)
        c_pc = w.add_connection("/os_cloud_node/points", "sensor_msgs/msg/PointCloud2", typestore=ts)
        w.write(c_tf, int(T0 * 1e9) - 1, ts.serialize_cdr(m.tf(T0, hops), "tf2_msgs/msg/TFMessage"))
        w.write(c_pc, int(T0 * 1e9), ts.serialize_cdr(cloud, "sensor_msgs/msg/PointCloud2"))
    next((tmp_path / "bagdir").glob("*.mcap")).rename(path)  # a lone .mcap file
    ds = open_dataset(path)  # no odometry: base_link, since TF has it
    f = next(ds.frames())
    np.testing.assert_allclose(f.cloud3d, pts[[0, 2]])  # the zeros (no return) dropped
    np.testing.assert_allclose(ds.extrinsic3d, [-0.1, 0, 1.536, 0, 0, np.pi], atol=1e-9)
    assert ds.describe()["tf_chains"] == {"3d": "base_link -> os_sensor -> os_lidar"}


@pytest.mark.parametrize("ros2", [False, True])
def test_laserscan_time_increment_gives_beam_times(tmp_path, monkeypatch, ros2):
    """A non-zero ``time_increment``: beam i at i * time_increment after the stamp, the same through the fast ROS1
    decoder and rosbags' deserializer; a zero one: no beam times."""
    from hsmap.testing import write_scan_bag

    r = np.tile(np.linspace(1.0, 3.0, 9, dtype=np.float32), (3, 1))
    stamps = 100.0 + 0.1 * np.arange(3)
    path = write_scan_bag(tmp_path / ("t" if ros2 else "t.bag"), r, stamps, angle_min=-1.0, angle_increment=0.25,
                          ros2=ros2, time_increment=0.001)
    ds = RosbagDataset(path)
    frames = list(ds.frames())
    assert ds.describe()["beam_time"]["field"] == "time_increment"
    for f in frames:
        np.testing.assert_allclose(f.scan2d.times, 0.001 * np.arange(9), rtol=1e-6)
    if not ros2:
        monkeypatch.setattr(rosbag_mod, "_ROS1_SCAN_MD5", "disabled")
        slow = list(RosbagDataset(path).frames())
        for f, s in zip(frames, slow, strict=True):
            np.testing.assert_array_equal(f.scan2d.times, s.scan2d.times)
    plain = write_scan_bag(tmp_path / ("p" if ros2 else "p.bag"), r, stamps, angle_min=-1.0, angle_increment=0.25,
                           ros2=ros2)
    ds = RosbagDataset(plain)
    assert all(f.scan2d.times is None for f in ds.frames()) and ds.describe()["beam_time"].startswith("none")


@pytest.mark.parametrize("ti", [float("nan"), 0.2])
def test_bad_laserscan_time_increment_names_the_field(tmp_path, ti):
    from hsmap.testing import write_scan_bag

    r = np.ones((2, 9), dtype=np.float32)
    path = write_scan_bag(tmp_path / "b.bag", r, [100.0, 100.1], angle_min=-1.0, angle_increment=0.25,
                          time_increment=ti)
    with pytest.raises(DataFormatError, match=r"b\.bag: /scan message 0 .*LaserScan time_increment is"):
        RosbagDataset(path)


def test_simulated_bag_scans_turn_over_their_scan_time(tmp_path):
    """The simulator's bag with a 2D scan time: LaserScan ``time_increment`` and ``scan_time`` as a driver writes
    them, the scan stamped at its first beam, each beam from the pose the robot has at its time."""
    pytest.importorskip("open3d")
    from hsmap.sim import Lidar2DConfig, Lidar3DConfig
    from hsmap.sim.bag import write_simulated_bag
    from hsmap.sim.catalog import resolve_scenario
    from hsmap.sim.robot import RobotConfig, sample_legs, simulate_motion
    from hsmap.sim.scenario import load_scenario
    from hsmap.sim.world import World

    scn = load_scenario(resolve_scenario("two-rooms"))
    scn = scn.replace(lidar2d=Lidar2DConfig(scan_time=0.1, noise_sigma=0.0),
                      robot=RobotConfig(max_speed=1.0, max_turn_rate_deg=60.0))
    bag = write_simulated_bag(scn, tmp_path / "s.mcap", seed=1, scan_rate=8.0, duration=4.0,
                              lidar3d=Lidar3DConfig(channels=4, columns=16))
    from rosbags.highlevel import AnyReader

    with AnyReader([bag.path]) as reader:
        conn = [c for c in reader.connections if c.topic == "/scan"]
        msg = reader.deserialize(next(iter(reader.messages(connections=conn)))[2], conn[0].msgtype)
    assert msg.time_increment == pytest.approx(0.1 * 0.25 / 360) and msg.scan_time == pytest.approx(0.1)
    ds = RosbagDataset(bag.path)
    assert ds.describe()["beam_time"]["field"] == "time_increment"
    frames = list(ds.frames(clouds=False))
    np.testing.assert_allclose(ds.stamps, bag.scans.stamps, atol=1e-6)
    f = frames[20]
    np.testing.assert_allclose(f.scan2d.times, np.arange(1081) * 0.1 * 0.25 / 360, rtol=1e-6)
    motion = simulate_motion(scn.start, scn.steps, scn.robot, scn.odometry, 8.0, np.random.default_rng([1, 1]),
                             1_700_000_000.0)
    at = sample_legs(motion.legs, bag.scans.stamps[20] + f.scan2d.times)
    world = World(scn)
    beams = np.arange(0, 1081, 90)
    want = np.array([world.scan2d(at[i : i + 1], scn.lidar2d)[0, i] for i in beams])
    ok = np.isfinite(want) & np.isfinite(f.scan2d.ranges[beams])
    assert ok.sum() >= 6
    np.testing.assert_allclose(f.scan2d.ranges[beams][ok], want[ok], atol=1e-4)
    with pytest.raises(ConfigError, match="scan_time"):
        write_simulated_bag(scn, tmp_path / "x.mcap", scan_rate=20.0, duration=1.0,
                            lidar3d=Lidar3DConfig(channels=4, columns=16))
