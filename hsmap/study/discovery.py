"""The study notebooks: ``notebooks/NN-name.ipynb`` found and selected, their ``parameters`` cell read, and
parameter files and command-line values parsed."""

from __future__ import annotations

import json
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..config import read_yaml
from ..errors import ConfigError, InputError
from ..limits import load_yaml
from .tooling import lighten_jupyter_imports, require_study_tooling

__all__ = ["NOTEBOOK_RE", "STANDARD_PARAMETERS", "PATH_PARAMETERS", "NotebookSpec", "discover", "select", "inspect_parameters", "parse_value", "load_parameters_file"]

NOTEBOOK_RE = re.compile(r"^(\d{2})-([a-z0-9][a-z0-9_-]*)\.ipynb$")
#: Parameters every notebook receives.
STANDARD_PARAMETERS = ("quick", "out_dir")
#: Parameters that name a file or folder: a relative one is taken from the caller's working directory (a notebook
#: runs in its own folder), e.g. ``hsmap reproduce -p dataset my-recording.bag``.
PATH_PARAMETERS = ("dataset", "datasets")
@dataclass(frozen=True)
class NotebookSpec:
    """A study notebook ``NN-name.ipynb``.

    Attributes
    ----------
    path : pathlib.Path
    name : str
        File stem, ``"NN-name"``: the report's name.
    number : int
    short : str
        ``"name"`` without the number.
    """

    path: Path
    name: str
    number: int
    short: str

    def matches(self, selector: str) -> bool:
        s = selector.strip()
        s = s[:-6] if s.endswith(".ipynb") else s
        return s in (self.name, self.short, f"{self.number:02d}", str(self.number))

    def title(self) -> str:
        """The first Markdown heading of the notebook (its name when it has none)."""
        try:
            nb = json.loads(self.path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return self.name
        for cell in nb.get("cells", []):
            if cell.get("cell_type") != "markdown":
                continue
            src = cell.get("source", "")
            src = "".join(src) if isinstance(src, list) else src
            for line in src.splitlines():
                if line.startswith("#"):
                    return line.lstrip("#").strip() or self.name
        return self.name


def discover(notebooks_dir: str | os.PathLike) -> list[NotebookSpec]:
    """The study notebooks ``NN-name.ipynb`` in ``notebooks_dir``, in number order.

    Files that do not follow the pattern (scratch notebooks, checkpoints) are not study notebooks.
    """
    d = Path(notebooks_dir)
    if not d.is_dir():
        raise InputError(f"notebooks folder {d} does not exist")
    specs = []
    for p in sorted(d.iterdir()):
        m = NOTEBOOK_RE.match(p.name)
        if m and p.is_file():
            specs.append(NotebookSpec(p.resolve(), p.stem, int(m.group(1)), m.group(2)))
    return sorted(specs, key=lambda s: (s.number, s.name))


def select(specs: Sequence[NotebookSpec], only: Sequence[str] | None) -> list[NotebookSpec]:
    """The notebooks named in ``only`` (full name, name without number, or number); all when empty."""
    if not only:
        return list(specs)
    chosen, unknown = [], []
    for sel in only:
        hits = [s for s in specs if s.matches(sel)]
        if not hits:
            unknown.append(sel)
        for h in hits:
            if h not in chosen:
                chosen.append(h)
    if unknown:
        have = ", ".join(s.name for s in specs) or "none"
        raise InputError(f"no notebook matches {', '.join(map(repr, unknown))}; the notebooks are: {have}")
    return sorted(chosen, key=lambda s: (s.number, s.name))


def inspect_parameters(spec: NotebookSpec | str | os.PathLike) -> dict[str, dict[str, Any]]:
    """The notebook's ``parameters`` cell as papermill reads it: name -> {inferred_type_name, default, help}."""
    require_study_tooling()
    lighten_jupyter_imports()
    import papermill

    path = spec.path if isinstance(spec, NotebookSpec) else Path(spec)
    return {k: dict(v) for k, v in papermill.inspect_notebook(str(path)).items()}


def parse_value(text: str) -> Any:
    """A ``-p KEY VALUE`` value read as YAML (``true``, ``3``, ``0.5``, ``[1, 2]``; otherwise the string)."""
    import yaml

    try:
        return load_yaml(text)
    except yaml.YAMLError:
        return text


def load_parameters_file(path: str | os.PathLike) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
    """Read a parameters YAML::

        parameters:            # every notebook
          seed: 1
        notebooks:             # one notebook (full name, short name or number)
          03-hs-slam-6dof: {every: 4}

    Returns (common parameters, per-notebook parameters keyed by selector).
    """

    path = Path(path)
    doc = read_yaml(path, "parameters file")
    if doc is None:
        return {}, {}
    if not isinstance(doc, dict):
        raise ConfigError(f"{path}: expected a mapping with 'parameters' and/or 'notebooks'")
    unknown = sorted(set(doc) - {"parameters", "notebooks"})
    if unknown:
        raise ConfigError(f"{path}: unknown key(s) {unknown}; expected 'parameters' and/or 'notebooks'")
    common = doc.get("parameters") or {}
    per = doc.get("notebooks") or {}
    if not isinstance(common, dict):
        raise ConfigError(f"{path}: 'parameters' must be a mapping of name to value")
    if not isinstance(per, dict) or not all(isinstance(v, dict) for v in per.values()):
        raise ConfigError(f"{path}: 'notebooks' must map a notebook name to a mapping of parameters")
    return dict(common), {str(k): dict(v) for k, v in per.items()}
