"""The study's one cache: folders of results computed once per key, under a lock, published atomically.

The simulated datasets (:func:`hsmap.study.runs.simulated_dataset`), the HS-SLAM runs
(:func:`hsmap.study.runs.cached_slam`) and the maps of a run (:func:`hsmap.study.maps.two_lidar_maps`) are all
folders of a :class:`FolderCache`. Each result has

- a **slot**, the folder's readable name (``slam-office-seed1``, ``office-3dof-<hash>``): what was asked, without
  the code that answers it. A new answer to the same question replaces the old folder instead of piling up
  beside it;
- a **key**, the SHA-256 of the caller's JSON description of the inputs (dataset, configuration, seed, ...),
  of :func:`code_digest` and of the source file of the function that computes the folder. The key is stored
  in the folder's ``cache.json``; a folder whose key differs is stale and is computed again.

**The code digest** covers every ``*.py`` file of the installed ``hsmap`` package except :data:`EXCLUDED` (the
figures, this study layer, the command line), with their paths, so any change to the simulator, the readers or
the algorithms gives every cached result a new key: an omission costs a recompute, never a stale result. The
study module that computes a folder is keyed on its own file (``compute``'s source), although ``study/`` is
excluded. The digest fails loudly (:class:`~hsmap.errors.CacheError`) when a file it expects is missing: the
package's ``__init__.py``, the ``__init__.py`` of every folder of modules, each excluded entry (a renamed one
would otherwise slip into, or out of, the key unnoticed), or a file it listed but could not read.

**A lookup** holds an exclusive lock (the ``filelock`` library: ``flock`` on POSIX, ``msvcrt`` on Windows) on
``root/.locks/SLOT.lock`` for its whole duration, so parallel notebooks (``hsmap reproduce --jobs 2``) compute a
slot once: the second caller waits, then reads what the first wrote. The folder is **validated on load**: its
``cache.json`` must name the key, every file it lists (with its size and SHA-256, recorded at publication) must
be there unchanged, and the caller's ``load`` must read it without error. A damaged folder (a truncated or
altered file, one that does not load) is removed and computed again, with an
:class:`~hsmap.errors.HsmapWarning` naming the file and what is wrong with it. A computation writes into ``root/.SLOT.tmp-PID``,
``cache.json`` last, and renames it into place (**atomic publication**): an interrupted run leaves no folder
that passes for a result, and its temporary folder is swept by the next caller of the slot.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import hashlib
import inspect
import json
import os
import shutil
import threading
import warnings
import zipfile
import zlib
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Generic, TypeVar

from filelock import FileLock, Timeout

from .. import __version__
from ..errors import CacheError, HsmapError, HsmapWarning
from ..io import to_plain, write_json

__all__ = ["EXCLUDED", "MARKER", "Cached", "FolderCache", "code_digest", "description_digest", "file_sha256", "slug"]

#: Parts of the package (relative to ``hsmap/``) left out of :func:`code_digest`: they draw, orchestrate and
#: parse command lines, and compute nothing a cached result is made of.
EXCLUDED: tuple[str, ...] = ("viz", "study", "pipeline", "cli.py", "__main__.py", "commands")

#: The file that marks a published cache folder and holds its key; written last.
MARKER = "cache.json"

T = TypeVar("T")

_digest_memo: dict[tuple, str] = {}
_file_memo: dict[tuple, str] = {}

#: What a damaged folder's ``load`` may raise (besides HsmapError): a truncated ``.npz`` raises BadZipFile or
#: EOFError, a corrupted one zlib.error, a cut-off JSON ValueError.
_DAMAGE = (HsmapError, OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zlib.error)


def _package_root() -> Path:
    return Path(__file__).resolve().parents[1]


def _excluded(rel: str, exclude: Sequence[str]) -> bool:
    return any(rel == e or rel.startswith(e.rstrip("/") + "/") for e in exclude)


def code_digest(root: str | os.PathLike | None = None, exclude: Sequence[str] = EXCLUDED) -> str:
    """SHA-256 of every ``*.py`` file of the package at ``root`` (default: the installed ``hsmap``), with its
    path, except the entries of ``exclude``.

    Raises
    ------
    CacheError
        A file the digest expects is missing: ``root/__init__.py``, the ``__init__.py`` of a folder of modules,
        an entry of ``exclude``; or a listed file cannot be read.
    """
    root = Path(root) if root is not None else _package_root()
    if not (root / "__init__.py").is_file():
        raise CacheError(f"{root / '__init__.py'}: missing; the code digest needs the package's root module")
    for e in exclude:
        if not (root / e).exists():
            raise CacheError(f"{root / e}: the code digest excludes it but it does not exist (renamed? update "
                             "hsmap.pipeline.cache.EXCLUDED)")
    files = []
    for p in root.rglob("*.py"):
        rel = p.relative_to(root).as_posix()
        if "__pycache__" not in rel and not _excluded(rel, exclude):
            files.append(rel)
    files.sort()
    for folder in sorted({Path(r).parent for r in files} - {Path(".")}):
        if not (root / folder / "__init__.py").is_file():
            raise CacheError(f"{root / folder / '__init__.py'}: missing; the code digest expects every folder of "
                             "modules to be a package")
    try:
        signature = (str(root), tuple(exclude),
                     tuple((r, (st := (root / r).stat()).st_size, st.st_mtime_ns) for r in files))
        if signature in _digest_memo:
            return _digest_memo[signature]
        h = hashlib.sha256()
        for r in files:
            h.update(r.encode() + b"\0" + (root / r).read_bytes() + b"\0")
    except OSError as exc:
        raise CacheError(f"{exc.filename}: cannot read it for the code digest ({exc.strerror})") from None
    _digest_memo[signature] = h.hexdigest()
    return _digest_memo[signature]


def _source_digest(fn: Callable[..., Any]) -> str:
    """SHA-256 of the file that defines ``fn`` (the study module computing a cached folder)."""
    path = inspect.getsourcefile(fn)
    if path is None:
        raise CacheError(f"{fn!r}: no source file to key the cache on")
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError as exc:
        raise CacheError(f"{path}: cannot read it for the cache key ({exc.strerror})") from None


def file_sha256(path: Path) -> str:
    """SHA-256 of a file, remembered per (path, size, modification time) for this process."""
    st = path.stat()
    memo = (str(path), st.st_size, st.st_mtime_ns)
    if memo not in _file_memo:
        h = hashlib.sha256()
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
        _file_memo[memo] = h.hexdigest()
    return _file_memo[memo]


def _manifest(folder: Path) -> dict[str, list]:
    """``{relative path: [size, sha256]}`` of every file in ``folder`` but its marker."""
    out = {}
    for p in sorted(folder.rglob("*")):
        if p.is_file() and not p.is_symlink() and p.relative_to(folder).as_posix() != MARKER:
            out[p.relative_to(folder).as_posix()] = [p.stat().st_size, file_sha256(p)]
    return out


def _damage(folder: Path, files: Mapping[str, Any]) -> str | None:
    """What is wrong with the files a folder's marker lists (None when they are all there, unchanged)."""
    for rel, (size, sha) in files.items():
        p = folder / rel
        if not p.is_file():
            return f"{p} is missing"
        actual = p.stat().st_size
        if actual != size:
            return f"{p} has {actual} bytes, {size} were written (truncated or replaced)"
        if file_sha256(p) != sha:
            return f"{p} was altered since it was written (its SHA-256 differs)"
    return None


