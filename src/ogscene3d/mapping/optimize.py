"""Geometry/appearance optimization of the Gaussians after each keyframe (paper Sec. III-B.4).

L = lambda_c * ((1 - lambda) * |C - C_obs|_1 + lambda * (1 - SSIM(C, C_obs))) + lambda_d * |D - D_obs|_1,
with the depth term over valid observed depth only (D is the expected depth, sum d_i w_i / sum w_i, where
the paper writes the accumulated sum d_i w_i: partly covered pixels are judged by their depth, not pushed to
full opacity by it), averaged over the current keyframe and a few memory
frames rendered together (one batched ``rasterization`` call). Adam with per-group learning rates (the
paper's: scales 0.001, opacity 0.05, colour 0.0001; means and rotations from the config). Only the
Gaussians that project into at least one of the views are optimised (the others get no gradient anyway);
the optimizer state is rebuilt for each keyframe, as the set of Gaussians changes between keyframes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from ..config import OptimizeConfig
from ..rendering import rasterization


@dataclass
class View:
    """One training view: observed RGB [H,W,3] in [0,1], depth [H,W] (0 = invalid), w2c [4,4], K [3,3]."""

    rgb: torch.Tensor
    depth: torch.Tensor
    viewmat: torch.Tensor
    K: torch.Tensor

    @classmethod
    def from_arrays(
        cls, rgb: np.ndarray, depth: np.ndarray, pose_c2w: np.ndarray, K: np.ndarray, device: torch.device
    ) -> View:
        return cls(
            torch.as_tensor(rgb, device=device).float() / 255.0,
            torch.as_tensor(np.ascontiguousarray(depth), dtype=torch.float32, device=device),
            torch.as_tensor(np.linalg.inv(pose_c2w), dtype=torch.float32, device=device),
            torch.as_tensor(np.asarray(K), dtype=torch.float32, device=device),
        )


def _gaussian_window(size: int, sigma: float, channels: int, device) -> torch.Tensor:
    x = torch.arange(size, dtype=torch.float32, device=device) - (size - 1) / 2
    g = torch.exp(-(x**2) / (2 * sigma**2))
    g = g / g.sum()
    w = g[:, None] * g[None, :]
    return w.expand(channels, 1, size, size).contiguous()


def ssim(a: torch.Tensor, b: torch.Tensor, window: int = 11, sigma: float = 1.5) -> torch.Tensor:
    """Mean SSIM of images [B,C,H,W] in [0,1] (Gaussian 11x11 window, as in 3DGS)."""
    c = a.shape[1]
    w = _gaussian_window(window, sigma, c, a.device)
    pad = window // 2
    mu_a = F.conv2d(a, w, padding=pad, groups=c)
    mu_b = F.conv2d(b, w, padding=pad, groups=c)
    saa = F.conv2d(a * a, w, padding=pad, groups=c) - mu_a**2
    sbb = F.conv2d(b * b, w, padding=pad, groups=c) - mu_b**2
    sab = F.conv2d(a * b, w, padding=pad, groups=c) - mu_a * mu_b
    c1, c2 = 0.01**2, 0.03**2
    s = ((2 * mu_a * mu_b + c1) * (2 * sab + c2)) / ((mu_a**2 + mu_b**2 + c1) * (saa + sbb + c2))
    return s.mean()


def mapping_loss(
    render_rgb: torch.Tensor,
    render_depth: torch.Tensor,
    views: list[View],
    lambda_c: float,
    lambda_d: float,
    ssim_lambda: float,
) -> torch.Tensor:
    """The paper's loss for renders [C,H,W,3] and [C,H,W] against ``views``."""
    obs_rgb = torch.stack([v.rgb for v in views])
    obs_d = torch.stack([v.depth for v in views])
    l1 = (render_rgb - obs_rgb).abs().mean()
    s = ssim(render_rgb.permute(0, 3, 1, 2), obs_rgb.permute(0, 3, 1, 2))
    lc = (1 - ssim_lambda) * l1 + ssim_lambda * (1 - s)
    valid = obs_d > 0
    ld = (render_depth - obs_d).abs()[valid].mean() if bool(valid.any()) else render_depth.sum() * 0
    return lambda_c * lc + lambda_d * ld


