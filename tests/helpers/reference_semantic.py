"""Dense torch reference for semantic voting and P_conf, built as the paper writes it: one-hot K-vectors,
rendered R_p, and P_conf from autograd of L_sq = 1/2 sum_p |R_p|^2 and L_lin = sum_p sum_k R_p[k].
Alpha, tile restriction and early termination are the rasterizer's (reference_raster). float64."""

from __future__ import annotations

import torch
from reference_raster import project


def semantic_reference(
    means,
    quats,
    scales,
    opacities,
    labels,
    conf,
    viewmat,
    K,
    width,
    height,
    pixel_mask=None,
    eps=1e-6,
    tile_size=16,
    near=0.01,
    far=1e10,
    eps2d=0.3,
):
    """-> (label map [H, W] int64 (-1 none), R [H*W, Kc], classes [Kc], P_conf [N])."""
    f = torch.float64
    means, quats, scales, opacities, conf = (
        t.detach().cpu().to(f) for t in (means, quats, scales, opacities, conf)
    )
    labels = labels.detach().cpu().long()
    viewmat, K = viewmat.detach().cpu().to(f), K.detach().cpu().to(f)
    keep = torch.nonzero(labels >= 0).squeeze(1)
    classes, inv = torch.unique(labels[keep], return_inverse=True)
    S = torch.nn.functional.one_hot(inv, max(len(classes), 1)).to(f).requires_grad_(True)
    m2d, con, depth, radii = project(
        means[keep], quats[keep], scales[keep], opacities[keep], viewmat, K, width, height, near, far, eps2d
    )
    order = torch.argsort(depth)
    ys, xs = torch.meshgrid(torch.arange(height, dtype=f), torch.arange(width, dtype=f), indexing="ij")
    px, py = xs.reshape(-1) + 0.5, ys.reshape(-1) + 0.5
    tx, ty = (xs.reshape(-1) // tile_size), (ys.reshape(-1) // tile_size)
    tiles_x = (width + tile_size - 1) // tile_size
    tiles_y = (height + tile_size - 1) // tile_size
    m2d, con, radii = m2d[order], con[order], radii[order]
    op, cf, So = opacities[keep][order], conf[keep][order], S[order]
    x0 = torch.clamp(torch.floor((m2d[:, 0] - radii) / tile_size), 0, tiles_x)
    y0 = torch.clamp(torch.floor((m2d[:, 1] - radii) / tile_size), 0, tiles_y)
    x1 = torch.clamp(torch.ceil((m2d[:, 0] + radii) / tile_size), 0, tiles_x)
    y1 = torch.clamp(torch.ceil((m2d[:, 1] + radii) / tile_size), 0, tiles_y)
    in_tile = (
        (tx[:, None] >= x0) & (tx[:, None] < x1) & (ty[:, None] >= y0) & (ty[:, None] < y1) & (radii > 0)
    )
    dx = m2d[None, :, 0] - px[:, None]
    dy = m2d[None, :, 1] - py[:, None]
    sigma = 0.5 * (con[None, :, 0] * dx * dx + con[None, :, 2] * dy * dy) + con[None, :, 1] * dx * dy
    alpha = torch.clamp(op[None] * torch.exp(-sigma), max=0.99)
    alpha = torch.where(in_tile & (sigma >= 0) & (alpha >= 1 / 255), alpha, torch.zeros_like(alpha))
    ca = cf[None] * alpha
    T_after = torch.cumprod(1 - ca, dim=1)
    T_before = torch.cat([torch.ones_like(T_after[:, :1]), T_after[:, :-1]], 1)
    w = ca * T_before * (T_after > 1e-4)
    R = w @ So  # [P, Kc]
    mask = (
        torch.ones(height * width, dtype=torch.bool) if pixel_mask is None else pixel_mask.cpu().reshape(-1)
    )
    L_sq = 0.5 * (R[mask] ** 2).sum()
    L_lin = R[mask].sum()
    g_sq = torch.autograd.grad(L_sq, S, retain_graph=True)[0]
    g_lin = torch.autograd.grad(L_lin, S)[0]
    idx = torch.arange(len(keep))
    p_sub = g_sq[idx, inv] / (g_lin[idx, inv] + eps)
    p_conf = torch.zeros(len(labels), dtype=f)
    p_conf[keep] = p_sub
    R = R.detach()
    best_w, best_k = R.max(dim=1) if len(classes) else (torch.zeros(len(px), dtype=f), None)
    lab = torch.full((height * width,), -1, dtype=torch.long)
    if len(classes):
        lab = torch.where(best_w > 0, classes[best_k], lab)
    return lab.reshape(height, width), R, classes, p_conf
