"""Room-segmentation precision and recall as in the benchmark of Bormann et al. (ICRA 2016).

Definitions (the IPA evaluation's, as ``datasets/ipa_room_segmentation/README.md`` give them):

* ground-truth rooms are the 8-connected regions of ground-truth pixels ``> 250`` (the ground truth is the
  map with room borders drawn across the doorways); only regions of more than ``min_area`` (100) pixels
  count, the rest (doorway lines, fragments) is no room;
* segments are the sets of pixels sharing one positive label of the segmentation (0 = no room); segments
  of ``min_area`` pixels or fewer are ignored;
* the precision of a segment is its largest overlap with one room over the segment's area;
* the recall of a room is its largest overlap with one segment over the room's area;
* each is reported as the plain mean over segments (precision) or rooms (recall), the "per-room mean"
  the benchmark's tables use, and area-weighted: the sum of the largest overlaps over the total area.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage as ndi

from ..errors import EmptyInputError, ShapeError

__all__ = ["SegmentationScores", "segmentation_scores", "ground_truth_rooms"]

_EIGHT = np.ones((3, 3), dtype=bool)


@dataclass
class SegmentationScores:
    """Precision and recall of a room segmentation against a ground truth.

    Attributes
    ----------
    precision, recall : float
        Per-room means: mean over segments of the segment precision, mean over rooms of the room recall.
    precision_area, recall_area : float
        Area-weighted: sum of the largest overlaps over the total segment (room) area.
    n_rooms, n_segments : int
        Ground-truth rooms and segments that count (more than ``min_area`` pixels).
    room_recall : list of float
        Recall of each counted room, in ground-truth label order.
    segment_precision : dict of int to float
        Precision of each counted segment, keyed by its label.
    """

    precision: float
    recall: float
    precision_area: float
    recall_area: float
    n_rooms: int
    n_segments: int
    room_recall: list[float] = field(default_factory=list)
    segment_precision: dict[int, float] = field(default_factory=dict)

    def as_dict(self, details: bool = False) -> dict:
        """Plain dict for JSON; ``details`` adds the per-room and per-segment values."""
        d = asdict(self)
        if not details:
            d.pop("room_recall")
            d.pop("segment_precision")
        else:
            d["segment_precision"] = {str(k): v for k, v in self.segment_precision.items()}
        return d


def ground_truth_rooms(gt: ArrayLike, min_area: int = 100, free_above: int = 250) -> NDArray[np.int32]:
    """Label image of the ground-truth rooms.

    Parameters
    ----------
    gt : ndarray of shape (H, W)
        Ground-truth gray image (8-bit), rooms are closed regions of pixels ``> free_above``.
    min_area : int
        Regions of ``min_area`` pixels or fewer are dropped.
    free_above : int
        Pixels strictly above this value are room pixels.

    Returns
    -------
    ndarray of shape (H, W), int32
        0 where there is no room, 1..R for the rooms (8-connected regions), in scan order.
    """
    gt = np.asarray(gt)
    if gt.ndim != 2:
        raise ShapeError(f"ground truth must be a 2D gray image (H, W), got shape {gt.shape}")
    lab, n = ndi.label(gt > free_above, structure=_EIGHT)
    if n == 0:
        return lab.astype(np.int32)
    sizes = np.bincount(lab.ravel(), minlength=n + 1)
    keep = sizes > min_area
    keep[0] = False
    remap = np.zeros(n + 1, dtype=np.int32)
    remap[keep] = np.arange(1, int(keep.sum()) + 1, dtype=np.int32)
    return remap[lab]


def _kept_labels(gt: NDArray, min_area: int) -> NDArray[np.int64]:
    """A label image's rooms of more than ``min_area`` pixels, numbered 1..R in label order (0 = no room)."""
    rooms = np.asarray(gt).astype(np.int64)
    ids, inv = np.unique(rooms.ravel(), return_inverse=True)
    sizes = np.bincount(inv)
    keep = (ids > 0) & (sizes > min_area)
    remap = np.zeros(len(ids), dtype=np.int64)
    remap[keep] = np.arange(1, int(keep.sum()) + 1)
    return remap[inv].reshape(gt.shape)


