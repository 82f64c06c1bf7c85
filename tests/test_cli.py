import subprocess
import sys

import hsmap


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "hsmap.cli", *args], capture_output=True, text=True)


def test_version():
    r = run_cli("--version")
    assert r.returncode == 0
    assert r.stdout.strip() == f"hsmap {hsmap.__version__}"


def test_help_lists_commands():
    r = run_cli("--help")
    assert r.returncode == 0
    for cmd in ("simulate", "slam", "map", "segment", "evaluate", "reproduce"):
        assert cmd in r.stdout
