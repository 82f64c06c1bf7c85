"""What every benchmark's JSON says about the machine it ran on, and how the JSON is written.

The machines are noisy (other runs, a day's speed), so each report keeps the load average at its start and at its
end beside the numbers; the JSON is written atomically (:func:`hsmap.io.write_json`), so an interrupted benchmark
never leaves a half-written report in ``reports/benchmarks/``.
"""

from __future__ import annotations

import os
import platform
from pathlib import Path

import numpy as np

from hsmap.io import write_json


def load_average() -> list[float]:
    """The 1, 5 and 15 minute load averages, rounded to 0.01."""
    return [round(x, 2) for x in os.getloadavg()]


def machine(**extra) -> dict:
    """The machine's description for a report (``extra`` adds fields), with the load average now."""
    return {"cpus": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version(),
            "numpy": np.__version__, "load_average_at_start": load_average(), **extra}


def finish(out: dict, path: str | Path) -> None:
    """Add the load average at the end to ``out["machine"]``, write ``out`` to ``path`` and say so."""
    out.setdefault("machine", {})["load_average_at_end"] = load_average()
    write_json(path, out)
    print(f"wrote {path}")
