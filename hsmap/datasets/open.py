"""One entry point for every input: :func:`open_dataset` picks the reader from what ``path`` is."""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import DatasetError
from .frames import Dataset

__all__ = ["open_dataset", "CARMEN_SUFFIXES"]

#: File endings read as CARMEN logs.
CARMEN_SUFFIXES = (".log", ".clf", ".gz")


def open_dataset(
    path: str | os.PathLike,
    *,
    scan_topic: str | None = None,
    cloud_topic: str | None = None,
    odom_topic: str | None = None,
    extrinsic2d=None,
    extrinsic3d=None,
) -> Dataset:
    """Open a simulator folder, a ROS1/ROS2 bag or a CARMEN log.

    Parameters
    ----------
    path : str or Path
        - a folder with ``dataset.yaml``: the simulator's output (:class:`hsmap.datasets.simulated.SimulatedDataset`);
        - a ``.bag`` file (ROS1), or a ROS2 bag folder (with ``metadata.yaml``) or its ``.db3``/``.mcap``
          file: :class:`hsmap.datasets.rosbag.RosbagDataset`;
        - a ``.log``/``.clf`` file or its ``.gz``: :class:`hsmap.datasets.carmen.CarmenDataset`.
    scan_topic, cloud_topic, odom_topic : str, optional
        Bag topics (auto-detected by message type when None); only meaningful for bags.
    extrinsic2d, extrinsic3d : array_like of shape (3,) / (6,), optional
        Override the sensor extrinsics the input declares (see :meth:`Dataset.override_extrinsics`). For
        example, the fr079 bag's TF puts the laser 0.04 m forward while the CARMEN log's PARAM says 0.04 m back;
        the Freiburg relations agree with the PARAM.

    Raises
    ------
    DatasetError
        ``path`` does not exist, is none of the above, topics are given for a non-bag input, or the
        simulated-dataset reader is not available.
    """
    ds = _open(Path(path), scan_topic, cloud_topic, odom_topic)
    if extrinsic2d is not None or extrinsic3d is not None:
        ds.override_extrinsics(extrinsic2d, extrinsic3d)
    return ds


def _open(p: Path, scan_topic: str | None, cloud_topic: str | None, odom_topic: str | None) -> Dataset:
    if not p.exists():
        raise DatasetError(f"{p}: no such file or folder")
    topics = {"scan_topic": scan_topic, "cloud_topic": cloud_topic, "odom_topic": odom_topic}
    given = [k for k, v in topics.items() if v is not None]

    def no_topics(kind: str) -> None:
        if given:
            raise DatasetError(f"{p}: {', '.join(given)} only apply to ROS bags, and this is a {kind}")

    if p.is_dir():
        if (p / "dataset.yaml").is_file():
            no_topics("simulated dataset folder")
            try:
                from .simulated import SimulatedDataset
            except ImportError as exc:
                raise DatasetError(
                    f"{p}: a simulated dataset folder, but its reader hsmap.datasets.simulated is not available ({exc})"
                ) from None
            return SimulatedDataset(p)
        if (p / "metadata.yaml").is_file():
            from .rosbag import RosbagDataset

            return RosbagDataset(p, **topics)
        raise DatasetError(
            f"{p}: a folder with neither dataset.yaml (simulator output) nor metadata.yaml (ROS2 bag)"
        )
    suffix = p.suffix.lower()
    if suffix == ".bag" or (suffix in (".db3", ".mcap") and (p.parent / "metadata.yaml").is_file()):
        from .rosbag import RosbagDataset

        return RosbagDataset(p, **topics)
    if suffix in CARMEN_SUFFIXES:
        no_topics("CARMEN log")
        from .carmen import CarmenDataset

        return CarmenDataset(p)
    raise DatasetError(
        f"{p}: unknown input type {suffix or '(no suffix)'!r}; expected a simulator folder (dataset.yaml), "
        f"a ROS1 .bag, a ROS2 bag folder, or a CARMEN log ({', '.join(CARMEN_SUFFIXES)})"
    )
