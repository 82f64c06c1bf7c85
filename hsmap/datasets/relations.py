"""Ground-truth relations of the Freiburg SLAM benchmark (Kümmerle et al. 2009), ``.relations`` files.

Each non-comment line holds 8 numbers ``t_i t_j x y z roll pitch yaw``: the relative motion of the robot from
its pose at time ``t_i`` to its pose at ``t_j``, expressed in the frame of pose ``i`` (pose_i⁻¹ ⊕ pose_j).
Lines starting with ``#`` and blank lines are skipped.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..errors import DatasetError, ShapeError
from ..io import read_number_rows

__all__ = ["Relations", "read_relations"]


@dataclass
class Relations:
    """Relative-motion constraints between two stamped poses.

    Attributes
    ----------
    t_i, t_j : ndarray of shape (N,)
        Stamps (s) of the two poses of each relation.
    poses : ndarray of shape (N, 6)
        (x, y, z, roll, pitch, yaw) of pose_j in the frame of pose_i (metres, radians).
    """

    t_i: NDArray[np.float64]
    t_j: NDArray[np.float64]
    poses: NDArray[np.float64]

    def __post_init__(self) -> None:
        self.t_i = np.asarray(self.t_i, dtype=float).reshape(-1)
        self.t_j = np.asarray(self.t_j, dtype=float).reshape(-1)
        self.poses = np.asarray(self.poses, dtype=float)
        if self.poses.ndim != 2 or self.poses.shape[1] not in (3, 6):
            raise ShapeError(f"Relations.poses must have shape (N, 3) or (N, 6), got {self.poses.shape}")
        if self.poses.shape[1] == 3:
            p = np.zeros((len(self.poses), 6))
            p[:, :2], p[:, 5] = self.poses[:, :2], self.poses[:, 2]
            self.poses = p
        if not (len(self.t_i) == len(self.t_j) == len(self.poses)):
            raise ShapeError(
                f"Relations needs as many t_i ({len(self.t_i)}), t_j ({len(self.t_j)}) and poses ({len(self.poses)})"
            )

    def __len__(self) -> int:
        return len(self.t_i)


def read_relations(path: str | os.PathLike) -> Relations:
    """Read a ``.relations`` file (8 numbers per line: ``t_i t_j x y z roll pitch yaw``).

    Raises
    ------
    DatasetError
        The file does not exist.
    DataFormatError
        A line does not hold 8 finite numbers (the message gives the file and line), or there is no relation.
    """
    if not Path(path).is_file():
        raise DatasetError(f"{path}: no such relations file")
    a = read_number_rows(path, "t_i t_j x y z roll pitch yaw", "relations")
    return Relations(a[:, 0], a[:, 1], a[:, 2:])
