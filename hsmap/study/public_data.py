"""The public benchmark data (Freiburg SLAM logs, Bormann et al.'s room segmentation maps, OctoMap's building 079,
BALM's real 3D LiDAR sweeps): where each file comes from, its SHA-256, and ``hsmap data fetch``, which downloads
them into the user cache.

The registry is package data, ``hsmap/study/public_data.yaml``: per dataset its folder in the datasets layout
(``slam2d/``, ``ipa_room_segmentation/``), citation, licence and sources, and per file the URL of the original
at a pinned commit of its public repository and the SHA-256 of its bytes. :func:`fetch` downloads with
`pooch <https://www.fatiando.org/pooch/>`_ (a download goes to a temporary file, is hash-checked and only then
moved into place; a file whose hash differs is deleted and refused) into :func:`hsmap.study.paths.fetch_dir`, under a
``filelock`` lock, so that two fetches at once do not trip over each other.

A dataset with a ``layout`` gets the files hsmap reads beside its originals once they are all there
(:func:`lay_out`; BALM: ``times.txt`` and ``groundtruth.tum`` from ``alidarPose.csv``), written atomically.

``$HSMAP_DATA_MIRROR`` (or ``mirror=``) replaces the original URLs with one base URL that serves the datasets
layout (``MIRROR/slam2d/intel/intel.orig.bag``): an institute's mirror, or the tests' local HTTP server.

Readers of the data (notebook 08, the tests, the benchmark scripts) find it through
:func:`hsmap.study.paths.datasets_dir` and :func:`dataset_folder`, which says where a whole dataset is, or None.
"""

from __future__ import annotations

import hashlib
import os
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from ..errors import DatasetError, InputError
from .paths import datasets_dir, fetch_dir
from .registry import PublicDataset, PublicFile, complete_folder, registry

__all__ = [
    "PublicFile",
    "PublicDataset",
    "FetchResult",
    "registry",
    "fetch",
    "fetch_dir",
    "dataset_folder",
    "missing_data_reason",
    "lay_out",
    "balm_poses",
    "MIRROR_ENV",
    "NO_DATA",
]

#: A base URL that replaces the original URLs (it serves the datasets layout).
MIRROR_ENV = "HSMAP_DATA_MIRROR"
#: What a notebook or test says when a public dataset is missing.
NO_DATA = "no data (run hsmap data fetch)"


@dataclass(frozen=True)
class FetchResult:
    """What :func:`fetch` did for one dataset: files downloaded now, files already there (hash checked), files
    that were there with a wrong hash and were replaced, and the dataset's folder."""

    dataset: PublicDataset
    folder: Path
    downloaded: tuple[str, ...]
    present: tuple[str, ...]
    replaced: tuple[str, ...]


def _choose(names: Sequence[str] | None) -> list[PublicDataset]:
    reg = registry()
    if not names:
        return list(reg.values())
    unknown = [n for n in names if n not in reg]
    if unknown:
        raise InputError(f"unknown dataset {', '.join(map(repr, unknown))}; the public datasets are: "
                         f"{', '.join(reg)}")
    return [reg[n] for n in dict.fromkeys(names)]


def dataset_folder(name: str, root: str | os.PathLike | None = None) -> Path | None:
    """The folder of public dataset ``name`` under ``root`` (default :func:`hsmap.study.paths.datasets_dir`)
    when every file of it is there (not hash-checked: :func:`fetch` checked them), else None."""
    return complete_folder(_choose([name])[0], Path(root if root is not None else datasets_dir()))


