"""CARMEN logs (``.log``, ``.clf``, optionally gzip-compressed) as :class:`~hsmap.datasets.frames.Frame` sequences.

Messages read (every message line ends with ``ipc_timestamp ipc_hostname logger_timestamp``; the
``ipc_timestamp`` is each frame's stamp, the one the Freiburg ``.relations`` files use):

- ``FLASER n r_1..r_n x y theta odom_x odom_y odom_theta ...`` (front laser, old format; ``RLASER`` is the
  same for the rear laser). ``Frame.odometry`` is the odometry triple; the ``x y theta`` triple (the pose the
  log assigns to the scan: odometry in a raw log, the corrected pose in a corrected log) is kept as
  :attr:`CarmenDataset.logged_poses`. The line carries no beam geometry. **Beam angles**: the fan is
  ``fov`` wide (``PARAM laser_front_laser_fov`` in degrees when the log has it, else 180°) and centred on
  the sensor's x axis, with beam i at ``-fov/2 + i * fov / (n - 1)``: first beam on the robot's right,
  last beam exactly on its left. This is the convention of the ricoslam converter that made the ROS bags in
  ``slam2d`` (their ``angle_increment`` is pi/179 for 180 beams), so a log and its bag give identical scans.
  The other common choice, ``-fov/2 + i * fov / n``, differs by at most half a beam at the edges.
  **Extrinsic**: ``(robot_frontlaser_offset, 0, 0)`` (``robot_rearlaser_offset`` with yaw pi for RLASER)
  from the log's ``PARAM`` lines, unless ``laser_offset`` is given.
- ``ROBOTLASER1 type start_angle fov ang_res max_range accuracy remission_mode n r_1..r_n m rem_1..rem_m
  laser_x laser_y laser_theta robot_x robot_y robot_theta tv rv fwd_safety side_safety turn_axis ...``
  (``ROBOTLASER2`` for the rear laser): the line carries its geometry, beam i at ``start_angle + i * ang_res``.
  ``Frame.odometry`` and :attr:`CarmenDataset.logged_poses` are the robot pose; the extrinsic is the laser
  pose expressed in the robot pose.
- ``ODOM x y theta tv rv accel ...``: kept as :attr:`CarmenDataset.odom_messages` (the laser lines carry
  their own odometry, which the frames use).
- ``PARAM name value ...``: kept in :attr:`CarmenDataset.params` (laser offset, maximum range, fov).
- Comments (``#``), blank lines and other messages (``NEFF``, ``SYNC``, ``TRUEPOS``, ``RAWLASER*``, ...)
  are skipped; a line whose first word is not a message name at all is a corrupted line.

A line of a read message type that is truncated or holds a non-number raises
:class:`~hsmap.errors.DataFormatError` naming the file and the line number; so does a truncated gzip stream.

No-return readings are masked (NaN), as for the bags: NaN/inf, below ``range_min`` (0), or at or above
``min(max_range - 0.05, no_return)`` where ``max_range`` is the ROBOTLASER1 field or
``PARAM robot_front_laser_max`` (``robot_rear_laser_max``), and ``no_return`` defaults to 80 m (SICK lasers
in CARMEN logs report 81.83 or 81.91 m for "no return").
"""

from __future__ import annotations

import gzip
import math
import os
import re
import zlib
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..errors import DataFormatError, DatasetError
from ..geometry import relative
from ..trajectory import Trajectory
from .frames import Dataset, Frame, LaserScan2D
from .rosbag import DEFAULT_NO_RETURN, no_return_threshold

__all__ = ["CarmenDataset", "LASER_MESSAGES"]

#: Laser message types this reader understands, and which laser each one is.
LASER_MESSAGES = {"FLASER": "front", "RLASER": "rear", "ROBOTLASER1": "front", "ROBOTLASER2": "rear"}
_TAIL = 3  # ipc_timestamp ipc_hostname logger_timestamp
_MESSAGE_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")  # other well-formed names (NEFF, SYNC, ...) are skipped


def _open_text(path: Path):
    with open(path, "rb") as fh:
        magic = fh.read(2)
    if magic == b"\x1f\x8b":
        return gzip.open(path, "rt", encoding="latin-1")
    return open(path, encoding="latin-1")


