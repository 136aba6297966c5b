"""``graph.json``: the one reader and writer of a run's scene graph document (docs/formats.md
"graph.json"): ``{"version", "nodes": [...], "edges": [...]}``, a node with an integer ``id`` and a finite
``center`` (3 numbers; a graph made by another tool for ``eval`` may leave it out), an edge with a
``relation`` between the ``source`` and ``target`` ids of two nodes, and the world up vector the graph was
built with (``up``: the vertical its rooms and relations used; :func:`graph_up` reads it).

The document is read and checked here; :meth:`ogscene3d.graph.SceneGraph.from_json` builds a graph from it.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_write_text
from ..errors import DataError
from ..up_axis import unit_up


def write_graph_json(path: str | Path, doc: dict[str, Any]) -> None:
    """Write the graph document ``doc`` to ``path`` atomically (never a half-written file)."""
    atomic_write_text(path, json.dumps(doc, indent=1))


def read_graph_json(path: str | Path, centers: bool = False) -> dict[str, Any]:
    """Read ``graph.json`` and check its structure.

    Args:
        path: the file.
        centers: every node must have a ``center`` (to place it: the viewer); otherwise a node's center is
            checked only where it has one (``eval`` scores graphs by their ids, tags and edges).

    Returns:
        The document, with ``nodes`` and ``edges`` lists (empty when absent).

    Raises:
        DataError: the file is missing or not JSON, a node lacks an integer ``id`` or has a center that is
            not a finite 3-vector, or an edge lacks its ``relation`` or does not join two of the nodes; the
            message names the file and the field.
    """
    p = Path(path)
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DataError(f"{p}: scene graph file does not exist") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise DataError(f"{p}: not valid JSON ({e})") from None
    if (
        not isinstance(doc, dict)
        or not isinstance(doc.get("nodes", []), list)
        or not isinstance(doc.get("edges", []), list)
    ):
        raise DataError(f"{p}: expected an object with 'nodes' and 'edges' lists")
    nodes = doc.setdefault("nodes", [])
    edges = doc.setdefault("edges", [])
    for i, node in enumerate(nodes):
        _check_node(p, i, node, centers)
    ids = {n["id"] for n in nodes}
    for i, e in enumerate(edges):
        if not isinstance(e, dict) or not {"source", "target", "relation"} <= set(e):
            raise DataError(f"{p}: every edge needs 'source', 'target' and 'relation' (edge {i}: {e!r:.80})")
        if not _known(e["source"], ids) or not _known(e["target"], ids):
            raise DataError(
                f"{p}: edge {i} joins nodes not in the graph (fields 'source' {e['source']!r:.20}, "
                f"'target' {e['target']!r:.20})"
            )
    return doc


def graph_up(
    doc: Mapping[str, Any], source: str | Path = "graph.json", default: Iterable[float] | None = None
) -> np.ndarray | None:
    """The up vector a scene graph was built with: its document's ``up`` (the world vertical its rooms and
    relations used, settled by the run by the time it wrote the graph).

    This is the graph's own up, the one to read rooms and heights with; the up a run was *configured* with
    (``config.yaml``'s ``graph.up_axis``, possibly ``auto``) is
    :func:`ogscene3d.runs.record.recorded_up`'s.

    Args:
        doc: a graph.json document (:func:`read_graph_json`; an in-memory graph's too).
        source: what ``doc`` was read from, for the error message.
        default: the up of a document without one (written before graphs recorded theirs); None: None.

    Returns:
        The unit up vector (float64, [3]), or ``default`` (as a unit vector) when ``doc`` has none.

    Raises:
        DataError: ``up`` is not a finite non-zero 3-vector; the message names ``source``.
    """
    up = doc.get("up")
    if up is None:
        return None if default is None else unit_up(default)
    try:
        return unit_up(up)
    except ValueError:
        raise DataError(f"{source}: 'up' must be a finite non-zero 3-vector, got {up!r}") from None


def _check_node(p: Path, i: int, node: object, centers: bool) -> None:
    """DataError naming the file, the node and the field unless ``node`` has an integer id and a finite
    3-vector center (where it has one, or ``centers`` asks for one)."""
    if not isinstance(node, dict) or "id" not in node or (centers and "center" not in node):
        raise DataError(f"{p}: node {i} lacks 'id'" + (" or 'center'" if centers else ""))
    nid = node["id"]
    if not isinstance(nid, int) or isinstance(nid, bool):
        raise DataError(f"{p}: node {i} field 'id' must be an integer, got {nid!r:.60}")
    if "center" not in node:
        return
    center = node["center"]
    numbers = isinstance(center, list) and all(
        isinstance(v, int | float) and not isinstance(v, bool) for v in center
    )
    if not numbers or len(center) != 3:
        raise DataError(f"{p}: node {nid} has a bad center {center!r:.80} (field 'center': 3 numbers)")
    if not np.isfinite(np.asarray(center, dtype=np.float64)).all():
        raise DataError(f"{p}: node {nid} has a non-finite center {center!r:.80} (field 'center')")


def _known(node_id: object, ids: set[int]) -> bool:
    # an unhashable id (a list) cannot be looked up in the set: it is simply not a known node
    return isinstance(node_id, int) and not isinstance(node_id, bool) and node_id in ids


__all__ = ["graph_up", "read_graph_json", "write_graph_json"]
