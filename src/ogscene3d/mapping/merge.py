"""Merging duplicate scene labels (an extension beyond the paper, ``mapping.merge.enabled``).

The paper's local association leaves a segment unlabeled when its KNN matches are split between two
scene labels (case i, r(m) >= tau_valid). Two situations produce that: the segment covers two objects
(SAM under-segmentation), or one object carries two labels, because an earlier view over-segmented it or
its probes found no match. The paper has no way out of the second: every later view of that object is
ambiguous again and all Gaussians added there stay unlabeled.

We tell the two apart in the keyframe's own view. The map's Gaussians of the two labels l1, l2 of an
ambiguous segment m are projected into the keyframe (before its own Gaussians are added); those that land
on a pixel whose observed depth agrees with theirs are visible, and the others are occluded or out of
view. The visible extent of a label is its count of visible Gaussians, and its containment in m the
fraction of them whose pixel lies in m. When both labels lie almost entirely inside one confident
segment (each containment >= ``tau_contain``, SAM score >= ``min_score``), the segment sees one object
that carries two labels, and the labels are merged (the one with more Gaussians keeps its id). A
segment that spills over onto a neighbouring object fails the containment test for that object's label;
two small objects that SAM fused are usually scored low, and the score gate keeps them apart. A small
object that the mask took in (a far chair absorbed into the wall behind it, a plant into the floor) lies
whole inside it too, at a high score when it is a small part of the mask; each label must therefore hold at
least ``min_part`` (``mapping.merge.min_part``, 0.1) of the mapped Gaussians inside the segment, as both
halves of one object do.

With ``mapping.merge.novel`` the test also judges a would-be novel segment (p < tau_p, case iii tested
first) whose few matches fall on two labels (r >= tau_valid): a wall or floor that the first view cut in
two, seen again further back, where the mapped part is a few percent of the segment. Without it each such
view started a third label on the surface. A confident novel segment that holds the whole visible extent
of its most matched label l*_m (``label_containment``) and merges nothing takes that label: a small object (a
clock) seen closer, whose few probes mostly missed its Gaussians, or a floor seen further.
Counting
Gaussians rather than rendering a label map keeps the check to one projection of the two labels'
Gaussians, and independent of the confidences that weight a semantic render.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch

from .._disjoint_sets import DisjointSets
from .local import CASE_AMBIGUOUS, CASE_MATCHED, CASE_NOVEL, coherence

if TYPE_CHECKING:
    from ..config import MappingConfig
    from ..frame import Frame
    from ..gaussians import GaussianMap
    from .timings import Timings


def visible_pixels(
    means: torch.Tensor, c2w: torch.Tensor, K: torch.Tensor, depth: torch.Tensor, margin: float
) -> torch.Tensor:
    """Flat pixel index (v * W + u) of each Gaussian centre ``means`` [N,3] in the view (c2w [4,4],
    K [3,3], observed ``depth`` [H,W] metres), or -1 where it is behind the camera, outside the image, on a
    pixel without depth, or more than ``margin`` metres off the observed depth (occluded, or in front of
    the surface)."""
    h, w = depth.shape
    R = c2w[:3, :3].to(means.dtype)
    p = (means - c2w[:3, 3].to(means.dtype)) @ R  # world -> camera: R^T (x - t)
    z = p[:, 2]
    zs = torch.where(z > 1e-6, z, torch.ones_like(z))
    u = torch.floor(K[0, 0] * p[:, 0] / zs + K[0, 2]).long()
    v = torch.floor(K[1, 1] * p[:, 1] / zs + K[1, 2]).long()
    inside = (z > 1e-6) & (u >= 0) & (v >= 0) & (u < w) & (v < h)
    pix = torch.where(inside, v * w + u, torch.zeros_like(u))
    d = depth.reshape(-1)[pix]
    ok = inside & (d > 0) & ((z - d).abs() <= margin)
    return torch.where(ok, pix, torch.full_like(pix, -1))


def duplicate_label_pairs(
    seg_index: torch.Tensor,
    item_labels: torch.Tensor,
    candidates: torch.Tensor,
    top1: torch.Tensor,
    top2: torch.Tensor,
    tau_contain: float = 0.8,
    min_part: float = 0.0,
) -> torch.Tensor:
    """Label pairs [P,2] (l1, l2) that a candidate segment shows to be one object.

    Items are what a label's visible extent is counted in: the visible Gaussians (``visible_pixels``) or
    the pixels of a rendered label map. seg_index [M] int: the segment index at each item (-1 outside every
    segment); item_labels [M] int: the item's scene label (-1 none); candidates [C]: segment indices to
    test, with their two most frequent matched labels top1[c], top2[c] (both >= 0). A pair is returned
    when, for both labels, at least ``tau_contain`` of the label's items lie inside the segment, and (with
    ``min_part`` > 0) they make up at least ``min_part`` of the labelled items in the segment each: a minor
    share is a detail the mask took in (a chair far in front of the wall, absorbed into the wall's segment),
    not half of an object that carries two labels.
    """
    dev = seg_index.device
    empty = torch.zeros((0, 2), dtype=torch.int64, device=dev)
    if candidates.numel() == 0:
        return empty
    l1 = top1[candidates].long()
    l2 = top2[candidates].long()
    ok = (l1 >= 0) & (l2 >= 0) & (l1 != l2)
    if not bool(ok.any()):
        return empty
    cand, l1, l2 = candidates[ok].long(), l1[ok], l2[ok]
    c = cand.numel()
    n, e = _counts_in(seg_index, item_labels, cand.repeat(2), torch.cat([l1, l2]))  # one pass for both
    n1, n2, e1, e2 = n[:c], n[c:], e[:c], e[c:]
    keep = (n1 >= tau_contain * e1) & (n2 >= tau_contain * e2) & (e1 > 0) & (e2 > 0)
    if min_part > 0:
        seg = seg_index.reshape(-1).long()
        inside = seg[(seg >= 0) & (item_labels.reshape(-1) >= 0)]
        total = torch.bincount(inside, minlength=int(cand.max()) + 1)[cand].float()
        keep &= (n1 >= min_part * total) & (n2 >= min_part * total)
    return torch.stack([l1[keep], l2[keep]], 1)


def label_containment(
    seg_index: torch.Tensor, item_labels: torch.Tensor, segs: torch.Tensor, labels: torch.Tensor
) -> torch.Tensor:
    """[C] the share of label ``labels[c]``'s items that lie in segment ``segs[c]`` (0 for a label without
    items). ``seg_index`` [M] and ``item_labels`` [M] as in ``duplicate_label_pairs``."""
    n, extent = _counts_in(seg_index, item_labels, segs, labels)
    return n / extent.clamp(min=1)


def _counts_in(
    seg_index: torch.Tensor, item_labels: torch.Tensor, segs: torch.Tensor, labels: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Per c: the items of label ``labels[c]`` in segment ``segs[c]``, and all of that label's items
    ([C] float each). ``seg_index`` [M] and ``item_labels`` [M] as in ``duplicate_label_pairs``."""
    dev = seg_index.device
    seg = seg_index.reshape(-1).long()
    ren = item_labels.reshape(-1).long()
    want = torch.unique(labels.long())
    nl = want.numel()
    pos = torch.searchsorted(want, ren.clamp(min=0)).clamp(max=nl - 1)
    hit = (ren >= 0) & (want[pos] == ren)
    extent = torch.bincount(pos[hit], minlength=nl).float()
    both = hit & (seg >= 0)
    keys, counts = torch.unique(seg[both] * nl + pos[both], return_counts=True)
    li = torch.searchsorted(want, labels.long())
    key = segs.long() * nl + li
    if keys.numel() == 0:
        return torch.zeros(key.shape, device=dev), extent[li]
    j = torch.searchsorted(keys, key).clamp(max=keys.numel() - 1)
    n = torch.where(keys[j] == key, counts[j], torch.zeros_like(counts[j]))
    return n.float(), extent[li]


