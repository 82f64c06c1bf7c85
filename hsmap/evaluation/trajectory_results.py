"""The choices and results of the trajectory metrics of :mod:`hsmap.evaluation.trajectory`: the alignment, the pose
relation and the delta unit (evo's names), the statistics of a set of errors, and the per-pose and per-relation
results."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from ..errors import EmptyInputError, InputError

#: Largest stamp difference (s) for two stamps to count as the same (TUM files keep 1 ns).
DEFAULT_MAX_DT = 1e-3

DOF_NAMES = {3: ("x", "y", "yaw"), 6: ("x", "y", "z", "roll", "pitch", "yaw")}
_ANGULAR = {"yaw", "roll", "pitch"}


class Alignment(enum.Enum):
    """How the estimate is aligned onto the reference before ATE."""

    NONE = "none"  #: no alignment
    ORIGIN = "origin"  #: the estimate's first pose moved onto the reference's first pose
    SE2 = "se2"  #: Umeyama on x, y: rotation about z and a planar translation
    SE3 = "se3"  #: Umeyama on x, y, z: rotation and translation
    SIM3 = "sim3"  #: Umeyama with scale


class PoseRelation(enum.Enum):
    """Which part of the error transform is measured (evo's names)."""

    TRANSLATION = "translation_part"  #: |t(E)| in metres
    ROTATION_ANGLE = "rotation_angle_deg"  #: |angle(E)| in degrees


class DeltaUnit(enum.Enum):
    """Unit of the RPE pair spacing ``delta``."""

    FRAMES = "frames"
    METERS = "meters"


@dataclass(frozen=True)
class Statistics:
    """Summary of an error vector (evo's statistics; ``std`` is the population standard deviation)."""

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    sse: float
    n: int

    @classmethod
    def of(cls, errors: NDArray[np.float64]) -> Statistics:
        e = np.asarray(errors, dtype=float)
        if e.size == 0:
            raise EmptyInputError("no errors to summarise (no associated poses or pairs)")
        return cls(
            rmse=float(np.sqrt(np.mean(e**2))),
            mean=float(np.mean(e)),
            median=float(np.median(e)),
            std=float(np.std(e)),
            min=float(np.min(e)),
            max=float(np.max(e)),
            sse=float(np.sum(e**2)),
            n=int(e.size),
        )

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in ("rmse", "mean", "median", "std", "min", "max", "sse", "n")}


@dataclass
class ErrorResult:
    """An ATE or RPE result: one error per pose (ATE) or pair (RPE), and their statistics.

    Attributes
    ----------
    name : str
        E.g. ``"ATE translation_part (se3)"``.
    unit : str
        ``"m"`` or ``"deg"``.
    errors : ndarray of shape (K,)
    stamps : ndarray of shape (K,)
        Stamp of each error (the pose's, or the first pose of each pair).
    statistics : Statistics
    alignment : ndarray of shape (4, 4)
        The transform applied to the estimate (identity for RPE and ``Alignment.NONE``); ``scale`` for Sim(3).
    """

    name: str
    unit: str
    errors: NDArray[np.float64]
    stamps: NDArray[np.float64]
    statistics: Statistics
    alignment: NDArray[np.float64] = field(default_factory=lambda: np.eye(4))
    scale: float = 1.0

    def as_dict(self) -> dict:
        return {"name": self.name, "unit": self.unit, **self.statistics.as_dict()}


