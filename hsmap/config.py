"""Configuration dataclasses <-> YAML, with unknown keys and wrong types reported by name."""

from __future__ import annotations

import dataclasses
import os
import typing
from pathlib import Path
from typing import Any, TypeVar

import yaml

from .errors import ConfigError
from .io import to_plain, write_text

T = TypeVar("T")

__all__ = ["from_dict", "to_dict", "read_yaml", "load_config", "dump_config"]


def to_dict(cfg: Any) -> dict[str, Any]:
    """A plain dict (nested for nested dataclasses) of a configuration dataclass."""
    return to_plain(dataclasses.asdict(cfg))


def from_dict(cls: type[T], data: dict[str, Any] | None, where: str = "config") -> T:
    """Build dataclass ``cls`` from ``data``; unknown keys raise :class:`ConfigError` naming them."""
    if data is None:
        return cls()
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a mapping of {cls.__name__} fields, got {type(data).__name__}")
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    hints = typing.get_type_hints(cls)
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {unknown}; {cls.__name__} has {sorted(fields)}")
    kwargs = {}
    for k, v in data.items():
        sub = hints.get(k)
        nested = dataclasses.is_dataclass(sub) and isinstance(v, dict)
        kwargs[k] = from_dict(sub, v, f"{where}.{k}") if nested else v  # type: ignore[arg-type]
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as exc:
        if isinstance(exc, ConfigError):
            raise
        raise ConfigError(f"{where}: {exc}") from None


def read_yaml(path: str | os.PathLike, what: str = "configuration file") -> Any:
    """The YAML document in ``path`` (None for an empty file).

    Raises
    ------
    ConfigError
        The file cannot be read (``"PATH: cannot read the WHAT: reason"``) or is not valid YAML.
    """
    path = Path(path)
    try:
        return yaml.safe_load(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the {what}: {exc.strerror}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {exc}") from None


def load_config(cls: type[T], path: str | os.PathLike) -> T:
    """Load dataclass ``cls`` from a YAML file."""
    return from_dict(cls, read_yaml(path), str(path))


def dump_config(cfg: Any, path: str | os.PathLike) -> None:
    """Write a configuration dataclass as YAML, atomically."""
    write_text(path, yaml.safe_dump(to_dict(cfg), sort_keys=False))
