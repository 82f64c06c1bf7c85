"""The study's simulated datasets: one folder per scenario and seed, simulated once and then reused.

``data/generated/<scenario>-seed<seed>`` (or ``...-first<N>`` for quick runs) is a folder of
:func:`hsmap.sim.simulate`, kept by :class:`hsmap.pipeline.cache.FolderCache` and keyed on the parsed scenario, the
seed, the frame count and the code of the whole core package (the simulator included): change a simulator
module and the dataset is simulated again, and with it every SLAM run and map made from it.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

from ..datasets.simulated import FORMAT, FORMAT_VERSION, SimulatedDataset
from ..errors import DatasetError, InputError
from ..pipeline.cache import FolderCache, description_digest, slug
from ..sim import writer
from ..sim.catalog import resolve_scenario
from ..sim.scenario import Scenario, load_scenario
from .paths import generated_dir

__all__ = ["simulated_dataset"]


def _scenario_description(scn: Scenario, seed: int, max_frames: int | None) -> dict:
    """The parsed scenario (not its file's bytes: a scenario changed in memory by ``replace`` counts too), the
    seed and the frame count of a simulated dataset."""

    content = dataclasses.asdict(scn)
    for k in ("raw", "path", "sha256"):
        content.pop(k, None)
    return {"format": FORMAT, "format_version": FORMAT_VERSION, "scenario": description_digest(content),
            "name": scn.name, "seed": int(seed), "max_frames": None if max_frames is None else int(max_frames)}


def _dataset_loader(frames: int | None):
    def load(folder: Path) -> SimulatedDataset:
        ds = SimulatedDataset(folder)
        if frames is not None and len(ds) != frames:
            raise DatasetError(f"{folder}: {len(ds)} frames, expected {frames}")
        return ds

    return load


def _simulate_into(scn: Scenario, seed: int, max_frames: int | None):
    def compute(folder: Path) -> None:

        writer.simulate(scn, folder, seed, max_frames=max_frames)

    return compute


def simulated_dataset(scenario: str | os.PathLike | Scenario = "slam-office", seed: int = 1, *,
                      max_frames: int | None = None, root: str | os.PathLike | None = None) -> SimulatedDataset:
    """The simulated dataset of ``scenario`` with ``seed``, generated once and then reused.

    The folder is ``data/generated/<scenario>-seed<seed>`` (``root`` replaces ``data/generated``): one folder per
    seed, so notebooks using different seeds never regenerate each other's data. With ``max_frames`` (quick
    runs) only the first frames are needed: the full folder is used when it is already there and current, else
    a prefix folder ``<scenario>-seed<seed>-first<N>`` is simulated (the simulator's frames do not depend on how
    many follow, so a prefix holds the same first frames as the full route). Callers still cut their runs at
    ``max_frames``.

    Returns
    -------
    SimulatedDataset
    """

    scn = scenario if isinstance(scenario, Scenario) else load_scenario(resolve_scenario(scenario))
    seed = int(seed)
    if max_frames is not None and int(max_frames) < 1:
        raise InputError(f"max_frames must be >= 1, got {max_frames}")
    cache = FolderCache(root if root is not None else generated_dir())
    slot = f"{slug(scn.name)}-seed{seed}"
    if max_frames is not None:
        full = cache.lookup(slot, _scenario_description(scn, seed, None), _simulate_into(scn, seed, None),
                            _dataset_loader(None))
        if full is not None:
            return full.value
        n = int(max_frames)
        frames = len(writer.motion_for(scn, seed, n))
        return cache.get(f"{slot}-first{n}", _scenario_description(scn, seed, n), _simulate_into(scn, seed, n),
                         _dataset_loader(frames)).value
    frames = len(writer.motion_for(scn, seed, None))
    return cache.get(slot, _scenario_description(scn, seed, None), _simulate_into(scn, seed, None),
                     _dataset_loader(frames)).value
