"""The ``ogscene3d`` command line: one entry point, one subcommand per capability.

Each subcommand lives in the module that implements it and exposes ``add_parser(subparsers)``,
which registers the subcommand and sets ``func`` (``args -> int`` exit code) as its default.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys

from .errors import OGSceneError

# Modules that register a subcommand, in the order they appear in --help.
_COMMAND_MODULES = [
    "ogscene3d.mapping.run_cli",  # run
    "ogscene3d.eval.eval_cli",  # eval
    "ogscene3d.viewer.cli",  # live
    "ogscene3d.datasets.synth_cli",  # synth
    "ogscene3d.segmentation.segment_cli",  # segment
    "ogscene3d.tracking",  # track
    "ogscene3d.graph.graph_cli",  # graph
    "ogscene3d.batch",  # run-batch, eval-batch
    "ogscene3d.render_demo",  # render-demo
    "ogscene3d.commands.models",  # models
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="ogscene3d", description="Incremental open-vocabulary 3D semantic mapping and scene graphs."
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in _COMMAND_MODULES:
        importlib.import_module(name).add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO, format="%(levelname)s %(name)s: %(message)s"
    )
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except OGSceneError as e:
        print(f"ogscene3d {args.command}: error: {e}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        # the reader went away (`ogscene3d graph RUN --nodes | head`): no traceback, and none at exit
        # either when Python flushes stdout
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    except OSError as e:
        if args.verbose:
            raise
        # a full disk, a read-only --out, a permission: the file and the reason say it all
        print(f"ogscene3d {args.command}: error: {e} (-v for the traceback)", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"ogscene3d {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
