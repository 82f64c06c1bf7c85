"""The smoothing's inputs (:class:`FrameMotions`): each frame's motion from the previous frame as the wheel
odometry has it and as its scan matched against the previous frame's scan has it."""

from __future__ import annotations

import time

import numpy as np
from numpy.typing import NDArray

from ..datasets.frames import Frame
from ..geometry import relative
from ..registration import RegistrationTarget
from .config import SlamConfig
from .costs import Costs
from .keyframes import pair_match
from .odometry import OdometryModel, constrains_xy

__all__ = ["FrameMotions"]

_NONE = np.full(3, np.nan)


def _scan_motion(scan: NDArray[np.float64], previous: RegistrationTarget, guess: NDArray[np.float64],
                 config: SlamConfig) -> NDArray[np.float64]:
    """``scan`` matched against the previous frame's scan from ``guess``: the motion (3,), NaN where the two
    overlap too little or the scene does not constrain x and y."""
    gc, lc = config.graph, config.loop_closure
    match = pair_match(scan, previous, guess, config.registration, gc.pair_iterations, lc.min_inlier_ratio)
    ok = match is not None and constrains_xy(match[1], config.degenerate_ratio)
    return match[0] if ok else _NONE


class FrameMotions:
    """Per frame, the motion from the previous frame: the odometry's (bias out) with its sigmas (x, y, yaw), and the
    scan-to-scan match's (NaN where there is none).

    Parameters
    ----------
    config : SlamConfig
    odometry : OdometryModel
        Gives the odometry's steps, their sigmas and the learned bias.
    costs : Costs
        Counts one refinement per scan match.
    """

    def __init__(self, config: SlamConfig, odometry: OdometryModel, costs: Costs) -> None:
        self.config = config
        self.odometry = odometry
        self.costs = costs
        self._odometry: list[NDArray[np.float64]] = []
        self._sigma: list[NDArray[np.float64]] = []
        self._scan: list[NDArray[np.float64]] = []
        self._previous: RegistrationTarget | None = None
        self.seconds = 0.0  # the time spent here

    def record(self, frame: Frame, scan: NDArray[np.float64], previous_pose: NDArray[np.float64],
               pose: NDArray[np.float64]) -> None:
        """Add ``frame`` (its points ``scan``, (N, 2)), tracked from ``previous_pose`` to ``pose``."""
        t0 = time.perf_counter()
        step = self.odometry.step(frame) if self._previous is not None else None
        if step is None:
            self._odometry.append(_NONE)
            self._sigma.append(_NONE)
            self._scan.append(_NONE)
        else:
            st, sr = self.odometry.model_sigmas(step, self.odometry.sigma())
            self._odometry.append(self.odometry.corrected(step))
            self._sigma.append(np.array([st, st, sr]))
            self._scan.append(_scan_motion(scan, self._previous, relative(previous_pose, pose), self.config))
            self.costs.add(refinements=1)
        # the next frame's reference (its normals are estimated when it is first matched)
        self._previous = RegistrationTarget(scan, self.config.registration) if frame.odometry is not None else None
        self.seconds += time.perf_counter() - t0

    def arrays(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """The odometry's motions, their sigmas and the scan matches' motions, each (frames, 3)."""
        return tuple(np.asarray(rows).reshape(-1, 3) for rows in (self._odometry, self._sigma, self._scan))
