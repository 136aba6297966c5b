"""A simulated SAM: realistic open-set segments made from ground-truth instance maps.

Used for the synthetic scenes (where no SAM model is needed to test the mapper) and for noise
ablations. Starting from the per-pixel instance ids it applies, in this order:

1. **missed objects**: every instance is dropped with ``drop_prob``; small ones (area below
   ``small_area`` of the image) and far ones (mean valid depth beyond ``far_depth`` m) additionally
   with ``miss_small_prob``;
1a. **first-view merges** (long scans, ``synthetic.layout: scan``): the frames listed in a plan made by the
   generator (``datasets/long_scan.py``) paint an instance into the segment of a given partner (the floor,
   the large furniture next to it, what it stands on) when the two touch in the image: an object
   under-segmented in the views that first show it. No plan, no change (and no random draw);
1b. **absorbed objects** (the SAM-like levels): a small or far instance is, with ``absorb_prob``,
   painted into the segment of the surface behind or under it instead of getting its own: its support
   (``support``: instance -> the instance it rests on or hangs on) when that touches it in the image,
   else the touching instance with the longest shared border among those farther from the camera (else
   any touching one). SAM does not leave such pixels empty: a light switch comes back as part of the wall;
1c. **support merges** (SAM-like): an instance below ``support_merge_area`` of the image that touches its
   support in the image is merged with it with ``support_merge_prob`` ("the cabinet with the vase on
   it", "the shelf with its books"), independently in every frame, so most views still show it apart;
2. **merging**: a pair of touching small instances (both below ``merge_area``) becomes one segment
   with ``merge_prob`` (SAM often returns "the books", not each book);
3. **over-segmentation**: a large region (above ``large_area``: walls, floor) is cut into 2 to
   ``max_pieces`` pieces with ``split_prob`` (nearest-seed cells in the image plane); with
   ``object_split_prob`` (SAM-like) a medium region (``object_split_area`` to ``large_area``: a chair,
   a cabinet, a door) is cut in two the same way;
4. **boundary noise**: boundaries are displaced by a smooth random field of ``boundary_px`` pixels
   amplitude, and boundary pixels are left unsegmented with ``unlabeled_boundary``;
5. **spurious segments**: on average ``spurious_rate`` random elliptic segments (shadows, texture);
6. segments smaller than ``min_area`` pixels are removed.

Ids are a fresh random permutation every frame (as SAM's, never consistent across frames). Scores
imitate SAM's predicted IoU after its 0.88 threshold: U(0.95, 1) for clean segments and
U(0.88, 0.95) for corrupted ones (split, merged, spurious, or with > 10 % of their pixels changed; a
segment that absorbed other instances counts as corrupted when they make up more than 10 % of it, so a
wall that swallowed a light switch keeps a high score, as SAM's would).
Level "none" returns the ground truth, permuted, with score 1.

Levels: "low", "default", "high" are SAM-like (absorption, support merges and object cuts on top of the
errors above); "legacy-low", "legacy-default", "legacy-high" are the earlier levels, which drop small and
far objects instead of absorbing them and never merge an object with its support (documented in
docs/consistency.md).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace

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
    # SAM-like errors (0 in the legacy levels)
    absorb_prob: float = 0.0  # a small/far instance joins the segment behind/under it
    support_merge_prob: float = 0.0  # an instance merged with its support in this frame
    support_merge_area: float = 0.06  # fraction of the image: larger instances are never merged
    object_split_prob: float = 0.0  # a medium region (object_split_area .. large_area) cut in two
    object_split_area: float = 0.01
    # long scans only (a first-view plan, datasets/long_scan.py): the share of the objects on the floor or on
    # large furniture that the views first showing them merge with the floor or a neighbour
    first_view_merge_prob: float = 0.0

    @property
    def clean(self) -> bool:
        """No corruption at all: the segments are the ground truth (renumbered), with score 1."""
        return not any(
            (self.drop_prob, self.miss_small_prob, self.merge_prob, self.split_prob, self.boundary_px,
             self.unlabeled_boundary, self.spurious_rate, self.min_area, self.absorb_prob,
             self.support_merge_prob, self.object_split_prob, self.first_view_merge_prob)
        )  # fmt: skip


LEGACY_LEVELS: dict[str, NoiseLevel] = {
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

# SAM-like: the legacy level's boundary noise, spurious segments and wall/floor cuts, but a small or far
# object is absorbed by the surface behind it (not left out), some views merge an object with its support,
# and objects are cut in two as well.
_SAM_LIKE = {
    "low": dict(absorb_prob=0.3, support_merge_prob=0.15, object_split_prob=0.1, first_view_merge_prob=0.25),
    "default": dict(
        absorb_prob=0.5, support_merge_prob=0.25, object_split_prob=0.15, first_view_merge_prob=0.4
    ),
    "high": dict(absorb_prob=0.7, support_merge_prob=0.4, object_split_prob=0.3, first_view_merge_prob=0.6),
}

NOISE_LEVELS: dict[str, NoiseLevel] = {
    "none": NoiseLevel(min_area=0),
    **{
        name: replace(LEGACY_LEVELS[name], miss_small_prob=0.0, **extra)  # absorbed, not missed
        for name, extra in _SAM_LIKE.items()
    },
    **{f"legacy-{name}": level for name, level in LEGACY_LEVELS.items()},
}


def _touching_pairs(labels: np.ndarray) -> np.ndarray:
    """Unique unordered pairs [P, 2] of different nonzero labels that are 4-neighbours."""
    a = np.concatenate([labels[:, :-1].ravel(), labels[:-1, :].ravel()])
    b = np.concatenate([labels[:, 1:].ravel(), labels[1:, :].ravel()])
    keep = (a != b) & (a > 0) & (b > 0)
    if not np.any(keep):
        return np.zeros((0, 2), dtype=np.int64)
    pairs = np.sort(np.stack([a[keep], b[keep]], 1), axis=1)
    return np.unique(pairs, axis=0)


def _touching_counts(labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ordered pairs [P, 2] (a, b) of different nonzero 4-neighbour labels (both orders) and the length of
    their shared border in pixel edges [P]."""
    a = np.concatenate([labels[:, :-1].ravel(), labels[:-1, :].ravel()])
    b = np.concatenate([labels[:, 1:].ravel(), labels[1:, :].ravel()])
    keep = (a != b) & (a > 0) & (b > 0)
    if not np.any(keep):
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0, dtype=np.int64)
    both = np.concatenate([np.stack([a[keep], b[keep]], 1), np.stack([b[keep], a[keep]], 1)])
    return np.unique(both, axis=0, return_counts=True)


