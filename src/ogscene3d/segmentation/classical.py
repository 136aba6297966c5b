"""A weight-free fallback segmenter: graph-based segmentation on colour, depth and surface normals.

For users without SAM/detector model files. It is clearly LOWER QUALITY than SAM: it has no notion of
objects, only of regions that look and lie alike, so objects with several colours split into parts and
touching objects of the same colour and depth merge. It is deterministic and needs no downloads.

Method: Felzenszwalb & Huttenlocher's graph segmentation (IJCV 2004) on the 8-connected pixel grid, with
the merge criterion w(e) <= min(Int(A) + k/|A|, Int(B) + k/|B|) (Int = largest edge of the component's
minimum spanning tree). Instead of the sequential Kruskal loop over sorted edges (a Python loop over
every edge), the edges are cut into 512 weight-ordered buckets and each bucket is merged in parallel
Boruvka rounds, fully vectorised in numpy (``graph_segment``); on 320x240 frames this gives the same
partition as the exact sequential algorithm (measured on Replica and 7-Scenes frames: docs/results.md,
"Dataset checks"; the tests compare against an exact reference). Components smaller than ``min_size`` and
strips at most 2 px wide are then merged into their cheapest neighbour.

Edge weight between neighbouring pixels p, q (in CIELAB ΔE units):

    w = |Lab_p - Lab_q| + depth_weight * |z_q - z_p - s_pq| / min(z_p, z_q) + normal_weight * (1 - n_p . n_q)

with s_pq the depth step the smoothed depth's gradient predicts (so slanted planes cost nothing and
occlusion boundaries do, see ``depth_step_residual``); the depth and normal terms count only where both
depths are valid (> 0). The depth is first median-filtered (5x5) against sensor noise. Normals come from
the smoothed depth and the camera's focal length (``fx``; without one, 0.8 x image width is assumed,
about a 64 degree field of view) and are ignored within 2 px of depth jumps. The scale k is in ΔE
units too (default 100 at 320 px).

Score heuristic (documented, not a calibrated probability): a region that is homogeneous inside and
contrasts with its surroundings is more likely a real surface. With σ the RMS colour deviation inside
the region (ΔE), I and B the mean weights of its internal and boundary edges,

    h = exp(-σ / 10),  c = B / (B + I) (0.5 when no boundary),  score = 0.88 + 0.12 * sqrt(h * c),

i.e. within SAM's usual predicted-IoU range [0.88, 1] so that the same confidence rescaling applies.
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

from ..config import SegmentationConfig, section_values
from .base import Segmentation
from .sam_onnx import check_rgb

log = logging.getLogger(__name__)

# neighbour offsets (dy, dx) of the 8-connected grid, each undirected edge once
_OFFSETS = ((0, 1), (1, 0), (1, 1), (1, -1))
# relative depth residual above which an edge counts as an occlusion boundary (10 %: far above the
# median-filtered noise of consumer depth sensors, far below real depth jumps between objects)
JUMP_RESIDUAL = 0.1


def _grid_edges(h: int, w: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Endpoints (flat pixel indices) of the 8-connected grid's edges and their (dy, dx) offsets."""
    idx = np.arange(h * w, dtype=np.int64).reshape(h, w)
    us, vs, dys, dxs = [], [], [], []
    for dy, dx in _OFFSETS:
        ys = slice(0, h - dy)
        yd = slice(dy, h)
        if dx >= 0:
            xs, xd = slice(0, w - dx), slice(dx, w)
        else:
            xs, xd = slice(-dx, w), slice(0, w + dx)
        u = idx[ys, xs].ravel()
        us.append(u)
        vs.append(idx[yd, xd].ravel())
        dys.append(np.full(u.size, dy, dtype=np.float32))
        dxs.append(np.full(u.size, dx, dtype=np.float32))
    return np.concatenate(us), np.concatenate(vs), np.concatenate(dys), np.concatenate(dxs)


