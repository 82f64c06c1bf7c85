"""Reader of the dataset folders written by ``hsmap simulate`` (see :mod:`hsmap.sim.writer`), and the format's
range-image codec (the writer encodes with it).

The simulator writes this format and the reader owns it: :mod:`hsmap.sim` imports from here, never the other
way round."""

from __future__ import annotations

import json
import os
import zipfile
import zlib
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import yaml
from numpy.typing import ArrayLike, NDArray

from ..errors import DataFormatError, DatasetError, InputError
from ..limits import load_yaml, quote
from ..maps.grid import GridGeometry
from ..trajectory import Trajectory, read_tum
from .frames import Dataset, Frame, LaserScan2D

__all__ = ["SimulatedDataset", "is_simulated_dataset", "FORMAT", "FORMAT_VERSION", "RANGE_UNIT", "beam_directions",
           "encode_range_image", "decode_range_image", "range_image_to_points"]

FORMAT = "hsmap-simulated-dataset"
#: The version :mod:`hsmap.sim.writer` writes.
FORMAT_VERSION = 1
SUPPORTED_VERSIONS = (1,)
RANGE_UNIT = 0.001  # metres per count in stored 3D range images


def _load_npz(path: Path, names: tuple[str, ...], optional: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """The arrays ``names`` (and those of ``optional`` it has) of an ``.npz`` file; a damaged (truncated,
    corrupted) file raises :class:`DataFormatError` naming it, a missing one :class:`DatasetError`."""
    if not path.is_file():
        raise DatasetError(f"{path}: missing (the dataset folder is damaged)")
    try:
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as z:  # our handle: closed if np.load fails
            missing = [n for n in names if n not in z.files]
            if missing:
                raise DataFormatError(f"{path}: missing array(s) {missing} (the file is damaged)")
            return {n: np.asarray(z[n]) for n in (*names, *(o for o in optional if o in z.files))}
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError) as exc:
        if isinstance(exc, DataFormatError):
            raise
        raise DataFormatError(f"{path}: damaged or truncated ({type(exc).__name__}: {exc}); simulate the dataset "
                              "again") from None