@dataclass
class PoseErrors:
    """Per-DOF errors of an estimate against ground truth, both relative to their first poses.

    Attributes
    ----------
    names : tuple of str
        ``("x", "y", "yaw")`` or ``("x", "y", "z", "roll", "pitch", "yaw")``.
    stamps : ndarray of shape (N,)
    errors : ndarray of shape (N, dof)
        Estimate minus reference per DOF (metres, radians; angles wrapped).
    max_abs : ndarray of shape (dof,)
        Maximum absolute error per DOF over the route.
    final : ndarray of shape (dof,)
        Absolute error per DOF at the last pose.
    final_translation : float
        Distance (m) between the final positions.
    final_rotation : float
        Angle (rad) of the rotation between the final orientations.
    """

    names: tuple[str, ...]
    stamps: NDArray[np.float64]
    errors: NDArray[np.float64]
    max_abs: NDArray[np.float64]
    final: NDArray[np.float64]
    final_translation: float
    final_rotation: float

    def _per_dof(self, values: NDArray[np.float64]) -> dict:
        return {
            (f"{n}_deg" if n in _ANGULAR else f"{n}_m"): float(np.degrees(v) if n in _ANGULAR else v)
            for n, v in zip(self.names, values, strict=True)
        }

    def as_dict(self) -> dict:
        return {
            "max_abs_error": self._per_dof(self.max_abs),
            "final_error": {
                **self._per_dof(self.final),
                "translation_m": self.final_translation,
                "rotation_deg": float(np.degrees(self.final_rotation)),
            },
            "n_poses": int(len(self.stamps)),
        }


@dataclass
class RelationsResult:
    """The Freiburg relations metric.

    Attributes
    ----------
    translation : ndarray of shape (K,)
        Translational error |t(E)| of each scored relation (m).
    rotation : ndarray of shape (K,)
        Rotational error |angle(E)| of each scored relation (rad).
    used : ndarray of shape (N,) of bool
        Which of the N input relations were scored.
    n_interpolated : int
        Relation end points that fell between trajectory stamps and were interpolated.
    estimated, reference : ndarray of shape (K, 3), optional
        The translation of each scored relation as the trajectory has it (P_i^-1 P_j) and as the relation states
        it (in the frame of pose i): what :meth:`distance_scale` compares.
    """

    translation: NDArray[np.float64]
    rotation: NDArray[np.float64]
    used: NDArray[np.bool_]
    n_interpolated: int
    estimated: NDArray[np.float64] | None = None
    reference: NDArray[np.float64] | None = None

    def distance_scale(self, min_distance: float = 0.2, mask: NDArray[np.bool_] | None = None) -> float:
        """How much longer the trajectory makes the relations' distances: the least-squares factor k that
        minimises sum |t_est . u - k d|^2 over the scored relations of length d >= ``min_distance`` (u the
        relation's direction; ``mask`` over the scored relations selects some). 1.0: no scale error; 1.01: the
        trajectory's distances are 1 % too long, which over a kilometre is 10 m of drift that no rotation
        explains (a range sensor and an odometry that disagree on scale). Give it the short relations (a few
        seconds apart): on a long relation a drifted trajectory's translation says nothing about scale. NaN
        when no relation qualifies."""
        if self.estimated is None or self.reference is None:
            raise InputError("this RelationsResult holds no relative translations (made by relations_error)")
        est, ref = self.estimated, self.reference
        if mask is not None:
            est, ref = est[mask], ref[mask]
        d = np.linalg.norm(ref, axis=1)
        keep = d >= min_distance
        if not keep.any():
            return float("nan")
        u = ref[keep] / d[keep, None]
        along = np.einsum("ij,ij->i", est[keep], u)
        return float(along @ d[keep] / (d[keep] @ d[keep]))

    @staticmethod
    def _mean_std(e: NDArray[np.float64]) -> dict:
        return {
            "mean": float(np.mean(e)),
            "std": float(np.std(e, ddof=1)) if e.size > 1 else 0.0,
            "median": float(np.median(e)),
            "max": float(np.max(e)),
        }

    def as_dict(self) -> dict:
        rot_deg = np.degrees(self.rotation)
        return {
            "translation_m": self._mean_std(self.translation),
            "rotation_deg": self._mean_std(rot_deg),
            "translation_squared_m2": self._mean_std(self.translation**2),
            "rotation_squared_deg2": self._mean_std(rot_deg**2),
            "n_relations": int(self.used.sum()),
            "n_skipped": int((~self.used).sum()),
            "n_interpolated_stamps": int(self.n_interpolated),
        }