def depth_normals(depth: np.ndarray, fx: float, fy: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit camera-space normals [H, W, 3] from a depth map in metres (0 = invalid), and their validity.

    Central differences of the back-projected points of the smoothed depth (``smooth_depth``: sensor
    noise and quantisation steps would otherwise make normals flicker); valid where the pixel and its
    (existing) four neighbours have valid depth. Oriented towards the camera (1 - n.n' sees creases only).
    """
    h, w = depth.shape
    if h < 2 or w < 2:  # a one-pixel strip (e.g. a very thin image after max_side) has no surface normal
        return np.zeros((h, w, 3), np.float32), np.zeros((h, w), bool)
    valid = depth > 0
    z = smooth_depth(depth)
    u = ((np.arange(w, dtype=np.float32) + 0.5 - w / 2) / fx)[None, :]
    v = ((np.arange(h, dtype=np.float32) + 0.5 - h / 2) / fy)[:, None]
    pts = np.stack([u * z, v * z, z], axis=-1)
    # central differences inside, one-sided at the image border (a border without normals would let
    # regions leak into each other along it at zero cost)
    du = np.gradient(pts, axis=1)
    dv = np.gradient(pts, axis=0)
    n = np.cross(du, dv)
    norm = np.linalg.norm(n, axis=-1)
    cross4 = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
    ok = cv2.erode(valid.astype(np.uint8), cross4, borderType=cv2.BORDER_CONSTANT, borderValue=1) > 0
    ok &= norm > 1e-12
    n = n / np.maximum(norm, 1e-12)[..., None]
    n = np.where((n[..., 2:3] > 0), -n, n)
    return n.astype(np.float32), ok


def smooth_depth(depth: np.ndarray, sigma: float = 1.0) -> np.ndarray:
    """Gaussian-smoothed depth by normalised convolution: invalid (0) pixels neither contribute nor drag
    the neighbourhood towards 0; pixels without a valid neighbour stay 0."""
    vf = (depth > 0).astype(np.float32)
    num = cv2.GaussianBlur(depth.astype(np.float32) * vf, (0, 0), sigma)
    den = cv2.GaussianBlur(vf, (0, 0), sigma)
    return np.where(den > 1e-3, num / np.maximum(den, 1e-3), 0.0).astype(np.float32)


def depth_step_residual(
    depth: np.ndarray, eu: np.ndarray, ev: np.ndarray, dy: np.ndarray, dx: np.ndarray
) -> np.ndarray:
    """Per edge p -> q: |z_q - z_p - s_pq| / min(z_p, z_q), s_pq the step the local surface predicts.

    s_pq is the smoothed depth's gradient (averaged over p and q) times the edge offset, so that a slanted
    plane (a floor at a grazing angle, whose depth changes a lot from row to row) costs nothing while an
    occlusion boundary does; a plain |dz|/z term cuts such floors into stripes. The smoothing spreads a
    step's gradient over its neighbours, which gives them a small residual too: the thin strips this can
    leave are merged by ``graph_segment``. 0 where either depth is invalid.
    """
    zs = smooth_depth(depth)
    # np.gradient needs two samples per axis; along an axis of one pixel there are no edges to predict
    gy = np.gradient(zs, axis=0) if zs.shape[0] > 1 else np.zeros_like(zs)
    gx = np.gradient(zs, axis=1) if zs.shape[1] > 1 else np.zeros_like(zs)
    gy, gx = gy.ravel(), gx.ravel()
    z = depth.ravel().astype(np.float32)
    expected = 0.5 * ((gx[eu] + gx[ev]) * dx + (gy[eu] + gy[ev]) * dy)
    both = (z[eu] > 0) & (z[ev] > 0)
    res = np.abs(z[ev] - z[eu] - expected) / np.maximum(np.minimum(z[eu], z[ev]), 1e-6)
    return np.where(both, res, 0.0).astype(np.float32)


class _Forest:
    """Vectorised union-find over grid nodes for the Boruvka rounds of ``graph_segment``.

    ``parent`` links every node towards its component's root (a node id); ``size`` and ``internal``
    (Int, the largest merge edge of the component's spanning tree) are valid at root ids. All work per
    round is proportional to the edges and components involved, not to the image size.
    """

    def __init__(self, n: int, n_edges: int) -> None:
        self.parent = np.arange(n, dtype=np.int64)
        self.size = np.ones(n, dtype=np.float64)
        self.internal = np.zeros(n, dtype=np.float64)
        self._best = np.full(n, n_edges, dtype=np.int64)  # scratch, reset after each use
        self._none = n_edges

    def find(self, x: np.ndarray) -> np.ndarray:
        r = self.parent[x]
        while True:
            r2 = self.parent[r]
            if np.array_equal(r2, r):
                break
            r = r2
        self.parent[x] = r  # path compression for the queried nodes
        return r

    def step(
        self,
        eu: np.ndarray,
        ev: np.ndarray,
        ew: np.ndarray,
        active: np.ndarray,
        k: float | None,
        force: np.ndarray | None = None,
    ) -> tuple[np.ndarray, int]:
        """One Boruvka round over ``active`` (indices into the weight-sorted edges: index = rank).

        With ``k``: only edges satisfying Felzenszwalb's criterion w <= min(Int(A) + k/|A|, Int(B) + k/|B|)
        (statistics at the start of the round) take part; each component merges along its cheapest one.
        With ``k`` None: each component whose root is marked in ``force`` merges along its cheapest edge.
        Returns (the active edges still between components, the number of merges).
        """
        cu, cv = self.find(eu[active]), self.find(ev[active])
        between = cu != cv
        active, cu, cv = active[between], cu[between], cv[between]
        if active.size == 0:
            return active, 0
        if k is not None:
            thr = self.internal
            ok = ew[active] <= np.minimum(thr[cu] + k / self.size[cu], thr[cv] + k / self.size[cv])
            pe, pu, pv = active[ok], cu[ok], cv[ok]
        else:
            pe, pu, pv = active, cu, cv
        if pe.size == 0:
            return active, 0
        best = self._best
        np.minimum.at(best, pu, pe)
        np.minimum.at(best, pv, pe)
        cand = np.unique(np.concatenate([pu, pv]))
        e = best[cand]
        best[cand] = self._none
        a, b = self.find(eu[e]), self.find(ev[e])
        other = np.where(a == cand, b, a)
        if k is None:
            must = force[cand]
            cand, other, e = cand[must], other[must], e[must]
            if cand.size == 0:
                return active, 0
        # local forest over the components involved: picks form trees plus 2-cycles (both ends of one
        # edge picked it); in a 2-cycle the smaller id stays the root
        nodes = np.unique(np.concatenate([cand, other]))
        src, dst = np.searchsorted(nodes, cand), np.searchsorted(nodes, other)
        ids = np.arange(nodes.size)
        par = ids.copy()
        par[src] = dst
        mutual = (par[par] == ids) & (ids < par)
        par[mutual] = ids[mutual]
        while True:
            nxt = par[par]
            if np.array_equal(nxt, par):
                break
            par = nxt
        merged = par[src] != src
        root = nodes[par[src]]
        np.maximum.at(self.internal, root, ew[e])  # merge edges are spanning-tree edges of the union
        np.maximum.at(self.internal, root, self.internal[cand])
        moved = cand[merged]
        np.add.at(self.size, root[merged], self.size[moved])
        self.parent[nodes] = nodes[par]
        return active, int(merged.sum())


def graph_segment(
    h: int,
    w: int,
    weights: np.ndarray,
    eu: np.ndarray,
    ev: np.ndarray,
    k: float,
    min_size: int,
    levels: int = 512,
    merge_thin: bool = True,
    max_rounds: int = 100000,
) -> np.ndarray:
    """Felzenszwalb-Huttenlocher segmentation of an h x w grid graph; returns labels [h, w] in 0..K-1.

    Kruskal's global weight order is approximated by ``levels`` buckets of equally many edges: within a
    bucket, merges happen in parallel Boruvka rounds; a bucket opens only when all cheaper ones are done,
    so a boundary edge is looked at only after the regions on both sides have grown (which is what makes
    the criterion work: small components accept almost any edge). Edges of a bucket that never pass the
    criterion are dropped with it, as Kruskal drops an edge after looking at it once.
    ``merge_thin``: also merge regions at most 2 px wide into their cheapest neighbour (not in the paper).
    """
    n = h * w
    order = np.argsort(weights, kind="stable")
    eu, ev, ew = eu[order], ev[order], weights[order].astype(np.float64)
    n_edges = eu.size
    forest = _Forest(n, n_edges)
    rounds = 0
    cuts = np.unique(np.linspace(0, n_edges, levels + 1).astype(np.int64))
    for lo, hi in zip(cuts[:-1], cuts[1:]):
        active = np.arange(lo, hi, dtype=np.int64)
        while active.size and rounds < max_rounds:
            active, merges = forest.step(eu, ev, ew, active, k)
            rounds += 1
            if merges == 0:
                break
    # clean-up: regions below min_size, and thin ones (no pixel whose 4 neighbours all share its region:
    # at most 2 px wide, the blurred transition strips along strong edges) join their cheapest neighbour
    active = np.arange(n_edges, dtype=np.int64)
    while rounds < max_rounds:
        roots = forest.find(np.arange(n, dtype=np.int64)).reshape(h, w)
        interior = np.zeros((h, w), dtype=bool)
        interior[1:-1, 1:-1] = (
            (roots[1:-1, 1:-1] == roots[:-2, 1:-1])
            & (roots[1:-1, 1:-1] == roots[2:, 1:-1])
            & (roots[1:-1, 1:-1] == roots[1:-1, :-2])
            & (roots[1:-1, 1:-1] == roots[1:-1, 2:])
        )
        force = forest.size < min_size
        if merge_thin:
            thick = np.zeros(n, dtype=bool)
            thick[roots[interior]] = True
            force |= ~thick
        active, merges = forest.step(eu, ev, ew, active, None, force)
        rounds += 1
        if merges == 0:
            break
    _, labels = np.unique(forest.find(np.arange(n, dtype=np.int64)), return_inverse=True)
    return labels.reshape(h, w)


def region_scores(
    labels: np.ndarray, lab: np.ndarray, eu: np.ndarray, ev: np.ndarray, weights: np.ndarray
) -> np.ndarray:
    """The score heuristic of the module docstring per region [K], in [0.88, 1]."""
    flat = labels.ravel()
    k = int(flat.max()) + 1
    cnt = np.bincount(flat, minlength=k).astype(np.float64)
    col = lab.reshape(-1, 3).astype(np.float64)
    mean = np.stack([np.bincount(flat, col[:, c], k) for c in range(3)], 1) / cnt[:, None]
    sq = sum(np.bincount(flat, col[:, c] ** 2, k) for c in range(3)) / cnt
    sigma = np.sqrt(np.maximum(sq - (mean**2).sum(1), 0.0))
    la, lb = flat[eu], flat[ev]
    same = la == lb
    w = weights.astype(np.float64)
    i_sum = np.bincount(la[same], w[same], k)
    i_cnt = np.bincount(la[same], minlength=k)
    b_sum = np.bincount(la[~same], w[~same], k) + np.bincount(lb[~same], w[~same], k)
    b_cnt = np.bincount(la[~same], minlength=k) + np.bincount(lb[~same], minlength=k)
    inner = i_sum / np.maximum(i_cnt, 1)
    bound = b_sum / np.maximum(b_cnt, 1)
    contrast = np.where(b_cnt > 0, bound / np.maximum(bound + inner, 1e-9), 0.5)
    homog = np.exp(-sigma / 10.0)
    return 0.88 + 0.12 * np.sqrt(np.clip(homog * contrast, 0.0, 1.0))


class ClassicalSegmenter:
    """Weight-free graph segmentation on colour + depth + normals (see the module docstring).

    ``seg = ClassicalSegmenter(fx=K[0, 0], fy=K[1, 1]); s = seg(rgb, depth)`` (focal lengths in pixels,
    also accepted per call): every pixel gets a segment; ``s.scores`` holds the heuristic scores in
    [0.88, 1]. Images larger than ``max_side`` are segmented at that size and the labels upsampled
    (nearest), which bounds the run time.
    """

    def __init__(
        self,
        k: float = 100.0,
        min_size: int = 60,
        max_side: int = 320,
        depth_weight: float = 300.0,
        normal_weight: float = 100.0,
        sigma: float = 0.8,
        fx: float | None = None,
        fy: float | None = None,
    ) -> None:
        if k <= 0 or min_size < 0 or max_side < 8 or depth_weight < 0 or normal_weight < 0 or sigma < 0:
            raise ValueError(
                "classical segmenter: needs k > 0, min_size >= 0, max_side >= 8 and non-negative "
                "weights and sigma"
            )
        self.k = float(k)
        self.min_size = int(min_size)
        self.max_side = int(max_side)
        self.depth_weight = float(depth_weight)
        self.normal_weight = float(normal_weight)
        self.sigma = float(sigma)
        if (fx is not None and not fx > 0) or (fy is not None and not fy > 0):
            raise ValueError(f"focal lengths must be positive, got fx={fx}, fy={fy}")
        self.fx = None if fx is None else float(fx)
        self.fy = None if fy is None else float(fy)

    @classmethod
    def from_config(cls, config: SegmentationConfig, K: np.ndarray | None = None) -> ClassicalSegmenter:
        """The classical segmenter that a ``segmentation`` config section describes.

        Args:
            config: the section; read are ``classical_k``, ``classical_min_size``, ``classical_max_side``,
                ``classical_depth_weight`` and ``classical_normal_weight``.
            K: 3x3 intrinsics (optional): their focal lengths, for the normals.

        Returns:
            The segmenter.
        """
        fx = fy = None
        if K is not None:
            K = np.asarray(K, dtype=np.float64)
            if K.shape != (3, 3):
                raise ValueError(f"K must be 3x3, got shape {K.shape}")
            fx, fy = float(K[0, 0]), float(K[1, 1])
        names = ("k", "min_size", "max_side", "depth_weight", "normal_weight")
        return cls(**section_values(config, names, "classical_"), fx=fx, fy=fy)

    def __call__(
        self,
        rgb: np.ndarray,
        depth: np.ndarray | None = None,
        *,
        fx: float | None = None,
        fy: float | None = None,
    ) -> Segmentation:
        rgb = check_rgb(rgb)
        h0, w0 = rgb.shape[:2]
        fx = self.fx if fx is None else fx
        fy = self.fy if fy is None else fy
        if depth is not None:
            depth = np.asarray(depth)
            if depth.shape != (h0, w0):
                raise ValueError(f"depth shape {depth.shape} differs from the rgb image's {(h0, w0)}")
            if not np.all(np.isfinite(depth)):
                raise ValueError("depth contains NaN or inf; mark invalid pixels with 0")
        scale = min(1.0, self.max_side / max(h0, w0))
        h, w = max(1, int(round(h0 * scale))), max(1, int(round(w0 * scale)))
        if (h, w) != (h0, w0):
            rgb_s = cv2.resize(rgb, (w, h), interpolation=cv2.INTER_AREA)
            depth_s = (
                None
                if depth is None
                else cv2.resize(depth.astype(np.float32), (w, h), interpolation=cv2.INTER_NEAREST)
            )
        else:
            rgb_s, depth_s = rgb, None if depth is None else depth.astype(np.float32)
        if self.sigma > 0:
            rgb_s = cv2.GaussianBlur(rgb_s, (0, 0), self.sigma)
        lab = cv2.cvtColor(rgb_s.astype(np.float32) / 255.0, cv2.COLOR_RGB2LAB).reshape(-1, 3)
        eu, ev, dy, dx = _grid_edges(h, w)
        weights = np.linalg.norm(lab[eu] - lab[ev], axis=1)
        if depth_s is not None and (self.depth_weight > 0 or self.normal_weight > 0):
            # sensor noise would dominate second differences: a 5x5 median removes it, keeps steps
            valid = depth_s > 0
            depth_m = np.where(valid, cv2.medianBlur(depth_s.astype(np.float32), 5), 0.0).astype(np.float32)
            residual = depth_step_residual(depth_m, eu, ev, dy, dx)
            if self.depth_weight > 0:
                weights += self.depth_weight * residual
            if self.normal_weight > 0:
                f_x = (float(fx) if fx is not None else 0.8 * w0) * scale
                f_y = float(fy) * scale if fy is not None else f_x
                nrm, ok = depth_normals(depth_m, f_x, f_y)
                # normals smoothed across an occlusion boundary describe no surface: drop them within
                # the smoothing support of depth jumps (the depth term marks those boundaries)
                jump = np.zeros(h * w, dtype=np.uint8)
                big = residual > JUMP_RESIDUAL
                jump[eu[big]] = 1
                jump[ev[big]] = 1
                near = cv2.dilate(jump.reshape(h, w), np.ones((5, 5), np.uint8)) > 0
                nrm, ok = nrm.reshape(-1, 3), (ok & ~near).ravel()
                crease = 1.0 - np.einsum("ij,ij->i", nrm[eu], nrm[ev])
                weights += np.where(ok[eu] & ok[ev], self.normal_weight * crease, 0.0)
        weights = weights.astype(np.float32)
        labels = graph_segment(h, w, weights, eu, ev, self.k, self.min_size)
        scores = region_scores(labels, lab, eu, ev, weights)
        if (h, w) != (h0, w0):
            labels = cv2.resize(labels.astype(np.int32), (w0, h0), interpolation=cv2.INTER_NEAREST)
        # upsampling may drop a tiny region entirely: renumber the present ones 1..K
        present = np.flatnonzero(np.bincount(labels.ravel(), minlength=scores.size))
        lut = np.zeros(scores.size, dtype=np.int32)
        lut[present] = np.arange(1, present.size + 1, dtype=np.int32)
        ids = lut[labels]
        return Segmentation(ids, {int(lut[i]): float(scores[i]) for i in present})
