"""The shipped scenarios: the YAML files of the package folder ``hsmap/sim/scenarios/`` (package data), found
through :mod:`importlib.resources`, so they come with any installation of hsmap, not with a repository."""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path

from ..errors import ScenarioError

__all__ = ["scenario_dir", "list_scenarios", "resolve_scenario"]


def scenario_dir() -> Path:
    """The folder of the shipped scenario files (inside the installed package)."""
    return Path(str(resources.files(__package__).joinpath("scenarios")))


def list_scenarios() -> list[str]:
    """Names of the shipped scenarios (file stems in :func:`scenario_dir`)."""
    return sorted(p.stem for p in scenario_dir().glob("*.yaml"))


def resolve_scenario(name_or_path: str | os.PathLike) -> Path:
    """The scenario file for a shipped scenario name or a path to a YAML file."""
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml") or p.is_file() or os.sep in str(name_or_path):
        if not p.is_file():
            raise ScenarioError(f"{p}: no such scenario file")
        return p
    cand = scenario_dir() / f"{p.name}.yaml"
    if cand.is_file():
        return cand
    raise ScenarioError(f"unknown scenario {str(name_or_path)!r}: not a file, and not one of the shipped "
                        f"scenarios {list_scenarios()}")
