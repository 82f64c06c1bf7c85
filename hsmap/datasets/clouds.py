"""A folder of point clouds (``.pcd``, ``.ply``, KITTI ``.bin``, ``.csv``) as a recording, optionally with a folder
of 2D scans beside it.

Layout
------
- The clouds: one file per 3D LiDAR sweep, in the 3D sensor's frame, in **natural order** of their names (digit
  runs compared as numbers: ``full2`` before ``full10``; KITTI's zero-padded ``000000.bin`` as they sort; names that
  are decimal numbers, such as stamps, by value). One kind of file per folder:

  - ``.pcd``: ``DATA ascii``, ``binary`` or ``binary_compressed`` (:mod:`hsmap.datasets.pcd`), any fields
    beside ``x y z``;
  - ``.ply``: read with Open3D (ASCII or binary);
  - ``.bin``: KITTI Velodyne, float32 ``x y z intensity`` per point (16 bytes);
  - ``.csv`` (or ``.txt``): one point per line, ``x y [z]`` separated by commas or spaces, ``#`` comments.

  Points at exactly (0, 0, 0) and non-finite ones are no returns and are dropped.
- Files that are not clouds are left out, with one note (:class:`~hsmap.errors.HsmapNote`) naming them and why:
  files of other endings (``README.md``), text files (``.csv``/``.txt``) beside ``.pcd``/``.ply``/``.bin`` clouds
  (poses, calibration), and, where most files are numbered alike (``full#.pcd``), the files not named so. Two
  kinds of cloud file (``.pcd`` and ``.ply``) are an error naming them.
- The stamps (seconds), one per cloud in natural order: a stamps file given as ``times`` (``--times FILE``), else
  a ``times.txt`` in the folder or beside it (KITTI's ``sequences/NN/times.txt`` next to ``velodyne/``). A stamps
  file holds one stamp a line, or is a TUM trajectory (``t x y z qx qy qz qw``, its first column taken). Or a fixed
  rate (``cloud_rate``, ``--cloud-rate HZ``: file *k* at *k* / rate), which wins over a ``times.txt``.
- Optionally the 2D scans (``scans``, ``--scans DIR``): a folder of the same kinds of files, each a 2D LiDAR
  scan as points in the 2D sensor's frame (z ignored), with its own ``times.txt`` or rate (``scan_rate``,
  ``--scan-rate HZ``).

With both sensors, frames are made by one of them (``drive``: the scans by default, the clouds for a 6-DOF run,
:meth:`CloudFolderDataset.driven_by`) and the other's nearest file within ``sync_tolerance`` is attached, as
for a bag (:mod:`hsmap.datasets.rosbag`). A folder has no transforms and no odometry. Clouds alone (no 2D scans)
are posed in their own frame: the robot base is the 3D sensor (a hand-held LiDAR), its offset zero without a
warning (source :data:`SOURCE_SENSOR`); ``extrinsic3d`` gives one where a base matters. With 2D scans too, the
offsets are zero unless given (``extrinsic2d``/``extrinsic3d``), with a warning.
"""

from __future__ import annotations

import math
import os
import re
import warnings
from collections import Counter
from collections.abc import Iterator
from decimal import Decimal
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..errors import DataFormatError, DatasetError, HsmapNote, InputError
from ..io import read_number_rows
from ..limits import check_allocation
from ..trajectory import nearest_index
from .frames import SOURCE_DEFAULT, Dataset, Frame, LaserScan2D, stamp_in_sweep
from .point_files import read_points, read_points_timed

__all__ = ["CloudFolderDataset", "CLOUD_SUFFIXES", "SOURCE_SENSOR", "is_cloud_folder", "natural_key",
           "cloud_files", "read_stamps", "read_points", "read_points_timed"]

#: File endings read as point clouds (``.txt`` as ``.csv``).
CLOUD_SUFFIXES = (".pcd", ".ply", ".bin", ".csv", ".txt")
TIMES = "times.txt"
#: The offset source of clouds alone: posed in their own frame.
SOURCE_SENSOR = "sensor frame (clouds alone)"
_TEXT = (".csv", ".txt")
#: Names listed per reason in the note on files left out.
_NOTE_NAMES = 6

