"""ROS messages decoded for the bag reader: PointCloud2 clouds (x, y, z and a per-point time), ROS1 LaserScan
and Odometry from their raw bytes, stamps and frame names, and the TF tree of a bag's transforms."""

from __future__ import annotations

import math
import struct

import numpy as np
from numpy.typing import NDArray

from ..errors import DataFormatError, InputError
from ..geometry import invert_matrix, quaternion_to_matrix

__all__ = ["pointcloud2_xyz", "pointcloud2_points", "ros1_header", "ros1_scan", "ros1_odom", "check_scan_geometry", "scan_beam_times", "stamp_seconds", "frame_name", "transform_matrix", "TfTree", "POINT_TIME_FIELDS", "MAX_POINT_TIME_OFFSET", "READ_AS_SECONDS", "point_time_unit", "point_time_convention"]

# sensor_msgs/PointField datatypes -> numpy
_POINTFIELD_DTYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


def pointcloud2_xyz(msg, *, source: str = "PointCloud2") -> NDArray[np.float64]:
    """The finite x, y, z points of a ``sensor_msgs/PointCloud2`` message.

    Parameters
    ----------
    msg : PointCloud2 message (as deserialised by rosbags)
    source : str
        Named in error messages.

    Returns
    -------
    ndarray of shape (N, 3)
        Points with any non-finite coordinate dropped, and points at exactly (0, 0, 0): organised clouds
        (Ouster's, 48 bytes a point) write zeros where a beam had no return.
    """
    return pointcloud2_points(msg, source=source)[0]


#: The per-point time fields read, in this order: name -> (what the driver writes, the unit, absolute or not).
POINT_TIME_FIELDS = {
    "t": ("ouster-ros: uint32 ns after the header stamp (the sweep's start)", 1e-9, False),
    "time": ("velodyne_pointcloud: float32 s relative to the header stamp (>= 0 where the stamp is the sweep's "
             "start, <= 0 where it is its end, as the driver version has it)", 1.0, False),
    "offset_time": ("livox_ros_driver2: uint32 ns after the header stamp", 1e-9, False),
    "timestamp": ("Hesai/RoboSense: float64 absolute s", 1.0, True),
}
#: Seconds: the largest distance of a point's time from its cloud's header stamp.
MAX_POINT_TIME_OFFSET = 1.0
#: Appended to a time field's name when its values were read as seconds against its driver's unit.
READ_AS_SECONDS = " as seconds"


def point_time_unit(name: str, values: NDArray) -> tuple[float, str]:
    """Seconds per unit of the time field ``name`` whose values (in the file's own dtype) are ``values``, and the
    field's label (its name, plus :data:`READ_AS_SECONDS` when read in seconds against its driver's unit).

    The rule: a field its driver writes in nanoseconds (``t``, ``offset_time``: uint32) that this file stores as
    floating point with every finite value within :data:`MAX_POINT_TIME_OFFSET` (1) of zero holds seconds: read
    as nanoseconds the whole sweep would last at most a nanosecond, which no LiDAR's does, and deskewing would
    move nothing. Integer fields, and floating ones with a value beyond 1, keep the driver's unit.
    """
    _, scale, _ = POINT_TIME_FIELDS[name]
    if scale != 1.0 and values.dtype.kind == "f" and len(values):
        finite = np.abs(values[np.isfinite(values)])
        if len(finite) and 0 < finite.max() <= MAX_POINT_TIME_OFFSET:
            return 1.0, name + READ_AS_SECONDS
    return scale, name


def point_time_convention(label: str) -> str:
    """What a time field's values mean: its driver's convention (:data:`POINT_TIME_FIELDS`), or, for a field read
    as seconds (:func:`point_time_unit`), that reading and why."""
    name = label.removesuffix(READ_AS_SECONDS)
    if name == label:
        return POINT_TIME_FIELDS[name][0]
    return (f"{POINT_TIME_FIELDS[name][0]}; here floating-point values within {MAX_POINT_TIME_OFFSET:g} of zero, "
            "read as seconds (as nanoseconds no sweep lasts that short)")


