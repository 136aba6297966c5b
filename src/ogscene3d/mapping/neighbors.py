"""Torch API over the Warp hash-grid neighbour kernels (``ogscene3d.kernels.knn``).

``knn``: for each query, the (up to) k nearest points within ``radius``, sorted by distance;
missing slots hold index -1 and distance inf. ``count_within``/``any_within``: how many points lie
within ``radius`` of each query. Both are exact (every point within the radius is examined).
``knn_components``: connected components of a KNN graph (``ogscene3d.kernels.components``).
"""

from __future__ import annotations

import torch

from ..device import warp_stream
from ..kernels.components import launch_components
from ..kernels.knn import launch_count_within, launch_knn

_GRID_DIM = 128
_grids: dict[str, object] = {}

GROUP_MODES = {None: 0, "same": 1, "different": 2}
# two-pass knn: queries sampled to size the first radius, and the quantile of their k-th distance used
_SAMPLE_QUERIES = 1024
_FIRST_PASS_QUANTILE = 0.95


def _grid_for(wdev, slot: int = 0) -> object:
    """One reusable hash grid per device and slot (slot 1: the finer grid of a two-pass ``knn``)."""
    import warp as wp

    key = f"{wdev}/{slot}"
    g = _grids.get(key)
    if g is None:
        g = wp.HashGrid(_GRID_DIM, _GRID_DIM, _GRID_DIM, device=wdev)
        _grids[key] = g
    return g


def _check_points(x: torch.Tensor, name: str) -> torch.Tensor:
    if not isinstance(x, torch.Tensor) or x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"{name} must be a [N, 3] tensor, got {getattr(x, 'shape', type(x))}")
    return x.detach().to(torch.float32).contiguous()


def knn(
    points: torch.Tensor,
    queries: torch.Tensor,
    k: int,
    radius: float,
    point_groups: torch.Tensor | None = None,
    query_groups: torch.Tensor | None = None,
    group_mode: str | None = None,
    two_pass: bool = False,
) -> tuple[torch.Tensor, torch.Tensor]:
    """k nearest ``points`` [N,3] within ``radius`` (metres) of each of ``queries`` [Q,3].

    ``group_mode``: None; "same" (only points whose ``point_groups`` equals the query's ``query_groups``)
    or "different". Returns (indices [Q,k] int64, -1 = none; distances [Q,k] float32, inf = none),
    each row sorted by increasing distance. Both tensors are on the queries' device. ``two_pass``: see
    ``knn_int32`` (for dense points and a radius far beyond the k-th neighbour).
    """
    idx, dist = knn_int32(points, queries, k, radius, point_groups, query_groups, group_mode, two_pass)
    return idx.long(), dist


def knn_int32(
    points: torch.Tensor,
    queries: torch.Tensor,
    k: int,
    radius: float,
    point_groups: torch.Tensor | None = None,
    query_groups: torch.Tensor | None = None,
    group_mode: str | None = None,
    two_pass: bool = False,
) -> tuple[torch.Tensor, torch.Tensor]:
    """``knn`` with the indices left int32, as the kernel writes them (no widening copy of [Q, k] for
    callers that hand them on to another kernel).

    ``two_pass``: for dense points and a ``radius`` much larger than the k-th neighbour distance (the
    refinement's same-label graph: 9 neighbours within about 2 cm, searched within 10 cm). A hash-grid
    query examines every point of the cells within the radius, ~(2 r)^2 of surface; a first pass with a
    radius r0 sized from a sample of queries (the 95% quantile of their k-th distance) examines far fewer,
    and every row that finds k neighbours within r0 is final: no point within ``radius`` that is nearer
    than its k-th can lie outside r0. Only the other rows are searched again within ``radius``. Same
    result as one pass (up to the order of exactly equidistant points)."""
    import warp as wp

    if k < 1:
        raise ValueError(f"knn: k must be >= 1, got {k}")
    if not radius > 0:
        raise ValueError(f"knn: radius must be > 0, got {radius}")
    if group_mode not in GROUP_MODES:
        raise ValueError(f"knn: group_mode must be None, 'same' or 'different', got {group_mode!r}")
    points = _check_points(points, "points")
    queries = _check_points(queries, "queries")
    dev = queries.device
    points = points.to(dev)
    q = queries.shape[0]
    if q == 0 or points.shape[0] == 0:
        idx = torch.full((q, k), -1, dtype=torch.int32, device=dev)
        return idx, torch.full((q, k), float("inf"), dtype=torch.float32, device=dev)
    mode = GROUP_MODES[group_mode]
    if mode:
        if point_groups is None or query_groups is None:
            raise ValueError("knn: group_mode needs point_groups and query_groups")
        if point_groups.shape != (points.shape[0],) or query_groups.shape != (q,):
            raise ValueError("knn: point_groups must be [N] and query_groups [Q]")
        pg = point_groups.to(dev, torch.int32).contiguous()
        qg = query_groups.to(dev, torch.int32).contiguous()
    else:
        pg = torch.zeros(1, dtype=torch.int32, device=dev)
        qg = pg
    with warp_stream(dev) as wdev:
        grid = _grid_for(wdev)
        wp_points = wp.from_torch(points, dtype=wp.vec3)
        grid.build(wp_points, float(radius))
        run = lambda g, qs, qgs, r: _launch(g, wp_points, qs, pg, qgs, mode, r, k, wdev)  # noqa: E731
        r0 = (
            _first_radius(run, grid, queries, qg, mode, radius, k)
            if two_pass and q > _SAMPLE_QUERIES
            else None
        )
        if r0 is None:
            return run(grid, queries, qg, radius)
        fine = _grid_for(wdev, 1)
        fine.build(wp_points, r0)
        idx, dist = run(fine, queries, qg, r0)
        redo = torch.nonzero(idx[:, k - 1] < 0).squeeze(1)
        if redo.numel():
            idx[redo], dist[redo] = run(
                grid, queries[redo].contiguous(), qg[redo].contiguous() if mode else qg, radius
            )
    return idx, dist