_OPTION_NAMES = {"cloud_rate": "cloud_rate", "scans": "scans", "scan_rate": "scan_rate",
                 "sync_tolerance": "sync_tolerance", "drive": "drive", "extrinsic2d": "extrinsic2d",
                 "extrinsic3d": "extrinsic3d", "times": "times"}


def natural_key(name: str) -> tuple:
    """Sort key of a file name in natural order: digit runs compared as numbers (``full2`` before ``full10``); a
    name whose stem is a decimal number (a stamp, ``1630577758.5690``) by its value, before other names."""
    stem = name[: -len(Path(name).suffix)] if Path(name).suffix else name
    if re.fullmatch(r"\d+(\.\d+)?", stem):
        return (0, (Decimal(stem),), name)
    parts = tuple((0, int(t), "") if t.isdigit() else (1, 0, t) for t in re.split(r"(\d+)", stem) if t)
    return (1, parts, name)


def _pattern(name: str) -> str:
    """A file name with its digit runs as ``#`` and its ending in lower case (``full#.pcd``)."""
    p = Path(name)
    return re.sub(r"\d+", "#", name[: len(name) - len(p.suffix)]) + p.suffix.lower()


def _candidates(folder: Path, skip: set[str]) -> tuple[list[Path], dict[str, list[str]]]:
    """The files of ``folder`` with a cloud ending (but ``skip``), and the others by why they are left out."""
    left: dict[str, list[str]] = {}
    found = []
    for f in folder.iterdir():
        if f.name.startswith(".") or f.name in skip or not f.is_file():
            continue
        if f.suffix.lower() in CLOUD_SUFFIXES:
            found.append(f)
        else:
            left.setdefault("not a cloud file", []).append(f.name)
    return found, left


def cloud_files(folder: str | os.PathLike, skip: tuple[str, ...] = (), what: str = "cloud"
                ) -> tuple[list[Path], dict[str, list[str]]]:
    """The cloud files of ``folder`` in natural order (:func:`natural_key`), and the files left out, by why.

    Left out: ``times.txt`` and ``skip`` (without a word), hidden files and folders, files of other endings, text
    files (``.csv``/``.txt``) beside binary clouds (``.pcd``/``.ply``/``.bin``) and, where more than half the files
    are numbered alike (``full#.pcd``), those named otherwise.

    Raises
    ------
    DatasetError
        The folder holds two kinds of cloud file (naming them).
    """
    folder = Path(folder)
    found, left = _candidates(folder, {TIMES, *skip})
    binary = sorted({f.suffix.lower() for f in found} - set(_TEXT))
    if binary:
        text = [f for f in found if f.suffix.lower() in _TEXT]
        if text:
            left.setdefault(f"text beside the {' and '.join(binary)} {what}s", []).extend(f.name for f in text)
            found = [f for f in found if f.suffix.lower() not in _TEXT]
    kinds = sorted({f.suffix.lower() for f in found})
    if len(kinds) > 1:
        raise DatasetError(f"{folder}: holds {' and '.join(kinds)} files; expected one kind of {what} file")
    if found:
        counts = Counter(_pattern(f.name) for f in found)
        top, n = max(counts.items(), key=lambda kv: (kv[1], kv[0]))
        if "#" in top and n > len(found) / 2 and n < len(found):
            others = [f for f in found if _pattern(f.name) != top]
            left.setdefault(f"not named like the numbered {what}s {top}", []).extend(f.name for f in others)
            found = [f for f in found if _pattern(f.name) == top]
    return sorted(found, key=lambda f: natural_key(f.name)), left


def _left_out_note(folder: Path, left: dict[str, list[str]], what: str) -> str:
    """One line naming the files left out of ``folder`` and why."""
    parts = []
    for why, names in left.items():
        names = sorted(names, key=natural_key)
        shown = ", ".join(names[:_NOTE_NAMES]) + (f" and {len(names) - _NOTE_NAMES} more" if len(names) >
                                                  _NOTE_NAMES else "")
        parts.append(f"{shown} ({why})")
    n = sum(len(v) for v in left.values())
    return f"{folder}: {n} file{'s' if n > 1 else ''} not read as {what}s: {'; '.join(parts)}"


