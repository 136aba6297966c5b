"""Slow, dense torch reference of the rasterizer (same math as the Warp kernels), for tests only.

Every pixel evaluates every Gaussian of its camera; the tile restriction of the real rasterizer is
reproduced by masking Gaussians whose tile rectangle misses the pixel's tile. float64 throughout.
"""

from __future__ import annotations

import torch


def quat_to_rotmat(q: torch.Tensor) -> torch.Tensor:
    w, x, y, z = (q / q.norm(dim=-1, keepdim=True)).unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - w * z),
            2 * (x * z + w * y),
            2 * (x * y + w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z - w * x),
            2 * (x * z - w * y),
            2 * (y * z + w * x),
            1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(*q.shape[:-1], 3, 3)


def project(means, quats, scales, opacities, viewmat, K, width, height, near, far, eps2d):
    """-> means2d [N,2], conics [N,3], depths [N], radii [N] (0 = culled).

    gsplat's (1.5) screen radius: per axis ceil(e * sqrt(cov2d_ii)) with e = min(3.33, sqrt(2 ln(255 o))),
    opacity < 1/255 culled, radii the larger of the two."""
    R, t = viewmat[:3, :3], viewmat[:3, 3]
    p = means @ R.T + t
    x, y, z = p.unbind(-1)
    M = quat_to_rotmat(quats)
    RS = M * scales[:, None, :]
    cov_c = R @ (RS @ RS.transpose(1, 2)) @ R.T
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    tan_fx, tan_fy = 0.5 * width / fx, 0.5 * height / fy
    lxp, lxn = (width - cx) / fx + 0.3 * tan_fx, cx / fx + 0.3 * tan_fx
    lyp, lyn = (height - cy) / fy + 0.3 * tan_fy, cy / fy + 0.3 * tan_fy
    zs = torch.where(z > 0, z, torch.ones_like(z))
    tx = zs * torch.minimum(lxp, torch.maximum(-lxn, x / zs))
    ty = zs * torch.minimum(lyp, torch.maximum(-lyn, y / zs))
    zero = torch.zeros_like(zs)
    J = torch.stack([fx / zs, zero, -fx * tx / zs**2, zero, fy / zs, -fy * ty / zs**2], dim=-1).reshape(
        -1, 2, 3
    )
    cov2d = J @ cov_c @ J.transpose(1, 2)
    a = cov2d[:, 0, 0] + eps2d
    b = cov2d[:, 0, 1]
    d = cov2d[:, 1, 1] + eps2d
    det = a * d - b * b
    dets = torch.where(det > 0, det, torch.ones_like(det))
    conics = torch.stack([d / dets, -b / dets, a / dets], dim=-1)
    means2d = torch.stack([fx * x / zs + cx, fy * y / zs + cy], dim=-1)
    visible = (z > near) & (z < far) & (det > 0)
    o = opacities.detach()
    visible &= o >= 1.0 / 255.0
    extend = torch.clamp(torch.sqrt(2 * torch.log(torch.clamp(o * 255.0, min=1.0))), max=3.33)
    rx = torch.ceil(extend * torch.sqrt(a.detach()))
    ry = torch.ceil(extend * torch.sqrt(d.detach()))
    visible &= (rx > 0) | (ry > 0)
    mx, my = means2d[:, 0].detach(), means2d[:, 1].detach()
    visible &= ~((mx + rx <= 0) | (mx - rx >= width) | (my + ry <= 0) | (my - ry >= height))
    r = torch.maximum(rx, ry)
    radii = torch.where(visible, r, torch.zeros_like(r))
    return means2d, conics, z, radii