def _first_radius(
    run, grid, queries: torch.Tensor, qg: torch.Tensor, mode: int, radius: float, k: int
) -> float | None:
    """The first-pass radius of a two-pass ``knn`` from evenly spaced sample queries, or None when it would
    not be much smaller than ``radius`` (sparse points: one pass is cheaper)."""
    pick = torch.linspace(0, queries.shape[0] - 1, _SAMPLE_QUERIES, device=queries.device).long()
    _, d = run(grid, queries[pick].contiguous(), qg[pick].contiguous() if mode else qg, radius)
    r0 = float(torch.quantile(d[:, k - 1], _FIRST_PASS_QUANTILE))  # inf when over 5% find fewer than k
    return r0 if r0 < 0.5 * radius else None


def _launch(grid, wp_points, queries: torch.Tensor, pg, qg, mode: int, radius: float, k: int, wdev):
    """One knn kernel launch on a built grid: (idx [Q, k] int32, dist [Q, k]); the kernel fills both."""
    import warp as wp


    q = queries.shape[0]
    idx = torch.empty((q, k), dtype=torch.int32, device=queries.device)
    dist = torch.empty((q, k), dtype=torch.float32, device=queries.device)
    launch_knn(
        grid,
        wp_points,
        wp.from_torch(queries, dtype=wp.vec3),
        wp.from_torch(pg),
        wp.from_torch(qg),
        mode,
        radius,
        k,
        wp.from_torch(idx),
        wp.from_torch(dist),
        wdev,
    )
    return idx, dist


def knn_components(nbr: torch.Tensor) -> torch.Tensor:
    """Connected components of the graph on V vertices whose edges are (i, nbr[i, j]) for nbr [V, k] int32
    (-1 = no edge; edges are undirected): per vertex, the smallest vertex of its component (int32 [V])."""
    import warp as wp


    nbr = nbr.to(torch.int32).contiguous()
    parent = torch.arange(nbr.shape[0], dtype=torch.int32, device=nbr.device)
    if nbr.numel() == 0:
        return parent
    with warp_stream(nbr.device) as wdev:
        launch_components(wp.from_torch(nbr), wp.from_torch(parent), wdev)
    return parent


def count_within(
    points: torch.Tensor, queries: torch.Tensor, radius: float, stop_at: int = 2**30
) -> torch.Tensor:
    """Number of ``points`` [N,3] within ``radius`` of each query [Q,3] (int32 [Q]), counting stops at
    ``stop_at`` (use 1 for a pure any-within test)."""
    import warp as wp


    if not radius > 0:
        raise ValueError(f"count_within: radius must be > 0, got {radius}")
    points = _check_points(points, "points")
    queries = _check_points(queries, "queries")
    dev = queries.device
    points = points.to(dev)
    out = torch.zeros(queries.shape[0], dtype=torch.int32, device=dev)
    if queries.shape[0] == 0 or points.shape[0] == 0:
        return out
    with warp_stream(dev) as wdev:
        grid = _grid_for(wdev)
        wp_points = wp.from_torch(points, dtype=wp.vec3)
        grid.build(wp_points, float(radius))
        launch_count_within(
            grid, wp_points, wp.from_torch(queries, dtype=wp.vec3), radius, stop_at, wp.from_torch(out), wdev
        )
    return out


def any_within(points: torch.Tensor, queries: torch.Tensor, radius: float) -> torch.Tensor:
    """Bool [Q]: whether any of ``points`` lies within ``radius`` of each query."""
    return count_within(points, queries, radius, stop_at=1) > 0
