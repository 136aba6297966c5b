r"""Where the time goes: torch.profiler tables (device kernels and host calls) for the three GPU benchmarks.

    python benchmarks/kernel_profile.py --device cuda --out OUTDIR   # 500k at 1200x680, mapping at 1M
    python benchmarks/kernel_profile.py --device cpu --width 160 --height 120 \
        --gaussians 5k --map-gaussians 20k

Writes OUTDIR/raster.txt (ours, and gsplat on CUDA when importable: forward and forward+backward),
OUTDIR/semantic.txt (labels + P_conf in one call and a colour forward of the same scene, on both scenes),
OUTDIR/mapping.txt (the ``mapping.py modules`` round with each module inside a named range
``M:<function>``) and OUTDIR/summary.txt: per call, the device-kernel time (host-independent) next to the
wall time, and the host time spent queueing a forward. Wall time well above kernel time means the call is
host-bound (launch overhead, syncs).
"""

from __future__ import annotations

import argparse
import functools
import sys
import time
from pathlib import Path

import torch
from torch.profiler import profile, record_function

sys.path.insert(0, str(Path(__file__).resolve().parent))
import mapping as mapping_bench  # noqa: E402
from _common import (  # noqa: E402
    SEMANTIC_SCENES,
    camera,
    parse_count,
    positive_int,
    profile_activities,
    profiled,
    profiled_kernel_ms,
    render_fns,
    run_main,
    sync,
    synthetic_gaussians,
    time_ms,
)

from ogscene3d import rasterization, rendering_contribution  # noqa: E402
from ogscene3d.device import resolve_device  # noqa: E402

MAPPING_FUNCTIONS = (
    "make_probes",
    "associate_segments",
    "visible_pixels",
    "duplicate_label_pairs",
    "global_refinement",
    "longterm_view_update",
)


def _write_tables(prof, path: Path, title: str, device: torch.device, rows: int = 30) -> None:
    ka = prof.key_averages()
    with path.open("a") as fh:
        fh.write(f"\n##### {title}\n")
        if device.type == "cuda":
            fh.write(ka.table(sort_by="self_cuda_time_total", row_limit=rows, max_name_column_width=70))
        fh.write(ka.table(sort_by="self_cpu_time_total", row_limit=rows, max_name_column_width=70))


NO_KERNELS = "n/a (no device kernels on the CPU)"


def _kernels_text(prof, device: torch.device, calls: int) -> str:
    """Device-kernel milliseconds per call, or why there are none (the CPU profile has no device
    timeline: its 0.000 would read as 'free')."""
    if device.type != "cuda":
        return NO_KERNELS
    return f"{profiled_kernel_ms(prof) / calls:.3f} ms per call"


def _host_ms(fn, device: torch.device, calls: int = 20) -> float:
    """Milliseconds per call spent on the host queueing work (includes any syncs the call makes)."""
    sync(device)
    t0 = time.perf_counter()
    for _ in range(calls):
        fn()
    host = (time.perf_counter() - t0) * 1000.0 / calls
    sync(device)
    return host


def profile_raster(args, device, out: Path, summary: list[str]) -> None:
    n = parse_count(args.gaussians)
    scene = synthetic_gaussians(n, device)
    vm, K = camera(args.width, args.height, device)
    renderers = [("ours", rasterization)]
    if device.type != "cuda":
        summary.append("gsplat comparison skipped (gsplat needs CUDA)")
    else:
        try:
            import gsplat

            renderers.append(("gsplat", gsplat.rasterization))
        except Exception as e:  # noqa: BLE001 - any import failure means "not available"
            summary.append(f"gsplat not available ({type(e).__name__}: {e})")
    for name, render in renderers:
        forward, forward_backward = render_fns(render, scene, vm, K, args.width, args.height)
        for label, fn in (("fwd", forward), ("fwd+bwd", forward_backward)):
            prof = profiled(fn, device, args.calls)
            _write_tables(prof, out / "raster.txt", f"{name} {label} x{args.calls}", device)
            summary.append(
                f"raster {name:6s} {label:8s} N={n}: wall {time_ms(fn, device, iters=args.calls):.3f} ms, "
                f"kernels {_kernels_text(prof, device, args.calls)}"
            )
        summary.append(f"raster {name:6s} fwd host-side {_host_ms(forward, device):.3f} ms per call")


