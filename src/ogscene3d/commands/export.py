"""``ogscene3d export``: export a run as a coloured point cloud, per-node clouds and GraphML.

Write a run's Gaussians as a PLY point cloud with standard red/green/blue colours and label/confidence
properties (Open3D, CloudCompare, MeshLab show its colours), one such cloud per scene-graph node, and the
scene graph as GraphML with each node's boxes.

The files: docs/exports.md.
"""

from __future__ import annotations

import argparse

from ..cli_types import unit_interval
from ..errors import ConfigError
from .options import add_command, add_shared_arguments


def add_parser(subparsers) -> None:
    p = add_command(subparsers, __doc__, run)
    p.add_argument("run", help="run directory (with gaussians.ply and graph.json)")
    add_shared_arguments(p, "--out", out={"required": False, "help": "output directory (default RUN/export)"})
    p.add_argument(
        "--colors",
        choices=("rgb", "semantic"),
        default="rgb",
        help="vertex colours: the Gaussians' colour, or their semantic label's colour as the viewer shows "
        "it (default rgb)",
    )
    p.add_argument("--no-cloud", action="store_true", help="skip the whole-map cloud points_<colors>.ply")
    p.add_argument("--no-nodes", action="store_true", help="skip the per-node clouds in nodes/")
    p.add_argument("--no-graphml", action="store_true", help="skip graph.graphml (which needs networkx)")
    p.add_argument(
        "--min-opacity",
        type=unit_interval,
        default=0.0,
        help="leave out Gaussians less opaque than this (0-1, default 0: all)",
    )


def run(args: argparse.Namespace) -> int:
    from ..export import export_run

    if args.no_cloud and args.no_nodes and args.no_graphml:
        raise ConfigError("nothing to export: --no-cloud, --no-nodes and --no-graphml were all given")
    result = export_run(
        args.run,
        args.out,
        colors=args.colors,
        cloud=not args.no_cloud,
        nodes=not args.no_nodes,
        graphml=not args.no_graphml,
        min_opacity=args.min_opacity,
    )
    if result.cloud:
        print(f"wrote {result.cloud}")
    if result.nodes:
        first = result.nodes[min(result.nodes)]
        print(f"wrote {len(result.nodes)} node clouds to {first.parent}")
    if result.graphml:
        print(f"wrote {result.graphml}")
    return 0
