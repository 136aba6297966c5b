"""Room segmentation scored as HOV-SG scores it (Werby et al., RSS 2024, after Hydra): on a bird's-eye view.

Every ground-truth room is the set of its surface points (each instance belongs to one room, walls and floor
included; only the points some frame saw count, as for the semantic scores), every predicted room the set of
Gaussians :func:`~ogscene3d.graph.rooms.assign_rooms` puts in it from graph.json's outlines. Both are
projected onto the horizontal plane (the run's up vector) and voxelised at ``voxel`` metres (HOV-SG: 5 cm);
a cell of one set counts as shared with the other when the other has a cell within one cell of it (HOV-SG:
points within 5 cm).

* **precision** of a predicted room: the largest share of its cells shared with one ground-truth room;
* **recall** of a ground-truth room: the largest share of its cells shared with one predicted room;

their means over the predicted and the ground-truth rooms are HOV-SG's (Hydra's) room precision and recall.
Per ground-truth room, the predicted room matched to it (one-to-one, largest overlap, Hungarian) gives the
room's own precision and recall. ``settle_frames``: how many frames after the camera first stood in a room
its matched node was first seen (negative: seen through a doorway before it was entered).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..config import RoomsConfig
from ..graph.geometry import horizontal_basis
from ..graph.rooms import assign_rooms, raster_outline, read_rooms
from ..runs.graph_json import graph_up
from ..up_axis import PROVISIONAL_UP, unit_up


@dataclass
class RoomScores:
    """Room segmentation scores (fractions in [0, 1]); see the module docstring."""

    precision: float  # mean over predicted rooms (HOV-SG / Hydra)
    recall: float  # mean over GT rooms (HOV-SG / Hydra)
    num_gt: int
    num_pred: int
    per_room: dict[int, dict[str, Any]] = field(default_factory=dict)  # GT room id -> its scores
    pred_precision: dict[int, float] = field(default_factory=dict)  # pred room id -> precision
    protocol: str = ""

    @property
    def matched_precision(self) -> float:
        """Mean over GT rooms of their matched predicted room's precision (0 for an unmatched room)."""
        v = [r["precision"] for r in self.per_room.values()]
        return float(np.mean(v)) if v else float("nan")

    @property
    def matched_recall(self) -> float:
        v = [r["recall"] for r in self.per_room.values()]
        return float(np.mean(v)) if v else float("nan")

    def to_dict(self) -> dict[str, Any]:
        settle = [r["settle_frames"] for r in self.per_room.values() if r.get("settle_frames") is not None]
        return {
            "protocol": self.protocol,
            "precision": self.precision,
            "recall": self.recall,
            "matched_precision": self.matched_precision,
            "matched_recall": self.matched_recall,
            "num_gt_rooms": self.num_gt,
            "num_pred_rooms": self.num_pred,
            "settle_frames_mean": float(np.mean(settle)) if settle else None,
            "settle_frames_max": int(max(settle)) if settle else None,
            "per_room": {str(k): v for k, v in sorted(self.per_room.items())},
            "pred_precision": {str(k): v for k, v in sorted(self.pred_precision.items())},
        }


def _keys(ij: np.ndarray) -> np.ndarray:
    ij = np.asarray(ij, dtype=np.int64).reshape(-1, 2)
    return np.unique((ij[:, 0] + (1 << 30)) << 32 | (ij[:, 1] + (1 << 30)))


def _cells(points: np.ndarray, up: np.ndarray, voxel: float) -> np.ndarray:
    e1, e2 = horizontal_basis(unit_up(up))
    return _keys(np.floor(np.stack([points @ e1, points @ e2], axis=1) / voxel))


def _near(keys: np.ndarray) -> np.ndarray:
    """The cells within one cell (3 x 3) of ``keys``."""
    out = [keys + (di << 32) + dj for di in (-1, 0, 1) for dj in (-1, 0, 1)]
    return np.unique(np.concatenate(out))


