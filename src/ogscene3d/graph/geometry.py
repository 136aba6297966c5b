"""Geometric descriptors of scene-graph nodes shared by the relation predictor and the heuristic captioner.

Everything here works on a node's (subsampled) Gaussian means in world coordinates, metres, and on the
configured world *up* vector (``graph.up_axis``). No axis is ever assumed: heights are ``p · up`` and the
horizontal plane is spanned by two unit vectors orthogonal to ``up``.

Robust extents use the 2nd / 98th percentiles so a few stray Gaussians do not inflate a box.
"""

from __future__ import annotations

import colorsys
from dataclasses import dataclass

import numpy as np

from ..up_axis import unit_up

#: Percentiles used for robust extents (a few outlier Gaussians do not change a box).
LO_PCT = 2.0
HI_PCT = 98.0


def horizontal_basis(up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors ``e1, e2`` with ``(e1, e2, up)`` orthonormal and right-handed."""
    u = unit_up(up)
    helper = np.eye(3)[int(np.argmin(np.abs(u)))]  # the world axis least aligned with up
    e1 = np.cross(helper, u)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    return e1, e2


def pca_frame(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Principal axes of ``points`` [N,3].

    Returns ``(mean [3], axes [3,3], std [3])``: rows of ``axes`` are unit principal directions sorted by
    decreasing spread, ``std`` the standard deviation along each. Degenerate inputs (N < 3) give the
    identity frame.
    """
    p = np.asarray(points, dtype=np.float64)
    mean = p.mean(axis=0) if len(p) else np.zeros(3)
    if len(p) < 3:
        return mean, np.eye(3), np.zeros(3)
    cov = np.cov((p - mean).T)
    evals, evecs = np.linalg.eigh(cov)  # ascending
    order = np.argsort(evals)[::-1]
    axes = evecs[:, order].T.copy()
    # Right-handed, and a deterministic sign per axis so the same cloud gives the same box.
    for k in range(2):
        if axes[k][np.argmax(np.abs(axes[k]))] < 0:
            axes[k] = -axes[k]
    axes[2] = np.cross(axes[0], axes[1])
    return mean, axes, np.sqrt(np.clip(evals[order], 0.0, None))


def oriented_box(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PCA oriented bounding box: ``(center [3], axes [3,3] rows, extent [3] full side lengths)``."""
    p = np.asarray(points, dtype=np.float64)
    if len(p) == 0:
        return np.zeros(3), np.eye(3), np.zeros(3)
    _, axes, _ = pca_frame(p)
    local = p @ axes.T
    lo, hi = local.min(axis=0), local.max(axis=0)
    center = ((lo + hi) / 2.0) @ axes
    return center, axes, hi - lo


@dataclass
class Shape:
    """Up-aware shape summary of one node (all lengths in metres).

    ``h_lo``/``h_hi``: robust height interval along up. ``footprint_center``/``footprint_axes``/
    ``footprint_half``: the node's horizontal footprint as a 2D PCA rectangle, in (e1, e2) coordinates.
    ``normal``: the direction of least spread; ``thickness`` the robust extent along it and ``planar``
    whether the node is a thin sheet (thickness small compared with its second extent).
    ``extent``: robust extents along the three PCA axes (decreasing).
    """

    up: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    h_lo: float
    h_hi: float
    footprint_center: np.ndarray
    footprint_axes: np.ndarray
    footprint_half: np.ndarray
    normal: np.ndarray
    thickness: float
    planar: bool
    extent: np.ndarray

    @property
    def height(self) -> float:
        return self.h_hi - self.h_lo

    @property
    def is_horizontal_plane(self) -> bool:
        return self.planar and abs(float(self.normal @ self.up)) > 0.9

    @property
    def is_vertical_plane(self) -> bool:
        return self.planar and abs(float(self.normal @ self.up)) < 0.3

    @property
    def size(self) -> float:
        """Largest robust extent (the object's 'size')."""
        return float(self.extent[0])

    @property
    def volume(self) -> float:
        """Robust box volume with a 1 cm floor on each side, so sheets still compare by area."""
        return float(np.prod(np.maximum(self.extent, 0.01)))

    def horizontal(self, points: np.ndarray) -> np.ndarray:
        """[N,2] coordinates of ``points`` in the horizontal plane (e1, e2)."""
        return np.stack([points @ self.e1, points @ self.e2], axis=-1)

    def in_footprint(self, points: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """[N] bool: the horizontal projection of ``points`` lies inside the footprint rectangle."""
        local = (self.horizontal(points) - self.footprint_center) @ self.footprint_axes.T
        return np.all(np.abs(local) <= self.footprint_half + margin, axis=-1)


def shape_of(
    points: np.ndarray, up: np.ndarray, planar_ratio: float = 0.15, max_thickness: float = 0.2
) -> Shape:
    """Compute the :class:`Shape` of a node from its points [N,3] (N >= 1).

    A node is *planar* when its robust thickness along the least-spread axis is below both
    ``planar_ratio`` x its second extent and ``max_thickness`` metres.
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) == 0:
        raise ValueError(f"shape_of: points must be [N>=1, 3], got {p.shape}")
    u = unit_up(up)
    e1, e2 = horizontal_basis(u)
    h = p @ u
    h_lo, h_hi = np.percentile(h, [LO_PCT, HI_PCT])
    _, axes, _ = pca_frame(p)
    local = p @ axes.T
    lo, hi = np.percentile(local, [LO_PCT, HI_PCT], axis=0)
    extent = hi - lo
    normal = axes[2]
    thickness = float(extent[2])
    planar = bool(
        len(p) >= 10 and thickness < planar_ratio * max(extent[1], 1e-9) and thickness < max_thickness
    )
    hp = np.stack([p @ e1, p @ e2], axis=-1)
    fc_mean = hp.mean(axis=0)
    if len(p) >= 3:
        evals, evecs = np.linalg.eigh(np.cov((hp - fc_mean).T))
        faxes = evecs[:, np.argsort(evals)[::-1]].T
    else:
        faxes = np.eye(2)
    fl = (hp - fc_mean) @ faxes.T
    flo, fhi = np.percentile(fl, [LO_PCT, HI_PCT], axis=0)
    fcenter = fc_mean + ((flo + fhi) / 2.0) @ faxes
    return Shape(
        up=u,
        e1=e1,
        e2=e2,
        h_lo=float(h_lo),
        h_hi=float(h_hi),
        footprint_center=fcenter,
        footprint_axes=faxes,
        footprint_half=(fhi - flo) / 2.0,
        normal=normal,
        thickness=thickness,
        planar=planar,
        extent=extent,
    )


def color_name(rgb: np.ndarray | list[float]) -> str:
    """A coarse English colour name for an RGB triple in [0, 1] (e.g. the median colour of a node)."""
    r, g, b = (float(np.clip(c, 0.0, 1.0)) for c in np.asarray(rgb, dtype=np.float64).reshape(3))
    hue, sat, val = colorsys.rgb_to_hsv(r, g, b)
    hue *= 360.0
    if val < 0.18:
        return "black"
    if sat < 0.18:
        if val > 0.85:
            return "white"
        if val > 0.6:
            return "light gray"
        if val > 0.35:
            return "gray"
        return "dark gray"
    if (hue < 45.0 or hue >= 345.0) and val < 0.6 and sat > 0.3:
        return "brown"
    for limit, name in (
        (15.0, "red"),
        (45.0, "orange"),
        (70.0, "yellow"),
        (165.0, "green"),
        (195.0, "cyan"),
        (255.0, "blue"),
        (290.0, "purple"),
        (345.0, "pink"),
    ):
        if hue < limit:
            return name
    return "red"


def format_length(metres: float) -> str:
    """Human size: ``"8 cm"`` below one metre, ``"1.4 m"`` above."""
    if metres < 1.0:
        return f"{max(1, round(metres * 100))} cm"
    return f"{metres:.1f} m"


def _expand_ranges(begin: np.ndarray, count: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For ranges [begin_k, begin_k + count_k): (range index, position) of every element, vectorised."""
    total = int(count.sum())
    which = np.repeat(np.arange(len(begin)), count)
    pos = np.arange(total) - np.repeat(np.cumsum(count) - count, count) + begin[which]
    return which, pos


def proximity_ratios(
    points: list[np.ndarray],
    theta: float,
    query: np.ndarray | list[int] | None = None,
    max_pairs_per_chunk: int = 2_000_000,
) -> dict[tuple[int, int], float]:
    """Proximity interaction ratios R_ij of paper Eqs. 20-21 for node point clouds.

    ``points[k]`` is node k's point cloud [N_k, 3] (world metres; callers pass a per-node subsample).
    P_{i->j} are the points of i with a point of j closer than ``theta``; R_ij = max(|P_{i->j}|/|p_i|,
    |P_{j->i}|/|p_j|). Only pairs with at least one node in ``query`` (all nodes when None) are
    evaluated, which is what the selective edge update needs. See :func:`proximate_points` for the
    neighbour search. Returns ``{(i, j): R_ij}`` with ``i < j`` for every pair with R_ij > 0.
    """
    sizes = np.array([len(np.asarray(p).reshape(-1, 3)) for p in points], dtype=np.int64)
    pt, other = proximate_points(points, theta, query, max_pairs_per_chunk)
    out: dict[tuple[int, int], float] = {}
    for (i, j), r in directed_ratios(pt, other, sizes).items():
        key = (min(i, j), max(i, j))
        out[key] = max(out.get(key, 0.0), r)
    return out


def directed_ratios(
    pt: np.ndarray, other: np.ndarray, sizes: np.ndarray, mask: np.ndarray | None = None
) -> dict[tuple[int, int], float]:
    """``{(i, j): |P_{i->j} ∩ M_i| / |M_i|}`` from :func:`proximate_points` output.

    ``sizes`` [n_nodes] point counts; ``mask`` (optional, [sum(sizes)] bool over the concatenated
    points) restricts both the numerator and the denominator to a subset M_i of each node's points
    (e.g. its bottom band); nodes with an empty subset get no entry.
    """
    n_nodes = len(sizes)
    owner = np.repeat(np.arange(n_nodes, dtype=np.int64), sizes)
    denom = sizes.astype(np.float64)
    if mask is not None:
        keep = mask[pt]
        pt, other = pt[keep], other[keep]
        denom = np.bincount(owner[mask], minlength=n_nodes).astype(np.float64)
    if len(pt) == 0:
        return {}
    codes, counts = np.unique(owner[pt] * n_nodes + other, return_counts=True)
    src, dst = np.divmod(codes, n_nodes)
    ok = denom[src] > 0
    return {
        (int(i), int(j)): float(c / denom[i])
        for i, j, c in zip(src[ok].tolist(), dst[ok].tolist(), counts[ok].tolist())
    }


def proximate_points(
    points: list[np.ndarray],
    theta: float,
    query: np.ndarray | list[int] | None = None,
    max_pairs_per_chunk: int = 2_000_000,
) -> tuple[np.ndarray, np.ndarray]:
    """The point-node proximity relation behind paper Eq. 20: every (point, other node) with a point of
    that other node closer than ``theta``. ``points[k]`` is node k's point cloud [N_k, 3] (metres).

    Neighbours come from a uniform hash grid with cell size ``theta`` (points sorted by cell, then node):
    a query point is compared only with the points of *other* nodes in its 27 neighbouring cells, and
    points whose whole neighbourhood belongs to their own node are skipped at the cell level, so the
    work is proportional to the points near node boundaries, never to all pairs of points. Candidate
    pairs are generated in chunks of at most about ``max_pairs_per_chunk``.

    Returns ``(pt, other)``, unique int64 arrays: ``pt`` indexes the concatenation of ``points``, and
    the point ``pt`` has a point of node ``other`` within ``theta``. Only pairs of nodes with at least
    one node in ``query`` (all when None) are searched, and both directions of those pairs are complete.
    """
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64))
    if not (np.isfinite(theta) and theta > 0):
        raise ValueError(f"proximity_ratios: theta must be positive, got {theta}")
    n_nodes = len(points)
    if n_nodes < 2:
        return empty
    clouds = [np.asarray(p, dtype=np.float64).reshape(-1, 3) for p in points]
    if sum(len(p) for p in clouds) == 0:
        return empty
    g = _HashGrid.build(clouds, theta)
    qsel = np.ones(n_nodes, dtype=bool)
    if query is not None:
        qsel[:] = False
        qsel[np.asarray(query, dtype=np.int64)] = True
    qidx = g.order[g.boundary_points() & qsel[g.owner[g.order]]]  # original indices of the query points
    if len(qidx) == 0:
        return empty
    found: list[np.ndarray] = []  # encoded (point index, other node), deduplicated per chunk
    step = max(1, int(max_pairs_per_chunk // max(1.0, 27.0 * float(g.counts.mean()))))
    for c0 in range(0, len(qidx), step):
        chunk = g.close_pairs(qidx[c0 : c0 + step], qsel, theta)
        if chunk.size:
            found.append(chunk)
    if not found:
        return empty
    codes = np.unique(np.concatenate(found))
    return np.divmod(codes, n_nodes)


@dataclass
class _HashGrid:
    """The points of all nodes in a uniform hash grid (cells of ``theta``), sorted by cell, then node."""

    n_nodes: int
    owner: np.ndarray  # node of each point
    ckey: np.ndarray  # cell key of each point
    order: np.ndarray  # point indices sorted by (cell, node)
    sokey: np.ndarray  # sorted (cell, node) keys
    ukeys: np.ndarray  # occupied cells, sorted
    starts: np.ndarray  # each occupied cell's first position in ``order``
    counts: np.ndarray  # points per occupied cell
    off_keys: np.ndarray  # key offsets of the 27 neighbouring cells
    P32: np.ndarray  # float32 points relative to the grid origin (plenty for cm-scale thresholds)

    @classmethod
    def build(cls, clouds: list[np.ndarray], theta: float) -> _HashGrid:
        n_nodes = len(clouds)
        sizes = np.array([len(p) for p in clouds], dtype=np.int64)
        P = np.concatenate(clouds, axis=0)
        owner = np.repeat(np.arange(n_nodes, dtype=np.int64), sizes)
        cells = np.floor((P - P.min(axis=0)) / theta).astype(np.int64) + 1  # +1: room for the -1 offset
        dims = cells.max(axis=0) + 2
        if float(np.prod(dims.astype(np.float64))) * n_nodes > 2.0**62:
            raise ValueError("proximity_ratios: scene extent / theta too large for the hash grid")
        ckey = (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2]
        okey = ckey * n_nodes + owner  # sort by cell, then by node inside a cell
        order = np.argsort(okey, kind="stable")
        ukeys, starts, counts = np.unique(ckey[order], return_index=True, return_counts=True)
        offsets = np.array([(dx, dy, dz) for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)])
        off_keys = (offsets[:, 0] * dims[1] + offsets[:, 1]) * dims[2] + offsets[:, 2]
        P32 = (P - P.min(axis=0)).astype(np.float32)
        return cls(n_nodes, owner, ckey, order, okey[order], ukeys, starts, counts, off_keys, P32)

    def boundary_points(self) -> np.ndarray:
        """Per point in sorted order: whether its cell or a neighbouring one holds another node's points
        (a single-node cell whose occupied neighbours hold only that node is "pure": skipped)."""
        ends = self.starts + self.counts
        omin = self.owner[self.order][self.starts]  # smallest / largest node id in each occupied cell
        omax = self.owner[self.order][ends - 1]
        mixed = omin != omax
        for dk in self.off_keys:
            pos = np.minimum(np.searchsorted(self.ukeys, self.ukeys + dk), len(self.ukeys) - 1)
            hit = self.ukeys[pos] == self.ukeys + dk
            mixed |= hit & ((omin[pos] != omin) | (omax[pos] != omin))
        return mixed[np.repeat(np.arange(len(self.ukeys)), self.counts)]

    def close_pairs(self, q: np.ndarray, qnode: np.ndarray, theta: float) -> np.ndarray:
        """Encoded (point, other node) pairs, unique, of the query points ``q`` with a point of another node
        within ``theta``. With every node queried (``qnode``), each close pair is met from both sides: only
        the query side is recorded then."""
        n_nodes, owner, ukeys = self.n_nodes, self.owner, self.ukeys
        theta2 = np.float32(theta * theta)
        ends = self.starts + self.counts
        qo = owner[q]
        found: list[np.ndarray] = []
        for dk in self.off_keys:
            nkey = self.ckey[q] + dk
            pos = np.minimum(np.searchsorted(ukeys, nkey), len(ukeys) - 1)
            hit = ukeys[pos] == nkey
            if not hit.any():
                continue
            qh, qoh, ph = q[hit], qo[hit], pos[hit]
            # the query node's own points form one sub-range of the cell: skip it
            own_lo = np.searchsorted(self.sokey, nkey[hit] * n_nodes + qoh, side="left")
            own_hi = np.searchsorted(self.sokey, nkey[hit] * n_nodes + qoh, side="right")
            for begin, count in ((self.starts[ph], own_lo - self.starts[ph]), (own_hi, ends[ph] - own_hi)):
                if not count.any():
                    continue
                which, spos = _expand_ranges(begin, count)
                a, b = qh[which], self.order[spos]
                d = self.P32[a] - self.P32[b]
                close = np.einsum("ij,ij->i", d, d) < theta2
                if close.any():
                    a, b = a[close], b[close]
                    ob = owner[b]
                    found.append(a * n_nodes + ob)  # the query point is near b's node
                    back = ~qnode[ob]  # b's node is not queried itself: record b near a's node here
                    if back.any():
                        found.append(b[back] * n_nodes + owner[a[back]])
        return np.unique(np.concatenate(found)) if found else np.zeros(0, np.int64)
