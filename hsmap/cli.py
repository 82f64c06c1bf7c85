"""The ``hsmap`` command: ``hsmap --help`` lists the sub-commands.

Every sub-command exits 0 on success; on bad input it prints one line ``hsmap: error: <reason>`` to
stderr and exits 2 (input/usage) or 1 (a stage failed).
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import warnings

from . import __version__
from ._blas import limited_blas
from .commands import COMMANDS
from .errors import HsmapError


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="hsmap",
        description="Multi-LiDAR indoor mapping: Harmony Search scan matching and SLAM, door detection, "
        "room segmentation and topological maps.",
    )
    parser.add_argument("--version", action="version", version=f"hsmap {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        mod = importlib.import_module(f".commands.{name}", __package__)
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=mod.__doc__)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings as one line on stderr (``hsmap: warning: ...``), not Python's two-line form."""
    print(f"hsmap: warning: {message}", file=sys.stderr if file is None else file)


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("RERUN_ANALYTICS", "0")
    warnings.showwarning = _show_warning
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    try:
        with limited_blas():  # hsmap's own process: BLAS on $HSMAP_BLAS_THREADS threads throughout
            return int(args._run(args) or 0)
    except HsmapError as exc:
        print(f"hsmap: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("hsmap: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
