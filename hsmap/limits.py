"""Bounds on what an input may ask of the machine, and bounded quoting of input values in messages.

Every array sized by an input (a grid from a resolution, a point count from a file header, an image from its
header) is checked with :func:`check_allocation` before it is allocated; every input value quoted in a message
goes through :func:`quote`, so that a value built from YAML aliases cannot make a message of gigabytes. YAML
documents are read with :func:`load_yaml`: YAML 1.2 numbers (``1e-1`` is a number) and at most
:data:`MAX_YAML_NODES` values once aliases are expanded; their files with :func:`read_bounded`, at most
:data:`MAX_YAML_BYTES` (``--config /dev/zero`` never ends otherwise).
"""

from __future__ import annotations

import os
import re
import reprlib
from typing import Any

import yaml

from .errors import InputError

__all__ = ["quote", "check_allocation", "available_memory", "load_yaml", "read_bounded", "MAX_YAML_NODES",
           "MAX_YAML_BYTES", "MAX_MESSAGE"]

#: Longest error message the command line prints, characters.
MAX_MESSAGE = 1000
#: Most values (scalars, lists, mappings, counting each alias use) a YAML document may expand to.
MAX_YAML_NODES = 1_000_000
#: Largest YAML file read, bytes (a configuration, scenario, map or parameters file is a few kilobytes; the
#: node bound above is reached well within it).
MAX_YAML_BYTES = 16 * 2**20


def read_bounded(path: str | os.PathLike, what: str, limit: int = MAX_YAML_BYTES) -> bytes:
    """The bytes of the file ``path``, read up to ``limit`` of them: an endless or huge input (``/dev/zero``) is
    an :class:`InputError` naming it and the ``what`` expected.

    Raises
    ------
    OSError
        The file cannot be opened or read (the caller names the reason).
    InputError
        It holds more than ``limit`` bytes.
    """
    with open(path, "rb") as fh:
        data = fh.read(limit + 1)
    if len(data) > limit:
        raise InputError(f"{path}: more than {limit} bytes; expected a {what} (a small YAML text file)")
    return data

_repr = reprlib.Repr()
_repr.maxlevel = 3
_repr.maxdict = _repr.maxlist = _repr.maxtuple = _repr.maxset = 6
_repr.maxstring = _repr.maxother = _repr.maxlong = 60


def quote(value: Any, limit: int = 120) -> str:
    """``repr(value)``, shortened to at most ``limit`` characters (nested containers cut at three levels and six
    items each), so that a message quoting an input value stays one short line."""
    text = _repr.repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def available_memory() -> int:
    """Bytes of memory this process could still allocate: the system's available memory (``MemAvailable`` of
    /proc/meminfo), else its physical memory."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return 1 << 40


def _size(nbytes: float) -> str:
    for unit, scale in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if nbytes >= scale:
            return f"{nbytes / scale:.1f} {unit}"
    return f"{int(nbytes)} bytes"


def check_allocation(nbytes: float, what: str, error: type[Exception] = InputError) -> None:
    """Raise ``error`` (an :class:`~hsmap.errors.HsmapError`) when ``nbytes`` is more than the memory available.

    Parameters
    ----------
    nbytes : float
        Bytes the caller is about to allocate (a float, so that products of header values cannot overflow).
    what : str
        What asks for it, naming the file, key or flag (``"--resolution 0.0001: a 300000 x 300000 grid"``).
    """
    limit = available_memory()
    if not nbytes <= limit:
        raise error(f"{what} needs {_size(nbytes)} of memory, more than the {_size(limit)} available")


class _Loader(yaml.SafeLoader):
    """The safe loader, reading YAML 1.2 floats (``1e-1``, ``1E5``) as numbers like YAML 1.2 and map_server do."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


def _expanded_size(node: yaml.Node, limit: int) -> int:
    """The number of values ``node`` expands to, aliases counted at every use (stops past ``limit``)."""
    memo: dict[int, int] = {}
    active: set[int] = set()

    def size(n: yaml.Node) -> int:
        key = id(n)
        if key in memo:
            return memo[key]
        if key in active:  # a recursive alias: count it once
            return 1
        active.add(key)
        total = 1
        if isinstance(n, yaml.SequenceNode):
            for child in n.value:
                total += size(child)
                if total > limit:
                    break
        elif isinstance(n, yaml.MappingNode):
            for k, v in n.value:
                total += size(k) + size(v)
                if total > limit:
                    break
        active.discard(key)
        memo[key] = total
        return total

    return size(node)


def load_yaml(text: str | bytes) -> Any:
    """The YAML document in ``text`` (None when empty), read with :class:`_Loader`.

    Raises
    ------
    yaml.YAMLError
        The text is not valid YAML, nests deeper than Python's recursion limit, or expands (through aliases) to
        more than :data:`MAX_YAML_NODES` values.
    """
    loader = _Loader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        if _expanded_size(node, MAX_YAML_NODES) > MAX_YAML_NODES:
            raise yaml.YAMLError(f"the document expands to more than {MAX_YAML_NODES} values through its aliases "
                                 f"(&name / *name)")
        return loader.construct_document(node)
    except RecursionError:
        raise yaml.YAMLError("the document nests too deeply") from None
    finally:
        loader.dispose()
