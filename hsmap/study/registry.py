"""The registry of public benchmark datasets (``hsmap/study/public_data.yaml``: files, URLs at pinned commits,
SHA-256, sizes, citations) and whether a folder holds a whole dataset.

A dataset lists its ``files`` one by one (URL, SHA-256, size), or gives a ``base_url`` at a pinned commit and a
``hashes`` file of package data beside the registry (``sha256sum`` lines: ``HASH  NAME``), each NAME fetched from
``base_url + NAME`` (sizes not listed). ``layout`` names what :func:`hsmap.study.public_data.lay_out` writes
beside the fetched files so that hsmap reads the folder as it is (``balm``: ``times.txt``, ``groundtruth.tum``)."""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import yaml

from ..errors import ConfigError

__all__ = ["PublicFile", "PublicDataset", "registry", "complete_folder"]


@dataclass(frozen=True)
class PublicFile:
    """One file of a public dataset.

    Attributes
    ----------
    path : str
        Relative to the dataset's folder (``intel/intel.orig.bag``).
    url : str
        The original file at a pinned commit.
    sha256 : str
    size : int or None
        Bytes (None: not listed).
    """

    path: str
    url: str
    sha256: str
    size: int | None


@dataclass(frozen=True)
class PublicDataset:
    """A public dataset of the registry (``hsmap/study/public_data.yaml``)."""

    name: str
    title: str
    folder: str
    citation: str
    licence: str
    sources: tuple[str, ...]
    files: tuple[PublicFile, ...]
    layout: str | None = None

    @property
    def size(self) -> int | None:
        """Bytes of all files (None where a file's size is not listed)."""
        sizes = [f.size for f in self.files]
        return None if None in sizes else sum(sizes)


def registry() -> dict[str, PublicDataset]:
    """The public datasets by name (``freiburg``, ``bormann``, ``octomap``), read from the package's ``public_data.yaml``."""
    where = "hsmap/study/public_data.yaml"
    text = resources.files(__package__).joinpath("public_data.yaml").read_text(encoding="utf-8")
    doc = yaml.safe_load(text)
    if not isinstance(doc, dict) or not isinstance(doc.get("datasets"), dict):
        raise ConfigError(f"{where}: expected a mapping 'datasets'")
    out = {}
    for name, d in doc["datasets"].items():
        try:
            if "hashes" in d:
                files = _hashed_files(str(d["hashes"]), str(d["base_url"]))
            else:
                files = tuple(PublicFile(str(p), str(f["url"]), str(f["sha256"]).lower(), int(f["size"]))
                              for p, f in d["files"].items())
            out[str(name)] = PublicDataset(str(name), str(d["title"]), str(d["folder"]), str(d["citation"]),
                                           str(d["licence"]), tuple(map(str, d.get("sources") or ())), files,
                                           None if d.get("layout") is None else str(d["layout"]))
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise ConfigError(f"{where}: dataset {name!r}: malformed entry ({exc})") from None
    return out


def _hashed_files(hashes: str, base_url: str) -> tuple[PublicFile, ...]:
    """The files of a ``sha256sum`` list of package data, each at ``base_url`` + its name."""
    text = resources.files(__package__).joinpath(hashes).read_text(encoding="utf-8")
    files = []
    for lineno, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        parts = line.split(maxsplit=1)
        if len(parts) != 2 or len(parts[0]) != 64:
            raise ValueError(f"{hashes}:{lineno}: expected 'SHA256  NAME'")
        path = parts[1].strip().lstrip("*")
        files.append(PublicFile(path, base_url.rstrip("/") + "/" + path, parts[0].lower(), None))
    if not files:
        raise ValueError(f"{hashes}: no files")
    return tuple(files)


def complete_folder(ds: PublicDataset, root: Path) -> Path | None:
    """``root / ds.folder`` when every file of dataset ``ds`` is there (not hash-checked), else None."""
    folder = Path(root) / ds.folder
    if all((folder / f.path).is_file() for f in ds.files):
        return folder
    return None