def merge_labels(labels: torch.Tensor, pairs: torch.Tensor) -> dict[int, int]:
    """Merge each pair's labels in ``labels`` [N] (in place); the label with more Gaussians keeps its id.

    Chains (a~b, b~c) collapse into one label. Returns {dropped label: kept label}."""
    if pairs.numel() == 0:
        return {}
    # a handful of pairs per keyframe: a union-find over them in Python is cheap
    sets = DisjointSets()
    for a, b in pairs.tolist():
        sets.union(b, a)
    mapping: dict[int, int] = {}
    for members in sets.groups().values():
        ids = torch.tensor(members, dtype=labels.dtype, device=labels.device)
        counts = (labels[:, None] == ids[None, :]).sum(0)
        keep = int(ids[int(torch.argmax(counts))])
        for m in ids.tolist():
            if m != keep:
                mapping[int(m)] = keep
    labels.copy_(relabel(labels, mapping))
    return mapping


def relabel(labels: torch.Tensor, mapping: dict[int, int]) -> torch.Tensor:
    """A copy of ``labels`` with every key of ``mapping`` replaced by its value (one pass, any shape)."""
    out = labels.clone()
    if not mapping:
        return out
    src = torch.tensor(list(mapping), dtype=labels.dtype, device=labels.device)
    dst = torch.tensor(list(mapping.values()), dtype=labels.dtype, device=labels.device)
    rows, cols = torch.nonzero(labels.reshape(-1)[:, None] == src[None, :], as_tuple=True)
    out.view(-1)[rows] = dst[cols]
    return out


