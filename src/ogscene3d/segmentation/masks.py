"""Binary-mask bookkeeping shared by the SAM, detector and fusion front-ends.

Masks are kept as bounding-box crops (``MaskRecord``) so that hundreds of grid masks of a large image
stay cheap; they are only expanded when painted into a per-frame id map.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from .base import Segmentation


@dataclass
class MaskRecord:
    """One binary mask: ``crop`` (bool [y1-y0, x1-x0]) placed at ``box`` = (x0, y0, x1, y1), ends exclusive.

    ``score`` is SAM's predicted IoU, ``stability`` SAM's stability score (1.0 when not computed),
    ``name`` the detector class for box-prompted masks (None for grid masks).
    """

    box: tuple[int, int, int, int]
    crop: np.ndarray
    score: float
    stability: float = 1.0
    name: str | None = None

    @property
    def area(self) -> int:
        return int(np.count_nonzero(self.crop))

    def full(self, shape: tuple[int, int]) -> np.ndarray:
        """The mask as a full bool [H, W] image."""
        out = np.zeros(shape, dtype=bool)
        x0, y0, x1, y1 = self.box
        out[y0:y1, x0:x1] = self.crop
        return out


def masks_to_records(
    masks: np.ndarray,
    scores: Sequence[float],
    stabilities: Sequence[float] | None = None,
    names: Sequence[str | None] | None = None,
) -> list[MaskRecord]:
    """Crop bool masks [K, H, W] to their bounding boxes; empty masks are dropped."""
    masks = np.asarray(masks, dtype=bool)
    if masks.ndim != 3:
        raise ValueError(f"masks must be [K, H, W], got shape {masks.shape}")
    k = masks.shape[0]
    if k == 0:
        return []
    rows = masks.any(axis=2)  # [K, H]
    cols = masks.any(axis=1)  # [K, W]
    nonempty = rows.any(axis=1)
    h, w = masks.shape[1:]
    y0 = rows.argmax(axis=1)
    y1 = h - rows[:, ::-1].argmax(axis=1)
    x0 = cols.argmax(axis=1)
    x1 = w - cols[:, ::-1].argmax(axis=1)
    out = []
    for i in np.flatnonzero(nonempty):
        box = (int(x0[i]), int(y0[i]), int(x1[i]), int(y1[i]))
        crop = masks[i, box[1] : box[3], box[0] : box[2]].copy()
        out.append(
            MaskRecord(
                box,
                crop,
                float(scores[i]),
                1.0 if stabilities is None else float(stabilities[i]),
                None if names is None else names[i],
            )
        )
    return out


def _shrink_to_content(rec: MaskRecord) -> MaskRecord | None:
    crop = rec.crop
    rows = np.flatnonzero(crop.any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(crop.any(axis=0))
    x0, y0, _, _ = rec.box
    box = (x0 + int(cols[0]), y0 + int(rows[0]), x0 + int(cols[-1]) + 1, y0 + int(rows[-1]) + 1)
    new_crop = crop[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1]
    return MaskRecord(box, np.ascontiguousarray(new_crop), rec.score, rec.stability, rec.name)


def remove_small_regions(rec: MaskRecord, min_area: int) -> tuple[MaskRecord | None, bool]:
    """segment-anything's post-processing: fill holes and drop islands smaller than ``min_area`` pixels.

    Returns (cleaned record, or None for an empty mask; whether the mask changed). 8-connectivity and,
    when every island is small, the largest one is kept, as in segment-anything. The crop is padded by
    one background pixel so that background touching the crop border counts as connected to the
    outside (it is, in the full image), never as a hole.
    """
    if min_area <= 0:
        return rec, False
    mask = np.pad(rec.crop, 1).astype(np.uint8)
    changed = False
    # holes: background components other than the outer one
    n, lab, stats, _ = cv2.connectedComponentsWithStats(1 - mask, connectivity=8)
    outer = lab[0, 0]
    small = np.flatnonzero(stats[:, cv2.CC_STAT_AREA] < min_area)
    small = small[(small != outer) & (small != 0)]  # label 0 of (1 - mask) is the mask itself
    if small.size:
        mask[np.isin(lab, small)] = 1
        changed = True
    # islands: foreground components that are too small; when all are, the largest stays (as in SAM)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    sizes = stats[1:, cv2.CC_STAT_AREA]
    small = np.flatnonzero(sizes < min_area) + 1
    if small.size == sizes.size and sizes.size:
        small = small[small != int(np.argmax(sizes)) + 1]
    if small.size:
        mask[np.isin(lab, small)] = 0
        changed = True
    if not changed:
        return rec, False
    crop = mask[1:-1, 1:-1].astype(bool)
    return _shrink_to_content(MaskRecord(rec.box, crop, rec.score, rec.stability, rec.name)), True


def box_iou_one_to_many(box: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """IoU of one box [4] against boxes [M, 4], all (x0, y0, x1, y1) with exclusive ends."""
    ix0 = np.maximum(box[0], boxes[:, 0])
    iy0 = np.maximum(box[1], boxes[:, 1])
    ix1 = np.minimum(box[2], boxes[:, 2])
    iy1 = np.minimum(box[3], boxes[:, 3])
    inter = np.clip(ix1 - ix0, 0, None) * np.clip(iy1 - iy0, 0, None)
    area = (box[2] - box[0]) * (box[3] - box[1])
    areas = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
    return inter / np.maximum(area + areas - inter, 1e-9)


def nms(
    boxes: np.ndarray, scores: np.ndarray, iou_thresh: float, classes: np.ndarray | None = None
) -> np.ndarray:
    """Greedy non-maximum suppression (OpenCV's ``cv2.dnn.NMSBoxes``); kept indices, best score first.

    A box is dropped when its IoU with a kept, better box exceeds ``iou_thresh``. ``classes``: when given,
    only boxes of the same class suppress each other (``cv2.dnn.NMSBoxesBatched``).
    """
    import cv2

    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    scores = np.asarray(scores, dtype=np.float64).reshape(-1)
    if boxes.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    xywh = np.concatenate([boxes[:, :2], boxes[:, 2:] - boxes[:, :2]], axis=1).tolist()
    # OpenCV sees each box's rank (1 = worst): positive as it requires, exact in its float32 scores, and
    # equal scores ordered by index; every box takes part (scores were thresholded before).
    order = np.argsort(-scores, kind="stable")
    rank = np.empty(len(scores), dtype=np.float64)
    rank[order] = np.arange(len(scores), 0, -1)
    if classes is None:
        keep = cv2.dnn.NMSBoxes(xywh, rank.tolist(), 0.0, float(iou_thresh))
    else:
        ids = np.asarray(classes, dtype=np.int64).reshape(-1).tolist()
        keep = cv2.dnn.NMSBoxesBatched(xywh, rank.tolist(), ids, 0.0, float(iou_thresh))
    keep = np.asarray(keep, dtype=np.int64).reshape(-1)
    return keep[np.argsort(-rank[keep])]  # best first, whatever order OpenCV returns them in


def mask_nms(records: Sequence[MaskRecord], iou_thresh: float) -> list[MaskRecord]:
    """segment-anything's mask NMS: greedy box-IoU suppression of the masks' bounding boxes by score."""
    if not records:
        return []
    boxes = np.array([r.box for r in records], dtype=np.float64)
    scores = np.array([r.score for r in records], dtype=np.float64)
    return [records[i] for i in nms(boxes, scores, iou_thresh)]


def paint_masks(records: Sequence[MaskRecord], shape: tuple[int, int], min_area: int = 1) -> Segmentation:
    """Paint masks into one id map, the higher score winning where masks overlap.

    Ties go to the mask listed first. Masks left with fewer than ``min_area`` visible pixels (covered by
    better masks) are dropped; surviving ids are 1..K in the order the masks were given.
    """
    h, w = shape
    ids = np.zeros((h, w), dtype=np.int32)
    if not records:
        return Segmentation(ids)
    scores = np.array([r.score for r in records], dtype=np.float64)
    # paint in ascending score so that better masks overwrite worse ones; lexsort keys: last is primary
    order = np.lexsort((-np.arange(len(records)), scores))
    for i in order:
        x0, y0, x1, y1 = records[i].box
        ids[y0:y1, x0:x1][records[i].crop] = i + 1
    visible = np.bincount(ids.ravel(), minlength=len(records) + 1)
    keep = np.flatnonzero(visible[1:] >= max(1, min_area)) + 1
    lut = np.zeros(len(records) + 1, dtype=np.int32)
    lut[keep] = np.arange(1, keep.size + 1, dtype=np.int32)
    out = lut[ids]
    seg_scores = {int(lut[k]): float(records[k - 1].score) for k in keep}
    names = {int(lut[k]): records[k - 1].name for k in keep if records[k - 1].name is not None}
    return Segmentation(out, seg_scores, names)
