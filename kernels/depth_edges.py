"""One round of moving segment border pixels onto depth edges, a thread per pixel.

The rule and its reasons are in ``ogscene3d.segmentation.depth_edges``, which owns the rounds; kernels and
launches only here. Depths are compared in float64, as the rule's reference (``tests/segmentation``) does,
so that a pixel at the margin goes the same way on every device.
"""

from __future__ import annotations

import warp as wp


@wp.func
def _depth(depth: wp.array2d(dtype=wp.float32), v: int, u: int) -> wp.float64:
    """The pixel's depth in float64, 0 where it has none (0, negative or not finite)."""
    z = depth[v, u]
    if not wp.isfinite(z) or z <= 0.0:
        return wp.float64(0.0)
    return wp.float64(z)


@wp.func
def _is_border(ids: wp.array2d(dtype=wp.int32), v: int, u: int) -> bool:
    """A pixel of a segment with a 4-neighbour of another id (the image's own edge is none)."""
    s = ids[v, u]
    h = ids.shape[0]
    w = ids.shape[1]
    if s <= 0:
        return False
    if v > 0 and ids[v - 1, u] != s:
        return True
    if v < h - 1 and ids[v + 1, u] != s:
        return True
    if u > 0 and ids[v, u - 1] != s:
        return True
    if u < w - 1 and ids[v, u + 1] != s:
        return True
    return False


@wp.func
def _is_inner(ids: wp.array2d(dtype=wp.int32), depth: wp.array2d(dtype=wp.float32), v: int, u: int) -> bool:
    """A pixel of a segment, with depth, whose 4-neighbours are all of its segment."""
    return ids[v, u] > 0 and not _is_border(ids, v, u) and _depth(depth, v, u) > wp.float64(0.0)


@wp.kernel(enable_backward=False)
def snap_round_kernel(
    ids: wp.array2d(dtype=wp.int32),
    depth: wp.array2d(dtype=wp.float32),
    margin: wp.float64,
    out: wp.array2d(dtype=wp.int32),
    moved: wp.array(dtype=wp.int32),
):
    """``out`` = ``ids`` with each border pixel that continues another segment's surface, and not its own,
    moved to that segment; ``moved[0]`` counts the pixels moved."""
    v, u = wp.tid()
    s = ids[v, u]
    out[v, u] = s
    z = _depth(depth, v, u)
    if z <= wp.float64(0.0) or not _is_border(ids, v, u):
        return
    h = ids.shape[0]
    w = ids.shape[1]
    inf = wp.float64(1.0e300)
    own = inf
    other = inf
    other_id = int(0)
    # the four axes, then the four diagonals (a box's corner pixel has its interior on a diagonal only)
    for k in range(8):
        dv = int(0)
        du = int(0)
        if k == 0:
            du = 1
        elif k == 1:
            du = -1
        elif k == 2:
            dv = 1
        elif k == 3:
            dv = -1
        elif k == 4:
            dv = 1
            du = 1
        elif k == 5:
            dv = 1
            du = -1
        elif k == 6:
            dv = -1
            du = 1
        else:
            dv = -1
            du = -1
        v2 = v + 2 * dv
        u2 = u + 2 * du
        if v2 < 0 or v2 >= h or u2 < 0 or u2 >= w:
            continue
        da = _depth(depth, v + dv, u + du)
        db = _depth(depth, v2, u2)
        if da <= wp.float64(0.0) or db <= wp.float64(0.0):
            continue
        off = wp.abs(z - (wp.float64(2.0) * da - db))
        a = ids[v + dv, u + du]
        b = ids[v2, u2]
        if a == s and b == s:
            if _is_inner(ids, depth, v + dv, u + du) and _is_inner(ids, depth, v2, u2):
                own = wp.min(own, off)
        elif a == b and a > 0 and off < other:
            other = off
            other_id = a
    if own < inf and own > margin and other < margin and other < wp.float64(0.5) * own:
        out[v, u] = other_id
        wp.atomic_add(moved, 0, 1)


def launch_snap_round(ids: wp.array, depth: wp.array, margin: float, out: wp.array, moved: wp.array, device):
    """One round: ``ids`` [H, W] int32 and ``depth`` [H, W] float32 in, ``out`` [H, W] int32 and
    ``moved`` [1] int32 (added to) out."""
    wp.launch(
        snap_round_kernel, dim=ids.shape, inputs=[ids, depth, wp.float64(margin), out, moved], device=device
    )
