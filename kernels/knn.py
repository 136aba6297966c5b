"""Radius-limited k-nearest-neighbour and radius-count queries on a Warp ``HashGrid``.

Each query thread walks the hash-grid cells within ``radius`` of its point and keeps the k closest
candidates in its own output row by insertion sort (k is small: 1..32); equidistant candidates are
ordered by index. An optional integer group per
point and per query filters candidates: ``group_mode`` 0 = no filter, 1 = only candidates of the same
group as the query, 2 = only candidates of a different group (used for "same label" radius graphs and
"nearest Gaussian outside my cluster" in the global refinement).

The torch-facing API is ``ogscene3d.mapping.neighbors``; this module holds kernels and launches only.
"""

from __future__ import annotations

import warp as wp

GROUP_NONE = 0
GROUP_SAME = 1
GROUP_DIFFERENT = 2


@wp.func
def _group_ok(mode: int, pg: int, qg: int) -> bool:
    if mode == 1:
        return pg == qg
    if mode == 2:
        return pg != qg
    return True


@wp.func
def _before(d2: float, index: int, od2: float, oindex: int) -> bool:
    """Order of candidates: by distance, equidistant ones by index, so that a row does not depend on the
    order in which the grid cells are visited (that is, on the cell size)."""
    return d2 < od2 or (d2 == od2 and index < oindex)


@wp.kernel(enable_backward=False)
def knn_radius_kernel(
    grid: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    queries: wp.array(dtype=wp.vec3),
    point_groups: wp.array(dtype=wp.int32),
    query_groups: wp.array(dtype=wp.int32),
    group_mode: int,
    radius: float,
    k: int,
    out_idx: wp.array2d(dtype=wp.int32),
    out_dist: wp.array2d(dtype=wp.float32),
):
    tid = wp.tid()
    q = queries[tid]
    qg = int(0)
    if group_mode != 0:
        qg = query_groups[tid]
    for j in range(k):
        out_idx[tid, j] = -1
        out_dist[tid, j] = 1.0e30
    r2 = radius * radius
    count = int(0)
    for index in wp.hash_grid_query(grid, q, radius):
        pg = int(0)
        if group_mode != 0:
            pg = point_groups[index]
        if _group_ok(group_mode, pg, qg):
            d2 = wp.length_sq(points[index] - q)
            if d2 <= r2:
                if count < k or _before(d2, index, out_dist[tid, k - 1], out_idx[tid, k - 1]):
                    pos = wp.min(count, k - 1)
                    # shift larger entries one slot to the right (the last one falls off when full)
                    while pos > 0 and _before(d2, index, out_dist[tid, pos - 1], out_idx[tid, pos - 1]):
                        out_idx[tid, pos] = out_idx[tid, pos - 1]
                        out_dist[tid, pos] = out_dist[tid, pos - 1]
                        pos = pos - 1
                    out_idx[tid, pos] = index
                    out_dist[tid, pos] = d2
                    count = wp.min(count + 1, k)
    for j in range(k):
        if out_idx[tid, j] >= 0:
            out_dist[tid, j] = wp.sqrt(out_dist[tid, j])
        else:
            out_dist[tid, j] = wp.inf


@wp.kernel(enable_backward=False)
def count_within_kernel(
    grid: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    queries: wp.array(dtype=wp.vec3),
    radius: float,
    stop_at: int,
    out_count: wp.array(dtype=wp.int32),
):
    tid = wp.tid()
    q = queries[tid]
    r2 = radius * radius
    c = int(0)
    for index in wp.hash_grid_query(grid, q, radius):
        if c < stop_at:
            if wp.length_sq(points[index] - q) <= r2:
                c = c + 1
    out_count[tid] = c


def launch_knn(
    grid: wp.HashGrid,
    points: wp.array,
    queries: wp.array,
    point_groups: wp.array,
    query_groups: wp.array,
    group_mode: int,
    radius: float,
    k: int,
    out_idx: wp.array,
    out_dist: wp.array,
    device,
) -> None:
    wp.launch(
        knn_radius_kernel,
        dim=queries.shape[0],
        inputs=[grid.id, points, queries, point_groups, query_groups, int(group_mode), float(radius), int(k)],
        outputs=[out_idx, out_dist],
        device=device,
    )


def launch_count_within(
    grid: wp.HashGrid,
    points: wp.array,
    queries: wp.array,
    radius: float,
    stop_at: int,
    out_count: wp.array,
    device,
) -> None:
    wp.launch(
        count_within_kernel,
        dim=queries.shape[0],
        inputs=[grid.id, points, queries, float(radius), int(stop_at)],
        outputs=[out_count],
        device=device,
    )
