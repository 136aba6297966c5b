"""Connected components of a graph by a lock-free union-find (one pass over the edges, no iterations).

``parent[i] <= i`` always holds: a union hooks the larger of two roots under the smaller one with an
atomic min, so every tree's root is the smallest vertex of its tree and, once all edges are united and
the paths compressed, ``parent[i]`` is the smallest vertex of i's component: the same answer as min-label
propagation, without its O(diameter) rounds over every edge (the graphs of dense surfaces have a diameter
of hundreds of hops).

An atomic min that finds its vertex no longer a root (another thread hooked it first) has replaced that
link by its own; the union then continues with the replaced parent, so no link is lost. Path halving in
``_find`` also only moves pointers to smaller vertices of the same set, via atomic min for the same reason.

The torch-facing API is ``ogscene3d.mapping.refine.connected_clusters``; kernels and launches only here.
"""

from __future__ import annotations

import warp as wp


@wp.func
def _find(parent: wp.array(dtype=wp.int32), x: int) -> int:
    p = parent[x]
    while p != x:
        gp = parent[p]
        if gp != p:
            wp.atomic_min(parent, x, gp)  # path halving: x skips its parent
        x = p
        p = parent[x]
    return x


@wp.kernel(enable_backward=False)
def union_knn_edges_kernel(nbr: wp.array2d(dtype=wp.int32), parent: wp.array(dtype=wp.int32)):
    """Unite row i with every neighbour nbr[i, j] >= 0 (a KNN result: [V, k], -1 = none)."""
    i, j = wp.tid()
    b = nbr[i, j]
    if b < 0:
        return
    a = i
    while True:
        ra = _find(parent, a)
        rb = _find(parent, b)
        if ra == rb:
            return
        lo = wp.min(ra, rb)
        hi = wp.max(ra, rb)
        old = wp.atomic_min(parent, hi, lo)
        if old == hi:
            return  # hi was still a root: hooked
        # hi had meanwhile been hooked under old; unite old with lo instead (hi now points at lo)
        a = old
        b = lo


@wp.kernel(enable_backward=False)
def compress_kernel(parent: wp.array(dtype=wp.int32)):
    i = wp.tid()
    parent[i] = _find(parent, i)


def launch_components(nbr: wp.array, parent: wp.array, device) -> None:
    """``parent`` [V] must hold 0..V-1; on return parent[i] is the smallest vertex of i's component."""
    wp.launch(union_knn_edges_kernel, dim=nbr.shape, inputs=[nbr, parent], device=device)
    wp.launch(compress_kernel, dim=parent.shape[0], inputs=[parent], device=device)