def _listed(names: list[str], most: int = 20) -> list[str]:
    """``names`` in natural order, at most ``most`` of them and a last ``"... and N more"``."""
    names = sorted(names, key=natural_key)
    return names if len(names) <= most else names[:most] + [f"... and {len(names) - most} more"]


def is_cloud_folder(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a folder holding point-cloud files (and no bag or simulator description)."""
    p = Path(path)
    return p.is_dir() and bool(_candidates(p, {TIMES})[0])


def read_stamps(path: str | os.PathLike) -> tuple[NDArray[np.float64], str]:
    """The stamps (seconds) of a stamps file: one a line, or a TUM trajectory (``t x y z qx qy qz qw``; its first
    column); ``#`` lines and blank lines skipped. Also what the file is (``"stamps"`` or ``"TUM trajectory"``).

    Raises
    ------
    DatasetError
        No such file.
    DataFormatError
        A line holds neither one number nor a TUM line's eight (naming the file and line), or no line holds any.
    """
    p = Path(path)
    if not p.is_file():
        raise DatasetError(f"{p}: no such file; expected a stamps file (one a line, or a TUM trajectory)")
    check_allocation(float(p.stat().st_size) * 16, f"{p}: a stamps file of {p.stat().st_size} bytes",
                     DataFormatError)
    width, at = None, 0
    with open(p, encoding="utf-8", errors="replace") as fh:
        for line in fh:
            at += 1
            text = line.strip()
            if text and not text.startswith("#"):
                width = len(text.replace(",", " ").split())
                break
    if width not in (None, 1, 8):
        raise DataFormatError(f"{p}:{at}: expected one stamp a line or a TUM trajectory line (t x y z qx qy "
                              f"qz qw), got {width} values")
    tum = width == 8
    rows = read_number_rows(p, "t x y z qx qy qz qw" if tum else "t", "stamps")
    return rows[:, 0].astype(float), "TUM trajectory" if tum else "stamps"


def _scan_from_points(pts: NDArray[np.float64]) -> LaserScan2D:
    xy = pts[:, :2]
    r = np.hypot(xy[:, 0], xy[:, 1])
    a = np.arctan2(xy[:, 1], xy[:, 0])
    order = np.argsort(a, kind="stable")
    return LaserScan2D(ranges=r[order], angles=a[order])


class _Stream:
    """One sensor's files and stamps; ``left_out``: the folder's files that are not its data, by why."""

    def __init__(self, folder: Path, rate: float | None, what: str, folder_flag: str, rate_flag: str,
                 times: str | os.PathLike | None = None, times_flag: str | None = None) -> None:
        if not folder.is_dir():
            raise DatasetError(f"{folder_flag} {folder}: no such folder; expected a folder of {what} files "
                               f"({', '.join(CLOUD_SUFFIXES)})")
        self.folder = folder
        if times is not None and rate is not None:
            raise InputError(f"{times_flag} and {rate_flag} both give the {what}s' stamps; give one of them")
        times = None if times is None else Path(times)
        skip = (times.name,) if times is not None and times.parent.resolve() == folder.resolve() else ()
        self.files, self.left_out = cloud_files(folder, skip, what)
        if self.left_out:  # before the stamps are counted against the files
            warnings.warn(_left_out_note(folder, self.left_out, what), HsmapNote, stacklevel=3)
        if not self.files:
            raise DatasetError(f"{folder_flag} {folder}: no {what} files ({', '.join(CLOUD_SUFFIXES)})")
        self.kind = self.files[0].suffix.lower()
        n = len(self.files)
        if rate is not None:
            if not (math.isfinite(rate) and rate > 0):
                raise InputError(f"{rate_flag} must be a rate in Hz > 0, got {rate!r}")
            self.stamps = np.arange(n) / float(rate)
            self.stamp_source = f"{rate_flag} {rate:g}"
            return
        if times is None:
            times = next((t for t in (folder / TIMES, folder.parent / TIMES) if t.is_file()), None)
        elif not times.is_file():
            raise DatasetError(f"{times_flag} {times}: no such file; expected the {what}s' stamps, one a line or a "
                               "TUM trajectory")
        if times is None:
            give = f"stamps with {times_flag} FILE (one a line, or a TUM trajectory) or their " if times_flag else ""
            raise DatasetError(f"{folder}: no {TIMES} in the folder or beside it; give the {what}s' {give}rate "
                               f"with {rate_flag} HZ")
        stamps, kind = read_stamps(times)
        if len(stamps) != n:
            raise DataFormatError(f"{times}: {len(stamps)} stamps{' (a TUM trajectory)' if kind != 'stamps' else ''} "
                                  f"for the {n} {what} files of {folder}; expected one per file, in natural order")
        self.stamps = stamps
        if not np.all(np.isfinite(self.stamps)) or np.any(np.diff(self.stamps) <= 0):
            raise DataFormatError(f"{times}: stamps must be finite and increase from line to line (the files' "
                                  "natural order)")
        self.stamp_source = str(times)

    def describe(self) -> dict:
        st = self.stamps
        return {"folder": str(self.folder), "files": len(self.files), "kind": self.kind,
                "first": self.files[0].name, "last": self.files[-1].name,
                "left_out": {why: _listed(names) for why, names in self.left_out.items()},
                "stamps": self.stamp_source,
                "rate_hz": (len(st) - 1) / float(st[-1] - st[0]) if len(st) > 1 else None}


class CloudFolderDataset(Dataset):
    """Frames from a folder of point clouds, optionally with a folder of 2D scans (see the module docstring).

    Parameters
    ----------
    path : str or Path
        The clouds folder.
    cloud_rate : float, optional
        Hz: file *k* is stamped *k* / rate (instead of a ``times.txt``).
    scans : str or Path, optional
        A folder of 2D scans.
    scan_rate : float, optional
        Hz, for the scans (instead of their ``times.txt``).
    sync_tolerance : float
        Largest stamp difference (s) for attaching the other sensor's file to a frame.
    drive : str, optional
        ``"scan"`` or ``"cloud"``: the sensor whose files make the frames (default the scans when given).
    extrinsic2d, extrinsic3d : array_like of shape (3,) / (6,), optional
        The sensors' poses in the robot base frame. Not given: zero; with 2D scans, with a warning; for clouds
        alone without one (the base is the 3D sensor, source :data:`SOURCE_SENSOR`).
    times : str or Path, optional
        The clouds' stamps file (one a line, or a TUM trajectory), instead of a ``times.txt``.
    option_names : mapping, optional
        The caller's names of the options, for messages (``{"cloud_rate": "--cloud-rate", ...}``).
    """

    def __init__(self, path: str | os.PathLike, *, cloud_rate: float | None = None, scans: str | os.PathLike | None = None,
                 scan_rate: float | None = None, sync_tolerance: float = 0.1, drive: str | None = None,
                 extrinsic2d=None, extrinsic3d=None, times: str | os.PathLike | None = None,
                 option_names: dict | None = None) -> None:
        names = {**_OPTION_NAMES, **(option_names or {})}
        self._names = names
        p = Path(path)
        self.path = str(p)
        self.name = p.name
        if not (math.isfinite(float(sync_tolerance)) and float(sync_tolerance) >= 0):
            raise InputError(f"{names['sync_tolerance']} must be a number of seconds >= 0, got {sync_tolerance!r}")
        self.sync_tolerance = float(sync_tolerance)
        if drive not in (None, "scan", "cloud"):
            raise InputError(f"{names['drive']} must be 'scan' or 'cloud', got {drive!r}")
        if scan_rate is not None and scans is None:
            raise InputError(f"{names['scan_rate']} needs a folder of 2D scans ({names['scans']} DIR)")
        self.cloud_rate, self.scan_rate = cloud_rate, scan_rate
        # read too: part of the input's identity
        self.extra_paths = ([] if scans is None else [str(scans)]) + ([] if times is None else [str(times)])
        self._clouds = _Stream(p, cloud_rate, "cloud", "input", names["cloud_rate"], times, names["times"])
        self._scans = None if scans is None else _Stream(Path(scans), scan_rate, "scan", names["scans"],
                                                        names["scan_rate"])
        self.extrinsic2d = np.zeros(3) if self._scans is not None else None
        self.extrinsic3d = np.zeros(6)
        self.extrinsic_sources.clear()
        self.extrinsic_sources["3d"] = SOURCE_DEFAULT if self._scans is not None else SOURCE_SENSOR
        if self._scans is not None:
            self.extrinsic_sources["2d"] = SOURCE_DEFAULT
        if extrinsic3d is not None:
            self.override_extrinsics(extrinsic3d=extrinsic3d, source=names["extrinsic3d"])
        if extrinsic2d is not None:
            if self._scans is None:
                raise InputError(f"{names['extrinsic2d']} is the 2D LiDAR's offset, and there are no 2D scans "
                                 f"({names['scans']} DIR)")
            self.override_extrinsics(extrinsic2d=extrinsic2d, source=names["extrinsic2d"])
        for key, sig in (("2d", "X,Y,YAW"), ("3d", "X,Y,Z,ROLL,PITCH,YAW")):
            if self.extrinsic_sources.get(key) == SOURCE_DEFAULT:
                what = "2D scans" if key == "2d" else "3D clouds"
                self._warn(f"{self.path}: a folder has no transforms: the offset of the {what} in the robot base "
                           f"frame is taken as zero; give it with {names['extrinsic' + key]} {sig}")
        self._build_frames(drive or ("scan" if self._scans is not None else "cloud"))

    def _build_frames(self, driver: str) -> None:
        if driver == "scan" and self._scans is None:
            raise DatasetError(f"{self.path}: frames made by 2D scans need a folder of them ({self._names['scans']} DIR)")
        self.driver = driver
        if driver == "cloud":
            self.stamps = self._clouds.stamps.copy()
            self._cloud_index = np.arange(len(self.stamps))
            self._scan_index = (None if self._scans is None else
                                nearest_index(self._scans.stamps, self.stamps, self.sync_tolerance))
        else:
            self.stamps = self._scans.stamps.copy()
            self._scan_index = np.arange(len(self.stamps))
            self._cloud_index = nearest_index(self._clouds.stamps, self.stamps, self.sync_tolerance)

    def __len__(self) -> int:
        return len(self.stamps)

    def _describe(self) -> dict:
        out = {"clouds": self._clouds.describe(), "sync_tolerance": self.sync_tolerance}
        if self._scans is not None:
            out["scans"] = self._scans.describe()
        return out

    def frames(self, clouds: bool = True) -> Iterator[Frame]:
        for i, t in enumerate(self.stamps):
            k = -1 if self._scan_index is None else int(self._scan_index[i])
            c = int(self._cloud_index[i])
            cloud = times = None
            if clouds and c >= 0:
                cstamp = float(self._clouds.stamps[c])
                cloud, times, field = read_points_timed(self._clouds.files[c], cstamp)
                if times is not None:
                    if self.point_time is None:
                        from .ros_messages import point_time_convention

                        self.point_time = {"field": field, "convention": point_time_convention(field)}
                    times = times + (cstamp - float(t))  # relative to the frame's stamp
                    if not np.any(times):
                        times = None
            yield Frame(
                stamp=float(t),
                scan2d=_scan_from_points(read_points(self._scans.files[k])) if k >= 0 else None,
                cloud3d=cloud,
                point_times=times,
                stamp_in_sweep=None if times is None else stamp_in_sweep(times),
                index=i,
                extrinsic2d=np.zeros(3) if self.extrinsic2d is None else self.extrinsic2d.copy(),
                extrinsic3d=self.extrinsic3d.copy(),
            )