def is_simulated_dataset(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a folder with a simulator ``dataset.yaml``."""
    p = Path(path) / "dataset.yaml"
    if not p.is_file():
        return False
    try:
        meta = yaml.safe_load(p.read_text(encoding="utf-8"))
    except (yaml.YAMLError, OSError, UnicodeDecodeError):
        return False
    return isinstance(meta, dict) and meta.get("format") == FORMAT


class SimulatedDataset(Dataset):
    """A simulated dataset folder as a sequence of :class:`~hsmap.datasets.frames.Frame`.

    Parameters
    ----------
    path : str or path
        The folder written by ``hsmap simulate`` (it must hold ``dataset.yaml``, written last).

    Attributes
    ----------
    meta : dict
        The parsed ``dataset.yaml``.
    sensors : dict
        ``{"lidar2d": {...}, "lidar3d": {...}}`` as described in ``dataset.yaml``.
    odometry, groundtruth : Trajectory
        (x, y, yaw) poses of the robot base at the scan stamps.
    stamps : ndarray of shape (N,)
    extrinsic2d : ndarray of shape (3,)
    extrinsic3d : ndarray of shape (6,)
    """

    def __init__(self, path: str | os.PathLike):
        self.path = str(path)
        root = Path(path)
        if not root.is_dir():
            raise DatasetError(f"{root}: no such dataset folder")
        meta_path = root / "dataset.yaml"
        if not meta_path.is_file():
            raise DatasetError(f"{root}: incomplete simulated dataset (no dataset.yaml; it is written last, so "
                               "the simulation did not finish); run `hsmap simulate` again")
        try:
            meta = load_yaml(meta_path.read_text(encoding="utf-8"))
        except (yaml.YAMLError, UnicodeDecodeError) as exc:
            raise DataFormatError(f"{meta_path}: not valid YAML: {' '.join(str(exc).split())}") from None
        except OSError as exc:
            raise DatasetError(f"{meta_path}: cannot read it ({exc.strerror})") from None
        if not isinstance(meta, dict) or meta.get("format") != FORMAT:
            raise DataFormatError(f"{meta_path}: not a simulated dataset description (format must be {FORMAT!r})")
        if meta.get("format_version") not in SUPPORTED_VERSIONS:
            raise DataFormatError(f"{meta_path}: format_version {meta.get('format_version')!r} is not supported "
                                  f"(this hsmap reads {list(SUPPORTED_VERSIONS)})")
        self.root = root
        self.meta = meta
        self.name = str(meta.get("scenario", root.name))
        self.sensors = meta.get("sensors")
        if not isinstance(self.sensors, dict) or not all(isinstance(self.sensors.get(k), dict)
                                                         for k in ("lidar2d", "lidar3d")):
            raise DataFormatError(f"{meta_path}: 'sensors' must be a mapping with the 'lidar2d' and 'lidar3d' "
                                  f"descriptions, got {quote(self.sensors)}")
        try:
            self.extrinsic2d = np.asarray(self.sensors["lidar2d"]["extrinsic"], dtype=float).reshape(3)
            self.extrinsic3d = np.asarray(self.sensors["lidar3d"]["extrinsic"], dtype=float).reshape(6)
            s3 = self.sensors["lidar3d"]
            self._shape3d = (int(s3["channels"]), int(s3["columns"]))
            s2 = self.sensors["lidar2d"]
            for key in ("range_min", "range_max"):
                float(s2[key])
            self.extrinsic_sources.update({"2d": "dataset.yaml", "3d": "dataset.yaml"})
        except KeyError as exc:
            raise DataFormatError(f"{meta_path}: bad sensor description: missing key {quote(exc.args[0])}") from None
        except (TypeError, ValueError) as exc:
            raise DataFormatError(f"{meta_path}: bad sensor description: {' '.join(str(exc).split())[:300]}") from None
        scans = root / "scans2d.npz"
        z = _load_npz(scans, ("stamps", "ranges", "angles"), ("beam_time",))
        try:
            self.stamps = np.asarray(z["stamps"], dtype=float).reshape(-1)
            self._ranges = np.asarray(z["ranges"])
            self.angles = np.asarray(z["angles"], dtype=float).reshape(-1)
            n = int(meta.get("frames", len(self.stamps)))
        except (TypeError, ValueError) as exc:
            raise DataFormatError(f"{scans}: unexpected contents ({exc})") from None
        if self._ranges.shape != (n, len(self.angles)) or len(self.stamps) != n:
            raise DataFormatError(f"{scans}: expected {n} scans of {len(self.angles)} beams, got ranges "
                                  f"{self._ranges.shape} and {len(self.stamps)} stamps")
        self.beam_times: NDArray[np.float64] | None = None
        if "beam_time" in z:
            bt = np.asarray(z["beam_time"]).reshape(-1)
            if bt.shape != self.angles.shape or not np.issubdtype(bt.dtype, np.floating) or not np.all(np.isfinite(bt)):
                raise DataFormatError(f"{scans}: beam_time must be {len(self.angles)} finite seconds, one per beam, "
                                      f"got shape {bt.shape} {bt.dtype}")
            if np.any(bt):
                self.beam_times = bt.astype(float)
                self.beam_time = {"field": "beam_time", "convention": "float64 s after the stamp (the scan's first "
                                  "beam), one per beam"}
        self.groundtruth = read_tum(root / "groundtruth.tum", dof=3)
        self.odometry = read_tum(root / "odometry.tum", dof=3)
        for name, tr in (("groundtruth.tum", self.groundtruth), ("odometry.tum", self.odometry)):
            if len(tr) != n or not np.allclose(tr.stamps, self.stamps, atol=1e-6):
                raise DataFormatError(f"{root / name}: its {len(tr)} stamps do not match the {n} scan stamps")
        self._dirs: NDArray[np.float64] | None = None
        if float(self.sensors["lidar3d"].get("sweep_time", 0.0)) > 0:
            self.point_time = {"field": "column_time", "convention": "float64 s after the stamp (the sweep's start), "
                               "one per range-image column"}

    def __len__(self) -> int:
        return len(self.stamps)

    def __repr__(self) -> str:
        return f"SimulatedDataset({self.path!r}, scenario={self.name!r}, frames={len(self)})"

    # ------------------------------------------------------------------ sensors
    def scan2d(self, index: int) -> LaserScan2D:
        """The 2D scan of frame ``index`` in the 2D sensor frame."""
        s = self.sensors["lidar2d"]
        return LaserScan2D(self._ranges[index].astype(float), self.angles, float(s["range_min"]),
                           float(s["range_max"]), None if self.beam_times is None else self.beam_times.copy())

    @property
    def ranges2d(self) -> NDArray[np.float32]:
        """All 2D ranges (N, M), NaN = no return."""
        return self._ranges

    def beam_directions(self) -> NDArray[np.float64]:
        """Unit directions (channels, columns, 3) of the 3D LiDAR's pixels in its frame."""
        if self._dirs is None:
            s = self.sensors["lidar3d"]
            el = np.deg2rad(np.asarray(s["vertical_angles_deg"], dtype=float))
            az = float(s["azimuth_min"]) + float(s["azimuth_increment"]) * np.arange(int(s["columns"]))
            self._dirs = beam_directions(el, az)
        return self._dirs

    def range_image(self, index: int) -> NDArray[np.uint16]:
        """The stored 3D range image (channels, columns) of frame ``index``: uint16 mm, 0 = no return."""
        if not 0 <= index < len(self):
            raise IndexError(f"frame {index} out of range 0..{len(self) - 1}")
        return self._cloud_file(index)[0]

    def _cloud_file(self, index: int) -> tuple[NDArray[np.uint16], NDArray[np.float64] | None]:
        """Frame ``index``'s range image and its ``column_time`` (columns,) (None for a sweep taken at once)."""
        p = self.root / "clouds3d" / f"{index:06d}.npz"
        z = _load_npz(p, ("range_mm",), ("column_time",))
        img = z["range_mm"]
        if img.shape != self._shape3d or img.dtype != np.uint16:
            raise DataFormatError(f"{p}: expected a {self._shape3d} uint16 range image, got {img.shape} {img.dtype}")
        col_t = z.get("column_time")
        if col_t is not None:
            col_t = np.asarray(col_t, dtype=float).reshape(-1)
            if col_t.shape != (self._shape3d[1],) or not np.all(np.isfinite(col_t)):
                raise DataFormatError(f"{p}: column_time must be {self._shape3d[1]} finite seconds, got shape "
                                      f"{col_t.shape}")
        return img, col_t

    def cloud3d(self, index: int) -> NDArray[np.float64]:
        """The 3D cloud (K, 3) of frame ``index`` in the 3D sensor frame (no-return pixels dropped)."""
        return range_image_to_points(self.range_image(index), self.beam_directions())

    def cloud3d_timed(self, index: int) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
        """The 3D cloud (K, 3) of frame ``index`` and each point's seconds after the stamp (K,) (None where the
        folder's clouds have no ``column_time``: taken at their stamps)."""
        img, col_t = self._cloud_file(index)
        pts = range_image_to_points(img, self.beam_directions())
        if col_t is None:
            return pts, None
        ok = img > 0
        return pts, np.broadcast_to(col_t[None, :], img.shape)[ok].astype(float)

    # ------------------------------------------------------------------ frames
    def frame(self, index: int, clouds: bool = True) -> Frame:
        """Frame ``index`` (negative indices count from the end)."""
        if index < 0:
            index += len(self)
        if not 0 <= index < len(self):
            raise IndexError(f"frame {index} out of range 0..{len(self) - 1}")
        cloud, times = self.cloud3d_timed(index) if clouds else (None, None)
        return Frame(
            stamp=float(self.stamps[index]),
            scan2d=self.scan2d(index),
            cloud3d=cloud,
            point_times=times,
            stamp_in_sweep=None if times is None else "start",
            odometry=self.odometry.poses[index].copy(),
            index=index,
            extrinsic2d=self.extrinsic2d.copy(),
            extrinsic3d=self.extrinsic3d.copy(),
        )

    __getitem__ = frame

    def frames(self, start: int = 0, stop: int | None = None, step: int = 1,
               clouds: bool = True) -> Iterator[Frame]:
        """Yield frames ``start:stop:step`` in order; ``clouds=False`` skips reading the 3D clouds."""
        for i in range(*slice(start, stop, step).indices(len(self))):
            yield self.frame(i, clouds)

    # ------------------------------------------------------------------ ground truth
    def labels(self) -> tuple[NDArray[np.uint16], GridGeometry, dict[int, str]]:
        """Ground-truth room labels: (image (H, W) uint16, 0 = no room; its GridGeometry; label -> name)."""
        from PIL import Image

        png, meta_path = self.root / "rooms.png", self.root / "rooms.yaml"
        if not png.is_file() or not meta_path.is_file():
            raise DatasetError(f"{self.root}: missing rooms.png or rooms.yaml")
        meta = yaml.safe_load(meta_path.read_text(encoding="utf-8"))
        with Image.open(png) as im:
            img = np.array(im)
        if img.ndim != 2:
            raise DataFormatError(f"{png}: expected a single-channel label image, got shape {img.shape}")
        img = img.astype(np.uint16)
        grid = GridGeometry(img.shape, float(meta["resolution"]), tuple(meta["origin"][:2]))
        names = {int(k): str(v) for k, v in (meta.get("labels") or {}).items()}
        return img, grid, names

    def doors(self) -> list[dict]:
        """Ground-truth doors (see ``doors.json``): name, center, width, endpoints, rooms, open, ..."""
        p = self.root / "doors.json"
        if not p.is_file():
            raise DatasetError(f"{p}: missing")
        try:
            data = json.loads(p.read_text(encoding="utf-8"))
        except json.JSONDecodeError as exc:
            raise DataFormatError(f"{p}: not valid JSON: {exc}") from None
        return list(data["doors"])

    def scenario_path(self) -> Path:
        """The copy of the scenario file in the folder."""
        return self.root / "scenario.yaml"

    def trajectory(self, which: str = "groundtruth") -> Trajectory:
        """``"groundtruth"`` or ``"odometry"``."""
        if which not in ("groundtruth", "odometry"):
            raise InputError(f"which must be 'groundtruth' or 'odometry', got {which!r}")
        return self.groundtruth if which == "groundtruth" else self.odometry


def beam_directions(elevations: ArrayLike, azimuths: ArrayLike) -> NDArray[np.float64]:
    """Unit vectors (C, W, 3) for elevations (C,) and azimuths (W,) in radians."""
    el = np.asarray(elevations, dtype=float)[:, None]
    az = np.asarray(azimuths, dtype=float)[None, :]
    return np.stack(
        [np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.broadcast_to(np.sin(el), (el.shape[0], az.shape[1]))],
        -1,
    )


def encode_range_image(ranges: ArrayLike) -> NDArray[np.uint16]:
    """Metres (NaN = no return) -> uint16 counts of :data:`RANGE_UNIT` (0 = no return)."""
    r = np.asarray(ranges, dtype=float)
    counts = np.where(np.isfinite(r), np.rint(r / RANGE_UNIT), 0.0)
    return np.clip(counts, 0, np.iinfo(np.uint16).max).astype(np.uint16)


def decode_range_image(counts: ArrayLike) -> NDArray[np.float64]:
    """uint16 counts -> metres, NaN where there is no return."""
    c = np.asarray(counts)
    return np.where(c > 0, c.astype(float) * RANGE_UNIT, np.nan)


def range_image_to_points(range_image: ArrayLike, directions: ArrayLike) -> NDArray[np.float64]:
    """Points (K, 3) in the sensor frame from a range image (C, W) and beam directions (C, W, 3).

    ``range_image`` is either uint16 counts of :data:`RANGE_UNIT` (0 = no return) or float metres
    (NaN = no return). Points come out in row-major order of the image, invalid pixels dropped.
    """
    img = np.asarray(range_image)
    r = decode_range_image(img) if np.issubdtype(img.dtype, np.integer) else img.astype(float)
    ok = np.isfinite(r) & (r > 0)
    return np.asarray(directions, dtype=float)[ok] * r[ok][:, None]