class CarmenDataset(Dataset):
    """Frames from a CARMEN log, one per laser message of the chosen type.

    Parameters
    ----------
    path : str or Path
        ``.log``, ``.clf`` or their ``.gz``.
    message : str, optional
        Laser message type to read (one of :data:`LASER_MESSAGES`); default: ``ROBOTLASER1`` when the
        log has it (it carries its geometry), else ``FLASER``, else whichever laser message the log has.
    no_return : float or None
        Readings at or above ``min(max_range - 0.05, no_return)`` are masked; None trusts max_range alone.
    laser_offset : float, optional
        Forward offset (m) of the laser on the robot for FLASER/RLASER, overriding the log's PARAM.
    fov_deg : float, optional
        Field of view for FLASER/RLASER, overriding ``PARAM laser_front_laser_fov`` (default 180).

    Attributes
    ----------
    message : str
        The laser message type read.
    stamps : ndarray of shape (N,)
        ``ipc_timestamp`` of each frame, in log order.
    logged_poses : Trajectory
        The pose each laser line gives the robot (``x y theta`` of FLASER, the robot pose of ROBOTLASER1).
    odometry : Trajectory
        Raw odometry of each frame.
    odom_messages : Trajectory or None
        The ODOM lines.
    params : dict of str to str
    extrinsic2d : ndarray of shape (3,)
        Laser pose on the robot (of the first frame for ROBOTLASER, where every line has one).
    """

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        message: str | None = None,
        no_return: float | None = DEFAULT_NO_RETURN,
        laser_offset: float | None = None,
        fov_deg: float | None = None,
    ) -> None:
        p = Path(path)
        if not p.is_file():
            raise DatasetError(f"{p}: no such CARMEN log")
        self.path = str(p)
        self.name = p.name.split(".")[0]
        if message is not None and message not in LASER_MESSAGES:
            raise DatasetError(f"message must be one of {sorted(LASER_MESSAGES)}, got {message!r}")
        self.no_return = no_return
        lines = self._parse(p)
        if message is None:
            present = [m for m in ("ROBOTLASER1", "FLASER", "ROBOTLASER2", "RLASER") if lines[m]]
            if not present:
                raise DatasetError(
                    f"{p}: no laser messages ({', '.join(sorted(LASER_MESSAGES))}) in the log"
                )
            message = present[0]
        elif not lines[message]:
            have = {m: len(v) for m, v in lines.items() if v}
            raise DatasetError(f"{p}: no {message} messages in the log; it has {have or 'no messages'}")
        self.message = message
        if message.startswith("ROBOTLASER"):
            self._build_robotlaser(lines[message])
        else:
            self._build_flaser(lines[message], laser_offset, fov_deg)
        odo = lines["ODOM"]
        self.odom_messages = (
            Trajectory(np.array([o[0] for o in odo]), np.array([o[1] for o in odo])) if odo else None
        )

    # -- parsing ------------------------------------------------------------------------------------------
    def _parse(self, p: Path) -> dict[str, list]:
        lines: dict[str, list] = {m: [] for m in (*LASER_MESSAGES, "ODOM")}
        self.params: dict[str, str] = {}
        lineno = 0
        try:
            with _open_text(p) as fh:
                for lineno, line in enumerate(fh, 1):
                    parts = line.split()
                    if not parts or parts[0].startswith("#"):
                        continue
                    kind = parts[0]
                    if kind == "PARAM":
                        if len(parts) < 3:
                            raise DataFormatError(f"{p}:{lineno}: PARAM line needs a name and a value: {line.strip()!r}")
                        self.params[parts[1]] = parts[2]
                    elif kind in lines:
                        lines[kind].append(self._parse_line(kind, parts, p, lineno))
                    elif not _MESSAGE_NAME.fullmatch(kind):
                        raise DataFormatError(
                            f"{p}:{lineno}: corrupted line: {kind[:40]!r} is not a CARMEN message name"
                        )
        except (EOFError, OSError, zlib.error, gzip.BadGzipFile) as exc:
            raise DataFormatError(f"{p}:{lineno + 1}: the log is truncated or corrupted ({exc})") from None
        return lines

    @staticmethod
    def _floats(parts: list[str], p: Path, lineno: int, kind: str) -> NDArray[np.float64]:
        try:
            return np.array(parts, dtype=float)
        except ValueError:
            bad = next(v for v in parts if not _is_number(v))
            raise DataFormatError(f"{p}:{lineno}: {kind}: {bad!r} is not a number") from None

    def _parse_line(self, kind: str, parts: list[str], p: Path, lineno: int):
        def need(n_fields: int, what: str) -> None:
            if len(parts) != n_fields:
                raise DataFormatError(
                    f"{p}:{lineno}: {kind} line has {len(parts) - 1} fields, expected {n_fields - 1} ({what})"
                )

        if kind == "ODOM":
            need(1 + 6 + _TAIL, "x y theta tv rv accel ipc_timestamp host logger_timestamp")
            try:
                v = [float(x) for x in parts[1:8]]
            except ValueError:
                self._floats(parts[1:8], p, lineno, kind)  # raises, naming the bad field
            if not all(math.isfinite(x) for x in v):
                raise DataFormatError(f"{p}:{lineno}: {kind}: NaN or inf in a pose, geometry or stamp field")
            return v[6], v[:3]
        if kind in ("FLASER", "RLASER"):
            n = _count(parts, 1, p, lineno, kind)
            need(2 + n + 6 + _TAIL, f"n={n} ranges, x y theta odom_x odom_y odom_theta, ipc_timestamp host logger_timestamp")
            v = self._floats(parts[2 : 2 + n + 7], p, lineno, kind)
            _finite(v[n:], p, lineno, kind)
            return float(v[n + 6]), v[:n], v[n : n + 3], v[n + 3 : n + 6]
        # ROBOTLASER1/2
        if len(parts) < 9:
            raise DataFormatError(f"{p}:{lineno}: {kind} line is truncated ({len(parts) - 1} fields)")
        n = _count(parts, 8, p, lineno, kind)
        if len(parts) < 10 + n:
            raise DataFormatError(f"{p}:{lineno}: {kind} line is truncated: {n} ranges announced, fewer present")
        m = _count(parts, 9 + n, p, lineno, kind)
        need(10 + n + m + 11 + _TAIL, f"n={n} ranges, m={m} remissions, 11 pose/velocity fields, 3 stamp fields")
        head = self._floats(parts[1:8], p, lineno, kind)
        ranges = self._floats(parts[9 : 9 + n], p, lineno, kind)
        o = 10 + n + m
        tail = _finite(self._floats(parts[o : o + 12], p, lineno, kind), p, lineno, kind)
        _finite(head[[1, 2, 3]], p, lineno, kind)
        if head[3] == 0 or abs(head[3]) * max(n - 1, 0) > 2 * math.pi + 1e-3:
            raise DataFormatError(f"{p}:{lineno}: {kind}: angular_resolution is {head[3]!r}; expected a non-zero "
                                  f"angle step (radians) with which its {n} beams span at most a full turn")
        # head: type start_angle fov ang_res max_range accuracy remission_mode
        return float(tail[11]), ranges, head, tail[0:3], tail[3:6]

    # -- frames -------------------------------------------------------------------------------------------
    def _param(self, name: str) -> float | None:
        v = self.params.get(name)
        if v is None:
            return None
        try:
            x = float(v)
        except ValueError:
            raise DataFormatError(f"{self.path}: PARAM {name} is not a number: {v!r}") from None
        if not math.isfinite(x):
            raise DataFormatError(f"{self.path}: PARAM {name} is {v!r}; expected a finite number")
        return x

    def _build_flaser(self, rows: list, laser_offset: float | None, fov_deg: float | None) -> None:
        side = LASER_MESSAGES[self.message]
        self.stamps = np.array([r[0] for r in rows])
        self._ranges = [r[1] for r in rows]
        logged = np.array([r[2] for r in rows])
        odom = np.array([r[3] for r in rows])
        off = laser_offset if laser_offset is not None else self._param(f"robot_{side}laser_offset")
        self.extrinsic2d = np.array([off or 0.0, 0.0, 0.0 if side == "front" else math.pi])
        self.extrinsic_sources["2d"] = ("laser_offset" if laser_offset is not None else
                                        f"PARAM robot_{side}laser_offset" if off is not None else "default")
        fov = fov_deg if fov_deg is not None else self._param(f"laser_{side}_laser_fov")
        fov = 180.0 if fov is None else fov
        if not (math.isfinite(fov) and 0 < fov <= 360):
            what = "fov_deg" if fov_deg is not None else f"{self.path}: PARAM laser_{side}_laser_fov"
            raise DataFormatError(f"{what} is {fov!r}; expected a field of view in (0, 360] degrees")
        self.fov = math.radians(fov)
        max_range = self._param(f"robot_{side}_laser_max")
        self._geometry = [(-self.fov / 2.0, self.fov, max_range if max_range else np.inf)] * len(rows)
        self._extrinsics = None
        self.logged_poses = Trajectory(self.stamps, logged)
        self.odometry = Trajectory(self.stamps.copy(), odom)

    def _build_robotlaser(self, rows: list) -> None:
        self.stamps = np.array([r[0] for r in rows])
        self._ranges = [r[1] for r in rows]
        head = np.array([r[2] for r in rows])
        laser = np.array([r[3] for r in rows])
        robot = np.array([r[4] for r in rows])
        # (start_angle, span of the n beams, max_range): beam i at start + i * ang_res
        self._geometry = [
            (float(h[1]), float(h[3]) * (len(rg) - 1), float(h[4])) for h, rg in zip(head, self._ranges, strict=True)
        ]
        self._extrinsics = relative(robot, laser)
        self.extrinsic2d = self._extrinsics[0].copy()
        self.extrinsic_sources["2d"] = "ROBOTLASER laser and robot poses"
        self.fov = float(np.median(head[:, 2]))
        self.logged_poses = Trajectory(self.stamps, robot)
        self.odometry = Trajectory(self.stamps.copy(), robot.copy())

    def __len__(self) -> int:
        return len(self.stamps)

    def _scan(self, k: int) -> LaserScan2D:
        r = np.array(self._ranges[k], dtype=float)
        start, span, max_range = self._geometry[k]
        n = len(r)
        angles = start + (span / (n - 1) * np.arange(n) if n > 1 else np.zeros(n))
        thr = no_return_threshold(max_range, self.no_return)
        r[~((r >= 0.0) & (r < thr))] = np.nan  # NaN, inf, negative, no return
        return LaserScan2D(ranges=r, angles=angles, range_min=0.0, range_max=thr)

    def override_extrinsics(self, extrinsic2d=None, extrinsic3d=None, *, source: str | None = None) -> None:
        """Replace the laser extrinsic (also the per-message one of ROBOTLASER lines); see :class:`Dataset`."""
        super().override_extrinsics(extrinsic2d, extrinsic3d, source=source)
        if extrinsic2d is not None:
            self._extrinsics = None

    def frames(self, clouds: bool = True) -> Iterator[Frame]:
        """Yield one frame per laser message, in log order (CARMEN logs have no 3D clouds)."""
        for k in range(len(self.stamps)):
            yield Frame(
                stamp=float(self.stamps[k]),
                scan2d=self._scan(k),
                odometry=self.odometry.poses[k].copy(),
                index=k,
                extrinsic2d=(self._extrinsics[k] if self._extrinsics is not None else self.extrinsic2d).copy(),
            )


def _finite(v: NDArray[np.float64], p: Path, lineno: int, kind: str) -> NDArray[np.float64]:
    if not np.all(np.isfinite(v)):
        raise DataFormatError(f"{p}:{lineno}: {kind}: NaN or inf in a pose, geometry or stamp field")
    return v


def _is_number(v: str) -> bool:
    try:
        float(v)
    except ValueError:
        return False
    return True


def _count(parts: list[str], i: int, p: Path, lineno: int, kind: str) -> int:
    try:
        n = int(parts[i])
    except (ValueError, IndexError):
        raise DataFormatError(f"{p}:{lineno}: {kind}: field {i} should be a count, got {parts[i:i + 1]}") from None
    if n < 0:
        raise DataFormatError(f"{p}:{lineno}: {kind}: negative count {n}")
    return n
