"""Where the study keeps things: the only part of hsmap that knows the repository's layout.

- generated data (simulated datasets, cached SLAM runs and maps): ``data/generated/`` (``$HSMAP_GENERATED``);
- the study's own small inputs (published reference numbers): ``data/``;
- the third-party benchmarks, read in place: ``../shared/datasets`` beside the repository (``$HSMAP_DATASETS``).

The core library takes every path as an argument; the notebooks, the batch and the benchmarks scripts find
their defaults here.
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["repository_root", "data_dir", "generated_dir", "datasets_dir"]


def repository_root() -> Path:
    """The checkout holding ``hsmap/``, ``data/`` and ``notebooks/`` (the package is installed editable)."""
    return Path(__file__).resolve().parents[2]


def data_dir() -> Path:
    """``data/`` of the repository: the small inputs the study defines."""
    return repository_root() / "data"


def generated_dir() -> Path:
    """Where generated data goes: ``$HSMAP_GENERATED``, else ``data/generated`` of the repository."""
    env = os.environ.get("HSMAP_GENERATED")
    return Path(env) if env else data_dir() / "generated"


def datasets_dir() -> Path:
    """The third-party datasets folder: ``$HSMAP_DATASETS``, else ``../shared/datasets`` beside the repository."""
    env = os.environ.get("HSMAP_DATASETS")
    return Path(env) if env else (repository_root().parent / "shared" / "datasets").resolve()
