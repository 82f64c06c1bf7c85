"""File I/O shared by every stage: the one output writer, JSON, rows of numbers.

Every file hsmap writes goes through :func:`atomic_path` (or :func:`atomic_open`, :func:`write_json`,
:func:`write_text`, :func:`write_ply_points`, :func:`publish_file` for a temporary file written elsewhere): it is
written to a hidden temporary file beside its target (``.NAME.XXXXXXXX.SUFFIX``), flushed to the disk
(``fsync``), checked where the library that wrote it cannot be trusted to report a failure (a ``.ply`` or a
rerun ``.rrd`` cut short: see :func:`verify_output`), and only then renamed over the target. A failure on the way (no space left, a read-only folder, a file that does not check out) raises
:class:`~hsmap.errors.OutputError` naming the output and the cause, deletes the temporary file and leaves the
target as it was: an interrupted or failed run never leaves a half-written file under an output's name.

A temporary file is locked (``flock``) by the process writing it, so :func:`sweep_stale_temporaries` can tell
the leftovers of a killed run (nobody holds their lock) from the files of a run still going, and a rerun removes
the former. :func:`staged_outputs` publishes a whole set of outputs together (a run's files appear only when
all of them are complete), and :func:`prepare_output_dir` checks an output folder before long work starts.
"""

from __future__ import annotations

import contextlib
import enum
import errno
import json
import os
import shutil
import tempfile
from collections.abc import Callable, Iterable, Iterator, Mapping
from pathlib import Path
from typing import IO, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import DataFormatError, DatasetError, InputError, OutputError
from .filechecks import verify_output

try:  # POSIX: temporaries are locked by the process that writes them
    import fcntl
except ImportError:  # pragma: no cover - Windows: stale temporaries are not swept
    fcntl = None  # type: ignore[assignment]

__all__ = [
    "atomic_path",
    "atomic_open",
    "publish_file",
    "locked_temporary",
    "locked_staging_folder",
    "verify_output",
    "staged_outputs",
    "sweep_stale_temporaries",
    "prepare_output_dir",
    "resolved",
    "folder_lock",
    "write_failure_reason",
    "write_json",
    "write_ply_points",
    "to_plain",
    "write_text",
    "read_number_rows",
]

#: Prefix of the staging folders of :func:`staged_outputs` (hidden, inside the output folder).
STAGING_PREFIX = ".hsmap-staging-"


def _default_file_mode() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


_FILE_MODE = _default_file_mode()  # what open() would give a new file (mkstemp makes it private)


def _why(exc: OSError) -> str:
    return exc.strerror or str(exc) or type(exc).__name__


def write_failure_reason(folder: str | os.PathLike, detail: str) -> str:
    """Why a library's write into ``folder`` failed, when it does not say: the device's state (no space left,
    read-only) if that explains it, else ``detail``."""
    try:
        st = os.statvfs(folder)
    except (OSError, AttributeError):
        return detail
    if st.f_flag & getattr(os, "ST_RDONLY", 1):
        return os.strerror(errno.EROFS)
    if st.f_bavail == 0 or st.f_favail == 0:
        return os.strerror(errno.ENOSPC)
    return detail


def _lock(fd: int) -> bool:
    """Take an exclusive lock on ``fd`` without waiting; False when another open file holds it."""
    if fcntl is None:  # pragma: no cover
        return True
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    except OSError:  # a filesystem without flock: nothing to coordinate with
        return True
    return True


def _abandoned(path: Path) -> bool:
    """Whether the temporary file or folder ``path`` is a leftover: no live process holds its lock."""
    if fcntl is None:  # pragma: no cover
        return False
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return False
    try:
        return _lock(fd)
    finally:
        os.close(fd)


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:  # some filesystems cannot sync a folder; the rename is still atomic
        pass
    finally:
        os.close(fd)