def room_scores(
    gt_points: np.ndarray,
    gt_rooms: np.ndarray,
    pred_points: np.ndarray,
    pred_rooms: np.ndarray,
    up: np.ndarray,
    voxel: float = 0.05,
    entered: Mapping[int, int | None] | None = None,
    first_seen: Mapping[int, int] | None = None,
    outlines: Mapping[int, Sequence[np.ndarray]] | None = None,
) -> RoomScores:
    """Score predicted rooms against ground-truth rooms (see the module docstring).

    Args:
        gt_points: [M, 3] ground-truth surface points; ``gt_rooms`` [M] their room ids (-1: none, left out).
        pred_points: [N, 3] Gaussian means; ``pred_rooms`` [N] their predicted room ids (-1: none).
        up: the world up vector.
        voxel: bird's-eye cell size in metres.
        entered: GT room id -> the first frame the camera stood in it (None: never); with ``first_seen``
            (pred room id -> the first frame its node existed) it gives each room's ``settle_frames``.
        outlines: pred room id -> its outline polygons (world points [K, 3] each): the cells they hold
            belong to the room too (its extent, also where the map holds few Gaussians).

    Returns:
        :class:`RoomScores`.
    """
    from scipy.optimize import linear_sum_assignment

    gt_ids = [int(i) for i in np.unique(gt_rooms) if i >= 0]
    outlines = outlines or {}
    pred_ids = sorted({int(i) for i in np.unique(pred_rooms) if i >= 0} | set(outlines))
    gt_cells = {g: _cells(gt_points[gt_rooms == g], up, voxel) for g in gt_ids}
    pred_cells = {
        p: np.union1d(_cells(pred_points[pred_rooms == p], up, voxel),
                      _keys(raster_outline(outlines.get(p, []), up, voxel)))
        for p in pred_ids
    }  # fmt: skip
    gt_near = {g: _near(c) for g, c in gt_cells.items()}
    pred_near = {p: _near(c) for p, c in pred_cells.items()}
    over_pred = np.zeros((len(pred_ids), len(gt_ids)))  # share of the pred room's cells near the GT room
    over_gt = np.zeros((len(pred_ids), len(gt_ids)))  # share of the GT room's cells near the pred room
    for a, p in enumerate(pred_ids):
        for b, g in enumerate(gt_ids):
            over_pred[a, b] = np.isin(pred_cells[p], gt_near[g], assume_unique=True).mean()
            over_gt[a, b] = np.isin(gt_cells[g], pred_near[p], assume_unique=True).mean()
    precision = over_pred.max(axis=1) if len(gt_ids) else np.zeros(len(pred_ids))
    recall = over_gt.max(axis=0) if len(pred_ids) else np.zeros(len(gt_ids))
    match: dict[int, int] = {}
    if pred_ids and gt_ids:
        rows, cols = linear_sum_assignment(-(over_pred + over_gt))
        match = {gt_ids[c]: r for r, c in zip(rows, cols) if over_gt[r, c] > 0}
    per_room: dict[int, dict[str, Any]] = {}
    for b, g in enumerate(gt_ids):
        a = match.get(g)
        row: dict[str, Any] = {
            "pred_room": pred_ids[a] if a is not None else None,
            "precision": float(over_pred[a, b]) if a is not None else 0.0,
            "recall": float(over_gt[a, b]) if a is not None else 0.0,
            "best_recall": float(recall[b]),
            "gt_cells": int(len(gt_cells[g])),
        }
        if entered is not None:
            e = entered.get(g)
            seen = (first_seen or {}).get(pred_ids[a]) if a is not None else None
            row["entered_frame"] = e
            row["first_seen_frame"] = seen
            row["settle_frames"] = int(seen - e) if e is not None and seen is not None and seen >= 0 else None
        per_room[g] = row
    return RoomScores(
        precision=float(precision.mean()) if len(pred_ids) else float("nan"),
        recall=float(recall.mean()) if len(gt_ids) else float("nan"),
        num_gt=len(gt_ids),
        num_pred=len(pred_ids),
        per_room=per_room,
        pred_precision={p: float(v) for p, v in zip(pred_ids, precision)},
        protocol=f"HOV-SG room precision / recall: bird's-eye cells of {voxel:g} m, shared within one cell; "
        "GT rooms: all their surface points; predicted rooms: their outlines and the Gaussians in them",
    )


def rooms_block(
    graph: Mapping[str, Any],
    means: np.ndarray,
    gt_points: np.ndarray,
    gt_point_rooms: np.ndarray,
    entered: Mapping[int, int | None],
    gt_types: Mapping[int, str] | None = None,
    source: str = "graph.json",
) -> dict[str, Any]:
    """The ``rooms`` block of ``metrics.json``: the graph's rooms (graph.json) scored against the GT rooms of
    ``gt_points`` (``gt_point_rooms``: -1 = none), with the Gaussians ``means`` put in rooms by their
    outlines; with ``gt_types`` (GT room id -> type) each matched room's type is checked too
    (``types_correct``)."""
    # the up the graph was built with (files without one: an upright OpenCV camera's world's)
    up = graph_up(graph, source, default=PROVISIONAL_UP)
    _, floors, rooms = read_rooms(graph, source)
    pred = assign_rooms(means, up, floors, rooms, RoomsConfig().assign_radius)
    first = {r.id: r.first_frame for r in rooms if r.first_frame >= 0}
    outlines = {r.id: r.outline for r in rooms}
    scores = room_scores(gt_points, gt_point_rooms, means, pred, up, entered=entered, first_seen=first,
                         outlines=outlines)  # fmt: skip
    out = scores.to_dict()
    out["pred_types"] = {str(r.id): r.type for r in rooms}
    if gt_types is not None:
        types = {r.id: r.type for r in rooms}
        for g, row in out["per_room"].items():
            row["gt_type"] = gt_types.get(int(g))
            row["pred_type"] = types.get(row["pred_room"]) if row["pred_room"] is not None else None
        out["types_correct"] = sum(row["gt_type"] == row["pred_type"] for row in out["per_room"].values())
    out["num_floors"] = len(floors)
    return out
