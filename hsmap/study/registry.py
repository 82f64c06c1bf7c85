"""The registry of public benchmark datasets (``hsmap/study/public_data.yaml``: files, URLs at pinned commits,
SHA-256, sizes, citations) and whether a folder holds a whole dataset."""

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
    size : int
        Bytes.
    """

    path: str
    url: str
    sha256: str
    size: int


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

    @property
    def size(self) -> int:
        return sum(f.size for f in self.files)


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
            files = tuple(PublicFile(str(p), str(f["url"]), str(f["sha256"]).lower(), int(f["size"]))
                          for p, f in d["files"].items())
            out[str(name)] = PublicDataset(str(name), str(d["title"]), str(d["folder"]), str(d["citation"]),
                                           str(d["licence"]), tuple(map(str, d.get("sources") or ())), files)
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise ConfigError(f"{where}: dataset {name!r}: malformed entry ({exc})") from None
    return out


def complete_folder(ds: PublicDataset, root: Path) -> Path | None:
    """``root / ds.folder`` when every file of dataset ``ds`` is there (not hash-checked), else None."""
    folder = Path(root) / ds.folder
    if all((folder / f.path).is_file() for f in ds.files):
        return folder
    return None