def description_digest(description: Any) -> str:
    """SHA-256 of a JSON-able description (numpy values and enums allowed), independent of key order."""
    text = json.dumps(to_plain(description), sort_keys=True, allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()


def slug(text: str, limit: int = 40) -> str:
    """``text`` as part of a folder name: letters, digits, ``-`` and ``_`` kept, anything else ``-``."""
    s = "".join(c if c.isalnum() or c in "-_" else "-" for c in str(text)).strip("-")
    return s[:limit] or "dataset"


@dataclass(frozen=True)
class Cached(Generic[T]):
    """A result of :meth:`FolderCache.get`.

    Attributes
    ----------
    value : object
        What the caller's ``load`` made of the folder.
    folder : Path
    key : str
    cached : bool
        True when the folder was there already (this call computed nothing).
    """

    value: T
    folder: Path
    key: str
    cached: bool


class FolderCache:
    """Result folders under ``root``, one per slot, computed once per key (see the module docstring).

    Parameters
    ----------
    root : path
        Where the folders, their temporary folders and ``.locks/`` live (created when needed).
    lock_timeout : float or None
        Seconds to wait for another process holding a slot (None: for ever).
    """

    def __init__(self, root: str | os.PathLike, *, lock_timeout: float | None = 3600.0) -> None:
        self.root = Path(root)
        self.lock_timeout = lock_timeout

    def __repr__(self) -> str:
        return f"FolderCache({str(self.root)!r})"

    def key(self, description: Mapping[str, Any], compute: Callable[[Path], Any]) -> str:
        """The key of a result: its description, the code digest and the source of ``compute``."""
        return description_digest({"description": description, "code": code_digest(),
                                   "compute": _source_digest(compute), "hsmap": __version__})

    @contextlib.contextmanager
    def lock(self, slot: str) -> Iterator[Path]:
        """Hold the slot's exclusive lock (``root/.locks/SLOT.lock``) for the ``with`` block."""
        path = self.root / ".locks" / f"{slot}.lock"
        path.parent.mkdir(parents=True, exist_ok=True)
        lock = FileLock(path, timeout=-1 if self.lock_timeout is None else self.lock_timeout)
        try:
            lock.acquire()
        except Timeout:
            raise CacheError(f"{path}: still locked by another process after {self.lock_timeout:g} s") from None
        try:
            yield path
        finally:
            lock.release()

    def _read(self, folder: Path, key: str, load: Callable[[Path], T]) -> T | None:
        """``load(folder)`` when the folder is published under ``key``, its files are the ones written and it
        reads without error; else None (with a warning naming what is damaged, when it is)."""
        try:
            stored = json.loads((folder / MARKER).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        if not isinstance(stored, dict) or stored.get("key") != key:
            return None
        files = stored.get("files")
        try:
            problem = ("its cache.json lists no files" if not isinstance(files, dict)
                       else _damage(folder, files))
        except (OSError, TypeError, ValueError) as exc:
            problem = f"its files cannot be checked ({exc})"
        if problem is None:
            try:
                return load(folder)
            except _DAMAGE as exc:
                problem = f"it does not load ({type(exc).__name__}: {' '.join(str(exc).split())})"
        warnings.warn(f"cache folder {folder} is damaged: {problem}; computing it again", HsmapWarning,
                      stacklevel=3)
        return None

    def lookup(self, slot: str, description: Mapping[str, Any], compute: Callable[[Path], Any],
               load: Callable[[Path], T]) -> Cached[T] | None:
        """The slot's result when it is there and current; None otherwise (nothing is computed)."""
        key = self.key(description, compute)
        folder = self.root / slot
        with self.lock(slot):
            value = self._read(folder, key, load)
        return None if value is None else Cached(value, folder, key, True)

    def get(self, slot: str, description: Mapping[str, Any], compute: Callable[[Path], Any],
            load: Callable[[Path], T]) -> Cached[T]:
        """The slot's result: read back when current, else computed by ``compute(tmp_folder)`` and published.

        Parameters
        ----------
        slot : str
            The folder's name under ``root``: a plain file name.
        description : mapping
            JSON-able description of everything the result depends on besides the code (see :meth:`key`).
        compute : callable
            Writes the result into the (new, empty) folder it is given.
        load : callable
            Reads a folder into the value returned; raises (an :class:`~hsmap.errors.HsmapError`, ``OSError``,
            ``ValueError`` or ``KeyError``) when the folder is incomplete or inconsistent.
        """
        if not slot or slot != Path(slot).name or slot.startswith("."):
            raise CacheError(f"cache slot must be a plain folder name, got {slot!r}")
        key = self.key(description, compute)
        folder = self.root / slot
        with self.lock(slot):
            value = self._read(folder, key, load)
            if value is not None:
                return Cached(value, folder, key, True)
            if folder.is_symlink() or folder.is_file():
                folder.unlink()
            elif folder.exists():
                shutil.rmtree(folder)  # stale (another key) or damaged
            for stale in self.root.glob(f".{slot}.tmp-*"):  # left by a killed run (we hold the lock)
                shutil.rmtree(stale, ignore_errors=True)
            tmp = self.root / f".{slot}.tmp-{os.getpid()}-{threading.get_ident()}"
            try:
                tmp.mkdir(parents=True)
                compute(tmp)
                write_json(tmp / MARKER, {
                    "key": key, "slot": slot, "description": to_plain(description), "code_digest": code_digest(),
                    "files": _manifest(tmp),
                    "hsmap_version": __version__,
                    "created": dt.datetime.now().astimezone().isoformat(timespec="seconds"),
                })
                os.rename(tmp, folder)
            except BaseException:
                shutil.rmtree(tmp, ignore_errors=True)
                raise
            try:
                value = load(folder)
            except _DAMAGE as exc:
                raise CacheError(f"{folder}: the folder just computed does not read back: {exc}") from exc
            return Cached(value, folder, key, False)
