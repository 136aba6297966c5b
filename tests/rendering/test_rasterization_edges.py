"""Edge cases and bad input for ogscene3d.rasterization."""

import math

import numpy as np
import pytest
import torch
from reference_raster import rasterize as ref_rasterize
from scenes import cameras, random_scene

from ogscene3d import rasterization


def test_no_gaussians_gives_background(device):
    vm, K = cameras(20, 10, count=2, device=device)
    empty = [
        torch.zeros(0, 3, device=device),
        torch.zeros(0, 4, device=device),
        torch.zeros(0, 3, device=device),
        torch.zeros(0, device=device),
        torch.zeros(0, 3, device=device),
    ]
    bg = torch.tensor([[0.1, 0.2, 0.3], [0.5, 0.5, 0.5]], device=device)
    img, alpha, meta = rasterization(*empty, vm, K, 20, 10, backgrounds=bg)
    assert img.shape == (2, 10, 20, 3)
    assert torch.allclose(img, bg[:, None, None, :].expand_as(img))
    assert alpha.abs().max() == 0
    assert meta["n_intersections"] == 0


def test_behind_and_outside_camera_are_culled(device):
    means = torch.tensor(
        [[0.0, 0.0, -3.0], [50.0, 0.0, 3.0], [0.0, 0.0, 0.005], [0.0, 0.0, 3.0]], device=device
    )
    quats = torch.tensor([[1.0, 0, 0, 0]] * 4, device=device)
    scales = torch.full((4, 3), 0.1, device=device)
    opac = torch.full((4,), 0.9, device=device)
    colors = torch.rand(4, 3, device=device)
    vm, K = cameras(32, 24, device=device)
    img, alpha, meta = rasterization(means, quats, scales, opac, colors, vm, K, 32, 24)
    radii = meta["radii"][0].cpu()
    assert radii[0] == 0 and radii[1] == 0 and radii[2] == 0 and radii[3] > 0
    only, only_alpha, _ = rasterization(means[3:], quats[3:], scales[3:], opac[3:], colors[3:], vm, K, 32, 24)
    assert torch.equal(img, only) and torch.equal(alpha, only_alpha)
    assert alpha.max() > 0.5


def test_huge_and_tiny_scales_match_reference(device):
    means, quats, scales, opac, colors = random_scene(30, seed=7, device=device)
    scales = scales.clone()
    scales[:5] = 3.0  # covers the whole image
    scales[5:10] = 1e-6  # sub-pixel: only eps2d keeps it visible
    scales[10:12] = 1e8  # a 3-sigma screen radius beyond int32 range (about 2.6e9 px)
    vm, K = cameras(40, 32, device=device)
    img, alpha, meta = rasterization(means, quats, scales, opac, colors, vm, K, 40, 32)
    ref, ref_alpha = ref_rasterize(means, quats, scales, opac, colors, vm, K, 40, 32)
    assert torch.isfinite(img).all()
    assert bool((meta["radii"] >= 0).all())  # no radius wrapped around to a negative int32
    assert (img.cpu().double() - ref).abs().mean() < 1e-3
    assert (alpha.cpu().double() - ref_alpha).abs().mean() < 1e-3


def test_alpha_is_clamped_at_099(device):
    means = torch.tensor([[0.0, 0.0, 3.0]], device=device)
    quats = torch.tensor([[1.0, 0, 0, 0]], device=device)
    scales = torch.full((1, 3), 2.0, device=device)  # ~9 px sigma: o * exp(-sigma) > 0.99 at the centre
    opac = torch.ones(1, device=device)
    colors = torch.ones(1, 3, device=device)
    vm, K = cameras(16, 16, device=device)
    img, alpha, _ = rasterization(means, quats, scales, opac, colors, vm, K, 16, 16)
    assert abs(float(alpha.max()) - 0.99) < 1e-5
    assert abs(float(img.max()) - 0.99) < 1e-5


