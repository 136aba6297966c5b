"""Shared helpers for the benchmark scripts: synthetic Gaussian scenes and a synchronising timer."""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import torch


def parse_count(text: str) -> int:
    text = text.strip().lower()
    mult = {"k": 1_000, "m": 1_000_000}.get(text[-1], 1)
    return int(float(text[:-1] if text[-1] in "km" else text) * mult)


def synthetic_gaussians(n: int, device: torch.device, seed: int = 0, labels: int = 2000):
    """A room-sized cloud of Gaussians in front of an identity camera, sizes typical of SLAM maps."""
    g = torch.Generator(device="cpu").manual_seed(seed)
    means = torch.rand(n, 3, generator=g) * torch.tensor([8.0, 5.0, 8.0]) - torch.tensor([4.0, 2.5, -0.5])
    quats = torch.randn(n, 4, generator=g)
    scales = torch.exp(torch.randn(n, 3, generator=g) * 0.3 - 4.0)  # ~2 cm
    opacities = torch.rand(n, generator=g) * 0.8 + 0.1
    colors = torch.rand(n, 3, generator=g)
    # spatially coherent labels (objects are contiguous regions), about 10% unlabelled, as in a real map
    cell = torch.floor(means / 0.4).long()
    lab = ((cell[:, 0] * 73856093) ^ (cell[:, 1] * 19349663) ^ (cell[:, 2] * 83492791)).abs() % labels
    lab = torch.where(torch.rand(n, generator=g) < 0.1, -1, lab).to(torch.int32)
    conf = torch.rand(n, generator=g)
    return [t.to(device) for t in (means, quats, scales, opacities, colors, lab, conf)]


def camera(width: int, height: int, device: torch.device):
    f = 0.5 * width / math.tan(math.radians(45.0))
    K = torch.tensor([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1.0]], device=device)[None]
    return torch.eye(4, device=device)[None], K


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def time_ms(fn: Callable[[], object], device: torch.device, warmup: int = 2, iters: int = 10) -> float:
    for _ in range(warmup):
        fn()
    sync(device)
    t0 = time.perf_counter()
    for _ in range(iters):
        fn()
    sync(device)
    return (time.perf_counter() - t0) * 1000.0 / iters


def peak_mb(fn: Callable[[], object], device: torch.device) -> float:
    """Peak device memory of one call in MiB (CUDA only; nan on CPU)."""
    if device.type != "cuda":
        return float("nan")
    sync(device)
    torch.cuda.reset_peak_memory_stats(device)
    base = torch.cuda.memory_allocated(device)
    fn()
    sync(device)
    return (torch.cuda.max_memory_allocated(device) - base) / 2**20


def print_table(rows: list[dict], columns: list[str]) -> None:
    widths = [max(len(c), *(len(_fmt(r.get(c))) for r in rows)) for c in columns]
    print("  ".join(c.rjust(w) for c, w in zip(columns, widths)))
    for r in rows:
        print("  ".join(_fmt(r.get(c)).rjust(w) for c, w in zip(columns, widths)))


def _fmt(v: object) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.2f}"
    return str(v)