def optimize_map(gm, views: list[View], cfg: OptimizeConfig, iters: int | None = None) -> dict[str, float]:
    """Run ``iters`` (default ``cfg.iters``) Adam steps on ``gm`` (a GaussianMap) over ``views``
    (all of one image size). Writes the optimised parameters back into the map. Returns first/last loss."""
    iters = cfg.iters if iters is None else int(iters)
    out = {"iters": 0, "loss_first": float("nan"), "loss_last": float("nan"), "optimized": 0}
    if iters <= 0 or len(gm) == 0 or not views:
        return out
    h, w = views[0].depth.shape
    if any(tuple(v.depth.shape) != (h, w) for v in views):
        raise ValueError("optimize_map: all views must have the same image size")
    viewmats = torch.stack([v.viewmat for v in views])
    Ks = torch.stack([v.K for v in views])

    with torch.no_grad():
        _, _, meta = rasterization(
            gm.means,
            gm.quats,
            gm.scales,
            gm.opacities,
            gm.colors[:, :1],
            viewmats,
            Ks,
            w,
            h,
            render_mode="RGB",
        )
        sel = torch.nonzero((meta["radii"] > 0).reshape(len(views), -1).any(dim=0)).squeeze(1)
    if sel.numel() == 0:
        return out
    params = {
        "means": torch.nn.Parameter(gm.means[sel].clone()),
        "quats": torch.nn.Parameter(gm.quats[sel].clone()),
        "log_scales": torch.nn.Parameter(gm.log_scales[sel].clone()),
        "opacity_logits": torch.nn.Parameter(gm.opacity_logits[sel].clone()),
        "colors": torch.nn.Parameter(gm.colors[sel].clone()),
    }
    lrs = {
        "means": cfg.lr_means,
        "quats": cfg.lr_quats,
        "log_scales": cfg.lr_scales,
        "opacity_logits": cfg.lr_opacities,
        "colors": cfg.lr_colors,
    }
    opt = torch.optim.Adam([{"params": [p], "lr": lrs[k], "name": k} for k, p in params.items()], eps=1e-15)
    for it in range(iters):
        opt.zero_grad(set_to_none=True)
        render, _, _ = rasterization(
            params["means"],
            F.normalize(params["quats"], dim=-1),
            params["log_scales"].exp(),
            torch.sigmoid(params["opacity_logits"]),
            params["colors"],
            viewmats,
            Ks,
            w,
            h,
            render_mode="RGB+ED",
        )
        loss = mapping_loss(
            render[..., :3], render[..., 3], views, cfg.lambda_c, cfg.lambda_d, cfg.ssim_lambda
        )
        if not torch.isfinite(loss):
            break  # keep the last finite parameters rather than poisoning the map
        loss.backward()
        opt.step()
        if it == 0:
            out["loss_first"] = float(loss.detach())
        out["loss_last"] = float(loss.detach())
        out["iters"] = it + 1
    with torch.no_grad():
        params["colors"].clamp_(0.0, 1.0)
        for k, p in params.items():
            gm.field(k)[sel] = p.detach()
    out["optimized"] = int(sel.numel())
    return out


def training_views(
    frame, pool: list, count: int, rng: np.random.Generator, device: torch.device
) -> list[View]:
    """The keyframe ``frame``'s view and up to ``count`` views drawn by ``rng`` from ``pool`` (memory
    entries; those of another image size are left out), in pool order."""
    views = [View.from_arrays(frame.rgb, frame.depth, frame.pose, frame.K, device)]
    pool = [e for e in pool if e.depth.shape == frame.depth.shape]
    if pool and count > 0:
        pick = rng.choice(len(pool), size=min(count, len(pool)), replace=False)
        views += [
            View.from_arrays(pool[i].rgb, pool[i].depth, pool[i].pose, pool[i].K, device)
            for i in sorted(pick)
        ]
    return views
