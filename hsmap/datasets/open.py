"""One entry point for every input: :func:`open_dataset` picks the reader from what ``path`` is."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ..errors import DatasetError
from .frames import Dataset

__all__ = ["open_dataset", "CARMEN_SUFFIXES", "BAG_SUFFIXES"]

#: File endings read as CARMEN logs.
CARMEN_SUFFIXES = (".log", ".clf", ".gz")
#: File endings read as bags: ROS1, and the ROS2 storage files (alone or in their bag folder).
BAG_SUFFIXES = (".bag", ".mcap", ".db3")

#: Options only some readers take, with the kinds of input that take them.
_BAG_OPTIONS = ("scan_topic", "cloud_topic", "odom_topic", "base_frame")
_FOLDER_OPTIONS = ("cloud_rate", "scans", "scan_rate", "times")


def open_dataset(
    path: str | os.PathLike,
    *,
    scan_topic: str | None = None,
    cloud_topic: str | None = None,
    odom_topic: str | None = None,
    extrinsic2d=None,
    extrinsic3d=None,
    base_frame: str | None = None,
    sync_tolerance: float | None = None,
    drive: str | None = None,
    cloud_rate: float | None = None,
    scans: str | os.PathLike | None = None,
    scan_rate: float | None = None,
    times: str | os.PathLike | None = None,
    option_names: Mapping[str, str] | None = None,
    progress: bool | None = False,
) -> Dataset:
    """Open a simulator folder, a ROS1/ROS2 bag, a CARMEN log or a folder of point clouds.

    Parameters
    ----------
    path : str or Path
        - a folder with ``dataset.yaml``: the simulator's output (:class:`hsmap.datasets.simulated.SimulatedDataset`);
        - a ``.bag`` file (ROS1), a ROS2 bag folder (with ``metadata.yaml``), or a ROS2 ``.mcap``/``.db3``
          storage file, in its folder or alone: :class:`hsmap.datasets.rosbag.RosbagDataset`;
        - a ``.log``/``.clf`` file or its ``.gz``: :class:`hsmap.datasets.carmen.CarmenDataset`;
        - a folder of ``.pcd``/``.ply``/KITTI ``.bin``/``.csv`` clouds (natural order, stamps from a ``times.txt``,
          ``times`` or ``cloud_rate``): :class:`hsmap.datasets.clouds.CloudFolderDataset`.
    scan_topic, cloud_topic, odom_topic, base_frame : str, optional
        Bags only: topics (each auto-detected by message type when None, ``""`` for none) and the robot base frame.
    extrinsic2d, extrinsic3d : array_like of shape (3,) / (6,), optional
        Override the sensor extrinsics the input declares. For example, the fr079 bag's TF puts the laser
        0.04 m forward while the CARMEN log's PARAM says 0.04 m back; the Freiburg relations agree with the PARAM.
    sync_tolerance : float, optional
        Bags and cloud folders: the largest stamp difference (s) between a frame and the other sensor's message
        attached to it (default :data:`hsmap.datasets.rosbag.DEFAULT_SYNC_TOLERANCE`).
    drive : str, optional
        ``"scan"`` or ``"cloud"``: which sensor's messages make the frames where an input has both at their own
        rates (bags, cloud folders); default the scans when there are any. A 6-DOF run wants ``"cloud"``.
    cloud_rate, scans, scan_rate, times :
        Cloud folders only: the clouds' rate (Hz) instead of a ``times.txt``, a folder of 2D scans, their rate, the
        clouds' stamps file (one a line, or a TUM trajectory) instead of a ``times.txt``.
    option_names : mapping, optional
        The caller's names of these options, used in messages (the command line passes its flags:
        ``{"scan_topic": "--scan-topic", ...}``).
    progress : bool or None
        A progress bar while a bag is read (None: on a terminal only).

    Raises
    ------
    DatasetError
        ``path`` does not exist, is none of the above, options are given for an input that does not take them,
        or the simulated-dataset reader is not available.
    """
    from .rosbag import OPTION_NAMES

    names = {**OPTION_NAMES, "cloud_rate": "cloud_rate", "scans": "scans", "scan_rate": "scan_rate",
             "times": "times", **(option_names or {})}
    p = Path(path)
    if not p.exists():
        raise DatasetError(f"{p}: no such file or folder")
    if not (p.is_dir() or p.is_file()):  # a device, pipe or socket (a link to /dev/zero): never ends
        raise DatasetError(f"{p}: not a regular file or a folder{f' (a link to {p.resolve()})' if p.is_symlink() else ''}"
                           "; expected a recording file or folder")
    options = {"scan_topic": scan_topic, "cloud_topic": cloud_topic, "odom_topic": odom_topic, "base_frame": base_frame,
               "cloud_rate": cloud_rate, "scans": scans, "scan_rate": scan_rate, "times": times,
               "extrinsic2d": extrinsic2d, "extrinsic3d": extrinsic3d, "sync_tolerance": sync_tolerance, "drive": drive}
    return _reader(p, _kind(p), options, names, progress)


def _reader(p: Path, kind: str, options: dict[str, Any], names: Mapping[str, str], progress: bool | None
            ) -> Dataset:
    """The reader of ``p``, a ``kind`` of input (:func:`_kind`), with :func:`open_dataset`'s ``options`` (None:
    not given); an option given for an input that does not take it is a DatasetError naming it by ``names``."""
    from .rosbag import DEFAULT_SYNC_TOLERANCE

    o = options
    given = [k for k in (*_BAG_OPTIONS, *_FOLDER_OPTIONS) if o[k] is not None]
    tol = DEFAULT_SYNC_TOLERANCE if o["sync_tolerance"] is None else o["sync_tolerance"]

    def only(allowed: tuple[str, ...]) -> None:
        wrong = [names[k] for k in given if k not in allowed]
        if wrong:
            raise DatasetError(f"{p}: {', '.join(wrong)} do not apply to a {kind}")

    if kind in ("ROS bag", "ROS2 bag folder"):
        only(_BAG_OPTIONS)
        from .rosbag import RosbagDataset

        return RosbagDataset(p, scan_topic=o["scan_topic"], cloud_topic=o["cloud_topic"], odom_topic=o["odom_topic"],
                             base_frame=o["base_frame"], sync_tolerance=tol, drive=o["drive"],
                             extrinsic2d=o["extrinsic2d"], extrinsic3d=o["extrinsic3d"], option_names=names,
                             progress=progress)
    if kind == "point-cloud folder":
        only(_FOLDER_OPTIONS)
        from .clouds import CloudFolderDataset

        return CloudFolderDataset(p, cloud_rate=o["cloud_rate"], scans=o["scans"], scan_rate=o["scan_rate"],
                                  sync_tolerance=tol, drive=o["drive"], extrinsic2d=o["extrinsic2d"],
                                  extrinsic3d=o["extrinsic3d"], times=o["times"], option_names=names)
    only(())
    if kind == "simulated dataset folder":
        try:
            from .simulated import SimulatedDataset
        except ImportError as exc:
            raise DatasetError(
                f"{p}: a simulated dataset folder, but its reader hsmap.datasets.simulated is not available ({exc})"
            ) from None
        ds: Dataset = SimulatedDataset(p)
    else:
        from .carmen import CarmenDataset

        ds = CarmenDataset(p)
    for key in ("extrinsic2d", "extrinsic3d"):
        if o[key] is not None:
            ds.override_extrinsics(**{key: o[key]}, source=names.get(key, key))
    return ds


def _kind(p: Path) -> str:
    """What ``p`` is, or a DatasetError saying what was expected."""
    if p.is_dir():
        if (p / "dataset.yaml").is_file():
            return "simulated dataset folder"
        if (p / "metadata.yaml").is_file():
            return "ROS2 bag folder"
        from .clouds import is_cloud_folder

        if is_cloud_folder(p):
            return "point-cloud folder"
        raise DatasetError(
            f"{p}: a folder with neither dataset.yaml (simulator output), metadata.yaml (ROS2 bag) nor point-cloud "
            "files (.pcd, .ply, KITTI .bin, .csv)"
        )
    suffix = p.suffix.lower()
    if suffix in BAG_SUFFIXES:
        return "ROS bag"
    if suffix in CARMEN_SUFFIXES:
        return "CARMEN log"
    raise DatasetError(
        f"{p}: unknown input type {suffix or '(no suffix)'!r}; expected a simulator folder (dataset.yaml), a ROS1 "
        f".bag, a ROS2 bag folder or .mcap/.db3 file, a CARMEN log ({', '.join(CARMEN_SUFFIXES)}) or a folder of "
        "point clouds"
    )
