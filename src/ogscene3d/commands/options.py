"""argparse options shared by the commands: ``--set KEY=VALUE`` of every command that reads a config and
``--poses`` of those that map. Their values go to :func:`ogscene3d.config.load_config` and the config."""

from __future__ import annotations

import argparse

from ..config import choices


def add_override_argument(parser: argparse.ArgumentParser, example: str = "mapping.opt_iters=5") -> None:
    """Add the ``--set KEY=VALUE`` option (repeatable; ``args.overrides``, parsed by ``load_config``).

    Args:
        parser: the subcommand's parser.
        example: the override its help shows.
    """
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help=f"config override, repeatable (e.g. --set {example})",
    )


def add_poses_argument(parser: argparse.ArgumentParser) -> None:
    """Add ``--poses gt|odometry`` (the choices of ``tracking.poses``) to a subcommand.

    The command then does ``if args.poses: cfg.tracking.poses = args.poses``.

    Args:
        parser: the subcommand's parser.
    """
    parser.add_argument(
        "--poses",
        choices=choices("tracking.poses"),
        default=None,
        help="camera poses: the dataset's (gt) or RGB-D odometry (odometry); default: config tracking.poses",
    )
