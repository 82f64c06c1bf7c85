"""MRPT rawlog files (observations-only format) written from any hsmap dataset, every observation with its own stamp.

A rawlog is a gzip stream of MRPT-serialised objects. Each frame of the dataset becomes a
``CObservationOdometry`` (the frame's wheel odometry, when it has one) and a ``CObservation2DRangeScan`` (the
frame's scan), both stamped with the frame's own stamp (MRPT ticks: 100 ns since 1601-01-01), so trajectories MRPT
writes join the Freiburg relations by stamp. Beams are assumed evenly spaced (MRPT's scan model); a fan that is not
centred on the sensor's x axis has its centre added to the sensor pose's yaw. :func:`read_rawlog` reads these two
classes back (and the ``CPose2D``/``CPose3D`` inside them), for tests and checks.

    python benchmarks/rawlog.py INPUT OUT.rawlog [--max-frames N] [--extrinsic2d X,Y,YAW] [--actions]
"""

from __future__ import annotations

import argparse
import gzip
import struct
import sys
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hsmap.datasets.frames import Frame
from hsmap.errors import DataFormatError
from hsmap.geometry import relative
from hsmap.io import atomic_path

#: MRPT ticks (100 ns) from 1601-01-01 (MRPT's time origin) to 1970-01-01.
EPOCH_1601_TICKS = 116444736000000000
_END = 0x88  # MRPT's end-of-object flag
ODOMETRY_LABEL = "ODOMETRY"
LASER_LABEL = "LASER"


def to_ticks(stamp: float) -> int:
    """A stamp in seconds (Unix or log-relative) as MRPT ticks (100 ns since 1601-01-01)."""
    return int(round(float(stamp) * 1e7)) + EPOCH_1601_TICKS


def from_ticks(ticks: int) -> float:
    """MRPT ticks as seconds on the stamps' own scale (the inverse of :func:`to_ticks`)."""
    return (ticks - EPOCH_1601_TICKS) / 1e7


def _string(s: str) -> bytes:
    b = s.encode()
    return struct.pack("<I", len(b)) + b


def _object(cls: str, version: int, body: bytes) -> bytes:
    name = cls.encode()
    return bytes([0x80 | len(name)]) + name + bytes([version]) + body + bytes([_END])


def _pose2d(x: float, y: float, yaw: float) -> bytes:
    return _object("mrpt::poses::CPose2D", 1, struct.pack("<3d", x, y, yaw))


def _pose3d(x: float, y: float, yaw: float) -> bytes:
    c, s = np.cos(yaw), np.sin(yaw)
    rot = (c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0)  # row-major
    return _object("mrpt::poses::CPose3D", 3, struct.pack("<12d", x, y, 0.0, *rot))


def odometry_observation(stamp: float, pose) -> bytes:
    """One ``CObservationOdometry`` (version 2): pose (3,) = (x, y, yaw) of the base in the odometry frame."""
    x, y, yaw = (float(v) for v in pose)
    body = _pose2d(x, y, yaw) + _string(ODOMETRY_LABEL) + struct.pack("<Q", to_ticks(stamp)) + b"\x00\x00"
    return _object("mrpt::obs::CObservationOdometry", 2, body)


def scan_observation(stamp: float, ranges, angles, range_max: float, extrinsic2d) -> bytes:
    """One ``CObservation2DRangeScan`` (version 7): ranges (M,) in metres, NaN for no return, at evenly spaced
    ``angles`` (M,); the sensor at ``extrinsic2d`` (3,) on the base."""
    r = np.asarray(ranges, dtype=float)
    a = np.asarray(angles, dtype=float)
    if r.ndim != 1 or r.shape != a.shape or r.size < 2:
        raise DataFormatError(f"scan at {stamp}: expected matching ranges and angles of at least 2 beams, got "
                              f"{r.shape} and {a.shape}")
    step = np.diff(a)
    if np.ptp(step) > 1e-3 * abs(step.mean()) + 1e-9:
        raise DataFormatError(f"scan at {stamp}: beams are not evenly spaced (steps {step.min()}..{step.max()} rad)")
    aperture = float(a[-1] - a[0])
    right_to_left = aperture > 0
    centre = 0.5 * float(a[0] + a[-1])
    valid = np.isfinite(r) & (r < range_max)
    vals = np.where(valid, r, range_max).astype("<f4")
    if not right_to_left:
        vals, valid, aperture = vals[::-1], valid[::-1], -aperture
    ex, ey, eyaw = (float(v) for v in extrinsic2d)
    body = (struct.pack("<f?f", aperture, True, float(range_max)) + _pose3d(ex, ey, eyaw + centre)
            + struct.pack("<I", r.size) + vals.tobytes() + valid.astype(np.uint8).tobytes()
            + struct.pack("<fQf", 0.01, to_ticks(stamp), 0.0) + _string(LASER_LABEL)
            + struct.pack("<f?f", 0.0, False, 0.0))  # deltaPitch, no intensity, sweep duration
    return _object("mrpt::obs::CObservation2DRangeScan", 7, body)


