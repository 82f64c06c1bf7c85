"""Benchmark scripts imported as modules, for the tests of their helpers."""

from __future__ import annotations

import importlib
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import ModuleType

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"
#: benchmarks/ modules that the scripts import from each other (dropped with them)
_SHARED = ("_report", "slam")


@contextmanager
def benchmark_modules(*names: str) -> Iterator[tuple[ModuleType, ...]]:
    """The scripts ``names`` of benchmarks/, imported with benchmarks/ on ``sys.path``; afterwards the path and
    the modules (theirs and the ones they share) are gone again."""
    sys.path.insert(0, str(BENCHMARKS))
    try:
        yield tuple(importlib.import_module(n) for n in names)
    finally:
        sys.path.remove(str(BENCHMARKS))
        for n in (*names, *_SHARED):
            sys.modules.pop(n, None)
