"""The door candidates of :func:`hsmap.rooms.segmentation.segment_rooms`: the free space filtered and cropped, its
skeleton and the candidate points on it (the paper's band or critical points), the lines across the narrowings
and the wall gaps, and those kept as door lines. Images are (row, col)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage as ndi

from ._kernels import (
    corner_wedges,
    edt,
    thin,
)
from ._steps import (
    EIGHT,
    basis_points_at,
    corner_points,
    critical_candidates,
    line_pixels_between,
    march,
    paper_candidates,
    runs_along_wall,
    skeleton_graph,
    wall_gap_lines,
)

if TYPE_CHECKING:  # annotations only: the settings live with segment_rooms
    from .segmentation import SegmentationConfig


_WEDGE_BINS = 32  # angular bins of the free wedges around obstacle pixels (corner detection)


@dataclass(frozen=True)
class _Crop:
    """Where the work image (the free space's bounding box, padded by ``pad`` on every side) sits in the map."""

    shape: tuple[int, int]
    r0: int
    r1: int
    c0: int
    c1: int
    pad: int = 3

    @classmethod
    def around(cls, free_full: NDArray[np.bool_], pad: int = 3) -> _Crop:
        rows = np.nonzero(free_full.any(1))[0]
        cols = np.nonzero(free_full.any(0))[0]
        return cls(free_full.shape, max(rows[0] - pad, 0), min(rows[-1] + pad + 1, free_full.shape[0]),
                   max(cols[0] - pad, 0), min(cols[-1] + pad + 1, free_full.shape[1]), pad)

    @property
    def offset(self) -> NDArray[np.int64]:
        """Map pixel of the work image's pixel (0, 0)."""
        return np.array([self.r0 - self.pad, self.c0 - self.pad])

    def work_image(self, free_full: NDArray[np.bool_]) -> NDArray[np.bool_]:
        pad = self.pad
        free = np.zeros((self.r1 - self.r0 + 2 * pad, self.c1 - self.c0 + 2 * pad), dtype=bool)
        free[pad:-pad, pad:-pad] = free_full[self.r0:self.r1, self.c0:self.c1]
        return free

    def full(self, img: NDArray, fill=0, dtype=None) -> NDArray:
        """A work image put back into an image of the map's size."""
        out = np.full(self.shape, fill, dtype=img.dtype if dtype is None else dtype)
        out[self.r0:self.r1, self.c0:self.c1] = img[self.pad:-self.pad, self.pad:-self.pad]
        return out


@dataclass
class _Skeleton:
    """Steps 2-3: the clearance, the skeleton, the door candidates and (for wall gaps) the free wedges."""

    dist_px: NDArray[np.float64]
    skel: NDArray[np.bool_]
    product: NDArray[np.float64]
    centres: list
    directions: list
    angles: NDArray[np.float64] | None = None
    starts: NDArray[np.int64] | None = None


@dataclass
class _Lines:
    """Step 4: the lines drawn, as a cut image and per line (centre, a, b, pixels, width)."""

    cut: NDArray[np.bool_]
    gap_cut: NDArray[np.bool_]
    door_px: list[tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], float]]
    soft: list[bool]
    n_critical: int


def _filtered_free(free: NDArray[np.bool_], res: float, cfg: SegmentationConfig) -> NDArray[np.bool_]:
    """Step 1: the free space median filtered, small obstacles (under ``min_obstacle_area``) cleared."""
    if cfg.median_size > 1:
        # the median of binary values is the majority
        k = cfg.median_size
        filtered = ndi.correlate(free.astype(np.uint8), np.ones((k, k), np.uint8), mode="reflect") > (k * k) // 2
        if cfg.median_keeps_walls:
            filtered &= free
    else:
        filtered = free.copy()
    if not filtered.any():
        filtered = free.copy()
    if cfg.min_obstacle_area > 0:
        occ, n_occ = ndi.label(~filtered, structure=EIGHT)
        boxes = ndi.find_objects(occ)
        small = np.bincount(occ.ravel(), minlength=n_occ + 1) * res * res < cfg.min_obstacle_area
        small[0] = False
        for k in np.nonzero(small)[0]:
            box = boxes[k - 1]
            if box is not None and max(box[0].stop - box[0].start, box[1].stop - box[1].start) * res >= \
                    cfg.min_obstacle_length:
                small[k] = False
        filtered |= small[occ]
    return filtered


