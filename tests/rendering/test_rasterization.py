"""The Warp rasterizer against the dense torch reference: forward images and gradients, cpu and cuda."""

import pytest
import torch
from reference_raster import rasterize as ref_rasterize
from scenes import cameras, random_scene

from ogscene3d import rasterization


def _cos(a: torch.Tensor, b: torch.Tensor) -> float:
    a, b = a.flatten().double(), b.flatten().double()
    return float((a @ b) / (a.norm() * b.norm() + 1e-30))


def _rel(a: torch.Tensor, b: torch.Tensor) -> float:
    a, b = a.flatten().double(), b.flatten().double()
    return float((a - b).norm() / (b.norm() + 1e-30))


@pytest.mark.parametrize("n,width,height", [(1, 64, 48), (37, 97, 61), (500, 64, 48), (200, 97, 61)])
def test_forward_matches_reference(device, n, width, height):
    means, quats, scales, opac, colors = random_scene(n, seed=n, device=device)
    vm, K = cameras(width, height, device=device)
    img, alpha, meta = rasterization(means, quats, scales, opac, colors, vm, K, width, height)
    ref_img, ref_alpha = ref_rasterize(means, quats, scales, opac, colors, vm, K, width, height)
    assert img.shape == (1, height, width, 3) and alpha.shape == (1, height, width, 1)
    assert (img.cpu().double() - ref_img).abs().mean() < 1e-3
    assert (alpha.cpu().double() - ref_alpha).abs().mean() < 1e-3
    assert meta["n_intersections"] > 0
    assert alpha.max() > 0.1  # the scene is actually in view


@pytest.mark.parametrize("mode", ["RGB", "D", "ED", "RGB+D", "RGB+ED"])
def test_render_modes_and_background(device, mode):
    means, quats, scales, opac, colors = random_scene(80, seed=3, device=device)
    vm, K = cameras(40, 30, count=2, device=device)
    bg = torch.tensor([[0.2, 0.4, 0.9], [1.0, 0.0, 0.5]], device=device)
    out, alpha, _ = rasterization(
        means, quats, scales, opac, colors, vm, K, 40, 30, backgrounds=bg, render_mode=mode
    )
    ref, ref_alpha = ref_rasterize(
        means, quats, scales, opac, colors, vm, K, 40, 30, backgrounds=bg, render_mode=mode
    )
    expect_channels = {"RGB": 3, "D": 1, "ED": 1, "RGB+D": 4, "RGB+ED": 4}[mode]
    assert out.shape == (2, 30, 40, expect_channels)
    err = (out.cpu().double() - ref).abs()
    if mode.endswith("ED"):
        # expected depth divides by alpha: compare where the pixel is meaningfully covered
        err = err[(ref_alpha > 0.05).expand_as(err)]
    assert err.mean() < 1e-3
    assert (alpha.cpu().double() - ref_alpha).abs().mean() < 1e-3


@pytest.mark.parametrize(
    "n,width,height,mode", [(60, 64, 48, "RGB"), (150, 97, 61, "RGB+ED"), (25, 33, 17, "D")]
)
def test_gradients_match_reference(device, n, width, height, mode):
    torch.manual_seed(n)
    scene = random_scene(n, seed=100 + n, device=device)
    vm, K = cameras(width, height, count=2 if mode == "RGB+ED" else 1, device=device)
    bg = torch.rand(vm.shape[0], 3, device=device) if mode == "RGB" else None
    params = [t.clone().requires_grad_(True) for t in scene]
    out, alpha, _ = rasterization(*params, vm, K, width, height, backgrounds=bg, render_mode=mode)
    w_out = torch.randn_like(out)
    w_alpha = torch.randn_like(alpha)
    valid = torch.isfinite(out)
    loss = (out * w_out)[valid].sum() + (alpha * w_alpha).sum()
    grads = torch.autograd.grad(loss, params, allow_unused=True)

    ref_params = [t.detach().cpu().double().requires_grad_(True) for t in scene]
    ref_out, ref_alpha = ref_rasterize(
        *ref_params,
        vm.cpu(),
        K.cpu(),
        width,
        height,
        backgrounds=None if bg is None else bg.cpu(),
        render_mode=mode,
    )
    ref_loss = (ref_out * w_out.cpu().double())[valid.cpu()].sum() + (
        ref_alpha * w_alpha.cpu().double()
    ).sum()
    ref_grads = torch.autograd.grad(ref_loss, ref_params, allow_unused=True)
    for name, g, rg in zip(["means", "quats", "scales", "opacities", "colors"], grads, ref_grads):
        if mode == "D" and name == "colors":
            assert g is None and rg is None  # depth-only rendering does not read colours
            continue
        g = g.cpu()
        assert torch.isfinite(g).all(), name
        assert _cos(g, rg) > 0.99, (name, _cos(g, rg))
        assert _rel(g, rg) < 1e-2, (name, _rel(g, rg))