def missing_data_reason(names: Sequence[str], root: str | os.PathLike | None = None) -> str:
    """One line saying which public datasets are missing under ``root``, and how to get them ('' if none)."""
    base = Path(root if root is not None else datasets_dir())
    missing = [n for n in names if dataset_folder(n, base) is None]
    if not missing:
        return ""
    return (f"{NO_DATA}: {' and '.join(missing)} not found in {base} (or set HSMAP_DATASETS to a folder "
            "holding them)")


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def fetch(
    names: Sequence[str] | None = None,
    *,
    dest: str | os.PathLike | None = None,
    mirror: str | None = None,
    timeout: float = 120.0,
    log: Callable[[str], None] | None = None,
) -> list[FetchResult]:
    """Download the public datasets ``names`` (default all) into ``dest``, each file hash-checked.

    Files already there with the right hash are kept; one with a wrong hash is deleted and downloaded again.

    Parameters
    ----------
    names : sequence of str, optional
        ``freiburg``, ``bormann``, ``octomap`` and/or ``balm``.
    dest : path, optional
        Default :func:`hsmap.study.paths.fetch_dir`.
    mirror : str, optional
        Base URL serving the datasets layout, replacing the original URLs (default ``$HSMAP_DATA_MIRROR``).
    timeout : float
        Seconds per request.
    log : callable, optional
        Receives a line per file downloaded or replaced.

    Returns
    -------
    list of FetchResult

    Raises
    ------
    DatasetError
        A download failed, or a downloaded file's SHA-256 differs from the registry's: the message names the
        file and where it came from; nothing of that file is stored.
    """
    import pooch
    from filelock import FileLock, Timeout

    chosen = _choose(names)
    dest = Path(dest) if dest is not None else fetch_dir()
    mirror = mirror if mirror is not None else (os.environ.get(MIRROR_ENV) or None)
    if mirror is not None and not re.match(r"^https?://", mirror):
        raise InputError(f"mirror must be an http:// or https:// URL, got {mirror!r}")
    if dest.exists() and not dest.is_dir():
        raise InputError(f"dest {dest}: exists and is not a folder")
    # what this call creates, removed again when nothing of it is stored (a refused or failed download)
    created = [p for p in (dest, *(dest / ds.folder for ds in chosen)) if not p.exists()]
    try:
        dest.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"dest {dest}: cannot create the folder ({exc.strerror or exc})") from None
    logger = pooch.get_logger()
    level = logger.level
    logger.setLevel("WARNING")  # pooch says "Downloading file ..." for every file; we say it once per dataset
    results = []
    try:
        with FileLock(str(dest / ".fetch.lock"), timeout=3600):
            for ds in chosen:
                results.append(_fetch_one(ds, dest, mirror, timeout, log, pooch))
    except Timeout:
        raise DatasetError(f"{dest}: another 'hsmap data fetch' holds {dest / '.fetch.lock'}") from None
    except BaseException:
        _remove_if_empty(created[::-1], dest / ".fetch.lock" if dest in created else None)
        raise
    finally:
        logger.setLevel(level)
    return results


def _remove_if_empty(folders: list[Path], lock: Path | None) -> None:
    """Remove the folders (innermost first) that hold nothing; ``lock``, this call's own lock file in a folder it
    created, goes first."""
    if lock is not None:
        lock.unlink(missing_ok=True)
    for folder in folders:
        try:
            folder.rmdir()
        except OSError:  # not empty, or already gone
            pass


def _fetch_one(ds: PublicDataset, dest: Path, mirror: str | None, timeout: float,
               log: Callable[[str], None] | None, pooch) -> FetchResult:
    folder = dest / ds.folder
    urls = {f.path: (f"{mirror.rstrip('/')}/{ds.folder}/{f.path}" if mirror else f.url) for f in ds.files}
    store = pooch.create(path=folder, base_url="", registry={f.path: f"sha256:{f.sha256}" for f in ds.files},
                         urls=urls, retry_if_failed=1)
    downloader = pooch.HTTPDownloader(progressbar=False, timeout=timeout)
    downloaded, present, replaced = [], [], []
    for f in ds.files:
        local = folder / f.path
        if local.is_file():
            if _sha256(local) == f.sha256:
                present.append(f.path)
                continue
            local.unlink()  # a damaged or outdated copy: never leave it where readers would take it
            replaced.append(f.path)
        rel = f"{ds.folder}/{f.path}"
        try:
            store.fetch(f.path, downloader=downloader)
        except ValueError as exc:
            if "hash" not in str(exc):
                raise DatasetError(f"{rel}: download from {urls[f.path]} failed: {_one_line(exc)}") from None
            got = re.search(r"but got ([0-9a-fA-F]+)", str(exc))
            raise DatasetError(
                f"{rel}: refused: the SHA-256 of the file from {urls[f.path]} is "
                f"{got.group(1) if got else 'different'}, the registry's is {f.sha256} (nothing stored)"
            ) from None
        except Exception as exc:  # requests' connection and HTTP errors, OSError
            raise DatasetError(f"{rel}: download from {urls[f.path]} failed: {_one_line(exc)}") from None
        if f.path not in replaced:
            downloaded.append(f.path)
        if log is not None:
            nbytes = local.stat().st_size
            size = f"{nbytes / 1e6:.1f} MB" if nbytes >= 100_000 else f"{nbytes / 1e3:.0f} kB"
            log(f"  {rel}: {'replaced a damaged copy' if f.path in replaced else 'downloaded'}, {size}, SHA-256 ok")
    if ds.layout is not None:
        for written in lay_out(ds.name, folder):
            if log is not None:
                log(f"  {ds.folder}/{written.name}: written from the originals")
    return FetchResult(ds, folder, tuple(downloaded), tuple(present), tuple(replaced))


