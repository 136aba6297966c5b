r"""The offline yardstick: view consensus of every frame's segments with a separation rule (issue 39).

The mapper decides online, one keyframe after the other; this clusters every frame's segments at once, after
the whole stream, and so tells how much instance accuracy the same segments allow. It is meant to be hard to
beat (docs/consistency.md measures it); the earlier, weaker yardstick (MaskClustering's consensus without a
separation rule) is ``_maskclustering.py`` (``--weak``).

* **Segments** are the mapper's: each frame's segment borders moved onto the depth edges
  (``ogscene3d.segmentation.snap_to_depth_edges``, ``segmentation.depth_snap``).
* **Scene points**: every frame's valid pixels are back-projected and pooled in ``VOXEL`` voxels. A frame
  *sees* the voxels its pixels fall in, and puts a voxel in a mask when all its segmented pixels there are of
  that one segment (else it is on a boundary, seen but in no mask, as MaskClustering's boundary points).
* **Masks** (a segment of one frame: the voxels it holds there) are the nodes; a cluster of masks carries the
  evidence of its masks together (MaskClustering's nodes: its frames and holding masks are its masks', not
  computed again from its voxels). A mask is *seen* in a frame that sees ``SEEN_FRACTION`` of its voxels (or
  ``SEEN_VOXELS``), and *held* by the frame's mask that holds at least ``CONTAIN`` (0.7, rule b) of its
  voxels that lie in some mask there, where the frame put ``SEGMENTED`` of the node's voxels it sees in a
  segment: a frame that left most of a floor unsegmented, and whose refrigerator segment spills over the few
  floor voxels it did segment, does not hold the floor by the refrigerator's segment.
* **Consensus** of two clusters: of the frames that hold both (each by some mask), the share where one mask
  holds both (MaskClustering's view consensus).
* **Under-segmented masks** (MaskClustering's filter): a mask that the other frames clearly split (a second
  mask holds ``SPLIT_PART`` of it) in more than ``SPLIT`` of the frames that see it (``SPLIT_SMALL`` for a
  mask under ``SPLIT_SMALL_VOXELS``) lies over two objects (a first view that merged a refrigerator with the
  floor): it is no node, holds nothing and has no vote.
* **Separation** (rule a): a frame separates two masks when it holds one by a mask that holds at most
  ``APART`` (a fifth) of the other's voxels seen there, and either that mask is small beside the other (at
  most ``SEP_SIZE`` of the other's voxels: a cup's own segment beside the table) or the other is held there
  by a mask of its own (a cabinet's segment beside the floor's). Two clusters are *apart* when at least
  ``SEP_MIN`` frames, and ``SEP_SHARE`` of the frames that hold both, separate a mask of one from a mask of
  the other: SAM merges an object with its support in some views and shows it apart in others, and a random
  cut through a wall separates two of its pieces in few of the views that see both. A frame whose one mask
  holds most of both clusters (each cluster's *main* mask there: the one that holds the most of the voxels
  it sees of the cluster's masks) does not separate them where the masks of each are mostly (the median) of
  ``CUT_VOXELS`` or more: it cut some of their masks, not the two (a random cut through the floor leaves
  masks of both of its clusters on one side and a mask of one on the other).
* **Levels** (:func:`schedule`): at the first threshold of ``THRESHOLDS``, MaskClustering's falling observer
  counts (the ``OBSERVER_PERCENTILES`` of the pairs' shared frames down to ``MIN_VIEWS``), then each further
  threshold at ``MIN_VIEWS``: the cluster pairs whose consensus reaches it are joined, best consensus first,
  never two groups that hold an apart pair (a segment over two objects links each of them; their separation
  keeps them apart).
* **Votes** (rule c): each voxel takes the cluster with the largest score-weighted *share* of views: the
  SAM scores of the views that put it in one of the cluster's masks over those of the views that could have
  (they see the voxel and hold some mask of the cluster), plus ``PRIOR``. A book that a few views show and
  the shelf's views absorb scores near 1 there, the shelf near the absorbing share. A mask that holds
  another cluster apart from its own (a table's segment that absorbed the cup) gives its vote on that
  cluster's voxels to that cluster (``nested``) where at least ``SEP_MIN`` views showed that cluster on its
  own: a view that merged the cup with the table says nothing against it, and a piece that one view cut
  off a vase is no object that the vase's views absorbed.

The result is a labelled point set (voxel means), scored like a map (``_instances.py``); :func:`at_points`
gives its labels at a map's own Gaussians.

    python benchmarks/yardstick.py SCENE_DIR          # instance mIoU and class mIoU of the strong yardstick
    python benchmarks/yardstick.py SCENE_DIR --weak   # the earlier one (MaskClustering without separation)
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

VOXEL = 0.03  # metres
CONTAIN = 0.7  # rule (b): a mask holds a node when it has this share of the node's voxels in masks there
APART = 0.2  # rule (a): ... and it separates it from a node of which it has at most this share
SEEN_FRACTION = 0.3
SEGMENTED = 0.7  # a frame holds a node only where it put this share of the node's voxels it sees in a segment
SEEN_VOXELS = 100
MIN_VIEWS = 3
MIN_MASK_VOXELS = 2
SPLIT = 0.3  # a mask split in more than this share of the frames that see it is under-segmented
# ... a small mask only above this share: a voxel or two that boundary noise moves is a large share of it, and
# a book seen in a few frames would lose its own masks where noise splits one in one view of three
SPLIT_SMALL, SPLIT_SMALL_VOXELS = 0.4, 100
SEP_SIZE: float | None = 0.3
SEP_MIN = 2  # ... in at least this many frames
SEP_SHARE = 0.5  # ... and this share of the frames that hold both
CUT_VOXELS = 100  # a frame that holds most of two clusters of masks mostly this large by one mask cut them
SPLIT_PART = 0.3  # ... where a second mask holds this share of it
THRESHOLDS = (0.9, 0.8, 0.7)
OBSERVER_PERCENTILES = (95, 85, 75, 65, 50)
UNSEGMENTED = -2  # ``Views.mask`` of a voxel whose pixels lie in no segment (-1: a boundary, or a small mask)
PRIOR = 1.0  # rule (c): a cluster's share at a voxel is its votes over (the views that could vote + PRIOR)


def _distinct(x: np.ndarray) -> np.ndarray:
    """``np.unique(x)`` of an int array, by a sort: numpy 2's hash-based plain unique is many times slower
    on the tens of millions of (pair, frame) keys of a long scan (docs/consistency.md has the timing)."""
    x = np.sort(x)
    return x[np.r_[True, x[1:] != x[:-1]]] if x.size else x


def _frames(scene: str | Path, depth_snap: float | None = None) -> list:
    """The scene's frames, their segments' borders moved onto the depth edges as the mapper moves them
    (``depth_snap`` metres; None: the default ``segmentation.depth_snap``; 0: not moved)."""
    from ogscene3d.config import Config
    from ogscene3d.datasets import open_dataset
    from ogscene3d.segmentation import snap_to_depth_edges

    frames = list(open_dataset(scene, kind="synthetic"))
    margin = Config().segmentation.depth_snap if depth_snap is None else depth_snap
    for fr in frames:
        if fr.segments is not None and margin > 0:
            fr.segments = snap_to_depth_edges(fr.segments, fr.depth, margin)
    return frames


@dataclass
class Views:
    """What every frame saw, on the scene's voxels.

    ``points`` [V, 3]: voxel means; per frame ``g``: ``seen[g]`` the voxels it sees and ``mask[g]`` the
    global mask index each lies in (-1: on a boundary; ``UNSEGMENTED``: every pixel there in no segment); per
    mask: ``mask_frame`` and ``mask_score`` (its segment's SAM score)."""

    points: np.ndarray
    seen: list[np.ndarray]
    mask: list[np.ndarray]
    mask_frame: np.ndarray
    mask_score: np.ndarray

    @property
    def n_masks(self) -> int:
        return len(self.mask_frame)


def _backproject(fr) -> tuple[np.ndarray, np.ndarray]:
    """World points [P, 3] of a frame's valid pixels and their segment id [P] (0: none)."""
    d = np.asarray(fr.depth, np.float64)
    vv, uu = np.nonzero((d > 0) & np.isfinite(d))
    K = np.asarray(fr.K, np.float64)
    z = d[vv, uu]
    cam = np.stack([(uu + 0.5 - K[0, 2]) / K[0, 0] * z, (vv + 0.5 - K[1, 2]) / K[1, 1] * z, z], 1)
    pose = np.asarray(fr.pose, np.float64)
    seg = np.zeros(len(z), np.int64) if fr.segments is None else np.asarray(fr.segments, np.int64)[vv, uu]
    return cam @ pose[:3, :3].T + pose[:3, 3], seg


def build_views(frames: list, voxel: float = VOXEL) -> Views:
    """Pool every frame's pixels in voxels and record which mask holds each voxel in each frame."""
    keys, segs, worlds = [], [], []
    for fr in frames:
        world, seg = _backproject(fr)
        keys.append(np.floor(world / voxel).astype(np.int64))
        segs.append(seg)
        worlds.append(world.astype(np.float32))
    if not sum(len(k) for k in keys):
        return Views(np.zeros((0, 3)), [], [], np.zeros(0, np.int64), np.zeros(0))
    cells = np.concatenate(keys)
    lo = cells.min(0)
    span = cells.max(0) - lo + 1
    flat = ((cells[:, 0] - lo[0]) * span[1] + (cells[:, 1] - lo[1])) * span[2] + (cells[:, 2] - lo[2])
    _, vox = np.unique(flat, return_inverse=True)
    vox = vox.reshape(-1)
    nv = int(vox.max()) + 1
    # a voxel's position is the mean of its pixels' points (near the surface, unlike the voxel centre)
    world = np.concatenate(worlds).astype(np.float64)
    counts = np.bincount(vox, minlength=nv).astype(np.float64)
    points = np.stack([np.bincount(vox, weights=world[:, a], minlength=nv) for a in range(3)], 1)
    points /= counts[:, None]
    seen, mask, mframe, mscore = [], [], [], []
    start, n_masks = 0, 0
    for g, fr in enumerate(frames):
        n = len(segs[g])
        v, s = vox[start : start + n], segs[g]
        start += n
        # per voxel of this frame: its one segment, or -1 (none, or two segments: a boundary)
        order = np.lexsort((s, v))
        v, s = v[order], s[order]
        starts = np.nonzero(np.r_[True, v[1:] != v[:-1]])[0]
        uv = v[starts]
        hi_s = np.maximum.reduceat(s, starts)
        lo_pos = np.minimum.reduceat(np.where(s > 0, s, np.iinfo(np.int64).max), starts)
        one = (lo_pos == hi_s) & (hi_s > 0)  # every segmented pixel there is in the same segment
        ids, local = np.unique(np.where(one, hi_s, 0), return_inverse=True)
        per_mask = np.bincount(local, minlength=len(ids))
        keep = (ids > 0) & (per_mask >= MIN_MASK_VOXELS)
        index = np.full(len(ids), -1, np.int64)
        index[keep] = n_masks + np.arange(int(keep.sum()))
        scores = fr.segment_scores or {}
        mframe.append(np.full(int(keep.sum()), g, np.int64))
        mscore.append(np.array([float(scores.get(int(i), 1.0)) for i in ids[keep]]))
        n_masks += int(keep.sum())
        seen.append(uv)
        mask.append(np.where(hi_s <= 0, UNSEGMENTED, index[local]))  # 0 or negative: no segment
    return Views(points, seen, mask, np.concatenate(mframe), np.concatenate(mscore))


def _membership(views: Views, node_of_mask: np.ndarray, n_nodes: int):
    """(voxels x nodes) CSR of 0/1: the voxels of each node (the union of its masks' voxels in their own
    frames), and each node's size."""
    from scipy.sparse import coo_matrix

    rows, cols = [], []
    for g in range(len(views.seen)):
        m = views.mask[g]
        ok = m >= 0
        node = node_of_mask[m[ok]]
        ok2 = node >= 0
        rows.append(views.seen[g][ok][ok2])
        cols.append(node[ok2])
    r, c = np.concatenate(rows), np.concatenate(cols)
    a = coo_matrix((np.ones(len(r), np.float32), (r, c)), shape=(len(views.points), n_nodes)).tocsr()
    a.data[:] = 1.0  # duplicates summed by tocsr: a node holds a voxel once
    return a, np.asarray((a > 0).sum(axis=0)).ravel()


@dataclass
class Holding:
    """Per node and frame: ``held`` the global mask that holds it (-1: none, also when unseen), ``seen``,
    ``n_in`` its voxels that lie in some mask there; and every (node, mask, voxels of the node in it)."""

    held: np.ndarray  # [N, F] int64
    seen: np.ndarray  # [N, F] bool
    n_in: np.ndarray  # [N, F] int32
    split: np.ndarray  # [N, F] bool: seen, and a second mask holds SPLIT_PART of it
    size: np.ndarray  # [N] voxels
    mask_size: np.ndarray  # [masks] voxels of each mask in its own frame
    pair_node: np.ndarray
    pair_mask: np.ndarray
    pair_count: np.ndarray

    def __post_init__(self) -> None:
        self._n_masks = int(self.pair_mask.max(initial=0)) + 1
        key = self.pair_node * self._n_masks + self.pair_mask
        order = np.argsort(key)
        self._key, self._cnt = key[order], self.pair_count[order]

    def count(self, node: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """Voxels of ``node`` that ``mask`` holds (0 where none), for arrays of pairs."""
        if not len(self._key):
            return np.zeros(len(node), np.int64)
        q = node.astype(np.int64) * self._n_masks + mask
        i = np.clip(np.searchsorted(self._key, q), 0, len(self._key) - 1)
        return np.where(self._key[i] == q, self._cnt[i], 0)


def holding(views: Views, node_of_mask: np.ndarray, n_nodes: int) -> Holding:
    """Which mask of each frame holds each node (rule b), from the union of the node's voxels."""
    member, size = _membership(views, node_of_mask, n_nodes)
    F = len(views.seen)
    held = np.full((n_nodes, F), -1, np.int64)
    seen = np.zeros((n_nodes, F), bool)
    n_in = np.zeros((n_nodes, F), np.int32)
    split = np.zeros((n_nodes, F), bool)
    pn, pm, pc = [], [], []
    for g in range(F):
        vox, msk = views.seen[g], views.mask[g]
        sub = member[vox]
        node = sub.indices.astype(np.int64)
        m = np.repeat(msk, np.diff(sub.indptr))
        n_vis = np.bincount(node, minlength=n_nodes)
        in_mask = m >= 0
        n_in[:, g] = np.bincount(node[in_mask], minlength=n_nodes)
        n_seg = n_vis - np.bincount(node[m == UNSEGMENTED], minlength=n_nodes)
        seen[:, g] = (n_vis >= np.minimum(SEEN_FRACTION * size, SEEN_VOXELS)) & (n_vis >= MIN_MASK_VOXELS)
        if not in_mask.any():
            continue
        base = int(m[in_mask].min())
        local = m[in_mask] - base
        k = int(local.max()) + 1
        cnt = np.bincount(node[in_mask] * k + local, minlength=n_nodes * k).reshape(n_nodes, k)
        best = cnt.argmax(1)
        top = cnt[np.arange(n_nodes), best]
        ok = seen[:, g] & (n_in[:, g] > 0) & (top >= CONTAIN * n_in[:, g]) & (n_seg >= SEGMENTED * n_vis)
        held[ok, g] = base + best[ok]
        second = np.partition(cnt, -2, axis=1)[:, -2] if k > 1 else np.zeros(n_nodes, np.int64)
        split[:, g] = seen[:, g] & (n_in[:, g] > 0) & (second >= SPLIT_PART * n_in[:, g])
        nz_n, nz_k = np.nonzero(cnt)
        pn.append(nz_n)
        pm.append(base + nz_k)
        pc.append(cnt[nz_n, nz_k])
    cat = lambda x: np.concatenate(x) if x else np.zeros(0, np.int64)  # noqa: E731
    all_masks = np.concatenate(views.mask)
    mask_size = np.bincount(all_masks[all_masks >= 0], minlength=views.n_masks)
    return Holding(held, seen, n_in, split, size, mask_size, cat(pn), cat(pm), cat(pc))


def _candidate_pairs(h: Holding, n_nodes: int, n_masks: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Node pairs (a < b) that some mask holds together, and in how many frames."""
    from scipy.sparse import coo_matrix, triu

    r, f = np.nonzero(h.held >= 0)
    z = coo_matrix((np.ones(len(r), np.float32), (r, h.held[r, f])), shape=(n_nodes, n_masks)).tocsr()
    s = triu(z @ z.T, k=1).tocoo()
    return s.row.astype(np.int64), s.col.astype(np.int64), s.data.astype(np.int64)


def _observers(h: Holding, a: np.ndarray, b: np.ndarray, chunk: int = 50000) -> np.ndarray:
    """Frames that hold both nodes of each pair (each by some mask)."""
    held = h.held >= 0
    out = np.zeros(len(a), np.int64)
    for s in range(0, len(a), chunk):
        out[s : s + chunk] = (held[a[s : s + chunk]] & held[b[s : s + chunk]]).sum(1)
    return out


def _separating_frames(
    h: Holding, a: np.ndarray, b: np.ndarray, chunk: int = 20000
) -> tuple[np.ndarray, np.ndarray]:
    """(pair index, frame) of every frame that clearly separates a pair (rule a), either way round."""
    hit = []
    for x, y in ((a, b), (b, a)):
        for s in range(0, len(x), chunk):
            xs, ys = x[s : s + chunk], y[s : s + chunk]
            k = h.held[xs]  # the mask holding x in each frame
            look = (k >= 0) & h.seen[ys] & (h.n_in[ys] > 0)
            if SEP_SIZE is not None:  # the mask that holds x is small beside y: a cup's, beside the table
                small = h.mask_size[np.maximum(k, 0)] <= SEP_SIZE * h.size[ys][:, None]
                ky = h.held[ys]  # ... or y has a mask of its own there: a cabinet's beside the floor's
                look &= small | ((ky >= 0) & (ky != k))
            e, g = np.nonzero(look)
            if e.size == 0:
                continue
            share = h.count(ys[e], k[e, g])
            apart = share <= APART * h.n_in[ys[e], g]
            hit.append((s + e[apart]) * h.held.shape[1] + g[apart])
    keys = _distinct(np.concatenate(hit)) if hit else np.zeros(0, np.int64)  # a frame counts once
    F = h.held.shape[1]
    return keys // F, keys % F


class _Union:
    """Union-find over the masks that never joins two groups holding a separated pair: a segment over two
    objects links each of them, and their separation keeps them apart (cannot-links, kept by group root)."""

    def __init__(self, n: int, apart_a: np.ndarray, apart_b: np.ndarray) -> None:
        self.parent = np.arange(n)
        self.cannot: dict[int, set[int]] = {}
        for x, y in zip(apart_a.tolist(), apart_b.tolist()):
            self.cannot.setdefault(x, set()).add(y)
            self.cannot.setdefault(y, set()).add(x)

    def find(self, x: int) -> int:
        p = self.parent
        while p[x] != x:
            p[x] = p[p[x]]
            x = int(p[x])
        return x

    def roots(self) -> np.ndarray:
        return np.array([self.find(x) for x in range(len(self.parent))], np.int64)

    def join(self, x: int, y: int) -> bool:
        ra, rb = self.find(x), self.find(y)
        if ra == rb or rb in self.cannot.get(ra, ()):
            return False
        if len(self.cannot.get(ra, ())) < len(self.cannot.get(rb, ())):
            ra, rb = rb, ra
        self.parent[rb] = ra
        moved = self.cannot.pop(rb, set())
        for z in moved:
            self.cannot[z].discard(rb)
            self.cannot[z].add(ra)
        self.cannot.setdefault(ra, set()).update(moved)
        return True


def undersegmented(h: Holding, views: Views) -> np.ndarray:
    """[masks] bool: masks that other frames clearly split (a second mask holds ``SPLIT_PART`` of them) in
    more than ``SPLIT`` of the frames that see them (``SPLIT_SMALL`` for a small mask): a segment over two
    objects (MaskClustering's under-segmentation filter, with a clear split: a book's few voxels spread by
    boundary noise are not)."""
    own = np.zeros_like(h.seen)
    own[np.arange(views.n_masks), views.mask_frame] = True
    look = h.seen & (h.n_in > 0) & ~own
    share = np.where(h.size < SPLIT_SMALL_VOXELS, SPLIT_SMALL, SPLIT)
    return (look & h.split).sum(1) > share * np.maximum(look.sum(1), 1)


def _drop_masks(h: Holding, drop: np.ndarray) -> None:
    """Masks ``drop`` hold nothing: the frames where they held a node no longer count for it."""
    bad = (h.held >= 0) & drop[np.maximum(h.held, 0)]
    h.held[bad] = -1


@dataclass
class Clusters:
    """The clusters of the masks (``node_of_mask``, -1: an under-segmented mask, left out), the masks'
    holding, and which clusters the views keep apart (``apart``: pairs of cluster ids, smaller first)."""

    node_of_mask: np.ndarray
    holding: Holding
    apart: set[tuple[int, int]]


class _Evidence:
    """The masks' holding and separating frames, summed over the masks of each cluster (MaskClustering's
    nodes: a cluster's frames and holding masks are those of its masks together, not computed again from
    its voxels, where one mask over two objects would make the cluster held nowhere and so never apart)."""

    def __init__(self, views: Views, h: Holding, a: np.ndarray, b: np.ndarray) -> None:
        from scipy.sparse import coo_matrix

        n = views.n_masks
        self.n, self.frames = n, len(views.seen)
        pair, frame = _separating_frames(h, a, b)
        self.sep_a, self.sep_b, self.sep_frame = a[pair], b[pair], frame
        self.mask_frame, self.mask_size = views.mask_frame, h.mask_size
        r, f = np.nonzero(h.held >= 0)
        # each mask's holding masks, weighted by its voxels that lie in some mask of the frame (held: > 0)
        self.z = coo_matrix((h.n_in[r, f].astype(np.float32), (r, h.held[r, f])), shape=(n, n)).tocsr()
        self.y = coo_matrix((np.ones(len(r), np.float32), (r, f)), shape=(n, self.frames)).tocsr()

    def of(self, node: np.ndarray):
        """For clusters ``node`` (per mask, -1: none, ids from 0): their holding masks [C, masks] and frames
        held [C, F] (0/1 CSR), and the pairs apart (two arrays)."""
        from scipy.sparse import coo_matrix

        nc = int(node.max()) + 1 if (node >= 0).any() else 0
        alive = node >= 0
        p = coo_matrix((np.ones(int(alive.sum()), np.float32), (node[alive], np.nonzero(alive)[0])),
                       shape=(nc, self.n)).tocsr()  # fmt: skip
        held, yc = p @ self.z, p @ self.y  # held: [C, masks], the voxels of each cluster each mask holds
        zc = held.copy()
        zc.data[:] = 1.0
        yc.data[:] = 1.0
        ca, cb = node[self.sep_a], node[self.sep_b]
        lo, hi = np.minimum(ca, cb), np.maximum(ca, cb)
        ok = (lo >= 0) & (lo != hi)
        keys = _distinct((lo[ok] * nc + hi[ok]) * self.frames + self.sep_frame[ok])  # a frame counts once
        keys = keys[~self._cut(node, held, keys, nc)]
        pair, count = np.unique(keys // self.frames, return_counts=True)
        pa, pb = pair // max(nc, 1), pair % max(nc, 1)
        apart = (count >= SEP_MIN) & (count >= SEP_SHARE * _shared(yc, pa, pb))
        return zc, yc, pa[apart], pb[apart]

    def _cut(self, node: np.ndarray, held, keys: np.ndarray, nc: int) -> np.ndarray:
        """Per separating (cluster pair, frame) key (``(lo * nc + hi) * frames + frame``): whether the
        frame's one mask holds most of both clusters (the main mask of each, :meth:`_main`), where the
        masks of each cluster are mostly of ``CUT_VOXELS`` or more: the frame cut their masks, not the
        two. (A light switch's cluster that took in one mask of the wall has that mask for its main one.)"""
        F = self.frames
        main_key, main_mask = self._main(held)
        pair, g = keys // F, keys % F
        lo, hi = pair // max(nc, 1), pair % max(nc, 1)

        def main(c: np.ndarray) -> np.ndarray:
            q = c * F + g
            i = np.clip(np.searchsorted(main_key, q), 0, max(len(main_key) - 1, 0))
            return np.where(main_key[i] == q, main_mask[i], -1) if len(main_key) else np.full(len(q), -1)

        a = main(lo)
        median = _median_per(node, self.mask_size, nc)
        return (a >= 0) & (a == main(hi)) & (np.minimum(median[lo], median[hi]) >= CUT_VOXELS)

    def _main(self, held) -> tuple[np.ndarray, np.ndarray]:
        """Each cluster's main mask in each frame that holds it (the mask that holds the most of the voxels
        the frame sees of the cluster's masks, ``held`` [clusters, masks]): sorted keys ``cluster * frames +
        frame`` and their masks."""
        w = held.tocoo()
        key = w.row.astype(np.int64) * self.frames + self.mask_frame[w.col]
        order = np.lexsort((-w.data, key))
        key, mask = key[order], w.col.astype(np.int64)[order]
        first = np.r_[True, key[1:] != key[:-1]] if len(key) else np.zeros(0, bool)
        return key[first], mask[first]


def _median_per(node: np.ndarray, size: np.ndarray, n: int) -> np.ndarray:
    """[n] the (upper) median of ``size`` over the masks of each cluster of ``node`` (-1: none; 0 for an
    empty cluster)."""
    alive = node >= 0
    nd, sz = node[alive], size[alive]
    order = np.lexsort((sz, nd))
    nd, sz = nd[order], sz[order]
    count = np.bincount(nd, minlength=n)
    out = np.zeros(max(n, 1))
    has = np.nonzero(count)[0]
    out[has] = sz[np.searchsorted(nd, has) + count[has] // 2]
    return out


def cluster(views: Views, thresholds: tuple[float, ...] = THRESHOLDS) -> Clusters:
    """Cluster the masks level by level (:func:`schedule`: the pairs that many frames hold first): join the
    pairs whose consensus reaches the level's threshold, best first, never two groups of which one holds a
    cluster apart from one of the other (at least ``SEP_MIN`` frames, and ``SEP_SHARE`` of the frames that
    hold both, separate some mask of one from some mask of the other)."""
    n = views.n_masks
    h = holding(views, np.arange(n), n)
    under = undersegmented(h, views)
    _drop_masks(h, under)
    h.held[under] = -1  # nor are they nodes
    a, b, _ = _candidate_pairs(h, n, n)
    ev = _Evidence(views, h, a, b)
    node = np.where(under, -1, np.arange(n))
    for thr, min_obs in schedule(_observers(h, a, b), thresholds):
        _, node = np.unique(node, return_inverse=True)
        node = node - int(under.any())
        node[under] = -1
        zc, yc, pa, pb = ev.of(node)
        union = _Union(zc.shape[0], pa, pb)
        xa, xb, support = _pairs(zc)
        observers = _shared(yc, xa, xb)
        rate = support / np.maximum(observers, 1)
        ok = (observers >= min_obs) & (rate >= thr)
        ja, jb = xa[ok], xb[ok]
        for e in np.lexsort((-observers[ok], -rate[ok])).tolist():
            union.join(int(ja[e]), int(jb[e]))
        node = np.where(node >= 0, union.roots()[np.maximum(node, 0)], -1)
    _, node = np.unique(node, return_inverse=True)
    node = node - int(under.any())
    node[under] = -1
    _, _, pa, pb = ev.of(node)
    return Clusters(node, h, set(zip(pa.tolist(), pb.tolist())))


def _pairs(zc) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cluster pairs (a < b) that a mask holds together, and how many masks do (one per frame)."""
    from scipy.sparse import triu

    s = triu(zc @ zc.T, k=1).tocoo()
    return s.row.astype(np.int64), s.col.astype(np.int64), s.data.astype(np.int64)


def _shared(yc, a: np.ndarray, b: np.ndarray, chunk: int = 50000) -> np.ndarray:
    """Frames that hold both clusters of each pair."""
    out = np.zeros(len(a), np.int64)
    for s in range(0, len(a), chunk):
        out[s : s + chunk] = np.asarray(yc[a[s : s + chunk]].multiply(yc[b[s : s + chunk]]).sum(1)).ravel()
    return out


def schedule(observers: np.ndarray, thresholds: tuple[float, ...] = THRESHOLDS) -> list[tuple[float, int]]:
    """(consensus, least frames holding both) of each level: at the first threshold, MaskClustering's
    falling observer counts (the ``OBSERVER_PERCENTILES`` of the masks' pairs, then ``MIN_VIEWS``), so that a
    fragment two frames saw joins after the pairs that many frames judged; then each further threshold."""
    counts = observers[observers >= MIN_VIEWS]
    pct = np.percentile(counts, OBSERVER_PERCENTILES).astype(int) if counts.size else []
    steps = [max(MIN_VIEWS, int(c)) for c in pct]
    steps = [*sorted(steps, reverse=True), MIN_VIEWS]
    first = [(thresholds[0], int(m)) for m in dict.fromkeys(steps)]
    return first + [(t, MIN_VIEWS) for t in thresholds[1:]]


def vote(views: Views, clusters: Clusters, nested: bool = True) -> np.ndarray:
    """Each voxel's cluster (-1: no mask of a cluster ever held it): the largest score-weighted share of the
    views that put it in one of the cluster's masks, of those that could have (rule c, :func:`_chances`);
    with ``nested``, see :func:`_nested`."""
    node_of_mask = clusters.node_of_mask
    nv = len(views.points)
    n = int(node_of_mask.max()) + 1 if len(node_of_mask) else 0
    vox, msk, frame = [], [], []
    for g in range(len(views.seen)):
        m = views.mask[g]
        ok = m >= 0
        ok[ok] = node_of_mask[m[ok]] >= 0  # an under-segmented mask has no vote
        vox.append(views.seen[g][ok])
        msk.append(m[ok])
        frame.append(np.full(int(ok.sum()), g, np.int64))
    vox, msk, frame = (np.concatenate(x) for x in (vox, msk, frame))
    clu, w = node_of_mask[msk], views.mask_score[msk]
    if nested and n:
        clu = _nested(clusters, vox, msk, frame, clu, len(views.seen))
    key = vox * max(n, 1) + clu
    uk, inv = np.unique(key, return_inverse=True)
    total = np.bincount(inv, weights=w)
    kv, kc = uk // max(n, 1), uk % max(n, 1)
    total = total / (_chances(views, clu, frame, w, kv, kc, n) + PRIOR)
    order = np.lexsort((-total, kv))
    first = np.r_[True, kv[order][1:] != kv[order][:-1]]
    out = np.full(nv, -1, np.int64)
    out[kv[order][first]] = kc[order][first]
    return out


def _chances(views: Views, clu, frame, w, kv, kc, n: int) -> np.ndarray:
    """Per (voxel ``kv``, cluster ``kc``): the score-weighted views that could have put the voxel in the
    cluster: those that see the voxel and hold some mask of the cluster (weight: its best mask's score)."""
    from scipy.sparse import coo_matrix

    F = len(views.seen)
    key = _distinct(clu.astype(np.int64) * F + frame)
    best = np.zeros(len(key))
    np.maximum.at(best, np.searchsorted(key, clu.astype(np.int64) * F + frame), w)
    yc = coo_matrix((best, (key // F, key % F)), shape=(max(n, 1), F)).tocsr()
    r = np.concatenate(views.seen)
    c = np.concatenate([np.full(len(v), g, np.int64) for g, v in enumerate(views.seen)])
    sv = coo_matrix((np.ones(len(r), np.float32), (r, c)), shape=(len(views.points), F)).tocsr()
    out = np.zeros(len(kv))
    for s in range(0, len(kv), 50000):
        out[s : s + 50000] = np.asarray(sv[kv[s : s + 50000]].multiply(yc[kc[s : s + 50000]]).sum(1)).ravel()
    return out


def _nested(clusters: Clusters, vox, msk, frame, clu, n_frames: int) -> np.ndarray:
    """The votes' clusters, where a mask held a mask of a cluster that the views separate from the holding
    mask's own (the table's segment that absorbed the cup): on the voxels the held cluster's own masks
    cover, the vote goes to it (the smallest such cluster), as that view merged the two and says nothing
    against it; only to a cluster whose masks come from at least ``SEP_MIN`` views."""
    node_of_mask, h = clusters.node_of_mask, clusters.holding
    m, g = np.nonzero(h.held >= 0)
    k = h.held[m, g]
    c, holder = node_of_mask[m], node_of_mask[k]
    keep = (c >= 0) & (holder >= 0) & (c != holder)
    m, g, k, c, holder = m[keep], g[keep], k[keep], c[keep], holder[keep]
    if m.size == 0:
        return clu
    apart = clusters.apart
    n = int(node_of_mask.max()) + 1
    # an object that at least SEP_MIN views showed on their own, not a piece that one view cut off a vase
    views_of = np.bincount(_distinct(clu.astype(np.int64) * n_frames + frame) // n_frames, minlength=n)
    keep = np.array([(min(x, y), max(x, y)) in apart for x, y in zip(c.tolist(), holder.tolist())], bool)
    keep &= views_of[c] >= SEP_MIN
    g, k, c = g[keep], k[keep], c[keep]
    uniq = np.unique(np.stack([c, g, k], 1), axis=0)
    if uniq.size == 0:
        return clu
    c, g, k = uniq[:, 0], uniq[:, 1], uniq[:, 2]
    # each cluster's own voxels (a CSR over clusters)
    nv = int(vox.max()) + 1
    own = _distinct(clu.astype(np.int64) * nv + vox)
    own_c, own_v = own // nv, own % nv
    ptr = np.searchsorted(own_c, np.arange(n + 1))
    # candidate votes: (own voxel of c, frame g) where mask k held c
    lens = ptr[c + 1] - ptr[c]
    row = np.repeat(np.arange(len(c)), lens)
    at = np.arange(int(lens.sum())) - np.repeat(np.cumsum(lens) - lens, lens) + np.repeat(ptr[c], lens)
    cand_v, cand_g, cand_k, cand_c = own_v[at], g[row], k[row], c[row]
    key = vox * n_frames + frame
    order = np.argsort(key)
    skey = key[order]
    q = cand_v * n_frames + cand_g
    pos = np.clip(np.searchsorted(skey, q), 0, len(skey) - 1)
    hit = (skey[pos] == q) & (msk[order[pos]] == cand_k)
    out = clu.copy()
    size = np.diff(ptr)
    sel = np.nonzero(hit)[0]
    sel = sel[np.argsort(-size[cand_c[sel]], kind="stable")]  # larger first, the smallest overwrites
    out[order[pos[sel]]] = cand_c[sel]
    return out


def strong_consensus(frames: list) -> tuple[np.ndarray, np.ndarray]:
    """Labelled voxel means [V, 3] and their cluster [V] (-1: never in a mask) of the strong yardstick."""
    views = build_views(frames)
    if views.n_masks == 0:
        return views.points, np.full(len(views.points), -1, np.int64)
    return views.points, vote(views, cluster(views))


def at_points(points: np.ndarray, labels: np.ndarray, query: np.ndarray) -> np.ndarray:
    """The yardstick's labels at other points: each of ``query`` [Q, 3] (a map's Gaussians) takes the label
    of its nearest voxel mean of ``points`` [V, 3], so that a map is compared with the yardstick at the map's
    own points (the voxels outnumber a map's Gaussians several times, and a small object's by as much)."""
    from ogscene3d.eval.protocols import nearest_neighbors

    if len(points) == 0:
        return np.full(len(query), -1, np.int64)
    _, j = nearest_neighbors(points, query, k=1)
    return np.asarray(labels)[j[:, 0]]


def main(argv: list[str] | None = None) -> int:
    from _instances import class_miou, instance_scores

    from ogscene3d.eval.readers import load_ground_truth

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene", type=Path, help="a synthetic scene folder (ogscene3d synth)")
    ap.add_argument("--weak", action="store_true", help="the earlier yardstick (_maskclustering.py)")
    args = ap.parse_args(argv)
    frames = _frames(args.scene)
    if args.weak:
        from _maskclustering import view_consensus

        pts, lab = view_consensus(frames)
    else:
        pts, lab = strong_consensus(frames)
    gt = load_ground_truth(args.scene)
    inst = instance_scores(pts, lab, gt)
    print(f"{int(lab.max()) + 1 if lab.size else 0} clusters on {pts.shape[0]} voxels")
    print(f"instance mIoU {100 * inst['miou']:.2f}  class mIoU {100 * class_miou(pts, lab, gt):.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