def test_pixel_covered_by_thousands_of_gaussians(device):
    n = 1500
    g = torch.Generator().manual_seed(1)
    means = torch.zeros(n, 3)
    means[:, 2] = torch.linspace(2.0, 6.0, n)
    means[:, :2] = torch.randn(n, 2, generator=g) * 0.01
    quats = torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1)
    scales = torch.full((n, 3), 0.3)
    opac = torch.full((n,), 0.005)  # above 1/255 near the centre; 1500 layers leave T ~ 5e-4 > 1e-4
    colors = torch.rand(n, 3, generator=g)
    scene = [t.to(device) for t in (means, quats, scales, opac, colors)]
    vm, K = cameras(16, 16, device=device)
    params = [t.clone().requires_grad_(True) for t in scene]
    img, alpha, meta = rasterization(*params, vm, K, 16, 16)
    ref, ref_alpha = ref_rasterize(*scene, vm, K, 16, 16)
    assert int(meta["tiles_per_gauss"].sum()) >= n
    assert (img.cpu().double() - ref).abs().mean() < 1e-3
    assert 0.5 < float(alpha.detach().max()) < 1.0
    img.sum().backward()
    assert torch.isfinite(params[0].grad).all() and params[3].grad.abs().sum() > 0


def test_many_channels_and_per_camera_colors(device):
    means, quats, scales, opac, _ = random_scene(40, seed=11, device=device)
    vm, K = cameras(24, 20, count=2, device=device)
    colors = torch.rand(2, 40, 37, device=device)  # > one blending pass, per-camera colours
    params = [t.clone().requires_grad_(True) for t in (means, quats, scales, opac, colors)]
    out, alpha, _ = rasterization(*params, vm, K, 24, 20)
    ref, ref_alpha = ref_rasterize(means, quats, scales, opac, colors, vm, K, 24, 20)
    assert out.shape == (2, 20, 24, 37)
    assert (out.cpu().double() - ref).abs().mean() < 1e-3
    w = torch.randn_like(out)
    (out * w).sum().backward()
    ref_params = [
        t.detach().cpu().double().requires_grad_(True) for t in (means, quats, scales, opac, colors)
    ]
    r, _ = ref_rasterize(*ref_params, vm.cpu(), K.cpu(), 24, 20)
    (r * w.cpu().double()).sum().backward()
    for p, rp in zip(params, ref_params):
        a, b = p.grad.cpu().double().flatten(), rp.grad.flatten()
        assert float((a - b).norm() / b.norm()) < 1e-2


def _args(device, **over):
    means, quats, scales, opac, colors = random_scene(5, device=device)
    vm, K = cameras(16, 12, device=device)
    args = dict(
        means=means,
        quats=quats,
        scales=scales,
        opacities=opac,
        colors=colors,
        viewmats=vm,
        Ks=K,
        width=16,
        height=12,
    )
    args.update(over)
    return args


@pytest.mark.parametrize(
    "field,value,match",
    [
        ("means", torch.zeros(5, 2), "means"),
        ("quats", torch.zeros(4, 4), "quats"),
        ("scales", torch.zeros(5, 3, dtype=torch.float64), "scales"),
        ("opacities", torch.zeros(5, 1), "opacities"),
        ("colors", torch.zeros(6, 3), "colors"),
        ("viewmats", torch.zeros(1, 3, 4), "viewmats"),
        ("Ks", torch.zeros(2, 3, 3), "Ks"),
        ("width", 0, "width"),
        ("height", -3, "height"),
        ("width", 2.5, "width"),
        ("width", True, "width"),
        ("tile_size", 64, r"tile_size must be an int in \[1, 32\]"),
        ("tile_size", 8.0, "tile_size"),
    ],
)
def test_bad_shapes_and_sizes(field, value, match):
    args = _args("cpu", **{field: value})
    with pytest.raises(ValueError, match=match):
        rasterization(**args)


