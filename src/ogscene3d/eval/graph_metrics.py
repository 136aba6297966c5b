"""Scene-graph evaluation: relation recall against ground-truth (subject, relation, object) triplets.

Nodes are matched to ground-truth instances by 3D overlap: with every predicted point (Gaussian)
paired with a ground-truth point (e.g. its nearest one), the IoU of a scene label and an instance
is |points with both| / |points with either|, and a one-to-one assignment maximising the total IoU
(Hungarian) keeps the pairs with IoU >= ``min_iou``.

A ground-truth triplet (s, r, o) is *recalled* when both s and o are matched and the graph has an
edge between their nodes whose relation equals r after normalisation, in the same direction, or in
either direction for a symmetric relation, or reversed with the inverse relation (``on`` vs
``under``). A triplet with an unmatched endpoint is a miss. ``edge_recall`` relaxes the relation
test (any edge between the two nodes, either direction), which separates "found the pair" from
"named the relation".
"""

from __future__ import annotations

import re
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

DEFAULT_SYMMETRIC: frozenset[str] = frozenset(
    {"next to", "near", "beside", "close by", "adjacent to", "same as", "connected to", "touching"}
)
DEFAULT_INVERSES: tuple[tuple[str, str], ...] = (
    ("on", "under"),
    ("above", "below"),
    ("supported by", "supporting"),
    ("inside", "contains"),
    ("in", "contains"),
    ("left", "right"),
    ("front", "behind"),
    ("in front of", "behind"),
    ("bigger than", "smaller than"),
    ("higher than", "lower than"),
)


def normalize_relation(text: str) -> str:
    """Lower case, ``_``/``-`` to spaces, single spaces: ``"Next_To"`` -> ``"next to"``."""
    return " ".join(re.sub(r"[_\-]+", " ", str(text).lower()).split())


