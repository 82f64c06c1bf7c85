"""Pictures: rerun recordings (:mod:`hsmap.viz.rerun`), matplotlib figures (:mod:`hsmap.viz.figures`,
:mod:`hsmap.viz.map_figures`), occupancy images (:mod:`hsmap.viz.occupancy`) and the colours they share
(:mod:`hsmap.viz.colors`).

The submodules import their heavy dependencies (rerun, matplotlib) themselves; importing this package is cheap.
"""
