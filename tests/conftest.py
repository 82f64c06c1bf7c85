"""Shared test fixtures: the datasets folder, deterministic generators."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("RERUN_ANALYTICS", "0")
os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def datasets_dir() -> Path:
    """The third-party datasets folder from $HSMAP_DATASETS; skips the test with the reason when absent."""
    env = os.environ.get("HSMAP_DATASETS")
    if not env:
        pytest.skip("HSMAP_DATASETS is not set (CI sets it to ../shared/datasets)")
    path = Path(env)
    if not path.is_dir():
        pytest.skip(f"HSMAP_DATASETS={env} is not a directory")
    return path
