"""Keyframes and the voxel maps of their points: the submaps that loop closure matches against and the local
maps that tracking registers to, built from the keyframes' current pose estimates."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..geometry import pose_to_matrix, transform_points
from ..maps.mapping import VoxelMap

__all__ = ["Keyframe", "keyframe_voxel_map"]


@dataclass
class Keyframe:
    """A keyframe: its frame, and its points and normals in its own (robot base) frame."""

    frame: int
    stamp: float
    points: NDArray[np.float64]
    normals: NDArray[np.float64]


def keyframe_voxel_map(poses, keyframes: list[Keyframe], which, dim: int, voxel: float, *,
                       average: bool = False, within: tuple[ArrayLike, float] | None = None) -> VoxelMap:
    """A voxel map of the keyframes ``which``, each moved by its pose in ``poses`` (one per keyframe of ``which``,
    in that order), points and normals inserted at once (the first point, or the mean, per voxel).

    ``within`` = (centre, radius): only the points within ``radius`` metres of ``centre`` (horizontally in 3D).
    A voxel whose points are all kept is the same as in the whole map (the same points in the same order), so
    the map is the whole map's crop within ``radius`` less two voxel diagonals."""
    c = None if within is None else np.asarray(within[0], dtype=float)[:2]
    r2 = None if within is None else within[1] ** 2

    def moved():
        for k, pose in zip(which, poses, strict=True):
            T = pose_to_matrix(pose)
            p = transform_points(T, keyframes[k].points)
            n = keyframes[k].normals @ T[:dim, :dim].T
            if c is not None:
                keep = ((p[:, :2] - c) ** 2).sum(1) <= r2
                p, n = p[keep], n[keep]
            yield p, n

    return VoxelMap.from_parts(dim, voxel, moved(), average=average)
