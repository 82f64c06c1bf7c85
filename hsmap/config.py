"""Configuration dataclasses <-> YAML, with unknown keys and wrong types reported by name."""

from __future__ import annotations

import dataclasses
import enum
import inspect
import os
import types
import typing
import warnings
from pathlib import Path
from typing import Any, TypeVar

import yaml

from .errors import ConfigError, HsmapWarning, InputError
from .io import to_plain, write_text
from .limits import load_yaml, quote, read_bounded

T = TypeVar("T")

__all__ = ["from_dict", "to_dict", "read_yaml", "load_config", "dump_config", "yaml_error_text", "field_docs",
           "config_reference"]


def to_dict(cfg: Any) -> dict[str, Any]:
    """A plain dict (nested for nested dataclasses) of a configuration dataclass."""
    return to_plain(dataclasses.asdict(cfg))


def yaml_error_text(exc: Exception) -> str:
    """A YAML parser error on one line: ``line L, column C: problem (context)``."""
    mark = getattr(exc, "problem_mark", None)
    problem = getattr(exc, "problem", None)
    context = getattr(exc, "context", None)
    if problem is None:
        return " ".join(str(exc).split())
    where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
    return where + " ".join(str(problem).split()) + (f" ({' '.join(str(context).split())})" if context else "")


def _check_type(value: Any, hint: Any, where: str) -> None:
    """ConfigError naming ``where`` when a YAML value cannot be what the field's annotation says (a number, a
    whole number, true/false, text); other annotations are left to the dataclass's own checks."""
    options = typing.get_args(hint) if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union \
        else (hint,)
    if value is None:
        if type(None) in options:
            return
    kinds = [o for o in options if o is not type(None)]
    if len(kinds) != 1:
        return
    kind = kinds[0]
    if isinstance(kind, type) and issubclass(kind, enum.Enum):
        if not isinstance(value, (str, kind)):
            raise ConfigError(f"{where} must be one of {[m.value for m in kind]}, got {quote(value)}")
        return
    expected = {float: "a number", int: "a whole number", bool: "true or false", str: "text"}.get(kind)
    if expected is None:
        return
    ok = (isinstance(value, bool) if kind is bool else
          isinstance(value, str) if kind is str else
          isinstance(value, int) and not isinstance(value, bool) if kind is int else
          isinstance(value, (int, float)) and not isinstance(value, bool))
    if not ok:
        raise ConfigError(f"{where} must be {expected}{' or null' if type(None) in options else ''}, "
                          f"got {quote(value)}")
    if kind is float and value != value:
        raise ConfigError(f"{where} must be a number, got NaN")


def _moved_keys(cls: type, data: dict[str, Any], where: str) -> dict[str, Any]:
    """``data`` with each key that ``cls.MOVED_KEYS`` maps (dotted path -> dotted path) read at its new place,
    with a warning; both places given is an error. ``data`` itself is left as it is."""
    for old, new in getattr(cls, "MOVED_KEYS", {}).items():
        *old_parents, old_key = old.split(".")
        node = data
        for part in old_parents:
            node = node.get(part) if isinstance(node, dict) else None
        if not isinstance(node, dict) or old_key not in node:
            continue
        value = node[old_key]
        data = _set_path(_set_path(data, old.split("."), None, remove=True), new.split("."), value, where)
        warnings.warn(f"{where}.{old} is read as {where}.{new}; write it there", HsmapWarning, stacklevel=3)
    return data


def _set_path(data: dict[str, Any], path: list[str], value: Any, where: str = "", remove: bool = False
              ) -> dict[str, Any]:
    """A copy of ``data`` with ``path`` set to ``value`` (``remove``: taken out), copying the mappings on the way."""
    out = dict(data)
    if len(path) == 1:
        if remove:
            out.pop(path[0], None)
        elif path[0] in out:
            raise ConfigError(f"{where}.{path[0]} is given twice, under its old and its new name")
        else:
            out[path[0]] = value
        return out
    child = out.get(path[0])
    out[path[0]] = _set_path(child if isinstance(child, dict) else {}, path[1:], value, f"{where}.{path[0]}", remove)
    return out


