"""The common currency of every reader: one :class:`Frame` per scan."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from ..errors import HsmapWarning, ShapeError

__all__ = ["LaserScan2D", "Frame", "Dataset", "SOURCE_INPUT", "SOURCE_DEFAULT", "stamp_in_sweep"]


@dataclass
class LaserScan2D:
    """A planar laser scan in the sensor frame.

    Attributes
    ----------
    ranges : ndarray of shape (M,)
        Metres; NaN where there is no return (readings at or beyond ``range_max`` are masked by readers).
    angles : ndarray of shape (M,)
        Beam angles in radians, counter-clockwise from the sensor's x axis.
    range_min, range_max : float
        Valid range interval of the sensor.
    times : ndarray of shape (M,) or None
        Seconds at which each beam was measured, relative to the frame's stamp (a scanner turning over its
        scan time); None for a scan taken at one instant.
    """

    ranges: NDArray[np.float64]
    angles: NDArray[np.float64]
    range_min: float = 0.0
    range_max: float = np.inf
    times: NDArray[np.float64] | None = None

    def points(self) -> NDArray[np.float64]:
        """Valid returns as (K, 2) points in the sensor frame."""
        r = np.asarray(self.ranges, dtype=float)
        ok = np.isfinite(r) & (r >= self.range_min) & (r < self.range_max)
        return np.column_stack([r[ok] * np.cos(self.angles[ok]), r[ok] * np.sin(self.angles[ok])])


@dataclass
class Frame:
    """One time step of robot data.

    Attributes
    ----------
    stamp : float
        Seconds; the scan's own timestamp (this is what trajectories are written with).
    scan2d : LaserScan2D or None
        Floor-level 2D scan, in the 2D sensor frame.
    cloud3d : ndarray of shape (N, 3) or None
        3D LiDAR points, in the 3D sensor frame.
    odometry : ndarray of shape (3,) or None
        Wheel-odometry pose (x, y, yaw) of the robot base in the odometry frame, at ``stamp``.
    index : int
        Position of the frame in its sequence.
    extrinsic2d : ndarray of shape (3,)
        Pose (x, y, yaw) of the 2D sensor in the robot base frame.
    extrinsic3d : ndarray of shape (6,)
        Pose (x, y, z, roll, pitch, yaw) of the 3D sensor in the robot base frame.
    point_times : ndarray of shape (N,) or None
        Seconds of each point of ``cloud3d`` relative to ``stamp`` (the cloud's reference time, where its
        trajectory pose is); None for a cloud taken at one instant (or deskewed already).
    stamp_in_sweep : str or None
        Where ``stamp`` lies in the sweep: ``"start"``, ``"end"`` or ``"within"``; None without point times.
    """

    stamp: float
    scan2d: LaserScan2D | None = None
    cloud3d: NDArray[np.float64] | None = None
    odometry: NDArray[np.float64] | None = None
    index: int = 0
    extrinsic2d: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    extrinsic3d: NDArray[np.float64] = field(default_factory=lambda: np.zeros(6))
    point_times: NDArray[np.float64] | None = None
    stamp_in_sweep: str | None = None


def stamp_in_sweep(times: NDArray[np.float64]) -> str:
    """Where the stamp lies in a sweep whose points have ``times`` (N,) seconds relative to it: ``"start"``
    (none before it), ``"end"`` (none after it) or ``"within"``."""
    t = np.asarray(times, dtype=float)
    if len(t) == 0 or t.min() >= 0.0:
        return "start"
    return "end" if t.max() <= 0.0 else "within"


#: Where a sensor offset came from when the reader says nothing else (a simulated folder's dataset.yaml, ...).
SOURCE_INPUT = "input"
#: No transform was found: the offset is zero.
SOURCE_DEFAULT = "default"


class Dataset:
    """What every reader returns: a sequence of :class:`Frame` plus what the source knows about itself.

    Attributes
    ----------
    name : str
        Short name for reports (file or folder stem).
    path : str
        Where it was read from.
    odometry : Trajectory or None
        Wheel odometry of the robot base at the scan stamps, when the source has it.
    groundtruth : Trajectory or None
        Ground-truth poses of the robot base at the scan stamps (simulator only).
    extrinsic_sources : dict
        ``{"2d": ..., "3d": ...}``: where each sensor offset came from: ``"tf"`` (a bag's transforms),
        ``"default"`` (none found: zero), the option that gave it (``"--extrinsic3d"`` at the command line,
        ``"extrinsic3d"`` in Python), or what the input says (``"input"``: a simulated folder's description).
    warnings : list of str
        What the reader worked around (a missing transform, ...), also issued as :class:`HsmapWarning`.
    driver : str or None
        ``"scan"`` or ``"cloud"``: the sensor whose messages make the frames, where a reader has both at their
        own rates (:meth:`driven_by`); None where every frame has both.
    """

    name: str = ""
    path: str = ""
    odometry = None
    groundtruth = None
    driver: str | None = None
    #: The per-point time field the 3D clouds were read with (``{"field", "convention"}``), or None for none.
    point_time: dict | None = None
    #: The per-beam time the 2D scans were read with (``{"field", "convention"}``), or None for none.
    beam_time: dict | None = None

    def __len__(self) -> int:
        raise NotImplementedError

    @property
    def extrinsic_sources(self) -> dict:
        return self.__dict__.setdefault("_extrinsic_sources", {"2d": SOURCE_INPUT, "3d": SOURCE_INPUT})

    @property
    def warnings(self) -> list:
        return self.__dict__.setdefault("_warnings", [])

    def override_extrinsics(self, extrinsic2d=None, extrinsic3d=None, *, source: str | None = None) -> None:
        """Replace the sensor extrinsics the source declares (e.g. a TF known to be wrong).

        Parameters
        ----------
        extrinsic2d : array_like of shape (3,), optional
            (x, y, yaw) of the 2D LiDAR in the robot base frame.
        extrinsic3d : array_like of shape (6,), optional
            (x, y, z, roll, pitch, yaw) of the 3D LiDAR in the robot base frame.
        source : str, optional
            What gave them, recorded in :attr:`extrinsic_sources` (default the argument's name).
        """

        for name, value, n in (("extrinsic2d", extrinsic2d, 3), ("extrinsic3d", extrinsic3d, 6)):
            if value is None:
                continue
            arr = np.asarray(value, dtype=float)
            if arr.shape != (n,) or not np.all(np.isfinite(arr)):
                raise ShapeError(f"{source or name} must be {n} finite numbers, got {np.asarray(value).tolist()}")
            setattr(self, name, arr)
            self.extrinsic_sources[name[-2:]] = source or name

    def driven_by(self, sensor: str) -> Dataset:
        """This dataset with frames made by ``sensor``'s messages (``"scan"`` or ``"cloud"``).

        A recording whose 2D LiDAR runs faster than its 3D one gives a 6-DOF run one frame per cloud (the
        nearest scan attached when within the reader's sync tolerance) and a 3-DOF run one frame per scan.
        Readers whose frames carry both sensors at once return themselves.
        """
        if sensor not in ("scan", "cloud"):
            from ..errors import InputError

            raise InputError(f"sensor must be 'scan' or 'cloud', got {sensor!r}")
        if self.driver is None or sensor == self.driver:
            return self
        import copy

        view = copy.copy(self)  # shares the messages read; its own frames, warnings and offset sources
        view.__dict__["_warnings"] = list(self.warnings)
        view.__dict__["_extrinsic_sources"] = dict(self.extrinsic_sources)
        view._build_frames(sensor)
        return view

    def _build_frames(self, driver: str) -> None:
        """Make the frames from ``driver``'s messages (readers with a :attr:`driver` implement it)."""
        raise NotImplementedError(f"{type(self).__name__} cannot make its frames from {driver!r} messages")

    def describe(self) -> dict:
        """What was read and how, JSON-ready (``input_info`` of a SLAM run's metrics.json).

        ``reader``, ``path``, ``frames``, ``driven_by``, ``extrinsics`` (per sensor its ``value`` and
        ``source``, see :attr:`extrinsic_sources`), ``warnings``, ``point_time`` (the clouds' per-point time
        field and its convention, :attr:`point_time`, once a cloud with one was read; else a line saying there
        was none), ``beam_time`` (the same for the 2D scans' beam times, :attr:`beam_time`), and what the reader adds (a bag's topics with
        their message counts, rates and frames, its base frame, the transforms used, the sync tolerance).
        """
        ext = {}
        for key, attr in (("2d", "extrinsic2d"), ("3d", "extrinsic3d")):
            value = getattr(self, attr, None)
            if value is not None and key in self.extrinsic_sources:
                ext[key] = {"value": [float(v) for v in np.asarray(value, dtype=float).reshape(-1)],
                            "source": self.extrinsic_sources.get(key, SOURCE_INPUT)}
        out = {"reader": type(self).__name__, "path": str(self.path), "frames": len(self),
               "driven_by": self.driver, "extrinsics": ext, "warnings": list(self.warnings),
               "point_time": self.point_time or "none: every cloud taken at its stamp",
               "beam_time": self.beam_time or "none: every 2D scan taken at its stamp"}
        out.update(self._describe())
        return out

    def _describe(self) -> dict:
        """Reader-specific entries of :meth:`describe`."""
        return {}

    def _warn(self, message: str, stacklevel: int = 3) -> None:
        """Record a warning in :attr:`warnings` and issue it as :class:`~hsmap.errors.HsmapWarning`."""
        import warnings


        self.warnings.append(message)
        warnings.warn(message, HsmapWarning, stacklevel=stacklevel)

    def frames(self, clouds: bool = True):  # -> Iterator[Frame]
        """Yield the frames in recording order; ``clouds=False`` may skip reading 3D clouds (faster 2D runs)."""
        raise NotImplementedError