def merge_duplicate_segments(
    gm: GaussianMap,
    frame: Frame,
    segments: np.ndarray,
    scores: dict[int, float],
    probes,
    res,
    cfg: MappingConfig,
    timings: Timings,
) -> None:
    """Merge the scene labels of ``gm`` that one confident ambiguous segment of the keyframe shows to be one
    object; the segment then takes the merged label (case ii), and the keyframe's segment labels in ``res``
    (``local.associate_segments``'s result) follow. With ``merge_novel`` a would-be novel segment is judged
    too: over two labels it may merge them, and when it holds its most matched label whole it takes that
    label. Runs before Eq. 5, so that the merged segments' matches get their confidence update too."""
    device = gm.device
    seg_ids = probes.seg_ids
    score = torch.tensor(
        [scores.get(int(i), 1.0) for i in seg_ids.tolist()], dtype=torch.float32, device=device
    )
    confident = score >= cfg.merge.min_score
    novel = (res.seg_case == CASE_NOVEL) & confident & bool(cfg.merge.novel)
    # ambiguous segments, and novel ones whose few matches fall on two labels, may merge those; a novel
    # one may hold its most matched label whole
    amb = torch.nonzero(
        (res.seg_case == CASE_AMBIGUOUS) & confident | novel & (res.r >= cfg.association.tau_valid)
    ).squeeze(1)
    ext = torch.nonzero(novel & (res.top_label >= 0)).squeeze(1)
    if amb.numel() == 0 and ext.numel() == 0:
        return
    with timings.section("merge"):
        items, item_labels = _visible_items(gm, frame, segments, seg_ids, cfg.init.depth_margin)
        if ext.numel():
            # it shows more of that object (a small one seen closer, whose few probes missed its
            # Gaussians): the segment takes its label instead of a new one
            held = label_containment(items, item_labels, ext, res.top_label[ext])
            grow = ext[held >= cfg.merge.contain]
            res.seg_labels[grow] = res.top_label[grow].to(torch.int32)
            res.seg_case[grow] = CASE_MATCHED
            timings.add("segments_extended", int(grow.numel()))
        pairs = duplicate_label_pairs(
            items, item_labels, amb, res.top_label, res.second_label, cfg.merge.contain, cfg.merge.min_part
        )
        mapping = merge_labels(gm.labels, pairs)
        if mapping:
            merged = _follow_merge(res, amb, mapping)
            timings.add("labels_merged", len(mapping))
            timings.add("segments_merged", int(merged.numel()))


def _visible_items(
    gm: GaussianMap, frame: Frame, segments: np.ndarray, seg_ids: torch.Tensor, margin: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """(segment index, label) of every labelled Gaussian visible in the keyframe (-1: on no segment)."""
    device = gm.device
    ids = torch.as_tensor(np.asarray(segments), dtype=torch.int64, device=device)
    top = max(int(ids.max()), int(seg_ids.max())) + 1
    lut = torch.full((top,), -1, dtype=torch.int64, device=device)
    lut[seg_ids] = torch.arange(seg_ids.numel(), device=device)
    seg_index = lut[ids.clamp(min=0)].masked_fill(ids <= 0, -1).reshape(-1)
    pick = torch.nonzero(gm.labels >= 0).squeeze(1)  # all: min_part counts the segment's labels
    pix = visible_pixels(
        gm.means[pick],
        torch.as_tensor(frame.pose, dtype=torch.float32, device=device),
        torch.as_tensor(frame.K, dtype=torch.float32, device=device),
        torch.as_tensor(frame.depth, dtype=torch.float32, device=device),
        margin,
    )
    vis = pix >= 0
    return seg_index[pix[vis]], gm.labels[pick[vis]]


def _follow_merge(res, amb: torch.Tensor, mapping: dict[int, int]) -> torch.Tensor:
    """The keyframe's association result after the merge ``mapping``: its labels renamed, the ambiguous
    segments ``amb`` whose two labels merged made matched (returned), and p(m) of the matched segments
    counted again."""
    res.top_label = relabel(res.top_label, mapping)
    res.second_label = relabel(res.second_label, mapping)
    res.seg_labels = relabel(res.seg_labels, mapping)
    merged = amb[res.top_label[amb] == res.second_label[amb]]
    res.seg_labels[merged] = res.top_label[merged].to(torch.int32)
    res.seg_case[merged] = CASE_MATCHED
    # p(m) as Eq. 5 must see it now: the probes on either merged label agree with l*_m (a merged
    # segment's p counted only one of the two; a matched one's may have had probes on a dropped label)
    res.match_labels = relabel(res.match_labels, mapping)
    p = coherence(res.match_labels, res.probe_seg, res.top_label, int(res.seg_case.numel()))
    res.p = torch.where(res.seg_case == CASE_MATCHED, p, res.p)
    return merged