def balm_poses(path: str | os.PathLike):
    """The poses of BALM's ``alidarPose.csv`` as a :class:`~hsmap.trajectory.Trajectory`: per sweep, 4 lines of 4
    comma-separated numbers, the rows of the sensor's 4x4 pose in the world whose last cell holds the sweep's Unix
    time (seconds) instead of 1.

    Raises
    ------
    DataFormatError
        Not a whole number of 4x4 blocks of numbers, a bottom row other than (0, 0, 0, time), or stamps that do
        not increase (naming the file).
    """
    import numpy as np

    from ..errors import DataFormatError
    from ..geometry import matrix_to_euler
    from ..trajectory import Trajectory

    p = Path(path)
    try:
        values = [float(v) for v in p.read_text(encoding="utf-8").replace("\n", ",").split(",") if v.strip()]
    except ValueError as exc:
        raise DataFormatError(f"{p}: expected comma-separated numbers ({exc})") from None
    except OSError as exc:
        raise DatasetError(f"{p}: cannot read it ({exc.strerror or exc})") from None
    if not values or len(values) % 16:
        raise DataFormatError(f"{p}: {len(values)} numbers; expected 16 (a 4x4 pose) per sweep")
    m = np.asarray(values).reshape(-1, 4, 4)
    stamps = m[:, 3, 3].copy()
    if not (np.all(np.isfinite(m)) and np.all(m[:, 3, :3] == 0.0)):
        raise DataFormatError(f"{p}: expected finite 4x4 poses whose bottom row is 0, 0, 0, time")
    if np.any(np.diff(stamps) <= 0):
        raise DataFormatError(f"{p}: the stamps (the last cell of each pose) must increase from sweep to sweep")
    return Trajectory(stamps, np.column_stack([m[:, :3, 3], matrix_to_euler(m[:, :3, :3])]))


def lay_out(name: str, folder: str | os.PathLike, out: str | os.PathLike | None = None) -> list[Path]:
    """Write the files hsmap reads beside public dataset ``name``'s originals in ``folder`` (into ``out``, default
    ``folder``; the shared copy is read-only); the paths written. BALM: ``times.txt`` (each sweep's stamp, one a
    line, in sweep order) and ``groundtruth.tum`` (the reference poses, TUM), from ``alidarPose.csv``."""
    import numpy as np

    from ..io import atomic_open
    from ..trajectory import write_tum

    ds = _choose([name])[0]
    folder = Path(folder)
    out = Path(out) if out is not None else folder
    if ds.layout != "balm":
        return []
    traj = balm_poses(folder / "alidarPose.csv")
    out.mkdir(parents=True, exist_ok=True)
    with atomic_open(out / "times.txt", "w", encoding="utf-8") as fh:
        np.savetxt(fh, traj.stamps, fmt="%.6f")
    write_tum(out / "groundtruth.tum", traj)
    return [out / "times.txt", out / "groundtruth.tum"]
