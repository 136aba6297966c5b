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
    parse_count,
    peak_mb,
    print_table,
    render_fns,
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
        "peak_MiB": peak_mb(forward_backward, device),
        "isects": _intersections(forward()[2]),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default=None)
    ap.add_argument("--counts", default="50k,200k,500k,2M")
    ap.add_argument("--width", type=int, default=1200)
    ap.add_argument("--height", type=int, default=680)
    ap.add_argument("--iters", type=int, default=10)
    args = ap.parse_args()
    device = resolve_device(args.device)
    gs = _gsplat() if device.type == "cuda" else None
    rows = []
    for n in (parse_count(c) for c in args.counts.split(",")):
        scene = synthetic_gaussians(n, device)
        vm, K = camera(args.width, args.height, device)
        ours = bench(rasterization, scene, vm, K, args.width, args.height, device, args.iters)
        row = {"N": n, "device": device.type, **{f"ours_{k}": v for k, v in ours.items()}}
        if gs is not None:
            theirs = bench(gs, scene, vm, K, args.width, args.height, device, args.iters)
            row.update({f"gsplat_{k}": v for k, v in theirs.items()})
            row["fwd_ratio"] = ours["fwd_ms"] / theirs["fwd_ms"]
            row["fwd+bwd_ratio"] = ours["fwd+bwd_ms"] / theirs["fwd+bwd_ms"]
        rows.append(row)
        print(f"done N={n}", file=sys.stderr)
    cols = ["N", "device", "ours_fwd_ms", "ours_fwd+bwd_ms", "ours_peak_MiB", "ours_isects"]
    if gs is not None:
        cols += ["gsplat_fwd_ms", "gsplat_fwd+bwd_ms", "gsplat_peak_MiB", "gsplat_isects"]
        cols += ["fwd_ratio", "fwd+bwd_ratio"]
    print(f"rasterization at {args.width}x{args.height}, RGB, one camera")
    print_table(rows, cols)


if __name__ == "__main__":
    main()
