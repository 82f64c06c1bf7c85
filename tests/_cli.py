"""The command line run in the test's process: its exit status and what it printed."""

from __future__ import annotations

import contextlib
import io
import warnings

from hsmap.cli import main

ERROR = "hsmap: error: "


def run_cli_out(*argv) -> tuple[int, str, str]:
    """``hsmap ARGV`` in this process: exit status, stdout and stderr (warnings printed as the command prints
    them)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), warnings.catch_warnings():
        warnings.simplefilter("always")
        code = main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


def run_cli(*argv) -> tuple[int, str]:
    """``hsmap ARGV`` in this process: exit status and stderr (stdout left as it goes)."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), warnings.catch_warnings():
        warnings.simplefilter("always")
        code = main([str(a) for a in argv])
    return code, err.getvalue()


def error_line(err: str) -> str:
    """The one ``hsmap: error:`` line of ``err`` (warnings aside), at most 1000 characters after the prefix."""
    lines = [line for line in err.splitlines() if not line.startswith("hsmap: warning:")]
    assert len(lines) == 1 and lines[0].startswith(ERROR), err[:2000]
    assert len(lines[0]) <= 1000 + len(ERROR)
    return lines[0][len(ERROR):]
