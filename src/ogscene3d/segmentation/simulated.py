"""A simulated SAM: realistic open-set segments made from ground-truth instance maps.

Used for the synthetic scenes (where no SAM model is needed to test the mapper) and for noise
ablations. Starting from the per-pixel instance ids it applies, in this order:

1. **missed objects**: every instance is dropped with ``drop_prob``; small ones (area below
   ``small_area`` of the image) and far ones (mean valid depth beyond ``far_depth`` m) additionally
   with ``miss_small_prob``;
2. **merging**: a pair of touching small instances (both below ``merge_area``) becomes one segment
   with ``merge_prob`` (SAM often returns "the books", not each book);
3. **over-segmentation**: a large region (above ``large_area``: walls, floor) is cut into 2 to
   ``max_pieces`` pieces with ``split_prob`` (nearest-seed cells in the image plane);
4. **boundary noise**: boundaries are displaced by a smooth random field of ``boundary_px`` pixels
   amplitude, and boundary pixels are left unsegmented with ``unlabeled_boundary``;
5. **spurious segments**: on average ``spurious_rate`` random elliptic segments (shadows, texture);
6. segments smaller than ``min_area`` pixels are removed.

Ids are a fresh random permutation every frame (as SAM's, never consistent across frames). Scores
imitate SAM's predicted IoU after its 0.88 threshold: U(0.95, 1) for clean segments and
U(0.88, 0.95) for corrupted ones (split, merged, spurious, or with > 10 % of their pixels changed).
Level "none" returns the ground truth, permuted, with score 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .base import Segmentation


@dataclass(frozen=True)
class NoiseLevel:
    drop_prob: float = 0.0
    miss_small_prob: float = 0.0
    small_area: float = 0.002  # fraction of the image
    far_depth: float = 4.0  # metres
    merge_prob: float = 0.0
    merge_area: float = 0.01
    split_prob: float = 0.0
    large_area: float = 0.08
    max_pieces: int = 3
    boundary_px: float = 0.0
    unlabeled_boundary: float = 0.0
    spurious_rate: float = 0.0
    min_area: int = 4  # pixels

    @property
    def clean(self) -> bool:
        """No corruption at all: the segments are the ground truth (renumbered), with score 1."""
        return not any(
            (self.drop_prob, self.miss_small_prob, self.merge_prob, self.split_prob, self.boundary_px,
             self.unlabeled_boundary, self.spurious_rate, self.min_area)
        )  # fmt: skip


NOISE_LEVELS: dict[str, NoiseLevel] = {
    "none": NoiseLevel(min_area=0),
    "low": NoiseLevel(
        drop_prob=0.02, miss_small_prob=0.2, merge_prob=0.1, split_prob=0.2, boundary_px=0.5,
        unlabeled_boundary=0.1, spurious_rate=0.2,
    ),
    "default": NoiseLevel(
        drop_prob=0.03, miss_small_prob=0.35, merge_prob=0.25, split_prob=0.3, boundary_px=1.0,
        unlabeled_boundary=0.2, spurious_rate=0.4,
    ),
    "high": NoiseLevel(
        drop_prob=0.08, miss_small_prob=0.6, merge_prob=0.45, split_prob=0.7, max_pieces=4, boundary_px=2.0,
        unlabeled_boundary=0.4, spurious_rate=1.5,
    ),
}  # fmt: skip


def _touching_pairs(labels: np.ndarray) -> np.ndarray:
    """Unique unordered pairs [P, 2] of different nonzero labels that are 4-neighbours."""
    a = np.concatenate([labels[:, :-1].ravel(), labels[:-1, :].ravel()])
    b = np.concatenate([labels[:, 1:].ravel(), labels[1:, :].ravel()])
    keep = (a != b) & (a > 0) & (b > 0)
    if not np.any(keep):
        return np.zeros((0, 2), dtype=np.int64)
    pairs = np.sort(np.stack([a[keep], b[keep]], 1), axis=1)
    return np.unique(pairs, axis=0)


def _boundary_mask(labels: np.ndarray) -> np.ndarray:
    m = np.zeros(labels.shape, dtype=bool)
    dx = labels[:, 1:] != labels[:, :-1]
    dy = labels[1:, :] != labels[:-1, :]
    m[:, 1:] |= dx
    m[:, :-1] |= dx
    m[1:, :] |= dy
    m[:-1, :] |= dy
    return m


def simulate_segments(
    instances: np.ndarray,
    depth: np.ndarray | None,
    level: NoiseLevel,
    rng: np.random.Generator,
) -> Segmentation:
    """One frame of simulated SAM output from an int instance map [H, W] (0 = no surface)."""
    inst = np.asarray(instances)
    if inst.ndim != 2:
        raise ValueError(f"gt_instances must be a 2D id map, got shape {inst.shape}")
    if inst.size and inst.min() < 0:
        raise ValueError("gt_instances must hold ids >= 0")
    if depth is not None and np.shape(depth) != inst.shape:
        raise ValueError(f"depth shape {np.shape(depth)} differs from gt_instances shape {inst.shape}")
    H, W = inst.shape
    npx = float(H * W)
    inst = inst.astype(np.int64)
    n_ids = int(inst.max(initial=0)) + 1
    area = np.bincount(inst.ravel(), minlength=n_ids).astype(np.float64)
    present = np.nonzero(area)[0]
    present = present[present > 0]
    corrupted: set[int] = set()

    # 1. missed instances
    lut = np.arange(n_ids, dtype=np.int64)
    if len(present):
        far = np.zeros(n_ids, dtype=bool)
        if depth is not None and level.far_depth > 0:
            d = np.asarray(depth, dtype=np.float64)
            valid = (d > 0) & np.isfinite(d)
            cnt = np.bincount(inst[valid], minlength=n_ids)
            mean_d = np.bincount(inst[valid], weights=d[valid], minlength=n_ids) / np.maximum(cnt, 1)
            far = (mean_d > level.far_depth) & (cnt > 0)
        hard = (area < level.small_area * npx) | far
        p_miss = level.drop_prob + np.where(hard, level.miss_small_prob, 0.0)
        missed = rng.uniform(size=n_ids) < p_miss
        missed[0] = False
        lut[missed] = 0

    # 2. merging of touching small instances (union-find over the few candidate pairs)
    if level.merge_prob > 0:
        pairs = _touching_pairs(lut[inst])
        small = area < level.merge_area * npx
        for a, b in pairs:
            if small[a] and small[b] and rng.uniform() < level.merge_prob:
                ra, rb = lut[a], lut[b]
                while lut[ra] != ra:
                    ra = lut[ra]
                while lut[rb] != rb:
                    rb = lut[rb]
                if ra != rb and ra > 0 and rb > 0:
                    lut[lut == rb] = ra
                    corrupted.add(int(ra))
    labels = lut[inst]

    # 3. over-segmentation of large regions
    next_id = n_ids
    if level.split_prob > 0:
        seg_area = np.bincount(labels.ravel(), minlength=n_ids)
        for s in np.nonzero(seg_area > level.large_area * npx)[0]:
            if s == 0 or rng.uniform() >= level.split_prob:
                continue
            ys, xs = np.nonzero(labels == s)
            k = int(rng.integers(2, level.max_pieces + 1))
            seeds = rng.choice(len(ys), size=k, replace=False)
            w = rng.uniform(0.5, 2.0, size=(k, 2))  # anisotropic cells: long strips as well as blobs
            d2 = (w[None, :, 0] * (ys[:, None] - ys[seeds][None]) ** 2) + (
                w[None, :, 1] * (xs[:, None] - xs[seeds][None]) ** 2
            )
            piece = np.argmin(d2, axis=1)
            new_ids = np.concatenate([[s], np.arange(next_id, next_id + k - 1)])
            labels[ys, xs] = new_ids[piece]
            corrupted.update(int(v) for v in new_ids)
            next_id += k - 1
    before = labels.copy()

    # 4. boundary noise: smooth displacement field, then unlabeled boundary pixels
    if level.boundary_px > 0:
        gh, gw = max(2, H // 8), max(2, W // 8)
        field = rng.normal(0.0, level.boundary_px, size=(gh, gw, 2)).astype(np.float32)
        field = cv2.resize(field, (W, H), interpolation=cv2.INTER_CUBIC)
        gx, gy = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))
        labels = cv2.remap(
            labels.astype(np.float32), gx + field[..., 0], gy + field[..., 1], cv2.INTER_NEAREST,
            borderMode=cv2.BORDER_REPLICATE,
        ).astype(np.int64)  # fmt: skip
    if level.unlabeled_boundary > 0:
        drop = _boundary_mask(labels) & (rng.uniform(size=labels.shape) < level.unlabeled_boundary)
        labels[drop] = 0

    # 5. spurious segments
    for _ in range(int(rng.poisson(level.spurious_rate))):
        mask = np.zeros((H, W), dtype=np.uint8)
        center = (int(rng.integers(0, W)), int(rng.integers(0, H)))
        axes = (max(2, int(rng.uniform(0.03, 0.15) * W)), max(2, int(rng.uniform(0.03, 0.15) * H)))
        cv2.ellipse(mask, center, axes, float(rng.uniform(0, 180)), 0, 360, 1, -1)
        labels[mask > 0] = next_id
        corrupted.add(next_id)
        next_id += 1

    # Segments whose pixels changed a lot under boundary noise count as corrupted too.
    changed = labels != before
    seg_area = np.bincount(labels.ravel(), minlength=next_id)
    changed_area = np.bincount(labels[changed].ravel(), minlength=next_id)
    corrupted.update(int(s) for s in np.nonzero(changed_area > 0.1 * np.maximum(seg_area, 1))[0])

    # 6. tiny fragments, then a fresh random id permutation
    small = seg_area < level.min_area
    small[0] = False
    labels[small[labels]] = 0
    final = np.unique(labels)
    final = final[final > 0]
    perm = rng.permutation(len(final)) + 1
    remap = np.zeros(next_id, dtype=np.int32)
    remap[final] = perm
    ids = remap[labels]
    scores: dict[int, float] = {}
    for old, new in zip(final.tolist(), perm.tolist()):
        if level.clean:
            scores[int(new)] = 1.0
        elif old in corrupted:
            scores[int(new)] = float(rng.uniform(0.88, 0.95))
        else:
            scores[int(new)] = float(rng.uniform(0.95, 1.0))
    return Segmentation(ids=ids.astype(np.int32), scores=scores)


class SimulatedSegmenter:
    """Segmenter protocol over ground truth: ``seg(rgb, depth, gt_instances=...)``.

    ``noise``: a level name (none | low | default | high) or a :class:`NoiseLevel`. The output of a
    frame depends only on (seed, frame_index, inputs); without ``frame_index`` an internal call
    counter is used, so a fixed call order is reproducible too.
    """

    def __init__(self, noise: str | NoiseLevel = "default", seed: int = 0) -> None:
        if isinstance(noise, str):
            if noise not in NOISE_LEVELS:
                raise ValueError(f"unknown noise level {noise!r}; expected one of {sorted(NOISE_LEVELS)}")
            noise = NOISE_LEVELS[noise]
        self.level = noise
        self.seed = int(seed)
        self._calls = 0

    def __call__(
        self,
        rgb: np.ndarray,
        depth: np.ndarray | None = None,
        *,
        gt_instances: np.ndarray | None = None,
        frame_index: int | None = None,
    ) -> Segmentation:
        if gt_instances is None:
            raise ValueError(
                "SimulatedSegmenter needs the ground-truth instance map: pass gt_instances=frame.gt_instances"
                " (only synthetic scenes have one)"
            )
        if np.shape(gt_instances) != np.shape(rgb)[:2]:
            raise ValueError(
                f"gt_instances shape {np.shape(gt_instances)} differs from rgb {np.shape(rgb)[:2]}"
            )
        index = self._calls if frame_index is None else int(frame_index)
        self._calls += 1
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, 0x5A4, index]))
        return simulate_segments(gt_instances, depth, self.level, rng)

    def segment_frame(self, frame) -> Segmentation:
        """Segment an :class:`~ogscene3d.frame.Frame` that carries ``gt_instances``."""
        return self(frame.rgb, frame.depth, gt_instances=frame.gt_instances, frame_index=frame.index)
