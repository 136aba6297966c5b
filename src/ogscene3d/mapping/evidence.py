"""One multi-view evidence model for the map's labels (beyond the paper; ``mapping.evidence``,
docs/consistency.md).

The paper fixes a Gaussian's label at first sight, and its two repairs judge confidence, not co-segmentation:
a later, clean view of a vase that the first view merged with its cabinet matches the cabinet's Gaussians and
only confirms the cabinet's label. SAM's segments tell more, view after view: which parts of the map one
segment holds together, and which it clearly keeps apart. This module accumulates exactly that, over every
judged view, at three grains, and the refinement and the long-term step decide from it.

**Units.** Every Gaussian belongs to a *cell*: the Gaussians one *part* has in one voxel of
``mapping.evidence.cell`` metres. A *part* is what one segment made: the new Gaussians of a novel (or
ambiguous) segment start a part; those of a segment that local association matched with a label join the
part most of its matched Gaussians belong to. The new Gaussians outside every segment start parts too, one
per spatial component (*unsegmented* parts: a book that SAM missed, or a strip along the borders of several
objects). Labels are groups of parts. Parts never merge
(a merge of labels is a grouping, so it can be undone); a part is split when its cells are clearly
separated (below). Ids are per-Gaussian auxiliary values (``ev_cell``) plus small tables per cell
(``cell_part``, its voxel); nothing is saved: a resumed run starts one part per label.

**Observe** (every keyframe, once its new Gaussians are in the map: the view that made a part is its first
judge). Gaussian centres are projected into the view (visible where the observed depth agrees; the boundary
pixels of a big segment are left out, ``spill_pixels``). Weights are the segments' rescaled SAM scores (the
c_sam of Eq. 5): a view's vote counts its segments' confidence.

* *cells*: a cell lies in the segment most of its visible Gaussians are in. Two neighbouring cells of one
  part (one among the other's ``NEIGHBOURS`` nearest visible cells of the part, within ``refine.r_search``)
  are *together* in a view that puts them in one segment, *apart* in one that puts them in two segments
  that are both mostly the part's label, or one in such a segment at most 1/``SMALL`` of the other and the
  other in the part's anchor segment, off its edge (a light switch whose Gaussians joined a piece of the
  wall labelled apart, beside the wall's segment, which is mostly the wall's main label); summed per cell
  pair over all views (``PairTable``), with the number of views.
* *parts*: a part is judged in a view where at least ``MIN_VISIBLE`` of its Gaussians are visible and
  ``CONTAIN`` of those lie in one segment. Two judged parts in one segment are *held together*: firmly when
  each holds ``mapping.merge.min_part`` of the segment's visible Gaussians (the two halves of a sofa), weakly
  otherwise (a cup inside the table's segment: SAM absorbs small objects into their support in most frames,
  which says little). Two judged parts in two segments are *clearly separated* where each is the main part
  of its segment (``MAJOR``): one segment holds one and at most 1 - ``CONTAIN`` of the other, and it is about
  that part, not a piece of a surface that SAM cut at a random place; or where one is the main part of its
  segment and the other lies whole (``CONTAIN``) in another (a nightstand's own segment beside the wall's,
  in which a piece of the wall labelled apart is a minor part). A view judges two parts as well as it sees
  the smaller of them: where it sees fewer than ``CLEAR`` of its Gaussians, its hold or separation counts by
  their share of ``CLEAR`` (SAM absorbs a cup that a far view shows with a few Gaussians into its
  nightstand's segment; the views that show the cup well show it on its own). A firm hold counts as *clear*
  too where the view sees ``CLEAR`` of each part's Gaussians or most of it (``MAJOR``): a book's piece of a
  dozen Gaussians, not the edge of a table in a far view's floor segment. A part can be shown apart where
  ``MAJOR`` of it lies in one segment (SAM cuts a large surface at random places, so it is rarely ``CONTAIN``
  in one segment), and held together only where it is judged. A part *owns* a view's segment when it holds
  ``OWN`` of it.
* *Gaussians*: a labelled Gaussian in a segment other than its label's main one (the segment holding most of
  the label) that is mostly other labels, and more than ``EDGE`` pixels from the main one, is *disputed* in
  that view (the label ran over into a neighbour);
  one in its label's main segment is *confirmed*; one in a segment that is mostly its own label but not the
  label's main one, at most 1/``SMALL`` of it and inside it (half its border with it), is *shown small* (a
  light switch that the wall's label took in, on its own; the segment's size noted). Every Gaussian counts
  the label holding most of its segment (a Misra-Gries counter: one candidate per Gaussian), which an
  unlabelled one takes at the fill and a disputed one in Algorithm 1 (``disputed_labels``).

**Decide** (``decide``, at the global refinement, before Algorithm 1):

1. *split parts*: a part's cells are grouped by average linkage: neighbouring groups merge where the views
   held them together ``LINK_RATIO`` times as often as apart, summed over all their cell pairs (judged in
   ``LINK_VIEWS`` views at least), and, between two groups of ``TINY`` Gaussians or more, in one segment in
   ``LINK_SHARE`` (half) of those views' weight (the views that held them in different segments without a
   verdict, one segment not their label's, count too), mutually best pairs first;
   a linked group other than the part's largest that views put apart from the rest of the part in at least
   ``mapping.evidence.split_ratio`` of their cross views becomes a part of its own (a fridge that the first
   view merged with the floor, books that it merged with each other), where the segments that put it apart
   held at most ``COHERE`` times the group: a SAM cut at random places separates a pair of cells in a few of
   its views only, each time in another, larger piece. A group at most 1/``SMALL`` of its part (a light
   switch in the wall's part) splits on about two views apart however many absorbed it; a group of fewer
   than ``TINY`` Gaussians counts as ``TINY`` in both tests (a segment of a few pixels takes in the support
   just behind its object; one Gaussian is not small beside a bottle of nine). A view that shows one of two
   cells in a segment at most 1/``SMALL`` of the other's counts ``SMALL_APART`` views against their link:
   SAM merges small objects into their support in most frames, so the few that show them apart are the
   evidence. Neighbouring groups that the views put apart from the anchor (``split_ratio`` of their views),
   and held together more often than apart, are judged as one: an object that its first view merged with its
   support is often linked in pieces only. So are such groups within ``SPARSE_REACH`` of each other that no
   cell pair links (far views sample a bookshelf's cells 10 cm apart), where their segments hold more than
   ``COHERE`` * ``TINY`` of the part, no pair of their cells was held apart as often as together, and the
   joined group stays at most 1/``SMALL`` of its part (a wall that SAM cuts at one place is no object).
   Such groups too far apart for that pass ``COHERE`` together: each where its segments held at most
   ``COHERE`` times the groups of its part that segments of about the same size (within ``COHERE``) put apart,
   while those stay at most 1/``SMALL`` of the part (a bookshelf's boards in the floor's part: the segments
   that put each board apart held them all).
   Where the part's largest group leaves and holds ``INHERIT`` (two thirds) of the part, it takes the part's
   history with other parts along. At the Gaussians' grain: a part's Gaussians shown small in
   ``SPLIT_VIEWS`` views, within a cell of each other, become a part of their own where there are ``TINY``
   of them, small beside their part (``SMALL``), and the segments that showed them small held about them
   (``COHERE``): a light switch of a dozen Gaussians shares its cells with the wall's, so no cell is ever
   in its segment (``_split_small``).
2. *group parts into labels*, from scratch every time, greedily by firm support: two groups merge when the
   views held them together (firmly, or weakly with no separation ever) and separated them in at most
   ``mapping.evidence.separation`` (0.5) of their firm views. Two groups that views showed apart from
   something (objects SAM found on their own) need ``MERGE_FIRM`` (about two) more clear firm views than
   separating ones, or, where no view separated them, ``MERGE_UNSEPARATED`` (half a view: the pieces of a
   book that few views saw), and do not merge on weak ones (a table and a piece of floor that the table's
   views never saw, held by three far views that see the table's edge, stay apart). A small object that
   SAM absorbs into its support in most views, but showed apart once, stays apart; a surface that its first
   view cut in two joins once later views hold it whole; a merge made earlier, by the association or a
   previous decision, is undone when the views grow to separate the parts.
3. *relabel*: each group keeps the label most of its Gaussians carry (the largest group first), or, where a
   larger group kept that, the next label of its Gaussians that it holds most of, or takes a new one (a wall
   piece whose label a larger piece kept does not take the label of the cabinet that a few of its Gaussians
   carry; a label that parts made by segments carry is held where most of those parts' Gaussians are, so
   that an unsegmented strip over a vase and its neighbours does not take the vase's label from the vase's
   own part); a part's Gaussians that carry its former label move with it. Unlabelled Gaussians of a group
   take its label; a group of unlabelled parts only gets a label when one of them owned a segment.
4. *fill*: an unlabelled Gaussian that is still unlabelled takes the label its segments voted for.

**Algorithm 1 and Eq. 16 decide from it**: the refinement may not relabel a cluster or a Gaussian across a
clear separation (``separated``: two labels whose parts the views separated more than they held firmly
together), nor across two objects found on their own that the views judged together but step 2 would not
merge, unless the Gaussian is disputed; a disputed Gaussian takes another label than its own: its nearest
confident one's, or, with none near, the one its views put it in. The
long-term step lowers disputed Gaussians' confidence by their share of disputing views (Eq. 16's decrease
with P_2D-3D = that share, P_conf = 0), so that Algorithm 1 re-decides them. A Gaussian whose label changed
(step 3, or Algorithm 1: ``EvidenceFeed.after_refine``) is judged afresh under its new label.

The pair tables grow with the scene's surface, not with the stream: a view adds counts to the pairs it sees.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass

import numpy as np
import torch

from .._disjoint_sets import DisjointSets
from ..config import EvidenceConfig
from .local import group_top2
from .longterm import label_edges
from .merge import visible_pixels
from .neighbors import knn
from .refine import connected_clusters
from .timings import Counters

CONTAIN = 0.8  # a part is judged in a view when this share of its visible Gaussians lies in one segment
OWN = 0.8  # a part owns a segment when it holds this share of the segment's visible Gaussians
# two parts are separated by a view only where each holds this share of its own segment
MAJOR = 0.5
MIN_VISIBLE = 3  # visible Gaussians a part needs to be judged
# a segment's Gaussians apart in space start parts of their own from this many on (a book of 4 Gaussians
# beside the shelf that SAM merged it with: the views can only split off what is a part or a cell group)
MIN_PART = 4
CELL_MIN = 1  # visible Gaussians (in its segment) a cell needs to be judged
NEIGHBOURS = 8  # a cell's neighbours in a view: its nearest visible cells (within ``radius``)
SPARSE_REACH = 2.0  # candidate groups of a part within this many times ``radius`` are judged as one
COHERE = 2.0  # apart segments hold at most this many times the group
TAIL_PAIRS = 4096  # the average linkage of a part's cells goes on group by group once this few pairs are left
TINY = 8  # a group of fewer Gaussians counts as this many for COHERE and SMALL
CLEAR = 8  # visible Gaussians of the smaller of two parts from which a view's judgement of them counts whole
SPLIT_VIEWS = 1.5  # weighted views apart a split needs (about two)
SMALL = 5.0  # a group at most 1/SMALL of its part splits on its apart views alone
SMALL_APART = 3.0  # weight of a cell pair's apart view where one segment is at most 1/SMALL of the other
ANCHOR = 8  # visible cells of a part (its oldest, or its largest linked group's) that anchor its views
LINK_RATIO = 2.0  # two groups of a part's cells are linked when held together this many times as apart
LINK_VIEWS = 2  # views that must have judged pairs of two groups' cells before the groups count as linked
LINK_SHARE = 0.5  # the share of those views' weight that must have held them in one segment (TINY on)
INHERIT = 2 / 3  # the share of its part a leaving largest group needs to take the part's history along
# two groups that views showed apart from something (objects SAM found on their own) merge where their firm
# views outnumber their separating ones by about two: one view that merged a nightstand with a piece of the
# wall behind it is SAM's error, and so are two that held a cup with its nightstand where one showed it apart
MERGE_FIRM = 1.5
# ... or, where no view ever separated them, on this many firm views: the pieces of a book that a few views
# saw, each shown on its own by the book's segment, are never apart, and their firm views are few and weighed
# down (CLEAR)
MERGE_UNSEPARATED = 0.5
DISPUTE = 0.5  # a Gaussian is disputed when this share of its judged views disputed its label
# a Gaussian within this many pixels of its label's main segment is not disputed by the view: along a contact
# line (a book beside a book, a bottle's foot on the table) the side its centre projects to says little
EDGE = 1
_VOX = 2048  # voxel coordinates are packed in 12 bits each (+-2048 cells)
_PART_SHIFT = 36


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


def segment_borders(seg: torch.Tensor, n: int) -> torch.Tensor:
    """[n,n] the pixel edges (4-neighbours) between each two segments of ``seg`` [H,W] (ids 0..n-1; 0, no
    segment, borders nothing), counted in both rows."""
    a = torch.cat([seg[:, :-1].reshape(-1), seg[:-1, :].reshape(-1)])
    b = torch.cat([seg[:, 1:].reshape(-1), seg[1:, :].reshape(-1)])
    k = (a != b) & (a > 0) & (b > 0)
    a, b = a[k], b[k]
    key = torch.cat([a * n + b, b * n + a])
    return torch.bincount(key, minlength=n * n).reshape(n, n)


def near_segment(seg: torch.Tensor, px: torch.Tensor, ids: torch.Tensor, radius: int) -> torch.Tensor:
    """[M] bool: whether the segment ``ids[i]`` of ``seg`` [H,W] holds a pixel within ``radius`` (in x and
    in y) of the flat pixel index ``px[i]``."""
    H, W = seg.shape
    y, x = px // W, px % W
    near = torch.zeros(px.shape, dtype=torch.bool, device=px.device)
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            near |= seg[(y + dy).clamp(0, H - 1), (x + dx).clamp(0, W - 1)] == ids
    return near


class PairTable:
    """Sparse statistics between pairs of ids (unordered): sorted int64 keys ``a << 31 | b`` (a < b) and
    ``cols`` float values per pair, summed over ``add`` calls. New pairs wait in a small sorted table that
    joins the main one when it reaches a quarter of its size, so that a view's update costs what the view
    sees, not a sort of everything stored."""

    def __init__(self, cols: int, device: torch.device) -> None:
        self._keys = [torch.zeros(0, dtype=torch.int64, device=device) for _ in range(2)]  # main, pending
        self._vals = [torch.zeros((0, cols), device=device) for _ in range(2)]

    def __len__(self) -> int:
        return int(self._keys[0].numel() + self._keys[1].numel())

    @property
    def keys(self) -> torch.Tensor:
        self._flush()
        return self._keys[0]

    @property
    def vals(self) -> torch.Tensor:
        self._flush()
        return self._vals[0]

    @staticmethod
    def key(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        lo, hi = torch.minimum(a, b).long(), torch.maximum(a, b).long()
        return (lo << 31) | hi

    @staticmethod
    def unkey(k: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The pairs (a, b), a < b, of keys made by ``key``."""
        return k >> 31, k & ((1 << 31) - 1)

    @staticmethod
    def summed(a: torch.Tensor, b: torch.Tensor, vals: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The distinct unordered pairs of (a[i], b[i]) as sorted keys, and ``vals`` [M, cols] summed per
        pair."""
        k, inv = torch.unique(PairTable.key(a, b), return_inverse=True)
        return k, torch.zeros((k.numel(), vals.shape[1]), device=vals.device).index_add_(0, inv, vals)

    def pairs(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(a [E], b [E]) of every stored pair, a < b (in the order of ``vals``)."""
        return self.unkey(self.keys)

    def _flush(self) -> None:
        if self._keys[1].numel():
            keys = torch.cat(self._keys)
            order = torch.argsort(keys)
            self._keys = [keys[order], self._keys[1][:0]]
            self._vals = [torch.cat(self._vals)[order], self._vals[1][:0]]

    def add(self, a: torch.Tensor, b: torch.Tensor, vals: torch.Tensor) -> None:
        """Add ``vals`` [M, cols] to the pairs (a[i], b[i]) (a != b; repeated pairs sum)."""
        if a.numel() == 0:
            return
        k, v = self.summed(a, b, vals)
        for level in (0, 1):
            keys = self._keys[level]
            if keys.numel() and k.numel():
                at = torch.searchsorted(keys, k).clamp(max=keys.numel() - 1)
                found = keys[at] == k
                self._vals[level].index_add_(0, at[found], v[found])
                k, v = k[~found], v[~found]
        if k.numel():
            keys = torch.cat([self._keys[1], k])
            order = torch.argsort(keys)
            self._keys[1], self._vals[1] = keys[order], torch.cat([self._vals[1], v])[order]
        if self._keys[1].numel() > max(1024, self._keys[0].numel() // 4):
            self._flush()

    def get(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        """[M, cols] the values of pairs (a[i], b[i]) (zeros for pairs never added)."""
        keys, vals = self.keys, self.vals
        out = torch.zeros((a.numel(), vals.shape[1]), device=vals.device)
        if keys.numel() == 0 or a.numel() == 0:
            return out
        k = self.key(a, b)
        at = torch.searchsorted(keys, k).clamp(max=keys.numel() - 1)
        found = keys[at] == k
        out[found] = vals[at[found]]
        return out


def _components(n: int, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Connected components of the graph on n vertices with edges (a[i], b[i]): a component id per vertex."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if n == 0:
        return torch.zeros(0, dtype=torch.long, device=a.device)
    an, bn = a.cpu().numpy(), b.cpu().numpy()
    adj = coo_matrix((np.ones(an.size), (an, bn)), shape=(n, n))
    return torch.as_tensor(connected_components(adj, directed=False)[1], dtype=torch.long, device=a.device)


def _cannot_link_join(
    ga: torch.Tensor, gb: torch.Tensor, na: torch.Tensor, nb: torch.Tensor, xa: torch.Tensor, xb: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """The pairs (na[i], nb[i]) whose joins, made in order after those of (ga, gb), put no cannot-link pair
    (xa[j], xb[j]) in one set; returns the kept pairs."""
    sets = DisjointSets()
    find = sets.find
    for u, v in zip(ga.tolist(), gb.tolist()):
        sets.union(u, v)
    cannot: dict[int, set[int]] = {}
    for u, v in zip(xa.tolist(), xb.tolist()):
        cannot.setdefault(u, set()).add(v)
        cannot.setdefault(v, set()).add(u)
    members: dict[int, list[int]] = {}
    for v in set(cannot):
        members.setdefault(find(v), []).append(v)
    keep = []
    for i, (u, v) in enumerate(zip(na.tolist(), nb.tolist())):
        ru, rv = find(u), find(v)
        if ru == rv:
            continue
        mu, mv = members.get(ru, []), members.get(rv, [])
        if any(find(w) == rv for m in mu for w in cannot[m]):
            continue
        sets.attach(ru, rv)
        if mu:
            members[rv] = mv + mu
            members.pop(ru, None)
        keep.append(i)
    idx = torch.tensor(keep, dtype=torch.long, device=na.device)
    return na[idx], nb[idx]


def _agglomerate(n: int, a: torch.Tensor, b: torch.Tensor, t: torch.Tensor, x: torch.Tensor,
                 nv: torch.Tensor, seen: torch.Tensor, mass: torch.Tensor) -> torch.Tensor:
    """Average-linkage groups of n cells from their pair statistics (a[i], b[i]: together t, apart x, in nv
    views of summed weight ``seen``; ``mass`` Gaussians per cell): a group id per cell. Neighbouring groups
    merge while their summed statistics link them (together at least ``LINK_RATIO`` times apart, in
    ``LINK_VIEWS`` views, and, where both groups hold ``TINY`` Gaussians, in ``LINK_SHARE`` of those views'
    weight), mutually best pairs first, by their margin t - ``LINK_RATIO`` x.
    Single linkage (components of linked cell pairs) lets a few pairs that the views mostly held in one
    segment chain two books on a shelf through their boundary; summed over the whole boundary, the views that
    kept them apart count."""
    out = torch.arange(n, device=a.device)
    if n == 0 or a.numel() == 0:
        return out
    # only the cells of the pairs take part (those of the parts a decision judges), renumbered in their order,
    # so that a round costs what those parts hold, not every cell the map has made since the stream began
    cells = torch.unique(torch.cat([a, b]))
    group = _link_groups(torch.searchsorted(cells, a), torch.searchsorted(cells, b),
                         torch.stack([t, x, nv, seen], 1), mass[cells])  # fmt: skip
    # each group is named by its first cell, as the groups of all n cells would be ordered
    first = torch.full((int(group.max()) + 1,), n, dtype=cells.dtype, device=cells.device)
    out[cells] = first.scatter_reduce_(0, group, cells, reduce="amin")[group]
    return out


def _link_groups(a: torch.Tensor, b: torch.Tensor, vals: torch.Tensor, gmass: torch.Tensor) -> torch.Tensor:
    """:func:`_agglomerate` on cells 0..m-1 (``gmass`` [m]), every one of them in some pair of (``a``,
    ``b``), the pairs' statistics in ``vals`` [P, 4]: a group id per cell, in the order of each group's first
    cell."""
    m = int(gmass.numel())
    comp = torch.arange(m, device=a.device)
    gmass = gmass.clone()
    # the graph of groups, contracted after every round: its pairs carry the summed statistics, so a round
    # costs what is left to merge, not the cells (a floor absorbs its cells a few per round)
    while True:
        cross = a != b
        if not bool(cross.any()):
            return comp
        keys, vals = PairTable.summed(a[cross], b[cross], vals[cross])
        a, b = PairTable.unkey(keys)
        if a.numel() <= TAIL_PAIRS:
            return _link_tail(a, b, vals, gmass)[comp]
        T, X, NV, W = vals.unbind(1)
        # views that held the two in different segments without a verdict (one segment not the part's
        # label's) count against a link too: a table and the sofa behind it, one part since the first view
        # merged them, touch at one cell pair that two of its seven views held in one segment, none apart. Not
        # for a piece of a few Gaussians: most of its cells lie at some segment's edge in most views, and a
        # book's cells, with perfect segments, ended in pieces
        held = (T >= LINK_SHARE * W) | (torch.minimum(gmass[a], gmass[b]) < TINY)
        # (_link_tail's ``link`` takes this test pair by pair: the two change together)
        ok = (T >= LINK_RATIO * X) & (T > 0) & (NV >= LINK_VIEWS) & held
        if not bool(ok.any()):
            return comp
        score = torch.where(ok, T - LINK_RATIO * X, torch.full_like(T, -float("inf")))
        # each group's best partner; mutual bests merge (the best pair overall always does)
        best = torch.full((m,), -float("inf"), device=a.device)
        best.scatter_reduce_(0, torch.cat([a, b]), torch.cat([score, score]), reduce="amax")
        pick = ok & (score >= best[a]) & (score >= best[b])
        # ties can give a group two mutual partners: merge through components of the chosen pairs (ids in
        # the order of each group's first cell, as the components of the cells would number them)
        lut = _components(m, a[pick], b[pick])
        comp, a, b = lut[comp], lut[a], lut[b]
        m = int(lut.max()) + 1
        gmass = torch.zeros(m, device=gmass.device).index_add_(0, lut, gmass)


def _link_tail(a: torch.Tensor, b: torch.Tensor, vals: torch.Tensor, gmass: torch.Tensor) -> torch.Tensor:
    """:func:`_link_groups`' rounds on a graph of few groups' pairs (a[i] < b[i], distinct, in key order;
    their statistics ``vals``; ``gmass`` Gaussians per group), a group at a time: a round looks again only at
    the groups whose pairs changed, where a round of tensors goes over every pair (late in a long scan a few
    large parts absorb one neighbour a round, for hundreds of rounds). Every sum is taken in float32 in the
    order the tensor rounds take it, so the groups are the same. Returns the group of each of the
    ``gmass.numel()`` groups, numbered in the order of each one's first group (as the tensor rounds number
    them)."""
    m = int(gmass.numel())
    mass = gmass.cpu().numpy().astype(np.float32)  # per node (a merged group lives on in one member's node)
    first = list(range(m))  # per node: its group's first group, which orders the pairs' keys
    ratio, share, inf = np.float32(LINK_RATIO), np.float32(LINK_SHARE), -float("inf")

    def link(u: int, v: int, e: np.ndarray) -> tuple[np.ndarray, float]:
        """The pair's statistics and its margin (-inf where the two do not link; see _link_groups)."""
        t, x, nv, w = e
        x2 = ratio * x
        ok = t >= x2 and t > 0 and nv >= LINK_VIEWS and (t >= share * w or min(mass[u], mass[v]) < TINY)
        return e, float(t - x2) if ok else inf

    def key(u: int, v: int) -> tuple[int, int]:
        fu, fv = first[u], first[v]
        return (fu, fv) if fu < fv else (fv, fu)

    adj: dict[int, dict[int, tuple[np.ndarray, float]]] = {}
    for u, v, e in zip(a.tolist(), b.tolist(), vals.cpu().numpy()):
        adj.setdefault(u, {})[v] = adj.setdefault(v, {})[u] = link(u, v, e)
    best: dict[int, float] = {}
    sets = DisjointSets()
    dirty = set(adj)
    while True:
        for u in dirty:
            best[u] = max((s for _, s in adj[u].values()), default=inf)
        # mutual bests (a pair of two groups whose pairs did not change was no pick last round, nor is it now)
        picks = DisjointSets()
        for u in dirty:
            bu = best[u]
            if bu != inf:
                for v, (_, s) in adj[u].items():
                    if s >= bu and s >= best[v]:
                        picks.union(u, v)
        if not picks:
            break
        groups = list(picks.groups().values())
        # each merged group lives on in its member with the most pairs, whose row is kept and amended
        into = {}
        for members in groups:
            node = max(members, key=lambda u: len(adj[u]))
            for u in members:
                into[u] = node
        # the merged groups' Gaussians (summed in the order of their first groups), before any pair's test
        small = {}
        for members in groups:
            node = into[members[0]]
            small[node] = mass[node] < TINY  # its pairs' link test may change with its mass
            acc = np.float32(0.0)
            for u in sorted(members, key=first.__getitem__):
                acc = acc + mass[u]
            mass[node] = acc
        dirty = set()
        for members in groups:
            node = into[members[0]]
            row = adj[node]
            # the pairs that the merge sums: to any merged group, and to the groups the other members touch
            sums: dict[int, list[tuple[tuple[int, int], np.ndarray]]] = {}
            # the kept member's pairs to merged groups, found from the shorter of its row and the merged ones
            shorter, longer = (row, into) if len(row) < len(into) else (into, row)
            to_merged = [w for w in shorter if w in longer]
            for w in to_merged:
                entry = row.pop(w)
                if into[w] != node:
                    sums.setdefault(into[w], []).append((key(node, w), entry[0]))
            for u in members:
                if u != node:
                    for w, (e, _) in adj[u].items():
                        h = into.get(w, w)
                        if h != node:
                            sums.setdefault(h, []).append((key(u, w), e))
                        if w not in into:
                            del adj[w][u]
            for h, contrib in sums.items():
                if h in row:  # a group that did not merge, a pair of the kept member's
                    contrib.append((key(node, h), row[h][0]))
                contrib.sort(key=lambda c: c[0])  # the tensor rounds sum in the order of the pairs' keys
                e = np.zeros(4, dtype=np.float32)
                for _, c in contrib:
                    e = e + c
                row[h] = link(node, h, e)
                if h not in into:
                    adj[h][node] = row[h]
                dirty.add(h)
            if small[node]:
                for h, (e, s) in row.items():
                    if h not in sums:
                        again = link(node, h, e)
                        if again[1] != s:
                            row[h] = adj[h][node] = again
                            dirty.add(h)
            dirty.add(node)
        for members in groups:  # the keys' order changes only now: the sums above were in the former one
            first[into[members[0]]] = min(first[u] for u in members)
        for u, node in into.items():
            if u != node:
                del adj[u]
                best.pop(u, None)
                sets.attach(u, node)
    root = [sets.find(x) for x in range(m)]
    order = torch.tensor([first[r] for r in root], dtype=torch.long, device=gmass.device)
    return torch.unique(order, return_inverse=True)[1]


def _rows_near(centre: torch.Tensor, part: torch.Tensor, fresh: torch.Tensor, radius: float) -> torch.Tensor:
    """Indices of the cells (``centre`` [C,3], ``part`` [C]) whose neighbour lists (same part, within
    ``radius``) can hold a ``fresh`` one: the fresh cells and those within ``radius`` of a fresh cell of their
    part. A revisited view keeps only the pairs with a fresh cell, and a row's neighbours do not depend on
    which other rows are searched, so these rows give exactly those pairs."""
    f = torch.nonzero(fresh).squeeze(1)
    near, _ = knn(centre[f], centre, 1, radius, part[f], part, "same")
    return torch.nonzero(fresh | (near[:, 0] >= 0)).squeeze(1)


def _majority(keys: torch.Tensor, values: torch.Tensor, n: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Per key 0..n-1: the most frequent value among ``values[keys == k]`` (-2 where none; values >= -1) and
    its count."""
    top, cnt, _, _ = group_top2(keys, values + 1, n)
    return torch.where(cnt > 0, top - 1, torch.full_like(top, -2)), cnt


def merge_test(firm, weak, apart, owners, separation: float, clear):
    """Step 2's merge test on two groups' summed statistics (firm, weak, apart, clear: floats, or tensors
    elementwise): held together firmly, and separated in at most ``separation`` of the firm views, or held
    weakly and never separated. ``owners``: a view showed each group apart from something (objects SAM found
    on their own); those merge where their firm views outnumber their separating ones by ``MERGE_FIRM``, or,
    never separated, on ``MERGE_UNSEPARATED`` firm views, and not on weak togetherness (that merges a fragment
    into what holds it); ``clear``: the firm views that saw both groups well, which alone count there (a far
    view that holds a table's edge, three of its Gaussians, in the floor's segment says little about the
    table). Algorithm 1's guard (``EvidenceModel.separation_test``) applies the same test to labels."""
    few_apart = apart <= separation * firm
    firmly = (clear >= MERGE_FIRM + apart) | ((apart <= 0) & (clear >= MERGE_UNSEPARATED))
    found = owners & firmly & few_apart
    fragment = ((firm > 0) & few_apart) | ((firm <= 0) & (apart == 0) & (weak > 0))
    return found | ((owners == 0) & fragment)


def _n_labels(gm) -> int:
    """Label ids of ``gm`` lie below this (its next label, or above its largest label)."""
    lab = gm.labels
    return max(int(gm.next_label), int(lab.max()) + 1 if lab.numel() else 0, 1)


def _candidates(gm) -> tuple[torch.Tensor, torch.Tensor]:
    """Each Gaussian's candidate label (the Misra-Gries counter of the labels holding most of its segments)
    [N] int64, and [N] bool where it is one: counted at least once more than the others, and still a label
    of the map (a merge may have retired it)."""
    c, n = gm.aux("ev_cand", -1.0).long(), gm.aux("ev_cand_n")
    ok = (c >= 0) & (n >= 1)
    if not bool(ok.any()):
        return c, ok
    alive = torch.zeros(max(_n_labels(gm), int(c.max()) + 1), dtype=torch.bool, device=gm.device)
    alive[gm.labels[gm.labels >= 0].long()] = True
    return c, ok & alive[c.clamp(min=0)]


@dataclass
class EvidenceStats(Counters):
    views: int = 0
    parts: int = 0
    cells: int = 0
    part_splits: int = 0
    relabelled_parts: int = 0
    relabelled_gaussians: int = 0
    new_labels: int = 0
    filled: int = 0
    lowered: int = 0


class EvidenceModel:
    """Co-segmentation evidence between cells, parts and labels (see the module docstring)."""

    # part pair columns: views that held both firmly together, weakly together, clearly apart, and firmly
    # together seeing each of them well (``CLEAR`` of its Gaussians, or most of it)
    FIRM, WEAK, APART, CLEAR_FIRM = 0, 1, 2, 3

    def __init__(
        self, device: torch.device, cfg: EvidenceConfig | None = None, *, radius: float = 0.1,
        min_part: float = 0.1,
    ) -> None:
        """``cfg``: the ``mapping.evidence`` section (its defaults when None); ``radius``: the refinement's
        ``r_search`` (a cell's neighbours); ``min_part``: ``mapping.merge.min_part`` (a real part of a
        segment)."""
        cfg = cfg if cfg is not None else EvidenceConfig()
        self.device = device
        self.cell = float(cfg.cell)
        self.radius = float(radius)
        self.separation = float(cfg.separation)
        self.split_ratio = float(cfg.split_ratio)
        self.min_part = float(min_part)
        self.min_views = int(cfg.dispute_views)
        self.cell_part = torch.zeros(0, dtype=torch.long, device=device)
        self.cell_vox = torch.zeros((0, 3), dtype=torch.long, device=device)
        # per cell: views in / apart from its part's anchor segment, and the part's Gaussians in the segments
        # of the apart views (summed, weighted)
        self.cell_main = torch.zeros((0, 3), device=device)
        # whether a cell is in its part's largest group of linked cells (at the last decision that judged it):
        # the views anchor the part there
        self.cell_core = torch.zeros(0, dtype=torch.bool, device=device)
        self._cell_keys = torch.zeros(0, dtype=torch.int64, device=device)  # sorted (part, voxel) keys
        self._cell_ids = torch.zeros(0, dtype=torch.long, device=device)
        self.next_part = 0
        self.part_owned = torch.zeros(0, device=device)  # views in which the part owned its segment
        self.part_apart = torch.zeros(0, device=device)  # views that separated the part from another
        self.part_touched = torch.zeros(0, dtype=torch.bool, device=device)  # judged since the last decide
        # made of Gaussians outside every segment of their view (no segment held them together)
        self.part_unsegmented = torch.zeros(0, dtype=torch.bool, device=device)
        self.cell_pairs = PairTable(4, device)  # together, apart (weighted), views, their weight
        self._judged: dict[int, tuple[int, int]] = {}  # view -> (cells, parts) when it was last judged
        self.part_pairs = PairTable(4, device)  # FIRM, WEAK, APART, CLEAR_FIRM
        self.stats = EvidenceStats()

    # ------------------------------------------------------------------ ids
    def new_parts(self, count: int) -> torch.Tensor:
        start = self.next_part
        self.next_part += int(count)
        for name in ("part_owned", "part_apart", "part_touched", "part_unsegmented"):
            t = getattr(self, name)
            grown = torch.zeros(self.next_part, dtype=t.dtype, device=self.device)
            grown[: t.numel()] = t
            setattr(self, name, grown)
        self.stats.parts = self.next_part
        return torch.arange(start, self.next_part, device=self.device)

    def _voxels(self, means: torch.Tensor) -> torch.Tensor:
        return torch.floor(means / self.cell).long().clamp(-_VOX + 1, _VOX - 1)

    def _cell_key(self, part: torch.Tensor, vox: torch.Tensor) -> torch.Tensor:
        v = vox + _VOX
        return (part.long() << _PART_SHIFT) | (v[:, 0] << 24) | (v[:, 1] << 12) | v[:, 2]

    def _reindex_cells(self) -> None:
        keys = self._cell_key(self.cell_part, self.cell_vox)
        order = torch.argsort(keys)
        self._cell_keys, self._cell_ids = keys[order], order

    def assign(self, gm, rows: torch.Tensor, parts: torch.Tensor) -> None:
        """Put the Gaussians ``rows`` [R] of ``gm`` into the cells of parts ``parts`` [R] (their voxel from
        their centre), creating cells where the part has none in that voxel."""
        if rows.numel() == 0:
            return
        vox = self._voxels(gm.means[rows])
        keys = self._cell_key(parts, vox)
        cell = torch.full_like(keys, -1)
        if self._cell_keys.numel():
            at = torch.searchsorted(self._cell_keys, keys).clamp(max=self._cell_keys.numel() - 1)
            found = self._cell_keys[at] == keys
            cell[found] = self._cell_ids[at[found]]
        miss = cell < 0
        if bool(miss.any()):
            uk, inv = torch.unique(keys[miss], return_inverse=True)
            first = torch.zeros(uk.numel(), dtype=torch.long, device=keys.device)
            first.scatter_(0, inv, torch.nonzero(miss).squeeze(1))
            n0 = self.cell_part.numel()
            ids = torch.arange(n0, n0 + uk.numel(), device=keys.device)
            cell[miss] = ids[inv]
            self.cell_part = torch.cat([self.cell_part, parts.long()[first]])
            self.cell_vox = torch.cat([self.cell_vox, vox[first]])
            self.cell_main = torch.cat([self.cell_main, torch.zeros((uk.numel(), 3), device=keys.device)])
            fresh = torch.zeros(uk.numel(), dtype=torch.bool, device=keys.device)
            self.cell_core = torch.cat([self.cell_core, fresh])
            self._reindex_cells()
            self.stats.cells = int(self.cell_part.numel())
        gm.aux("ev_cell", -1.0)[rows] = cell.float()

    def ensure_cells(self, gm) -> None:
        """Cells for Gaussians that have none (a map resumed from a checkpoint, or made before the evidence
        was collected): one part per label, and per keyframe of origin for unlabelled ones."""
        cell = gm.aux("ev_cell", -1.0)
        rows = torch.nonzero(cell < 0).squeeze(1)
        if rows.numel() == 0:
            return
        lab = gm.labels[rows].long()
        key = torch.where(lab >= 0, lab, -1 - gm.origin_kf[rows].long())
        uk, inv = torch.unique(key, return_inverse=True)
        self.assign(gm, rows, self.new_parts(int(uk.numel()))[inv])

    def parts_of(self, gm) -> torch.Tensor:
        """[N] the part of every Gaussian (-1 for none)."""
        cell = gm.aux("ev_cell", -1.0).long()
        return torch.where(cell >= 0, self.cell_part[cell.clamp(min=0)], torch.full_like(cell, -1))

    # ------------------------------------------------------------------ observe
    def observe(
        self,
        gm,
        segments: np.ndarray | None,
        pose: np.ndarray,
        K: np.ndarray,
        depth: np.ndarray,
        *,
        weights: dict[int, float] | None = None,
        margin: float = 0.1,
        view: int | None = None,
        revisit: bool = False,
    ) -> int:
        """Add one view's evidence (see the module docstring); returns how many of the map's Gaussians the
        view sees (centres in the image, at the observed depth within ``margin``). ``segments`` [H,W] ids
        (0 = none); ``pose`` c2w, ``K``, ``depth`` the view's (metres); ``weights`` each segment's weight (its
        rescaled SAM score; 1 where missing); ``view``: the keyframe index of this view, whose own new
        Gaussians cast no Gaussian-level vote (their label came from these segments), and whose own parts it
        does not hold together (they came from its segments). A view judged again
        (``revisit``: the long-term step's memory views) votes only where it has not yet: for the cells and
        parts made since it was last judged, and the Gaussians made after it, so that no view counts twice
        for anything however often it is revisited."""
        if segments is None or len(gm) == 0:
            return 0
        self.ensure_cells(gm)
        since = self._judged.get(view, (0, 0)) if revisit else (0, 0)
        if view is not None:
            self._judged[view] = (int(self.cell_part.numel()), self.next_part)
        if revisit and since == self._judged[view]:
            return 0  # nothing made since (not counted: a revisit)
        dev = gm.device
        seg = torch.as_tensor(np.ascontiguousarray(segments), device=dev).long()
        pix = visible_pixels(
            gm.means,
            torch.as_tensor(pose, dtype=torch.float32, device=dev),
            torch.as_tensor(K, dtype=torch.float32, device=dev),
            torch.as_tensor(np.ascontiguousarray(depth), dtype=torch.float32, device=dev),
            margin,
        )
        g = torch.nonzero(pix >= 0).squeeze(1)
        n_visible = int(g.numel())
        s = seg.reshape(-1)[pix[g]]
        inside = s > 0
        g, s, px = g[inside], s[inside], pix[g][inside]
        if g.numel() == 0:
            return n_visible
        self.stats.views += 1
        S = int(seg.max()) + 1
        w = torch.ones(S, device=dev)
        for i, v in (weights or {}).items():
            if 0 < int(i) < S:
                w[int(i)] = float(v)
        cell = gm.aux("ev_cell", -1.0)[g].long()
        # a big segment's boundary pixels (spills across an edge)
        ok = ~spill_pixels(seg).reshape(-1)[px]
        # cells: every visible Gaussian (a Gaussian at an edge, in its object's segment in most views, links
        # with its object's cells; an even split links nothing)
        self._observe_cells(cell, gm.labels[g].long(), s, w, since[0], ok)
        # parts and Gaussians: the boundary pixels are left out
        g, s, cell = g[ok], s[ok], cell[ok]
        if g.numel() == 0:
            return n_visible
        n_seg = torch.bincount(s, minlength=S).float()
        mine = (gm.origin_kf[g] == view) if (view is not None and not revisit) else None
        parts = self.parts_of(gm)
        size = torch.bincount(parts[parts >= 0], minlength=self.next_part)
        self._observe_parts(self.cell_part[cell], gm.labels[g].long(), s, n_seg, w, size, since[1], mine)
        self._observe_gaussians(gm, g, s, S, px[ok], seg, view, revisit)
        return n_visible

    def _observe_cells(
        self,
        cell: torch.Tensor,
        lab: torch.Tensor,
        s: torch.Tensor,
        w: torch.Tensor,
        since: int,
        inner: torch.Tensor,
    ) -> None:
        if since and not bool((cell >= since).any()):
            return  # a revisit votes for the cells made since only, and sees none of them
        n_cell = torch.bincount(cell, minlength=int(self.cell_part.numel()))
        top, cnt = _majority(cell, s, int(self.cell_part.numel()))
        c = torch.nonzero((cnt >= CELL_MIN) & (2 * cnt > n_cell)).squeeze(1)  # a strict majority
        if c.numel() == 0:
            return
        # each judged cell: in its part's anchor segment of this view, or in another segment that the part
        # holds most of (the part falls into two segments here: two objects, or a random cut), or inside a
        # segment of other labels (below; ``inner``: the visible Gaussians off the segments' boundary pixels).
        # At the edge of one it says nothing here (the Gaussians' disputes judge that: a label that ran over
        # into its neighbour). The anchor is the segment of most of the part's oldest visible cells
        # (``ANCHOR``): the largest share of a part that spans two objects is now one of them, now the other,
        # as the view moves; its oldest cells are where it began. Once a decision has grouped the part's
        # cells, it is the segment of most of its largest linked group's visible cells, where the view sees
        # ``ANCHOR`` of them: the cells that one view made are of one age, and the oldest by id lie at one end
        # of the part (a table in front of a sofa that the first view merged with it, anchored at the table in
        # the views that show the table on its own, never put it apart)
        part_of = self.cell_part[cell]
        P, S = self.next_part, int(w.numel())
        pc, sc = self.cell_part[c], top[c]
        order = torch.argsort(pc * (int(c.max()) + 1) + c)  # by part, then by age (cell id)
        po = pc[order]
        start = torch.ones_like(po, dtype=torch.bool)
        start[1:] = po[1:] != po[:-1]
        first = torch.cummax(torch.where(start, torch.arange(po.numel(), device=c.device), 0), 0).values
        oldest = order[torch.arange(po.numel(), device=c.device) - first < ANCHOR]
        anchor, _ = _majority(pc[oldest], sc[oldest], P)
        core = self.cell_core[c]
        anchor_core, _ = _majority(pc[core], sc[core], P)
        seen_core = torch.bincount(pc[core], minlength=P)
        anchor = torch.where(seen_core >= ANCHOR, anchor_core, anchor)
        n_part = torch.bincount(part_of, minlength=P)
        # a segment is the part's when the part's label holds most of it (the label's other parts share it)
        plab, _ = _majority(part_of, lab, P)
        L = int(lab.max()) + 2 if lab.numel() else 1
        held_l = torch.bincount((lab + 1) * S + s, minlength=L * S)  # [label + 1, segment] visible Gaussians
        held_p = torch.bincount(part_of * S + s, minlength=P * S)
        n_seg = torch.bincount(s, minlength=S)

        def held(parts: torch.Tensor, segs: torch.Tensor) -> torch.Tensor:
            pl = plab[parts]
            return torch.where(pl >= 0, held_l[(pl + 1).clamp(min=0) * S + segs], held_p[parts * S + segs])

        own = held(pc, sc) >= MAJOR * n_seg[sc]
        ok = n_part[pc] >= MIN_VISIBLE
        inside = sc == anchor[pc]
        wc = w[sc] * ok
        fresh = c >= since
        # or in another label's segment with most of its visible Gaussians off the segments' edges (not a
        # spill across an edge): a picture that the wall's part took in where its first view merged the two,
        # shown in the segment of the label that the picture's own views gave it. SAM merges it with the wall
        # again in most views; these are the views that show where it belongs
        off_edge = 2 * torch.bincount(cell[inner], minlength=n_cell.numel()) > n_cell  # per cell id
        away = wc * (~inside & (own | off_edge[c]))
        # and, for the apart votes, how much of the part that segment held: an object the part took in is
        # all of its segment; a random cut is a large piece of the part
        votes = torch.stack([wc * inside, away, away * held_p[pc * S + sc].float()], 1)
        self.cell_main.index_add_(0, c[fresh], votes[fresh])
        if c.numel() < 2:
            return
        centre = (self.cell_vox[c].float() + 0.5) * self.cell
        part = self.cell_part[c]  # a part's cells only: the splits judge a part's own cells
        r = max(self.radius, self.cell)
        # a revisit searches only the rows that can hold a pair with a cell made since
        rows = _rows_near(centre, part, c >= since, r) if since else torch.arange(c.numel(), device=c.device)
        nbr, _ = knn(centre, centre[rows], NEIGHBOURS + 1, r, part, part[rows], "same")
        i = rows[:, None].expand_as(nbr)
        keep = (nbr >= 0) & (nbr != i)
        a, b = c[i[keep]], c[nbr[keep]]
        a, b = PairTable.unkey(torch.unique(PairTable.key(a, b)))  # a pair found from both sides counts once
        if since:
            a, b = a[b >= since], b[b >= since]  # b > a: one of them made since
        sa, sb = top[a], top[b]
        same = sa == sb
        pa = self.cell_part[a]
        # apart where both segments are mostly the part's (see above), or where one cell lies in a segment
        # that is mostly the part's and at most 1/SMALL of the other's, and the other cell in the part's
        # anchor segment, off its edge pixels: a light switch that joined a piece of the wall labelled apart
        # (the piece is a minor share of the wall's segment, which is mostly the wall's main label). A cell of
        # an object at the edge of its support's segment (a spill) or in a segment that is not its part's
        # anchor (a cup that SAM cut in two) says nothing here
        own_a, own_b = held(pa, sa) >= MAJOR * n_seg[sa], held(pa, sb) >= MAJOR * n_seg[sb]
        lo, hi = torch.minimum(n_seg[sa], n_seg[sb]), torch.maximum(n_seg[sa], n_seg[sb])
        small = SMALL * lo <= hi
        a_small = n_seg[sa] <= n_seg[sb]
        big = torch.where(a_small, b, a)
        in_anchor = (top[big] == anchor[pa]) & off_edge[big]
        beside = small & torch.where(a_small, own_a, own_b) & in_anchor
        apart = ~same & ((own_a & own_b) | beside)
        wt = torch.minimum(w[sa], w[sb])
        # a view that shows one of the two in a segment at most 1/SMALL of the other's (a light switch's own
        # segment beside the wall's) counts SMALL_APART views apart: SAM absorbs small objects into their
        # support in most frames (the yardstick's separation rule)
        wx = wt * torch.where(small, SMALL_APART, 1.0)
        self.cell_pairs.add(a, b, torch.stack([wt * same, wx * apart, torch.ones_like(wt), wt], 1))

    def _observe_parts(
        self,
        part: torch.Tensor,
        lab: torch.Tensor,
        s: torch.Tensor,
        n_seg: torch.Tensor,
        w: torch.Tensor,
        size: torch.Tensor,
        since: int = 0,
        mine: torch.Tensor | None = None,
    ) -> None:
        """Part pairs of one view (``part``, ``lab``, ``s`` per visible Gaussian; ``size``: each part's
        Gaussians in the map). A part's share of a segment
        is its label's (the parts of one object share the segment that shows it): each of two parts in one
        segment is a real part of it when its label holds ``min_part`` of it, and a view separates two parts
        in two segments where each one's label is the main one of its segment (``MAJOR``). ``mine`` (per
        visible Gaussian, None on a revisit): made by this view; two parts made of its Gaussians alone are
        not held together by it."""
        P, S = self.next_part, int(n_seg.numel())
        n_part = torch.bincount(part, minlength=P)
        top, cnt = _majority(part, s, P)
        judged = (n_part >= MIN_VISIBLE) & (cnt >= CONTAIN * n_part)
        # a part whose main segment holds most of it (not all: SAM cuts a wall at random places) can still be
        # shown apart from another part; only a judged one can be shown with one
        loose = (n_part >= MIN_VISIBLE) & (cnt >= MAJOR * n_part)
        p = torch.nonzero(loose).squeeze(1)
        if p.numel() == 0:
            return
        self.part_touched[p[(p >= since) & judged[p]]] = True
        sp = top[p]
        # each judged part's label (the one most of its visible Gaussians carry) and that label's share of the
        # part's segment; an unlabelled part counts alone
        plab, _ = _majority(part, lab, P)
        lp = plab[p]
        L = int(lab.max()) + 2 if lab.numel() else 1
        held = torch.bincount((lab + 1) * S + s, minlength=L * S).float()
        share = torch.where(lp >= 0, held[(lp + 1) * S + sp], cnt[p].float()) / n_seg[sp]
        self.part_owned[p[(share >= OWN) & (p >= since) & judged[p]]] += 1
        if p.numel() < 2:
            return
        i, j = torch.triu_indices(p.numel(), p.numel(), 1, device=p.device)
        if since:  # (p is sorted: j > i) one of them made since
            keep = p[j] >= since
            i, j = i[keep], j[keep]
        si, sj = sp[i], sp[j]
        both = judged[p[i]] & judged[p[j]]
        same = (si == sj) & both
        if mine is not None:
            # two parts that this view made: its segment made them (a part per piece of it apart in space), so
            # its hold restates that. A first view that merged a cabinet with a piece of the sofa beside it
            # held them once; no later view judged them together, and once the piece went to the sofa's label
            # that one view merged the cabinet into it
            made = torch.bincount(part[mine], minlength=P) == n_part
            same &= ~(made[p[i]] & made[p[j]])
        big = share >= self.min_part
        firm = same & big[i] & big[j]
        # apart: each part's label the main one in its segment. A SAM cut through a wall puts a small piece of
        # it in a segment of its own now and then, but that segment is mostly the rest of the wall; an object
        # that SAM shows on its own is most of its segment
        major = share >= MAJOR
        # or where one is the main part of its segment and the other lies whole in another segment (the
        # yardstick's rule): a nightstand's own segment beside the wall's, which holds a piece of the wall
        # that the map labelled apart from the rest of the wall (a minor part of that segment), separates the
        # two. Both must be judged, so that a random cut through a part, which leaves it in two segments,
        # says nothing
        whole = judged[p[i]] & judged[p[j]]
        apart = (si != sj) & ((major[i] & major[j]) | (whole & (major[i] | major[j])))
        wt = torch.where(same, w[si], torch.minimum(w[si], w[sj]))
        # a view judges two parts as well as it sees the smaller one: SAM absorbs a cup that a far view shows
        # with a few Gaussians into its nightstand, and the views that show it well put it apart
        seen = (n_part[p].float() / CLEAR).clamp(max=1.0)
        well = torch.minimum(seen[i], seen[j])
        # and the firm holds of two parts each seen well: CLEAR of its Gaussians, or most of a smaller part
        # (a book's pieces of a dozen Gaussians, not a table's edge)
        clear = (n_part[p] >= CLEAR) | (n_part[p] >= MAJOR * size[p])
        clear_firm = wt * firm * clear[i] * clear[j]
        wt = wt * well
        vals = torch.stack([wt * firm, wt * (same & ~firm), wt * apart, clear_firm], 1)
        self.part_apart.index_add_(0, p[i], wt * apart).index_add_(0, p[j], wt * apart)
        self.part_pairs.add(p[i], p[j], vals)

    def _observe_gaussians(
        self,
        gm,
        g: torch.Tensor,
        s: torch.Tensor,
        S: int,
        px: torch.Tensor,
        seg: torch.Tensor,
        view: int | None,
        revisit: bool,
    ) -> None:
        lab = gm.labels[g].long()
        labelled = lab >= 0
        L = _n_labels(gm)
        # each label's main segment, and each segment's majority label (over its visible labelled Gaussians)
        main, _ = _majority(lab[labelled], s[labelled], max(L, 1))
        seg_lab, seg_cnt = _majority(s[labelled], lab[labelled], S)
        n_lab = torch.bincount(s[labelled], minlength=S)
        seg_lab = torch.where(2 * seg_cnt > n_lab, seg_lab, torch.full_like(seg_lab, -1))
        vote = seg_lab[s]
        if view is not None:  # the Gaussians the view made itself (or, revisited, those it judged) cast none
            old = (gm.origin_kf[g] > view) if revisit else (gm.origin_kf[g] != view)
            g, s, px, lab, labelled, vote = g[old], s[old], px[old], lab[old], labelled[old], vote[old]
        own = labelled & (main[lab.clamp(min=0)] == s)
        disputed = labelled & ~own & (vote != lab)
        d = torch.nonzero(disputed).squeeze(1)
        disputed[d[near_segment(seg, px[d], main[lab[d]], EDGE)]] = False
        # in a small segment of its own label inside that label's main one: a light switch that the wall's
        # label took in, shown on its own (its cells mix with the wall's, so only its Gaussians can tell).
        # A piece at an object's side (SAM cuts a chair's back off its seat) borders other segments as well
        n_vis = torch.bincount(s, minlength=S)
        m = main[lab.clamp(min=0)].clamp(min=0)
        small = labelled & ~own & (vote == lab) & (SMALL * n_vis[s] <= n_vis[m])
        if bool(small.any()):
            border = segment_borders(seg, S)
            inside = border[s, m]
            small &= (inside > 0) & (2 * inside >= border[s].sum(1))
        gm.aux("ev_small").index_add_(0, g[small], torch.ones(int(small.sum()), device=g.device))
        gm.aux("ev_small_seg").index_add_(0, g[small], n_vis[s[small]].float())
        gm.aux("ev_own").index_add_(0, g[own], torch.ones(int(own.sum()), device=g.device))
        gm.aux("ev_disputed").index_add_(0, g[disputed], torch.ones(int(disputed.sum()), device=g.device))
        # one candidate label each (Misra-Gries) of the segments the views put a Gaussian in: an unlabelled
        # one's for the fill, a disputed one's for Algorithm 1 (``disputed_labels``)
        u = vote >= 0
        gu, v = g[u], vote[u].float()
        cand, n = gm.aux("ev_cand", -1.0), gm.aux("ev_cand_n")
        c, k = cand[gu], n[gu]
        agree = c == v
        take = ~agree & (k <= 0)
        cand[gu] = torch.where(take, v, c)
        n[gu] = torch.where(agree | take, k + 1, k - 1)

    # ------------------------------------------------------------------ Gaussian level
    def disputed_ratio(self, gm) -> torch.Tensor:
        """[N] the share of a Gaussian's judged views that disputed its label (0 with fewer than
        ``min_views`` judged views)."""
        d, o = gm.aux("ev_disputed"), gm.aux("ev_own")
        seen = d + o
        return torch.where(seen >= self.min_views, d / seen.clamp(min=1), torch.zeros_like(seen))

    def disputed(self, gm) -> torch.Tensor:
        """[N] bool: labelled Gaussians whose views disputed their label (``DISPUTE`` of at least
        ``min_views``)."""
        return (self.disputed_ratio(gm) >= DISPUTE) & (gm.labels >= 0)

    def disputed_labels(self, gm, disputed: torch.Tensor | None = None) -> torch.Tensor:
        """[N] int64: for the disputed Gaussians (``disputed``, as :meth:`disputed` gives it, computed when
        not passed), the label the views most often put them in (their candidate, where it still exists and
        is not their own); -1 elsewhere."""
        c, ok = _candidates(gm)
        ok &= (self.disputed(gm) if disputed is None else disputed) & (c != gm.labels.long())
        return torch.where(ok, c, torch.full_like(c, -1))

    def restart_votes(self, gm, rows: torch.Tensor) -> None:
        """The Gaussian-level votes of ``rows`` ([N] bool: Gaussians whose label just changed) start afresh:
        they were cast about the former label. Kept, they would dispute the new one as well (a Gaussian at a
        bottle's foot that the views disputed as the bottle's, in the table's segment, would count as
        disputed as the table's too, and each refinement would move it to the other label)."""
        for name in ("ev_own", "ev_disputed", "ev_small", "ev_small_seg"):
            gm.aux(name)[rows] = 0.0

    def lower_disputed(self, gm) -> int:
        """Eq. 16's decrease for disputed Gaussians, by their share of disputing views (in place). Returns
        how many."""
        r = self.disputed_ratio(gm)
        low = self.disputed(gm)
        conf = gm.confidences
        conf[low] = (conf[low] - r[low] * conf[low]).clamp(0.0, 1.0)
        n = int(low.sum())
        self.stats.lowered += n
        return n

    # ------------------------------------------------------------------ decide
    def decide(self, gm) -> dict[str, int]:
        """Split parts, group parts into labels, relabel and fill (in place on ``gm.labels`` /
        ``gm.confidences``; see the module docstring). Returns counts."""
        out = {"part_splits": 0, "relabelled_parts": 0, "relabelled_gaussians": 0, "new_labels": 0,
               "filled": 0}  # fmt: skip
        if len(gm) == 0:
            return out
        self.ensure_cells(gm)
        out["part_splits"] = self._split_parts(gm) + self._split_small(gm)
        parts = self.parts_of(gm)
        has = parts >= 0
        # each part's former label: the one most of its Gaussians carry (-1: mostly unlabelled)
        old, _ = _majority(parts[has], gm.labels[has].long(), max(self.next_part, 1))
        mass = torch.bincount(parts[has], minlength=self.next_part)
        group = self._group_parts(old, mass)
        out.update(self._relabel(gm, parts, old, group))
        out["filled"] = self._fill(gm)
        self.part_touched.zero_()
        for k, v in out.items():
            setattr(self.stats, k, getattr(self.stats, k) + v)
        return out

    def _split_parts(self, gm) -> int:
        """Step 1: cells of a touched part that the views keep apart from the rest of it become parts."""
        if len(self.cell_pairs) == 0:
            return 0
        a, b = self.cell_pairs.pairs()
        pa, pb = self.cell_part[a], self.cell_part[b]
        inside = (pa == pb) & self.part_touched[pa]
        if not bool(inside.any()):
            return 0
        a, b = a[inside], b[inside]
        t, x, nv, seen = (self.cell_pairs.vals[inside, i] for i in range(4))
        n_cells = int(self.cell_part.numel())
        # groups of cells linked by their summed statistics: a cell on the edge between two objects, that
        # views give now to one, now to the other, cannot bridge the cut, nor can a few merged pairs
        cell = gm.aux("ev_cell", -1.0).long()
        mass = torch.bincount(cell[cell >= 0], minlength=n_cells).float()
        comp = _agglomerate(n_cells, a, b, t, x, nv, seen, mass)
        st = self._component_votes(comp, mass)

        def clearly_apart(st: dict[str, torch.Tensor]) -> torch.Tensor:
            # put apart from the anchor in about two views, and in ``split_ratio`` of the component's views
            ap = st["apart"]
            return (ap >= SPLIT_VIEWS) & (ap >= self.split_ratio * (ap + st["together"]))

        # an object that its first view merged with its support is often linked in pieces only (each cell
        # judged by few views, at a sparse sampling): neighbouring pieces that the views put apart from the
        # part's anchor, and that the views hold together more often than apart, are one candidate, judged
        # whole (a fragment alone holds less than the segments that separate it, and would look like a cut);
        # so are the pieces of a sparsely sampled object, near each other but linked by no pair
        cand = clearly_apart(st)
        joined = self._join_candidates(comp, cand, st["size"], a, b, t, x, mass)
        if joined is not None:
            comp = joined
            st = self._component_votes(comp, mass)
        comp_mass, together, apart = st["mass"], st["together"], st["apart"]
        comp_part = torch.full((n_cells,), -1, dtype=torch.long, device=self.device)
        comp_part[comp] = self.cell_part
        present = (comp_mass > 0) & (comp_part >= 0)
        put_apart = clearly_apart(st)
        best = torch.full((self.next_part,), -1.0, device=self.device)
        best.scatter_reduce_(0, comp_part[present], comp_mass[present], reduce="amax")
        is_main = (comp_mass >= best[comp_part.clamp(min=0)]) & (comp_part >= 0)
        # a component of a few Gaussians counts as TINY in the two tests below: its segment of a few pixels
        # also holds the support's Gaussians just behind the object (within the depth margin), and one
        # Gaussian that a few views cut off a bottle of nine is a cut, not a cup
        counted = comp_mass.clamp(min=TINY)
        # the segments that put it apart held about the component itself, not a larger piece of its part:
        # SAM cuts a floor at random places, each time another piece; an object is its segment every time
        coherent = st["size"] <= COHERE * counted
        part_mass = torch.zeros(self.next_part, device=self.device)
        part_mass.index_add_(0, comp_part[present], comp_mass[present])
        coherent |= self._coherent_together(put_apart & present, comp_part, comp_mass, st["size"], counted,
                                            part_mass)  # fmt: skip
        # a component that is small beside the rest of its part (a light switch in the wall's part, a cup in
        # the table's) splits on the views that showed it apart, however many absorbed it: SAM merges small
        # objects into their support in most frames, so those frames say little (the yardstick's rule)
        small = SMALL * counted <= part_mass[comp_part.clamp(min=0)]
        go = coherent & (put_apart | (small & (apart >= SPLIT_VIEWS)))
        # a part keeps the components that stay; if none would, its largest
        stays = torch.zeros(self.next_part, dtype=torch.bool, device=self.device)
        live = present & self.part_touched[comp_part.clamp(min=0)]
        stays[comp_part[live & ~go]] = True
        go &= live & (stays[comp_part.clamp(min=0)] | ~is_main)
        # the part's largest component may tie with another: one of them stays (the smaller id)
        go_ids = torch.nonzero(go).squeeze(1)
        # the largest group of each judged part anchors its views until the next decision (a part that loses
        # it has no core, and its oldest cells anchor it again)
        judged_part = self.part_touched[self.cell_part]
        self.cell_core[judged_part] = is_main[comp[judged_part]]
        if go_ids.numel() == 0:
            return 0
        old = comp_part[go_ids]
        new = self.new_parts(int(go_ids.numel()))
        lut = torch.full((n_cells,), -1, dtype=torch.long, device=self.device)
        lut[go_ids] = new
        moved = lut[comp]
        sel = moved >= 0
        self.cell_part[sel] = moved[sel]
        self.cell_main[sel] = 0.0  # their part's main segment is another now
        self.cell_core[sel] = True  # a new part is one linked group
        self._reindex_cells()
        # only a piece that is most of its part is what the views judged as the part: where a part that its
        # first view made over a chair and a floor piece loses the piece, the views that separated the part
        # from the rest of the floor were about the chair as much, and would keep the piece off the floor
        heir = is_main[go_ids] & (comp_mass[go_ids] >= INHERIT * part_mass[old])
        self._inherit(old[heir], new[heir])
        # the new part starts its history with what the cells said about it and its former part (the views
        # that held them in one segment held two real parts of it)
        self.part_pairs.add(new, old, torch.stack([together[go_ids], torch.zeros_like(together[go_ids]),
                                                   apart[go_ids], together[go_ids]], 1))  # fmt: skip
        self.part_touched[new] = True
        return int(go_ids.numel())

    def _split_small(self, gm) -> int:
        """Step 1 at the Gaussians' grain: a part's Gaussians that views showed small (in a small segment of
        their own label, inside the label's main one) in ``SPLIT_VIEWS`` views, within a cell of each other,
        become a part where there are ``TINY`` of them, those segments held about them (``COHERE``) and they
        are small beside their part (``SMALL``): a light switch whose few Gaussians share their cells with
        the wall's. Fewer are a few pixels' segment, which takes in its support's Gaussians behind it (a
        book's spine picks Gaussians of the books beside it). Returns how many parts it made."""
        n_small = gm.aux("ev_small")
        part = self.parts_of(gm)
        rows = torch.nonzero((n_small >= SPLIT_VIEWS) & (gm.labels >= 0) & (part >= 0)).squeeze(1)
        if rows.numel() < TINY:
            return 0
        pr = part[rows]
        comp = connected_clusters(gm.means[rows], pr, self.cell, NEIGHBOURS - 1)  # k counts the point itself
        n_comp = int(comp.max()) + 1
        size = torch.bincount(comp, minlength=n_comp).float()
        votes = torch.zeros(n_comp, device=self.device).index_add_(0, comp, n_small[rows])
        held = torch.zeros(n_comp, device=self.device).index_add_(0, comp, gm.aux("ev_small_seg")[rows])
        comp_part = torch.zeros(n_comp, dtype=torch.long, device=self.device).scatter_(0, comp, pr)
        part_mass = torch.bincount(part[part >= 0], minlength=self.next_part).float()
        go = (size >= TINY) & (held / votes <= COHERE * size) & (SMALL * size <= part_mass[comp_part])
        go_ids = torch.nonzero(go).squeeze(1)
        if go_ids.numel() == 0:
            return 0
        lut = torch.full((n_comp,), -1, dtype=torch.long, device=self.device)
        lut[go_ids] = self.new_parts(int(go_ids.numel()))
        moved = lut[comp] >= 0
        self.assign(gm, rows[moved], lut[comp][moved])
        # the views that showed it small separated it from its former part
        apart = votes[go_ids] / size[go_ids]
        zero = torch.zeros_like(apart)
        self.part_pairs.add(lut[go_ids], comp_part[go_ids], torch.stack([zero, zero, apart, zero], 1))
        self.part_touched[lut[go_ids]] = True
        for name in ("ev_small", "ev_small_seg"):  # they showed it small in its former part
            gm.aux(name)[rows[moved]] = 0.0
        return int(go_ids.numel())

    @staticmethod
    def _coherent_together(
        cand: torch.Tensor,
        comp_part: torch.Tensor,
        mass: torch.Tensor,
        size: torch.Tensor,
        counted: torch.Tensor,
        part_mass: torch.Tensor,
    ) -> torch.Tensor:
        """Per component: a candidate (put apart from its part's anchor, ``cand``) whose segments held more
        than ``COHERE`` times it, but at most ``COHERE`` times the candidates of its part that segments of
        about the same size (within ``COHERE``) put apart, where those stay at most 1/``SMALL`` of the part:
        the pieces of one object that its first view merged with a large part, too far apart to be joined
        (a bookshelf's boards in the floor's part; the segments that put each board apart held them all)."""
        out = torch.zeros_like(cand)
        fail = torch.nonzero(cand & (size > COHERE * counted)).squeeze(1)
        if fail.numel() == 0:
            return out
        # the candidates' mass within a size window of the same part, by binary search over the candidates
        # sorted by (part, size rank): memory and time grow with the candidates, not with fail x candidates
        allc = torch.nonzero(cand).squeeze(1)
        by_size, order = torch.sort(size[allc], stable=True)
        rank = torch.empty_like(order)
        rank[order] = torch.arange(order.numel(), device=order.device)
        stride = order.numel() + 1
        key, at = torch.sort(comp_part[allc] * stride + rank)
        cum = torch.cat([mass.new_zeros(1), torch.cumsum(mass[allc][at], 0)])
        lo = torch.searchsorted(by_size, size[fail] / COHERE)  # COHERE * s_a >= s_f
        hi = torch.searchsorted(by_size, size[fail] * COHERE, right=True)  # s_a <= COHERE * s_f
        base = comp_part[fail] * stride
        joint = cum[torch.searchsorted(key, base + hi)] - cum[torch.searchsorted(key, base + lo)]
        out[fail] = (size[fail] <= COHERE * joint) & (SMALL * joint <= part_mass[comp_part[fail]])
        return out

    def _join_candidates(
        self,
        comp: torch.Tensor,
        cand: torch.Tensor,
        size: torch.Tensor,
        a: torch.Tensor,
        b: torch.Tensor,
        t: torch.Tensor,
        x: torch.Tensor,
        mass: torch.Tensor,
    ) -> torch.Tensor | None:
        """Candidate groups (``cand`` per component) judged as one: a new component per cell, or None where
        none join. Neighbouring candidates (a cell pair ``a``, ``b`` between them) join where the views held
        the pair together more often than apart (``t`` > ``x``). Far views sample an object sparsely (a
        bookshelf's cells 10 cm apart), and its pieces are often not neighbours at all: candidates of one
        part within ``SPARSE_REACH`` of each other join too, nearest first, where their segments hold more
        than ``COHERE`` * ``TINY`` of the part (``size``; a small object's segment takes in the support just
        behind it, and a piece of the support would join it: a cup and its nightstand), unless a pair of
        their cells was held apart at least as often as together, and only while the joined group stays at
        most 1/``SMALL`` of its part (a larger one is a surface cut at the same place in most views)."""
        n_cells = int(comp.numel())
        pair = cand[comp[a]] & cand[comp[b]] & (comp[a] != comp[b])
        grow = pair & (t > x)
        ga, gb = comp[a[grow]], comp[b[grow]]
        wide = cand & (size > COHERE * TINY)
        na, nb = self._near_candidates(comp, wide, SPARSE_REACH * max(self.radius, self.cell))
        if na.numel():
            held_apart = pair & (x > 0) & (x >= t)
            na, nb = _cannot_link_join(ga, gb, na, nb, comp[a[held_apart]], comp[b[held_apart]])
        if ga.numel() == 0 and na.numel() == 0:
            return None
        joined = _components(n_cells, torch.cat([ga, na]), torch.cat([gb, nb]))[comp]
        if na.numel():
            own = _components(n_cells, ga, gb)[comp] if ga.numel() else comp
            jm = torch.zeros(n_cells, device=self.device).index_add_(0, joined, mass)
            pm = torch.zeros(self.next_part, device=self.device).index_add_(0, self.cell_part, mass)
            big = SMALL * jm[joined] > pm[self.cell_part]
            joined = torch.unique(torch.where(big, own + n_cells, joined), return_inverse=True)[1]
        return joined

    def _near_candidates(
        self, comp: torch.Tensor, cand: torch.Tensor, reach: float
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Pairs of candidate components (``cand`` per component) of one judged part whose cells lie within
        ``reach`` of each other, the nearest pairs first."""
        lc = torch.nonzero(self.part_touched[self.cell_part] & cand[comp]).squeeze(1)
        if lc.numel() < 2:
            return lc[:0], lc[:0]
        centre = (self.cell_vox[lc].float() + 0.5) * self.cell
        pt = self.cell_part[lc]
        nbr, dist = knn(centre, centre, NEIGHBOURS + 1, reach, pt, pt, "same")
        i = torch.arange(lc.numel(), device=lc.device)[:, None].expand_as(nbr)
        ok = nbr >= 0
        na, nb, d = comp[lc[i[ok]]], comp[lc[nbr[ok]]], dist[ok]
        keep = na != nb
        order = torch.argsort(d[keep], stable=True)
        return na[keep][order], nb[keep][order]

    def _component_votes(self, comp: torch.Tensor, mass: torch.Tensor) -> dict[str, torch.Tensor]:
        """Per component of cells (``comp`` per cell; ``mass`` Gaussians per cell): its Gaussians, its cells'
        views in (``together``) and apart from (``apart``) their part's anchor segment per judged cell, and
        how much of the part the segments that put it apart held on average (``size``)."""
        n_cells = int(comp.numel())
        judged = self.cell_main[:, :2].sum(1) > 0
        votes = torch.zeros((n_cells, 3), device=self.device).index_add_(0, comp, self.cell_main)
        n_judged = torch.zeros(n_cells, device=self.device).index_add_(0, comp, judged.float()).clamp(min=1)
        return {
            "mass": torch.zeros(n_cells, device=self.device).index_add_(0, comp, mass),
            "together": votes[:, 0] / n_judged,
            "apart": votes[:, 1] / n_judged,
            "size": votes[:, 2] / votes[:, 1].clamp(min=1e-9),
        }

    def _inherit(self, old: torch.Tensor, new: torch.Tensor) -> None:
        """A part's largest component that leaves it (only smaller pieces stayed, with the anchor) and holds
        ``INHERIT`` of it is most of what the views judged: the new part takes over the old part's statistics
        with every other part."""
        if old.numel() == 0 or len(self.part_pairs) == 0:
            return
        lut = torch.full((self.next_part,), -1, dtype=torch.long, device=self.device)
        lut[old] = new
        a, b = self.part_pairs.pairs()
        vals = self.part_pairs.vals
        la, lb = lut[a], lut[b]
        for keep, x, y in ((la >= 0, la, b), (lb >= 0, a, lb)):
            keep &= (x != y) & ((la < 0) | (lb < 0))
            if bool(keep.any()):
                self.part_pairs.add(x[keep], y[keep], vals[keep].clone())
        self.part_owned[new] = self.part_owned[old]
        self.part_apart[new] = self.part_apart[old]

    def _group_parts(self, part_label: torch.Tensor, part_mass: torch.Tensor) -> torch.Tensor:
        """Step 2: a group id per part. Each label's parts start as one group; a part that the views separate
        from the rest of its label leaves it (the smallest such part first, then the rest is judged again);
        then groups merge greedily, the most firmly held first, with the merge test on their summed
        statistics. A part no view judged stays with its label."""
        n = self.next_part
        dev = self.device
        if n == 0:
            return torch.zeros(0, dtype=torch.long, device=dev)
        lab = part_label.clone()
        lab[part_mass <= 0] = -1
        # each label's largest part roots its group
        L = int(lab.max()) + 1 if bool((lab >= 0).any()) else 0
        big = torch.full((max(L, 1),), -1.0, device=dev)
        has = lab >= 0
        big.scatter_reduce_(0, lab[has], part_mass[has].float(), reduce="amax")
        ids = torch.arange(n, device=dev)
        is_big = has & (part_mass.float() >= big[lab.clamp(min=0)])
        first = torch.full((max(L, 1),), n, dtype=torch.long, device=dev)
        first.scatter_reduce_(0, lab[is_big], ids[is_big], reduce="amin")
        root = torch.where(has, first[lab.clamp(min=0)], ids)
        if len(self.part_pairs) == 0:
            return root
        a, b = self.part_pairs.pairs()
        vals = self.part_pairs.vals
        # 1. parts that leave their label: each part's statistics with the rest of its label
        inner = (lab[a] == lab[b]) & (lab[a] >= 0)
        rest = torch.zeros((n, vals.shape[1]), device=dev)
        rest.index_add_(0, a[inner], vals[inner]).index_add_(0, b[inner], vals[inner])
        sep = (rest[:, 2] > 0) & (rest[:, 2] > self.separation * rest[:, 0])
        for label in torch.unique(lab[sep]).tolist():
            root = self._detach(label, lab, part_mass, a, b, vals, root)
        return self._merge_groups(root, a, b, vals)

    def _merge_groups(
        self, root: torch.Tensor, a: torch.Tensor, b: torch.Tensor, vals: torch.Tensor
    ) -> torch.Tensor:
        """Step 2's merges: the groups' (``root`` per part) summed statistics over the part pairs (a, b,
        ``vals``), merged greedily, the most firmly held first, in Python (a few hundred groups); returns
        each part's group."""
        n = self.next_part
        dev = self.device
        ra, rb = root[a], root[b]
        cross = ra != rb
        keys, gv = PairTable.summed(ra[cross], rb[cross], vals[cross])
        ga, gb = (x.tolist() for x in PairTable.unkey(keys))
        own_t = torch.zeros(n, dtype=torch.bool, device=dev)
        own_t[root[self.part_apart[:n] > 0]] = True  # a group that some view showed apart from anything
        owned = own_t.tolist()
        group_adj: dict[int, dict[int, np.ndarray]] = {}
        heap = []
        for i, j, v in zip(ga, gb, gv.cpu().numpy().astype(np.float64)):
            group_adj.setdefault(i, {})[j] = v
            group_adj.setdefault(j, {})[i] = v
            if self._mergeable(v, owned[i] and owned[j]):
                heap.append((-self._score(v), i, j))
        heapq.heapify(heap)
        sets = DisjointSets()
        find = sets.find
        while heap:
            neg, i, j = heapq.heappop(heap)
            ri, rj = find(i), find(j)
            if ri == rj:
                continue
            v = group_adj.get(ri, {}).get(rj)
            if v is None or not self._mergeable(v, owned[ri] and owned[rj]):
                continue
            sc = self._score(v)
            if sc < -neg - 1e-9:  # stale: the groups changed since it was pushed
                heapq.heappush(heap, (-sc, ri, rj))
                continue
            if len(group_adj.get(ri, {})) < len(group_adj.get(rj, {})):
                ri, rj = rj, ri
            sets.attach(rj, ri)
            owned[ri] = owned[ri] or owned[rj]
            dri = group_adj.setdefault(ri, {})
            for k, vk in group_adj.pop(rj, {}).items():
                if k == ri:
                    continue
                dk = group_adj[k]
                del dk[rj]
                acc = dri[k] + vk if k in dri else vk
                dri[k] = acc
                dk[ri] = acc
                if self._mergeable(acc, owned[ri] and owned[k]):
                    heapq.heappush(heap, (-self._score(acc), ri, k))
            dri.pop(rj, None)
        if not sets:
            return root
        top = torch.tensor([find(x) for x in range(n)], dtype=torch.long, device=dev)
        return top[root]

    def _detach(
        self,
        label: int,
        lab: torch.Tensor,
        mass: torch.Tensor,
        a: torch.Tensor,
        b: torch.Tensor,
        vals: torch.Tensor,
        root: torch.Tensor,
    ) -> torch.Tensor:
        """The parts of ``label`` that the views separate from the rest of it, one by one (the smallest
        first, then the rest judged again), each its own group in ``root`` (returned)."""
        ms = torch.nonzero(lab == label).squeeze(1)
        m = int(ms.numel())
        pos = torch.full((int(lab.numel()),), -1, dtype=torch.long, device=lab.device)
        pos[ms] = torch.arange(m, device=lab.device)
        inner = (pos[a] >= 0) & (pos[b] >= 0)
        mat = torch.zeros((m, m, vals.shape[1]), device=lab.device)
        mat[pos[a[inner]], pos[b[inner]]] = vals[inner]
        mat = mat + mat.transpose(0, 1)
        stay = torch.ones(m, dtype=torch.bool, device=lab.device)
        size = mass[ms].float()
        while int(stay.sum()) > 1:
            rest = (mat * stay[None, :, None]).sum(1)
            out = stay & (rest[:, 2] > 0) & (rest[:, 2] > self.separation * rest[:, 0])
            if not bool(out.any()):
                break
            x = int(torch.argmin(torch.where(out, size, torch.full_like(size, float("inf")))))
            stay[x] = False
            root[ms[x]] = ms[x]
        keep = ms[stay]
        root[keep] = keep[int(torch.argmax(size[stay]))]
        return root

    def _mergeable(self, v: np.ndarray, owners: bool = False) -> bool:
        """``merge_test`` on the summed statistics v (firm, weak, apart, clear firm) of two groups."""
        return bool(merge_test(float(v[0]), float(v[1]), float(v[2]), owners, self.separation, float(v[3])))

    @staticmethod
    def _score(v: np.ndarray) -> float:
        return float(v[0]) + 1e-3 * float(v[1])

    def _relabel(self, gm, parts: torch.Tensor, old: torch.Tensor, group: torch.Tensor) -> dict[str, int]:
        """Step 3: label ids for the groups, and the Gaussians of parts whose group's label changed."""
        out = {"relabelled_parts": 0, "relabelled_gaussians": 0, "new_labels": 0}
        has = parts >= 0
        if not bool(has.any()):
            return out
        P = self.next_part
        lab = gm.labels.long()
        present = old > -2
        mass = torch.bincount(group[parts[has]], minlength=P)  # per group
        L = _n_labels(gm)

        def counts(rows: torch.Tensor):
            """(group, label, Gaussians) of the labelled Gaussians ``rows``."""
            k, c = torch.unique(group[parts[rows]] * L + lab[rows], return_counts=True)
            return zip((k // L).tolist(), (k % L).tolist(), c.tolist())

        def holders(rows: torch.Tensor) -> dict[int, tuple[int, int]]:
            """Per label: (Gaussians, -group) of the group holding most of its Gaussians among ``rows``."""
            best: dict[int, tuple[int, int]] = {}
            for gg, ll, cc in counts(rows):
                best[ll] = max(best.get(ll, (0, 1)), (cc, -gg))
            return best

        labelled = has & (lab >= 0)
        votes: dict[int, list[tuple[int, int]]] = {}  # per group: (Gaussians, label) of its labelled ones
        for gg, ll, cc in counts(labelled):
            votes.setdefault(gg, []).append((cc, ll))
        holder = holders(labelled)
        # a label that parts made by segments carry is held where most of those parts' Gaussians are: a strip
        # outside every segment, over a vase and the objects around it, that holds more of the vase's label
        # than the vase's own part does not take it from the vase
        made = labelled & ~self.part_unsegmented[parts.clamp(min=0)]
        if bool(made.any()):
            holder.update(holders(made))
        owned = torch.zeros(P, device=self.device).index_add_(0, group, self.part_owned)
        groups = torch.unique(group[present]).tolist()
        groups.sort(key=lambda x: -int(mass[x]))
        taken: set[int] = set()
        label_of = torch.full((P,), -1, dtype=torch.long, device=self.device)
        fresh: list[int] = []
        for gg in groups:
            choice = -1
            # the group's most frequent label, or the next that it holds most of: not a few Gaussians of
            # another object's label (a wall piece whose own label a larger piece kept took the cabinet's)
            for k, (_, ll) in enumerate(sorted(votes.get(gg, []), reverse=True)):
                if ll not in taken and (k == 0 or holder[ll][1] == -gg):
                    choice = ll
                    break
            if choice < 0 and (votes.get(gg) or owned[gg] >= 1):
                fresh.append(gg)
                continue
            if choice >= 0:
                taken.add(choice)
                label_of[gg] = choice
        if fresh:
            ids = gm.new_labels(len(fresh)).long()
            label_of[torch.tensor(fresh, dtype=torch.long, device=self.device)] = ids
            out["new_labels"] = len(fresh)
        new = label_of[group]
        change = present & (new != old) & ((new >= 0) | (old >= 0))
        # a part whose group has no label keeps its Gaussians' labels
        change &= new >= 0
        if not bool(change.any()):
            return out
        pg = torch.where(has, parts, torch.zeros_like(parts))
        move = has & change[pg] & (lab == old[pg])
        gm.labels[move] = new[pg][move].to(gm.labels.dtype)
        gm.confidences[move & (lab < 0)] = 0.5  # filled: as Algorithm 1's individual level does
        self.restart_votes(gm, move)
        out["relabelled_parts"] = int(change.sum())
        out["relabelled_gaussians"] = int(move.sum())
        return out

    def _fill(self, gm) -> int:
        """Step 4: unlabelled Gaussians take the label their segments voted for, where it still exists."""
        c, ok = _candidates(gm)
        rows = torch.nonzero((gm.labels < 0) & ok).squeeze(1)
        gm.labels[rows] = c[rows].to(gm.labels.dtype)
        gm.confidences[rows] = 0.5
        gm.aux("ev_cand", -1.0)[rows] = -1.0
        gm.aux("ev_cand_n")[rows] = 0.0
        return int(rows.numel())

    # ------------------------------------------------------------------ Algorithm 1's guard
    def separation_test(self, gm):
        """A function ``separated(a, b) -> [M] bool`` for label tensors a, b [M]: whether the views clearly
        separated the parts of label a from those of label b more than they held them firmly together (the
        labels of parts as the map holds them now)."""
        dev = gm.device
        parts = self.parts_of(gm)
        has = (parts >= 0) & (gm.labels >= 0)
        label_of, _ = _majority(parts[has], gm.labels[has].long(), max(self.next_part, 1))
        table = PairTable(4, dev)
        if len(self.part_pairs):
            pa, pb = self.part_pairs.pairs()
            la, lb = label_of[pa], label_of[pb]
            ok = (la >= 0) & (lb >= 0) & (la != lb)
            table.add(la[ok], lb[ok], self.part_pairs.vals[ok])
        sep = self.separation
        # labels with a part that some view showed apart from anything (objects SAM found on their own)
        L = int(gm.labels.max()) + 1 if len(gm) else 1
        owner = torch.zeros(max(L, 1), dtype=torch.bool, device=dev)
        n = self.part_apart.numel()  # label_of has one entry at least, for a model with no part yet
        shown = (label_of[:n] >= 0) & (self.part_apart > 0)
        owner[label_of[:n][shown]] = True

        def separated(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
            v = table.get(a.long(), b.long())
            # the pairs the views judged that the decision would not merge: a clear separation, or two
            # objects found on their own without the firm views to merge them (a cup kept apart from its
            # nightstand, whose confidence its low SAM score keeps low, is not Algorithm 1's to relabel)
            ok = (a >= 0) & (b >= 0) & (a < L) & (b < L)
            both = torch.zeros_like(ok)
            both[ok] = owner[a[ok].long()] & owner[b[ok].long()]
            return (v.sum(1) > 0) & ~merge_test(v[:, 0], v[:, 1], v[:, 2], both, sep, v[:, 3]) & (a != b)

        return separated
