"""The README's front door: the quickstart comes first and its Python example runs as written (on a small
simulated two-rooms run), its commands exist, the reference's tables keep their cells short, and its list of
study notebooks is the notebooks folder."""

from __future__ import annotations

import contextlib
import io
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from hsmap.study.discovery import discover

REPO = Path(__file__).resolve().parent.parent
README = (REPO / "README.md").read_text(encoding="utf-8")
#: The longest table cell the reference keeps (about 200 characters; longer text is prose under a heading).
MAX_CELL = 240


def _section(title: str) -> str:
    m = re.search(rf"^## {re.escape(title)}\n(.*?)(?=^## )", README, flags=re.MULTILINE | re.DOTALL)
    assert m, f"README has no section '## {title}'"
    return m.group(1)


def test_the_quickstart_comes_first():
    assert re.findall(r"^## (.+)$", README, flags=re.MULTILINE)[0] == "Quickstart"


def test_the_quickstart_commands_exist():
    shell = re.search(r"```sh\n(.*?)```", _section("Quickstart"), flags=re.DOTALL).group(1)
    commands = [line.split("#")[0].split() for line in shell.splitlines() if line.strip()]
    makefile = (REPO / "Makefile").read_text(encoding="utf-8")
    for words in commands:
        if words[0] == "make":
            assert re.search(rf"^{words[1]}:", makefile, flags=re.MULTILINE), words
            for assignment in words[2:]:
                assert re.search(rf"^{assignment.split('=')[0]} \?=", makefile, flags=re.MULTILINE), words
        else:
            assert words[0] == ".venv/bin/hsmap", words
            from hsmap.cli import build_parser

            args = build_parser().parse_args(words[1:])
            assert args.command == "map" and args.out == "DIR"
    assert ["make", "reproduce", "REPRODUCE_ARGS=--quick"] in commands


@pytest.mark.slow
def test_the_quickstart_python_example_runs(tmp_path, monkeypatch):
    from hsmap.cli import main
    from hsmap.sim.catalog import resolve_scenario

    code = re.search(r"```python\n(.*?)```", _section("Quickstart"), flags=re.DOTALL).group(1)
    assert len(code.strip().splitlines()) <= 12
    assert 'open_dataset("two-rooms")' in code
    # the two-rooms run the README's `hsmap simulate two-rooms --out two-rooms` makes, shortened and with a
    # small 3D LiDAR: the example reads only the 2D scans
    scenario = yaml.safe_load(resolve_scenario("two-rooms").read_text(encoding="utf-8"))
    scenario.setdefault("sensors", {})["lidar3d"] = {"channels": 4, "columns": 32}
    (tmp_path / "two-rooms.yaml").write_text(yaml.safe_dump(scenario), encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["simulate", "two-rooms.yaml", "--out", "two-rooms", "--max-frames", "60"]) == 0
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    m = re.fullmatch(r"(\d+) poses, (\d+) rooms, (\d+) doors\n", r.stdout)
    assert m and int(m.group(1)) == 60 and int(m.group(2)) >= 1, r.stdout


def test_no_table_cell_is_a_paragraph():
    long = []
    for number, line in enumerate(README.splitlines(), start=1):
        if line.startswith("|"):
            cells = [c.strip() for c in re.split(r"(?<!\\)\|", line)[1:-1]]
            long += [(number, len(c), c[:60]) for c in cells if len(c) > MAX_CELL]
    assert long == []


def test_the_readme_lists_every_study_notebook():
    listed = re.findall(r"^- `(\d\d-[a-z0-9-]+)`:", README, flags=re.MULTILINE)
    assert listed == [s.name for s in discover(REPO / "notebooks")]
    assert not re.search(r"\b(nine|ten|eleven|twelve) (study )?notebooks\b", README)
