"""The command modules of ``ogscene3d`` (one per command, each with ``add_parser(subparsers)``)."""