@pytest.mark.parametrize("mode", ["RGB", "RGB+ED"])
def test_viewmat_gradients_match_reference(device, mode):
    """Camera-pose gradients (as gsplat gives them), per camera of a two-camera batch."""
    means, quats, scales, opac, colors = random_scene(80, seed=7, device=device)
    vm, K = cameras(48, 36, count=2, device=device)
    vm = vm.clone().requires_grad_(True)
    out, alpha, _ = rasterization(means, quats, scales, opac, colors, vm, K, 48, 36, render_mode=mode)
    torch.manual_seed(1)
    w_out, w_alpha = torch.randn_like(out), torch.randn_like(alpha)
    valid = torch.isfinite(out)
    (g,) = torch.autograd.grad((out * w_out)[valid].sum() + (alpha * w_alpha).sum(), [vm])

    ref_vm = vm.detach().cpu().double().requires_grad_(True)
    ref_out, ref_alpha = ref_rasterize(
        means, quats, scales, opac, colors, ref_vm, K.cpu(), 48, 36, render_mode=mode
    )
    ref_loss = (ref_out * w_out.cpu().double())[valid.cpu()].sum() + (
        ref_alpha * w_alpha.cpu().double()
    ).sum()
    (rg,) = torch.autograd.grad(ref_loss, [ref_vm])
    g = g.cpu()
    assert g.shape == (2, 4, 4) and torch.isfinite(g).all()
    assert all(float(rg[c].abs().sum()) > 0 for c in range(2))  # both cameras' poses matter
    for c in range(2):
        assert _cos(g[c], rg[c]) > 0.99, (c, _cos(g[c], rg[c]))
        assert _rel(g[c], rg[c]) < 1e-2, (c, _rel(g[c], rg[c]))


@pytest.mark.parametrize("tile_size", [5, 8, 24, 32])
def test_other_tile_sizes_match_reference(device, tile_size):
    # 5x5 = 25 pixels: on CUDA a tile's threads are padded to whole 32-lane warps (rows of pixels); sides
    # that are multiples of 8 put each warp on an 8x4 block (24: three across); a 32x32 tile spans four
    # 256-thread blocks. Images and gradients must not depend on that layout
    scene = random_scene(90, seed=tile_size, device=device)
    vm, K = cameras(45, 37, device=device)
    params = [t.clone().requires_grad_(True) for t in scene]
    out, alpha, meta = rasterization(*params, vm, K, 45, 37, tile_size=tile_size)
    assert meta["tile_size"] == tile_size
    w_out = torch.randn_like(out)
    grads = torch.autograd.grad((out * w_out).sum() + alpha.sum(), params)

    ref_params = [t.detach().cpu().double().requires_grad_(True) for t in scene]
    ref_out, ref_alpha = ref_rasterize(*ref_params, vm.cpu(), K.cpu(), 45, 37, tile_size=tile_size)
    assert (out.cpu().double() - ref_out).abs().mean() < 1e-3
    assert (alpha.cpu().double() - ref_alpha).abs().mean() < 1e-3
    ref_grads = torch.autograd.grad((ref_out * w_out.cpu().double()).sum() + ref_alpha.sum(), ref_params)
    for name, g, rg in zip(["means", "quats", "scales", "opacities", "colors"], grads, ref_grads):
        assert _cos(g.cpu(), rg) > 0.99, name
        assert _rel(g.cpu(), rg) < 1e-2, name
