"""``ogscene3d graph``: inspect, query or export a scene graph.

Print a scene graph (graph.json of a run directory): a summary line, and with --nodes / --edges one line per
node / edge; query its nodes by text, or export it to GraphML.
"""

from __future__ import annotations

import argparse
import json
import textwrap
from pathlib import Path
from typing import TYPE_CHECKING

from ..cli_types import positive_int
from ..config import load_config
from ..errors import DataError
from ..runs import RunFolder
from .options import add_command, add_override_argument, add_shared_arguments

if TYPE_CHECKING:
    from ..graph.scenegraph import SceneGraph
    from ..graph.types import SceneNode


def _query_text(text: str) -> str:
    """argparse type: a query with some text in it (matching an empty string means nothing)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("the query text is empty")
    return text


def add_parser(subparsers) -> None:
    p = add_command(subparsers, __doc__, run)
    p.add_argument("path", help="graph.json, or a run directory that contains one")
    p.add_argument(
        "--query",
        "-q",
        action="append",
        default=[],
        type=_query_text,
        help='a query: an object ("chair"), with a relation ("pillow on the bed"), a room ("chair in the '
        'kitchen", "the mug on the desk in the office"), a room alone ("kitchen") or #id; repeatable',
    )
    p.add_argument("--top-k", type=positive_int, default=5, help="results per query (default 5)")
    p.add_argument("--graphml", help="write the graph as GraphML to this path (needs networkx)")
    add_shared_arguments(p, "--config", config="YAML config (for graph.query_embedding and its endpoint)")
    add_override_argument(p, "graph.query_embedding=openai --set graph.embedding_model=MODEL")
    p.add_argument(
        "--nodes",
        action="store_true",
        help="list every node: id, tag, caption (shortened), Gaussians, confidence, center",
    )
    p.add_argument("--edges", action="store_true", help="list every edge")
    p.add_argument("--rooms", action="store_true", help="list the storeys and rooms with their objects")
    p.add_argument(
        "--json",
        action="store_true",
        help="print the query answers as JSON ({query, source, message, parsed, hits: [{kind, id, score, "
        "reason, ...}]} per query, a list) instead of text",
    )


def _name(g: SceneGraph, i: int) -> str:
    n = g.nodes.get(i)
    return f"{(n.tag or 'node') if n else 'node'}#{i}"


def node_line(n: SceneNode, caption_width: int = 60) -> str:
    """One node as ``--nodes`` lists it: ``#id 'tag' N Gaussians, confidence C at [x, y, z]: caption``
    (the Gaussian count only when the graph stores one; long captions shortened to ``caption_width``)."""
    c = n.center
    tag = textwrap.shorten(n.tag, 30, placeholder="...") if n.tag else "(untagged)"
    parts = [f"#{n.id} {tag!r}" if n.tag else f"#{n.id} {tag}"]
    if n.num_gaussians > 0:
        parts.append(f"{n.num_gaussians} Gaussians,")
    parts.append(f"confidence {n.confidence:.2f} at [{c[0]:.2f}, {c[1]:.2f}, {c[2]:.2f}]")
    line = " ".join(parts)
    if n.caption:
        line += ": " + textwrap.shorten(n.caption, caption_width, placeholder="...")
    return line


def run(args: argparse.Namespace) -> int:
    from ..graph.scenegraph import SceneGraph

    path = Path(args.path)
    if path.is_dir():
        path = RunFolder(path).graph
    if not path.is_file():
        raise DataError(f"no scene graph at {str(path)!r}")
    cfg = load_config(args.config, args.overrides).graph
    g = SceneGraph.load(path, cfg)
    if args.json:
        print(json.dumps([g.ask(q, top_k=args.top_k).to_dict() for q in args.query], indent=1))
        if args.graphml:
            g.save_graphml(args.graphml)
        return 0
    rels: dict[str, int] = {}
    for e in g.edges.values():
        rels[e.relation] = rels.get(e.relation, 0) + 1
    rooms = f", {len(g.rooms)} rooms" if g.rooms else ""
    print(
        f"{path}: {len(g.nodes)} nodes, {len(g.edges)} edges "
        f"({', '.join(f'{k}: {v}' for k, v in sorted(rels.items())) or 'none'}){rooms}"
    )
    if args.nodes:
        for i in sorted(g.nodes):
            print("  " + node_line(g.nodes[i]))
    if args.edges:
        for k in sorted(g.edges):
            e = g.edges[k]
            print(f"  {_name(g, e.source)} {e.relation} {_name(g, e.target)}  (R={e.score:.2f})")
    if args.rooms:
        for f in g.floors:
            print(f"  floor {f.id} at height {f.height:.2f} m")
        for i in sorted(g.rooms):
            r = g.rooms[i]
            tags = ", ".join(_name(g, o) for o in r.objects[:12]) + (" ..." if len(r.objects) > 12 else "")
            print(
                f"  room #{r.id} {r.type!r} (floor {r.floor}, {r.area:.1f} m^2, type by "
                f"{r.type_source or '-'}: {r.type_reason}): {tags or 'no object'}"
            )
    for q in args.query:
        answer = g.ask(q, top_k=args.top_k)
        print(
            f"query {q!r}: {len(answer.hits)} match(es)"
            + (f" ({answer.source})" if answer.source != "offline" else "")
        )
        if answer.message:
            print(f"  note: {answer.message}")
        for h in answer.hits:
            c = h.node.center
            what = f"{h.node.tag!r}" if h.kind == "object" else f"room {h.node.type!r}"
            print(f"  #{h.id} {what} score {h.score:.2f} at [{c[0]:.2f}, {c[1]:.2f}, {c[2]:.2f}]: {h.reason}")
    if args.graphml:
        g.save_graphml(args.graphml)
        print(f"wrote {args.graphml}")
    return 0