def test_meta_has_gsplats_keys(device):
    """The keys gsplat's densification strategies check for, with gsplat's meaning (not packed)."""
    means, quats, scales, opac, colors = random_scene(60, seed=5, device=device)
    vm, K = cameras(40, 30, count=2, device=device)
    means = means.clone().requires_grad_(True)
    img, _, meta = rasterization(means, quats, scales, opac, colors, vm, K, 40, 30, tile_size=8)
    for key in ["width", "height", "n_cameras", "radii", "gaussian_ids", "means2d"]:
        assert key in meta, key
    assert meta["gaussian_ids"] is None and meta["camera_ids"] is None
    C, N = 2, 60
    assert meta["means2d"].shape == (C, N, 2) and meta["radii"].shape == (C, N)
    assert meta["opacities"].shape == (C, N) and torch.equal(meta["opacities"][1], opac)
    ids = meta["flatten_ids"].long()
    assert ids.numel() == meta["n_intersections"] == int(meta["tiles_per_gauss"].sum()) > 0
    # tile t of camera c lists Gaussians of camera c that the projection kept, each as c * N + n
    tiles_per_cam = meta["tile_width"] * meta["tile_height"]
    for t in range(C * tiles_per_cam):
        span = ids[int(meta["tile_start"][t]) : int(meta["tile_end"][t])]
        assert bool((span // N == t // tiles_per_cam).all())
        assert bool((meta["radii"].reshape(-1)[span] > 0).all())
    # the screen-space gradient a strategy reads after backward
    meta["means2d"].retain_grad()
    img.sum().backward()
    assert meta["means2d"].grad.shape == (C, N, 2) and meta["means2d"].grad.abs().sum() > 0


def test_sizes_of_any_integer_type():
    """numpy and 0-dim torch integers pass where Python ints do (sizes often come from arrays)."""
    want, _, _ = rasterization(**_args("cpu"))
    for cast in (np.int64, np.int32, torch.tensor):
        args = _args("cpu")
        args.update(width=cast(args["width"]), height=cast(args["height"]), tile_size=cast(8))
        got, _, meta = rasterization(**args)
        assert torch.allclose(got, want, atol=1e-6)
        assert type(meta["width"]) is int and type(meta["tile_size"]) is int


@pytest.mark.parametrize("field", ["means", "quats", "scales", "opacities", "colors", "viewmats", "Ks"])
@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_nan_inf_rejected(field, bad):
    args = _args("cpu")
    t = args[field].clone()
    t.view(-1)[0] = bad
    args[field] = t
    with pytest.raises(ValueError, match=field):
        rasterization(**args)


def _set(t, index, value):
    t = t.clone()
    t[index] = value
    return t


@pytest.mark.parametrize(
    "field,index,value,message",
    [
        ("means", (2, 1), math.nan, "means contains NaN"),
        ("scales", (4, 2), 0.0, "scales must be positive"),
        ("quats", 1, 0.0, "zero quaternion"),
        ("Ks", (0, 1, 1), -5.0, "positive focal"),
        ("viewmats", (0, 2, 3), math.inf, "viewmats contains"),
        ("colors", (3, 0), math.nan, "colors contains"),
    ],
)
def test_value_checks_name_the_argument(device, field, index, value, message):
    # one kernel checks every value on the render's device; the verdict comes with the binning's sync
    args = _args(device)
    args[field] = _set(args[field], index, value)
    with pytest.raises(ValueError, match=message):
        rasterization(**args)
    bg = torch.zeros(1, 3, device=device)
    with pytest.raises(ValueError, match="backgrounds contains"):
        rasterization(**_args(device), backgrounds=_set(bg, (0, 2), math.nan))


def test_bad_mode_and_mixed_devices():
    with pytest.raises(ValueError, match="render_mode"):
        rasterization(**_args("cpu"), render_mode="RGBD")
    if torch.cuda.is_available():
        args = _args("cpu")
        args["colors"] = args["colors"].cuda()
        with pytest.raises(ValueError, match="colors"):
            rasterization(**args)
    with pytest.raises(ValueError, match="backgrounds"):
        rasterization(**_args("cpu"), backgrounds=torch.zeros(1, 4))
