"""The set-up's system-library check (``.ci/ensure-system-libs``, run by ``make setup``): on a machine that has the
libraries it finds them every time, as root and as a user without root, and never calls apt-get or sudo then."""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
import tempfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
SCRIPT = REPO / ".ci" / "ensure-system-libs"
LIBRARIES = ("libusb-1.0.so.0", "libgomp.so.1")
RUNS = 500
# a login shell's PATH for a user without root on Debian/Ubuntu: no /sbin, where ldconfig lives
USER_PATH = "/usr/local/bin:/usr/bin:/bin"


def _missing_libraries() -> list[str]:
    ldconfig = shutil.which("ldconfig", path=os.environ.get("PATH", "") + ":/usr/sbin:/sbin")
    if ldconfig is None:
        return list(LIBRARIES)
    cache = subprocess.run([ldconfig, "-p"], capture_output=True, text=True, check=False).stdout
    return [lib for lib in LIBRARIES if f"{lib} " not in cache]


@pytest.fixture
def sandbox():
    """A world-readable folder with a copy of the check and an apt-get and a sudo that record each call and fail."""
    if shutil.which("bash") is None:
        pytest.skip("no bash on this machine")
    missing = _missing_libraries()
    if missing:
        pytest.skip(f"this machine lacks {', '.join(missing)}: the check would rightly install them")
    root = Path(tempfile.mkdtemp(prefix="hsmap-setup-check-"))
    try:
        root.chmod(0o755)
        fake = root / "bin"
        fake.mkdir(mode=0o755)
        log = root / "calls.log"
        log.touch()
        log.chmod(0o666)
        for name in ("apt-get", "sudo"):
            tool = fake / name
            tool.write_text(f'#!/bin/sh\necho "{name} $*" >> "{log}"\nexit 1\n', encoding="utf-8")
            tool.chmod(0o755)
        script = root / "ensure-system-libs"
        shutil.copyfile(SCRIPT, script)
        script.chmod(stat.S_IRWXU | stat.S_IRGRP | stat.S_IXGRP | stat.S_IROTH | stat.S_IXOTH)
        yield script, fake, log
    finally:
        shutil.rmtree(root, ignore_errors=True)


def _run_many(script: Path, fake: Path, path: str, prefix: list[str]) -> subprocess.CompletedProcess:
    loop = (f'for i in $(seq {RUNS}); do "{script}" >/dev/null 2>&1 || echo miss; done')
    env = {"PATH": f"{fake}:{path}", "LANG": "C"}
    return subprocess.run([*prefix, "bash", "-c", loop], env=env, capture_output=True, text=True, timeout=300,
                          check=False)


def test_the_check_finds_present_libraries_every_time_without_installing(sandbox):
    script, fake, log = sandbox
    r = _run_many(script, fake, os.environ.get("PATH", USER_PATH), [])
    assert r.returncode == 0, r.stderr
    misses = r.stdout.count("miss")
    assert misses == 0, f"{misses} of {RUNS} runs reported a present library as missing"
    assert log.read_text(encoding="utf-8") == "", "the check called apt-get or sudo with nothing missing"


def test_the_check_finds_present_libraries_as_a_user_without_root(sandbox):
    script, fake, log = sandbox
    if os.geteuid() == 0:
        setpriv = shutil.which("setpriv")
        if setpriv is None:
            pytest.skip("running as root and no setpriv to drop to an unprivileged user")
        prefix = [setpriv, "--reuid=65534", "--regid=65534", "--clear-groups"]  # nobody:nogroup
    else:
        prefix = []
    r = _run_many(script, fake, USER_PATH, prefix)
    assert r.returncode == 0, r.stderr
    misses = r.stdout.count("miss")
    assert misses == 0, f"{misses} of {RUNS} runs without root reported a present library as missing"
    assert log.read_text(encoding="utf-8") == "", "the check called apt-get or sudo with nothing missing"
