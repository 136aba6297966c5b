"""Where gsplat (1.5) decides what a pixel sees, checked against its rules directly rather than against
our own reference: the opacity-aware screen radius (projection ``extend``), the tile bounds of
``isect_tiles`` and what follows from the two, that every pixel where alpha >= 1/255 is blended."""

import math

import torch
from reference_raster import project

from ogscene3d import rasterization


def _pinhole(width: int, height: int, f: float = 40.0) -> torch.Tensor:
    return torch.tensor([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]], dtype=torch.float32)


def test_screen_radius_is_gsplats_opacity_aware_box(device: str) -> None:
    """gsplat: per axis ceil(e * sqrt(cov2d_ii)), e = min(3.33, sqrt(2 ln(255 o))), 0 below o = 1/255;
    meta["radii"] holds the larger axis. Not ceil(3 sqrt(lambda_max)), whatever the opacity."""
    W, H, f, z = 48, 32, 40.0, 2.0
    sx, sy = 0.23, 0.11  # axis-aligned, on the optical axis: cov2d = diag((f s / z)^2) + eps2d
    opac = torch.tensor([1.0, 0.6, 0.05, 0.0045, 0.003])
    n = len(opac)
    means = torch.tensor([[0.0, 0.0, z]]).expand(n, 3).contiguous()
    quats = torch.tensor([[1.0, 0, 0, 0]]).expand(n, 4).contiguous()
    scales = torch.tensor([[sx, sy, 0.05]]).expand(n, 3).contiguous()
    colors = torch.ones(n, 3)
    args = [t.to(device) for t in (means, quats, scales, opac, colors)]
    vm, K = torch.eye(4)[None].to(device), _pinhole(W, H, f)[None].to(device)
    _, _, meta = rasterization(*args, vm, K, W, H)
    want = []
    for o in opac.tolist():
        if o < 1 / 255:
            want.append(0)
            continue
        e = min(3.33, math.sqrt(2 * math.log(255 * o)))
        rx = math.ceil(e * math.sqrt((f * sx / z) ** 2 + 0.3))
        ry = math.ceil(e * math.sqrt((f * sy / z) ** 2 + 0.3))
        want.append(max(rx, ry))
    assert meta["radii"][0].cpu().tolist() == want
    lam = (f * sx / z) ** 2 + 0.3
    assert want[0] != math.ceil(3 * math.sqrt(lam))  # the old radius differs here


def test_every_pixel_with_alpha_above_threshold_is_blended(device: str) -> None:
    """One opaque Gaussian (5 px sigma) seen from cameras that shift it by quarter pixels across a tile,
    and past the image's left edge: gsplat's radius box holds its whole alpha >= 1/255 ellipse (to
    3.33 sigma, beyond the 3 sqrt(lambda_max) square) and its tile bounds keep every tile with a pixel
    centre in the box, so the alpha image is the dense per-pixel formula whatever the tiles."""
    W, H, f, z = 48, 32, 40.0, 2.0
    o = 0.99
    shifts = [k * 0.25 for k in range(64)] + [-16.0, -16.4, -16.8]  # pixels, along x and y
    C = len(shifts)
    vms = torch.eye(4).repeat(C, 1, 1)
    for c, s in enumerate(shifts):
        vms[c, 0, 3] = s * z / f  # moves the centre by s px in x
        vms[c, 1, 3] = 0.5 * s * z / f  # and by s / 2 px in y
    Ks = _pinhole(W, H, f).repeat(C, 1, 1)
    means = torch.tensor([[0.0, 0.0, z]])
    quats = torch.tensor([[1.0, 0, 0, 0]])
    scales = torch.tensor([[0.25, 0.25, 0.25]])
    opac = torch.tensor([o])
    colors = torch.ones(1, 1)
    args = [t.to(device) for t in (means, quats, scales, opac, colors)]
    _, alphas, _ = rasterization(*args, vms.to(device), Ks.to(device), W, H)
    ys, xs = torch.meshgrid(
        torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64), indexing="ij"
    )
    for c in range(C):
        m2d, con, _, _ = project(
            means.double(),
            quats.double(),
            scales.double(),
            opac.double(),
            vms[c].double(),
            Ks[c].double(),
            W,
            H,
            0.01,
            1e10,
            0.3,
        )
        dx, dy = m2d[0, 0] - (xs + 0.5), m2d[0, 1] - (ys + 0.5)
        sigma = 0.5 * (con[0, 0] * dx * dx + con[0, 2] * dy * dy) + con[0, 1] * dx * dy
        a = o * torch.exp(-sigma)
        want = torch.where(a >= 1 / 255, a.clamp(max=0.99), torch.zeros_like(a))
        got = alphas[c, ..., 0].cpu().double()
        assert (got - want).abs().max() < 1e-5, f"shift {shifts[c]} px"
