"""Geometry/appearance optimization after each keyframe (paper Sec. III-B.4)."""

import numpy as np
import pytest
import torch

from ogscene3d.config import OptimizeConfig
from ogscene3d.gaussians import GaussianMap
from ogscene3d.mapping.optimize import View, optimize_map


def _plane_views(device: str, count: int = 2, shift: float = 0.05) -> list[View]:
    """Views of a flat grey wall 2 m in front of cameras side by side."""
    h, w = 24, 32
    K = np.array([[30.0, 0, w / 2], [0, 30.0, h / 2], [0, 0, 1]], np.float32)
    rgb = np.full((h, w, 3), 180, np.uint8)
    depth = np.full((h, w), 2.0, np.float32)
    views = []
    for i in range(count):
        pose = np.eye(4)
        pose[0, 3] = shift * i
        views.append(View.from_arrays(rgb, depth, pose, K, torch.device(device)))
    return views


def _wall(device: str, z: float, n: int = 300, seed: int = 0) -> GaussianMap:
    g = torch.Generator().manual_seed(seed)
    xy = torch.rand(n, 2, generator=g) * 2.4 - 1.2
    means = torch.cat([xy, torch.full((n, 1), z)], 1)
    gm = GaussianMap(device)
    gm.append(means.to(device), torch.rand(n, 3, generator=g).to(device), torch.full((n,), -3.0))
    return gm


def test_optimize_map_lowers_the_loss(device):
    gm = _wall(device, 2.3)  # 30 cm behind the observed wall, wrong colours
    gm.append(torch.tensor([[0.0, 0.0, -5.0]], device=device), torch.zeros(1, 3), torch.full((1,), -3.0))
    behind = gm.means[-1].clone()
    out = optimize_map(gm, _plane_views(device), OptimizeConfig(iters=15, lr_means=0.01))
    assert out["iters"] == 15 and out["loss_last"] < 0.9 * out["loss_first"]
    assert 0 < out["optimized"] < len(gm)  # only the Gaussians that project into a view take steps
    torch.testing.assert_close(gm.means[-1], behind)
    assert bool(torch.isfinite(gm.means).all()) and float(gm.colors.min()) >= 0.0


def test_default_learning_rate_keeps_centres_on_the_surface():
    """Many keyframes of the same wall: the centres stay on it (a too large means step walks them off)."""
    views = _plane_views("cpu", 3)

    def drift(lr: float) -> float:
        gm = _wall("cpu", 2.0)
        cfg = OptimizeConfig(iters=3, lr_means=lr)
        for _ in range(40):
            optimize_map(gm, views, cfg)
        return float((gm.means[:, 2] - 2.0).abs().quantile(0.9))  # metres

    assert OptimizeConfig().lr_means <= 1e-4
    default = drift(OptimizeConfig().lr_means)
    assert default < 0.02
    assert drift(1e-3) > 4 * default  # 120 steps at 1e-3 leave 10% of the centres ~10 cm off the wall


def test_optimize_map_rejects_mixed_sizes():
    gm = _wall("cpu", 2.0, n=5)
    view = _plane_views("cpu", 1)[0]
    small = View(view.rgb[:10], view.depth[:10], view.viewmat, view.K)
    with pytest.raises(ValueError, match="same image size"):
        optimize_map(gm, [view, small], OptimizeConfig(iters=1))
