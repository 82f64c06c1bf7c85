"""Harmony-ICP (:func:`harmony_icp`): a global Harmony Search over the pose (:mod:`~hsmap.registration.harmony`)
scored by a distance field (:mod:`~hsmap.registration.fitness`), then a local refinement on the correspondences
(:mod:`~hsmap.registration.neighbours`, :mod:`~hsmap.registration.normals`), and the information of the result
(:mod:`~hsmap.registration.information`); the call itself in :mod:`~hsmap.registration.icp`."""

from .icp import *  # noqa: F403  (the public registration API)
from .icp import __all__  # noqa: F401
