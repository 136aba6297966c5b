"""Multi-view co-segmentation evidence (beyond the paper; the ``mapping.evidence_*`` switches, each rule's
measured effect in docs/consistency.md).

The paper fixes a Gaussian's label at first sight: a later view's segment that matches the map takes the
label the map already has (case ii), so when the first view merged a vase with the cabinet it stands on, or
absorbed a light switch into the wall, every later, cleaner view of the vase or the switch only confirms the
wrong label, and the long-term step's consistency test (the majority rendered label inside each stored
segment, Eq. 16) agrees with it too. What the later views do show is that the label's region falls into two
segments, and that one part of it is always in a segment of its own. This module collects that evidence at
every keyframe, as view-consensus mask clustering does offline (MaskClustering, CVPR 2024), and decides
incrementally:

* **observe** (every keyframe, on the map as it stands before the keyframe's association; and, with
  ``evidence_revisit``, the long-term step's memory views again, against the map as it is then: Gaussians
  made after a view was a keyframe had no word from it, and the ones the view made itself get none from it):
  the labelled Gaussians are projected into the frame (visible where the observed depth agrees,
  ``merge.visible_pixels``); those on the boundary of a segment whose interior holds most of it are left out
  (``spill_pixels``: a small segment, a book or a switch a few pixels across, is nearly all boundary and is
  kept whole). For each label L, its visible Gaussians are counted per segment; the segment with the most of
  them is L's *main* segment in this view. A Gaussian in the main segment gets a "together" view; one in
  another segment that is itself mostly L (at least half of its visible Gaussians, and ``min_group`` of
  them) gets a "split" view: the view shows it as a separate part of L. One in another segment that is
  mostly *other* labels gets a "wrong" view: L ran over into a neighbouring object (a first view that merged
  a cabinet with the floor gave the cabinet's label to the floor around it, and later views put that floor
  in the floor's segment). Per label, the views where it was judged count, and those where it *owned* its
  main segment (held ``OWN`` of the segment's visible Gaussians). Per label pair, the views where both
  labels lie mostly (``CONTAIN``) in one segment count, those where it is the same segment count as
  "together", and of those the ones where each label is ``min_part`` of the segment's visible Gaussians
  ("firm"), and where that segment is confident ("sure").
* **lower_confidences** (with the long-term step, ``evidence_split``, ``evidence_wrong``): a Gaussian judged
  in at least ``min_views`` views, shown apart (or in another label's segment) in at least ``split_ratio``
  of them, loses that ratio of its confidence (Eq. 16's decrease with P_2D-3D = the ratio and P_conf = 0):
  its stored views disagree with its label. Algorithm 1 then re-decides the wrong-label ones even in a
  protected label, giving them another label than their own (``refine.global_refinement``'s ``exposed``).
* **quick splits** (``evidence_quick_split``): a Gaussian judged in fewer than ``min_views`` views is
  decided when every one of them showed it apart and there were two, or one of them was a segment SAM
  scored at least ``evidence_confident_score``. A book first seen in the last keyframes has no third view;
  one clean, confident view of it on its own says more than a random cut, which SAM scores low.
* **partition** (with the global refinement, first, ``evidence_partition``): every judged Gaussian remembers
  the segment each of its latest ``SLOTS`` views put it in. A label's spatial components (Alg. 1's clusters,
  each of at least ``partition_min`` Gaussians) are compared view by view through the segment most of their
  Gaussians were in: components that at least ``LINKED`` of their common views put in one segment form a
  group, and a group that fewer than ``partition_apart`` of its common views with the label's largest group
  put in one segment becomes a new label once the group's mean confidence is under ``partition_below``
  (``mapping.evidence_partition_conf``, ``tau_low`` by default): the long-term step lowers the group's
  Gaussians by the share of the views that put it apart (``lower_partitioned``, Eq. 16's decrease), and the
  refinement re-decides what is low. A first view that merged a chair, a cabinet and a sofa with the
  floor, or three books with each other, left one label over parts that no later view joins again; the
  Gaussian-level split votes below cannot undo it when each part is its label's main segment in some views.
  Components are separated in space, so a surface that SAM cuts at random places stays whole: its pieces
  are one component, and separate patches of it are in one segment in most views.
* **split_and_merge** (with the global refinement, before Alg. 1): labels that at least ``merge_ratio`` of
  at least ``min_views`` views show in one segment are merged (``evidence_merge``); with
  ``evidence_quick_merge`` also a pair judged in fewer views when every one held both in one segment, firm,
  and two did or one was sure (a sofa that its first view cut in pieces; a cup inside the table's segment is
  no firm part of it). Gaussians with split evidence and a confidence under ``split_below``
  (``mapping.evidence_split_conf``: 1 by default, the views decide; ``tau_low`` waits for the long-term
  step's decrease, except for quick decisions, which may have no long-term step left) are split off their
  label, each spatially connected group of at least ``min_group`` of them (same label, r_search) becoming a
  new label at confidence 0.5 (``evidence_split``). Algorithm 1 then re-decides what is left low.
* **protected_labels** (for Alg. 1, ``evidence_protect``): labels that owned a segment in a view since they
  were made, and labels not yet judged in ``min_views`` views, keep their Gaussians through Alg. 1. Without
  it a small object whose confidence is low (its low SAM score at birth, Eq. 5 decreases in the views that
  absorbed it) took the label of the wall or the table around it, its only high-confidence neighbour.
* **veto** (after Alg. 1, ``evidence_veto``, off): a relabelling by Alg. 1 from label a to label b is undone
  when at least ``min_views`` views held both labels mostly in one segment each and fewer than
  ``apart_ratio`` of them in the same one.

A SAM that cuts a wall or a chair at random places puts a given Gaussian in a minority piece only in a few
views, far below ``split_ratio``, and a fragment of a surface does not come back as a segment of its own; a
support merge that SAM makes in a quarter of the views leaves the pair apart (merging needs ``merge_ratio``,
0.9, of the views). Evidence is not saved in checkpoints: a resumed run collects it anew.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from .local import group_top2
from .longterm import label_edges
from .merge import merge_labels, visible_pixels
from .neighbors import knn_components
from .refine import connected_clusters

UNSTAMPED = 3.0e38  # evidence_born of a Gaussian no view has judged yet
SLOTS = 4  # the latest judged views whose segment each Gaussian remembers (8 measured the same)
LINKED = 0.5  # two components of a label are one object when this share of their common views joins them
OWN = 0.8  # a label owns a view's segment when it holds this share of the segment's visible Gaussians
CONTAIN = 0.8  # a label lies "in one segment" of a view when this share of its visible Gaussians does


@dataclass
class EvidenceStats:
    views: int = 0
    judged: int = 0
    split_votes: int = 0
    lowered: int = 0
    split_labels: int = 0
    split_gaussians: int = 0
    merged_labels: int = 0
    partitioned_labels: int = 0

    def as_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


def spill_pixels(seg: torch.Tensor) -> torch.Tensor:
    """[H,W] bool: the boundary pixels of the segments ``seg`` [H,W] (ids >= 0) whose interior holds at least
    half of their pixels. A Gaussian at an object's edge may project just across it (a spill); a small
    segment (a book, a light switch: a few pixels across) is nearly all boundary, and leaving that out would
    leave the objects the evidence exists for unjudged."""
    edge = label_edges(seg)
    flat = seg.reshape(-1).clamp(min=0)
    area = torch.bincount(flat)
    inner = torch.bincount(flat[~edge.reshape(-1)], minlength=area.numel())
    big = 2 * inner >= area
    return edge & big[flat].reshape(seg.shape)


def _start_afresh(gm, rows: torch.Tensor) -> None:
    """Clear the label-level votes of Gaussians ``rows`` that moved to a new label: its views start afresh
    (the segments they remember stay: they say where the Gaussians were, whatever their label)."""
    for name in ("evidence_views", "evidence_split", "evidence_sure", "evidence_wrong"):
        gm.aux(name)[rows] = 0.0


def remember_segments(gm, rows: torch.Tensor, segs: torch.Tensor, view: int) -> None:
    """Record that judgement ``view`` (a stamp, unique per judgement) put the Gaussians ``rows`` [R] in the
    segments ``segs`` [R]. Each Gaussian keeps its latest ``SLOTS`` views, round robin, in the auxiliary
    values ``evidence_seen{k}`` (the stamp) and ``evidence_seg{k}`` (the segment id), -1 where empty."""
    if rows.numel() == 0:
        return
    count = gm.aux("evidence_remembered")
    slot = (count[rows] % SLOTS).long()
    for k in range(SLOTS):
        at = slot == k
        gm.aux(f"evidence_seen{k}", -1.0)[rows[at]] = float(view)
        gm.aux(f"evidence_seg{k}", -1.0)[rows[at]] = segs[at].float()
    count[rows] += 1


def component_segments(
    gm, rows: torch.Tensor, comp: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per (component, remembered view) seen: the segment most of the component's Gaussians were in, for the
    Gaussians ``rows`` [R] in components ``comp`` [R]. Returns (component [E], view [E] compact 0..V-1,
    segment [E]); ties go to the smaller segment id."""
    cs, vs, ss = [], [], []
    for k in range(SLOTS):
        view = gm.aux(f"evidence_seen{k}", -1.0)[rows]
        seg = gm.aux(f"evidence_seg{k}", -1.0)[rows]
        ok = view >= 0
        cs.append(comp[ok])
        vs.append(view[ok].long())
        ss.append(seg[ok].long())
    c, v, sg = torch.cat(cs), torch.cat(vs), torch.cat(ss)
    if c.numel() == 0:
        return c, v, sg
    _, vi = torch.unique(v, return_inverse=True)
    nv = int(vi.max()) + 1
    keys, at = torch.unique(c * nv + vi, return_inverse=True)
    top, _, _, _ = group_top2(at, sg, keys.numel())
    return keys // nv, keys % nv, top


