"""An open ROS1/ROS2 bag for the reader (:class:`BagReader`): its connections, its messages (damaged data a
:class:`~hsmap.errors.DataFormatError`), decoding, the TF transforms, and one pass over the sensor topics."""

from __future__ import annotations

import contextlib
import functools
import math
import struct
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..errors import DataFormatError, DatasetError, HsmapWarning
from .ros_messages import (
    TfTree,
    check_scan_geometry,
    frame_name,
    ros1_odom,
    ros1_scan,
    scan_beam_times,
    stamp_seconds,
    transform_matrix,
)

__all__ = ["BagReader", "ROS2_STORAGE_SUFFIXES", "TF_TYPE"]

TF_TYPE = "tf2_msgs/msg/TFMessage"
#: ROS2 storage files that open alone, without their bag folder.
ROS2_STORAGE_SUFFIXES = (".mcap", ".db3")


@functools.cache
def _ros2_typestore():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.LATEST)


def _topics_listing(reader) -> str:
    return ", ".join(f"{c.topic} ({c.msgtype})" for c in sorted(reader.connections, key=lambda c: c.topic)) or "none"


class _SensorRecords:
    """The sensors' messages that :meth:`BagReader.read_sensors` gathers, one at a time."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.scans: dict[str, list] = {"stamp": [], "seq": [], "ranges": [], "geometry": [], "frame": [],
                                       "time_increment": []}
        self.clouds: dict[str, list] = {"stamp": [], "seq": [], "frame": []}
        self.odom: list[tuple[float, float, float, float, int]] = []
        self.odom_child: str | None = None
        self.checked: set = set()  # scan geometries found sound
        self.bad_odom = 0

    def add_scan(self, topic: str, seq, stamp: float, frame: str, geom: tuple, ranges: NDArray[np.float32],
                 time_inc: float) -> None:
        scans = self.scans
        if (geom, len(ranges), time_inc) not in self.checked:
            where = f"{self.path}: {topic} message {len(scans['stamp'])} (stamp {stamp:.6f})"
            check_scan_geometry(geom, len(ranges), where)
            scan_beam_times(time_inc, len(ranges), where)
            self.checked.add((geom, len(ranges), time_inc))
        scans["stamp"].append(stamp)
        scans["seq"].append(seq)
        scans["frame"].append(frame)
        scans["ranges"].append(ranges)
        scans["geometry"].append(geom)
        scans["time_increment"].append(time_inc)

    def add_cloud(self, seq, stamp: float, frame: str) -> None:
        self.clouds["stamp"].append(stamp)
        self.clouds["seq"].append(seq)
        self.clouds["frame"].append(frame)

    def add_odom(self, seq, stamp: float, frame: str, pose: tuple) -> None:
        """An odometry pose (x, y, yaw), left out and counted where it or its stamp is not finite."""
        if not all(math.isfinite(v) for v in (stamp, *pose)):
            self.bad_odom += 1
            return
        self.odom.append((stamp, *pose, -1 if seq is None else seq))
        if self.odom_child is None:
            self.odom_child = frame


class BagReader:
    """An open bag (made by :meth:`open`).

    Parameters
    ----------
    path : str
        The bag as the caller named it, for messages.
    reader : rosbags.highlevel.AnyReader
    """

    def __init__(self, path: str, reader) -> None:
        self.path = path
        self.reader = reader

    @classmethod
    @contextlib.contextmanager
    def open(cls, path: str | Path) -> Iterator[BagReader]:
        """The bag at ``path`` opened for reading (closed after the ``with`` block)."""
        from rosbags.highlevel import AnyReader

        p = Path(path)
        if not p.exists():
            raise DatasetError(f"{p}: no such bag file or folder")
        if p.is_file() and p.suffix in ROS2_STORAGE_SUFFIXES and (p.parent / "metadata.yaml").is_file():
            p = p.parent
        try:
            # ROS1 bags carry their message definitions; older ROS2 bags need the standard ones
            reader = AnyReader([p], default_typestore=_ros2_typestore() if p.suffix != ".bag" else None)
            reader.open()
        except Exception as exc:  # rosbags raises its own error types (and plain OSError) for bad files
            raise DatasetError(f"{p}: cannot read as a ROS1/ROS2 bag: {exc}") from None
        try:
            yield cls(str(path), reader)
        finally:
            reader.close()

    @property
    def connections(self) -> list:
        return self.reader.connections

    def topics_listing(self) -> str:
        """Every topic with its message type, for messages."""
        return _topics_listing(self.reader)

    def messages(self, conns) -> Iterator:
        """``reader.messages`` with rosbags' errors on damaged data turned into DataFormatError."""
        it = self.reader.messages(connections=conns)
        while True:
            try:
                item = next(it)
            except StopIteration:
                return
            except Exception as exc:  # ReaderError, struct.error, OSError, ... from a damaged bag
                raise DataFormatError(f"{self.path}: damaged bag data ({type(exc).__name__}: {exc})") from None
            yield item

    def deserialize(self, raw, c):
        try:
            return self.reader.deserialize(raw, c.msgtype)
        except Exception as exc:  # rosbags' SerdeError and friends
            raise DataFormatError(f"{self.path}: cannot decode a {c.msgtype} message on {c.topic}: {exc}") from None

    def conns(self, topic: str | None):
        return [c for c in self.reader.connections if c.topic == topic] if topic else []

    def static_tf(self) -> TfTree:
        """The transforms of the bag's /tf_static."""
        tf = TfTree()
        conns = [c for c in self.reader.connections if c.msgtype == TF_TYPE and c.topic.endswith("tf_static")]
        if conns:
            for c, _, raw in self.messages(conns):
                for t in self.deserialize(raw, c).transforms:
                    where = f"{self.path}: {c.topic} transform {t.header.frame_id} -> {t.child_frame_id}"
                    tf.add(t.header.frame_id, t.child_frame_id, transform_matrix(t.transform, where))
        return tf

    def read_sensors(self, scan_topic: str | None, cloud_topic: str | None, odom_topic: str | None,
                     progress: bool | None, fast: tuple[str, ...] = ()
                     ) -> tuple[dict, dict, NDArray[np.float64], str | None]:
        """The scans (stamp, seq, ranges, geometry, frame, time_increment), the clouds' headers (stamp, seq, frame), the odometry
        (N, 5: stamp, x, y, yaw, seq) and the odometry's child frame, read in one pass over the topics. ROS1
        LaserScan and Odometry connections whose definition digest is in ``fast`` are decoded from their raw
        bytes (:func:`hsmap.datasets.ros_messages.ros1_scan`)."""

        scan_c = self.conns(scan_topic)
        cloud_c = self.conns(cloud_topic)
        odom_c = self.conns(odom_topic)
        from ..progress import bar as progress_bar

        kinds = {**{id(c): "scan" for c in scan_c}, **{id(c): "cloud" for c in cloud_c}}
        fast_ids = {id(c) for c in scan_c + odom_c if c.digest in fast}
        rec = _SensorRecords(self.path)
        total = sum(int(c.msgcount) for c in scan_c + cloud_c + odom_c)
        bar = progress_bar(total, unit="msg", desc=f"reading {Path(self.path).name}", progress=progress, leave=False,
                           mininterval=0.5)
        for c, _, raw in self.messages(scan_c + cloud_c + odom_c):
            bar.update(1)
            kind = kinds.get(id(c), "odom")
            seq, stamp, frame, payload = self._decode(c, raw, kind, id(c) in fast_ids)
            if kind == "scan":
                rec.add_scan(c.topic, seq, stamp, frame, *payload)
            elif kind == "cloud":
                rec.add_cloud(seq, stamp, frame)
            else:
                rec.add_odom(seq, stamp, frame, payload)
        bar.close()
        if rec.bad_odom:
            import warnings

            warnings.warn(f"{self.path}: {rec.bad_odom} {odom_topic} message(s) have a non-finite pose or stamp and "
                          "are ignored", HsmapWarning, stacklevel=3)
        if scan_topic and not rec.scans["stamp"]:
            raise DatasetError(f"{self.path}: topic {scan_topic!r} has no messages")
        if cloud_topic and not rec.clouds["stamp"]:
            raise DatasetError(f"{self.path}: topic {cloud_topic!r} has no messages")
        return rec.scans, rec.clouds, np.asarray(rec.odom, dtype=float).reshape(-1, 5), rec.odom_child

    def _decode(self, c, raw, kind: str, fast: bool) -> tuple:
        """(seq, stamp, frame, payload) of one message of a ``kind`` ("scan", "cloud", "odom") connection: a scan's
        payload is (geometry, ranges, time_increment), an odometry message's (x, y, yaw) and its frame the child
        frame; with ``fast``, decoded from the ROS1 bytes."""
        if fast:
            try:
                if kind == "scan":
                    seq, stamp, frame, geom, ranges, time_inc = ros1_scan(raw)
                    return seq, stamp, frame, (geom, ranges, time_inc)
                return ros1_odom(raw)
            except (struct.error, UnicodeDecodeError, ValueError) as exc:
                raise DataFormatError(
                    f"{self.path}: cannot decode a {c.msgtype} message on {c.topic}: {exc}"
                ) from None
        msg = self.deserialize(raw, c)
        h = msg.header
        seq, stamp = getattr(h, "seq", None), stamp_seconds(h)
        if kind == "scan":
            geom = (float(msg.angle_min), float(msg.angle_increment), float(msg.range_min), float(msg.range_max))
            return seq, stamp, h.frame_id, (geom, np.asarray(msg.ranges, dtype=np.float32), float(msg.time_increment))
        if kind == "cloud":
            return seq, stamp, h.frame_id, None
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
        return seq, stamp, msg.child_frame_id, (p.x, p.y, yaw)

    def dynamic_tf(self, tf: TfTree, base: str, sensors: list[str]) -> None:
        """Add the first /tf transform of every edge that does not move the base (odom -> base is skipped),
        until every sensor frame is connected to the base."""
        conns = [c for c in self.reader.connections if c.msgtype == TF_TYPE and not c.topic.endswith("tf_static")]
        if not conns:
            return
        for c, _, raw in self.messages(conns):
            added = False
            for t in self.deserialize(raw, c).transforms:
                child = frame_name(t.child_frame_id)
                if child != base and child not in tf.parent:
                    where = f"{self.path}: {c.topic} transform {t.header.frame_id} -> {t.child_frame_id}"
                    tf.add(t.header.frame_id, child, transform_matrix(t.transform, where))
                    added = True
            if added and all(f == base or tf.lookup(base, f) is not None for f in sensors):
                return
