"""The streams of an open bag that a :class:`~hsmap.datasets.rosbag.RosbagDataset` is made of: the topic of
each sensor chosen, counted and summarised (frame, rate), the clouds streamed in frame order, the odometry
interpolated at the frames' stamps."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from numpy.typing import NDArray

from ..errors import DatasetError
from ..geometry import wrap_angle
from .bag_reader import BagReader
from .ros_messages import frame_name, pointcloud2_points

__all__ = ["pick_topic", "topic_counts", "topic_summary", "odometry_at", "clouds_in_order"]


def pick_topic(bag: BagReader, path: str, topic: str | None, msgtype: str, what: str, flag: str) -> str | None:
    """The topic of ``msgtype`` to read: ``topic`` checked, or when None the bag's one topic of that type;
    ``flag`` is the caller's name of the option, for messages."""
    conns = [c for c in bag.connections if c.msgtype == msgtype]
    if topic is not None:
        if topic == "":
            return None
        named = [c for c in bag.connections if c.topic == topic]
        if not named:
            raise DatasetError(
                f"{path}: {flag} {topic}: no such topic ({what}); the bag has: {bag.topics_listing()}"
            )
        if named[0].msgtype != msgtype:
            raise DatasetError(
                f"{path}: {flag} {topic}: the topic is {named[0].msgtype}, expected {msgtype}"
            )
        return topic
    topics = sorted({c.topic for c in conns})
    if len(topics) > 1:
        raise DatasetError(
            f"{path}: several {msgtype} topics {topics}: choose one with {flag} (or {flag} '' for none)"
        )
    return topics[0] if topics else None


def topic_counts(bag: BagReader, topics: dict[str, str | None]) -> dict[str, dict]:
    """Topic, type and message count of each sensor's topic used (``topics``: sensor -> topic or None)."""
    counts = {}
    for key, topic in topics.items():
        if topic:
            c = next(c for c in bag.connections if c.topic == topic)
            counts[key] = {"topic": topic, "type": c.msgtype,
                           "messages": int(sum(x.msgcount for x in bag.connections if x.topic == topic))}
    return counts


def odometry_at(odom: NDArray[np.float64], t: NDArray[np.float64], tolerance: float) -> NDArray[np.float64]:
    """Odometry rows (stamp, x, y, yaw) interpolated at ``t`` (yaw unwrapped); NaN rows more than ``tolerance``
    seconds outside the odometry's time span."""
    out = np.full((len(t), 3), np.nan)
    if len(odom) == 0:
        return out
    od = odom[np.argsort(odom[:, 0], kind="stable")]
    ts = od[:, 0]
    inside = (t >= ts[0] - tolerance) & (t <= ts[-1] + tolerance)
    if len(od) == 1:
        out[inside] = od[0, 1:]
        return out
    yaw = np.unwrap(od[:, 3])
    tq = t[inside]
    out[inside, 0] = np.interp(tq, ts, od[:, 1])
    out[inside, 1] = np.interp(tq, ts, od[:, 2])
    out[inside, 2] = wrap_angle(np.interp(tq, ts, yaw))
    return out


def clouds_in_order(path: str, topic: str, wanted: NDArray[np.intp]) -> Iterator[tuple | None]:
    """Yield the cloud of each entry of ``wanted`` (index among the messages of ``topic``, -1 = none),
    streaming the bag once, as :func:`pointcloud2_points` returns it."""
    need: dict[int, int] = {}
    for k in wanted:
        if k >= 0:
            need[int(k)] = need.get(int(k), 0) + 1
    if not need:
        yield from (None for _ in wanted)
        return
    pending: dict[int, tuple] = {}
    with BagReader.open(path) as bag:
        stream = bag.messages(bag.conns(topic))
        pos = -1
        for k in wanted:
            k = int(k)
            if k < 0:
                yield None
                continue
            while k not in pending:
                c, _, raw = next(stream)
                pos += 1
                if pos in need:
                    msg = bag.deserialize(raw, c)
                    pending[pos] = pointcloud2_points(msg, source=f"{path} {topic} message {pos}")
            cloud = pending[k]
            need[k] -= 1
            if need[k] == 0:
                del pending[k]
            yield cloud


def _rate(stamps: NDArray[np.float64]) -> float | None:
    st = np.sort(stamps)
    return (len(st) - 1) / float(st[-1] - st[0]) if len(st) > 1 and st[-1] > st[0] else None


def topic_summary(counts: dict, scans: dict, clouds: dict, odom: NDArray[np.float64],
                   odom_child: str | None) -> dict:
    """Each topic used (:func:`topic_counts`) with its frame (or the odometry's child frame) and rate."""
    topics = {}
    for key, rec in (("scan", scans), ("cloud", clouds)):
        if key in counts:
            topics[key] = {**counts[key], "frame_id": frame_name(rec["frame"][0]) if rec["frame"] else None,
                           "rate_hz": _rate(np.asarray(rec["stamp"], dtype=float))}
    if "odom" in counts:
        topics["odom"] = {**counts["odom"], "child_frame_id": odom_child, "rate_hz": _rate(odom[:, 0])}
    return topics
