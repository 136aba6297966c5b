"""Rasterizer speed and memory: ogscene3d (Warp) vs gsplat on the same scenes, in one process.

    python benchmarks/rasterize.py --device cuda                       # 50k..2M at 1200x680
    python benchmarks/rasterize.py --device cpu --width 160 --height 120 --counts 5k,20k

Prints forward and forward+backward milliseconds, peak GPU memory, the (Gaussian, tile) intersections
of a forward, and ours/gsplat ratios (gsplat only when importable).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import (  # noqa: E402
    camera,
    kernel_ms,
    parse_count,
    peak_mb,
    positive_int,
    print_table,
    render_fns,
    run_main,
    synthetic_gaussians,
    time_ms,
)

from ogscene3d import rasterization  # noqa: E402
from ogscene3d.device import resolve_device  # noqa: E402


def _gsplat():
    try:
        import gsplat

        return gsplat.rasterization
    except Exception as e:  # noqa: BLE001 - any import failure means "not available"
        print(f"gsplat not available ({type(e).__name__}: {e}); reporting ours only", file=sys.stderr)
        return None


def _no_gsplat_on_cpu() -> None:
    """gsplat has CUDA kernels only: say so, instead of a table that silently lacks its columns."""
    print("gsplat comparison skipped (gsplat needs CUDA); reporting ours only", file=sys.stderr)
    return None


def _intersections(meta: dict) -> int | None:
    """(Gaussian, tile) pairs of one forward: ours counts them, gsplat's meta holds their keys."""
    if "n_intersections" in meta:
        return int(meta["n_intersections"])
    ids = meta.get("isect_ids")
    return int(ids.numel()) if ids is not None else None


def bench(fn, scene, vm, K, width, height, device, iters):
    forward, forward_backward = render_fns(fn, scene, vm, K, width, height)

    return {
        "fwd_ms": time_ms(forward, device, iters=iters),
        "fwd+bwd_ms": time_ms(forward_backward, device, iters=iters),
        "fwd_kernel_ms": kernel_ms(forward, device),
        "fwd+bwd_kernel_ms": kernel_ms(forward_backward, device),
        "peak_MiB": peak_mb(forward_backward, device),
        "isects": _intersections(forward()[2]),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default=None)
    ap.add_argument("--counts", default="50k,200k,500k,2M")
    ap.add_argument("--width", type=positive_int, default=1200)
    ap.add_argument("--height", type=positive_int, default=680)
    ap.add_argument("--iters", type=positive_int, default=10, help="calls per timed block (default 10)")
    args = ap.parse_args()
    device = resolve_device(args.device)
    gs = _gsplat() if device.type == "cuda" else _no_gsplat_on_cpu()
    rows = []
    for n in (parse_count(c) for c in args.counts.split(",")):
        scene = synthetic_gaussians(n, device)
        vm, K = camera(args.width, args.height, device)
        ours = bench(rasterization, scene, vm, K, args.width, args.height, device, args.iters)
        row = {"N": n, "device": device.type, **{f"ours_{k}": v for k, v in ours.items()}}
        if gs is not None:
            theirs = bench(gs, scene, vm, K, args.width, args.height, device, args.iters)
            row.update({f"gsplat_{k}": v for k, v in theirs.items()})
            for k in ("fwd", "fwd+bwd", "fwd_kernel", "fwd+bwd_kernel"):
                row[f"{k}_ratio"] = ours[f"{k}_ms"] / theirs[f"{k}_ms"]
        rows.append(row)
        print(f"done N={n}", file=sys.stderr)
    figures = ["fwd_ms", "fwd+bwd_ms", "fwd_kernel_ms", "fwd+bwd_kernel_ms", "peak_MiB", "isects"]
    cols = ["N", "device"] + [f"ours_{k}" for k in figures]
    if gs is not None:
        cols += [f"gsplat_{k}" for k in figures]
        cols += ["fwd_ratio", "fwd+bwd_ratio", "fwd_kernel_ratio", "fwd+bwd_kernel_ratio"]
    print(f"rasterization at {args.width}x{args.height}, RGB, one camera")
    print("wall ms: median of 5 timed blocks; kernel ms: device-kernel time per call (torch.profiler)")
    print_table(rows, cols)


if __name__ == "__main__":
    run_main(main)