def _apart_groups(
    comp: torch.Tensor, view: torch.Tensor, seg: torch.Tensor, size: torch.Tensor, apart: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """Per component of one label: its group's index, or -1 for the components that stay with the label, and
    the share of the group's common views with the label's largest group that put them apart (0 where it
    stays). ``comp``, ``view``, ``seg`` [E]: the segment of component ``comp`` (0..C-1) in ``view``, at most
    one entry per component and view; ``size`` [C] the components' Gaussians. Common and joint views are
    counted as products of one-hot tables ([C,V] views, [C,P] view-segment pairs): a [C,C,V] table grows with
    the stream's length."""
    n, dev = size.numel(), size.device
    _, vi = torch.unique(view, return_inverse=True)
    seen = torch.zeros((n, int(vi.max()) + 1 if vi.numel() else 0), device=dev)
    seen[comp, vi] = 1.0
    _, pi = torch.unique(vi * (int(seg.max()) + 1 if seg.numel() else 1) + seg, return_inverse=True)
    pair = torch.zeros((n, int(pi.max()) + 1 if pi.numel() else 0), device=dev)
    pair[comp, pi] = 1.0
    common = seen @ seen.T
    together = pair @ pair.T
    linked = (common > 0) & (together >= LINKED * common)
    nodes = torch.arange(n, device=dev)
    grp = knn_components(
        torch.where(linked, nodes[None, :], torch.full_like(linked, -1, dtype=torch.long))
    ).long()
    mass = torch.zeros(n, device=dev).index_add_(0, grp, size.float())
    main = grp == int(torch.argmax(mass))
    out = torch.full_like(grp, -1)
    share = torch.zeros(n, device=dev)
    for g in torch.unique(grp[~main]).tolist():
        mem = grp == g
        c = float(common[mem][:, main].sum())
        t = float(together[mem][:, main].sum())
        if c > 0 and t < apart * c:
            out[mem] = g
            share[mem] = 1.0 - t / c
    return out, share


class SegmentEvidence:
    """Per-Gaussian split evidence (auxiliary values of the GaussianMap) and per-label-pair co-segmentation
    counts, collected view by view."""

    # per label pair: views where both lay mostly in one segment each; of those, in the same one; of those,
    # with each label a real part of the segment (``min_part``); of those, in a confident segment
    _PAIRS = ("pair_views", "pair_together", "pair_firm", "pair_sure")

    def __init__(self, device: torch.device) -> None:
        self.device = device
        for name in self._PAIRS:
            setattr(self, name, torch.zeros((0, 0), device=device))
        self.label_seen = torch.zeros(0, device=device)
        self.label_owned = torch.zeros(0, device=device)
        self.clock = 0  # judgements so far: the stamps of observe
        self._judged: dict[int, int] = {}  # view (keyframe index) -> the stamp of its last judgement
        self.stats = EvidenceStats()

    def _grow(self, n: int) -> None:
        old = self.pair_views.shape[0]
        if n <= old:
            return
        size = max(n, 2 * old, 64)
        for name in self._PAIRS:
            t = torch.zeros((size, size), device=self.device)
            t[:old, :old] = getattr(self, name)
            setattr(self, name, t)
        for name in ("label_seen", "label_owned"):
            t = torch.zeros(size, device=self.device)
            t[:old] = getattr(self, name)
            setattr(self, name, t)

    def observe(
        self,
        gm,
        segments: np.ndarray | None,
        pose: np.ndarray,
        K: np.ndarray,
        depth: np.ndarray,
        *,
        margin: float = 0.1,
        min_group: int = 3,
        view: int | None = None,
        revisit: bool = False,
        scores: dict[int, float] | None = None,
        confident: float = 0.95,
        min_part: float = 0.1,
    ) -> None:
        """Add one view's evidence (see the module docstring). ``gm``: the GaussianMap; ``segments`` [H,W]
        int ids (0 = none); ``pose`` c2w, ``K``, ``depth`` the view's (metres); ``view`` its key (the
        keyframe index), under which its judgement is remembered; ``scores`` the segments' SAM scores, a
        split vote from a segment scored at least ``confident`` also counting as a confident one; two labels
        in one segment count as *firm* together when each holds ``min_part`` of its visible Gaussians.

        A view judged again (``revisit``, the long-term step's memory views) gives votes only to the
        Gaussians first stamped after its last judgement (made since), and leaves the per-label and per-pair
        counts alone, so that no view counts twice for any Gaussian or label however often it is revisited."""
        if segments is None:
            return
        since = self._judged.get(view, 0) if revisit else None
        dev = gm.device
        self.clock += 1
        if view is not None:
            # the Gaussians a keyframe makes get the next stamp (they did not exist when it was judged): its
            # own segments made them, so a revisit must not count them as a second opinion
            self._judged[view] = self.clock if revisit else self.clock + 1
        if len(gm) == 0:
            return
        born = gm.aux("evidence_born", UNSTAMPED)
        born[born == UNSTAMPED] = float(self.clock)  # the Gaussians this view is the first to see
        pick = torch.nonzero(gm.labels >= 0).squeeze(1)
        if pick.numel() == 0:
            return
        seg = torch.as_tensor(np.ascontiguousarray(segments), device=dev).long()
        pix = visible_pixels(
            gm.means[pick],
            torch.as_tensor(pose, dtype=torch.float32, device=dev),
            torch.as_tensor(K, dtype=torch.float32, device=dev),
            torch.as_tensor(np.ascontiguousarray(depth), dtype=torch.float32, device=dev),
            margin,
        )
        vis = pix >= 0
        g, p = pick[vis], pix[vis]
        s = seg.reshape(-1)[p]
        ok = (s > 0) & ~spill_pixels(seg).reshape(-1)[p]
        g, s = g[ok], s[ok]
        if g.numel() == 0:
            return
        self.stats.views += 1
        lab = gm.labels[g].long()
        S = int(s.max()) + 1
        key = lab * S + s
        uniq, inv, cnt = torch.unique(key, return_inverse=True, return_counts=True)
        ul, us = uniq // S, uniq % S
        # the main segment of each label: its entry with the most Gaussians (ties: the smaller segment id)
        order = torch.argsort(-cnt, stable=True)
        order = order[torch.argsort(ul[order], stable=True)]
        first = torch.ones_like(order, dtype=torch.bool)
        first[1:] = ul[order][1:] != ul[order][:-1]
        is_main = torch.zeros_like(first)
        is_main[order[first]] = True
        n_seg = torch.zeros(S, device=dev).index_add_(0, us, cnt.float())
        n_lab = torch.zeros(int(ul.max()) + 1, device=dev).index_add_(0, ul, cnt.float())
        main_big = torch.zeros(int(ul.max()) + 1, dtype=torch.bool, device=dev)
        main_big[ul[is_main]] = cnt[is_main] >= min_group
        part = ~is_main & (cnt >= min_group) & main_big[ul]
        split = part & (cnt.float() >= 0.5 * n_seg[us])
        # a part of the label inside another label's segment, away from the label's own: the label ran over
        # into a neighbouring object (a cabinet's label that took in the floor around it)
        wrong = part & ~split
        together = is_main & main_big[ul]
        judged = (split | together)[inv]
        fresh = torch.ones_like(judged) if since is None else born[g] > float(since)
        remember_segments(gm, g[fresh], s[fresh], self.clock)
        judged &= fresh
        views, votes = gm.aux("evidence_views"), gm.aux("evidence_split")
        views.index_add_(0, g[judged], torch.ones(int(judged.sum()), device=dev))
        sv = split[inv] & fresh
        votes.index_add_(0, g[sv], torch.ones(int(sv.sum()), device=dev))
        wv = wrong[inv] & fresh
        gm.aux("evidence_wrong").index_add_(0, g[wv], torch.ones(int(wv.sum()), device=dev))
        is_sure = torch.zeros(S, dtype=torch.bool, device=dev)
        if scores:
            sure_ids = [int(i) for i, v in scores.items() if 0 < int(i) < S and float(v) >= confident]
            is_sure[torch.tensor(sure_ids, dtype=torch.long, device=dev)] = True
            sure = sv & is_sure[s]
            gm.aux("evidence_sure").index_add_(0, g[sure], torch.ones(int(sure.sum()), device=dev))
        self.stats.judged += int(judged.sum())
        self.stats.split_votes += int(sv.sum())

        if revisit:
            return
        # ownership: a label whose main segment holds little else in this view is an object SAM found
        self._grow(int(gm.next_label))
        ml, mc, ms = ul[is_main], cnt[is_main], us[is_main]
        big = mc >= min_group
        self.label_seen.index_add_(0, ml[big], torch.ones(int(big.sum()), device=dev))
        pure = big & (mc.float() >= OWN * n_seg[ms])
        self.label_owned.index_add_(0, ml[pure], torch.ones(int(pure.sum()), device=dev))

        # label pairs: the labels that lie mostly in one segment, and which segment that is
        share = cnt[is_main].float() / n_lab[ul[is_main]]
        contained = share >= CONTAIN
        labs, mains = ul[is_main][contained], us[is_main][contained]
        if labs.numel() < 2:
            return
        part = (mc[contained].float() >= min_part * n_seg[mains]).float()
        ii, jj = labs[:, None].expand(-1, labs.numel()), labs[None, :].expand(labs.numel(), -1)
        same = (mains[:, None] == mains[None, :]).float()
        firm = same * part[:, None] * part[None, :]
        sure = firm * is_sure[mains].float()[:, None]
        at = (ii.reshape(-1), jj.reshape(-1))
        self.pair_views.index_put_(at, torch.ones(ii.numel(), device=dev), True)
        self.pair_together.index_put_(at, same.reshape(-1), True)
        self.pair_firm.index_put_(at, firm.reshape(-1), True)
        self.pair_sure.index_put_(at, sure.reshape(-1), True)

    def protected_labels(self, n_labels: int, min_views: int, min_owned: int = 1) -> torch.Tensor:
        """[n_labels] bool: the labels Algorithm 1 leaves alone (``mapping.evidence_protect``): those that
        owned a segment (held nearly all of it, ``OWN``) in at least ``min_owned`` views since they were made,
        objects that SAM found on their own again, and those judged in fewer than ``min_views`` views, which
        the evidence cannot tell yet from a fragment (a small object's label starts at its low SAM score and
        is all low confidence). One view is enough: a light switch that SAM absorbs into the wall in most
        views still owns its segment in some, and a fragment of a surface (a spurious or cut segment) does not
        come back as a segment of its own."""
        out = torch.ones(n_labels, dtype=torch.bool, device=self.device)
        m = min(n_labels, self.label_owned.numel())
        out[:m] = (self.label_owned[:m] >= min_owned) | (self.label_seen[:m] < min_views)
        return out

    def split_ratio(self, gm, min_views: int, quick: bool = False) -> torch.Tensor:
        """[N] the share of a Gaussian's judged views that showed it as a separate part of its label (0 with
        fewer than ``min_views`` judged views). With ``quick``, fewer views decide when every one of them
        showed it apart and there were two, or one of them was a confident segment (ratio 1)."""
        views, votes = gm.aux("evidence_views"), gm.aux("evidence_split")
        decided = views >= min_views
        if quick:
            sure = gm.aux("evidence_sure")
            decided |= (votes >= views) & ((views >= 2) | (sure >= 1))
        return torch.where(decided, votes / views.clamp(min=1), torch.zeros_like(views))

    def wrong_ratio(self, gm, min_views: int) -> torch.Tensor:
        """[N] the share of a Gaussian's judged views that showed it inside another label's segment, away from
        its own label's main segment (0 while it has been judged in fewer than ``min_views`` views)."""
        wrong, views = gm.aux("evidence_wrong"), gm.aux("evidence_views")
        seen = views + wrong
        return torch.where(seen >= min_views, wrong / seen.clamp(min=1), torch.zeros_like(seen))

    def lower_confidences(
        self,
        gm,
        *,
        min_views: int = 3,
        split_ratio: float = 0.5,
        quick: bool = False,
        split: bool = True,
        wrong: bool = False,
        wrong_views: int = 3,
    ) -> int:
        """Eq. 16's decrease for Gaussians with split evidence (``split``) or wrong-label evidence
        (``wrong``, decided after ``wrong_views`` judged views), by the larger of the two ratios (in place);
        returns how many."""
        zero = torch.zeros_like(gm.confidences)
        r = torch.maximum(
            self.split_ratio(gm, min_views, quick) if split else zero,
            self.wrong_ratio(gm, wrong_views) if wrong else zero,
        )
        low = (r >= split_ratio) & (gm.labels >= 0)
        conf = gm.confidences
        conf[low] = (conf[low] - r[low] * conf[low]).clamp(0.0, 1.0)
        n = int(low.sum())
        self.stats.lowered += n
        return n

    def split_and_merge(
        self,
        gm,
        *,
        split: bool = True,
        merge: bool = True,
        min_views: int = 3,
        split_ratio: float = 0.5,
        merge_ratio: float = 0.9,
        quick: bool = False,
        quick_merge: bool = False,
        split_below: float = 1.0,
        r_search: float = 0.1,
        graph_k: int = 8,
        min_group: int = 3,
        partition: bool = False,
        partition_apart: float = 0.25,
        partition_min: int = 2,
        partition_below: float = 1.0,
    ) -> dict[str, int]:
        """Partition labels into the objects their views show (``partition``), merge labels that most views
        show in one segment, then split low-confidence parts with split evidence off their labels (in place
        on ``gm.labels`` / ``gm.confidences``). Returns counts."""
        out = {"partitioned_labels": 0, "merged_labels": 0, "split_labels": 0, "split_gaussians": 0}
        if partition:
            out["partitioned_labels"] = self.partition(
                gm, r_search, graph_k, partition_min, partition_apart, partition_below
            )
        if merge and self.pair_views.numel():
            v, t = self.pair_views, self.pair_together
            hit = (v >= min_views) & (t >= merge_ratio * v)
            if quick_merge:  # too few views for the ratio: unanimous, and firm in two or sure in one
                hit |= (v >= 1) & (v < min_views) & (t >= v) & ((self.pair_firm >= 2) | (self.pair_sure >= 1))
            hit.fill_diagonal_(False)
            pairs = torch.nonzero(torch.triu(hit, diagonal=1))
            present = torch.zeros(v.shape[0], dtype=torch.bool, device=v.device)
            lab = gm.labels[gm.labels >= 0].long()
            present[lab[lab < v.shape[0]]] = True
            pairs = pairs[present[pairs[:, 0]] & present[pairs[:, 1]]]
            mapping = merge_labels(gm.labels, pairs)
            if mapping:
                gone = torch.tensor(list(mapping), dtype=torch.long, device=v.device)
                for m in (getattr(self, name) for name in self._PAIRS):
                    m[gone] = 0
                    m[:, gone] = 0
                out["merged_labels"] = len(mapping)
        if split:
            r = self.split_ratio(gm, min_views, quick)
            # a quick decision (fewer than min_views views: first seen in the last keyframes) does not wait
            # for the long-term decrease, which may not come before the stream ends
            few = gm.aux("evidence_views") < min_views
            low = (r >= split_ratio) & ((gm.confidences < split_below) | few) & (gm.labels >= 0)
            cand = torch.nonzero(low).squeeze(1)
            if cand.numel() >= min_group:
                comp = connected_clusters(gm.means[cand], gm.labels[cand], r_search, graph_k)
                size = torch.bincount(comp[comp >= 0])
                big = torch.nonzero(size >= min_group).squeeze(1)
                if big.numel():
                    lut = torch.full((size.numel(),), -1, dtype=torch.int64, device=gm.device)
                    lut[big] = gm.new_labels(int(big.numel())).long()
                    new = lut[comp.clamp(min=0)]
                    take = (comp >= 0) & (new >= 0)
                    rows = cand[take]
                    gm.labels[rows] = new[take].to(gm.labels.dtype)
                    gm.confidences[rows] = 0.5
                    _start_afresh(gm, rows)
                    out["split_labels"] = int(big.numel())
                    out["split_gaussians"] = int(rows.numel())
        self.stats.partitioned_labels += out["partitioned_labels"]
        self.stats.merged_labels += out["merged_labels"]
        self.stats.split_labels += out["split_labels"]
        self.stats.split_gaussians += out["split_gaussians"]
        return out

    def _partition_plan(
        self, gm, r_search: float, graph_k: int, min_size: int, apart: float
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None:
        """The groups that ``partition`` would give labels of their own: per labelled Gaussian (the rows
        [R] returned first), its group (-1 for none; ids unique over the map) and the share of the views that
        put its group apart from its label's largest group. None when nothing is apart."""
        dev = gm.device
        rows = torch.nonzero(gm.labels >= 0).squeeze(1)
        if rows.numel() < 2 * min_size:
            return None
        comp = connected_clusters(gm.means[rows], gm.labels[rows], r_search, graph_k)
        n_comp = int(comp.max()) + 1
        size = torch.bincount(comp, minlength=n_comp)
        owner = torch.zeros(n_comp, dtype=torch.long, device=dev)
        owner[comp] = gm.labels[rows].long()
        big = size >= min_size
        several = torch.bincount(owner[big], minlength=int(gm.next_label)) >= 2
        cand = big & several[owner]
        if not bool(cand.any()):
            return None
        pick = cand[comp]
        ec, ev, es = component_segments(gm, rows[pick], comp[pick])
        if ec.numel() == 0:
            return None
        group = torch.full((n_comp,), -1, dtype=torch.long, device=dev)
        share = torch.zeros(n_comp, device=dev)
        index = torch.full((n_comp,), -1, dtype=torch.long, device=dev)
        # the candidate components and their entries, sorted by label: one slice of each per label
        cs_all = torch.nonzero(cand).squeeze(1)
        cs_all = cs_all[torch.argsort(owner[cs_all], stable=True)]
        labs, n_cs = torch.unique_consecutive(owner[cs_all], return_counts=True)
        order = torch.argsort(owner[ec], stable=True)
        ec, ev, es = ec[order], ev[order], es[order]
        e_labs, n_e = torch.unique_consecutive(owner[ec], return_counts=True)
        e_at = dict(zip(e_labs.tolist(), zip(torch.cumsum(n_e, 0).sub(n_e).tolist(), n_e.tolist())))
        start = 0
        for lab, n in zip(labs.tolist(), n_cs.tolist()):
            cs = cs_all[start : start + n]
            start += n
            if n < 2 or lab not in e_at:
                continue
            e0, ne = e_at[lab]
            lc = ec[e0 : e0 + ne]
            index[cs] = torch.arange(n, device=dev)
            grp, sh = _apart_groups(index[lc], ev[e0 : e0 + ne], es[e0 : e0 + ne], size[cs], apart)
            index[cs] = -1
            apart_here = grp >= 0
            group[cs[apart_here]] = cs[grp[apart_here]]  # the group's smallest component: unique on the map
            share[cs] = sh
        if not bool((group >= 0).any()):
            return None
        return rows, group[comp], share[comp]

    def lower_partitioned(
        self, gm, r_search: float, graph_k: int = 8, min_size: int = 2, apart: float = 0.25
    ) -> int:
        """Eq. 16's decrease for the Gaussians of the groups ``partition`` would split off, by the share of
        the views that put them apart (in place; P_2D-3D = that share, P_conf = 0). Returns how many."""
        plan = self._partition_plan(gm, r_search, graph_k, min_size, apart)
        if plan is None:
            return 0
        rows, group, share = plan
        at = rows[group >= 0]
        conf = gm.confidences
        conf[at] = (conf[at] - share[group >= 0] * conf[at]).clamp(0.0, 1.0)
        return int(at.numel())

    def partition(
        self,
        gm,
        r_search: float,
        graph_k: int = 8,
        min_size: int = 2,
        apart: float = 0.25,
        below: float = 1.0,
    ) -> int:
        """Give each group of a label's spatial components that the remembered views put apart from the
        label's largest group a new label (see the module docstring), when its Gaussians' mean confidence is
        under ``below`` (1: the views decide; ``tau_low``: only what ``lower_partitioned`` brought low). In
        place, the moved Gaussians' confidence capped at 0.5 and their split evidence cleared, as a split's.
        Returns how many new labels."""
        plan = self._partition_plan(gm, r_search, graph_k, min_size, apart)
        if plan is None:
            return 0
        rows, group, _ = plan
        ids, inv = torch.unique(group, return_inverse=True)
        mean = torch.zeros(ids.numel(), device=gm.device).index_add_(0, inv, gm.confidences[rows])
        mean /= torch.bincount(inv, minlength=ids.numel()).float()
        take = (ids >= 0) & (mean < below)
        made = int(take.sum())
        if made == 0:
            return 0
        lut = torch.full((ids.numel(),), -1, dtype=torch.long, device=gm.device)
        lut[take] = gm.new_labels(made).long()
        new = lut[inv]
        at = rows[new >= 0]
        gm.labels[at] = new[new >= 0].to(gm.labels.dtype)
        gm.confidences[at] = gm.confidences[at].clamp(max=0.5)
        _start_afresh(gm, at)
        return made

    def veto(
        self,
        gm,
        labels_before: torch.Tensor,
        conf_before: torch.Tensor,
        *,
        min_views: int = 3,
        apart_ratio: float = 0.3,
    ) -> int:
        """Undo relabellings (``labels_before`` -> ``gm.labels``) between labels that the views show apart
        (in place, confidences restored from ``conf_before``). Returns how many Gaussians were restored."""
        n = self.pair_views.shape[0]
        changed = (gm.labels != labels_before) & (labels_before >= 0) & (gm.labels >= 0)
        rows = torch.nonzero(changed).squeeze(1)
        if rows.numel() == 0 or n == 0:
            return 0
        a, b = labels_before[rows].long(), gm.labels[rows].long()
        ok = (a < n) & (b < n)
        rows, a, b = rows[ok], a[ok], b[ok]
        v, t = self.pair_views[a, b], self.pair_together[a, b]
        apart = (v >= min_views) & (t < apart_ratio * v)
        back = rows[apart]
        gm.labels[back] = labels_before[back]
        gm.confidences[back] = conf_before[back]
        return int(back.numel())