def _find(lut: np.ndarray, a: int) -> int:
    while lut[a] != a:
        a = int(lut[a])
    return a


def _absorb_and_merge(
    inst: np.ndarray,
    lut: np.ndarray,
    hard: np.ndarray,
    mean_depth: np.ndarray | None,
    area: np.ndarray,
    support: Mapping[int, int] | None,
    level: NoiseLevel,
    rng: np.random.Generator,
) -> set[int]:
    """Steps 1b and 1c on the id table ``lut`` (in place: an absorbed or merged instance points to the
    instance that takes it). Returns the instances whose segment grew."""
    grown: set[int] = set()
    pairs, border = _touching_counts(lut[inst])
    if len(pairs) == 0:
        return grown
    npx = float(inst.size)
    sup = support or {}
    nbrs: dict[int, list[tuple[int, int]]] = {}
    for (a, b), n in zip(pairs.tolist(), border.tolist()):
        nbrs.setdefault(a, []).append((b, n))
    for a in sorted(nbrs):
        if lut[a] != a:
            continue
        touching = dict(nbrs[a])
        s = sup.get(a)
        target = None
        if hard[a] and level.absorb_prob > 0 and rng.uniform() < level.absorb_prob:
            if s is not None and s in touching:
                target = s
            else:
                behind = [
                    (n, b)
                    for b, n in touching.items()
                    if mean_depth is None or mean_depth[b] >= mean_depth[a] - 0.05
                ]
                target = max(behind or [(n, b) for b, n in touching.items()])[1]
        elif (
            s is not None
            and s in touching
            and area[a] < level.support_merge_area * npx
            and level.support_merge_prob > 0
            and rng.uniform() < level.support_merge_prob
        ):
            target = s
        if target is None:
            continue
        root = _find(lut, int(target))
        if root != a and root > 0:
            lut[lut == a] = root
            grown.add(root)
    return grown