def odometry_action(stamp: float, increment) -> bytes:
    """One ``CActionCollection`` holding a ``CActionRobotMovement2D`` (version 6, odometry with MRPT's Gaussian
    motion model at the parameters of MRPT's own sample rawlogs): ``increment`` (3,) = (dx, dy, dyaw) of the base
    since the previous frame, in the previous base frame."""
    dx, dy, dyaw = (float(v) for v in increment)
    model = struct.pack("<I6fI4f", 0, 0.01, 0.0573, 0.01745, 0.05, 0.01, 0.00873, 300, 0.15, 0.25, 0.15, 0.1)
    body = struct.pack("<I", 0) + _pose2d(dx, dy, dyaw) + model + bytes(26) + struct.pack("<Q", to_ticks(stamp))
    return _object("mrpt::obs::CActionCollection", 0,
                   struct.pack("<I", 1) + _object("mrpt::obs::CActionRobotMovement2D", 6, body))


def write_rawlog(frames: Iterable[Frame], path: str | Path, *, actions: bool = False,
                 compresslevel: int = 1) -> list[tuple[str, float]]:
    """Write ``frames`` (with a ``scan2d``) as a rawlog at ``path`` (atomically); the entries written, in order,
    as (kind, stamp), kind "odometry", "action" or "scan".

    ``actions=False``: observations only; each frame's odometry (if any) precedes its scan, both carry the frame's
    stamp. ``actions=True``: MRPT's action / sensory-frame pairs (what ``rbpf-slam`` reads); each frame's
    odometry increment since the previous frame (zero for the first, or without odometry) as an action, then a
    sensory frame holding the scan, both stamped with the frame's stamp.
    """
    entries: list[tuple[str, float]] = []
    prev = None
    with atomic_path(path) as tmp, gzip.open(tmp, "wb", compresslevel=compresslevel) as out:
        for f in frames:
            if f.scan2d is None:
                raise DataFormatError(f"{path}: frame {f.index} has no 2D scan")
            odo = f.odometry if f.odometry is not None and np.all(np.isfinite(f.odometry)) else None
            s = f.scan2d
            scan = scan_observation(f.stamp, s.ranges, s.angles, float(min(s.range_max, 1e6)), f.extrinsic2d)
            if actions:
                inc = relative(prev, odo) if prev is not None and odo is not None else np.zeros(3)
                out.write(odometry_action(f.stamp, inc))
                out.write(_object("mrpt::obs::CSensoryFrame", 2, struct.pack("<I", 1) + scan))
                entries += [("action", f.stamp), ("scan", f.stamp)]
                prev = odo if odo is not None else prev
            else:
                if odo is not None:
                    out.write(odometry_observation(f.stamp, odo))
                    entries.append(("odometry", f.stamp))
                out.write(scan)
                entries.append(("scan", f.stamp))
    return entries


@dataclass
class RawlogObservation:
    """One observation read back: ``kind`` "odometry" (``pose`` (3,)) or "scan" (``ranges`` (M,) with NaN where
    invalid, ``angles`` (M,) about the fan's centre, ``sensor_pose`` (3,) = x, y, yaw of that centre on the base,
    ``range_max``)."""

    kind: str
    stamp: float
    label: str
    pose: np.ndarray | None = None
    ranges: np.ndarray | None = None
    angles: np.ndarray | None = None
    sensor_pose: np.ndarray | None = None
    range_max: float | None = None


class _Reader:
    def __init__(self, data: bytes, where: str):
        self.b, self.i, self.where = data, 0, where

    def take(self, n: int) -> bytes:
        if self.i + n > len(self.b):
            raise DataFormatError(f"{self.where}: truncated at byte {self.i}")
        out = self.b[self.i:self.i + n]
        self.i += n
        return out

    def unpack(self, fmt: str):
        return struct.unpack(fmt, self.take(struct.calcsize(fmt)))

    def string(self) -> str:
        (n,) = self.unpack("<I")
        return self.take(n).decode()

    def header(self) -> tuple[str, int]:
        (n,) = self.unpack("<B")
        if not n & 0x80:
            raise DataFormatError(f"{self.where}: byte {self.i - 1}: expected an MRPT object header")
        return self.take(n & 0x7F).decode(), self.unpack("<B")[0]

    def end(self) -> None:
        if self.unpack("<B")[0] != _END:
            raise DataFormatError(f"{self.where}: byte {self.i - 1}: expected the end-of-object flag 0x88")

    def pose(self) -> np.ndarray:
        cls, ver = self.header()
        if cls == "mrpt::poses::CPose2D" and ver == 1:
            p = np.array(self.unpack("<3d"))
        elif cls == "mrpt::poses::CPose3D" and ver == 3:
            v = self.unpack("<12d")
            p = np.array([v[0], v[1], np.arctan2(v[6], v[3])])  # R[1,0], R[0,0] (row-major)
        else:
            raise DataFormatError(f"{self.where}: unsupported pose {cls} version {ver}")
        self.end()
        return p


