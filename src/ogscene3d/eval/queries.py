"""Query accuracy: queries generated from the ground truth, answered by the run's scene graph.

Three kinds of queries come from the ground truth's instances (floor, wall and ceiling left out as answers
and as anchors):

* ``object``: a class name ("lamp"); the right answers are the instances of that class;
* ``relation``: object + relation + object from the relation triplets ("cup on the table", "book in the
  bookshelf", "picture above the sofa"); the right answers are the instances of the first class that have
  that relation with an instance of the second (symmetric relations both ways);
* ``room``: object + room ("chair in the kitchen"), when the ground truth gives rooms; the right answers
  are the instances of that class in a room of that type.

Each query is asked once (one text per kind and distinct wording). It succeeds when the top-ranked node
overlaps one of its right answers: the IoU of the node's Gaussians and the instance's points (each Gaussian
paired with its nearest ground-truth point, as for relation recall) is at least ``min_iou``. ``answerable``
counts the queries for which some node overlaps a right answer at all (the best any ranking could do).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..graph.scenegraph import SceneGraph
from .graph_metrics import node_overlap_iou

STRUCTURAL = frozenset({"floor", "wall", "ceiling"})
KINDS = ("object", "relation", "room")


@dataclass(frozen=True)
class GTQuery:
    """A generated query: its ``kind``, ``text`` and the instance ids that answer it."""

    kind: str
    text: str
    answers: frozenset[int]


def generate_queries(
    instance_class: Mapping[int, str],
    relations: Iterable[tuple[int, str, int]],
    instance_room: Mapping[int, int] | None = None,
    room_type: Mapping[int, str] | None = None,
    present: set[int] | None = None,
    symmetric: Iterable[str] = ("next to",),
) -> list[GTQuery]:
    """The queries of a ground truth (see the module docstring): ``instance_class`` {instance: class name},
    ``relations`` (subject, relation, object) triplets, ``instance_room`` {instance: room id} and
    ``room_type`` {room id: type} (no room queries without them), ``present``: the instances the scan saw
    (others neither answer nor anchor a query; None: all)."""
    ok = {i for i, c in instance_class.items() if c not in STRUCTURAL and (present is None or i in present)}
    by_class: dict[str, set[int]] = {}
    for i in ok:
        by_class.setdefault(instance_class[i], set()).add(i)
    out = [GTQuery("object", c, frozenset(ids)) for c, ids in sorted(by_class.items())]
    sym = set(symmetric)
    rel_answers: dict[str, set[int]] = {}
    for s, r, o in relations:
        pairs = [(s, o), (o, s)] if r in sym else [(s, o)]
        for a, b in pairs:
            if a in ok and b in ok:
                rel_answers.setdefault(f"{instance_class[a]} {r} the {instance_class[b]}", set()).add(a)
    out += [GTQuery("relation", t, frozenset(ids)) for t, ids in sorted(rel_answers.items())]
    if instance_room and room_type:
        room_answers: dict[str, set[int]] = {}
        for i in ok:
            rid = instance_room.get(i)
            if rid is not None and rid in room_type:
                room_answers.setdefault(f"{instance_class[i]} in the {room_type[rid]}", set()).add(i)
        out += [GTQuery("room", t, frozenset(ids)) for t, ids in sorted(room_answers.items())]
    return out


def query_accuracy(
    queries: list[GTQuery],
    answer: Callable[[str], int | None],
    node_instance_iou: Callable[[int, frozenset[int]], float],
    min_iou: float = 0.1,
    answerable: Callable[[frozenset[int]], bool] | None = None,
) -> dict[str, Any]:
    """Top-1 success per kind. ``answer(text)`` -> the top node id (None: no hit); ``node_instance_iou(node,
    instances)`` -> its best IoU with one of them; ``answerable(instances)`` -> whether any node overlaps
    one (None: not reported)."""
    per_kind: dict[str, Counter] = {k: Counter() for k in KINDS}
    failures: list[dict[str, Any]] = []
    for q in queries:
        c = per_kind.setdefault(q.kind, Counter())
        c["queries"] += 1
        can = answerable(q.answers) if answerable is not None else True
        c["answerable"] += int(can)
        top = answer(q.text)
        if top is None:
            c["no_hit"] += 1
            failures.append({"kind": q.kind, "query": q.text, "top": None, "answerable": can})
            continue
        if node_instance_iou(top, q.answers) >= min_iou:
            c["top1"] += 1
        else:
            failures.append({"kind": q.kind, "query": q.text, "top": int(top), "answerable": can})
    kinds = {}
    for k, c in per_kind.items():
        n = c["queries"]
        kinds[k] = {
            "queries": n,
            "top1": c["top1"],
            "top1_accuracy": c["top1"] / n if n else float("nan"),
            "answerable": c["answerable"] if answerable is not None else None,
            "no_hit": c["no_hit"],
        }
    return {"per_kind": kinds, "failures": failures}


class NodeOverlap:
    """IoU between scene labels (graph nodes) and GT instances over paired points (nearest GT point of every
    Gaussian), for :func:`query_accuracy`."""

    def __init__(self, labels: np.ndarray, gt_instances: np.ndarray) -> None:
        self.labels, self.instances, self.iou = node_overlap_iou(labels, gt_instances)
        self._row = {int(v): k for k, v in enumerate(self.labels)}
        self._col = {int(v): k for k, v in enumerate(self.instances)}

    def __call__(self, node: int, instances: frozenset[int]) -> float:
        r = self._row.get(int(node))
        cols = [self._col[i] for i in instances if i in self._col]
        return float(self.iou[r, cols].max()) if r is not None and cols else 0.0

    def answerable(self, instances: frozenset[int], min_iou: float) -> bool:
        cols = [self._col[i] for i in instances if i in self._col]
        return bool(cols) and bool(np.any(self.iou[:, cols] >= min_iou))


def queries_block(
    graph_doc: Mapping[str, Any],
    labels: np.ndarray,
    gt_instances_of_gaussians: np.ndarray,
    instance_class: Mapping[int, str],
    relations: Iterable[tuple[int, str, int]],
    instance_rooms: Mapping[int, int],
    room_types: Mapping[int, str],
    present: set[int] | None,
    min_iou: float,
    symmetric: Iterable[str] = ("next to",),
    source: str = "graph.json",
) -> dict[str, Any]:
    """The ``queries`` block of ``metrics.json``: the generated queries answered offline by the run's graph
    (graph.json), scored against the instances the labelled Gaussians overlap (``labels`` and the GT
    instance of each one's nearest GT point, -1 = none)."""
    graph = SceneGraph.from_json(graph_doc, source=source)
    node_ids = np.array(sorted(graph.nodes), dtype=np.int64)
    node_labels = np.where(np.isin(labels, node_ids), labels, -1)
    overlap = NodeOverlap(node_labels, gt_instances_of_gaussians)
    queries = generate_queries(instance_class, relations, instance_rooms, room_types, present, symmetric)

    def top(text: str) -> int | None:
        hits = [h for h in graph.ask(text, top_k=1).hits if h.kind == "object"]
        return hits[0].id if hits else None

    out = query_accuracy(queries, top, overlap, min_iou, lambda a: overlap.answerable(a, min_iou))
    out["protocol"] = (
        "queries generated from the GT (object; object + relation + object; object + room), answered "
        f"offline by the graph; top-1 success: the first node's point IoU with a right instance >= {min_iou}"
    )
    return out
