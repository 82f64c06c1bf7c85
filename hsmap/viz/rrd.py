"""Checking ``.rrd`` files with the rerun command line: the binary, ``rrd verify``, what a recording holds."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

os.environ["RERUN_ANALYTICS"] = "0"  # before rerun is imported: never phone home from our runs


from ..errors import DataFormatError, HsmapError  # noqa: E402

__all__ = ["rerun_binary", "verify_rrd", "recording_contents"]

# --- verification --------------------------------------------------------------------------------------


def rerun_binary() -> Path | None:
    """The ``rerun`` command-line tool of this environment (beside the interpreter), or on PATH."""
    beside = Path(sys.executable).with_name("rerun")
    if beside.is_file() and os.access(beside, os.X_OK):
        return beside
    found = shutil.which("rerun")
    return Path(found) if found else None


def verify_rrd(path: str | os.PathLike, *, timeout: float = 300.0) -> str:
    """Run ``rerun rrd verify PATH``; returns its report, raises :class:`DataFormatError` when it fails.

    Raises :class:`HsmapError` when no ``rerun`` binary is installed.
    """
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(f"{path}: no such recording")
    exe = rerun_binary()
    if exe is None:
        raise HsmapError("the 'rerun' command-line tool is not installed (it comes with rerun-sdk)")
    env = dict(os.environ, RERUN_ANALYTICS="0", NO_COLOR="1", RUST_LOG_STYLE="never")
    try:
        r = subprocess.run([str(exe), "rrd", "verify", str(path)], capture_output=True, text=True,
                           timeout=timeout, env=env)
    except subprocess.TimeoutExpired:
        raise DataFormatError(f"{path}: 'rerun rrd verify' did not finish in {timeout:.0f} s") from None
    out = _ANSI.sub("", (r.stdout + r.stderr)).strip()
    if r.returncode != 0:
        lines = [line.strip() for line in out.splitlines() if line.strip()]
        errors = [line for line in lines if line.startswith("Error")] or lines[-3:]
        raise DataFormatError(f"{path}: 'rerun rrd verify' failed (exit {r.returncode}): {' | '.join(errors)}")
    return out


_ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")


_CHUNK_LINE = re.compile(r"with (\d+) rows .* - (/\S*) - data columns: \[(.*)\]")


def recording_contents(path: str | os.PathLike, *, timeout: float = 300.0) -> dict[str, dict[str, Any]]:
    """What a recording holds, per entity, from ``rerun rrd print``: ``{"/world/robot": {"columns":
    {"Transform3D:translation", ...}, "rows": 177}, ...}`` (blueprint entities included)."""
    exe = rerun_binary()
    if exe is None:
        raise HsmapError("the 'rerun' command-line tool is not installed (it comes with rerun-sdk)")
    env = dict(os.environ, RERUN_ANALYTICS="0", NO_COLOR="1", RUST_LOG_STYLE="never")
    r = subprocess.run([str(exe), "rrd", "print", str(path)], capture_output=True, text=True, timeout=timeout,
                       env=env)
    if r.returncode != 0:
        raise DataFormatError(f"{path}: 'rerun rrd print' failed: {_ANSI.sub('', r.stderr).strip()[-500:]}")
    out: dict[str, dict[str, Any]] = {}
    for line in r.stdout.splitlines():
        m = _CHUNK_LINE.search(line)
        if m:
            e = out.setdefault(m.group(2), {"columns": set(), "rows": 0})
            e["rows"] += int(m.group(1))
            e["columns"].update(m.group(3).split())
    return out