def node_overlap_iou(pred_labels: Any, gt_instances: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """IoU between every scene label and every GT instance over paired points.

    Args:
        pred_labels: [N] scene label per point (-1 = unlabeled).
        gt_instances: [N] GT instance id of the paired point (-1 = none).

    Returns:
        (labels [P], instances [Q], iou [P, Q]); unlabeled/void points count in no set.
    """
    p = np.asarray(pred_labels)
    g = np.asarray(gt_instances)
    if p.ndim != 1 or p.shape != g.shape:
        raise ValueError(f"pred_labels {p.shape} and gt_instances {g.shape} must be equal 1-D arrays")
    if not (np.issubdtype(p.dtype, np.integer) and np.issubdtype(g.dtype, np.integer)):
        raise ValueError("pred_labels and gt_instances must be integer arrays")
    p = p.astype(np.int64)
    g = g.astype(np.int64)
    labels, p_inv, p_cnt = np.unique(p[p >= 0], return_inverse=True, return_counts=True)
    insts, g_inv, g_cnt = np.unique(g[g >= 0], return_inverse=True, return_counts=True)
    inter = np.zeros((labels.size, insts.size), dtype=np.int64)
    both = (p >= 0) & (g >= 0)
    if both.any():
        pi = np.searchsorted(labels, p[both])
        gi = np.searchsorted(insts, g[both])
        np.add.at(inter, (pi, gi), 1)
    union = p_cnt[:, None] + g_cnt[None, :] - inter
    with np.errstate(invalid="ignore", divide="ignore"):
        iou = np.where(union > 0, inter / np.maximum(union, 1), 0.0)
    return labels, insts, iou


def match_nodes_by_overlap(pred_labels: Any, gt_instances: Any, min_iou: float = 0.1) -> dict[int, int]:
    """One-to-one GT instance -> scene label matching by point-set IoU (Hungarian, IoU >= min_iou)."""
    from scipy.optimize import linear_sum_assignment

    labels, insts, iou = node_overlap_iou(pred_labels, gt_instances)
    if labels.size == 0 or insts.size == 0:
        return {}
    rows, cols = linear_sum_assignment(-iou)
    return {int(insts[c]): int(labels[r]) for r, c in zip(rows, cols) if iou[r, c] >= min_iou}


@dataclass(frozen=True)
class RelationRecall:
    """Relation recall of one scene graph against GT triplets (fractions in [0, 1])."""

    protocol: str
    recall: float  # triplets recalled with the right relation / all GT triplets
    edge_recall: float  # triplets whose two matched nodes share any edge / all GT triplets
    num_gt: int
    num_recalled: int
    num_edge_found: int
    num_unmatched_endpoint: int  # misses because subject or object has no matched node
    num_no_edge: int  # both matched, no edge between them
    num_wrong_relation: int  # an edge exists but with another relation
    node_matches: dict[int, int] = field(default_factory=dict)  # GT instance -> scene label
    per_relation: dict[str, dict[str, int]] = field(default_factory=dict)  # relation -> {gt, recalled}

    def to_dict(self) -> dict[str, Any]:
        return {
            "protocol": self.protocol,
            "recall": self.recall,
            "edge_recall": self.edge_recall,
            "num_gt": self.num_gt,
            "num_recalled": self.num_recalled,
            "num_edge_found": self.num_edge_found,
            "num_unmatched_endpoint": self.num_unmatched_endpoint,
            "num_no_edge": self.num_no_edge,
            "num_wrong_relation": self.num_wrong_relation,
            "num_matched_nodes": len(self.node_matches),
            "node_matches": {str(k): v for k, v in sorted(self.node_matches.items())},
            "per_relation": self.per_relation,
        }


def relation_recall(
    gt_triplets: Iterable[Sequence[Any]],
    pred_edges: Iterable[Sequence[Any] | Mapping[str, Any]],
    node_matches: Mapping[int, int],
    symmetric: Iterable[str] = DEFAULT_SYMMETRIC,
    inverses: Iterable[tuple[str, str]] = DEFAULT_INVERSES,
    protocol: str = "relation-recall (nodes matched by 3D overlap)",
) -> RelationRecall:
    """Recall of GT triplets among predicted edges (see the module docstring).

    Args:
        gt_triplets: (subject instance id, relation, object instance id) triplets.
        pred_edges: (source label, target label, relation) tuples or ``graph.json`` edge dicts
            ({"source", "target", "relation"}).
        node_matches: GT instance id -> scene label (from :func:`match_nodes_by_overlap`).
        symmetric: relations that hold in both directions.
        inverses: (r, r') pairs with r(a, b) == r'(b, a).
    """
    sym = {normalize_relation(r) for r in symmetric}
    inv: dict[str, set[str]] = {}
    for a, b in inverses:
        a, b = normalize_relation(a), normalize_relation(b)
        inv.setdefault(a, set()).add(b)
        inv.setdefault(b, set()).add(a)

    directed: dict[tuple[int, int], set[str]] = {}
    for e in pred_edges:
        if isinstance(e, Mapping):
            try:
                s, t, r = e["source"], e["target"], e["relation"]
            except KeyError as err:
                raise ValueError(f"pred edge {e!r} lacks key {err}") from None
        else:
            if len(e) != 3:
                raise ValueError(f"pred edge {e!r}: expected (source, target, relation)")
            s, t, r = e
        directed.setdefault((int(s), int(t)), set()).add(normalize_relation(r))

    gt = [tuple(t) for t in gt_triplets]
    n_rec = n_edge = n_unm = n_noedge = n_wrong = 0
    per: dict[str, Counter] = {}
    for trip in gt:
        if len(trip) != 3:
            raise ValueError(f"GT triplet {trip!r}: expected (subject, relation, object)")
        s_id, rel, o_id = int(trip[0]), normalize_relation(trip[1]), int(trip[2])
        per.setdefault(rel, Counter())["gt"] += 1
        if s_id not in node_matches or o_id not in node_matches:
            n_unm += 1
            continue
        a, b = node_matches[s_id], node_matches[o_id]
        fwd = directed.get((a, b), set())
        bwd = directed.get((b, a), set())
        if not fwd and not bwd:
            n_noedge += 1
            continue
        n_edge += 1
        ok = rel in fwd or (rel in sym and rel in bwd) or bool(inv.get(rel, set()) & bwd)
        if ok:
            n_rec += 1
            per[rel]["recalled"] += 1
        else:
            n_wrong += 1
    n = len(gt)
    return RelationRecall(
        protocol=protocol,
        recall=n_rec / n if n else float("nan"),
        edge_recall=n_edge / n if n else float("nan"),
        num_gt=n,
        num_recalled=n_rec,
        num_edge_found=n_edge,
        num_unmatched_endpoint=n_unm,
        num_no_edge=n_noedge,
        num_wrong_relation=n_wrong,
        node_matches=dict(node_matches),
        per_relation={k: {"gt": v["gt"], "recalled": v["recalled"]} for k, v in sorted(per.items())},
    )
