"""argparse options shared by the commands: ``--config``, ``--data``, ``--out``, ``--device`` and the others
that several commands take (:data:`SHARED_OPTIONS`, added by :func:`add_shared_arguments`), ``--set
KEY=VALUE`` of every command that reads a config and ``--poses`` of those that map. Their values go to
:func:`ogscene3d.config.load_config` and the config."""

from __future__ import annotations

import argparse
import re
from collections.abc import Callable
from typing import Any

from ..config import choices

#: The options several commands take, flag -> ``add_argument`` keywords: what each means is written once
#: here; a command changes only what differs for it (its own help, a default, a type).
SHARED_OPTIONS: dict[str, dict[str, Any]] = {
    "--config": {"default": None, "help": "YAML config (e.g. configs/replica.yaml); defaults otherwise"},
    "--data": {"default": None, "help": "dataset folder (Replica, ScanNet, TUM, 7-Scenes, synthetic)"},
    "--segments": {"default": None, "help": "folder of precomputed segments (<rgb stem>.png/.json)"},
    "--out": {"required": True, "help": "output folder"},
    "--device": {"default": None, "help": "cpu, cuda or cuda:N (default: config, else CUDA if present)"},
    "--max-frames": {"type": int, "default": None, "help": "map at most this many frames"},
    "--no-progress": {"action": "store_true", "help": "no progress bar"},
}


def add_shared_arguments(parser: Any, *flags: str, **changes: str | dict[str, Any]) -> None:
    """Add the shared options ``flags`` (keys of :data:`SHARED_OPTIONS`), in that order.

    Args:
        parser: the subcommand's parser (or an argument group of it).
        flags: the options to add, e.g. ``"--config", "--out"``.
        changes: what differs for this command, by the option's dest (``max_frames``): its help (a string)
            or ``add_argument`` keywords that replace the shared ones.
    """
    dests = {flag.lstrip("-").replace("-", "_"): flag for flag in flags}
    unknown = set(changes) - set(dests)
    if unknown:
        raise ValueError(f"changes for options not added: {sorted(unknown)} (added: {list(flags)})")
    for dest, flag in dests.items():
        change = changes.get(dest, {})
        kwargs = {**SHARED_OPTIONS[flag], **({"help": change} if isinstance(change, str) else change)}
        parser.add_argument(flag, **kwargs)


def add_override_argument(parser: argparse.ArgumentParser, example: str = "mapping.optimize.iters=5") -> None:
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


def add_command(subparsers: Any, doc: str | None, func: Callable[[argparse.Namespace], int]) -> Any:
    """Register the subcommand that ``doc`` describes, run by ``func``; its ``--help`` text comes from
    ``doc``, which is written once, as the command module's docstring::

        ``ogscene3d NAME``: what it does (the one-line help in ``ogscene3d --help``).

        What ``ogscene3d NAME --help`` says about it (the description; optional).

        Further paragraphs, for the code's readers only.

    Args:
        subparsers: ``ogscene3d``'s subparsers.
        doc: the command's docstring, as above.
        func: ``args -> exit code``.

    Returns:
        The subcommand's parser, for its options.
    """
    head, _, rest = (doc or "").strip().partition("\n\n")
    match = re.fullmatch(r"``ogscene3d ([a-z-]+)``: (.+)\.", " ".join(head.split()))
    if match is None:
        raise ValueError(f"a command's docstring starts with '``ogscene3d NAME``: help.', got {head!r}")
    description = " ".join(rest.partition("\n\n")[0].split()) or None
    parser = subparsers.add_parser(match[1], help=match[2], description=description)
    parser.set_defaults(func=func)
    return parser
