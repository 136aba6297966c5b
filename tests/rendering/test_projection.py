"""The rendering package's projection internals (shared by the rasterizer and the semantic renderer): the
bare Warp array descriptors of launch arguments, and the tile sort."""

from __future__ import annotations

import pytest
import torch

from ogscene3d.device import init_warp
from ogscene3d.rendering import _projection as projection

wp = init_warp()


def _fields(arg) -> tuple:
    return arg.data, arg.grad, arg.ndim, arg.shape[0], arg.strides[0]


@pytest.mark.parametrize(
    "tensor,dtype,count,stride",
    [
        (torch.zeros(5, 3), wp.vec3, 5, 12),
        (torch.zeros(2, 4, 3), wp.vec3, 8, 12),
        (torch.zeros(6, 3, 3), wp.mat33, 6, 36),
        (torch.zeros(7, dtype=torch.int32), None, 7, 4),
        (torch.zeros(7), wp.float32, 7, 4),
        (torch.zeros(3, 8, dtype=torch.int32), wp.types.vector(length=8, dtype=wp.int32), 3, 32),
        (torch.zeros(4, dtype=torch.uint8), None, 4, 1),
    ],
)
def test_descriptor_matches_from_torch(tensor, dtype, count, stride, monkeypatch) -> None:
    arg = projection.as_wp(tensor, dtype)
    assert _fields(arg)[2:] == (1, count, stride)
    assert arg.data == arg.tensor.data_ptr() and arg.tensor.is_contiguous()
    monkeypatch.setattr(projection, "_array_descriptor", lambda: None)  # the wp.from_torch path
    assert _fields(projection.as_wp(tensor, dtype))[1:] == _fields(arg)[1:]


def test_non_contiguous_tensor_is_copied() -> None:
    t = torch.arange(12, dtype=torch.float32).reshape(3, 4).t()
    arg = projection.as_wp(t)
    assert arg.tensor.is_contiguous() and torch.equal(arg.tensor, t)


@pytest.mark.parametrize(
    "tensor,dtype",
    [
        (torch.zeros(3, dtype=torch.float64), None),
        (torch.zeros(3, 2), wp.vec2i),
        (torch.zeros(3), wp.int32),
        (torch.zeros(4, 4), wp.vec3),
        (torch.zeros(3, 9), wp.mat33),
    ],
)
def test_mismatched_dtype_is_refused(tensor, dtype) -> None:
    with pytest.raises(TypeError, match="cannot pass|trailing dims"):
        projection.as_wp(tensor, dtype)


@pytest.mark.parametrize("bit_range", [True, False])
def test_binning_sorts_by_tile_then_depth(device, bit_range, monkeypatch) -> None:
    """The radix sort runs over the key bits in use (tile index and depth) where Warp takes a bit range:
    every tile's list is front to back, and both paths give the same lists."""
    monkeypatch.setattr(projection, "_sort_takes_bit_range", lambda: bit_range)
    g = torch.Generator().manual_seed(3)
    C, N, W, H = 2, 3000, 300, 170  # 19 x 11 tiles per camera: 418 tiles, 9 bits
    means2d = (torch.rand(C, N, 2, generator=g) * torch.tensor([W, H])).to(device)
    conics = torch.tensor([0.05, 0.0, 0.05]).repeat(C, N, 1).to(device)
    opac = torch.full((N,), 0.9, device=device)
    radii = torch.randint(1, 40, (C, N), generator=g, dtype=torch.int32).to(device)
    depths = (torch.rand(C, N, generator=g) * 10 + 0.1).to(device)
    bins = projection.bin_gaussians(means2d, conics, opac, radii, depths, W, H, 16)
    ids = bins.isect_ids.long().cpu()
    tiles = torch.repeat_interleave(
        torch.arange(bins.tile_start.numel()), (bins.tile_end - bins.tile_start).cpu()
    )
    assert len(tiles) == len(ids) == int(bins.tiles_per_gaussian.sum())
    d = depths.reshape(-1).cpu()[ids]
    same_tile = tiles[1:] == tiles[:-1]
    assert torch.all(d[1:][same_tile] >= d[:-1][same_tile])
    assert (ids // N == tiles // (bins.tiles_x * bins.tiles_y)).all()  # each camera's Gaussians in its tiles


def test_binning_keeps_only_voters(device) -> None:
    """With ``voters`` the binning leaves out Gaussians of label < 0 or confidence 0 in every camera: the
    same tiles and lists as zeroing their radii, and no tiles of their own."""
    g = torch.Generator().manual_seed(4)
    C, N, W, H = 2, 2000, 200, 120
    means2d = (torch.rand(C, N, 2, generator=g) * torch.tensor([W, H])).to(device)
    conics = torch.tensor([0.05, 0.01, 0.08]).repeat(C, N, 1).to(device)
    opac = (torch.rand(N, generator=g) * 0.9 + 0.05).to(device)
    radii = torch.randint(1, 30, (C, N), generator=g, dtype=torch.int32).to(device)
    depths = (torch.rand(C, N, generator=g) * 10 + 0.1).to(device)
    labels = torch.randint(-1, 5, (N,), generator=g, dtype=torch.int32).to(device)
    conf = torch.where(torch.rand(N, generator=g) < 0.2, 0.0, torch.rand(N, generator=g)).to(device)
    votes = (labels >= 0) & (conf > 0)
    assert 0 < int(votes.sum()) < N
    bins = projection.bin_gaussians(means2d, conics, opac, radii, depths, W, H, 16, voters=(labels, conf))
    zeroed = torch.where(votes, radii, torch.zeros_like(radii))
    expect = projection.bin_gaussians(means2d, conics, opac, zeroed, depths, W, H, 16)
    assert torch.equal(bins.isect_ids, expect.isect_ids)
    assert torch.equal(bins.tile_start, expect.tile_start) and torch.equal(bins.tile_end, expect.tile_end)
    assert torch.equal(bins.tiles_per_gaussian, expect.tiles_per_gaussian)
    assert (bins.tiles_per_gaussian[:, ~votes] == 0).all() and (bins.extents[:, ~votes] < 0).all()
    assert int(bins.tiles_per_gaussian[:, votes].sum()) > 0
