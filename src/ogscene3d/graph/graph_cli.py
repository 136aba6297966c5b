"""``ogscene3d graph``: inspect, query and export a run's scene graph (graph.json)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..config import add_override_argument, load_config
from ..errors import DataError
from .scenegraph import SceneGraph


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "graph",
        help="inspect, query or export a scene graph",
        description="Print a scene graph (graph.json of a run directory), query its nodes by text, or export "
        "it to GraphML.",
    )
    p.add_argument("path", help="graph.json, or a run directory that contains one")
    p.add_argument("--query", "-q", action="append", default=[], help="text to look up in node tags/captions")
    p.add_argument("--top-k", type=int, default=5, help="results per query (default 5)")
    p.add_argument("--graphml", help="write the graph as GraphML to this path (needs networkx)")
    p.add_argument("--config", help="YAML config (for graph.query_embedding and its endpoint)")
    add_override_argument(p, "graph.query_embedding=openai --set graph.embedding_model=MODEL")
    p.add_argument("--edges", action="store_true", help="list every edge")
    p.set_defaults(func=run)


def _name(g: SceneGraph, i: int) -> str:
    n = g.nodes.get(i)
    return f"{(n.tag or 'node') if n else 'node'}#{i}"


def run(args: argparse.Namespace) -> int:
    path = Path(args.path)
    if path.is_dir():
        path = path / "graph.json"
    if not path.is_file():
        raise DataError(f"no scene graph at {str(path)!r}")
    cfg = load_config(args.config, args.overrides).graph
    g = SceneGraph.load(path, cfg)
    rels: dict[str, int] = {}
    for e in g.edges.values():
        rels[e.relation] = rels.get(e.relation, 0) + 1
    print(
        f"{path}: {len(g.nodes)} nodes, {len(g.edges)} edges "
        f"({', '.join(f'{k}: {v}' for k, v in sorted(rels.items())) or 'none'})"
    )
    if args.edges:
        for k in sorted(g.edges):
            e = g.edges[k]
            print(f"  {_name(g, e.source)} {e.relation} {_name(g, e.target)}  (R={e.score:.2f})")
    for q in args.query:
        hits = g.query_scored(q, top_k=args.top_k)
        print(f"query {q!r}: {len(hits)} match(es)")
        for n, s in hits:
            c = n.center
            print(f"  #{n.id} {n.tag!r} score {s:.2f} at [{c[0]:.2f}, {c[1]:.2f}, {c[2]:.2f}]: {n.caption}")
    if args.graphml:
        g.save_graphml(args.graphml)
        print(f"wrote {args.graphml}")
    return 0
