"""Notebook parameters given to ``hsmap reproduce`` (``-p KEY VALUE``, ``--parameters-file``), checked against the
names and types each notebook's ``parameters`` cell declares, before any notebook runs; and inside a running
notebook (:func:`check_declared`, its first cell after the parameters), so that plain papermill checks them too."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from ..errors import ConfigError
from ..limits import quote
from .discovery import inspect_parameters

__all__ = ["check_parameters", "declared_parameters", "check_declared"]

_KINDS = {"bool": "true or false", "int": "a whole number", "float": "a number", "str": "text"}


def _fits(value: Any, kind: str) -> bool:
    if kind == "bool":
        return isinstance(value, bool)
    if kind == "int":
        return isinstance(value, int) and not isinstance(value, bool)
    if kind == "float":
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if kind == "str":
        return isinstance(value, str)
    return True  # a type papermill does not infer (None, a list): the notebook checks it


def declared_parameters(spec) -> dict[str, dict[str, Any]] | None:
    """The parameters notebook ``spec`` declares (:func:`hsmap.study.discovery.inspect_parameters`), or None when its
    parameters cell cannot be read without running it (no kernel named in the notebook)."""
    try:
        return inspect_parameters(spec)
    except ValueError:
        return None


def check_parameters(declared: Mapping[str, Mapping[str, Mapping[str, Any]] | None], common: Mapping[str, Any],
                     per_notebook: Mapping[str, Mapping[str, Any]], *, where: Sequence[str] = ()) -> None:
    """ConfigError naming the parameter (and the notebook) when a parameter is declared by none of the notebooks
    it is given to, or its value is not of the type they declare.

    Parameters
    ----------
    declared : mapping
        Notebook name -> its parameters as :func:`hsmap.study.discovery.inspect_parameters` gives them
        (name -> ``{"inferred_type_name": ..., "default": ..., "help": ...}``); None where unknown (such a
        notebook may take any parameter).
    common : mapping
        Parameters for every notebook (``-p KEY VALUE``).
    per_notebook : mapping
        Notebook name -> its own parameters (``--parameters-file``'s ``notebooks:``).
    """
    def check(name: str, value: Any, notebooks: Sequence[str], flag: str) -> None:
        if any(declared.get(nb) is None for nb in notebooks):
            return
        having = [nb for nb in notebooks if name in declared[nb]]
        if not having:
            known = sorted({k for nb in notebooks for k in declared[nb]})
            raise ConfigError(f"{flag} {name}: no such parameter in {', '.join(notebooks)}; they have "
                              f"{', '.join(known) or 'none'}")
        for nb in having:
            spec = declared[nb][name]
            kind = str(spec.get("inferred_type_name") or "")
            if kind in _KINDS and not _fits(value, kind):
                raise ConfigError(f"{flag} {name}: {nb} declares it {kind} ({_KINDS[kind]}; default "
                                  f"{spec.get('default')}), got {quote(value)}")

    names = list(declared)
    for name, value in common.items():
        check(str(name), value, names, "-p")
    for nb, params in per_notebook.items():
        for name, value in params.items():
            check(str(name), value, [nb], f"--parameters-file notebooks.{nb}:")


def check_declared(namespace: Mapping[str, Any]) -> None:
    """ConfigError naming the parameter when a notebook parameter's value is not of the type its line in the
    ``parameters`` cell declares (``quick: bool = False``).

    Every study notebook calls it with ``globals()`` in its first cell after the parameters: papermill injects
    its values (``papermill NB OUT -p quick notabool``) after the parameters cell and before that one, so a bad
    value stops the notebook there, named, whether ``hsmap reproduce`` or plain papermill runs it. The declared
    types are the annotations the parameters cell leaves in the namespace (``__annotations__``); a float takes
    a whole number too.
    """
    annotations = namespace.get("__annotations__") or {}
    for name, kind in annotations.items():
        if name not in namespace:
            continue
        kind_name = kind if isinstance(kind, str) else getattr(kind, "__name__", "")
        value = namespace[name]
        if kind_name in _KINDS and not _fits(value, kind_name):
            raise ConfigError(f"notebook parameter {name} is declared {kind_name} ({_KINDS[kind_name]}) in the "
                              f"parameters cell, got {quote(value)} (papermill -p {name} VALUE, or hsmap reproduce)")