def locked_temporary(path: str | os.PathLike, suffix: str | None = None) -> tuple[int, Path]:
    """A new empty temporary file ``.NAME.XXXXXXXX.SUFFIX`` beside ``path``, locked by this process.

    Returns its open file descriptor (closing it releases the lock: keep it open until the file is published
    or deleted) and its path. Raises :class:`~hsmap.errors.OutputError` when it cannot be created.
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix if suffix is not None else path.suffix,
                                   dir=path.parent)
    except OSError as exc:
        raise OutputError(f"{path}: cannot write it ({_why(exc)})") from None
    _lock(fd)
    return fd, Path(tmp)


def publish_file(tmp: str | os.PathLike, path: str | os.PathLike, *,
                 verify: Callable[[Path], None] | None = None) -> Path:
    """Move a complete temporary file ``tmp`` to ``path``: fsync, check, rename, fsync the folder.

    Parameters
    ----------
    tmp : path-like
        The temporary file, in ``path``'s folder.
    path : path-like
        Its final name.
    verify : callable, optional
        Called with ``tmp``; raises when the file is not complete. By default :func:`verify_output` checks the
        formats it knows by ``path``'s suffix.

    Raises
    ------
    OutputError
        The file cannot be synced or renamed, or does not check out. ``tmp`` is left for the caller to delete.
    """
    tmp, path = Path(tmp), Path(path)
    try:
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        try:
            if verify is not None:
                verify(tmp)
            else:
                verify_output(tmp, name=path)
        except OutputError as exc:  # a library wrote it short without a word: say why, when the device tells
            why = write_failure_reason(path.parent, "")
            raise OutputError(f"{exc}: {why}" if why else str(exc)) from None
        os.chmod(tmp, _FILE_MODE)
        os.replace(tmp, path)
    except OutputError:
        raise
    except OSError as exc:
        raise OutputError(f"{path}: cannot write it ({_why(exc)})") from None
    _fsync_dir(path.parent)
    return path


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None, *,
                verify: Callable[[Path], None] | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success publish it as ``path``, on error delete it.

    Use for writers that want a file name (open3d, PIL, rerun): ``with atomic_path(p) as tmp: write(tmp)``.
    The temporary file keeps ``path``'s suffix (or ``suffix``) so that format-sniffing writers work. After the
    ``with`` block the file is synced, checked (``verify``, else :func:`verify_output` by suffix) and renamed
    (:func:`publish_file`).

    Raises
    ------
    OutputError
        Writing, syncing, checking or renaming failed (an ``OSError`` inside the block, ENOSPC included, is
        turned into one, naming ``path``). Nothing is published; the temporary file is deleted.
    """
    path = Path(path)
    fd, tmp_path = locked_temporary(path, suffix)
    try:
        try:
            yield tmp_path
        except OutputError:
            raise
        except OSError as exc:
            raise OutputError(f"{path}: cannot write it ({_why(exc)})") from None
        publish_file(tmp_path, path, verify=verify)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "w", **kwargs: Any) -> Iterator[IO[Any]]:
    """Open ``path`` for writing atomically (see :func:`atomic_path`); the file is flushed and synced before it
    is published."""
    with atomic_path(path) as tmp, open(tmp, mode, **kwargs) as fh:
        yield fh
        fh.flush()



# --- folders of outputs ----------------------------------------------------------------------------------------


def prepare_output_dir(path: str | os.PathLike, what: str = "output folder", *, create: bool = True) -> Path:
    """Check that files can be written into the output folder ``path`` (creating it, with ``create``).

    Call it before long work starts, so that a typo or a read-only disk is reported at once, not after the run.
    With ``create=False`` a missing folder is not created: the check is made in its nearest existing parent
    (where it would be created), so that a run that fails on its input leaves no empty folder behind.

    Parameters
    ----------
    path : path-like
    what : str
        How to name it in the message (the command line passes its flag, ``"--out"``).
    create : bool
        Create the folder (and its parents) now.

    Raises
    ------
    InputError
        ``path`` (or a parent) exists and is not a folder, cannot be created, or is not writable (read-only
        filesystem, permissions), with the reason.
    """
    path = Path(path)
    resolved(path, what)
    if path.is_symlink() and not path.exists():
        raise InputError(f"{what} {path}: a broken symbolic link (to {os.readlink(path)}), not a folder")
    if path.exists() and not path.is_dir():
        raise InputError(f"{what} {path}: exists and is not a folder")
    probe_in = path
    if create:
        try:
            path.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise InputError(f"{what} {path}: cannot create the folder ({_why(exc)})") from None
    else:
        while not probe_in.exists():
            if probe_in.parent == probe_in:
                break
            probe_in = probe_in.parent
        if not probe_in.is_dir():
            raise InputError(f"{what} {path}: cannot create the folder ({probe_in} is not a folder)")
    try:
        fd, probe = tempfile.mkstemp(prefix=".hsmap-write-test-", dir=probe_in)
        try:
            os.write(fd, b"\0")
        finally:
            os.close(fd)
            os.unlink(probe)
    except OSError as exc:
        verb = "write into the folder" if probe_in == path else f"create the folder in {probe_in}"
        raise InputError(f"{what} {path}: cannot {verb} ({_why(exc)})") from None
    return path


