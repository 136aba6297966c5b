"""Map a Replica-layout scene (NICE-SLAM layout) and print the per-module timing table.

Layout: results/frame*.jpg, results/depth*.png, traj.txt.

    python examples/replica.py /path/to/room0 [--segments DIR] [--out runs/replica] [--device cuda]
        [--max-frames N] [--set mapping.optimize.iters=5 ...]

Precomputed SAM segments are used when --segments is given (or when the scene has a segments/ folder);
otherwise the weight-free classical segmenter runs on each keyframe. On the shared 20-frame room0 sample:
    python examples/replica.py ../shared/data/replica_room0_nice_slam/room0 --device cpu \
        --set mapping.init.pixels_per_gaussian=64 --set mapping.optimize.iters=2
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from ogscene3d.config import load_config
from ogscene3d.datasets import open_dataset
from ogscene3d.mapping.mapper import Mapper

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("--segments", default=None)
    ap.add_argument("--out", default="runs/replica")
    ap.add_argument("--config", default=str(ROOT / "configs" / "replica.yaml"))
    ap.add_argument("--device", default=None)
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--set", dest="overrides", action="append", default=[])
    args = ap.parse_args()

    scene = Path(args.scene)
    segments = args.segments or (scene / "segments" if (scene / "segments").is_dir() else None)
    cfg = load_config(args.config, args.overrides)
    ds = open_dataset(
        scene, kind="replica", segments_dir=segments, max_frames=args.max_frames, config=cfg.data
    )
    mapper = Mapper(cfg, args.device)
    t0 = time.perf_counter()
    for frame in ds:
        mapper.process(frame)  # frames without segments go through the config's segmenter
        print(
            f"\rframe {frame.index + 1}/{len(ds)}  keyframes {mapper.keyframe_count}  "
            f"Gaussians {len(mapper.map)}",
            end="",
            flush=True,
        )
    mapper.finalize()
    mapper.save(args.out)
    print(f"\nmapped {len(ds)} frames in {time.perf_counter() - t0:.1f} s on {mapper.device} -> {args.out}")
    print(mapper.timings.table())


if __name__ == "__main__":
    main()