def _skeleton_candidates(filtered: NDArray[np.bool_], res: float, cfg: SegmentationConfig) -> _Skeleton:
    """Steps 2-3: skeleton x distance transform, and the door candidates on the skeleton."""
    dist_px, feat_r, feat_c = edt(filtered)
    angles = starts = None
    if cfg.method == "critical" and cfg.wall_gaps:
        angles, starts = corner_wedges(filtered, dist_px, feat_r, feat_c, 0.15 / res, 0.5 / res, _WEDGE_BINS)
    skel = thin(filtered)
    product = np.where(skel, dist_px * res, 0.0)
    rr, cc, nbr = skeleton_graph(skel)
    dvals = dist_px[rr, cc] * res
    if cfg.method == "paper":
        centres, directions = paper_candidates(skel, product, rr, cc, nbr, dvals, cfg, res)
    else:
        centres, directions = critical_candidates(rr, cc, nbr, dvals, cfg, res)
    return _Skeleton(dist_px, skel, product, centres, directions, angles, starts)


def _candidate_lines(filtered: NDArray[np.bool_], sk: _Skeleton, res: float, cfg: SegmentationConfig) -> _Lines:
    """Step 4, the candidates: a line through each to the obstacles on both sides, kept where a wall runs on
    from one end at least (``critical`` with wall gaps) and not over 1.5 times the longest door."""
    cut = np.zeros_like(filtered)
    door_px: list[tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], float]] = []
    max_len = 2.0 * (cfg.max_door_half_width if cfg.method == "critical"
                     else cfg.door_half_width + cfg.door_half_width_tolerance)
    max_steps = min(int(np.ceil(1.5 * max_len / res)) + 2, sum(filtered.shape))  # a march never leaves the image
    wall_steps = max(2, int(round(cfg.wall_continuation / res)))
    for (r, c), u in zip(sk.centres, sk.directions, strict=True):
        p = np.array([r, c], dtype=float)
        if cfg.method == "paper":
            a = march(filtered, p, u, max_steps)
            b = march(filtered, p, -u, max_steps)
        else:
            a, b = basis_points_at(filtered, np.array([r, c]), max_steps, float(sk.dist_px[r, c]))
        if a is None or b is None:
            continue
        if cfg.method == "critical" and cfg.wall_gaps:
            # a door runs on from a wall at one end at least (a frame, a partition's end): a bulge of a wall or
            # a pillar narrowing a corridor does not
            d = (b - a) / max(float(np.hypot(*(b - a))), 1e-9)
            side = int(round(0.25 / res))
            ca = runs_along_wall(filtered, a.astype(float), -d, wall_steps, side)
            cb = runs_along_wall(filtered, b.astype(float), d, wall_steps, side)
            if not (ca or cb):
                continue
        # the free span: between the facing edges of the two end pixels
        width = max(float(np.hypot(*(a - b))) - 1.0, 0.0) * res
        if width > 1.5 * max_len:
            continue
        lr, lc = line_pixels_between(a, b)
        cut[lr, lc] = True
        door_px.append((np.array([r, c]), a, b, np.stack([lr, lc], 1), width))
    return _Lines(cut, np.zeros_like(filtered), door_px, [True] * len(door_px), len(door_px))


def _door_lines(filtered: NDArray[np.bool_], sk: _Skeleton, res: float, cfg: SegmentationConfig) -> _Lines:
    """Step 4: the candidates' lines, then (``critical`` with wall gaps) the wall-gap lines."""
    lines = _candidate_lines(filtered, sk, res, cfg)
    if cfg.method == "critical" and cfg.wall_gaps:
        corners = corner_points(sk.angles, cfg.corner_angle)
        for a, b, width, firm in wall_gap_lines(filtered, sk.dist_px, corners, sk.angles, sk.starts, _WEDGE_BINS,
                                                res, cfg):
            lr, lc = line_pixels_between(a, b)
            lines.cut[lr, lc] = True
            lines.gap_cut[lr, lc] |= firm
            lines.door_px.append((np.rint((a + b) / 2).astype(np.int64), a, b, np.stack([lr, lc], 1), width))
            lines.soft.append(not firm)
    return lines