def pointcloud2_points(msg, *, source: str = "PointCloud2"
                       ) -> tuple[NDArray[np.float64], NDArray[np.float64] | None, str | None]:
    """The finite points of a ``sensor_msgs/PointCloud2`` and, when it has a per-point time field
    (:data:`POINT_TIME_FIELDS`), each point's seconds relative to its header stamp.

    Any standard layout: the fields' offsets and datatypes, ``point_step``, ``row_step`` (padded rows),
    ``is_bigendian``, organised (``height`` > 1) or not. Points with a non-finite coordinate or at exactly
    (0, 0, 0) (an organised cloud's no return) are dropped with their times.

    Returns
    -------
    points : ndarray of shape (N, 3)
    times : ndarray of shape (N,) or None
        Seconds relative to ``msg.header.stamp``; None without a time field.
    field : str or None
        The time field read (its label, :func:`point_time_unit`).

    Raises
    ------
    DataFormatError
        A missing x/y/z field, an unknown datatype, a too short ``point_step`` or data, or point times more than
        :data:`MAX_POINT_TIME_OFFSET` from the stamp or not finite (naming the field).
    """
    fields = {f.name: f for f in msg.fields}
    missing = [n for n in ("x", "y", "z") if n not in fields]
    if missing:
        raise DataFormatError(f"{source}: PointCloud2 has no field(s) {missing}; fields are {sorted(fields)}")
    tname = next((n for n in POINT_TIME_FIELDS if n in fields), None)
    names = ["x", "y", "z"] + ([tname] if tname else [])
    endian = ">" if msg.is_bigendian else "<"
    formats = []
    for n in names:
        code = _POINTFIELD_DTYPES.get(int(fields[n].datatype))
        if code is None:
            raise DataFormatError(f"{source}: PointCloud2 field {n!r} has unknown datatype {fields[n].datatype}")
        formats.append(endian + code)
    step = int(msg.point_step)
    width, height = int(msg.width), int(msg.height)
    offsets = [int(fields[n].offset) for n in names]
    if step <= 0 or max(o + np.dtype(f).itemsize for o, f in zip(offsets, formats, strict=True)) > step:
        raise DataFormatError(f"{source}: PointCloud2 point_step {step} is too small for fields at {offsets}")
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": step})
    data = np.frombuffer(memoryview(msg.data).cast("B"), dtype=np.uint8)
    row_step = int(msg.row_step) if int(msg.row_step) > 0 else width * step
    if data.size < row_step * (height - 1) + width * step:
        raise DataFormatError(
            f"{source}: PointCloud2 data has {data.size} bytes, expected {height} rows of {row_step} bytes"
        )
    if height == 0 or width == 0:
        return np.zeros((0, 3)), (np.zeros(0) if tname else None), tname
    if row_step == width * step:
        rec = data[: height * row_step].view(dtype)
    else:
        rows = np.lib.stride_tricks.as_strided(data, shape=(height, width * step), strides=(row_step, 1))
        rec = np.ascontiguousarray(rows).reshape(-1).view(dtype)
    xyz = np.column_stack([rec["x"], rec["y"], rec["z"]]).astype(float)
    ok = np.isfinite(xyz).all(axis=1) & (xyz != 0.0).any(axis=1)
    if tname is None:
        return xyz[ok], None, None
    raw = rec[tname][ok]
    scale, label = point_time_unit(tname, raw)
    t = raw.astype(float) * scale
    if POINT_TIME_FIELDS[tname][2]:
        t = t - stamp_seconds(msg.header)
    bad = int((~np.isfinite(t)).sum())
    if bad:
        raise DataFormatError(f"{source}: PointCloud2 field {tname!r} ({POINT_TIME_FIELDS[tname][0]}) holds {bad} "
                              f"non-finite (NaN or infinite) time(s) of {len(t)}; expected finite times")
    if len(t) and np.abs(t).max() > MAX_POINT_TIME_OFFSET:
        raise DataFormatError(f"{source}: PointCloud2 field {tname!r} ({point_time_convention(label)}) puts points "
                              f"{float(np.abs(t).max()):.6g} s from the header stamp; expected at most "
                              f"{MAX_POINT_TIME_OFFSET} s")
    return xyz[ok], t, label