def segmentation_scores(
    labels: ArrayLike, gt: ArrayLike, *, min_area: int = 100, free_above: int = 250, gt_is_labels: bool = False
) -> SegmentationScores:
    """Score a room segmentation against a ground truth (Bormann et al. 2016).

    Parameters
    ----------
    labels : ndarray of shape (H, W), integer
        Room labels of the segmentation, 0 = no room; each positive value is one segment.
    gt : ndarray of shape (H, W)
        Ground-truth gray image (rooms are 8-connected regions of pixels ``> free_above``), or, with
        ``gt_is_labels=True``, an integer room label image (0 = no room).
    min_area : int
        Segments and rooms of ``min_area`` pixels or fewer are ignored (IPA uses 100).
    free_above : int
        Gray threshold of room pixels in ``gt``.
    gt_is_labels : bool
        ``gt`` is already a label image.

    Returns
    -------
    SegmentationScores
        With no counted segment, precision and recall are 0.

    Raises
    ------
    ShapeError
        The images differ in shape or are not 2D.
    EmptyInputError
        The ground truth has no room larger than ``min_area``.
    """
    seg = np.asarray(labels)
    gt = np.asarray(gt)
    if seg.ndim != 2:
        raise ShapeError(f"segmentation labels must be a 2D image (H, W), got shape {seg.shape}")
    if seg.shape != gt.shape:
        raise ShapeError(f"segmentation {seg.shape} and ground truth {gt.shape} differ in size")
    if not np.issubdtype(seg.dtype, np.integer):
        raise ShapeError(f"segmentation labels must be integers, got dtype {seg.dtype}")
    rooms = (_kept_labels(gt, min_area) if gt_is_labels
             else ground_truth_rooms(gt, min_area, free_above).astype(np.int64))
    n_rooms = int(rooms.max(initial=0))
    if n_rooms == 0:
        raise EmptyInputError(f"the ground truth has no room of more than {min_area} px (pixels > {free_above})")

    seg_ids, seg_inv = np.unique(seg.ravel(), return_inverse=True)
    seg_sizes = np.bincount(seg_inv)
    seg_keep = (seg_ids > 0) & (seg_sizes > min_area)
    seg_index = np.full(len(seg_ids), -1, dtype=np.int64)
    seg_index[seg_keep] = np.arange(int(seg_keep.sum()))
    n_seg = int(seg_keep.sum())
    room_sizes = np.bincount(rooms.ravel(), minlength=n_rooms + 1)[1:]
    if n_seg == 0:
        return SegmentationScores(0.0, 0.0, 0.0, 0.0, n_rooms, 0, [0.0] * n_rooms, {})

    s = seg_index[seg_inv]
    r = rooms.ravel() - 1
    both = (s >= 0) & (r >= 0)
    overlap = np.bincount(s[both] * n_rooms + r[both], minlength=n_seg * n_rooms).reshape(n_seg, n_rooms)
    seg_area = seg_sizes[seg_keep].astype(float)
    best_for_seg = overlap.max(axis=1)
    best_for_room = overlap.max(axis=0)
    precision = best_for_seg / seg_area
    recall = best_for_room / room_sizes
    return SegmentationScores(
        precision=float(precision.mean()),
        recall=float(recall.mean()),
        precision_area=float(best_for_seg.sum() / seg_area.sum()),
        recall_area=float(best_for_room.sum() / room_sizes.sum()),
        n_rooms=n_rooms,
        n_segments=n_seg,
        room_recall=[float(v) for v in recall],
        segment_precision={int(k): float(v) for k, v in zip(seg_ids[seg_keep], precision, strict=True)},
    )
