"""Shared test fixtures: the datasets folder, deterministic generators."""

from __future__ import annotations

import functools
import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("RERUN_ANALYTICS", "0")
os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


@functools.cache
def _datasets() -> tuple[Path, str | None]:
    """The third-party datasets folder and why the tests cannot use it (None: they can), looked up once."""
    from hsmap.study.paths import datasets_dir as find
    from hsmap.study.public_data import missing_data_reason

    path = find()
    return path, missing_data_reason(["freiburg", "bormann"], path)


@pytest.fixture
def datasets_dir() -> Path:
    """The third-party datasets folder (``slam2d/``, ``ipa_room_segmentation/``) where the study finds it:
    $HSMAP_DATASETS, else what ``hsmap data fetch`` downloaded, else ../shared/datasets beside the checkout
    (:func:`hsmap.study.paths.datasets_dir`). Skips the test, saying why, unless both datasets are complete there."""
    path, reason = _datasets()
    if reason:
        pytest.skip(reason)
    return path
