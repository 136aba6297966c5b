"""Mapping speed and memory benchmarks (no timed asserts anywhere; this script only reports).

Two modes:

``stream``: map a synthetic scene frame by frame and report per-module milliseconds per keyframe, plus the
Gaussian count, peak host RSS and peak CUDA memory every ``--report-every`` keyframes (the bounded-memory
check on long runs: ``--frames 2000``).

    python benchmarks/mapping.py stream --frames 120 --size 160x120 --device cpu \\
        [--set mapping.optimize.iters=0]

``modules``: the semantic modules alone at a given image size on a map of ``--gaussians`` Gaussians (random
points on the walls of a 6 x 3 x 6 m box, 50 labels): local 3D optimization (probe association + Eq. 5 + the
duplicate-label check of every segment), global refinement (Alg. 1) and long-term
optimization (one memory view), averaged over ``--repeat`` runs, in ms. This is the "local + global + long-
term per keyframe" figure (the paper: 323 ms on an RTX 4090).

    python benchmarks/mapping.py modules --size 1200x680 --gaussians 1000000 --device cuda
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import positive_int, run_main  # noqa: E402

from ogscene3d.batch import json_safe  # noqa: E402
from ogscene3d.cli_types import image_size  # noqa: E402
from ogscene3d.config import load_config  # noqa: E402
from ogscene3d.gaussians import GaussianMap  # noqa: E402
from ogscene3d.mapping.init import make_probes  # noqa: E402
from ogscene3d.mapping.local import associate_segments  # noqa: E402
from ogscene3d.mapping.longterm import MemoryEntry, longterm_view_update  # noqa: E402
from ogscene3d.mapping.mapper import Mapper  # noqa: E402
from ogscene3d.mapping.merge import duplicate_label_pairs, visible_pixels  # noqa: E402
from ogscene3d.mapping.refine import global_refinement  # noqa: E402


def _sync(dev: torch.device) -> None:
    if dev.type == "cuda":
        torch.cuda.synchronize(dev)


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def stream(args) -> dict:
    from ogscene3d.datasets import make_synthetic_scene, open_dataset

    w, h = args.size
    scene = make_synthetic_scene(
        Path(args.out) / f"scene_{args.frames}_{w}x{h}",
        args.seed,
        args.frames,
        w,
        h,
        "default",
        progress=True,
    )
    cfg = load_config(args.config, ["graph.enabled=false", *args.overrides])
    mapper = Mapper(cfg, args.device)
    dev = mapper.device
    if dev.type == "cuda":
        torch.cuda.reset_peak_memory_stats(dev)
    history = []
    t0 = time.perf_counter()
    for frame in open_dataset(scene, config=cfg.data):
        if mapper.process(frame) and mapper.keyframe_count % args.report_every == 0:
            row = {
                "keyframe": mapper.keyframe_count,
                "frames": mapper.frames_seen,
                "gaussians": len(mapper.map),
                "map_mb": mapper.map.memory_bytes() / 2**20,
                "memory_frames": len(mapper.memory),
                "peak_rss_mb": _rss_mb(),
                "seconds": time.perf_counter() - t0,
            }
            if dev.type == "cuda":
                row["peak_cuda_mb"] = torch.cuda.max_memory_allocated(dev) / 2**20
            history.append(row)
            print(json.dumps(row))
    mapper.finalize()
    print(mapper.timings.table())
    return {
        "mode": "stream",
        "device": str(dev),
        "size": "{}x{}".format(*args.size),
        "frames": args.frames,
        "timings": mapper.timings.as_dict(),
        "history": history,
    }


def _box_map(n: int, n_labels: int, dev: torch.device, seed: int) -> GaussianMap:
    g = torch.Generator().manual_seed(seed)
    pts = torch.rand(n, 3, generator=g) * torch.tensor([6.0, 3.0, 6.0]) - torch.tensor([3.0, 1.5, 3.0])
    axis = torch.randint(0, 3, (n,), generator=g)
    side = torch.randint(0, 2, (n,), generator=g).float()
    half = torch.tensor([3.0, 1.5, 3.0])
    pts[torch.arange(n), axis] = (side * 2 - 1) * half[axis]  # onto the box walls
    cell = (pts[:, 0] // 1.2 + 5 * (pts[:, 1] // 1.0) + 17 * (pts[:, 2] // 1.2)).long() % n_labels
    gm = GaussianMap(dev, capacity=n)
    gm.append(
        pts.to(dev),
        torch.rand(n, 3, generator=g).to(dev),
        torch.full((n,), float(np.log(0.01))).to(dev),
        labels=cell.int().to(dev),
        confidences=torch.rand(n, generator=g).to(dev),
        opacity_logits=torch.full((n,), 2.0).to(dev),
    )
    return gm


def modules(args) -> dict | None:
    """Time the modules over ``args.repeat`` rounds after one warm-up round and print the result.
    ``args.repeat == 0`` only warms up (compiles the kernels): nothing is timed, printed or returned."""
    from ogscene3d.device import resolve_device

    dev = resolve_device(args.device)
    w, h = args.size
    cfg = load_config(args.config, args.overrides).mapping
    gm = _box_map(args.gaussians, 50, dev, args.seed)
    # a camera at the box centre looking at the +z wall; depth from the wall plane, 40 rectangular segments
    f = 0.5 * w
    K = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1]], np.float32)
    depth = np.full((h, w), 3.0, np.float32)
    seg = (np.arange(w)[None, :] * 8 // w + 8 * (np.arange(h)[:, None] * 5 // h) + 1).astype(np.int32)
    seg = np.broadcast_to(seg, (h, w)).copy()
    from ogscene3d.frame import Frame

    rgb = np.zeros((h, w, 3), np.uint8)
    frame = Frame(0, rgb, depth, K, np.eye(4), segments=seg, segment_scores={i: 0.95 for i in range(1, 41)})
    times: dict[str, list[float]] = {"local": [], "refine": [], "longterm": []}
    for rep in range(args.repeat + 1):  # the first round compiles / warms up and is not counted
        _sync(dev)
        t = time.perf_counter()
        probes = make_probes(
            frame,
            seg,
            frame.segment_scores,
            dev,
            replace(cfg.init, dense_below=0),  # the grid alone, as measured before the dense small segments
            rendered=(torch.zeros(h, w, device=dev), torch.zeros(h, w, device=dev)),
        )
        res = associate_segments(
            probes.means,
            probes.seg,
            probes.conf,
            int(probes.seg_ids.numel()),
            gm.means,
            gm.labels,
            gm.confidences,
            gm.new_labels,
            k=cfg.association.knn_k,
            radius=cfg.association.knn_radius,
            tau_valid=cfg.association.tau_valid,
            tau_p=cfg.association.tau_p,
        )
        # duplicate-label check (mapping.merge.enabled), as if every segment were ambiguous: the worst case
        amb = torch.arange(int(probes.seg_ids.numel()), device=dev)
        involved = torch.cat([res.top_label, res.second_label])
        pick = torch.nonzero(torch.isin(gm.labels.long(), involved[involved >= 0])).squeeze(1)
        pix = visible_pixels(
            gm.means[pick],
            torch.eye(4, device=dev),
            torch.as_tensor(K, device=dev),
            torch.as_tensor(depth, device=dev),
            cfg.init.depth_margin,
        )
        vis = pix >= 0
        seg_index = torch.as_tensor(seg, device=dev).long().reshape(-1) - 1
        duplicate_label_pairs(
            seg_index[pix[vis]], gm.labels[pick[vis]], amb, res.top_label, res.second_label, cfg.merge.contain
        )
        _sync(dev)
        t1 = time.perf_counter()
        global_refinement(
            gm.means,
            gm.labels,
            gm.confidences,
            tau_low=cfg.refine.tau_low,
            tau_high=cfg.refine.tau_high,
            r_search=cfg.refine.r_search,
            cluster_radius=cfg.refine.cluster_radius,
            graph_k=cfg.refine.graph_k,
        )
        _sync(dev)
        t2 = time.perf_counter()
        entry = MemoryEntry(0, rgb, depth, K, np.eye(4), seg, frame.segment_scores)
        longterm_view_update(gm, entry, cfg.longterm, cfg.association.knn_radius)
        _sync(dev)
        t3 = time.perf_counter()
        if rep:
            times["local"].append(t1 - t)
            times["refine"].append(t2 - t1)
            times["longterm"].append(t3 - t2)
    if not args.repeat:
        return None  # a warm-up call: there are no timed rounds to average
    ms = {k: 1000 * float(np.mean(v)) for k, v in times.items()}
    # per keyframe: local every keyframe, refinement and long-term every 6 keyframes (the paper's schedule)
    ms["per_keyframe_amortised"] = ms["local"] + (ms["refine"] + ms["longterm"]) / 6.0
    ms["all_three"] = ms["local"] + ms["refine"] + ms["longterm"]
    out = {
        "mode": "modules",
        "device": str(dev),
        "size": "{}x{}".format(*args.size),
        "gaussians": len(gm),
        "ms": ms,
    }
    print(json.dumps(out, indent=1))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("mode", choices=["stream", "modules"])
    ap.add_argument("--device", default=None)
    ap.add_argument("--size", type=image_size(), default=(160, 120), metavar="WxH")
    ap.add_argument("--frames", type=positive_int, default=120, help="stream: frames of the scene")
    ap.add_argument("--gaussians", type=positive_int, default=100_000, help="modules: Gaussians in the map")
    ap.add_argument("--repeat", type=positive_int, default=3, help="modules: timed rounds (default 3)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--report-every", type=positive_int, default=10, help="stream: keyframes between rows")
    ap.add_argument(
        "--config", default=str(Path(__file__).resolve().parents[1] / "configs" / "synthetic.yaml")
    )
    ap.add_argument("--out", default="runs/bench")
    ap.add_argument("--json", default=None, help="also write the result here (unmeasured figures: null)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args()
    res = stream(args) if args.mode == "stream" else modules(args)
    if args.json:
        Path(args.json).write_text(json.dumps(json_safe(res), indent=1))  # strict JSON: NaN -> null


if __name__ == "__main__":
    run_main(main)
