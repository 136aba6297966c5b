"""``ogscene3d synth``: generate a synthetic RGB-D scene with ground truth and simulated segments.

Render a procedural furnished room along an exploring trajectory (Replica layout plus gt/ and segments/).
Defaults come from the config's `synthetic` section.
"""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

from ..cli_types import add_size_argument
from ..config import choices, load_config
from ..errors import ConfigError, OGSceneError
from .options import add_command, add_override_argument, add_shared_arguments

log = logging.getLogger(__name__)


def add_parser(subparsers) -> None:
    p = add_command(subparsers, __doc__, run)
    add_shared_arguments(
        p, "--out", "--config", config="YAML config (its `synthetic` section gives the defaults)"
    )
    p.add_argument("--seed", type=int, default=None, help="scene, trajectory and noise seed")
    p.add_argument("--frames", type=int, default=None, help="number of frames (--layout apartment: per room)")
    p.add_argument(
        "--layout",
        default=None,
        choices=choices("synthetic.layout"),
        help="room (one furnished room, a smooth walk) | scan (a long scan like a real ScanNet one; give it "
        "300 frames or more) | apartment (2-5 rooms walked through room by room)",
    )
    add_size_argument(p, "--size", "image size, e.g. 160x120", minimum=8)
    p.add_argument(
        "--noise",
        default=None,
        choices=choices("synthetic.noise"),
        help="simulated-SAM level (docs/consistency.md)",
    )
    p.add_argument("--depth-noise", type=float, default=None, help="depth noise std in metres")
    p.add_argument("--pose-noise", type=float, default=None, help="pose translation noise std in metres")
    add_shared_arguments(
        p, "--device", device={"default": "cpu", "help": "Warp device for ray casting (cpu, cuda, cuda:0)"}
    )
    p.add_argument("--force", action="store_true", help="overwrite a non-empty output folder")
    add_override_argument(p, "synthetic.frames=30")


def _reusable(out: str | Path, params: dict, overwrite: bool) -> bool:
    """Whether ``make_synthetic_scene`` will reuse ``out`` as is: it holds a scene made with the same
    arguments (its scene.json) and --force was not given. Decided before the call, so that the final
    line can say "reused" instead of "written"."""
    from ..datasets.synthetic import holds_scene, scene_params  # numpy and OpenCV: not for `--help`

    return not overwrite and holds_scene(out, scene_params(**params))


def _frame_count(out: Path) -> int:
    """The frames written (an apartment's path has ``frames`` per room): the poses in traj.txt."""
    with open(Path(out) / "traj.txt") as f:
        return sum(1 for line in f if line.strip())


def run(args: argparse.Namespace) -> int:
    from ..datasets.synthetic import make_synthetic_scene

    cfg = load_config(args.config, args.overrides).synthetic
    width, height = args.size if args.size is not None else (cfg.width, cfg.height)
    params = dict(
        seed=cfg.seed if args.seed is None else args.seed,
        frames=cfg.frames if args.frames is None else args.frames,
        width=width,
        height=height,
        noise=cfg.noise if args.noise is None else args.noise,
        depth_noise=cfg.depth_noise if args.depth_noise is None else args.depth_noise,
        pose_noise=cfg.pose_noise if args.pose_noise is None else args.pose_noise,
        layout=cfg.layout if args.layout is None else args.layout,
    )
    try:
        reused = _reusable(args.out, params, args.force)
        t0 = time.perf_counter()
        out = make_synthetic_scene(
            args.out, **params, overwrite=args.force, device=args.device, progress=True,
            remedy="choose another --out, or pass --force to regenerate it",
        )  # fmt: skip
    except ValueError as e:
        if isinstance(e, OGSceneError):
            raise
        # Bad argument values (frames, size, noise std, device): print them like config errors.
        raise ConfigError(f"synth: {e}") from e
    what = f"{_frame_count(out)} frames" + (", an apartment" if params["layout"] == "apartment" else "")
    if reused:
        print(f"synthetic scene reused from {out} ({what}, made with the same arguments)")
    else:
        dt = time.perf_counter() - t0
        print(f"synthetic scene written to {out} ({what}, {dt:.1f} s)")
    return 0