def rasterize(
    means,
    quats,
    scales,
    opacities,
    colors,
    viewmats,
    Ks,
    width,
    height,
    near_plane=0.01,
    far_plane=1e10,
    backgrounds=None,
    render_mode="RGB",
    eps2d=0.3,
    tile_size=16,
):
    """Reference for ogscene3d.rasterization (same arguments, same outputs without meta)."""
    f = torch.float64
    # on the CPU in float64 whatever the inputs' device (autograd carries gradients back to them)
    means, quats, scales, opacities = (t.to("cpu", f) for t in (means, quats, scales, opacities))
    viewmats, Ks = viewmats.to("cpu", f), Ks.to("cpu", f)
    C = viewmats.shape[0]
    if colors.dim() == 2:
        colors = colors.unsqueeze(0).expand(C, -1, -1)
    colors = colors.to("cpu", f)
    if backgrounds is not None:
        backgrounds = backgrounds.to("cpu", f)
    ys, xs = torch.meshgrid(torch.arange(height, dtype=f), torch.arange(width, dtype=f), indexing="ij")
    px, py = xs.reshape(-1) + 0.5, ys.reshape(-1) + 0.5
    tile_x = (xs.reshape(-1) // tile_size).long()
    tile_y = (ys.reshape(-1) // tile_size).long()
    tiles_x = (width + tile_size - 1) // tile_size
    tiles_y = (height + tile_size - 1) // tile_size
    outs, alphas = [], []
    for c in range(C):
        m2d, con, depth, radii = project(
            means, quats, scales, opacities, viewmats[c], Ks[c], width, height, near_plane, far_plane, eps2d
        )
        if render_mode in ("D", "ED"):
            feat = depth[:, None]
            bg = None
        elif render_mode in ("RGB+D", "RGB+ED"):
            feat = torch.cat([colors[c], depth[:, None]], -1)
            bg = None if backgrounds is None else torch.cat([backgrounds[c].to(f), torch.zeros(1, dtype=f)])
        else:
            feat = colors[c]
            bg = None if backgrounds is None else backgrounds[c].to(f)
        order = torch.argsort(depth.detach())
        m2d, con, radii, feat, op = m2d[order], con[order], radii[order], feat[order], opacities[order]
        # tile rectangle of each Gaussian's radius square, as gsplat's isect_tiles bounds it
        mx, my = m2d[:, 0].detach(), m2d[:, 1].detach()
        x0 = torch.clamp(torch.floor((mx - radii) / tile_size), 0, tiles_x)
        y0 = torch.clamp(torch.floor((my - radii) / tile_size), 0, tiles_y)
        x1 = torch.clamp(torch.ceil((mx + radii) / tile_size), 0, tiles_x)
        y1 = torch.clamp(torch.ceil((my + radii) / tile_size), 0, tiles_y)
        in_tile = (
            (tile_x[:, None] >= x0)
            & (tile_x[:, None] < x1)
            & (tile_y[:, None] >= y0)
            & (tile_y[:, None] < y1)
        ) & (radii > 0)
        dx = m2d[None, :, 0] - px[:, None]
        dy = m2d[None, :, 1] - py[:, None]
        sigma = 0.5 * (con[None, :, 0] * dx * dx + con[None, :, 2] * dy * dy) + con[None, :, 1] * dx * dy
        alpha = torch.clamp(op[None] * torch.exp(-sigma), max=0.99)
        valid = in_tile & (sigma >= 0) & (alpha >= 1.0 / 255.0)
        alpha = torch.where(valid, alpha, torch.zeros_like(alpha))
        one_minus = 1 - alpha
        T_after = torch.cumprod(one_minus, dim=1)
        T_before = torch.cat([torch.ones_like(T_after[:, :1]), T_after[:, :-1]], dim=1)
        # a Gaussian that would take T to <= 1e-4 is not blended and ends the pixel; T is monotone
        keep = T_after.detach() > 1e-4
        w = alpha * T_before * keep
        out = w @ feat
        T_final = torch.prod(torch.where(keep, one_minus, torch.ones_like(one_minus)), dim=1)
        if bg is not None:
            out = out + T_final[:, None] * bg[None]
        a_out = 1 - T_final
        if render_mode in ("ED", "RGB+ED"):
            out = torch.cat([out[:, :-1], out[:, -1:] / torch.clamp(a_out[:, None], min=1e-10)], -1)
        outs.append(out.reshape(height, width, -1))
        alphas.append(a_out.reshape(height, width, 1))
    return torch.stack(outs), torch.stack(alphas)
