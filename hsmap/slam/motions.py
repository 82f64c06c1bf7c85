"""The smoothing's inputs (:class:`FrameMotions`): each frame's motion from the previous frame as the wheel
odometry has it and as its scan matched against the previous frame's scan has it; the smoothing run on them."""

from __future__ import annotations

import time

import numpy as np
from numpy.typing import NDArray

from .._blas import blas_limited
from .._helper_process import HelperProcessError, helper_process
from .._threads import current_threads
from ..datasets.frames import Frame
from ..geometry import relative
from ..registration.icp import RegistrationTarget
from .config import SlamConfig
from .costs import Costs
from .keyframes import pair_match
from .odometry import OdometryModel, constrains_xy
from .smoothing import SmoothingResult, smooth_with_odometry

__all__ = ["FrameMotions", "scan_motions"]

_NONE = np.full(3, np.nan)
#: Frames per batch of scan matches (one call of :func:`scan_motions`, inline or in the helper process).
BATCH_FRAMES = 128


def _scan_motion(scan: NDArray[np.float64], previous: RegistrationTarget, guess: NDArray[np.float64],
                 config: SlamConfig) -> NDArray[np.float64]:
    """``scan`` matched against the previous frame's scan from ``guess``: the motion (3,), NaN where the two
    overlap too little or the scene does not constrain x and y."""
    gc, lc = config.graph, config.loop_closure
    match = pair_match(scan, previous, guess, config.registration, gc.pair_iterations, lc.min_inlier_ratio)
    ok = match is not None and constrains_xy(match[1], config.degenerate_ratio)
    return match[0] if ok else _NONE


@blas_limited
def scan_motions(previous: NDArray[np.float64] | None,
                 frames: list[tuple[NDArray[np.float64], NDArray[np.float64] | None, bool]],
                 config: SlamConfig) -> NDArray[np.float64]:
    """The scan matches of consecutive frames, (len(frames), 3): each frame is ``(scan, guess, reference)``, its
    scan matched from ``guess`` against the last scan before it that is a ``reference`` (``previous`` for the
    first; NaN where ``guess`` is None)."""
    out = np.full((len(frames), 3), np.nan)
    target = None if previous is None else RegistrationTarget(previous, config.registration)
    for i, (scan, guess, reference) in enumerate(frames):
        if guess is not None and target is not None:
            out[i] = _scan_motion(scan, target, guess, config)
        # the next frame's reference (its normals are estimated when it is first matched)
        target = RegistrationTarget(scan, config.registration) if reference else None
    return out


class FrameMotions:
    """Per frame, the motion from the previous frame: the odometry's (bias out) with its sigmas (x, y, yaw), and the
    scan-to-scan match's (NaN where there is none).

    The scan matches are made in batches of :data:`BATCH_FRAMES` frames (:func:`scan_motions`), by the helper
    process (:func:`hsmap._helper_process.helper_process`) when the run has more than one compute thread, else
    inline: the answer is the same either way, and nothing else in the run waits for it.

    Parameters
    ----------
    config : SlamConfig
    odometry : OdometryModel
        Gives the odometry's steps, their sigmas and the learned bias.
    costs : Costs
        Counts one refinement per scan match.
    helper : bool, optional
        Use the helper process (default: when :func:`hsmap._threads.current_threads` is above one).
    """

    def __init__(self, config: SlamConfig, odometry: OdometryModel, costs: Costs, *, helper: bool | None = None
                 ) -> None:
        self.config = config
        self.odometry = odometry
        self.costs = costs
        self._odometry: list[NDArray[np.float64]] = []
        self._sigma: list[NDArray[np.float64]] = []
        self._helper = helper_process() if (current_threads() > 1 if helper is None else helper) else None
        self._frames: list[tuple] = []  # the batch being filled: (scan, guess or None, reference)
        self._first: NDArray[np.float64] | None = None  # the reference scan before the batch
        self._batches: list = []  # per batch, its answer, or (its arguments, the helper's Future) until it comes
        self._reference = False  # whether the previous frame's scan is a reference
        self.seconds = 0.0  # the time spent here, in this process
        self.result: SmoothingResult | None = None  # the smoothing's (:meth:`smooth`)

    def record(self, frame: Frame, scan: NDArray[np.float64], previous_pose: NDArray[np.float64],
               pose: NDArray[np.float64]) -> None:
        """Add ``frame`` (its points ``scan``, (N, 2)), tracked from ``previous_pose`` to ``pose``."""
        t0 = time.perf_counter()
        step = self.odometry.step(frame) if self._reference else None
        guess = None
        if step is None:
            self._odometry.append(_NONE)
            self._sigma.append(_NONE)
        else:
            st, sr = self.odometry.model_sigmas(step, self.odometry.sigma())
            self._odometry.append(self.odometry.corrected(step))
            self._sigma.append(np.array([st, st, sr]))
            guess = relative(previous_pose, pose)
            self.costs.add(refinements=1)
        self._reference = frame.odometry is not None
        self._frames.append((scan, guess, self._reference))
        if len(self._frames) == BATCH_FRAMES:
            self._flush()
        self.seconds += time.perf_counter() - t0

    def _flush(self) -> None:
        """Hand the batch over: to the helper process, or matched now; keep the answers that have come."""
        self._batches = [self._settled(b, wait=False) for b in self._batches]
        if not self._frames:
            return
        args = (self._first, self._frames, self.config)
        self._batches.append((args, self._helper.submit(scan_motions, *args)) if self._helper is not None
                             else scan_motions(*args))
        last = self._frames[-1]
        self._first = last[0] if last[2] else None
        self._frames = []

    @staticmethod
    def _settled(batch: NDArray[np.float64] | tuple, wait: bool) -> NDArray[np.float64] | tuple:
        """A batch's answer where it has come (or ``wait``), computed here where the helper process failed;
        else the batch as it is."""
        if not isinstance(batch, tuple):
            return batch
        args, future = batch
        if not (wait or future.done()):
            return batch
        try:
            return future.result()
        except HelperProcessError:
            return scan_motions(*args)  # the same answer, computed here

    def arrays(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """The odometry's motions, their sigmas and the scan matches' motions, each (frames, 3)."""
        t0 = time.perf_counter()
        self._flush()
        self._batches = [self._settled(b, wait=True) for b in self._batches]
        self.seconds += time.perf_counter() - t0
        scan = np.concatenate(self._batches) if self._batches else np.empty((0, 3))
        return (*(np.asarray(rows).reshape(-1, 3) for rows in (self._odometry, self._sigma)), scan)

    def smooth(self, poses: NDArray[np.float64]) -> SmoothingResult:
        """The trajectory ``poses`` (frames, 3) smoothed with the motions recorded
        (:func:`hsmap.slam.smoothing.smooth_with_odometry`), kept as :attr:`result`."""
        odometry, sigma, scan = self.arrays()
        t0 = time.perf_counter()
        self.result = smooth_with_odometry(poses, odometry, sigma, scan)
        self.seconds += time.perf_counter() - t0
        return self.result

    def summary(self) -> dict:
        """What the smoothing measured and did (JSON-ready), or that it did not run."""
        if self.result is None:
            return {"status": "not run (finish() was not called)"}
        return self.result.as_dict() | {"seconds": self.seconds}
