"""A bad notebook parameter stops the notebook at its first cell after the parameters, named, however it is run:
``hsmap reproduce`` checks before any notebook starts (``test_study_batch.py``), and plain papermill
(``papermill NB OUT -p quick notabool``, as the README documents) injects its values after the parameters cell,
where every study notebook calls :func:`hsmap.study.parameters.check_declared`."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hsmap.errors import ConfigError
from hsmap.study.parameters import check_declared

NOTEBOOKS = sorted((Path(__file__).parents[1] / "notebooks").glob("*.ipynb"))


def _cells(path: Path) -> tuple[str, str]:
    """A notebook's parameters cell and the first cell after it."""
    cells = json.loads(path.read_text(encoding="utf-8"))["cells"]
    i = next(k for k, c in enumerate(cells) if "parameters" in (c.get("metadata", {}).get("tags") or []))
    return "".join(cells[i]["source"]), "".join(cells[i + 1]["source"])


def _shell():
    from IPython.core.interactiveshell import InteractiveShell

    InteractiveShell.clear_instance()
    return InteractiveShell.instance()


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_a_bad_papermill_value_stops_every_notebook_at_its_check(path):
    """Before: ``papermill 05-voronoi-steps.ipynb out.ipynb -p quick notabool`` ran with quick = 'notabool' (a
    true value: the quick run, silently)."""
    params, after = _cells(path)
    check = after[: after.index("check_declared(globals())")] + "check_declared(globals())\n"
    sh = _shell()
    try:
        assert sh.run_cell(params).success
        assert sh.run_cell('quick = "notabool"\n').success  # papermill's injected-parameters cell
        res = sh.run_cell(check, silent=True)
        assert isinstance(res.error_in_exec, ConfigError)
        assert str(res.error_in_exec).startswith("notebook parameter quick is declared bool (true or false) in the "
                                                 "parameters cell, got 'notabool'")
        assert sh.run_cell("quick = True\nseed = 3\n").success  # good values pass
        assert sh.run_cell(check, silent=True).success
    finally:
        sh.clear_instance()


def test_check_declared_takes_whole_numbers_for_floats_and_names_the_parameter():
    ns = {"__annotations__": {"rate": float, "n": int, "name": str, "flag": bool}, "rate": 2, "n": 3, "name": "a",
          "flag": False}
    check_declared(ns)
    with pytest.raises(ConfigError, match=r"^notebook parameter n is declared int \(a whole number\).*got 1\.5"):
        check_declared({**ns, "n": 1.5})
    with pytest.raises(ConfigError, match=r"^notebook parameter flag is declared bool"):
        check_declared({**ns, "flag": 1})