# ROS1 md5sums of the standard definitions, for which the raw layout below is fixed
_U32 = struct.Struct("<I")
_HDR = struct.Struct("<III")
_SCAN_GEOM = struct.Struct("<7f")
_POSE = struct.Struct("<7d")


def ros1_header(raw: memoryview | bytes) -> tuple[int, float, str, int]:
    """(seq, stamp, frame_id, end offset) of a ROS1 std_msgs/Header at the start of ``raw``."""
    seq, sec, nsec = _HDR.unpack_from(raw, 0)
    (n,) = _U32.unpack_from(raw, 12)
    frame = bytes(raw[16 : 16 + n]).decode()
    return seq, sec + nsec * 1e-9, frame, 16 + n


def ros1_scan(raw) -> tuple[int, float, str, tuple[float, float, float, float], NDArray[np.float32], float]:
    """(seq, stamp, frame_id, (angle_min, angle_increment, range_min, range_max), ranges, time_increment) of a raw
    ROS1 LaserScan."""
    seq, stamp, frame, o = ros1_header(raw)
    amin, _amax, inc, ti, _st, rmin, rmax = _SCAN_GEOM.unpack_from(raw, o)
    o += 28
    (n,) = _U32.unpack_from(raw, o)
    ranges = np.frombuffer(raw, dtype="<f4", count=n, offset=o + 4)
    o += 4 + 4 * n
    (m,) = _U32.unpack_from(raw, o)
    if o + 4 + 4 * m != len(raw):
        raise struct.error("LaserScan size mismatch")
    return seq, stamp, frame, (float(amin), float(inc), float(rmin), float(rmax)), ranges, float(ti)


def ros1_odom(raw) -> tuple[int, float, str, tuple[float, float, float]]:
    """(seq, stamp, child_frame_id, (x, y, yaw)) of a raw ROS1 nav_msgs/Odometry."""
    seq, stamp, _frame, o = ros1_header(raw)
    (n,) = _U32.unpack_from(raw, o)
    child = bytes(raw[o + 4 : o + 4 + n]).decode()
    o += 4 + n
    x, y, _z, qx, qy, qz, qw = _POSE.unpack_from(raw, o)
    if o + 56 + 36 * 8 + 48 + 36 * 8 != len(raw):
        raise struct.error("Odometry size mismatch")
    yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
    return seq, stamp, child, (x, y, yaw)


def check_scan_geometry(geom: tuple[float, float, float, float], n: int, where: str) -> None:
    """Reject LaserScan geometry that cannot be right: it would put the beams at wrong angles or keep impossible
    (negative) ranges, giving a wrong map without any other sign.

    Raises
    ------
    DataFormatError
        Naming ``where`` (file, topic, message), the field and what was expected.
    """
    amin, inc, rmin, rmax = geom

    def bad(field: str, value: float, expected: str) -> DataFormatError:
        return DataFormatError(f"{where}: LaserScan {field} is {value!r}; expected {expected}")

    if not math.isfinite(amin):
        raise bad("angle_min", amin, "a finite angle (radians)")
    if not math.isfinite(inc) or inc == 0.0:
        raise bad("angle_increment", inc, "a finite, non-zero angle step (radians) between beams")
    if n > 1 and abs(inc) * (n - 1) > 2 * math.pi + 1e-3:
        raise bad("angle_increment", inc, f"at most 2 pi / {n - 1} rad: its {n} beams would span "
                                          f"{abs(inc) * (n - 1):.3f} rad, more than a full turn")
    if not math.isfinite(rmin) or rmin < 0:
        raise bad("range_min", rmin, "a finite distance >= 0 (metres): ranges are never negative")
    if math.isnan(rmax) or rmax <= rmin:
        raise bad("range_max", rmax, f"a distance (metres) above range_min ({rmin!r})")


