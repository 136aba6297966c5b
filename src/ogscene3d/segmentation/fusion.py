"""Fusion of grid-prompted and detector-prompted SAM segments (paper Sec. III-B.1).

M_f keeps every segment of M_d (detector boxes as SAM prompts, precise, labelled) and adds each segment s
of M_s (SAM's automatic grid masks, complete coverage) whose pixel overlap ratio with its corresponding
M_d segment is below tau_m (0.7):

    ratio(s) = max_d |s ∩ d| / |s|,

the corresponding segment being the M_d segment that covers most of s. Where the kept M_s segments and
M_d overlap, M_d wins the pixel (it "maintains object-level precision"); a kept M_s segment therefore
only fills pixels that no detector segment claims. Per-pixel scores are the winning segment's SAM
predicted IoU (``Segmentation.score_map``).

The paper does not define the ratio's denominator; |s| (not IoU) makes a grid segment that lies inside
a detected object a duplicate of it however small it is. Ratios are taken on the painted id maps
(each pixel belongs to one segment of M_s and one of M_d: the higher predicted IoU wins where masks of
the same set overlap). Pixels covered by no kept segment have no segment (id 0).

Deviation from "M_f includes all segments from M_d" (``SamDetectorSegmenter``): detector-prompted masks
get the same clean-up as SAM's grid masks (holes and islands below ``min_region_area`` pixels), and a
detector mask left with fewer than ``min_region_area`` visible pixels, because it is that small or
because a better-scored detector mask covers it (two detections of one object, e.g. "chair" and
"sofa"), is dropped: its slivers would otherwise become segments that override M_s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import SegmentationConfig
from .base import Segmentation
from .detector_onnx import Detections, DetectorOnnx, require_detector
from .masks import paint_masks
from .sam_onnx import SamOnnx, check_rgb


def overlap_ratios(ms: Segmentation, md: Segmentation) -> dict[int, float]:
    """{M_s id: max_d |s ∩ d| / |s|} for every segment present in ``ms.ids``."""
    s_ids = np.asarray(ms.ids, dtype=np.int64)
    d_ids = np.asarray(md.ids, dtype=np.int64)
    if s_ids.shape != d_ids.shape:
        raise ValueError(f"M_s {s_ids.shape} and M_d {d_ids.shape} id maps differ in shape")
    if s_ids.min(initial=0) < 0 or d_ids.min(initial=0) < 0:
        raise ValueError("segment ids must be >= 0")
    # ids made compact first: a histogram over max id x max id would take gigabytes for sparse ids
    # (e.g. precomputed maps numbered up to 65535), one over the present ids stays small
    s_u, s_c = np.unique(s_ids.ravel(), return_inverse=True)
    d_u, d_c = np.unique(d_ids.ravel(), return_inverse=True)
    ns, nd = s_u.size, d_u.size
    # joint histogram of (s, d) pixel pairs: one bincount instead of a loop over segments
    joint = np.bincount(s_c.ravel() * nd + d_c.ravel(), minlength=ns * nd).reshape(ns, nd)
    area = joint.sum(axis=1)
    d_seg = d_u > 0
    best = joint[:, d_seg].max(axis=1) if d_seg.any() else np.zeros(ns, dtype=np.int64)
    return {int(s): float(best[i] / area[i]) for i, s in enumerate(s_u) if s > 0}


def fuse_segmentations(
    ms: Segmentation, md: Segmentation, tau_m: float = 0.7, min_area: int = 1
) -> Segmentation:
    """M_f from M_s and M_d (see the module docstring).

    Output ids: the M_d segments first (1..K_d, in their id order), then the kept M_s segments. M_s
    segments left with fewer than ``min_area`` visible pixels once M_d has taken its pixels are dropped.
    Scores missing from a Segmentation's ``scores`` default to 1.0 (as for precomputed segments).
    """
    if not 0.0 <= tau_m <= 1.0:
        raise ValueError(f"tau_m must lie in [0, 1], got {tau_m}")
    ratios = overlap_ratios(ms, md)
    keep_s = np.array(sorted(s for s, r in ratios.items() if r < tau_m), dtype=np.int64)
    d_ids = np.asarray(md.ids, dtype=np.int64)
    s_ids = np.asarray(ms.ids, dtype=np.int64)
    d_present = np.flatnonzero(np.bincount(d_ids.ravel())[1:]) + 1
    lut_d = np.zeros(int(d_ids.max(initial=0)) + 1, dtype=np.int64)
    lut_d[d_present] = np.arange(1, d_present.size + 1)
    out = lut_d[d_ids]
    lut_s = np.zeros(int(s_ids.max(initial=0)) + 1, dtype=np.int64)
    lut_s[keep_s] = np.arange(d_present.size + 1, d_present.size + 1 + keep_s.size)
    free = out == 0
    out[free] = lut_s[s_ids[free]]
    # drop M_s segments that M_d has (almost) swallowed, then make ids consecutive again
    visible = np.bincount(out.ravel(), minlength=d_present.size + keep_s.size + 1)
    alive = np.ones(visible.size, dtype=bool)
    alive[0] = False
    alive[d_present.size + 1 :] = visible[d_present.size + 1 :] >= max(1, min_area)
    alive[1 : d_present.size + 1] = True
    final = np.zeros(visible.size, dtype=np.int32)
    final[alive] = np.arange(1, int(alive.sum()) + 1, dtype=np.int32)
    ids = final[out]
    scores: dict[int, float] = {}
    names: dict[int, str] = {}
    for new, old in zip(final[1 : d_present.size + 1], d_present):
        scores[int(new)] = float(md.scores.get(int(old), 1.0))
        if int(old) in md.names:
            names[int(new)] = md.names[int(old)]
    for new, old in zip(final[d_present.size + 1 :], keep_s):
        if new > 0:
            scores[int(new)] = float(ms.scores.get(int(old), 1.0))
            if int(old) in ms.names:
                names[int(new)] = ms.names[int(old)]
    return Segmentation(ids, scores, names)


@dataclass
class OpenSetResult:
    """The three segmentations of one frame: grid M_s, detector M_d, fused M_f, plus the detections."""

    ms: Segmentation
    md: Segmentation
    mf: Segmentation
    detections: Detections


class SamDetectorSegmenter:
    """The paper's open-set front-end: SAM grid masks + detector-prompted SAM masks, fused (M_f).

    One SAM encoder pass per frame serves both the grid prompts and the detector's box prompts.
    """

    def __init__(self, sam: SamOnnx, detector: DetectorOnnx, tau_m: float = 0.7) -> None:
        if not 0.0 <= tau_m <= 1.0:
            raise ValueError(f"tau_m must lie in [0, 1], got {tau_m}")
        self.sam = sam
        self.detector = detector
        self.tau_m = float(tau_m)

    @classmethod
    def from_config(cls, config: SegmentationConfig) -> SamDetectorSegmenter:
        """The ``sam+detector`` front-end that a ``segmentation`` config section describes.

        Args:
            config: the section: the SAM settings (:meth:`SamOnnx.from_config`), the detector's
                (:meth:`DetectorOnnx.from_config`) and ``tau_m``.

        Returns:
            The front-end, every model file opened; a missing detector file is reported before SAM's
            files are opened.
        """
        require_detector(config)
        sam = SamOnnx.from_config(config)
        return cls(sam, DetectorOnnx.from_config(config), tau_m=config.tau_m)

    def segment(self, rgb: np.ndarray) -> OpenSetResult:
        """M_s, M_d and M_f of one uint8 RGB frame [H, W, 3]."""
        rgb = check_rgb(rgb)
        image = self.sam.embed(rgb)
        shape = image.orig_size
        area = self.sam.filters.min_region_area
        ms = paint_masks(self.sam.generate(image), shape, area)
        dets = self.detector(rgb)
        md = paint_masks(self.sam.segment_boxes(image, dets.boxes, list(dets.names)), shape, area)
        return OpenSetResult(ms, md, fuse_segmentations(ms, md, self.tau_m, area), dets)

    def __call__(self, rgb: np.ndarray, depth: np.ndarray | None = None) -> Segmentation:
        """M_f for one frame (depth is unused)."""
        return self.segment(rgb).mf