def _first_view_merges(inst: np.ndarray, lut: np.ndarray, merges: Mapping[int, int]) -> set[int]:
    """Step 1a on the id table ``lut`` (in place): each instance of ``merges`` joins its partner's segment
    where the two touch in the image. Returns the instances whose segment grew."""
    touching = {tuple(p) for p in _touching_pairs(lut[inst]).tolist()}
    grown: set[int] = set()
    for a, partner in sorted(merges.items()):
        if not (0 < a < len(lut) and 0 < partner < len(lut)) or lut[a] != a:
            continue
        root = _find(lut, int(partner))
        if root in (0, a) or (min(a, root), max(a, root)) not in touching:
            continue
        lut[lut == a] = root
        grown.add(root)
        touching = {tuple(p) for p in _touching_pairs(lut[inst]).tolist()}
    return grown


def _cut(labels: np.ndarray, s: int, k: int, next_id: int, rng: np.random.Generator) -> list[int]:
    """Cut region ``s`` of ``labels`` (in place) into ``k`` nearest-seed cells; returns the ids used."""
    ys, xs = np.nonzero(labels == s)
    seeds = rng.choice(len(ys), size=k, replace=False)
    w = rng.uniform(0.5, 2.0, size=(k, 2))  # anisotropic cells: long strips as well as blobs
    d2 = (w[None, :, 0] * (ys[:, None] - ys[seeds][None]) ** 2) + (
        w[None, :, 1] * (xs[:, None] - xs[seeds][None]) ** 2
    )
    piece = np.argmin(d2, axis=1)
    new_ids = np.concatenate([[s], np.arange(next_id, next_id + k - 1)])
    labels[ys, xs] = new_ids[piece]
    return [int(v) for v in new_ids]


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
    support: Mapping[int, int] | None = None,
    merges: Mapping[int, int] | None = None,
) -> Segmentation:
    """One frame of simulated SAM output from an int instance map [H, W] (0 = no surface).

    ``support``: instance id -> the instance it rests on or hangs on (the synthetic room's support
    relation); without it an absorbed instance goes to the touching surface behind it, and no support
    merges happen. ``merges``: instance id -> the partner it is merged with in this frame (step 1a: a long
    scan's first-view plan)."""
    inst = _checked_instances(instances, depth)
    H, W = inst.shape
    npx = float(H * W)
    n_ids = int(inst.max(initial=0)) + 1
    area = np.bincount(inst.ravel(), minlength=n_ids).astype(np.float64)
    corrupted: set[int] = set()
    # 1. missed instances, merged in a long scan's first views, absorbed into the surface behind, merged with
    # the support
    lut, grown = _miss_and_absorb(inst, depth, area, npx, support, merges, level, rng)
    # 2. merging of touching small instances
    if level.merge_prob > 0:
        _merge_small(lut, inst, area < level.merge_area * npx, level.merge_prob, rng, corrupted)
    labels = lut[inst]
    if grown:
        # an absorbing segment is corrupted when what it took makes up more than 10 % of it
        own = np.bincount(inst[labels == inst], minlength=n_ids)
        total = np.bincount(labels.ravel(), minlength=n_ids)
        corrupted.update(g for g in grown if total[g] - own[g] > 0.1 * total[g])
    # 3. over-segmentation of large regions (and, SAM-like, of medium ones: objects cut in two)
    next_id = _split_regions(labels, n_ids, npx, level, rng, corrupted)
    before = labels.copy()
    # 4. boundary noise: smooth displacement field, then unlabeled boundary pixels
    labels = _boundary_noise(labels, level, rng)
    # 5. spurious segments
    next_id = _spurious_segments(labels, next_id, level, rng, corrupted)
    # Segments whose pixels changed a lot under boundary noise count as corrupted too.
    changed = labels != before
    seg_area = np.bincount(labels.ravel(), minlength=next_id)
    changed_area = np.bincount(labels[changed].ravel(), minlength=next_id)
    corrupted.update(int(s) for s in np.nonzero(changed_area > 0.1 * np.maximum(seg_area, 1))[0])
    # 6. tiny fragments, then a fresh random id permutation
    small = seg_area < level.min_area
    small[0] = False
    labels[small[labels]] = 0
    return _renumbered(labels, next_id, corrupted, level, rng)