def sweep_stale_temporaries(folder: str | os.PathLike, names: Iterable[str] | None = None) -> list[Path]:
    """Delete the temporaries a killed run left in ``folder``: hidden files ``.NAME.*`` of the outputs ``names``
    (all hidden ``.NAME.XXXXXXXX*`` temporaries when None) and staging folders of :func:`staged_outputs`, when
    no live process holds their lock.

    Returns
    -------
    list of Path
        What was deleted.
    """
    folder = Path(folder)
    if not folder.is_dir():
        return []
    wanted = None if names is None else [f".{n}." for n in names]
    removed = []
    for p in sorted(folder.iterdir()):
        n = p.name
        if not n.startswith("."):
            continue
        staging = n.startswith(STAGING_PREFIX) and p.is_dir() and not p.is_symlink()
        if not staging:
            if not p.is_file() or p.is_symlink():
                continue
            if wanted is not None and not any(n.startswith(w) for w in wanted):
                continue
            if wanted is None and n.count(".") < 2:
                continue
        if not _abandoned(p):
            continue
        try:
            if staging:
                shutil.rmtree(p)
            else:
                p.unlink()
        except OSError:
            continue
        removed.append(p)
    return removed


def locked_staging_folder(parent: str | os.PathLike, prefix: str = STAGING_PREFIX) -> tuple[int, Path]:
    """A new hidden folder ``PREFIX-XXXXXXXX`` in ``parent``, locked by this process (see
    :func:`locked_temporary`): returns the descriptor that holds the lock and the folder's path.
    :func:`sweep_stale_temporaries` removes it once no live process holds it."""
    parent = Path(parent)
    try:
        parent.mkdir(parents=True, exist_ok=True)
        stage = Path(tempfile.mkdtemp(prefix=prefix, dir=parent))
        fd = os.open(stage, os.O_RDONLY)
    except OSError as exc:
        raise OutputError(f"{parent}: cannot write into the folder ({_why(exc)})") from None
    _lock(fd)
    return fd, stage


@contextlib.contextmanager
def folder_lock(folder: str | os.PathLike) -> Iterator[Path]:
    """Hold an exclusive lock on ``folder`` (``flock`` on the folder itself: no lock file is left behind) for the
    ``with`` block, waiting for other processes that hold it. For short read-modify-write updates of files in the
    folder by concurrent runs (the index of ``hsmap reproduce``). Without ``flock`` (Windows) it does not lock."""
    folder = Path(folder)
    fd = os.open(folder, os.O_RDONLY)
    try:
        if fcntl is not None:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX)
            except OSError:  # a filesystem without flock
                pass
        yield folder
    finally:
        os.close(fd)  # releases the lock


@contextlib.contextmanager
def staged_outputs(out: str | os.PathLike, *, last: str | None = None, folders: bool = False,
                   replaces: Iterable[str] = ()) -> Iterator[Path]:
    """Yield a locked staging folder inside ``out``; on success move every file written there into ``out``.

    A run writes its outputs into the staging folder; they appear in ``out`` only when the ``with`` block ends
    without an error, so a failure or an interrupt leaves the previous run's files in ``out`` as they were.
    Publishing removes ``out/last`` first and moves it in last: while files are being moved, the folder reads
    as incomplete (``last`` is the marker of a complete folder, e.g. ``metrics.json``). With ``folders``, a
    folder staged (``figures/``) replaces the one of that name in ``out`` as a whole (the old one is moved
    aside into the staging folder, then deleted with it). A file named in ``replaces`` (every output the command
    may write) that this run did not write is removed from ``out`` with the others' publication: a rerun with
    other options leaves no output of an earlier run beside its own.

    Raises
    ------
    OutputError
        The staging folder cannot be created or a file cannot be moved.
    """
    out = Path(out)
    fd, stage = locked_staging_folder(out)
    try:
        try:
            yield stage
        except OutputError as exc:  # name the output where it was to appear, not its staging copy
            shutil.rmtree(stage, ignore_errors=True)
            raise OutputError(str(exc).replace(str(stage), str(out))) from None
        except BaseException:
            shutil.rmtree(stage, ignore_errors=True)
            raise
        files = sorted(p.name for p in stage.iterdir())
        dirs = [f for f in files if (stage / f).is_dir()]
        if dirs and not folders:
            shutil.rmtree(stage, ignore_errors=True)
            raise OutputError(f"{out}: staged outputs must be files, got folder(s) {dirs}")
        order = [f for f in files if f != last] + ([last] if last in files else [])
        try:
            if last is not None:
                (out / last).unlink(missing_ok=True)
            for f in replaces:
                if f not in files and (out / f).is_file():
                    (out / f).unlink()
                elif f not in files and folders and (out / f).is_dir() and not (out / f).is_symlink():
                    os.replace(out / f, stage / f".replaced-{f}")  # deleted with the staging folder
            for f in order:
                if f in dirs:
                    old = out / f
                    if old.is_dir() and not old.is_symlink():
                        os.replace(old, stage / f".replaced-{f}")
                    elif old.exists() or old.is_symlink():
                        old.unlink()
                os.replace(stage / f, out / f)
        except OSError as exc:
            shutil.rmtree(stage, ignore_errors=True)
            raise OutputError(f"{out}: cannot move the outputs into the folder ({_why(exc)})") from None
        _fsync_dir(out)
        shutil.rmtree(stage, ignore_errors=True)
    finally:
        os.close(fd)


