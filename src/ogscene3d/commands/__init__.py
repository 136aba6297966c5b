"""The ``ogscene3d`` subcommands, one module per command.

Each module has ``add_parser(subparsers)``, which registers its subcommand(s) and sets ``func``
(``args -> int`` exit code). A command module imports only light things at module level (argparse, the
config dataclasses, the errors): the heavy ones (torch, warp, open3d, viser) go inside ``func``, so that
``ogscene3d --help`` answers at once. tests/test_commands.py holds every module listed here to that.
"""

from __future__ import annotations

#: Modules that register a subcommand, in the order they appear in ``ogscene3d --help``.
COMMAND_MODULES: list[str] = [
    "ogscene3d.commands.run",  # run
    "ogscene3d.commands.eval",  # eval
    "ogscene3d.commands.live",  # live
    "ogscene3d.commands.synth",  # synth
    "ogscene3d.commands.segment",  # segment
    "ogscene3d.commands.track",  # track
    "ogscene3d.commands.graph",  # graph
    "ogscene3d.commands.batch",  # run-batch, eval-batch
    "ogscene3d.commands.render_demo",  # render-demo
    "ogscene3d.commands.config",  # config
    "ogscene3d.commands.export",  # export
    "ogscene3d.commands.models",  # models export
]
