r"""The offline yardstick: view consensus of every frame's segments with a separation rule (issue 39).

The mapper decides online, one keyframe after the other; this clusters every frame's segments at once, after
the whole stream, and so tells how much instance accuracy the same segments allow. It is meant to be hard to
beat (docs/consistency.md measures it); the earlier, weaker yardstick (MaskClustering's consensus without a
separation rule) is ``_maskclustering.py`` (``--weak``).

* **Scene points**: every frame's valid pixels are back-projected and pooled in ``VOXEL`` voxels. A frame
  *sees* the voxels its pixels fall in, and puts a voxel in a mask when all its segmented pixels there are of
  that one segment (else it is on a boundary, seen but in no mask, as MaskClustering's boundary points).
* **Nodes** start as the masks (a segment of one frame: the voxels it holds there) and become clusters of
  masks, level by level. A node is *seen* in a frame that sees ``SEEN_FRACTION`` of its voxels (or
  ``SEEN_VOXELS``: a large cluster is never seen whole), and *held* by the frame's mask that holds at least
  ``CONTAIN`` (0.7, rule b) of its voxels that lie in some mask there.
* **Consensus** of two nodes: of the frames that hold both (each by some mask), the share where one mask
  holds both, over at least ``MIN_VIEWS`` such frames (MaskClustering's view consensus).
* **Under-segmented masks** (MaskClustering's filter): a mask that the other frames clearly split (a second
  mask holds ``SPLIT_PART`` of it) in more than ``SPLIT`` of the frames that see it lies over two objects (a
  first view that merged a refrigerator with the floor): it is no node, holds nothing and has no vote.
* **Separation** (rule a): two nodes stay apart when some frame clearly separates them, that is holds one
  by a mask that holds at most ``APART`` (a fifth) of the other's voxels seen there, a mask that is small
  beside the other (at most ``SEP_SIZE`` of the other's voxels there: a cup's own segment beside the table;
  a random cut through a wall is no evidence). SAM merges a small object into its support in most far
  views; the few views that show it apart are the evidence.
* **Levels**: at each threshold of ``THRESHOLDS`` the node pairs whose consensus reaches it are joined, best
  consensus first, unless the two groups hold a separated pair (a segment over two objects links each of
  them; their separation keeps them apart); seen / held / separation are computed again for the new
  clusters from the union of their voxels.
* **Votes** (rule c): each voxel takes the cluster with the largest score-weighted share of the views that
  put it in a mask (a view's weight: its segment's SAM score). A mask that holds another cluster which the
  views separate from its own (a table's segment that absorbed the cup) gives its vote on that cluster's
  voxels to that cluster (``nested``): a view that merged the cup with the table says nothing against it.

The result is a labelled point set (voxel means), scored like a map (``_instances.py``).

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
SEEN_VOXELS = 100
MIN_VIEWS = 2
MIN_MASK_VOXELS = 2
SPLIT = 0.3  # a mask split in more than this share of the frames that see it is under-segmented
SEP_SIZE: float | None = 0.3
SPLIT_PART = 0.3  # ... where a second mask holds this share of it
THRESHOLDS = (0.9, 0.8, 0.7)


def _frames(scene: str | Path) -> list:
    from ogscene3d.datasets import open_dataset

    return list(open_dataset(scene, kind="synthetic"))


@dataclass
class Views:
    """What every frame saw, on the scene's voxels.

    ``points`` [V, 3]: voxel means; per frame ``g``: ``seen[g]`` the voxels it sees and ``mask[g]`` the
    global mask index each lies in (-1: on a boundary or in no segment); per mask: ``mask_frame``,
    ``mask_score`` (its segment's SAM score) and ``mask_voxels`` (a CSR of its voxels in its own frame)."""

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
        mask.append(index[local])
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
        seen[:, g] = (n_vis >= np.minimum(SEEN_FRACTION * size, SEEN_VOXELS)) & (n_vis >= MIN_MASK_VOXELS)
        if not in_mask.any():
            continue
        base = int(m[in_mask].min())
        local = m[in_mask] - base
        k = int(local.max()) + 1
        cnt = np.bincount(node[in_mask] * k + local, minlength=n_nodes * k).reshape(n_nodes, k)
        best = cnt.argmax(1)
        top = cnt[np.arange(n_nodes), best]
        ok = seen[:, g] & (n_in[:, g] > 0) & (top >= CONTAIN * n_in[:, g])
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


def _separated(h: Holding, a: np.ndarray, b: np.ndarray, chunk: int = 20000) -> np.ndarray:
    """[E] bool: pairs that some frame separates (rule a), either way round."""
    out = np.zeros(len(a), bool)
    for x, y in ((a, b), (b, a)):
        for s in range(0, len(x), chunk):
            xs, ys = x[s : s + chunk], y[s : s + chunk]
            k = h.held[xs]  # the mask holding x in each frame
            look = (k >= 0) & h.seen[ys] & (h.n_in[ys] > 0)
            if SEP_SIZE is not None:  # the mask that holds x is small beside y: a cup's, beside the table
                look &= h.mask_size[np.maximum(k, 0)] <= SEP_SIZE * h.n_in[ys]
            e, g = np.nonzero(look)
            if e.size == 0:
                continue
            share = h.count(ys[e], k[e, g])
            apart = share <= APART * h.n_in[ys[e], g]
            out[s + np.unique(e[apart])] = True
    return out


def _constrained_components(n: int, a, b, rank, apart_a, apart_b) -> np.ndarray:
    """Union the pairs (a, b) in the order of ``rank`` (best first), never joining two groups that hold a
    separated pair (apart_a, apart_b): a segment over two objects links each of them, and the separation
    between the two keeps them apart. Returns each node's group."""
    parent = np.arange(n)

    def find(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    cannot: dict[int, set[int]] = {}
    for x, y in zip(apart_a.tolist(), apart_b.tolist()):
        cannot.setdefault(x, set()).add(y)
        cannot.setdefault(y, set()).add(x)
    for e in np.argsort(rank, kind="stable"):
        ra, rb = find(int(a[e])), find(int(b[e]))
        if ra == rb or rb in cannot.get(ra, ()):
            continue
        if len(cannot.get(ra, ())) < len(cannot.get(rb, ())):
            ra, rb = rb, ra
        parent[rb] = ra
        moved = cannot.pop(rb, set())
        for x in moved:
            cannot[x].discard(rb)
            cannot[x].add(ra)
        cannot.setdefault(ra, set()).update(moved)
    return np.array([find(x) for x in range(n)], np.int64)


def undersegmented(h: Holding, views: Views) -> np.ndarray:
    """[masks] bool: masks that other frames clearly split (a second mask holds ``SPLIT_PART`` of them) in
    more than ``SPLIT`` of the frames that see them: a segment over two objects (MaskClustering's
    under-segmentation filter, with a clear split: a book's few voxels spread by boundary noise are not)."""
    own = np.zeros_like(h.seen)
    own[np.arange(views.n_masks), views.mask_frame] = True
    look = h.seen & (h.n_in > 0) & ~own
    return (look & h.split).sum(1) > SPLIT * np.maximum(look.sum(1), 1)


def _drop_masks(h: Holding, drop: np.ndarray) -> None:
    """Masks ``drop`` hold nothing: the frames where they held a node no longer count for it."""
    bad = (h.held >= 0) & drop[np.maximum(h.held, 0)]
    h.held[bad] = -1


def cluster(views: Views, thresholds: tuple[float, ...] = THRESHOLDS) -> tuple[np.ndarray, Holding]:
    """The cluster of every mask (-1: an under-segmented mask, left out) after the last level, and the final
    clusters' holding."""
    node_of_mask = np.arange(views.n_masks)
    n = views.n_masks
    h = holding(views, node_of_mask, n)
    under = undersegmented(h, views)
    node_of_mask = np.where(under, -1, node_of_mask)
    _drop_masks(h, under)
    h.held[under] = -1  # nor are they nodes
    for thr in thresholds:
        a, b, support = _candidate_pairs(h, n, views.n_masks)
        observers = _observers(h, a, b)
        apart = _separated(h, a, b)
        rate = support / np.maximum(observers, 1)
        ok = (observers >= MIN_VIEWS) & (rate >= thr) & ~apart
        rank = np.lexsort((-observers[ok], -rate[ok]))
        order = np.empty(len(rank), np.int64)
        order[rank] = np.arange(len(rank))
        comp = _constrained_components(n, a[ok], b[ok], order, a[apart], b[apart])
        alive = np.unique(node_of_mask[node_of_mask >= 0])
        _, comp_alive = np.unique(comp[alive], return_inverse=True)
        lut = np.full(n, -1, np.int64)
        lut[alive] = comp_alive
        node_of_mask = np.where(node_of_mask >= 0, lut[np.maximum(node_of_mask, 0)], -1)
        n = int(comp_alive.max()) + 1 if len(comp_alive) else 0
        h = holding(views, node_of_mask, n)
        _drop_masks(h, under)
    return node_of_mask, h


def vote(views: Views, node_of_mask: np.ndarray, h: Holding, nested: bool = True) -> np.ndarray:
    """Each voxel's cluster (-1: no mask of a cluster ever held it): the largest score-weighted share of the
    views that put it in a mask (rule c); with ``nested``, see :func:`_nested`."""
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
        clu = _nested(node_of_mask, h, vox, msk, frame, clu, len(views.seen))
    key = vox * max(n, 1) + clu
    uk, inv = np.unique(key, return_inverse=True)
    total = np.bincount(inv, weights=w)
    kv, kc = uk // max(n, 1), uk % max(n, 1)
    order = np.lexsort((-total, kv))
    first = np.r_[True, kv[order][1:] != kv[order][:-1]]
    out = np.full(nv, -1, np.int64)
    out[kv[order][first]] = kc[order][first]
    return out


def _nested(node_of_mask, h: Holding, vox, msk, frame, clu, n_frames: int) -> np.ndarray:
    """The votes' clusters, where a mask holds a cluster that the views separate from the mask's own (the
    table's segment that absorbed the cup): on the voxels the held cluster's own masks cover, the vote goes
    to it (the smallest such cluster), as that view merged the two and says nothing against it."""
    c, g = np.nonzero(h.held >= 0)
    k = h.held[c, g]
    other = node_of_mask[k] != c
    c, g, k = c[other], g[other], k[other]
    if c.size == 0:
        return clu
    apart = _separated(h, c, node_of_mask[k])
    c, g, k = c[apart], g[apart], k[apart]
    # each cluster's own voxels (a CSR over clusters)
    n = int(node_of_mask.max()) + 1
    nv = int(vox.max()) + 1
    own = np.unique(clu.astype(np.int64) * nv + vox)
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
    # the smallest held cluster wins where several are
    size = np.diff(ptr)
    sel = np.nonzero(hit)[0]
    sel = sel[np.argsort(-size[cand_c[sel]], kind="stable")]  # larger first, smaller overwrite
    out[order[pos[sel]]] = cand_c[sel]
    return out


def strong_consensus(frames: list) -> tuple[np.ndarray, np.ndarray]:
    """Labelled voxel means [V, 3] and their cluster [V] (-1: never in a mask) of the strong yardstick."""
    views = build_views(frames)
    if views.n_masks == 0:
        return views.points, np.full(len(views.points), -1, np.int64)
    node_of_mask, h = cluster(views)
    return views.points, vote(views, node_of_mask, h)


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
