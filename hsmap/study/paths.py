"""Where the study keeps things: the only part of hsmap that knows the repository's layout, and what an
installed hsmap uses instead of it.

hsmap runs either from a checkout of its repository (``make setup`` installs it editable) or from an installed
wheel (``pip install hsmap``). A checkout is recognised by ``pyproject.toml`` and ``notebooks/`` beside the
package folder.

- the study notebooks: a checkout's ``notebooks/``; installed, the copy shipped as package data
  (``hsmap/study/notebooks/``, found through :mod:`importlib.resources`);
- generated data (simulated datasets, cached SLAM runs and maps): ``$HSMAP_GENERATED``, else a checkout's
  ``data/generated/``, else ``generated/`` in the user cache (:func:`user_cache_dir`);
- reports: a checkout's ``reports/``, else ``reports/`` in the working directory;
- the third-party benchmarks: :func:`datasets_dir` (``$HSMAP_DATASETS``, else the data ``hsmap data fetch``
  downloaded, else ``../shared/datasets`` beside a checkout).

The core library takes every path as an argument; the notebooks, the batch, the commands and the benchmark
scripts find their defaults here.
"""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path

from .registry import complete_folder, registry

__all__ = [
    "repository_root",
    "generated_dir",
    "reports_dir",
    "notebooks_dir",
    "user_cache_dir",
    "datasets_dir",
    "fetch_dir",
    "DATASETS_ENV",
    "GENERATED_ENV",
    "CACHE_ENV",
]

#: The third-party datasets folder; when set, it is the only place looked at.
DATASETS_ENV = "HSMAP_DATASETS"
#: Where generated data goes.
GENERATED_ENV = "HSMAP_GENERATED"
#: hsmap's user cache (default: the platform's cache folder, e.g. ``~/.cache/hsmap``).
CACHE_ENV = "HSMAP_CACHE"


def repository_root() -> Path | None:
    """The checkout holding ``hsmap/``, ``notebooks/`` and ``pyproject.toml``; None for an installed hsmap."""
    root = Path(__file__).resolve().parents[2]
    if (root / "pyproject.toml").is_file() and (root / "notebooks").is_dir() and (root / "hsmap").is_dir():
        return root
    return None


def user_cache_dir() -> Path:
    """hsmap's user cache: ``$HSMAP_CACHE``, else the platform's cache folder (``~/.cache/hsmap`` on Linux)."""
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env).expanduser()
    import platformdirs

    return Path(platformdirs.user_cache_dir("hsmap"))


def generated_dir() -> Path:
    """Where generated data goes: ``$HSMAP_GENERATED``, else a checkout's ``data/generated``, else
    ``generated/`` in the user cache."""
    env = os.environ.get(GENERATED_ENV)
    if env:
        return Path(env)
    root = repository_root()
    return root / "data" / "generated" if root is not None else user_cache_dir() / "generated"


def reports_dir() -> Path:
    """The default reports folder: a checkout's ``reports/``, else ``reports/`` in the working directory."""
    root = repository_root()
    return root / "reports" if root is not None else Path.cwd() / "reports"


def notebooks_dir() -> Path:
    """The study notebooks: a checkout's ``notebooks/``, else the copy installed with the package."""
    root = repository_root()
    if root is not None:
        return root / "notebooks"
    return Path(str(resources.files(__package__).joinpath("notebooks")))


def fetch_dir() -> Path:
    """Where ``hsmap data fetch`` puts the data: ``datasets/`` in hsmap's user cache (``$HSMAP_CACHE``, else e.g.
    ``~/.cache/hsmap``), laid out as ``$HSMAP_DATASETS`` is."""
    return user_cache_dir() / "datasets"


def datasets_dir() -> Path:
    """The third-party datasets folder (``slam2d/``, ``ipa_room_segmentation/``).

    ``$HSMAP_DATASETS`` when it is set (the only place looked at then); else the folder ``hsmap data fetch``
    downloads into (:func:`hsmap.study.paths.fetch_dir`) when it holds a complete dataset (every file of
    it; what a failed download left does not count); else
    ``../shared/datasets`` beside a checkout when that exists; else the download folder (empty: notebook 08 and
    the benchmark tests then say to run ``hsmap data fetch``).
    """
    env = os.environ.get(DATASETS_ENV)
    if env:
        return Path(env)
    fetched = fetch_dir()
    if fetched.is_dir() and any(complete_folder(ds, fetched) is not None for ds in registry().values()):
        return fetched
    root = repository_root()
    if root is not None:
        beside = (root.parent / "shared" / "datasets").resolve()
        if beside.is_dir():
            return beside
    return fetched