def _checked_instances(instances: np.ndarray, depth: np.ndarray | None) -> np.ndarray:
    """``instances`` as an int64 [H, W] id map, after the checks of its shape, ids and ``depth``'s shape."""
    inst = np.asarray(instances)
    if inst.ndim != 2:
        raise ValueError(f"gt_instances must be a 2D id map, got shape {inst.shape}")
    if inst.size and inst.min() < 0:
        raise ValueError("gt_instances must hold ids >= 0")
    if depth is not None and np.shape(depth) != inst.shape:
        raise ValueError(f"depth shape {np.shape(depth)} differs from gt_instances shape {inst.shape}")
    return inst.astype(np.int64)


def _miss_and_absorb(
    inst: np.ndarray,
    depth: np.ndarray | None,
    area: np.ndarray,
    npx: float,
    support: Mapping[int, int] | None,
    merges: Mapping[int, int] | None,
    level: NoiseLevel,
    rng: np.random.Generator,
) -> tuple[np.ndarray, set[int]]:
    """The instance -> segment table after missing instances (small or far ones more often), merging those
    of a long scan's first-view plan (``merges``) and absorbing or merging them into what is behind or under
    them; the segments that grew by absorbing or merging."""
    n_ids = len(area)
    lut = np.arange(n_ids, dtype=np.int64)
    present = np.nonzero(area)[0]
    if not len(present[present > 0]):
        return lut, set()
    far = np.zeros(n_ids, dtype=bool)
    mean_d = None
    if depth is not None:
        d = np.asarray(depth, dtype=np.float64)
        valid = (d > 0) & np.isfinite(d)
        cnt = np.bincount(inst[valid], minlength=n_ids)
        mean_d = np.bincount(inst[valid], weights=d[valid], minlength=n_ids) / np.maximum(cnt, 1)
        if level.far_depth > 0:
            far = (mean_d > level.far_depth) & (cnt > 0)
    hard = (area < level.small_area * npx) | far
    p_miss = level.drop_prob + np.where(hard, level.miss_small_prob, 0.0)
    missed = rng.uniform(size=n_ids) < p_miss
    missed[0] = False
    lut[missed] = 0
    grown: set[int] = _first_view_merges(inst, lut, merges) if merges else set()
    if level.absorb_prob > 0 or level.support_merge_prob > 0:
        grown |= _absorb_and_merge(inst, lut, hard, mean_d, area, support, level, rng)
    return lut, grown


def _merge_small(
    lut: np.ndarray,
    inst: np.ndarray,
    small: np.ndarray,
    merge_prob: float,
    rng: np.random.Generator,
    corrupted: set[int],
) -> None:
    """Merge touching small instances in ``lut`` (union-find over the few candidate pairs)."""
    for a, b in _touching_pairs(lut[inst]):
        if small[a] and small[b] and rng.uniform() < merge_prob:
            ra, rb = lut[a], lut[b]
            while lut[ra] != ra:
                ra = lut[ra]
            while lut[rb] != rb:
                rb = lut[rb]
            if ra != rb and ra > 0 and rb > 0:
                lut[lut == rb] = ra
                corrupted.add(int(ra))


