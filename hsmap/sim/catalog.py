"""Where the shipped scenarios and the generated datasets live.

Scenarios are the YAML files in ``data/scenarios/`` of the repository (``$HSMAP_SCENARIOS`` overrides the
folder); datasets generated without an explicit output folder go to ``data/generated/<scenario>/``
(``$HSMAP_GENERATED`` overrides the folder).
"""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import ScenarioError

__all__ = ["repository_root", "scenario_dir", "list_scenarios", "resolve_scenario", "generated_dir",
           "default_output_dir"]


def repository_root() -> Path:
    """The folder holding ``hsmap/`` and ``data/`` (the package is installed editable)."""
    return Path(__file__).resolve().parents[2]


def scenario_dir() -> Path:
    """The folder of the shipped scenario files."""
    env = os.environ.get("HSMAP_SCENARIOS")
    return Path(env) if env else repository_root() / "data" / "scenarios"


def list_scenarios() -> list[str]:
    """Names of the shipped scenarios (file stems in :func:`scenario_dir`)."""
    d = scenario_dir()
    return sorted(p.stem for p in d.glob("*.yaml")) if d.is_dir() else []


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
                        f"scenarios {list_scenarios()} in {scenario_dir()}")


def generated_dir() -> Path:
    """Where generated datasets go by default."""
    env = os.environ.get("HSMAP_GENERATED")
    return Path(env) if env else repository_root() / "data" / "generated"


def default_output_dir(scenario_name: str) -> Path:
    """``data/generated/<scenario_name>``."""
    return generated_dir() / scenario_name
