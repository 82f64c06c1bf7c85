"""Rooms: Voronoi door detection and room segmentation (:mod:`~hsmap.rooms.segmentation`, its pixel-grid steps in
:mod:`~hsmap.rooms._steps` and compiled loops in :mod:`~hsmap.rooms._kernels`) and the room/door graph
(:mod:`~hsmap.rooms.topology`)."""
