"""Semantic render + rendering contribution cost relative to a colour forward pass of the same scene.

python benchmarks/semantic.py --device cuda                 # 500k Gaussians at 1200x680
python benchmarks/semantic.py --device cpu --counts 20k --width 160 --height 120

Two scenes (``--scene``, both by default): ``cloud`` fills the room's volume with Gaussians of random
confidence, so rays run deep and every pixel sees more labels than the buffer holds (the worst case);
``surfaces`` puts flat Gaussians on the room's faces and on boxes, with confidences in [0.6, 1], as a
mapped scene holds them.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import (  # noqa: E402
    SEMANTIC_SCENES,
    camera,
    kernel_ms,
    parse_count,
    peak_mb,
    positive_int,
    print_table,
    run_main,
    time_ms,
)

import ogscene3d  # noqa: E402
from ogscene3d import rasterization, render_semantics, rendering_contribution  # noqa: E402
from ogscene3d.batch import json_safe  # noqa: E402
from ogscene3d.device import resolve_device  # noqa: E402


def bench_one(scene: str, n: int, W: int, H: int, n_labels: int, iters: int, device: torch.device) -> dict:
    means, quats, scales, opac, colors, labels, conf = SEMANTIC_SCENES[scene](n, device, labels=n_labels)
    vm, K = camera(W, H, device)

    def color():
        with torch.no_grad():
            return rasterization(means, quats, scales, opac, colors, vm, K, W, H)

    def semantic():
        return render_semantics(means, quats, scales, opac, labels, conf, vm, K, W, H)

    def contribution():
        return rendering_contribution(means, quats, scales, opac, labels, conf, vm[0], K[0], W, H)

    def both():
        return rendering_contribution(
            means, quats, scales, opac, labels, conf, vm[0], K[0], W, H, return_semantics=True
        )

    t_color = time_ms(color, device, iters=iters)
    t_sem = time_ms(semantic, device, iters=iters)
    t_contrib = time_ms(contribution, device, iters=iters)
    t_both = time_ms(both, device, iters=iters)
    k_color, k_both = kernel_ms(color, device), kernel_ms(both, device)
    return {
        "scene": scene,
        "N": n,
        "device": device.type,
        "color_fwd_ms": t_color,
        "semantic_ms": t_sem,
        "contribution_ms": t_contrib,
        "sem+contrib_1call_ms": t_both,
        "1call/color": t_both / t_color,
        "color_fwd_kernel_ms": k_color,
        "1call_kernel_ms": k_both,
        "1call/color_kernels": k_both / k_color,
        "peak_MiB": peak_mb(contribution, device),
        "overflow_px": int(semantic().meta["overflow_pixels"]),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default=None)
    ap.add_argument("--counts", default="500k")
    ap.add_argument("--width", type=positive_int, default=1200)
    ap.add_argument("--height", type=positive_int, default=680)
    ap.add_argument("--labels", type=positive_int, default=2000)
    ap.add_argument("--iters", type=positive_int, default=10, help="calls per timed block (default 10)")
    ap.add_argument("--scene", choices=sorted(SEMANTIC_SCENES), action="append", help="default: both")
    ap.add_argument(
        "--json",
        type=Path,
        help="also write the rows here (figures not measured, such as kernel times on the CPU, are null)",
    )
    args = ap.parse_args()
    device = resolve_device(args.device)
    W, H = args.width, args.height
    rows = [
        bench_one(scene, parse_count(c), W, H, args.labels, args.iters, device)
        for scene in args.scene or sorted(SEMANTIC_SCENES)
        for c in args.counts.split(",")
    ]
    print(f"semantic kernels at {W}x{H}, {args.labels} distinct labels, one camera ({ogscene3d.__file__})")
    print("contribution_ms includes the voting pass it needs; 1call = labels + P_conf from one call")
    print("wall ms: median of 5 timed blocks; kernel ms: device-kernel time per call (torch.profiler)")
    print_table(rows, list(rows[0].keys()))
    if args.json:
        args.json.write_text(json.dumps(json_safe(rows), indent=1))  # strict JSON: NaN -> null


if __name__ == "__main__":
    run_main(main)
