"""``ogscene3d run``: map an RGB-D sequence (or the default synthetic scene) into a run directory."""

from __future__ import annotations

import argparse
import logging
import signal
import time
from pathlib import Path
from typing import Any

import yaml

from ..config import add_override_argument, load_config
from ..device import resolve_device
from ..errors import DataError
from ..tracking import add_poses_argument
from .pose_jump import PoseJumpError
from .source import (
    check_same_source,
    dataset_source,
    matching_pixel_centers,
    record_data,
    remove_run_temps,
    resumed_run_id,
    start_run_dir,
)

log = logging.getLogger(__name__)


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "run",
        help="map an RGB-D sequence into semantic Gaussians and a scene graph",
        description="Incremental semantic mapping (paper Sec. III). Writes gaussians.ply, map.npz (and "
        "its memory views in map_memory/), graph.json, timings.json, config.yaml and run_id (the run's id, "
        "which --resume checks map.npz against) to --out. Without "
        "--data a synthetic scene is generated (in OUT/scene) from the config's `synthetic` section and "
        "mapped.",
    )
    p.add_argument(
        "--config", default=None, help="YAML config (e.g. configs/replica.yaml); defaults otherwise"
    )
    p.add_argument("--data", default=None, help="dataset folder (Replica, ScanNet, TUM, 7-Scenes, synthetic)")
    p.add_argument("--segments", default=None, help="folder of precomputed segments (<rgb stem>.png/.json)")
    p.add_argument(
        "--models", default=None, help="models folder from `ogscene3d models export` (its models.json)"
    )
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
    from ..datasets import configured_scene, open_dataset
    from .mapper import Mapper

    overrides = list(args.overrides)
    if args.models:  # the exported models' settings first: --set still overrides them
        from ..models.manifest import manifest_overrides

        overrides = manifest_overrides(args.models) + overrides
    if args.ablation:
        overrides.append(f"mapping.ablation={args.ablation}")
    if args.device:
        overrides.append(f"device={args.device}")
    out = Path(args.out)
    saved = out / "config.yaml"
    base = args.config
    if args.resume and base is None and saved.is_file():
        base = saved  # a resumed run goes on with the settings (and the data) it started with
        log.info("resuming with the run's own %s", saved)
    cfg = load_config(base, overrides)
    if args.poses:
        cfg.tracking.poses = args.poses
    resolve_device(cfg.device)  # an unusable device fails before a synthetic scene is generated
    out.mkdir(parents=True, exist_ok=True)

    data = args.data or cfg.data.path or (_recorded_data_path(saved) if args.resume else None)
    if data is None and args.resume:
        raise DataError(f"{out}: --resume needs the run's dataset: pass --data (the run records none)")
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
        data = configured_scene(
            out / "scene",
            s,
            progress=not args.no_progress,
            remedy="give a new --out, or remove that folder to generate the scene there again",
        )
    # the run's config.yaml records what was mapped: eval finds the ground truth and --resume the frames
    record_data(cfg, data, args.segments)
    # --max-frames bounds this invocation only (a resume without it goes on to the end)
    ds = open_dataset(max_frames=args.max_frames, config=cfg.data)
    if len(ds) == 0:
        raise DataError(f"{data}: the dataset has no frames")
    source = dataset_source(cfg, ds)
    remove_run_temps(out)

    mapper = Mapper(cfg, cfg.device)
    mapper.set_checkpoint_dir(out)
    start = 0
    run_id = None
    if args.resume:
        ckpt = out / "map.npz"
        if not ckpt.is_file():
            raise DataError(f"{ckpt}: --resume needs a checkpoint from an earlier run in --out")
        mapper.load_checkpoint(ckpt)
        # first: with another run's config.yaml, the checks below would compare the map with the wrong data
        run_id = resumed_run_id(out, mapper.source, cfg)
        start = mapper.next_index
        check_same_source(
            ckpt, mapper.source, source, start, pixel_centers=lambda K: matching_pixel_centers(ds, K)
        )
        recorded_names = mapper.source.get("names")
        if len(source["names"]) < start:
            # a resume bounded short of where the map got (--max-frames): its checkpoint must still name every
            # frame the map has read, for a later resume and eval --held-out; a map of an older version names
            # none, and then neither does this one (a shorter list would read as frames removed since)
            if recorded_names is not None:
                source["names"] = recorded_names[:start]
            else:
                del source["names"]
        log.info(
            "resuming at frame %d (%d frames mapped, %d keyframes, %d Gaussians)",
            start,
            mapper.frames_seen,
            mapper.keyframe_count,
            len(mapper.map),
        )
    elif (out / "map.npz").is_file():
        # config.yaml is rewritten now: should this run die before its first save, --resume refuses the old
        # map beside the new settings (resumed_run_id), so say so while the old map can still be kept
        log.warning(
            "%s holds a map from an earlier run: this run replaces it at its first save (--resume continues "
            "that map instead; a new --out keeps it)",
            out,
        )
    mapper.source = source
    source.update(start_run_dir(out, cfg, run_id))

    # bad frames raise, or are skipped with a warning under data.on_bad_frame: skip
    frames = ds.frames(start)
    if not args.no_progress:
        from tqdm import tqdm

        frames = tqdm(frames, desc="mapping", unit="frame", total=max(0, len(ds) - start))
    t0 = time.perf_counter()
    given, seen0, counts0 = 0, mapper.frames_seen, dict(mapper.timings.counts)
    stop = _StopRequest()
    try:
        with stop:
            for frame in frames:
                mapper.process(frame)
                given += 1
                if hasattr(frames, "set_postfix"):
                    frames.set_postfix(gaussians=len(mapper.map), kf=mapper.keyframe_count)
                if stop.requested:
                    break
    except DataError as e:
        if mapper.keyframe_count:
            # a bad frame late in a long sequence must not cost the map built so far
            mapper.save_checkpoint(out / "map.npz")
            fix = (
                "fix the pose (or --set mapping.on_pose_jump=skip, or =warn to map it)"
                if isinstance(e, PoseJumpError)
                else "fix the frame (or --set data.on_bad_frame=skip)"
            )
            log.error("the map so far is in %s: %s, then --resume", out / "map.npz", fix)
        raise
    if stop.requested:
        if mapper.keyframe_count:
            mapper.save_checkpoint(out / "map.npz")
            print(f"stopped after {given} frames; the map so far is in {out / 'map.npz'}: --resume goes on")
        else:
            print(f"stopped after {given} frames, before any keyframe: nothing to save")
        return 130
    if given == 0 and mapper.finalized:
        print(f"nothing to do: {out} has mapped every frame of {data} (--resume read no new frame)")
        return 0
    if mapper.keyframe_count == 0:
        untracked = int(mapper.timings.counts.get("frames_untracked", 0))
        why = f", {untracked} of them untracked by odometry (see the warnings above)" if untracked else ""
        raise DataError(f"{data}: none of the {given} frames read could be mapped{why}")
    mapper.finalize()
    mapper.save(out)
    dt = time.perf_counter() - t0
    mapped = mapper.frames_seen - seen0
    skipped = ""
    # this invocation's frames only: the counts go on across resumes
    for key, what in (("frames_untracked", "untracked"), ("frames_skipped_pose_jump", "pose jumps")):
        n = int(mapper.timings.counts.get(key, 0) - counts0.get(key, 0))
        skipped += f", {n} {what} left out" if n else ""
    print(
        f"read {given} frames: {mapped} mapped ({mapper.keyframe_count} keyframes in all){skipped}, "
        f"in {dt:.1f} s on {mapper.device}: {len(mapper.map)} Gaussians -> {out}"
    )
    print(mapper.timings.table())
    return 0


class _StopRequest:
    """Ctrl-C or SIGTERM while mapping: finish the frame, then stop (the caller saves a checkpoint);
    a second one stops at once. Saving from inside a frame could write a half-updated state."""

    def __init__(self) -> None:
        self.requested = False
        self._previous: dict[int, Any] = {}

    def __enter__(self) -> _StopRequest:
        for sig in (signal.SIGINT, signal.SIGTERM):
            try:
                self._previous[sig] = signal.signal(sig, self._handle)
            except ValueError:  # not the main thread (an embedding application): its handlers stay
                break
        return self

    def __exit__(self, *exc) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)

    def _handle(self, signum, frame) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True
        log.warning("stopping after this frame to save the map (again to stop at once, losing it)")


def _recorded_data_path(saved: Path) -> str | None:
    """data.path from a run's config.yaml (None when absent or unreadable)."""
    try:
        loaded = yaml.safe_load(saved.read_text())
    except (OSError, yaml.YAMLError):
        return None
    data = loaded.get("data") if isinstance(loaded, dict) else None
    path = data.get("path") if isinstance(data, dict) else None
    return path if isinstance(path, str) else None
