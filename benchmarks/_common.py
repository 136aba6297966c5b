"""Shared helpers for the benchmark scripts: synthetic Gaussian scenes, a synchronising timer and a
device-kernel timer, and the scripts' command-line plumbing (argument types, clean errors)."""

from __future__ import annotations

import math
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import torch
from torch.autograd import DeviceType
from torch.profiler import ProfilerActivity, profile

from ogscene3d.cli_types import positive_int  # noqa: F401 - the benchmarks' argparse type, from here


def run_main(main: Callable[[], int | None]) -> None:
    """Run a script's ``main`` and exit with its status. ogscene3d's input errors (no CUDA GPU for
    ``--device cuda``, a bad ``--set``) end the script with one line, as the ``ogscene3d`` CLI prints them,
    instead of a traceback."""
    from ogscene3d.errors import OGSceneError

    try:
        rc = main()
    except OGSceneError as e:
        print(f"{Path(sys.argv[0]).name}: error: {e}", file=sys.stderr)
        sys.exit(2)
    sys.exit(rc or 0)


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


def synthetic_surfaces(n: int, device: torch.device, seed: int = 0, labels: int = 2000):
    """A mapped room as a SLAM map holds it: flat Gaussians on the walls, floor and ceiling of a 8 x 5 x 8 m
    room and on 60 boxes (furniture) inside, one label per 0.4 m patch of surface, confidences in [0.6, 1]
    as the mapping leaves them. Same outputs as :func:`synthetic_gaussians`; the camera of :func:`camera`
    stands inside, 1.5 m from the back wall."""
    g = torch.Generator(device="cpu").manual_seed(seed)
    lo, hi = torch.tensor([-4.0, -2.5, -1.5]), torch.tensor([4.0, 2.5, 6.5])
    boxes_lo = lo + torch.rand(60, 3, generator=g) * (hi - lo - 1.0)
    boxes_lo[:, 2] = boxes_lo[:, 2].clamp(min=0.5)
    boxes_hi = boxes_lo + 0.2 + torch.rand(60, 3, generator=g) * 0.8
    room = n // 2  # half on the room's six faces, half on the boxes
    owner = torch.cat([torch.full((room,), -1), torch.randint(0, 60, (n - room,), generator=g)])
    b_lo = torch.where(owner[:, None] < 0, lo, boxes_lo[owner.clamp(min=0)])
    b_hi = torch.where(owner[:, None] < 0, hi, boxes_hi[owner.clamp(min=0)])
    means = b_lo + torch.rand(n, 3, generator=g) * (b_hi - b_lo)
    axis = torch.randint(0, 3, (n,), generator=g)
    side = torch.randint(0, 2, (n,), generator=g).bool()
    rows = torch.arange(n)
    means[rows, axis] = torch.where(side, b_hi[rows, axis], b_lo[rows, axis])  # onto a face
    scales = torch.exp(torch.randn(n, 3, generator=g) * 0.2 - 3.9)  # ~2 cm across the surface
    scales[rows, axis] *= 0.1  # thin along the face normal
    quats = torch.zeros(n, 4)
    quats[:, 0] = 1.0  # axis-aligned, so the thin axis is the face normal
    opacities = torch.rand(n, generator=g) * 0.3 + 0.7
    colors = torch.rand(n, 3, generator=g)
    cell = torch.floor(means / 0.4).long()
    lab = ((cell[:, 0] * 73856093) ^ (cell[:, 1] * 19349663) ^ (cell[:, 2] * 83492791)).abs() % labels
    lab = torch.where(torch.rand(n, generator=g) < 0.05, -1, lab).to(torch.int32)
    conf = torch.rand(n, generator=g) * 0.4 + 0.6
    return [t.to(device) for t in (means, quats, scales, opacities, colors, lab, conf)]


def camera(width: int, height: int, device: torch.device):
    f = 0.5 * width / math.tan(math.radians(45.0))
    K = torch.tensor([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1.0]], device=device)[None]
    return torch.eye(4, device=device)[None], K


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def render_fns(render, scene, vm, K, width, height):
    """(forward without grad, forward + backward of sum(image) + sum(alpha)) of a gsplat-style ``render``
    on ``scene`` (means, quats, scales, opacities, colors first); the backward's inputs are leaf copies."""
    params = [t.clone().requires_grad_(True) for t in scene[:5]]

    def forward():
        with torch.no_grad():
            return render(*params, vm, K, width, height)

    def forward_backward():
        img, alpha, _ = render(*params, vm, K, width, height)
        (img.sum() + alpha.sum()).backward()

    return forward, forward_backward


def time_ms(
    fn: Callable[[], object], device: torch.device, warmup: int = 2, iters: int = 10, blocks: int = 5
) -> float:
    """Wall milliseconds per call: the median over ``blocks`` timed blocks of ``iters`` calls each, so one
    block slowed by the host (another process, a clock change) does not move the figure."""
    for _ in range(warmup):
        fn()
    per_block = []
    for _ in range(blocks):
        sync(device)
        t0 = time.perf_counter()
        for _ in range(iters):
            fn()
        sync(device)
        per_block.append((time.perf_counter() - t0) * 1000.0 / iters)
    return statistics.median(per_block)


def profiled_kernel_ms(prof) -> float:
    """Total device-kernel time (kernels, memsets, copies) in a torch.profiler run, in ms. Named ranges
    (``record_function``, autograd Functions) also appear on the device timeline, spanning the kernels
    they launch: they are left out, or their kernels would count twice."""
    total_us = 0.0
    for evt in prof.key_averages():  # the same sum as the "Self CUDA time total" line of its table
        if evt.device_type == DeviceType.CUDA and not getattr(evt, "is_user_annotation", False):
            total_us += evt.self_device_time_total
    return total_us / 1000.0


def profile_activities(device: torch.device) -> list:
    return [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device.type == "cuda" else [])


def profiled(fn: Callable[[], object], device: torch.device, calls: int):
    """A torch.profiler run of ``calls`` calls of ``fn``, after three unprofiled ones (compilation, the
    allocator's first requests)."""
    for _ in range(3):
        fn()
    sync(device)
    with profile(activities=profile_activities(device)) as prof:
        for _ in range(calls):
            fn()
        sync(device)
    return prof


def kernel_ms(fn: Callable[[], object], device: torch.device, calls: int = 10) -> float:
    """Device-kernel milliseconds per call (host-independent; nan on the CPU)."""
    if device.type != "cuda":
        return float("nan")
    return profiled_kernel_ms(profiled(fn, device, calls)) / calls


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


# the semantic benchmarks' scenes: a volume-filling cloud (worst case) and a mapped room of surfaces
SEMANTIC_SCENES = {"cloud": synthetic_gaussians, "surfaces": synthetic_surfaces}
