"""``ogscene3d render-demo``: render a procedural Gaussian scene to PNG (a rasterizer smoke test)."""

from __future__ import annotations

import math
import numbers
from pathlib import Path

import numpy as np
import torch

from ..device import resolve_device
from ..errors import ConfigError, DataError
from ._rasterization import rasterization


def procedural_scene(n: int, seed: int = 0, device: torch.device | str = "cpu") -> list[torch.Tensor]:
    """A coloured torus knot over a checkered floor: [means, quats, scales, opacities, colors]."""
    g = torch.Generator().manual_seed(seed)
    k = n // 2
    t = torch.rand(k, generator=g) * 2 * math.pi
    p, q = 2, 3
    r = torch.cos(q * t) + 2.0
    knot = torch.stack([r * torch.cos(p * t), -torch.sin(q * t) - 1.5, r * torch.sin(p * t)], dim=1) * 0.5
    knot += torch.randn(k, 3, generator=g) * 0.05
    hue = t / (2 * math.pi)
    knot_col = torch.stack(
        [0.5 + 0.5 * torch.cos(2 * math.pi * (hue + s)) for s in (0.0, 1 / 3, 2 / 3)], dim=1
    )
    m = n - k
    floor = torch.rand(m, 3, generator=g) * torch.tensor([6.0, 0.0, 6.0]) - torch.tensor([3.0, 0.0, 3.0])
    checker = ((torch.floor(floor[:, 0] * 2) + torch.floor(floor[:, 2] * 2)) % 2).unsqueeze(1)
    floor_col = 0.25 + 0.5 * checker.expand(m, 3)
    means = torch.cat([knot, floor])
    colors = torch.cat([knot_col, floor_col]).clamp(0, 1)
    quats = torch.randn(n, 4, generator=g)
    scales = torch.cat([torch.full((k, 3), 0.04), torch.tensor([[0.05, 0.005, 0.05]]).expand(m, 3)])
    opac = torch.full((n,), 0.9)
    return [x.to(device) for x in (means, quats, scales, opac, colors)]


def orbit_viewmat(angle: float, radius: float = 5.0, height: float = -2.0) -> torch.Tensor:
    """World-to-camera matrix of a camera on a circle looking at the origin (OpenCV axes, world y down)."""
    eye = torch.tensor([radius * math.sin(angle), height, -radius * math.cos(angle)])
    z = -eye / eye.norm()
    x = torch.linalg.cross(torch.tensor([0.0, 1.0, 0.0]), z)
    x = x / x.norm()
    y = torch.linalg.cross(z, x)
    R = torch.stack([x, y, z])
    V = torch.eye(4)
    V[:3, :3] = R
    V[:3, 3] = -R @ eye
    return V


def check_demo_args(out: Path, n: int, width: int, height: int, views: int) -> None:
    """Raise :class:`ConfigError` for arguments the renderer or the PNG writer would fail on deep inside
    (an empty list of views, a zero-size image, a file name OpenCV has no writer for)."""
    import cv2

    for name, value in (("n", n), ("width", width), ("height", height), ("views", views)):
        if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1:
            raise ConfigError(f"render_demo: {name} must be an integer >= 1, got {value!r}")
    if not cv2.haveImageWriter(str(out)):
        raise ConfigError(
            f"render_demo: out={str(out)!r} is not an image file OpenCV can write; give a file name ending "
            "in .png (or .jpg)"
        )


def render_demo(
    out: Path, n: int = 20000, width: int = 320, height: int = 240, views: int = 4, device: str | None = None
) -> Path:
    """Render ``views`` orbit views of :func:`procedural_scene` side by side into the image file ``out``."""
    import cv2

    out = Path(out)
    check_demo_args(out, n, width, height, views)
    dev = resolve_device(device)
    scene = procedural_scene(n, device=dev)
    viewmats = torch.stack([orbit_viewmat(2 * math.pi * i / views) for i in range(views)]).to(dev)
    f = 0.5 * width / math.tan(math.radians(30))
    K = torch.tensor([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1.0]], device=dev).expand(views, 3, 3)
    bg = torch.full((views, 3), 0.08, device=dev)
    img, _, _ = rasterization(*scene, viewmats, K.contiguous(), width, height, backgrounds=bg)
    tiles = (img.clamp(0, 1) * 255).to(torch.uint8).cpu().numpy()
    mosaic = np.concatenate(list(tiles), axis=1)
    out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), cv2.cvtColor(mosaic, cv2.COLOR_RGB2BGR)):
        raise DataError(f"could not write {out}")
    return out
