"""``ogscene3d run``: map an RGB-D sequence into semantic Gaussians and a scene graph.

Incremental semantic mapping (paper Sec. III). Writes gaussians.ply, map.npz (and its memory views in
map_memory/), graph.json, timings.json, config.yaml and run_id (the run's id, which --resume checks map.npz
against) to --out. Without --data a synthetic scene is generated (in OUT/scene) from the config's `synthetic`
section and mapped.

The options are parsed and the outcome printed here; the session is :mod:`ogscene3d.mapping.session`'s and
the run :mod:`ogscene3d.mapping.engine`'s (heavy modules are imported inside :func:`run` only, so that
``ogscene3d --help`` stays quick).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
from collections.abc import Iterator
from pathlib import Path

from ..cli_types import add_rerun_arguments
from ..config import choices, load_config
from ..errors import DataError
from ..models.manifest import manifest_overrides
from ..progress import RunTimeEstimate
from ..runs import RunFolder, recorded_data_path
from .options import add_command, add_override_argument, add_poses_argument, add_shared_arguments

log = logging.getLogger(__name__)


def add_parser(subparsers) -> None:
    p = add_command(subparsers, __doc__, run)
    add_shared_arguments(p, "--config", "--data", "--segments")
    p.add_argument(
        "--models", default=None, help="models folder from `ogscene3d models export` (its models.json)"
    )
    add_shared_arguments(p, "--out", "--device", "--max-frames", out="run directory to write")
    p.add_argument(
        "--ablation",
        default=None,
        choices=choices("mapping.ablation"),
        help="which semantic modules run (default: the config's, 'full')",
    )
    p.add_argument("--resume", action="store_true", help="continue from OUT/map.npz")
    add_override_argument(p)
    add_poses_argument(p)
    add_shared_arguments(p, "--no-progress")
    add_rerun_arguments(p)


def run(args: argparse.Namespace) -> int:
    from ..device import resolve_device
    from ..mapping.engine import stopped_message
    from ..mapping.session import mapping_session

    overrides = list(args.overrides)
    if args.models:  # the exported models' settings first: --set still overrides them
        overrides = manifest_overrides(args.models) + overrides
    if args.ablation:
        overrides.append(f"mapping.ablation={args.ablation}")
    if args.device:
        overrides.append(f"device={args.device}")
    out = Path(args.out)
    saved = RunFolder(out).config
    base = args.config
    if args.resume and base is None and saved.is_file():
        base = saved  # a resumed run goes on with the settings (and the data) it started with
        log.info("resuming with the run's own %s", saved)
    cfg = load_config(base, overrides)
    if args.poses:
        cfg.tracking.poses = args.poses
    resolve_device(cfg.device)  # an unusable device fails before a synthetic scene is generated
    if args.rerun or args.rerun_save:  # a missing rerun-sdk fails now, before anything is generated or read
        from ..viewer.rerun_log import rerun_module

        rerun_module()
    data = args.data or cfg.data.path or (recorded_data_path(out) if args.resume else None)
    if data is None and args.resume:
        raise DataError(f"{out}: --resume needs the run's dataset: pass --data (the run records none)")
    # no data: the synthetic scene, generated in OUT/scene; --max-frames bounds this invocation only
    with mapping_session(
        cfg,
        out,
        data,
        command="run",
        segments=args.segments,
        max_frames=args.max_frames,
        resume=args.resume,
        progress=not args.no_progress,
    ) as session:
        _warn_small_images(cfg, session.dataset)
        with run_observers(args, cfg, session.data, session.total) as observers:
            session.engine.observers.extend(observers)
            # bad frames raise, or are skipped with a warning under data.on_bad_frame: skip
            summary = session.run(progress=not args.no_progress)
    start, data = session.start, session.data
    if summary.status == "stopped":
        print(stopped_message(summary))
        return 130
    if summary.status == "up to date":
        if args.max_frames is not None:
            # the map may not have reached the end of the sequence: only this bound stopped it reading on
            print(
                f"nothing to do: --max-frames {args.max_frames} ends at or before frame {start}, where the "
                f"map in {out} already is; leave --max-frames out, or raise it, to map the frames after it"
            )
        else:
            print(f"nothing to do: {out} has mapped every frame of {data} (--resume read no new frame)")
        return 0
    print(summary.line())
    print(session.mapper.timings.table())
    return 0


@contextlib.contextmanager
def run_observers(args: argparse.Namespace, cfg, data, frames: int | None) -> Iterator[list]:
    """What watches a run (``MappingEngine``'s observers): the run-time estimate over ``frames`` (None: a
    camera, no end to estimate), and the Rerun logger that ``--rerun`` / ``--rerun-save`` ask for (closed,
    its file complete, when the block ends)."""
    m = cfg.mapping
    observers: list = []
    if frames is not None:
        observers.append(RunTimeEstimate(frames, m.keyframe_every, cfg.data.scale, m.optimize.iters))
    rerun = None
    if getattr(args, "rerun", None) or getattr(args, "rerun_save", None):
        from ..viewer.rerun_log import rerun_logger

        rerun = rerun_logger(args.rerun, args.rerun_save, Path(str(data)).name)
        observers.append(rerun)
    try:
        yield observers
    finally:
        if rerun is not None:
            rerun.close()


# The most a Gaussian centre may drift per keyframe (mapping.optimize.lr_means x mapping.optimize.iters)
# before small images' maps suffer: configs/synthetic.yaml's budget; docs/defaults.md has the measurements.
SMALL_IMAGE_WIDTH = 320
SMALL_IMAGE_DRIFT = 3e-4


def _warn_small_images(cfg, ds) -> None:
    """Say which config to use when the paper's optimisation budget meets small images (slow, and it moves
    the Gaussians off the surfaces there)."""
    import numpy as np

    width = 2.0 * float(np.asarray(ds.K)[0, 2])  # the principal point is near the image centre
    drift = cfg.mapping.optimize.lr_means * cfg.mapping.optimize.iters
    if width <= SMALL_IMAGE_WIDTH and drift > SMALL_IMAGE_DRIFT * 1.001:
        log.warning(
            "images about %d px wide with mapping.optimize.iters=%d and mapping.optimize.lr_means=%g: slow, "
            "and the Gaussians drift off the surfaces; for images up to %d px wide use --config synthetic "
            "(see docs/defaults.md)",
            round(width),
            cfg.mapping.optimize.iters,
            cfg.mapping.optimize.lr_means,
            SMALL_IMAGE_WIDTH,
        )