def resolved(path: str | os.PathLike, what: str | None = None) -> Path:
    """``path`` made absolute, its links followed (``Path.resolve``); a link that leads back to itself is an
    :class:`InputError` naming it (``what``: how to name it, e.g. the flag ``--out``)."""
    try:
        return Path(path).resolve()
    except (RuntimeError, OSError) as exc:  # Python < 3.13 raises RuntimeError on a loop, later ones OSError
        name = f"{what} {path}" if what else str(path)
        why = "a symbolic link loop" if isinstance(exc, RuntimeError) or exc.errno == errno.ELOOP else _why(exc)
        raise InputError(f"{name}: cannot follow the path ({why})") from None


def refuse_overwriting_input(out: str | os.PathLike, inputs: Iterable[str | os.PathLike | None],
                             outputs: Iterable[str], flag: str = "--out") -> None:
    """OutputError naming ``flag`` when writing ``outputs`` (file names) into folder ``out`` would replace or
    mix with an input: ``out`` is an input folder, or an input file is one of the outputs' paths."""
    target = resolved(out, flag)
    names = set(outputs)
    for given in inputs:
        if given is None:
            continue
        p = resolved(given)
        if p == target or (p.parent == target and p.name in names):
            raise OutputError(f"{flag} {out}: would write over the input {given}; choose another output folder")


def to_plain(value: Any) -> Any:
    """``value`` as plain Python data for JSON and YAML: mappings become dicts with string keys, lists and tuples
    lists, numpy arrays nested lists, numpy scalars Python numbers, enums their value, paths strings; anything
    else is returned as it is."""
    if isinstance(value, Mapping):
        return {str(k): to_plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, enum.Enum):
        return value.value
    if isinstance(value, Path):
        return str(value)
    return value


def _json_default(o: Any) -> Any:
    plain = to_plain(o)
    if plain is o:
        raise TypeError(f"cannot serialise {type(o).__name__} to JSON")
    return plain


def write_ply_points(path: str | os.PathLike, points: ArrayLike) -> Path:
    """Write points as a binary little-endian PLY of double ``x``, ``y``, ``z`` (what Open3D writes for a cloud of
    points only, and reads back), atomically.

    hsmap writes its point clouds itself: Open3D's ``write_point_cloud`` returns True when the disk fills, prints
    ``RPly: Error closing up`` and leaves the file open (its space is held until the process ends).

    Parameters
    ----------
    path : path-like
    points : array_like of shape (N, 3)

    Raises
    ------
    OutputError
        The file cannot be written (see :func:`atomic_path`).
    """
    pts = np.ascontiguousarray(np.asarray(points, dtype="<f8").reshape(-1, 3))
    header = ("ply\nformat binary_little_endian 1.0\ncomment written by hsmap\n"
              f"element vertex {len(pts)}\nproperty double x\nproperty double y\nproperty double z\nend_header\n")
    with atomic_open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(pts.tobytes())
    return Path(path)


def write_json(path: str | os.PathLike, obj: Any) -> None:
    """Write ``obj`` as indented JSON, atomically (numpy scalars and arrays allowed)."""
    with atomic_open(path, "w", encoding="utf-8") as fh:
        json.dump(obj, fh, indent=2, default=_json_default)
        fh.write("\n")


def write_text(path: str | os.PathLike, text: str) -> None:
    """Write text atomically."""
    with atomic_open(path, "w", encoding="utf-8") as fh:
        fh.write(text)


def read_number_rows(path: str | os.PathLike, fields: str, what: str) -> NDArray[np.float64]:
    """Rows of whitespace- (or comma-) separated finite numbers, one per line; ``#`` lines and blank lines skipped.

    Parameters
    ----------
    fields : str
        The expected fields, e.g. ``"t x y z qx qy qz qw"``: their count is the row width, their names go into
        the error messages.
    what : str
        What the rows are (``"poses"``), for the message of an empty file.

    Raises
    ------
    DatasetError
        The file does not exist.
    DataFormatError
        A line does not hold that many finite numbers (the message gives the file and line), or no line does.
    """
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: no such file")
    n = len(fields.split())
    rows = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for lineno, line in enumerate(fh, 1):
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            parts = line.replace(",", " ").split()
            if len(parts) != n:
                raise DataFormatError(f"{path}:{lineno}: expected {n} values '{fields}', got {len(parts)}")
            try:
                vals = [float(v) for v in parts]
            except ValueError:
                raise DataFormatError(f"{path}:{lineno}: not a number in {line!r}") from None
            if not np.all(np.isfinite(vals)):
                raise DataFormatError(f"{path}:{lineno}: NaN or inf in {line!r}")
            rows.append(vals)
    if not rows:
        raise DataFormatError(f"{path}: no {what} in file")
    return np.asarray(rows)