def read_rawlog(path: str | Path) -> list[RawlogObservation]:
    """The entries :func:`write_rawlog` writes, read back from a rawlog (gzip or plain), in file order: odometry
    observations, scans (also inside sensory frames) and odometry actions (``kind`` "action", ``pose`` the
    increment).

    Raises
    ------
    DataFormatError
        Another class, another version of these classes, or a truncated file.
    """
    raw = Path(path).read_bytes()
    data = gzip.decompress(raw) if raw[:2] == b"\x1f\x8b" else raw
    rd = _Reader(data, str(path))
    out: list[RawlogObservation] = []
    while rd.i < len(data):
        _read_object(rd, out)
    return out


def _read_object(rd: _Reader, out: list[RawlogObservation]) -> None:
    cls, ver = rd.header()
    if cls == "mrpt::obs::CObservationOdometry" and ver == 2:
        pose = rd.pose()
        label = rd.string()
        (ticks,) = rd.unpack("<Q")
        if rd.unpack("<?")[0]:
            rd.unpack("<2i")
        if rd.unpack("<?")[0]:
            rd.unpack("<3d")
        out.append(RawlogObservation("odometry", from_ticks(ticks), label, pose=pose))
    elif cls == "mrpt::obs::CObservation2DRangeScan" and ver == 7:
        aperture, right_to_left, range_max = rd.unpack("<f?f")
        sensor = rd.pose()
        (n,) = rd.unpack("<I")
        vals = np.frombuffer(rd.take(4 * n), dtype="<f4").astype(float)
        valid = np.frombuffer(rd.take(n), dtype=np.uint8).astype(bool)
        _, ticks, _ = rd.unpack("<fQf")
        label = rd.string()
        _, has_intensity = rd.unpack("<f?")
        if has_intensity:
            rd.take(4 * n)
        rd.unpack("<f")
        ang = np.linspace(-aperture / 2, aperture / 2, n)  # in the frame of sensor_pose
        if not right_to_left:
            ang = ang[::-1]
        out.append(RawlogObservation("scan", from_ticks(ticks), label, ranges=np.where(valid, vals, np.nan),
                                     angles=ang, sensor_pose=sensor, range_max=float(range_max)))
    elif cls in ("mrpt::obs::CActionCollection", "mrpt::obs::CSensoryFrame") and ver in (0, 2):
        (n,) = rd.unpack("<I")
        for _ in range(n):
            _read_object(rd, out)
    elif cls == "mrpt::obs::CActionRobotMovement2D" and ver == 6:
        if rd.unpack("<I")[0] != 0:
            raise DataFormatError(f"{rd.where}: byte {rd.i}: only odometry actions are read")
        inc = rd.pose()
        rd.take(48 + 26)  # motion model, no encoders, no velocities
        (ticks,) = rd.unpack("<Q")
        out.append(RawlogObservation("action", from_ticks(ticks), "", pose=inc))
    else:
        raise DataFormatError(f"{rd.where}: unsupported object {cls} version {ver}")
    rd.end()


def main(argv=None) -> int:
    from hsmap.datasets.open import open_dataset

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("input", help="anything hsmap reads (a ROS bag, a CARMEN log, ...)")
    ap.add_argument("out", help="the rawlog to write")
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--extrinsic2d", default=None, help="x,y,yaw of the laser on the base, instead of the input's")
    ap.add_argument("--actions", action="store_true", help="action / sensory-frame pairs (rbpf-slam)")
    args = ap.parse_args(argv)
    ext = [float(v) for v in args.extrinsic2d.split(",")] if args.extrinsic2d else None
    ds = open_dataset(args.input, extrinsic2d=ext)
    frames = (f for k, f in zip(range(args.max_frames or len(ds)), ds.frames(clouds=False), strict=False))
    entries = write_rawlog(frames, args.out, actions=args.actions)
    print(f"wrote {sum(k == 'scan' for k, _ in entries)} frames to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