def from_dict(cls: type[T], data: dict[str, Any] | None, where: str = "config") -> T:
    """Build dataclass ``cls`` from ``data``; unknown keys raise :class:`ConfigError` naming them, and so do values
    of the wrong kind (text where a number is expected, ...)."""
    if data is None:
        return cls()
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a mapping of {cls.__name__} fields, got {type(data).__name__}")
    data = _moved_keys(cls, data, where)
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    hints = typing.get_type_hints(cls)
    odd = [k for k in data if not isinstance(k, str)]
    if odd:
        raise ConfigError(f"{where}: key {quote(odd[0])} is not a name; {cls.__name__} has {sorted(fields)}")
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {unknown}; {cls.__name__} has {sorted(fields)}")
    kwargs = {}
    for k, v in data.items():
        sub = hints.get(k)
        nested = dataclasses.is_dataclass(sub) and isinstance(v, dict)
        if dataclasses.is_dataclass(sub) and not nested and not isinstance(v, sub):
            raise ConfigError(f"{where}.{k} must be a mapping of {sub.__name__} fields (key: value lines), "
                              f"got {quote(v)}")
        if not nested:
            _check_type(v, sub, f"{where}.{k}")
        kwargs[k] = from_dict(sub, v, f"{where}.{k}") if nested else v  # type: ignore[arg-type]
    try:
        return cls(**kwargs)
    except (TypeError, ValueError, OverflowError) as exc:  # the dataclass's own checks: the file (or key) in front
        text = " ".join(str(exc).split())
        text = text if len(text) <= 600 else text[:597] + "..."
        raise ConfigError(text if text.startswith(where) else f"{where}: {text}") from None


def read_yaml(path: str | os.PathLike, what: str = "configuration file") -> Any:
    """The YAML document in ``path`` (None for an empty file).

    Raises
    ------
    ConfigError
        The file cannot be read (``"PATH: cannot read the WHAT: reason"``) or is not valid YAML.
    """
    path = Path(path)
    try:
        return load_yaml(read_bounded(path, what).decode("utf-8"))
    except InputError as exc:
        raise ConfigError(str(exc)) from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the {what}: {exc.strerror}") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: cannot read the {what}: not UTF-8 text ({exc.reason})") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {yaml_error_text(exc)}") from None


def load_config(cls: type[T], path: str | os.PathLike) -> T:
    """Load dataclass ``cls`` from a YAML file."""
    return from_dict(cls, read_yaml(path), str(path))


def dump_config(cfg: Any, path: str | os.PathLike) -> None:
    """Write a configuration dataclass as YAML, atomically."""
    write_text(path, yaml.safe_dump(to_dict(cfg), sort_keys=False))


def field_docs(cls: type) -> dict[str, str]:
    """Each field's meaning from the numpydoc ``Attributes`` section of dataclass ``cls``'s docstring, joined into
    one line (``a, b : float`` documents both)."""
    doc = inspect.cleandoc(cls.__doc__ or "")
    lines = doc.splitlines()
    try:
        start = next(i for i, line in enumerate(lines[:-1])
                     if line.strip() == "Attributes" and set(lines[i + 1].strip()) == {"-"}) + 2
    except StopIteration:
        return {}
    out: dict[str, str] = {}
    names: list[str] = []
    text: list[str] = []

    def flush() -> None:
        for name in names:
            out[name] = " ".join(text)

    for i in range(start, len(lines)):
        line = lines[i]
        if i + 1 < len(lines) and lines[i + 1].strip() and set(lines[i + 1].strip()) == {"-"}:
            break  # the next section's title
        if line and not line[0].isspace():
            flush()
            names = [n.strip() for n in line.split(" : ")[0].split(",")]
            text = []
        elif line.strip():
            text.append(line.strip())
    flush()
    return out


def _default_text(value: Any) -> str:
    value = to_plain(value)
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, list):
        return "[" + ", ".join(_default_text(v) for v in value) + "]"
    return "null" if value is None else str(value).lower() if isinstance(value, bool) else str(value)


def config_reference(cfg: Any, prefix: str = "") -> list[tuple[str, str, str]]:
    """Every key of a configuration dataclass instance (nested ones flattened with dots), its value (the
    defaults, for ``cls()``) as YAML writes it and its meaning (:func:`field_docs`; empty where undocumented)."""
    docs = field_docs(type(cfg))
    rows: list[tuple[str, str, str]] = []
    for f in dataclasses.fields(cfg):
        value = getattr(cfg, f.name)
        key = f"{prefix}{f.name}"
        if dataclasses.is_dataclass(value):
            rows.extend(config_reference(value, key + "."))
        else:
            rows.append((key, _default_text(value), docs.get(f.name, "")))
    return rows
