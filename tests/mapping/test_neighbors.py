import numpy as np
import pytest
import torch
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ogscene3d.mapping.neighbors import any_within, count_within, knn, knn_components


def _brute_knn(points, queries, k, radius, pg=None, qg=None, mode=None):
    d = torch.cdist(queries.double(), points.double())
    ok = d <= radius
    if mode == "same":
        ok &= pg[None, :] == qg[:, None]
    elif mode == "different":
        ok &= pg[None, :] != qg[:, None]
    d = torch.where(ok, d, torch.full_like(d, float("inf")))
    dist, idx = torch.sort(d, dim=1)
    dist, idx = dist[:, :k], idx[:, :k]
    idx = torch.where(torch.isinf(dist), torch.full_like(idx, -1), idx)
    if dist.shape[1] < k:  # fewer points than k
        pad = k - dist.shape[1]
        dist = torch.cat([dist, torch.full((dist.shape[0], pad), float("inf"), dtype=dist.dtype)], 1)
        idx = torch.cat([idx, torch.full((idx.shape[0], pad), -1, dtype=idx.dtype)], 1)
    return idx, dist.float()


@pytest.mark.parametrize("k,radius", [(1, 0.2), (5, 0.15), (8, 0.5)])
def test_knn_matches_brute_force(device, k, radius):
    g = torch.Generator().manual_seed(k)
    points = torch.rand(400, 3, generator=g)
    queries = torch.rand(60, 3, generator=g) * 1.2 - 0.1
    idx, dist = knn(points.to(device), queries.to(device), k, radius)
    ref_idx, ref_dist = _brute_knn(points, queries, k, radius)
    assert idx.shape == (60, k) and idx.dtype == torch.int64
    assert torch.equal(idx.cpu(), ref_idx)
    torch.testing.assert_close(dist.cpu(), ref_dist, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("mode", ["same", "different"])
def test_knn_group_filter(device, mode):
    g = torch.Generator().manual_seed(3)
    points = torch.rand(300, 3, generator=g)
    queries = torch.rand(40, 3, generator=g)
    pg = torch.randint(0, 4, (300,), generator=g)
    qg = torch.randint(0, 4, (40,), generator=g)
    idx, dist = knn(points.to(device), queries.to(device), 4, 0.3, pg.to(device), qg.to(device), mode)
    ref_idx, ref_dist = _brute_knn(points, queries, 4, 0.3, pg, qg, mode)
    assert torch.equal(idx.cpu(), ref_idx)
    torch.testing.assert_close(dist.cpu(), ref_dist, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("mode", [None, "same"])
def test_knn_two_pass_equals_one_pass(device, mode):
    # dense points with a sparse corner (rows that the first pass leaves incomplete) and duplicated points
    # (equidistant candidates, ordered by index in either pass); enough queries to take the two-pass path
    g = torch.Generator().manual_seed(5)
    dense = torch.rand(6000, 3, generator=g) * torch.tensor([1.0, 1.0, 0.02])
    sparse = torch.rand(200, 3, generator=g) * 0.5 + 2.0
    points = torch.cat([dense, sparse, dense[:300]])
    queries = torch.cat([points[::2], torch.rand(100, 3, generator=g) * 3.0])
    pg = torch.randint(0, 3, (points.shape[0],), generator=g)
    qg = torch.randint(0, 3, (queries.shape[0],), generator=g)
    args = (points.to(device), queries.to(device), 6, 0.3, pg.to(device), qg.to(device), mode)
    idx, dist = knn(*args)
    idx2, dist2 = knn(*args, two_pass=True)
    assert torch.equal(idx, idx2) and torch.equal(dist, dist2)
    ref_idx, _ = _brute_knn(points, queries, 6, 0.3, pg, qg, mode)
    assert torch.equal((idx.cpu() >= 0).sum(1), (ref_idx >= 0).sum(1))


def test_knn_empty_and_fewer_than_k(device):
    pts = torch.tensor([[0.0, 0, 0], [0.05, 0, 0]], device=device)
    q = torch.tensor([[0.0, 0.0, 0.01], [5.0, 5.0, 5.0]], device=device)
    idx, dist = knn(pts, q, 3, 0.1)
    assert idx.cpu().tolist() == [[0, 1, -1], [-1, -1, -1]]
    assert torch.isinf(dist[1]).all() and torch.isinf(dist[0, 2])
    idx, _ = knn(torch.zeros(0, 3, device=device), q, 2, 0.1)
    assert (idx == -1).all()
    idx, _ = knn(pts, torch.zeros(0, 3, device=device), 2, 0.1)
    assert idx.shape == (0, 2)


def test_knn_bad_args():
    pts = torch.zeros(3, 3)
    with pytest.raises(ValueError, match="points"):
        knn(torch.zeros(3, 2), pts, 1, 0.1)
    with pytest.raises(ValueError, match="radius"):
        knn(pts, pts, 1, 0.0)
    with pytest.raises(ValueError, match="group"):
        knn(pts, pts, 1, 0.1, group_mode="same")


def test_count_and_any_within(device):
    g = torch.Generator().manual_seed(7)
    points = torch.rand(200, 3, generator=g)
    queries = torch.rand(50, 3, generator=g) * 2 - 0.5
    ref = (torch.cdist(queries, points) <= 0.12).sum(1).int()
    assert torch.equal(count_within(points.to(device), queries.to(device), 0.12).cpu(), ref)
    assert torch.equal(any_within(points.to(device), queries.to(device), 0.12).cpu(), ref > 0)


def test_knn_components_match_a_reference(device):
    # random sparse graphs, incl. long chains (many hops) and isolated vertices; reference: scipy's CC
    rng = np.random.default_rng(0)
    for v, k, density in [(1, 1, 1.0), (50, 3, 0.1), (3000, 4, 0.3), (3000, 2, 0.9)]:
        nbr = rng.integers(0, v, size=(v, k))
        nbr[rng.random((v, k)) > density] = -1
        nbr[: v // 2, 0] = np.arange(1, v // 2 + 1) % v  # a chain through the first half
        ok = nbr >= 0
        rows = np.repeat(np.arange(v), k)[ok.reshape(-1)]
        _, ref = connected_components(coo_matrix((np.ones(len(rows)), (rows, nbr[ok])), shape=(v, v)))
        smallest = np.full(ref.max() + 1, v)
        np.minimum.at(smallest, ref, np.arange(v))
        got = knn_components(torch.as_tensor(nbr, dtype=torch.int32, device=device)).cpu().numpy()
        np.testing.assert_array_equal(got, smallest[ref])
