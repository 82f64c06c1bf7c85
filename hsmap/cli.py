"""The ``hsmap`` command: ``hsmap --help`` lists the sub-commands.

Every sub-command exits 0 on success. Every expected failure ends in one place, :func:`main`, as one line
``hsmap: error: <reason>`` on stderr and exit status 2: bad input or configuration (an
:class:`~hsmap.errors.HsmapError`, the reason naming the file, key, field or flag), an output that cannot be
written (an ``OSError``, e.g. a full disk or a read-only folder: the reason names the file), and a malformed
command line (argparse's message, on one line). A run that completes but has a failed part (a notebook of
``hsmap reproduce``) exits 1. An interrupt (Ctrl-C, SIGTERM) ends with ``hsmap: interrupted`` and status 130
(143 for SIGTERM), after the command has removed its temporary files; earlier outputs are left as they were.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import re
import signal
import sys
import warnings

from . import __version__
from ._blas import limited_blas
from .commands import COMMANDS
from .errors import HsmapError, HsmapNote, HsmapWarning
from .limits import MAX_MESSAGE

_NEGATIVE = re.compile(r"^-\.?\d")  # '-0.04,0,0', '-.5', '-2'


class _Parser(argparse.ArgumentParser):
    """argparse with its usage errors on one line (``hsmap slam: error: ...``), exit status 2, and a flag's value
    that starts with a minus sign taken as its value (``--extrinsic2d -0.04,0,0``), where argparse would take it
    for a flag unless it is a plain number."""

    def error(self, message: str):  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")

    def parse_known_args(self, args=None, namespace=None):  # type: ignore[override]
        args = list(sys.argv[1:] if args is None else args)
        takes_value = {s for a in self._actions if a.nargs is None for s in a.option_strings}
        joined: list[str] = []
        i = 0
        while i < len(args):
            if args[i] in takes_value and i + 1 < len(args) and _NEGATIVE.match(args[i + 1]):
                joined.append(f"{args[i]}={args[i + 1]}")
                i += 2
                continue
            if args[i] == "--":
                joined.extend(args[i:])
                break
            joined.append(args[i])
            i += 1
        return super().parse_known_args(joined, namespace)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="hsmap",
        description="Multi-LiDAR indoor mapping: Harmony Search scan matching and SLAM, door detection, "
        "room segmentation and topological maps.",
    )
    parser.add_argument("--version", action="version", version=f"hsmap {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name in COMMANDS:
        mod = importlib.import_module(f".commands.{name}", __package__)
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=mod.__doc__)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings as one line on stderr (``hsmap: warning: ...``, notes ``hsmap: note: ...``), not Python's
    two-line form."""
    kind = "note" if issubclass(category, HsmapNote) else "warning"
    print(f"hsmap: {kind}: {message}", file=sys.stderr if file is None else file)


class _Terminated(KeyboardInterrupt):
    """SIGTERM, raised like Ctrl-C so that every command's clean-up runs."""


def _on_sigterm(signum, frame) -> None:
    raise _Terminated()


def _one_line(text: str) -> str:
    line = " ".join(str(text).split())
    return line if len(line) <= MAX_MESSAGE else line[: MAX_MESSAGE - 3] + "..."


def _size_hint() -> str:
    from .limits import available_memory

    return f"{available_memory() / 2**30:.1f} GiB available; a smaller input or a coarser resolution needs less"


def main(argv: list[str] | None = None) -> int:
    """Run the ``hsmap`` command line; returns the exit status. hsmap's warnings are printed, one line each,
    whatever the caller's warning filters (restored on return)."""
    with warnings.catch_warnings():
        warnings.showwarning = _show_warning
        warnings.simplefilter("default", HsmapWarning)
        return _main(argv)


def _main(argv: list[str] | None) -> int:
    os.environ.setdefault("RERUN_ANALYTICS", "0")
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    previous = signal.getsignal(signal.SIGTERM)
    if previous in (signal.SIG_DFL, None):
        signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        with limited_blas():  # hsmap's own process: BLAS on $HSMAP_BLAS_THREADS threads throughout
            return int(args._run(args) or 0)
    except HsmapError as exc:
        print(f"hsmap: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # the reader of stdout went away (``hsmap config show | head``): not an error
        with contextlib.suppress(OSError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as exc:  # an output (or input) the system refused: full disk, read-only folder, ...
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        print(f"hsmap: error: {where}{_one_line(exc.strerror or exc)}", file=sys.stderr)
        return 2
    except MemoryError:  # a size no check foresaw: still one line, not a traceback
        print(f"hsmap: error: {args.command}: out of memory ({_size_hint()})", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        print("hsmap: interrupted", file=sys.stderr)
        return 143 if isinstance(exc, _Terminated) else 130
    finally:
        if previous in (signal.SIG_DFL, None):
            signal.signal(signal.SIGTERM, signal.SIG_DFL)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
