"""What an installation of hsmap holds: a wheel built from this checkout carries the scenarios, the study notebooks
and the study's data files as package data (found through importlib.resources), `python -m hsmap` runs, the
study tooling (Jupyter) is an extra, and the licence is MIT as pyproject says."""

from __future__ import annotations

import email
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest
from setuptools import find_packages

import hsmap
from hsmap.study import paths

REPO = Path(__file__).resolve().parent.parent
PYPROJECT = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))


def test_the_package_list_is_the_tree():
    listed = PYPROJECT["tool"]["setuptools"]["packages"]
    assert sorted(listed) == sorted([*find_packages(str(REPO), include=["hsmap*"]), "hsmap.study.notebooks"])
    assert PYPROJECT["tool"]["setuptools"]["package-dir"] == {"hsmap.study.notebooks": "notebooks"}


def test_licence_and_extras():
    assert PYPROJECT["project"]["license"] == {"text": "MIT"}
    assert (REPO / "LICENSE").read_text(encoding="utf-8").startswith("MIT License")
    deps = " ".join(PYPROJECT["project"]["dependencies"])
    for jupyter in ("jupyter", "papermill", "nbconvert", "ipykernel"):
        assert jupyter not in deps  # the library and the commands run without Jupyter
    assert {"jupyterlab", "papermill", "nbconvert", "ipykernel"} <= {
        d.split(">")[0].split("=")[0] for d in PYPROJECT["project"]["optional-dependencies"]["study"]}


def test_python_m_hsmap():
    r = subprocess.run([sys.executable, "-m", "hsmap", "--version"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == f"hsmap {hsmap.__version__}"


def test_a_checkout_finds_its_own_folders(monkeypatch):
    monkeypatch.delenv("HSMAP_GENERATED", raising=False)
    assert paths.repository_root() == REPO
    assert paths.notebooks_dir() == REPO / "notebooks"
    assert paths.generated_dir() == REPO / "data" / "generated"
    assert paths.reports_dir() == REPO / "reports"


def test_an_installed_hsmap_uses_the_package_data_and_the_user_cache(tmp_path, monkeypatch):
    monkeypatch.setattr(paths, "repository_root", lambda: None)  # as from a wheel: no checkout around
    monkeypatch.delenv("HSMAP_GENERATED", raising=False)
    monkeypatch.setenv("HSMAP_CACHE", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    assert paths.generated_dir() == tmp_path / "cache" / "generated"
    assert paths.reports_dir() == tmp_path / "reports"
    assert paths.notebooks_dir() == Path(hsmap.__file__).parent / "study" / "notebooks"


@pytest.mark.slow
def test_the_wheel_holds_the_package_data(tmp_path):
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-build-isolation", "--no-deps", "-q",
                        "-w", str(tmp_path), str(REPO)], capture_output=True, text=True, timeout=600,
                       cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    (wheel,) = tmp_path.glob("hsmap-*.whl")
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
        meta = email.message_from_bytes(z.read(next(n for n in names if n.endswith(".dist-info/METADATA"))))
    notebooks = sorted(p.name for p in (REPO / "notebooks").iterdir() if p.suffix == ".ipynb" or p.name == "README.md")
    assert {f"hsmap/study/notebooks/{n}" for n in notebooks} <= names
    assert {"hsmap/__main__.py", "hsmap/sim/scenarios/two-rooms.yaml", "hsmap/sim/scenarios/slam-office.yaml",
            "hsmap/study/published.yaml", "hsmap/study/public_data.yaml", "hsmap/study/balm.sha256"} <= names
    assert not [n for n in names if n.startswith(("tests/", "notebooks/", "data/"))]
    requires = meta.get_all("Requires-Dist")
    jupyter = [d for d in requires if d.split(";")[0].strip().split(">")[0] in ("jupyterlab", "papermill",
                                                                                  "nbconvert", "ipykernel")]
    assert len(jupyter) == 4 and all('extra == "study"' in d for d in jupyter), jupyter
    assert "study" in meta.get_all("Provides-Extra")


def test_every_module_the_architecture_names_exists():
    """docs/ARCHITECTURE.md names modules (``slam/``, ``keyframes.py``, ``study/batch.py``): each is a file or
    folder of the package (or of the repository: ``benchmarks/...``), not of an installed copy in ``.venv/``;
    ``hsmap/study/notebooks/`` is ``notebooks/`` installed (pyproject's package-dir)."""
    import re

    text = (REPO / "docs" / "ARCHITECTURE.md").read_text(encoding="utf-8")
    names = set(re.findall(r"`([A-Za-z_][\w/]*(?:\.py|/))`", text))
    assert len(names) > 40
    files = {p.relative_to(REPO).as_posix() for p in REPO.rglob("*.py") if "build" not in p.parts}
    folders = {p.relative_to(REPO).as_posix() + "/" for p in REPO.rglob("*") if p.is_dir()}
    generated = ("data/", "reports/")  # made by the runs, not in a checkout
    installed = {k.replace(".", "/") + "/" for k in PYPROJECT["tool"]["setuptools"]["package-dir"]}
    missing = [n for n in sorted(names) if not n.startswith(generated) and n not in installed
               and not any(f == n or f.endswith("/" + n) for f in files | folders if not f.startswith(".venv/"))]
    assert missing == []
