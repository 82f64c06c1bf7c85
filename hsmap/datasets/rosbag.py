"""ROS1 and ROS2 bags as :class:`~hsmap.datasets.frames.Frame` sequences, through the pure-Python ``rosbags``.

What is read
------------
- ``sensor_msgs/LaserScan`` (2D scans; a non-zero ``time_increment`` gives each beam its time,
  :attr:`~hsmap.datasets.frames.LaserScan2D.times`) and/or ``sensor_msgs/PointCloud2`` (3D clouds, the x, y, z
  fields and a per-point time);
- ``nav_msgs/Odometry``: the planar pose (x, y, yaw) of the robot base, interpolated at each frame's stamp;
- ``/tf_static`` (and, only when the static tree does not connect them, the first ``/tf`` transform of each
  edge that does not move the base): the sensor extrinsics, robot base -> sensor frame.

Inputs: a ROS1 ``.bag``, a ROS2 bag folder (``metadata.yaml``), or a ROS2 storage file alone (``.mcap`` or
``.db3``, without its folder: rosbags reads the topics from the file itself).

Topics are chosen independently of each other: each of ``scan_topic``, ``cloud_topic`` and ``odom_topic``
is the named topic, or, when None, the one topic of its message type (none when the bag has none); ``""``
leaves that sensor out. Several candidates, or a named topic that is absent or of another type, raise
:class:`~hsmap.errors.DatasetError` naming the option (``option_names`` maps them to the caller's names, the
command line's ``--scan-topic`` ...) and listing the topics of the bag.
ROS1 LaserScan and Odometry messages with the standard definitions (checked by md5sum) are decoded straight
from their bytes, about twice as fast as rosbags' generic deserializer (the tests check both agree); all
other messages, and every ROS2 message, go through rosbags.

Frames and order
----------------
A 2D LiDAR usually runs faster than a 3D one (40 Hz and 10 Hz), and they are not synchronised. The frames are
made by one sensor's messages, the *driver*: the 2D scans by default when there are any (a 3-DOF run), the
clouds for a 6-DOF run (``drive="cloud"`` or :meth:`RosbagDataset.driven_by`); the other sensor's nearest
message within ``sync_tolerance`` seconds is attached (``None`` when there is none). Each frame carries its
driving message's own ``Header.stamp``. (A 6-DOF run seeded by a 2D run interpolates the 2D poses at the
clouds' stamps: :meth:`hsmap.trajectory.Trajectory.interpolate`.)

The order of frames is :class:`FrameOrder`. ``AUTO`` (default) takes ROS1's ``Header.seq`` (the publisher's
counter, i.e. the order in which the messages were produced) when every message of the topic has a distinct
seq, and the header stamps otherwise (ROS2 has no seq). This matters for the Freiburg ``intel`` log: its
CARMEN IPC stamps are receive times of bursty messages (a quarter of consecutive scans are about 1 ms apart)
and go backwards 631 times in log order, by up to 0.9 s. Log (seq) order is the physical one: the
odometry carried by each scan is a smooth 508 m path in seq order and a 661 m zig-zag in stamp order. The
frames therefore keep their original, non-monotonic stamps in seq order; consumers that interpolate in time
(the relations metric) sort by stamp themselves.

Sensor offsets
--------------
The pose of each sensor's ``frame_id`` in the base frame comes from TF (the chain of transforms, any number of
hops: ``base_link -> os_sensor -> os_lidar``), or from the caller (``extrinsic2d``/``extrinsic3d``, the
command line's ``--extrinsic2d``/``--extrinsic3d``), which overrides TF. A sensor with neither gets a zero
offset and a warning (:class:`~hsmap.errors.HsmapWarning`, also in :attr:`Dataset.warnings` and
``describe()``), because a zero offset is almost never right (a 3D LiDAR on a mast is a metre or more above the
base). :meth:`RosbagDataset.describe` records the topics, their message counts, rates and frames, the base
frame, each offset with its source (``tf`` and the chain, the option, ``default``) and the warnings.

Odometry
--------
``Frame.odometry`` is the odometry pose linearly interpolated (yaw on the unwrapped angle) at the time the
frame's message was made; frames more than ``odom_tolerance`` seconds outside the odometry's time span get
``None``. Where stamps are receive times that go backwards in production order (intel, see above), they are
not those times: the odometry messages are then taken in ROS1 seq order, and both they and the frames get
production times estimated from their stamps (:func:`_monotone`: a message was made no later than every later
one was received, so each stamp is lowered to the earliest stamp after it, and a burst of equal values is
spread back to the value before it). Stamps already in order are unchanged, and the frames keep their original
stamps (the relations join to those). On intel this takes the frame-to-frame odometry steps over 0.3 m from 37
to 4 and the path from 585 m to 508 m, as long as the odometry CARMEN stored with each scan (which
``intel.clf2bag.bag`` carries, one message per scan: none over 0.3 m); :func:`adopt_odometry` gives the
``orig.bag`` frames that odometry after checking the scans are identical.

No-return points of a cloud
---------------------------
Points with a non-finite coordinate, and points at exactly (0, 0, 0) (organised clouds such as Ouster's
write zeros where a beam had no return), are dropped.

No-return readings
------------------
A range is masked (NaN) when it is NaN or infinite, below ``range_min``, or at or above the no-return
threshold ``min(range_max - NO_RETURN_MARGIN, no_return)``: ROS says readings beyond ``range_max`` are
invalid, and a SICK laser in the CARMEN logs reports 81.83 m or 81.91 m for "no return" while the converted
bags' ``range_max`` is the converter's (80 m; 81.9 m in fr-clinic, where 81.83 m also means no return), so the
default ``no_return=80.0`` m catches both. Pass ``no_return=None`` to trust ``range_max`` alone.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..errors import DatasetError, InputError
from ..geometry import matrix_to_pose
from ..trajectory import Trajectory, nearest_index
from .bag_reader import ROS2_STORAGE_SUFFIXES, TF_TYPE, BagReader
from .bag_streams import clouds_in_order, odometry_at, pick_topic, topic_counts, topic_summary
from .frames import SOURCE_DEFAULT, Dataset, Frame, LaserScan2D, stamp_in_sweep
from .ros_messages import (
    POINT_TIME_FIELDS,
    TfTree,
    frame_name,
    point_time_convention,
    pointcloud2_points,
    pointcloud2_xyz,
    scan_beam_times,
)

__all__ = [
    "FrameOrder",
    "RosbagDataset",
    "SCAN_TYPE",
    "CLOUD_TYPE",
    "ODOM_TYPE",
    "TF_TYPE",
    "NO_RETURN_MARGIN",
    "DEFAULT_NO_RETURN",
    "pointcloud2_xyz",
    "pointcloud2_points",
    "POINT_TIME_FIELDS",
    "no_return_threshold",
    "adopt_odometry",
    "ROS2_STORAGE_SUFFIXES",
    "DEFAULT_SYNC_TOLERANCE",
]

SCAN_TYPE = "sensor_msgs/msg/LaserScan"
CLOUD_TYPE = "sensor_msgs/msg/PointCloud2"
ODOM_TYPE = "nav_msgs/msg/Odometry"

#: Readings within this many metres of ``range_max`` count as "no return".
NO_RETURN_MARGIN = 0.05
#: Readings at or above this many metres count as "no return" (SICK error codes 81.83 / 81.91 m in CARMEN logs).
DEFAULT_NO_RETURN = 80.0
#: Seconds: the largest stamp difference between a frame and the other sensor's message attached to it.
DEFAULT_SYNC_TOLERANCE = 0.1



class FrameOrder(enum.Enum):
    """How frames are ordered (see the module docstring)."""

    AUTO = "auto"  #: ROS1 Header.seq when distinct, else STAMP
    SEQ = "seq"  #: ROS1 Header.seq (publisher's counter = log order); error when seqs repeat
    STAMP = "stamp"  #: Header.stamp (stable: ties keep the bag's order)
    BAG = "bag"  #: the order the bag stores them in (record time)


def no_return_threshold(range_max: float, no_return: float | None = DEFAULT_NO_RETURN) -> float:
    """Range (m) at and above which a reading is "no return": ``min(range_max - margin, no_return)``."""
    thr = float(range_max) - NO_RETURN_MARGIN if np.isfinite(range_max) and range_max > 0 else np.inf
    if no_return is not None:
        thr = min(thr, float(no_return))
    return thr


_ROS1_SCAN_MD5 = "90c7ef2dc6895d81024acba2ac42f369"
_ROS1_ODOM_MD5 = "cd5e73d190d741a2f92e81eda573aca7"


#: The Python names of the options, used in messages unless the caller names them its own way.
OPTION_NAMES = {"scan_topic": "scan_topic", "cloud_topic": "cloud_topic", "odom_topic": "odom_topic",
                "base_frame": "base_frame", "extrinsic2d": "extrinsic2d", "extrinsic3d": "extrinsic3d",
                "sync_tolerance": "sync_tolerance", "drive": "drive"}


def _checked_options(names: dict, order, sync_tolerance, drive) -> FrameOrder:
    """The frame order asked for; raises, naming the option (``names``: the caller's names), where ``order``,
    ``sync_tolerance`` or ``drive`` is not one it can take."""
    try:
        frame_order = FrameOrder(order)
    except ValueError:
        raise DatasetError(f"order must be one of {[o.value for o in FrameOrder]}, got {order!r}") from None
    if not (math.isfinite(float(sync_tolerance)) and float(sync_tolerance) >= 0):
        raise InputError(f"{names['sync_tolerance']} must be a number of seconds >= 0, got {sync_tolerance!r}")
    if drive not in (None, "scan", "cloud"):
        raise InputError(f"{names['drive']} must be 'scan' or 'cloud', got {drive!r}")
    return frame_order


class _BeamGeometry:
    """Beam angles (mirrored for a scanner mounted upside down) and no-return threshold of each scan geometry
    (angle_min, angle_increment, range_min, range_max) and beam count, computed once."""

    def __init__(self, flip: bool, no_return: float | None) -> None:
        self.flip, self.no_return = flip, no_return
        self._cache: dict = {}

    def __call__(self, geom: tuple, n: int) -> tuple[NDArray[np.float64], float]:
        key = (geom, n)
        if key not in self._cache:
            amin, inc, rmin, rmax = geom
            angles = amin + inc * np.arange(n)
            self._cache[key] = (-angles if self.flip else angles, no_return_threshold(rmax, self.no_return))
        return self._cache[key]


def _decode_scan(scans: dict, k: int, stamp: float, beams: _BeamGeometry, path: str) -> LaserScan2D:
    """Scan ``k`` of a bag's scans (as :meth:`BagReader.read_sensors` returns them), no-return readings masked,
    its beam times (if any) relative to ``stamp``."""
    r = scans["ranges"][k].astype(float)
    geom = scans["geometry"][k]
    angles, thr = beams(geom, len(r))
    r[~((r >= geom[2]) & (r < thr))] = np.nan  # NaN, inf, below range_min, no return
    times = scan_beam_times(scans["time_increment"][k], len(r), path)  # checked when read
    if times is not None:
        shift = float(scans["stamp"][k]) - float(stamp)
        times = times + shift if shift else times
    return LaserScan2D(ranges=r, angles=angles.copy(), range_min=geom[2], range_max=thr, times=times)


class RosbagDataset(Dataset):
    """Frames from a ROS1 bag (``.bag``), a ROS2 bag (folder with ``metadata.yaml``) or a ROS2 storage file alone
    (``.mcap``, ``.db3``).

    Parameters
    ----------
    path : str or Path
        The bag file (ROS1), bag folder or storage file (ROS2).
    scan_topic, cloud_topic, odom_topic : str, optional
        Topics to read, each chosen on its own: the named one, or when None the one topic of its type (see the
        module docstring); ``""`` leaves that sensor (or the odometry) out.
    order : FrameOrder or str
        Frame order, default ``AUTO`` (ROS1 seq when distinct, else stamps).
    base_frame : str, optional
        Robot base frame for the extrinsics; default: the odometry's ``child_frame_id``, else ``base_link``
        or ``base_footprint`` when TF has them. A named frame must be in TF, or be a sensor's frame or the
        odometry's child frame. The grids' heights (a 3D map's slice) are measured from its z = 0: use a
        frame on the floor (``base_footprint``) where the bag has one.
    no_return : float or None
        Ranges at or above ``min(range_max - 0.05, no_return)`` are no-return and masked (NaN).
    odom_tolerance : float
        Frames more than this many seconds outside the odometry's time span get no odometry.
    sync_tolerance : float
        Largest stamp difference (s) for attaching the other sensor's message to a frame.
    drive : str, optional
        ``"scan"`` or ``"cloud"``: the sensor whose messages make the frames (default: the scans when the bag
        has a scan topic, else the clouds); :meth:`driven_by` gives the other view of the same bag.
    extrinsic2d, extrinsic3d : array_like of shape (3,) / (6,), optional
        Sensor offsets in the base frame that override TF.
    option_names : mapping, optional
        The caller's names of the options, for messages (``{"scan_topic": "--scan-topic", ...}``).
    progress : bool or None
        A progress bar while the bag is read (None: on a terminal only).

    Attributes
    ----------
    scan_topic, cloud_topic, odom_topic : str or None
        The topics actually used.
    stamps : ndarray of shape (N,)
        Frame stamps in frame order.
    order : FrameOrder
        The order actually used (never AUTO).
    driver : str
        ``"scan"`` or ``"cloud"``.
    base_frame : str or None
    extrinsic2d : ndarray of shape (3,)
    extrinsic3d : ndarray of shape (6,)
    extrinsic_found : dict
        For each sensor frame used, whether TF gave its pose in the base frame (zero otherwise).
    odometry : Trajectory or None
        Odometry at the frame stamps (frames that have one), in frame order.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        scan_topic: str | None = None,
        cloud_topic: str | None = None,
        odom_topic: str | None = None,
        order: FrameOrder | str = FrameOrder.AUTO,
        base_frame: str | None = None,
        no_return: float | None = DEFAULT_NO_RETURN,
        odom_tolerance: float = 0.5,
        sync_tolerance: float = DEFAULT_SYNC_TOLERANCE,
        drive: str | None = None,
        extrinsic2d=None,
        extrinsic3d=None,
        option_names: dict | None = None,
        progress: bool | None = False,
    ) -> None:
        self.path = str(path)
        p = Path(path)
        self.name = p.name.split(".")[0] if p.is_file() else p.name
        self._names = {**OPTION_NAMES, **(option_names or {})}
        self.order = _checked_options(self._names, order, sync_tolerance, drive)
        self.no_return = no_return
        self.odom_tolerance = float(odom_tolerance)
        self.sync_tolerance = float(sync_tolerance)
        self._progress = progress

        with BagReader.open(self.path) as bag:
            self._resolve_topics(bag, scan_topic, cloud_topic, odom_topic)
            tf = bag.static_tf()
            self._scans, self._clouds, odom, self._odom_child = bag.read_sensors(
                self.scan_topic, self.cloud_topic, self.odom_topic, self._progress, (_ROS1_SCAN_MD5, _ROS1_ODOM_MD5))
            self._odom = _production_times(odom)
            self._resolve_extrinsics(bag, tf, base_frame)
        if any(self._scans["time_increment"]):
            self.beam_time = {"field": "time_increment", "convention": "LaserScan: beam i measured i * "
                              "time_increment s after the header stamp (the first beam's)"}
        if extrinsic2d is not None:
            self.override_extrinsics(extrinsic2d=extrinsic2d, source=self._names["extrinsic2d"])
        if extrinsic3d is not None:
            self.override_extrinsics(extrinsic3d=extrinsic3d, source=self._names["extrinsic3d"])
        self._warn_missing_extrinsics()
        self._build_frames(drive or ("scan" if self.scan_topic else "cloud"))

    # -- opening and topics -------------------------------------------------------------------------
    def _resolve_topics(self, bag: BagReader, scan_topic, cloud_topic, odom_topic) -> None:
        self.scan_topic = pick_topic(bag, self.path, scan_topic, SCAN_TYPE, "2D scans", self._names["scan_topic"])
        self.cloud_topic = pick_topic(bag, self.path, cloud_topic, CLOUD_TYPE, "3D clouds",
                                       self._names["cloud_topic"])
        if self.scan_topic is None and self.cloud_topic is None:
            raise DatasetError(
                f"{self.path}: no {SCAN_TYPE} or {CLOUD_TYPE} topic to read; the bag has: {bag.topics_listing()}"
            )
        self.odom_topic = pick_topic(bag, self.path, odom_topic, ODOM_TYPE, "odometry", self._names["odom_topic"])
        self._counts = topic_counts(bag, {"scan": self.scan_topic, "cloud": self.cloud_topic,
                                           "odom": self.odom_topic})

    # -- reading ------------------------------------------------------------------------------------
    # -- extrinsics ---------------------------------------------------------------------------------
    def _sensor_frames(self) -> dict[str, str]:
        sensors = {}
        if self.scan_topic:
            sensors["2d"] = frame_name(self._scans["frame"][0])
        if self.cloud_topic:
            sensors["3d"] = frame_name(self._clouds["frame"][0])
        return sensors

    def _resolve_extrinsics(self, bag: BagReader, tf: TfTree, base_frame: str | None) -> None:
        sensors = self._sensor_frames()
        named = base_frame is not None
        if base_frame is None:
            if self._odom_child:
                base_frame = self._odom_child
            else:
                base_frame = next((b for b in ("base_link", "base_footprint") if b in tf), None)
        base = frame_name(base_frame) if base_frame else None
        found = {k: base is None or f == base or tf.lookup(base, f) is not None for k, f in sensors.items()}
        if base is not None and not all(found.values()):
            bag.dynamic_tf(tf, base, list(sensors.values()))
            found = {k: f == base or tf.lookup(base, f) is not None for k, f in sensors.items()}
        if named and base not in tf and base not in sensors.values() and base != frame_name(self._odom_child or ""):
            known = sorted(tf.frames() | set(sensors.values()) | ({frame_name(self._odom_child)} if self._odom_child else set()))
            raise DatasetError(f"{self.path}: {self._names['base_frame']} {base_frame}: no such frame in the bag's TF "
                               f"or sensor messages; its frames are: {', '.join(known) or 'none'}")
        self.base_frame = base
        self.sensor_frames = sensors
        self.extrinsic_found = {sensors[k]: bool(v and base is not None) for k, v in found.items()}
        self.extrinsic2d = np.zeros(3)
        self.extrinsic3d = np.zeros(6)
        self._tf_chains: dict[str, list[str]] = {}
        self.height2d = 0.0  # the 2D LiDAR's height above the base frame (TF), for drawing
        self._flip_scan = False
        for key in ("2d", "3d"):
            if key in sensors:
                ok = base is not None and found[key]
                self.extrinsic_sources[key] = "tf" if ok else SOURCE_DEFAULT
                if ok:
                    self._tf_chains[key] = tf.chain(base, sensors[key]) if sensors[key] != base else [base]
            else:
                self.extrinsic_sources.pop(key, None)
        if base is not None:
            self._set_tf_offsets(tf, base, {k: f for k, f in sensors.items() if found[k]})

    def _set_tf_offsets(self, tf: TfTree, base: str, sensors: dict[str, str]) -> None:
        """The offsets of the ``sensors`` (key -> frame) that TF places in ``base``."""
        if "2d" in sensors:
            T = tf.lookup(base, sensors["2d"])
            R = T[:3, :3]
            if R[2, 2] < 0:  # mounted upside down: beam angles are mirrored about the sensor's x axis
                self._flip_scan = True
                R = R @ np.diag([1.0, -1.0, -1.0])
            self.extrinsic2d = np.array([T[0, 3], T[1, 3], math.atan2(R[1, 0], R[0, 0])])
            self.height2d = float(T[2, 3])
        if "3d" in sensors:
            self.extrinsic3d = matrix_to_pose(tf.lookup(base, sensors["3d"]))

    def _warn_missing_extrinsics(self) -> None:
        """A sensor whose offset neither TF nor the caller gave: a warning (a zero offset is rarely right)."""
        what = {"2d": ("2D scans", "X,Y,YAW"), "3d": ("3D clouds", "X,Y,Z,ROLL,PITCH,YAW")}
        for key, frame in self.sensor_frames.items():
            if self.extrinsic_sources.get(key) != SOURCE_DEFAULT:
                continue
            topic = self.scan_topic if key == "2d" else self.cloud_topic
            where = (f"no transform from the base frame {self.base_frame!r} to {frame!r}" if self.base_frame
                     else "no base frame (no odometry child frame, no base_link or base_footprint in TF)")
            self._warn(f"{self.path}: {where} (the {what[key][0]} of {topic}): its offset is taken as zero; give it "
                       f"with {self._names['extrinsic' + key]} {what[key][1]}"
                       + ("" if self.base_frame else f" or name the base frame with {self._names['base_frame']}"),
                       stacklevel=4)

    # -- frames -------------------------------------------------------------------------------------
    def _order_of(self, stamps: NDArray[np.float64], seqs: Sequence) -> tuple[NDArray[np.intp], FrameOrder]:
        order = self.order
        have_seq = all(s is not None for s in seqs)
        seq = np.asarray([s if s is not None else -1 for s in seqs], dtype=np.int64)
        distinct = have_seq and len(np.unique(seq)) == len(seq)
        if order is FrameOrder.AUTO:
            order = FrameOrder.SEQ if distinct and len(seq) > 1 else FrameOrder.STAMP
            if order is FrameOrder.SEQ:
                step = np.diff(np.asarray(stamps, dtype=float)[np.argsort(seq, kind="stable")])
                if np.count_nonzero(step < 0) > np.count_nonzero(step > 0):  # seq contradicts the clock
                    self._warn(f"{self.path}: the ROS1 Header.seq of its messages runs against their stamps "
                               f"({np.count_nonzero(step < 0)} of {len(step)} steps go back in time); the frames "
                               "are ordered by stamp")
                    order = FrameOrder.STAMP
        if order is FrameOrder.SEQ:
            if not distinct:
                raise DatasetError(f"{self.path}: order='seq' needs distinct ROS1 Header.seq values, which this bag lacks")
            return np.argsort(seq, kind="stable"), order
        if order is FrameOrder.STAMP:
            return np.argsort(stamps, kind="stable"), order
        return np.arange(len(stamps)), order

    def _drop_repeated_stamps(self, stamps: NDArray[np.float64], idx: NDArray[np.intp], topic: str) -> NDArray[np.intp]:
        """``idx`` without the messages whose stamp an earlier one (in ``idx`` order) already has, with a warning:
        a trajectory has one pose per stamp."""
        _, first = np.unique(stamps[idx], return_index=True)
        if len(first) == len(idx):
            return idx
        keep = np.zeros(len(idx), dtype=bool)
        keep[first] = True
        dup = stamps[idx][~keep]
        self._warn(f"{self.path}: {len(dup)} of the {len(idx)} messages of {topic} repeat an earlier message's "
                   f"stamp (first: {dup[0]:.6f} s{'; zero stamps: the recording was not stamped' if np.any(dup == 0) else ''})"
                   "; they are dropped, one frame per stamp")
        return idx[keep]

    def _build_frames(self, driver: str) -> None:
        topic = self.scan_topic if driver == "scan" else self.cloud_topic
        if not topic:
            kind = "2D scan (sensor_msgs/LaserScan)" if driver == "scan" else "3D cloud (sensor_msgs/PointCloud2)"
            flag = self._names["scan_topic" if driver == "scan" else "cloud_topic"]
            raise DatasetError(f"{self.path}: frames made by the {driver}s need a {kind} topic, and none is used "
                               f"(name one with {flag})")
        self.driver = driver
        primary = self._scans if driver == "scan" else self._clouds
        stamps = np.asarray(primary["stamp"], dtype=float)
        idx, self.order = self._order_of(stamps, primary["seq"])
        idx = self._drop_repeated_stamps(stamps, idx, topic)
        self.stamps = stamps[idx]
        other = self._clouds if driver == "scan" else self._scans
        other_topic = self.cloud_topic if driver == "scan" else self.scan_topic
        paired = nearest_index(other["stamp"], self.stamps, self.sync_tolerance) if other_topic else None
        if driver == "scan":
            self._scan_index, self._cloud_index = idx, paired
        else:
            self._scan_index, self._cloud_index = paired, idx
        self._odometry = odometry_at(self._odom, _monotone(self.stamps), self.odom_tolerance)
        ok = ~np.isnan(self._odometry[:, 0])
        self.odometry = Trajectory(self.stamps[ok], self._odometry[ok]) if ok.any() else None
        self._beams = _BeamGeometry(self._flip_scan, self.no_return)

    def _describe(self) -> dict:
        n = len(self.stamps)
        attached = {}
        if self.driver == "scan" and self._cloud_index is not None:
            attached["frames_with_cloud"] = int((self._cloud_index >= 0).sum())
        if self.driver == "cloud" and self._scan_index is not None:
            attached["frames_with_scan"] = int((self._scan_index >= 0).sum())
        return {
            "topics": topic_summary(self._counts, self._scans, self._clouds, self._odom, self._odom_child),
            "base_frame": self.base_frame,
            "sensor_frames": dict(self.sensor_frames),
            "tf_chains": {k: " -> ".join(v) for k, v in self._tf_chains.items()},
            "height2d": self.height2d,
            "order": self.order.value,
            "sync_tolerance": self.sync_tolerance,
            "frames_with_odometry": int((~np.isnan(self._odometry[:, 0])).sum()) if n else 0,
            **attached,
        }

    def __len__(self) -> int:
        return len(self.stamps)

    def _scan(self, k: int, stamp: float) -> LaserScan2D:
        """Scan ``k`` of the bag, its beam times (if any) relative to ``stamp`` (the frame's)."""
        return _decode_scan(self._scans, k, stamp, self._beams, self.path)

    def frames(self, clouds: bool = True) -> Iterator[Frame]:
        """Yield the frames in :attr:`order` (see the module docstring); ``clouds=False`` skips the 3D clouds."""
        n = len(self.stamps)
        want = clouds and self._cloud_index is not None
        clouds = clouds_in_order(self.path, self.cloud_topic, self._cloud_index) if want else (None for _ in range(n))
        for i, got in zip(range(n), clouds, strict=True):
            odo = self._odometry[i]
            k = -1 if self._scan_index is None else int(self._scan_index[i])
            cloud, times = (None, None) if got is None else got[:2]
            if times is not None:
                if self.point_time is None:
                    self.point_time = {"field": got[2], "convention": point_time_convention(got[2])}
                # relative to the frame's stamp (a scan's, where scans make the frames)
                shift = float(self._clouds["stamp"][int(self._cloud_index[i])]) - float(self.stamps[i])
                times = times + shift if shift else times
                if not np.any(times):
                    times = None  # the whole cloud at the frame's stamp
            yield Frame(
                stamp=float(self.stamps[i]),
                scan2d=self._scan(k, self.stamps[i]) if k >= 0 else None,
                cloud3d=cloud,
                point_times=times,
                stamp_in_sweep=None if times is None else stamp_in_sweep(times),
                odometry=None if np.isnan(odo[0]) else odo.copy(),
                index=i,
                extrinsic2d=self.extrinsic2d.copy(),
                extrinsic3d=self.extrinsic3d.copy(),
            )



def _monotone(stamps: NDArray[np.float64]) -> NDArray[np.float64]:
    """Stamps in production order made non-decreasing: each becomes the earliest stamp at or after it. A
    receive stamp is no earlier than its message was made, and a message was made before every later one was
    received, so the running minimum from the end bounds each production time from above, tightly where the
    stamps are in order (they are then unchanged)."""
    t = np.minimum.accumulate(np.asarray(stamps, dtype=float)[::-1])[::-1]
    # a run of equal values (messages received in one burst) is spread evenly back to the value before it
    start = np.r_[True, t[1:] != t[:-1]]
    run = np.cumsum(start) - 1
    first = np.flatnonzero(start)
    length = np.diff(np.r_[first, len(t)])
    k = np.arange(len(t)) - first[run]
    prev = np.r_[t[0], t[first[1:] - 1]][run]
    spread = length[run] > 1
    out = t.copy()
    out[spread] = prev[spread] + (t[spread] - prev[spread]) * (k[spread] + 1) / length[run][spread]
    return out


def _production_times(odom: NDArray[np.float64]) -> NDArray[np.float64]:
    """Odometry rows (stamp, x, y, yaw, seq) as (stamp, x, y, yaw) in production order (ROS1 seq when every
    message has a distinct one) with :func:`_monotone` stamps; else as recorded."""
    seq = odom[:, 4]
    if len(odom) > 1 and (seq >= 0).all() and len(np.unique(seq)) == len(seq):
        odom = odom[np.argsort(seq, kind="stable")]
        odom[:, 0] = _monotone(odom[:, 0])
    return odom[:, :4].copy()


def adopt_odometry(dataset: RosbagDataset, source: RosbagDataset) -> RosbagDataset:
    """Give ``dataset`` the per-frame odometry of ``source``, a recording of the same scans.

    For the Freiburg logs: ``intel.orig.bag`` has the true (IPC) stamps, which join to the relations, but its
    /odom runs at its own rate with jittered stamps; ``intel.clf2bag.bag`` has made-up stamps but carries, one
    message per scan, the odometry CARMEN stored with each scan. Frame *i* of one (in seq order) is frame *i*
    of the other; this checks that their 2D scans are identical before pairing them.

    Returns
    -------
    RosbagDataset
        ``dataset`` itself, its frames and ``odometry`` now carrying ``source``'s odometry.

    Raises
    ------
    DatasetError
        The two have different frame counts, different scans, or ``source`` has no odometry for every frame.
    """
    if len(dataset) != len(source):
        raise DatasetError(
            f"{source.path} has {len(source)} frames, {dataset.path} has {len(dataset)}: not the same scans"
        )
    if dataset.driver != "scan" or source.driver != "scan":
        raise DatasetError("adopt_odometry pairs 2D scans: both datasets need frames made by their scan topic")
    for i in range(len(dataset)):
        a = dataset._scans["ranges"][int(dataset._scan_index[i])]
        b = source._scans["ranges"][int(source._scan_index[i])]
        if a.shape != b.shape or not np.array_equal(a, b, equal_nan=True):
            raise DatasetError(
                f"frame {i} of {dataset.path} and of {source.path} have different scans: not the same recording"
            )
    if np.isnan(source._odometry[:, 0]).any():
        raise DatasetError(f"{source.path} lacks odometry for {int(np.isnan(source._odometry[:, 0]).sum())} frames")
    dataset._odometry = source._odometry.copy()
    dataset.odometry = Trajectory(dataset.stamps.copy(), dataset._odometry.copy())
    return dataset
