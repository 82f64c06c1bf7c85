"""Visual output of the study: rerun recordings (:mod:`hsmap.viz.rerun`), matplotlib figures
(:mod:`hsmap.viz.figures`) and the notebook report helper :class:`~hsmap.viz.report.Study`.

The submodules import their heavy dependencies (rerun, matplotlib) themselves; importing this package is cheap.
"""

from __future__ import annotations

from .report import Study

__all__ = ["Study"]