def scan_beam_times(time_increment: float, n: int, where: str) -> NDArray[np.float64] | None:
    """Seconds (n,) of each beam of a LaserScan after its header stamp (the first beam's, as ROS defines it):
    ``i * time_increment``; None where ``time_increment`` is 0 (every beam at the stamp).

    Raises
    ------
    DataFormatError
        Naming ``where``, for a non-finite ``time_increment`` or one that puts the last beam more than
        :data:`MAX_POINT_TIME_OFFSET` from the stamp.
    """
    ti = float(time_increment)
    if ti == 0.0:
        return None
    if not math.isfinite(ti) or abs(ti) * max(n - 1, 0) > MAX_POINT_TIME_OFFSET:
        raise DataFormatError(f"{where}: LaserScan time_increment is {ti!r}; expected a finite step (seconds) "
                              f"that keeps its {n} beams within {MAX_POINT_TIME_OFFSET} s of the stamp")
    return ti * np.arange(n, dtype=float)


def stamp_seconds(header) -> float:
    return float(header.stamp.sec) + float(header.stamp.nanosec) * 1e-9


def frame_name(name: str) -> str:
    return name.lstrip("/")


def transform_matrix(tf, where: str = "transform") -> NDArray[np.float64]:
    t, q = tf.translation, tf.rotation
    T = np.eye(4)
    try:
        T[:3, :3] = quaternion_to_matrix([q.x, q.y, q.z, q.w])
    except InputError as exc:
        raise DataFormatError(f"{where}: rotation {exc}") from None
    T[:3, 3] = [t.x, t.y, t.z]
    if not np.all(np.isfinite(T)):
        raise DataFormatError(f"{where}: translation {[t.x, t.y, t.z]} is not finite")
    return T


class TfTree:
    """Fixed transforms parent -> child (4x4), looked up between any two connected frames."""

    def __init__(self) -> None:
        self.parent: dict[str, tuple[str, NDArray[np.float64]]] = {}

    def add(self, parent: str, child: str, T: NDArray[np.float64]) -> None:
        self.parent.setdefault(frame_name(child), (frame_name(parent), T))

    def _to_root(self, frame: str) -> tuple[str, NDArray[np.float64]]:
        T = np.eye(4)
        seen = {frame}
        while frame in self.parent:
            parent, Tp = self.parent[frame]
            T = Tp @ T
            frame = parent
            if frame in seen:  # a cycle: stop rather than loop
                break
            seen.add(frame)
        return frame, T

    def chain(self, target: str, source: str) -> list[str]:
        """The frames from ``target`` to ``source`` through their common ancestor (both ends included)."""
        def up(frame: str) -> list[str]:
            out, seen = [frame], {frame}
            while frame in self.parent and self.parent[frame][0] not in seen:
                frame = self.parent[frame][0]
                out.append(frame)
                seen.add(frame)
            return out

        a, b = up(frame_name(target)), up(frame_name(source))
        common = next((f for f in a if f in set(b)), None)
        if common is None:
            return []
        return a[: a.index(common) + 1] + b[: b.index(common)][::-1]

    def frames(self) -> set[str]:
        return set(self.parent) | {p for p, _ in self.parent.values()}

    def lookup(self, target: str, source: str) -> NDArray[np.float64] | None:
        """Pose of ``source`` in ``target`` (4x4), or None when they are not connected."""
        rs, Ts = self._to_root(frame_name(source))
        rt, Tt = self._to_root(frame_name(target))
        if rs != rt:
            return None
        return invert_matrix(Tt) @ Ts

    def __contains__(self, frame: str) -> bool:
        frame = frame_name(frame)
        return frame in self.parent or any(p == frame for p, _ in self.parent.values())
