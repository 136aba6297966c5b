"""``ogscene3d run``: map an RGB-D sequence (or the default synthetic scene) into a run directory."""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

from ..config import add_override_argument, load_config
from ..device import resolve_device
from ..errors import DataError
from ..tracking import add_poses_argument

log = logging.getLogger(__name__)


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "run",
        help="map an RGB-D sequence into semantic Gaussians and a scene graph",
        description="Incremental semantic mapping (paper Sec. III). Writes gaussians.ply, map.npz, "
        "graph.json, timings.json and config.yaml to --out. Without --data a synthetic scene is generated "
        "(in OUT/scene) from the config's `synthetic` section and mapped.",
    )
    p.add_argument(
        "--config", default=None, help="YAML config (e.g. configs/replica.yaml); defaults otherwise"
    )
    p.add_argument("--data", default=None, help="dataset folder (Replica, ScanNet, TUM, 7-Scenes, synthetic)")
    p.add_argument("--segments", default=None, help="folder of precomputed segments (<rgb stem>.png/.json)")
    p.add_argument("--out", required=True, help="run directory to write")
    p.add_argument(
        "--device", default=None, help="cpu, cuda or cuda:N (default: config, else CUDA if present)"
    )
    p.add_argument("--max-frames", type=int, default=None, help="map at most this many frames")
    p.add_argument(
        "--ablation",
        default=None,
        choices=["naive", "local", "local+global", "full"],
        help="which semantic modules run (default: the config's, 'full')",
    )
    p.add_argument("--resume", action="store_true", help="continue from OUT/map.npz")
    add_override_argument(p)
    add_poses_argument(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..datasets import make_synthetic_scene, open_dataset
    from .mapper import Mapper

    overrides = list(args.overrides)
    if args.ablation:
        overrides.append(f"mapping.ablation={args.ablation}")
    if args.device:
        overrides.append(f"device={args.device}")
    cfg = load_config(args.config, overrides)
    if args.poses:
        cfg.tracking.poses = args.poses
    resolve_device(cfg.device)  # an unusable device fails before a synthetic scene is generated
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    data = args.data or cfg.data.path
    if data is None:
        s = cfg.synthetic
        log.info(
            "no --data: generating the synthetic scene (seed %d, %d frames, %dx%d) in %s",
            s.seed,
            s.frames,
            s.width,
            s.height,
            out / "scene",
        )
        data = make_synthetic_scene(
            out / "scene",
            s.seed,
            s.frames,
            s.width,
            s.height,
            s.noise,
            s.depth_noise,
            s.pose_noise,
            progress=not args.no_progress,
        )
    ds = open_dataset(data, segments_dir=args.segments, max_frames=args.max_frames, config=cfg.data)
    if len(ds) == 0:
        raise DataError(f"{data}: the dataset has no frames")

    mapper = Mapper(cfg, cfg.device)
    mapper.set_checkpoint_dir(out)
    start = 0
    if args.resume:
        ckpt = out / "map.npz"
        if not ckpt.is_file():
            raise DataError(f"{ckpt}: --resume needs a checkpoint from an earlier run in --out")
        mapper.load_checkpoint(ckpt)
        start = mapper.next_index
        log.info(
            "resuming at frame %d (%d frames mapped, %d keyframes, %d Gaussians)",
            start,
            mapper.frames_seen,
            mapper.keyframe_count,
            len(mapper.map),
        )

    # bad frames raise, or are skipped with a warning under data.on_bad_frame: skip
    frames = ds.frames(start)
    if not args.no_progress:
        from tqdm import tqdm

        frames = tqdm(frames, desc="mapping", unit="frame", total=max(0, len(ds) - start))
    t0 = time.perf_counter()
    given = 0
    for frame in frames:
        mapper.process(frame)
        given += 1
        if hasattr(frames, "set_postfix"):
            frames.set_postfix(gaussians=len(mapper.map), kf=mapper.keyframe_count)
    mapper.finalize()
    mapper.save(out)
    dt = time.perf_counter() - t0
    print(
        f"mapped {given} frames ({mapper.keyframe_count} keyframes) in {dt:.1f} s "
        f"on {mapper.device}: "
        f"{len(mapper.map)} Gaussians -> {out}"
    )
    print(mapper.timings.table())
    return 0
