"""Culling: the binning leaves out tiles a Gaussian's alpha >= 1/255 ellipse misses, and the blending
kernels skip, per warp, the Gaussians of a batch that reach none of the warp's pixels.

On the CPU a warp is one thread, so the rasterizer and semantic tests only exercise one-pixel warps;
these tests pin the pieces of the 32-lane path (the warp's pixel rectangle, the ballot and bit helpers,
the ellipse test) on every device, and check that no test drops a Gaussian that blends at some pixel.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from ogscene3d.kernels.binning import tile_reached
from ogscene3d.kernels.lanes import bit_clear, bit_lowest, lane_ballot, lane_sum_int
from ogscene3d.kernels.raster import (
    alpha_extent,
    gaussian_alpha,
    gaussian_reaches,
    sigma_limit,
    tile_pixel,
    warp_reaches,
    warp_rect,
)

from ogscene3d.device import init_warp

wp = init_warp()


@wp.kernel(enable_backward=False)
def _rects(
    tile_size: int,
    tile_threads: int,
    tiles_x: int,
    tiles_per_cam: int,
    lanes: int,
    width: int,
    height: int,
    out_rect: wp.array(dtype=wp.vec4),
    out_pix: wp.array(dtype=wp.vec4i),
):
    tid = wp.tid()
    out_rect[tid] = warp_rect(tid, tile_size, tile_threads, tiles_x, tiles_per_cam, lanes)
    out_pix[tid] = tile_pixel(tid, tile_size, tile_threads, tiles_x, tiles_per_cam, width, height)


@wp.kernel(enable_backward=False)
def _bits(
    masks: wp.array(dtype=wp.int32),
    k: wp.array(dtype=wp.int32),
    low: wp.array(dtype=wp.int32),
    cleared: wp.array(dtype=wp.int32),
):
    i = wp.tid()
    low[i] = bit_lowest(masks[i])
    cleared[i] = bit_clear(masks[i], k[i])


@wp.kernel(enable_backward=False)
def _ballot(out: wp.array(dtype=wp.int32)):
    tid = wp.tid()
    out[tid] = lane_ballot(int(tid % 3 == 0))


@wp.kernel(enable_backward=False)
def _sum_int(values: wp.array(dtype=wp.int32), out: wp.array(dtype=wp.int32)):
    tid = wp.tid()
    out[tid] = lane_sum_int(values[tid])


@wp.kernel(enable_backward=False)
def _reach(
    means2d: wp.array(dtype=wp.vec2),
    conics: wp.array(dtype=wp.vec3),
    opacities: wp.array(dtype=float),
    rects: wp.array(dtype=wp.vec4),
    reaches: wp.array(dtype=wp.int32),
    exact: wp.array(dtype=wp.int32),
    one_pixel: wp.array(dtype=wp.int32),
    blends: wp.array(dtype=wp.int32),
):
    i = wp.tid()
    r = rects[i]
    ext = alpha_extent(conics[i], sigma_limit(opacities[i]))
    reaches[i] = gaussian_reaches(means2d[i], ext, r)
    exact[i] = warp_reaches(means2d[i], conics[i], opacities[i], ext, r, 32)
    one_pixel[i] = warp_reaches(means2d[i], conics[i], opacities[i], ext, r, 1)
    hit = int(0)
    y = r[2]
    while y <= r[3]:
        x = r[0]
        while x <= r[1]:
            if gaussian_alpha(conics[i], means2d[i], opacities[i], x, y)[0] > 0.0:
                hit = 1
            x += 1.0
        y += 1.0
    blends[i] = hit


@wp.kernel(enable_backward=False)
def _tiles(
    means2d: wp.array(dtype=wp.vec2),
    conics: wp.array(dtype=wp.vec3),
    limits: wp.array(dtype=float),
    tile_size: int,
    reached: wp.array(dtype=wp.int32),
    inside: wp.array(dtype=wp.int32),
):
    i = wp.tid()
    reached[i] = tile_reached(means2d[i], conics[i], limits[i], 0, 0, tile_size)
    hit = int(0)
    for y in range(tile_size):
        for x in range(tile_size):
            dx = means2d[i][0] - (float(x) + 0.5)
            dy = means2d[i][1] - (float(y) + 0.5)
            c = conics[i]
            if 0.5 * (c[0] * dx * dx + c[2] * dy * dy) + c[1] * dx * dy <= limits[i]:
                hit = 1
    inside[i] = hit


@pytest.mark.parametrize("tile_size", [1, 5, 8, 16, 24, 32])
@pytest.mark.parametrize("lanes", [1, 32])
def test_warp_rect_spans_the_warps_pixels(device: str, tile_size: int, lanes: int) -> None:
    width, height = 3 * tile_size - 2, 2 * tile_size + 1  # partial tiles on the right and bottom
    tiles_x, tiles_y = math.ceil(width / tile_size), math.ceil(height / tile_size)
    tile_threads = (tile_size * tile_size + 31) // 32 * 32
    n = tiles_x * tiles_y * tile_threads
    rects = wp.empty(n, dtype=wp.vec4, device=device)
    pix = wp.empty(n, dtype=wp.vec4i, device=device)
    wp.launch(
        _rects,
        dim=n,
        inputs=[tile_size, tile_threads, tiles_x, tiles_x * tiles_y, lanes, width, height],
        outputs=[rects, pix],
        device=device,
    )
    rects, pix = rects.numpy(), pix.numpy()
    for w0 in range(0, n, lanes):
        group = slice(w0, w0 + lanes)
        local = np.arange(w0, w0 + lanes) % tile_threads
        real = local < tile_size * tile_size  # spare threads own no pixel (image clipping aside)
        if not real.any():
            r = rects[group]
            assert np.all((r[:, 0] > r[:, 1]) | (r[:, 2] > r[:, 3]))  # an empty rectangle
            continue
        xy = pix[group][real][:, 2:4] + 0.5
        expect = [xy[:, 0].min(), xy[:, 0].max(), xy[:, 1].min(), xy[:, 1].max()]
        np.testing.assert_array_equal(rects[group], np.tile(expect, (lanes, 1)))


def test_bit_helpers(device: str) -> None:
    rng = np.random.default_rng(0)
    masks = np.concatenate([[0, 1, -(2**31), -1, 0b1010000], rng.integers(-(2**31), 2**31, 200)]).astype(
        np.int32
    )
    ks = rng.integers(0, 32, masks.size).astype(np.int32)
    ks[:5] = [3, 0, 31, 31, 4]
    low = wp.empty(masks.size, dtype=wp.int32, device=device)
    cleared = wp.empty(masks.size, dtype=wp.int32, device=device)
    wp.launch(
        _bits,
        dim=masks.size,
        inputs=[wp.array(masks, device=device), wp.array(ks, device=device)],
        outputs=[low, cleared],
        device=device,
    )
    u = masks.view(np.uint32).astype(np.int64)
    expect_low = [(int(m) & -int(m)).bit_length() - 1 for m in u]
    expect_cleared = (u & ~(np.int64(1) << ks.astype(np.int64)) & 0xFFFFFFFF).astype(np.uint32).view(np.int32)
    np.testing.assert_array_equal(low.numpy(), expect_low)
    np.testing.assert_array_equal(cleared.numpy(), expect_cleared)


def test_lane_ballot(device: str) -> None:
    out = wp.empty(64, dtype=wp.int32, device=device)
    wp.launch(_ballot, dim=64, outputs=[out], device=device, block_dim=64)
    got = out.numpy()
    if device == "cpu":  # a warp is one thread: its own bit
        np.testing.assert_array_equal(got, (np.arange(64) % 3 == 0).astype(np.int32))
    else:
        for w in range(2):
            bits = sum(1 << k for k in range(32) if (32 * w + k) % 3 == 0)
            expect = np.array([bits], dtype=np.uint32).view(np.int32)[0]
            assert np.all(got[32 * w : 32 * w + 32] == expect)


def test_lane_sum_int(device: str) -> None:
    values = np.random.default_rng(1).integers(-1000, 100000, 64).astype(np.int32)
    out = wp.empty(64, dtype=wp.int32, device=device)
    wp.launch(
        _sum_int, dim=64, inputs=[wp.array(values, device=device)], outputs=[out], device=device, block_dim=64
    )
    got = out.numpy()
    if device == "cpu":  # a warp is one thread: its own value
        np.testing.assert_array_equal(got, values)
    else:
        for w in range(2):
            assert np.all(got[32 * w : 32 * w + 32] == values[32 * w : 32 * w + 32].sum())


def _random_conics(n: int, g: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """Conics of random screen ellipses (any angle, 0.4-20 px, down to 5% as thin, plus eps2d) and their
    major sigmas."""
    ang = torch.rand(n, generator=g) * math.pi
    s1 = torch.exp(torch.rand(n, generator=g) * 4 - 1)
    s2 = s1 * torch.exp(-torch.rand(n, generator=g) * 3)
    c, s = torch.cos(ang), torch.sin(ang)
    rot = torch.stack([torch.stack([c, -s], -1), torch.stack([s, c], -1)], -2)
    cov = rot @ torch.diag_embed(torch.stack([s1, s2], -1) ** 2) @ rot.transpose(1, 2) + 0.3 * torch.eye(2)
    inv = torch.linalg.inv(cov)
    return torch.stack([inv[:, 0, 0], inv[:, 0, 1], inv[:, 1, 1]], -1), s1


def test_gaussian_reaches_keeps_every_gaussian_that_blends(device: str) -> None:
    """Random ellipses (thin, round, faint, near the ALPHA_MIN threshold) around 16x2 and 1x1 rectangles:
    a Gaussian that blends at any pixel centre of its rectangle is always kept, by the bounding-box test
    and by the exact ellipse test of multi-pixel warps."""
    g = torch.Generator().manual_seed(0)
    n = 20000
    conics, s1 = _random_conics(n, g)
    opac = torch.where(
        torch.rand(n, generator=g) < 0.2, torch.rand(n, generator=g) * 0.01, torch.rand(n, generator=g)
    )  # a fifth near or below 1/255
    wide = torch.rand(n, generator=g) < 0.5
    x0 = torch.floor(torch.rand(n, generator=g) * 64) + 0.5
    y0 = torch.floor(torch.rand(n, generator=g) * 64) + 0.5
    rects = torch.stack([x0, x0 + torch.where(wide, 15.0, 0.0), y0, y0 + torch.where(wide, 1.0, 0.0)], -1)
    centre = torch.stack([x0 + 8 * wide, y0 + wide.float()], -1)
    means = centre + (torch.rand(n, 2, generator=g) - 0.5) * 4 * s1[:, None].clamp(min=4)
    arrs = [
        wp.array(t.contiguous().numpy(), dtype=d, device=device)
        for t, d in ((means, wp.vec2), (conics, wp.vec3), (opac, float), (rects, wp.vec4))
    ]
    reaches = wp.empty(n, dtype=wp.int32, device=device)
    blends = wp.empty(n, dtype=wp.int32, device=device)
    exact = wp.empty(n, dtype=wp.int32, device=device)
    one_pixel = wp.empty(n, dtype=wp.int32, device=device)
    wp.launch(_reach, dim=n, inputs=arrs, outputs=[reaches, exact, one_pixel, blends], device=device)
    reaches, exact, one_pixel, blends = (a.numpy() for a in (reaches, exact, one_pixel, blends))
    assert blends.sum() > n // 5  # the scene is not all misses
    assert np.all(reaches[blends == 1] == 1) and np.all(exact[blends == 1] == 1)
    assert (reaches[blends == 0] == 0).mean() > 0.5  # the bounding box culls most misses
    assert np.all(exact <= reaches) and (exact < reaches).sum() > n // 50  # the ellipse culls more
    np.testing.assert_array_equal(one_pixel, reaches)  # one-pixel warps: the box only


def test_binning_leaves_out_tiles_where_alpha_stays_below_threshold(device: str) -> None:
    """The same Gaussian, opaque and faint: the faint one's alpha >= 1/255 region is smaller, so it is
    binned to fewer tiles; below 1/255 everywhere it is binned nowhere (and culled: gsplat's opacity-aware
    screen radius is 0 below opacity 1/255). The images still match the reference, which bins by the
    screen radius alone."""
    from reference_raster import rasterize as ref_rasterize
    from scenes import cameras

    from ogscene3d import rasterization

    means = torch.tensor([[0.05, -0.03, 2.0]], device=device)
    quats = torch.tensor([[1.0, 0, 0, 0]], device=device)
    scales = torch.tensor([[0.4, 0.25, 0.1]], device=device)
    colors = torch.tensor([[0.2, 0.7, 0.4]], device=device)
    vm, K = cameras(96, 80, device=device)
    tiles = []
    for o in (0.99, 0.02, 0.003):
        scene = [means, quats, scales, torch.tensor([o], device=device), colors]
        img, alpha, meta = rasterization(*scene, vm, K, 96, 80, tile_size=8)
        ref, ref_alpha = ref_rasterize(*scene, vm, K, 96, 80, tile_size=8)
        assert (img.cpu().double() - ref).abs().max() < 1e-4
        assert (int(meta["radii"][0, 0]) > 0) == (o >= 1 / 255)
        tiles.append(int(meta["tiles_per_gauss"].sum()))
    assert tiles[0] > tiles[1] > tiles[2] == 0


@pytest.mark.parametrize("tile_size", [8, 16])
def test_tile_reached_keeps_every_tile_with_a_pixel_inside_the_ellipse(device: str, tile_size: int) -> None:
    """Slanted, thin and round ellipses around a tile: a tile with a pixel centre where sigma <= t is
    always kept, and a tile only the ellipse's bounding box meets is left out."""
    g = torch.Generator().manual_seed(tile_size)
    n = 20000
    conics, _ = _random_conics(n, g)
    limits = torch.rand(n, generator=g) * 5.5
    means = (torch.rand(n, 2, generator=g) - 0.5) * 4 * tile_size + tile_size / 2
    arrs = [
        wp.array(t.contiguous().numpy(), dtype=d, device=device)
        for t, d in ((means, wp.vec2), (conics, wp.vec3), (limits, float))
    ]
    reached = wp.empty(n, dtype=wp.int32, device=device)
    inside = wp.empty(n, dtype=wp.int32, device=device)
    wp.launch(_tiles, dim=n, inputs=[*arrs, tile_size], outputs=[reached, inside], device=device)
    reached, inside = reached.numpy(), inside.numpy()
    assert inside.sum() > n // 10
    assert np.all(reached[inside == 1] == 1)
    # the continuous box is a little larger than its pixel centres, so a few more are kept
    assert (reached[inside == 0] == 1).mean() < 0.05
    det = conics[:, 0] * conics[:, 2] - conics[:, 1] ** 2
    ex = torch.sqrt(2 * limits * conics[:, 2] / det)
    ey = torch.sqrt(2 * limits * conics[:, 0] / det)
    lo, hi = 0.5, tile_size - 0.5
    box_meets = (
        (means[:, 0] + ex >= lo)
        & (means[:, 0] - ex <= hi)
        & (means[:, 1] + ey >= lo)
        & (means[:, 1] - ey <= hi)
    ).numpy()
    assert (box_meets & (reached == 0)).sum() > n // 50  # bounding-box-only tiles are dropped