def _profile_semantic_scene(scene: str, make, args, device, out: Path) -> str:
    n = parse_count(args.gaussians)
    W, H = args.width, args.height
    vm, K = camera(W, H, device)
    means, quats, scales, opac, colors, labels, conf = make(n, device)

    def one_call():
        return rendering_contribution(
            means, quats, scales, opac, labels, conf, vm[0], K[0], W, H, return_semantics=True
        )

    def color():
        with torch.no_grad():
            return rasterization(means, quats, scales, opac, colors, vm, K, W, H)

    kernels = {}
    for label, fn in (("labels + P_conf", one_call), ("colour fwd", color)):
        prof = profiled(fn, device, args.calls)
        _write_tables(prof, out / "semantic.txt", f"{scene} {label} x{args.calls}", device)
        kernels[label] = profiled_kernel_ms(prof) / args.calls
    wall = f"semantic {scene:8s} 1call N={n}: wall {time_ms(one_call, device, iters=args.calls):.3f} ms"
    if device.type != "cuda":
        return f"{wall}, kernels {NO_KERNELS}"
    both, col = kernels["labels + P_conf"], kernels["colour fwd"]
    ratio = f"{both / col:.2f}" if col else "n/a"
    return f"{wall}, kernels {both:.3f} ms per call; colour fwd kernels {col:.3f} ms; ratio {ratio}"


def profile_semantic(args, device, out: Path, summary: list[str]) -> None:
    for scene, make in SEMANTIC_SCENES.items():
        summary.append(_profile_semantic_scene(scene, make, args, device, out))


def profile_mapping(args, device, out: Path, summary: list[str]) -> None:
    for name in MAPPING_FUNCTIONS:
        fn = getattr(mapping_bench, name)

        @functools.wraps(fn)
        def ranged(*a, _fn=fn, _name=name, **k):
            with record_function("M:" + _name):
                return _fn(*a, **k)

        setattr(mapping_bench, name, ranged)
    margs = argparse.Namespace(
        device=str(device),
        size=f"{args.width}x{args.height}",
        gaussians=parse_count(args.map_gaussians),
        repeat=0,
        seed=0,
        config=str(Path(__file__).resolve().parents[1] / "configs" / "synthetic.yaml"),
        overrides=[],
    )
    mapping_bench.modules(margs)  # repeat=0: compile and warm up only (nothing timed or printed)
    margs.repeat = 2
    with profile(activities=profile_activities(device)) as prof:
        res = mapping_bench.modules(margs)
    ka = prof.key_averages()
    with (out / "mapping.txt").open("w") as fh:
        if device.type == "cuda":
            fh.write(ka.table(sort_by="self_cuda_time_total", row_limit=40, max_name_column_width=70))
        fh.write(ka.table(sort_by="cpu_time_total", row_limit=40, max_name_column_width=70))
    summary.append(f"mapping modules ({margs.gaussians} Gaussians, 2 rounds, profiled): {res['ms']}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default=None)
    ap.add_argument("--out", default="runs/profile")
    ap.add_argument("--width", type=positive_int, default=1200)
    ap.add_argument("--height", type=positive_int, default=680)
    ap.add_argument("--gaussians", default="500k", help="for the rasterizer and the semantic kernels")
    ap.add_argument("--map-gaussians", default="1M", help="for the mapping modules")
    ap.add_argument("--calls", type=positive_int, default=5, help="profiled calls per table (default 5)")
    ap.add_argument("--only", choices=["raster", "semantic", "mapping"], action="append")
    args = ap.parse_args()
    device = resolve_device(args.device)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name in ("raster.txt", "semantic.txt", "mapping.txt"):
        (out / name).unlink(missing_ok=True)
    summary: list[str] = [f"device {device}, {args.width}x{args.height}"]
    steps = {"raster": profile_raster, "semantic": profile_semantic, "mapping": profile_mapping}
    for name in args.only or list(steps):
        steps[name](args, device, out, summary)
    (out / "summary.txt").write_text("\n".join(summary) + "\n")
    print("\n".join(summary))


if __name__ == "__main__":
    run_main(main)
