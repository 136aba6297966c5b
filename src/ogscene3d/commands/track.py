"""``ogscene3d track``: estimate camera poses of an RGB-D sequence with Open3D RGB-D odometry.

Track a dataset with keyframe-to-frame RGB-D odometry (config section `tracking`). Writes OUT/traj.txt (one
row-major c2w 4x4 per frame; a skipped frame repeats the last good pose) and OUT/tracking.json (per-frame
status, and the ATE against the dataset's poses when it has them).

The tracker: :mod:`ogscene3d.tracking`.
"""

from __future__ import annotations

import math
from typing import Any

from ..atomic import atomic_write_text
from ..config import load_config
from ..errors import ConfigError, OGSceneError
from .options import add_command, add_override_argument, add_shared_arguments


def add_parser(subparsers: Any) -> None:
    p = add_command(subparsers, __doc__, run)
    add_shared_arguments(
        p,
        "--data",
        "--out",
        "--config",
        "--device",
        "--max-frames",
        "--no-progress",
        data="dataset folder (default: config data.path)",
        config="YAML config; defaults otherwise",
        device="cpu, cuda or cuda:N (default: config, else CUDA if usable)",
        max_frames="track at most this many frames",
    )
    add_override_argument(p, "tracking.max_width=320")


def run(args: Any) -> int:
    import json
    import time
    from pathlib import Path

    import numpy as np

    from ..datasets import open_dataset
    from ..eval.trajectory import ate
    from ..tracking import Tracker, hold_last_good, track_frames, trajectory_text, validate_tracking_config

    cfg = load_config(args.config, args.overrides)
    validate_tracking_config(cfg.tracking)
    if args.data is None and cfg.data.path is None:
        # open_dataset's own message names its `path` argument, which this command does not have
        raise ConfigError("no dataset to track: pass --data DIR (or set data.path in --config)")
    ds = open_dataset(args.data, max_frames=args.max_frames, config=cfg.data)
    try:
        tracker = Tracker(cfg.tracking, device=args.device or cfg.device, frame_step=cfg.data.stride)
    except ValueError as e:  # a device Open3D cannot use
        raise ConfigError(f"track: {e}") from e
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    poses: list[np.ndarray | None] = []
    given: list[np.ndarray | None] = []
    rows: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    for frame, pose, info in track_frames(tracker, ds, progress=not args.no_progress):
        given.append(frame.pose)
        poses.append(pose)
        rows.append(
            {
                "index": frame.index,
                "name": frame.name,
                "status": info.status,
                "reason": info.reason,
                "fitness": None if math.isnan(info.fitness) else info.fitness,
                "inlier_rmse": None if math.isnan(info.inlier_rmse) else info.inlier_rmse,
                "keyframe": info.keyframe,
                "reference": info.reference,
                "method": info.method,
            }
        )
    seconds = time.perf_counter() - t0
    if not poses:
        raise OGSceneError(f"track: the dataset at {ds.root} yielded no frames")
    filled = hold_last_good(poses)
    if not filled:
        raise OGSceneError(f"track: none of the {len(poses)} frames could be tracked ({rows[0]['reason']})")
    valid = [q is not None for q in poses]
    summary: dict[str, Any] = {
        "frames": len(poses),
        "tracked": int(sum(valid)),
        "skipped": int(len(valid) - sum(valid)),
        "keyframes": int(sum(r["keyframe"] or r["status"] == "anchor" for r in rows)),
        "seconds": seconds,
        "device": str(tracker.device),
    }
    pairs = [(q, g) for q, g in zip(poses, given, strict=True) if q is not None and g is not None]
    if len(pairs) >= 3:
        err = ate([q for q, _ in pairs], [g for _, g in pairs], "se3")
        summary["ate_rmse_m"] = err.rmse
        summary["ate_protocol"] = f"positions of {err.num_poses} tracked frames vs dataset poses, se3-aligned"
    atomic_write_text(out / "traj.txt", trajectory_text(filled))
    atomic_write_text(
        out / "tracking.json", json.dumps({"summary": summary, "frames": rows}, indent=1) + "\n"
    )
    msg = f"tracked {summary['tracked']}/{summary['frames']} frames in {seconds:.1f} s"
    if "ate_rmse_m" in summary:
        msg += f", ATE RMSE {summary['ate_rmse_m'] * 100:.2f} cm vs the dataset's poses"
    print(f"{msg}; wrote {out / 'traj.txt'} and {out / 'tracking.json'}")
    return 0
