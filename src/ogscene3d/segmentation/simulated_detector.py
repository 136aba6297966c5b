"""A simulated open-vocabulary detector (YOLO-World style) over ground truth, fused like the real path.

The synthetic scenes have no detector model, but their objects have class names. This module plays the
detector's part of the ``sam+detector`` front-end: per frame it "detects" the visible objects whose class
is in the vocabulary, with the errors a real open-vocabulary detector makes, prompts the (simulated) SAM
with the boxes, and fuses the result with the grid segments exactly as
:class:`~ogscene3d.segmentation.fusion.SamDetectorSegmenter` does (``paint_masks`` then
``fuse_segmentations``), so the fused segments carry class names (``Segmentation.names``).

Errors, in this order (rates per :class:`DetectorNoise`):

1. **missed objects**: every object is missed with ``miss_prob``; small ones (below ``small_area`` of
   the image) and ones cut by the image border additionally with ``miss_hard_prob``;
2. **wrong class**: with ``confuse_prob`` the detection takes a confusable class (chair -> sofa, table
   -> desk, ...; :data:`CONFUSABLE`, restricted to the vocabulary) or, without one, another vocabulary
   class; its score is lower (``U(0.25, 0.55)``);
3. **low score**: a correct detection's score is ``U(0.45, 0.95)``, or with ``low_score_prob``
   ``U(0.05, 0.35)``: those under ``score_thresh`` are dropped as the real detector's threshold does;
4. **duplicates**: with ``duplicate_prob`` a second box of a confusable class on the same object (the
   fusion then keeps the better-scored mask, as for a real "chair" + "sofa" pair);
5. **false positives**: on average ``false_positive_rate`` boxes per frame around a random patch with a
   random vocabulary class and a low score;
6. **box jitter**: box corners move by ``box_jitter`` of the box size (std); the box-prompted mask is
   the ground-truth object inside the box (SAM's answer to a box prompt) with its boundary displaced by a
   smooth random field of ``mask_boundary_px`` pixels, scored ``U(0.88, 0.99)`` (1 at level "none",
   which detects every vocabulary object exactly).

Then class-wise NMS (``nms_thresh``) as the ONNX detector runs it. Everything is seeded per frame.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from .base import Segmentation
from .detector_onnx import Detections
from .fusion import OpenSetResult, fuse_segmentations
from .masks import MaskRecord, nms, paint_masks

#: Changes when the simulation changes: synthetic scenes record it and are regenerated when it differs.
SIMULATED_DETECTOR_VERSION = 2

#: Classes an open-vocabulary detector plausibly mixes up (used only when they are in the vocabulary).
CONFUSABLE: dict[str, tuple[str, ...]] = {
    "chair": ("sofa", "stool", "bench"),
    "sofa": ("chair", "bed", "bench"),
    "table": ("desk", "cabinet", "nightstand"),
    "desk": ("table",),
    "cabinet": ("table", "bookshelf", "nightstand"),
    "bookshelf": ("cabinet", "shelf"),
    "lamp": ("vase", "plant", "clock"),
    "vase": ("lamp", "plant", "bottle"),
    "plant": ("vase", "lamp"),
    "monitor": ("picture", "tv", "window"),
    "picture": ("window", "monitor", "clock"),
    "window": ("picture", "door"),
    "clock": ("picture", "lamp"),
    "book": ("box",),
    "box": ("book", "trash can"),
    "trash can": ("vase", "box"),
    "rug": ("floor",),
    "door": ("window", "cabinet"),
}

#: Classes a furniture/object vocabulary leaves out: detectors are weak on "stuff", which SAM's grid covers.
STUFF_CLASSES = ("floor", "wall", "ceiling")


@dataclass(frozen=True)
class DetectorNoise:
    miss_prob: float = 0.0
    miss_hard_prob: float = 0.0
    small_area: float = 0.004  # fraction of the image
    confuse_prob: float = 0.0
    low_score_prob: float = 0.0
    duplicate_prob: float = 0.0
    false_positive_rate: float = 0.0
    box_jitter: float = 0.0  # std, fraction of the box's width / height
    mask_boundary_px: float = 0.0  # box-prompted masks' boundaries displaced by a smooth field (pixels)
    min_pixels: int = 16  # visible object pixels below which nothing is detected

    @property
    def clean(self) -> bool:
        """No error at all: every vocabulary object is detected exactly, its mask scored 1 (as the
        simulated SAM's level "none" gives the ground truth with score 1)."""
        return not any(
            (self.miss_prob, self.miss_hard_prob, self.confuse_prob, self.low_score_prob, self.duplicate_prob,
             self.false_positive_rate, self.box_jitter, self.mask_boundary_px)
        )  # fmt: skip


#: Named levels, as the simulated SAM's (``synthetic.noise`` picks both).
DETECTOR_NOISE_LEVELS: dict[str, DetectorNoise] = {
    "none": DetectorNoise(min_pixels=1),
    "low": DetectorNoise(
        miss_prob=0.05, miss_hard_prob=0.2, confuse_prob=0.05, low_score_prob=0.05, duplicate_prob=0.03,
        false_positive_rate=0.05, box_jitter=0.02, mask_boundary_px=0.5,
    ),
    "default": DetectorNoise(
        miss_prob=0.1, miss_hard_prob=0.35, confuse_prob=0.12, low_score_prob=0.1, duplicate_prob=0.08,
        false_positive_rate=0.15, box_jitter=0.04, mask_boundary_px=1.0,
    ),
    "high": DetectorNoise(
        miss_prob=0.25, miss_hard_prob=0.5, confuse_prob=0.25, low_score_prob=0.2, duplicate_prob=0.15,
        false_positive_rate=0.4, box_jitter=0.08, mask_boundary_px=2.0,
    ),
}  # fmt: skip


def _displace(mask: np.ndarray, amplitude: float, rng: np.random.Generator) -> np.ndarray:
    """``mask`` with its boundary moved by a smooth random displacement field (SAM's masks are not
    pixel-exact at object edges)."""
    h, w = mask.shape
    gh, gw = max(2, h // 8), max(2, w // 8)
    field = cv2.resize(rng.normal(0.0, amplitude, (gh, gw, 2)).astype(np.float32), (w, h),
                       interpolation=cv2.INTER_CUBIC)  # fmt: skip
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    moved = cv2.remap(mask.astype(np.uint8), gx + field[..., 0], gy + field[..., 1], cv2.INTER_NEAREST,
                      borderMode=cv2.BORDER_CONSTANT, borderValue=0)  # fmt: skip
    return moved.astype(bool)


@dataclass
class _Boxes:
    """The boxes a simulated detection found, before the threshold and NMS: each with its score, class name
    and owner (the instance whose pixels its box-prompted mask takes; -1: a false positive)."""

    boxes: list[list[float]] = field(default_factory=list)
    scores: list[float] = field(default_factory=list)
    names: list[str] = field(default_factory=list)
    owners: list[int] = field(default_factory=list)

    def add(self, box: list[float], score: float, name: str, owner: int) -> None:
        self.boxes.append(box)
        self.scores.append(score)
        self.names.append(name)
        self.owners.append(owner)


class SimulatedDetector:
    """Detections and box-prompted masks from a ground-truth instance map, with detector errors.

    ``instance_classes``: {instance id: class name} of the scene. ``vocabulary``: the class names the
    detector is prompted with (default: the scene's classes without floor / wall / ceiling). ``noise``:
    a level name of :data:`DETECTOR_NOISE_LEVELS` or a :class:`DetectorNoise`.
    """

    def __init__(
        self,
        instance_classes: Mapping[int, str],
        vocabulary: Sequence[str] | None = None,
        noise: str | DetectorNoise = "default",
        seed: int = 0,
        score_thresh: float = 0.25,
        nms_thresh: float = 0.5,
        tau_m: float = 0.7,
        min_area: int = 4,
    ) -> None:
        if isinstance(noise, str):
            if noise not in DETECTOR_NOISE_LEVELS:
                raise ValueError(
                    f"unknown detector noise level {noise!r}; expected one of {sorted(DETECTOR_NOISE_LEVELS)}"
                )
            noise = DETECTOR_NOISE_LEVELS[noise]
        self.noise = noise
        self.instance_classes = {int(k): str(v) for k, v in instance_classes.items()}
        if vocabulary is None:
            vocabulary = sorted({c for c in self.instance_classes.values() if c not in STUFF_CLASSES})
        self.vocabulary = [str(v) for v in vocabulary]
        if not self.vocabulary:
            raise ValueError("SimulatedDetector: the vocabulary is empty")
        self.seed = int(seed)
        self.score_thresh = float(score_thresh)
        self.nms_thresh = float(nms_thresh)
        if not 0.0 <= tau_m <= 1.0:
            raise ValueError(f"tau_m must lie in [0, 1], got {tau_m}")
        self.tau_m = float(tau_m)
        self.min_area = int(min_area)

    def _rng(self, frame_index: int) -> np.random.Generator:
        return np.random.default_rng(np.random.SeedSequence([self.seed, 0xDE7EC7, int(frame_index)]))

    def _confused(self, cls: str, rng: np.random.Generator) -> str:
        options = [c for c in CONFUSABLE.get(cls, ()) if c in self.vocabulary and c != cls]
        if not options:
            options = [c for c in self.vocabulary if c != cls]
        return str(options[int(rng.integers(len(options)))]) if options else cls

    def detect(self, gt_instances: np.ndarray, frame_index: int) -> tuple[Detections, list[MaskRecord]]:
        """The frame's detections (after threshold and class-wise NMS, best first) and, for each, the
        box-prompted mask SAM would return."""
        inst = np.asarray(gt_instances)
        if inst.ndim != 2:
            raise ValueError(f"gt_instances must be a 2D id map, got shape {inst.shape}")
        inst = inst.astype(np.int64)
        rng = self._rng(frame_index)  # every step below draws from it in turn: keep their order
        found = _Boxes()
        self._object_boxes(inst, rng, found)
        self._false_positives(inst.shape, rng, found)
        b, s, idx = self._kept_boxes(found, inst.shape, rng)
        records, kept = self._box_masks(inst, b, idx, found, rng)
        names = found.names
        dets = Detections(
            boxes=b[kept].astype(np.float32).reshape(-1, 4),
            scores=s[kept].astype(np.float32),
            labels=np.asarray([self.vocabulary.index(names[k]) for k in kept], dtype=np.int64),
            names=[names[k] for k in kept],
        )
        return dets, records

    def _object_boxes(self, inst: np.ndarray, rng: np.random.Generator, found: _Boxes) -> None:
        """Errors 1-4 on the boxes of the visible vocabulary objects: misses, wrong classes, low scores,
        duplicates."""
        H, W = inst.shape
        nz = self.noise
        area = np.bincount(inst.ravel(), minlength=1)
        for i in np.flatnonzero(area):
            cls = self.instance_classes.get(int(i))
            if i == 0 or cls is None or cls not in self.vocabulary or area[i] < max(1, nz.min_pixels):
                continue
            ys, xs = np.nonzero(inst == i)
            x0, y0, x1, y1 = xs.min(), ys.min(), xs.max() + 1, ys.max() + 1
            cut = x0 == 0 or y0 == 0 or x1 == W or y1 == H
            hard = area[i] < nz.small_area * H * W or cut
            if rng.uniform() < nz.miss_prob + (nz.miss_hard_prob if hard else 0.0):
                continue
            box = [float(x0), float(y0), float(x1), float(y1)]
            if rng.uniform() < nz.confuse_prob:
                name, score = self._confused(cls, rng), float(rng.uniform(0.25, 0.55))
            elif rng.uniform() < nz.low_score_prob:
                name, score = cls, float(rng.uniform(0.05, 0.35))
            else:
                name, score = cls, float(rng.uniform(0.45, 0.95))
            found.add(box, score, name, int(i))
            if rng.uniform() < nz.duplicate_prob:
                other = self._confused(cls, rng)
                if other != name:
                    found.add(list(box), float(rng.uniform(0.25, 0.9)) * score, other, int(i))

    def _false_positives(self, shape: tuple[int, int], rng: np.random.Generator, found: _Boxes) -> None:
        """Error 5: boxes around random patches, of a random vocabulary class and a low score."""
        H, W = shape
        for _ in range(int(rng.poisson(self.noise.false_positive_rate))):
            w, h = rng.uniform(0.05, 0.3) * W, rng.uniform(0.05, 0.3) * H
            x, y = rng.uniform(0, W - w), rng.uniform(0, H - h)
            name = self.vocabulary[int(rng.integers(len(self.vocabulary)))]
            found.add([x, y, x + w, y + h], float(rng.uniform(0.2, 0.45)), name, -1)

    def _kept_boxes(
        self, found: _Boxes, shape: tuple[int, int], rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Error 6's box jitter, then the score threshold and class-wise NMS. -> (boxes [M, 4], scores [M],
        the indices kept, best first)."""
        H, W = shape
        b = np.asarray(found.boxes, dtype=np.float64).reshape(-1, 4)
        if self.noise.box_jitter > 0 and len(b):
            size = np.repeat(b[:, 2:] - b[:, :2], 2, axis=0).reshape(-1, 4)
            b = b + rng.normal(0.0, self.noise.box_jitter, b.shape) * size
        b = np.clip(b, 0.0, [W, H, W, H])
        s = np.asarray(found.scores, dtype=np.float64)
        ok = (s >= self.score_thresh) & (b[:, 2] - b[:, 0] >= 1) & (b[:, 3] - b[:, 1] >= 1)
        idx = np.flatnonzero(ok)
        labels = np.asarray([self.vocabulary.index(found.names[k]) for k in idx], dtype=np.int64)
        idx = idx[nms(b[idx], s[idx], self.nms_thresh, classes=labels)] if len(idx) else idx
        return b, s, idx

    def _box_masks(
        self, inst: np.ndarray, b: np.ndarray, idx: np.ndarray, found: _Boxes, rng: np.random.Generator
    ) -> tuple[list[MaskRecord], np.ndarray]:
        """Error 6's masks: what SAM returns for each kept box (its object, or for a false positive the most
        prominent surface inside it), the boundary displaced. -> (records, the indices that got one)."""
        nz = self.noise
        records: list[MaskRecord] = []
        kept: list[int] = []
        for k in idx:
            rx0, ry0 = int(np.floor(b[k, 0])), int(np.floor(b[k, 1]))
            rx1, ry1 = int(np.ceil(b[k, 2])), int(np.ceil(b[k, 3]))
            window = inst[ry0:ry1, rx0:rx1]
            if found.owners[k] > 0:
                crop = window == found.owners[k]
            else:  # a false positive: SAM returns the most prominent surface inside the box
                ids, counts = np.unique(window[window > 0], return_counts=True)
                if ids.size == 0:
                    continue
                crop = window == ids[int(np.argmax(counts))]
            if nz.mask_boundary_px > 0:
                crop = _displace(crop, nz.mask_boundary_px, rng)
            kept.append(int(k))
            score = 1.0 if nz.clean else float(rng.uniform(0.88, 0.99))
            records.append(MaskRecord((rx0, ry0, rx1, ry1), crop, score, name=found.names[k]))
        return records, np.asarray(kept, dtype=np.int64)

    def segment(self, ms: Segmentation, gt_instances: np.ndarray, frame_index: int) -> OpenSetResult:
        """M_s (the grid segments given), M_d (box-prompted masks), M_f (fused, with class names)."""
        shape = np.shape(gt_instances)
        if np.shape(ms.ids) != shape:
            raise ValueError(f"segments {np.shape(ms.ids)} and gt_instances {shape} differ in shape")
        dets, records = self.detect(gt_instances, frame_index)
        md = paint_masks(records, shape, self.min_area)
        return OpenSetResult(ms, md, fuse_segmentations(ms, md, self.tau_m, self.min_area), dets)

    def __call__(self, ms: Segmentation, gt_instances: np.ndarray, frame_index: int) -> Segmentation:
        """M_f: the grid segments fused with the detector's named segments."""
        return self.segment(ms, gt_instances, frame_index).mf