def _split_regions(
    labels: np.ndarray,
    n_ids: int,
    npx: float,
    level: NoiseLevel,
    rng: np.random.Generator,
    corrupted: set[int],
) -> int:
    """Cut large regions into pieces and medium ones in two, in place. -> the next free segment id."""
    next_id = n_ids
    if level.split_prob > 0 or level.object_split_prob > 0:
        seg_area = np.bincount(labels.ravel(), minlength=n_ids)
        # without object cuts only large regions draw a number: the legacy levels' random stream is kept
        lo = level.large_area
        if level.object_split_prob > 0:
            lo = min(lo, level.object_split_area)
        for s in np.nonzero(seg_area > lo * npx)[0]:
            if s == 0:
                continue
            large = seg_area[s] > level.large_area * npx
            if rng.uniform() >= (level.split_prob if large else level.object_split_prob):
                continue
            k = int(rng.integers(2, level.max_pieces + 1)) if large else 2
            corrupted.update(_cut(labels, int(s), k, next_id, rng))
            next_id += k - 1
    return next_id


def _boundary_noise(labels: np.ndarray, level: NoiseLevel, rng: np.random.Generator) -> np.ndarray:
    """Boundaries moved by a smooth random displacement field, then boundary pixels left unlabelled."""
    H, W = labels.shape
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
    return labels


def _spurious_segments(
    labels: np.ndarray, next_id: int, level: NoiseLevel, rng: np.random.Generator, corrupted: set[int]
) -> int:
    """Random ellipses painted in as segments of their own, in place. -> the next free segment id."""
    H, W = labels.shape
    for _ in range(int(rng.poisson(level.spurious_rate))):
        mask = np.zeros((H, W), dtype=np.uint8)
        center = (int(rng.integers(0, W)), int(rng.integers(0, H)))
        axes = (max(2, int(rng.uniform(0.03, 0.15) * W)), max(2, int(rng.uniform(0.03, 0.15) * H)))
        cv2.ellipse(mask, center, axes, float(rng.uniform(0, 180)), 0, 360, 1, -1)
        labels[mask > 0] = next_id
        corrupted.add(next_id)
        next_id += 1
    return next_id


def _renumbered(
    labels: np.ndarray, next_id: int, corrupted: set[int], level: NoiseLevel, rng: np.random.Generator
) -> Segmentation:
    """The segments under fresh random ids, each with a SAM-like score (lower for corrupted ones)."""
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

    ``noise``: a level name (see ``NOISE_LEVELS``) or a :class:`NoiseLevel`. ``support``: instance id ->
    the instance it rests on or hangs on (a synthetic room's, for support merges). ``first_view_merges``:
    {frame index: {instance: partner}}, a long scan's first-view plan (step 1a). The output of a
    frame depends only on (seed, frame_index, inputs); without ``frame_index`` an internal call
    counter is used, so a fixed call order is reproducible too.
    """

    def __init__(
        self,
        noise: str | NoiseLevel = "default",
        seed: int = 0,
        support: Mapping[int, int] | None = None,
        first_view_merges: Mapping[int, Mapping[int, int]] | None = None,
    ) -> None:
        if isinstance(noise, str):
            if noise not in NOISE_LEVELS:
                raise ValueError(f"unknown noise level {noise!r}; expected one of {sorted(NOISE_LEVELS)}")
            noise = NOISE_LEVELS[noise]
        self.level = noise
        self.seed = int(seed)
        self.support = {int(k): int(v) for k, v in (support or {}).items() if v is not None}
        self.first_view_merges = {
            int(f): {int(a): int(b) for a, b in m.items()} for f, m in (first_view_merges or {}).items()
        }
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
        merges = self.first_view_merges.get(index)
        return simulate_segments(gt_instances, depth, self.level, rng, self.support, merges)

    def segment_frame(self, frame) -> Segmentation:
        """Segment an :class:`~ogscene3d.frame.Frame` that carries ``gt_instances``."""
        return self(frame.rgb, frame.depth, gt_instances=frame.gt_instances, frame_index=frame.index)
