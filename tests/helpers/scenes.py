"""Random Gaussian scenes and cameras for kernel tests."""

from __future__ import annotations

import math

import torch


def look_at_viewmat(eye, target, up=(0.0, -1.0, 0.0)) -> torch.Tensor:
    """World-to-camera 4x4 (OpenCV axes: z forward, y down) looking from eye at target."""
    eye = torch.tensor(eye, dtype=torch.float32)
    target = torch.tensor(target, dtype=torch.float32)
    z = target - eye
    z = z / z.norm()
    x = torch.linalg.cross(z, torch.tensor(up, dtype=torch.float32))
    x = x / x.norm()
    y = torch.linalg.cross(z, x)
    R = torch.stack([x, y, z])  # rows: camera axes in world
    V = torch.eye(4)
    V[:3, :3] = R
    V[:3, 3] = -R @ eye
    return V


def intrinsics(width: int, height: int, fov_deg: float = 60.0) -> torch.Tensor:
    f = 0.5 * width / math.tan(math.radians(fov_deg) / 2)
    return torch.tensor([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]], dtype=torch.float32)


def random_scene(n: int, seed: int = 0, channels: int = 3, spread: float = 1.0, device="cpu"):
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=g) * spread
    means[:, 2] += 4.0
    quats = torch.randn(n, 4, generator=g)
    scales = torch.exp(torch.randn(n, 3, generator=g) * 0.5 - 2.0)
    opacities = torch.rand(n, generator=g) * 0.9 + 0.05
    colors = torch.rand(n, channels, generator=g)
    return [t.to(device) for t in (means, quats, scales, opacities, colors)]


def cameras(width: int, height: int, count: int = 1, device="cpu"):
    eyes = [(0.0, 0.0, 0.0), (0.6, -0.3, 0.2), (-0.5, 0.2, -0.3)]
    vms = torch.stack([look_at_viewmat(eyes[i], (0.0, 0.0, 4.0)) for i in range(count)])
    Ks = torch.stack([intrinsics(width, height) for _ in range(count)])
    return vms.to(device), Ks.to(device)
