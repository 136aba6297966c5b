"""Storeys and rooms of the map, segmented from the mapped geometry as the map grows.

The segmentation works on the Gaussian means alone, in the frame given by the world *up* vector
(``graph.up_axis``; heights are ``p · up``, no axis is assumed) and reads a bird's-eye floor plan as HOV-SG
does (Werby et al., RSS 2024), made to run at every few keyframes:

1. **Storeys** (:func:`find_floors`): peaks of the height histogram; the lowest is the ground floor, a peak at
   least ``graph.rooms.storey_height`` higher is a further floor when the map goes on above it (a ceiling
   has nothing over it); of a ceiling / floor pair across a slab the upper peak is the floor.
2. **Floor plan** per storey, ``cell_size`` metres per cell: *walls* are the cells holding Gaussians between
   ``wall_low`` and ``wall_high`` above the floor (above most furniture, below door lintels, so doorways
   stay open); *explored* cells hold any Gaussian of the storey, closed and with their enclosed holes
   filled (the floor under the camera's own path is never seen).
3. **Rooms**: the distance of every free cell (explored, no wall) to the nearest wall or unexplored cell;
   where it exceeds half of ``door_width`` lie room cores (a doorway is narrower), and the cores grow back
   over the free cells, so two rooms meet in their doorway. Rooms smaller than ``min_room_area`` are left out.
4. **Outlines**: each room's cells as polygons (world coordinates at its floor's height); a point belongs to
   the room whose outline holds it, or else to the nearest outline within ``assign_radius`` (walls, which lie
   outside every outline, go to the room on their own side). :func:`assign_rooms` is that rule: the live
   graph, the evaluation and the viewer use it alike, from the outlines graph.json stores.

:class:`RoomMap` keeps the rooms across updates: a new segmentation's rooms take the ids of the rooms they
overlap most (a room that grows keeps its id and ``first_seen``), and each room is typed from the tags of
the objects in it (:class:`RuleRoomTyper`, or :class:`LLMRoomTyper` with the rule as fallback).
"""

from __future__ import annotations

import json
import logging
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..config import EndpointConfig, RoomsConfig
from ..errors import DataError
from ..runs.graph_json import graph_up
from ..up_axis import unit_up
from .geometry import horizontal_basis
from .openai_client import ChatClient, extract_json

log = logging.getLogger(__name__)

#: Room types the offline rule names, with the objects (and their usual other names) that point to each, and
#: how strongly. Only these words count: a generic synonym ("cabinet" for "wardrobe") says nothing of a room.
ROOM_TYPE_CUES: dict[str, dict[str, float]] = {
    "bedroom": {"bed": 3, "nightstand": 2, "bedside table": 2, "night table": 2, "wardrobe": 2,
                "dresser": 1.5, "pillow": 0.5, "cushion": 0.5},
    "kitchen": {"refrigerator": 3, "fridge": 3, "stove": 3, "oven": 3, "cooker": 3, "hob": 3, "counter": 2,
                "countertop": 2, "worktop": 2, "microwave": 2, "dishwasher": 2, "sink": 0.5},
    "bathroom": {"toilet": 3, "bathtub": 3, "bath": 3, "tub": 3, "shower": 3, "towel": 2, "mirror": 1,
                 "sink": 1, "washbasin": 1, "basin": 1},
    "living room": {"sofa": 3, "couch": 3, "settee": 3, "loveseat": 3, "tv": 2, "television": 2,
                    "armchair": 1, "fireplace": 2},
    "office": {"desk": 3, "monitor": 2, "computer": 2, "laptop": 1, "printer": 2, "keyboard": 1},
}  # fmt: skip
#: The type of a room the rule cannot name (no cue, or too little).
UNKNOWN_ROOM = "room"
#: Other names users give the room types (queries, LLM replies).
ROOM_SYNONYMS: dict[str, str] = {
    "lounge": "living room",
    "living area": "living room",
    "sitting room": "living room",
    "family room": "living room",
    "livingroom": "living room",
    "bed room": "bedroom",
    "sleeping room": "bedroom",
    "restroom": "bathroom",
    "washroom": "bathroom",
    "bath room": "bathroom",
    "lavatory": "bathroom",
    "study": "office",
    "workroom": "office",
    "home office": "office",
    "kitchenette": "kitchen",
}
_MIN_TYPE_SCORE = 2.0  # a single weak cue (a pillow, a sink) names no room
#: Gaussians from which an object's cue counts fully when typing a room (a smaller one counts in proportion).
FULL_WEIGHT_GAUSSIANS = 400


def room_type_of(text: str) -> str | None:
    """The room type a word or phrase names (``"lounge"`` -> ``"living room"``), None when none."""
    t = " ".join(re.sub(r"[^a-z ]+", " ", str(text).lower()).split())
    if t in ROOM_TYPE_CUES:
        return t
    return ROOM_SYNONYMS.get(t)


# --------------------------------------------------------------------------------------- data


@dataclass
class Floor:
    """A storey: ``height`` of its floor surface along up (metres), ``top``: where the next storey starts
    (None for the top one)."""

    id: int
    height: float
    top: float | None = None

    def to_dict(self) -> dict:
        return {
            "id": self.id,
            "height": float(self.height),
            "top": None if self.top is None else float(self.top),
        }


@dataclass
class RoomNode:
    """A room node: its storey ``floor``, ``type`` and where it came from (``type_source``: "rule", "llm"
    or "" before any object is in it), ``outline``: polygons [K, 3] (world, at the floor's height) whose
    union is the room's floor plan, ``area`` (m^2), ``center`` and ``bbox_min`` / ``bbox_max`` of its
    Gaussians, ``objects``: the ids of the object nodes in it, ``first_seen`` / ``last_updated``:
    keyframes, ``first_frame``: the frame of ``first_seen``."""

    id: int
    floor: int
    outline: list[np.ndarray]
    area: float
    center: np.ndarray
    bbox_min: np.ndarray
    bbox_max: np.ndarray
    num_gaussians: int = 0
    type: str = UNKNOWN_ROOM
    type_source: str = ""
    type_reason: str = ""
    type_scores: dict[str, float] = field(default_factory=dict)  # the rule's cue weight per type
    objects: list[int] = field(default_factory=list)
    first_seen: int = -1
    last_updated: int = -1
    first_frame: int = -1  # the dataset frame index of the keyframe ``first_seen`` (-1: unknown)

    def to_dict(self) -> dict:
        """The room as graph.json stores it (docs/formats.md)."""
        return {
            "id": int(self.id),
            "floor": int(self.floor),
            "type": self.type,
            "type_source": self.type_source,
            "type_reason": self.type_reason,
            "type_scores": {k: round(float(v), 3) for k, v in sorted(self.type_scores.items())},
            "center": [float(v) for v in self.center],
            "bbox_min": [float(v) for v in self.bbox_min],
            "bbox_max": [float(v) for v in self.bbox_max],
            "area": round(float(self.area), 3),
            "num_gaussians": int(self.num_gaussians),
            "outline": [[[round(float(v), 4) for v in p] for p in poly] for poly in self.outline],
            "objects": [int(i) for i in self.objects],
            "first_seen": int(self.first_seen),
            "last_updated": int(self.last_updated),
            "first_frame": int(self.first_frame),
        }

    @classmethod
    def from_dict(cls, d: Any, source: str, k: int) -> RoomNode:
        """A room from its graph.json entry; DataError naming ``source`` and the entry."""
        try:
            outline = [np.asarray(p, dtype=np.float64).reshape(-1, 3) for p in d.get("outline", [])]
            node = cls(
                id=int(d["id"]),
                floor=int(d.get("floor", 0)),
                outline=outline,
                area=float(d.get("area", 0.0)),
                center=np.asarray(d["center"], dtype=np.float64).reshape(3),
                bbox_min=np.asarray(d["bbox_min"], dtype=np.float64).reshape(3),
                bbox_max=np.asarray(d["bbox_max"], dtype=np.float64).reshape(3),
                num_gaussians=int(d.get("num_gaussians", 0)),
                type=str(d.get("type", UNKNOWN_ROOM)),
                type_source=str(d.get("type_source", "")),
                type_reason=str(d.get("type_reason", "")),
                type_scores={str(k): float(v) for k, v in (d.get("type_scores") or {}).items()},
                objects=[int(i) for i in d.get("objects", [])],
                first_seen=int(d.get("first_seen", -1)),
                last_updated=int(d.get("last_updated", -1)),
                first_frame=int(d.get("first_frame", -1)),
            )
        except (KeyError, TypeError, ValueError, AttributeError) as e:
            raise DataError(f"{source}: room #{k} is malformed ({type(e).__name__}: {e})") from None
        if not all(np.all(np.isfinite(a)) for a in (node.center, node.bbox_min, node.bbox_max, *outline)):
            raise DataError(f"{source}: room #{k} has non-finite coordinates")
        return node


@dataclass
class FloorPlan:
    """One storey's bird's-eye grid: cell (i, j) covers horizontal coordinates ``(i, j) * cell`` (global
    anchoring: cells of two updates are comparable); ``labels`` [I, J] int32: room index + 1, 0 = none."""

    floor: int
    origin: np.ndarray  # int [2]: the global index of cell [0, 0]
    cell: float
    labels: np.ndarray
    walls: np.ndarray  # bool [I, J]
    explored: np.ndarray  # bool [I, J]


@dataclass
class Segmentation:
    """What :func:`segment_rooms` found: the storeys, the floor plans, and per room (index k) its storey,
    its cells as global (floor, i, j) keys and its polygons."""

    floors: list[Floor]
    plans: list[FloorPlan]
    room_floor: list[int]
    room_cells: list[np.ndarray]  # int64 keys per room
    room_outline: list[list[np.ndarray]]
    room_area: list[float]


# --------------------------------------------------------------------------------------- storeys


def find_floors(heights: np.ndarray, config: RoomsConfig) -> list[Floor]:
    """Storeys from point heights (metres along up): see the module docstring. An empty input gives none."""
    h = np.asarray(heights, dtype=np.float64)
    h = h[np.isfinite(h)]
    if len(h) == 0:
        return []
    bin_w = 0.05
    lo = np.floor(h.min() / bin_w) * bin_w
    counts = np.bincount(((h - lo) / bin_w).astype(np.int64))
    smooth = np.convolve(counts, [0.25, 0.5, 0.25], mode="same")
    peak_min = max(0.05 * smooth.max(), 0.002 * len(h))
    is_peak = (smooth >= peak_min) & (smooth >= np.roll(smooth, 1)) & (smooth >= np.roll(smooth, -1))
    peaks = lo + (np.flatnonzero(is_peak) + 0.5) * bin_w
    if len(peaks) == 0:
        return [Floor(0, float(np.percentile(h, 1)))]
    floors = [float(peaks[0])]
    band = (0.3, 1.8)  # what stands on a floor: furniture and walls up to head height
    base = max(1, int(np.sum((h > floors[0] + band[0]) & (h < floors[0] + band[1]))))
    for p in peaks[1:]:
        if p < floors[-1] + config.storey_height:
            continue
        top = float(peaks[(peaks >= p) & (peaks <= p + 0.6)].max())  # over a slab: the upper peak
        above = int(np.sum((h > top + band[0]) & (h < top + band[1])))
        if above >= 0.1 * base:
            floors.append(top)
    out = []
    for k, f in enumerate(floors):
        nxt = floors[k + 1] - 0.1 if k + 1 < len(floors) else None
        out.append(Floor(k, f, nxt))
    return out


def floor_of(heights: np.ndarray, floors: Sequence[Floor]) -> np.ndarray:
    """The storey index of every height (-1: below the lowest floor by more than 0.3 m)."""
    h = np.asarray(heights, dtype=np.float64)
    out = np.full(h.shape, -1, dtype=np.int64)
    for f in floors:
        top = np.inf if f.top is None else f.top
        out[(h >= f.height - 0.3) & (h < top)] = f.id
    return out


# --------------------------------------------------------------------------------------- floor plan


def _grid(uv: np.ndarray, cell: float, pad: int = 2) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """Global cell indices of ``uv`` points, the grid's origin (index of cell [0, 0]) and its shape."""
    idx = np.floor(uv / cell).astype(np.int64)
    origin = idx.min(axis=0) - pad
    shape = tuple(int(v) for v in idx.max(axis=0) - origin + 1 + pad)
    return idx - origin, origin, shape


def _cell_key(floor: int, ij: np.ndarray) -> np.ndarray:
    """Global (floor, i, j) cells as int64 keys (i, j within +-2^20 cells)."""
    ij = np.asarray(ij, dtype=np.int64).reshape(-1, 2) + (1 << 20)
    return (np.int64(floor) << 42) | (ij[:, 0] << 21) | ij[:, 1]


def _plan(
    uvr: np.ndarray, cell: float, config: RoomsConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple]:
    """(walls, explored, origin, shape) of one storey from its points' horizontal coordinates and heights
    above the floor (``uvr`` [N, 3])."""
    from scipy import ndimage

    ij, origin, shape = _grid(uvr[:, :2], cell)
    occupied = np.zeros(shape, dtype=bool)
    occupied[ij[:, 0], ij[:, 1]] = True
    wall_pts = (uvr[:, 2] >= config.wall_low) & (uvr[:, 2] <= config.wall_high)
    walls = np.zeros(shape, dtype=bool)
    walls[ij[wall_pts, 0], ij[wall_pts, 1]] = True
    walls = ndimage.binary_closing(walls, structure=np.ones((3, 3), bool))  # close pinholes between samples
    explored = ndimage.binary_closing(occupied, structure=np.ones((3, 3), bool), iterations=2)
    explored = ndimage.binary_fill_holes(explored | walls)
    return walls, explored, origin, shape


def _grow(seeds: np.ndarray, free: np.ndarray) -> np.ndarray:
    """Grow the labelled ``seeds`` (int, 0 = none) over ``free`` cells one cell per step (4-neighbours), so
    that two regions meet halfway between them; cells no region reaches stay 0."""
    from scipy import ndimage

    labels = seeds.copy()
    cross = ndimage.generate_binary_structure(2, 1)
    while True:
        grown = ndimage.grey_dilation(labels, footprint=cross)
        new = (labels == 0) & free & (grown > 0)
        if not new.any():
            return labels
        labels[new] = grown[new]


def _outline(mask: np.ndarray, origin: np.ndarray, cell: float) -> list[np.ndarray]:
    """The outer boundaries of a cell mask as polygons [K, 2] in horizontal coordinates (metres), within a
    quarter of a cell of the cells' edges (traced on the mask at twice its resolution)."""
    import cv2

    fine = np.repeat(np.repeat(mask, 2, axis=0), 2, axis=1)
    m = np.ascontiguousarray(fine.T.astype(np.uint8))  # rows = j, cols = i: OpenCV's (x, y) = (i, j)
    contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    out = []
    for c in contours:
        c = cv2.approxPolyDP(c, 1.0, True).reshape(-1, 2).astype(np.float64)
        if len(c) >= 3:
            out.append(((c + 0.5) / 2 + origin) * cell)
    return out


def segment_rooms(points: np.ndarray, up: np.ndarray, config: RoomsConfig) -> Segmentation:
    """Storeys and rooms of a point set (Gaussian means [N, 3], world metres) seen from ``up``: see the module
    docstring. A map with too little free space for a room core gives storeys but no room."""
    from scipy import ndimage

    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    P = P[np.all(np.isfinite(P), axis=1)]
    u = unit_up(up)
    e1, e2 = horizontal_basis(u)
    h = P @ u
    floors = find_floors(h, config)
    seg = Segmentation(floors, [], [], [], [], [])
    which = floor_of(h, floors)
    cell = config.cell_size
    core = config.door_width / 2
    for f in floors:
        sel = which == f.id
        if sel.sum() < 10:
            continue
        uvr = np.stack([P[sel] @ e1, P[sel] @ e2, h[sel] - f.height], axis=1)
        walls, explored, origin, shape = _plan(uvr, cell, config)
        blocked = ndimage.binary_dilation(walls, structure=np.ones((3, 3), bool))
        free = explored & ~blocked
        dist = ndimage.distance_transform_edt(np.pad(free, 1))[1:-1, 1:-1] * cell
        cores, n = ndimage.label(dist > core)
        if n:
            sizes = ndimage.sum_labels(np.ones(shape), cores, index=np.arange(1, n + 1)) * cell * cell
            keep = np.flatnonzero(sizes >= 0.1)  # specks of core where free space widens for a moment
            lut = np.zeros(n + 1, dtype=np.int32)
            lut[keep + 1] = np.arange(1, len(keep) + 1)
            cores = lut[cores]
        labels = _grow(cores.astype(np.int32), free)
        # rooms too small to be rooms leave the plan: their cells go to no room
        final = np.zeros(shape, dtype=np.int32)
        for lab in range(1, int(labels.max(initial=0)) + 1):
            mask = labels == lab
            area = float(mask.sum()) * cell * cell
            if area < config.min_room_area:
                continue
            final[mask] = len(seg.room_floor) + 1
            seg.room_floor.append(f.id)
            seg.room_cells.append(_cell_key(f.id, np.argwhere(mask) + origin))
            seg.room_outline.append(_outline(mask, origin, cell))
            seg.room_area.append(area)
        seg.plans.append(FloorPlan(f.id, origin, cell, final, walls, explored))
    return seg


def raster_outline(outline: Sequence[np.ndarray], up: np.ndarray, cell: float) -> np.ndarray:
    """The cells (i, j) [K, 2] of the horizontal grid of ``cell`` metres (cell (i, j) spans ``[i, i + 1) *
    cell`` along e1 and ``[j, j + 1) * cell`` along e2, as :func:`segment_rooms` indexes them) whose centres
    the polygons ``outline`` (world points [M, 3] each) hold."""
    import cv2

    e1, e2 = horizontal_basis(unit_up(up))
    polys = [np.stack([p @ e1, p @ e2], axis=1) / cell for p in outline if len(p) >= 3]
    if not polys:
        return np.zeros((0, 2), dtype=np.int64)
    allp = np.concatenate(polys)
    lo = np.floor(allp.min(0)).astype(np.int64) - 1
    shape = np.ceil(allp.max(0)).astype(np.int64) - lo + 2
    grid = np.zeros((int(shape[1]), int(shape[0])), dtype=np.uint8)
    for q in polys:
        # OpenCV fills the pixels whose centres lie inside; pixel (i, j)'s centre is at (i + 0.5, j + 0.5)
        cv2.fillPoly(grid, [np.round((q - lo - 0.5) * 16).astype(np.int32)], 1, shift=4)
    jj, ii = np.nonzero(grid)
    return np.stack([ii, jj], axis=1) + lo


def _outline_cells(room: RoomNode, up: np.ndarray, cell: float) -> np.ndarray:
    """The global cell keys a room's outlines cover (as :func:`segment_rooms` keys them)."""
    return np.unique(_cell_key(room.floor, raster_outline(room.outline, up, cell)))


# --------------------------------------------------------------------------------------- assignment


def assign_rooms(
    points: np.ndarray,
    up: np.ndarray,
    floors: Sequence[Floor],
    rooms: Sequence[RoomNode],
    assign_radius: float = 0.5,
    cell: float = 0.05,
) -> np.ndarray:
    """The room id of every point (-1: none): the room of its storey whose outline holds its horizontal
    position, else the nearest such outline within ``assign_radius`` metres. The outlines are rasterised at
    ``cell`` metres per cell."""
    import cv2
    from scipy import ndimage

    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.full(len(P), -1, dtype=np.int64)
    if not len(P) or not rooms:
        return out
    u = unit_up(up)
    e1, e2 = horizontal_basis(u)
    h = P @ u
    which = floor_of(h, floors) if floors else np.zeros(len(P), dtype=np.int64)
    uv = np.stack([P @ e1, P @ e2], axis=1)
    for fid in sorted({r.floor for r in rooms}):
        mine = [r for r in rooms if r.floor == fid and r.outline]
        sel = np.flatnonzero((which == fid) & np.all(np.isfinite(uv), axis=1))
        if not mine or not len(sel):
            continue
        polys = [np.stack([p @ e1, p @ e2], axis=1) for r in mine for p in r.outline]
        allp = np.concatenate(polys)
        lo = np.floor(np.minimum(allp.min(0), uv[sel].min(0)) / cell) - 2
        hi = np.ceil(np.maximum(allp.max(0), uv[sel].max(0)) / cell) + 2
        shape = tuple(int(v) for v in hi - lo + 1)
        grid = np.zeros((shape[1], shape[0]), dtype=np.int32)  # rows = j (second coordinate)
        for k, r in enumerate(mine):
            for p in r.outline:
                # pixel (i, j) spans [i, i + 1) x [j, j + 1); OpenCV fills the pixels whose centres lie inside
                q = np.stack([p @ e1, p @ e2], axis=1) / cell - lo - 0.5
                cv2.fillPoly(grid, [np.round(q * 16).astype(np.int32)], k + 1, shift=4)
        dist, (jj, ii) = ndimage.distance_transform_edt(grid == 0, return_indices=True)
        near = grid[jj, ii]
        near[dist * cell > assign_radius] = 0
        ij = np.floor(uv[sel] / cell - lo).astype(np.int64)
        ok = (ij[:, 0] >= 0) & (ij[:, 1] >= 0) & (ij[:, 0] < shape[0]) & (ij[:, 1] < shape[1])
        k = np.zeros(len(sel), dtype=np.int64)
        k[ok] = near[ij[ok, 1], ij[ok, 0]]
        ids = np.array([-1] + [r.id for r in mine], dtype=np.int64)
        out[sel] = ids[k]
    return out


# --------------------------------------------------------------------------------------- types


class RuleRoomTyper:
    """Names a room from its objects' tags: the type whose cues (:data:`ROOM_TYPE_CUES`, whole tags) weigh
    most, each object counting by its size (up to :data:`FULL_WEIGHT_GAUSSIANS` Gaussians, so that a
    fragment a detector misnamed counts little), when they weigh at least 2 (one strong cue); else "room"."""

    name = "rule"

    @staticmethod
    def scores(tags: Sequence[str], sizes: Sequence[int] | None = None) -> tuple[dict[str, float], dict]:
        """({type: cue weight}, {type: the tags that gave it}) of a room holding objects tagged ``tags``
        (``sizes``: their Gaussians; None: each counts fully)."""
        scores: dict[str, float] = {}
        found: dict[str, list[str]] = {}
        for k, tag in enumerate(tags):
            words = " ".join(re.sub(r"[^a-z ]+", " ", str(tag).lower()).split())
            if not words:
                continue
            size = 1.0 if sizes is None else min(1.0, float(sizes[k]) / FULL_WEIGHT_GAUSSIANS)
            for kind, cues in ROOM_TYPE_CUES.items():
                w = cues.get(words, 0.0) * size
                if w > 0:
                    scores[kind] = scores.get(kind, 0.0) + w
                    found.setdefault(kind, []).append(words)
        return scores, found

    def describe(self, tags: Sequence[str], sizes: Sequence[int] | None = None) -> tuple[str, str]:
        """(type, reason) for a room holding objects tagged ``tags`` (``sizes``: their Gaussians)."""
        scores, found = self.scores(tags, sizes)
        if not scores:
            return UNKNOWN_ROOM, "no object that names a room type"
        best = max(sorted(scores), key=lambda k: scores[k])
        if scores[best] < _MIN_TYPE_SCORE:
            return UNKNOWN_ROOM, f"too few cues ({', '.join(sorted(set(found[best])))})"
        return best, f"{', '.join(sorted(set(found[best])))} (score {scores[best]:.1f})"


class LLMRoomTyper:
    """Names a room with a language model at an OpenAI-compatible endpoint: the room's object tags go in, one
    of :data:`ROOM_TYPE_CUES`' types (or "room") comes out; a failed request or an answer outside the
    vocabulary falls back to the rule. Replies are cached per set of tags."""

    name = "llm"

    def __init__(self, client, max_tokens: int = 200) -> None:
        self.client = client
        self.max_tokens = max_tokens
        self.fallback = RuleRoomTyper()
        self._cache: dict[tuple[str, ...], tuple[str, str, str]] = {}

    @classmethod
    def from_config(cls, config: RoomsConfig, endpoint: EndpointConfig | None = None) -> LLMRoomTyper:
        """From ``graph.rooms`` and the endpoint it calls (``graph.endpoint``; None: the defaults)."""
        client = ChatClient.from_config(endpoint or EndpointConfig(), config.model, "graph.rooms.model")
        return cls(client, config.max_tokens)

    def describe_with_source(
        self, tags: Sequence[str], sizes: Sequence[int] | None = None
    ) -> tuple[str, str, str]:
        """(type, reason, source "llm" | "rule"); ``sizes`` weigh the tags for the rule only."""
        key = tuple(sorted(str(t) for t in tags if str(t).strip()))
        if not key:
            t, why = self.fallback.describe(key)
            return t, why, "rule"
        if key in self._cache:
            return self._cache[key]
        types = [*ROOM_TYPE_CUES, UNKNOWN_ROOM]
        prompt = (
            "A room of an indoor map holds these objects: " + ", ".join(json.dumps(t) for t in key) + ".\n"
            "Which kind of room is it? Choose one of: "
            + ", ".join(json.dumps(t) for t in types)
            + ' ("room" when the objects do not tell).\n'
            'Answer with JSON only: {"type": "<type>", "reason": "<a few words>"}'
        )
        try:
            reply = extract_json(self.client.chat([{"role": "user", "content": prompt}], self.max_tokens))
            kind = room_type_of(str(reply.get("type", ""))) if isinstance(reply, dict) else None
            if (
                kind is None
                and isinstance(reply, dict)
                and str(reply.get("type", "")).strip().lower() == "room"
            ):
                kind = UNKNOWN_ROOM
            if kind is None:
                raise ValueError(f"room type {reply!r} is not one of {types}")
            out = (kind, str(reply.get("reason", ""))[:200], "llm")
        except Exception as e:  # any model failure: the rule names the room
            log.warning("room typing LLM failed (%s); using the offline rule", e)
            t, why = self.fallback.describe(tags, sizes)
            return t, why, "rule"
        self._cache[key] = out
        return out

    def describe(self, tags: Sequence[str], sizes: Sequence[int] | None = None) -> tuple[str, str]:
        t, why, _ = self.describe_with_source(tags, sizes)
        return t, why


def build_room_typer(config: RoomsConfig, endpoint: EndpointConfig | None = None):
    """The typer ``graph.rooms.typer`` selects; ``endpoint``: the one ``llm`` calls (``graph.endpoint``;
    None: the defaults)."""
    return LLMRoomTyper.from_config(config, endpoint) if config.typer == "llm" else RuleRoomTyper()


def read_rooms(doc: Mapping[str, Any], source: str = "graph.json") -> tuple[np.ndarray | None, list[Floor],
                                                                            list[RoomNode]]:  # fmt: skip
    """The up vector (:func:`~ogscene3d.runs.graph_json.graph_up`; None when the document has none), storeys
    and rooms of a graph.json document (none in files written before rooms); DataError naming ``source`` for
    malformed ones."""
    rm = RoomMap(RoomsConfig(), typer=RuleRoomTyper())
    u = graph_up(doc, source)
    rm.load(doc, source, u if u is not None else np.array([0.0, 0.0, 1.0]))
    return u, rm.floors, [rm.rooms[i] for i in sorted(rm.rooms)]


# --------------------------------------------------------------------------------------- the room map


class RoomMap:
    """The storeys and rooms of a growing map, kept across updates (see the module docstring).

    ``update(kf, means, up, objects)`` segments the rooms anew, carries the ids of the previous rooms over,
    assigns the object nodes to rooms and types the rooms; ``objects``: {node id: (points [M, 3], tag[,
    number of Gaussians])} (without the number, the points count).
    """

    def __init__(self, config: RoomsConfig, typer=None) -> None:
        self.config = config
        self.typer = typer if typer is not None else build_room_typer(config)
        self.floors: list[Floor] = []
        self.rooms: dict[int, RoomNode] = {}
        self.object_room: dict[int, int] = {}
        self._cells: dict[int, np.ndarray] = {}  # room id -> its global cell keys at the last update
        self._tags: dict[int, str] = {}  # object node id -> tag, at the last assignment
        self._sizes: dict[int, int] = {}  # object node id -> its Gaussians, at the last assignment
        self._next_id = 1

    def update(
        self,
        kf: int,
        means: np.ndarray,
        up: np.ndarray,
        objects: Mapping[int, tuple[np.ndarray, str]],
        frame: int = -1,
        ask_model: bool = True,
    ) -> None:
        """One room update at keyframe ``kf`` (dataset frame ``frame``) from all Gaussian means [N, 3]
        (world metres). ``ask_model``: an LLM typer is asked (else a room keeps the type it had, a new one
        gets the rule's until the next update that asks)."""
        P = np.asarray(means, dtype=np.float64).reshape(-1, 3)
        P = P[np.all(np.isfinite(P), axis=1)]
        scale = 1.0
        if len(P) > self.config.max_points:  # a large map: a fixed random subset keeps the update cheap
            scale = len(P) / self.config.max_points
            P = P[np.random.default_rng(0).choice(len(P), self.config.max_points, replace=False)]
        seg = segment_rooms(P, up, self.config)
        ids = self._match(seg)
        rooms: dict[int, RoomNode] = {}
        for k, rid in enumerate(ids):
            old = self.rooms.get(rid)
            rooms[rid] = RoomNode(
                id=rid,
                floor=seg.room_floor[k],
                outline=[
                    self._lift(p, seg.floors[seg.room_floor[k]].height, up) for p in seg.room_outline[k]
                ],
                area=seg.room_area[k],
                center=np.zeros(3),
                bbox_min=np.zeros(3),
                bbox_max=np.zeros(3),
                type=old.type if old else UNKNOWN_ROOM,
                type_source=old.type_source if old else "",
                type_reason=old.type_reason if old else "",
                first_seen=old.first_seen if old else kf,
                last_updated=kf,
                first_frame=old.first_frame if old else frame,
            )
        self.floors = seg.floors
        self._cells = {rid: seg.room_cells[k] for k, rid in enumerate(ids)}
        room_list = [rooms[i] for i in sorted(rooms)]
        which = assign_rooms(P, up, self.floors, room_list, self.config.assign_radius)
        for r in room_list:
            mine = P[which == r.id]
            r.num_gaussians = int(round(len(mine) * scale))
            if len(mine):
                r.center, r.bbox_min, r.bbox_max = mine.mean(0), mine.min(0), mine.max(0)
            else:  # (a room's own floor cells hold points, so this stays rare)
                pts = np.concatenate(r.outline)
                r.center, r.bbox_min, r.bbox_max = pts.mean(0), pts.min(0), pts.max(0)
        self.rooms = rooms
        self.assign_objects(objects, up)
        self._type(ask_model)

    @staticmethod
    def _lift(poly: np.ndarray, height: float, up: np.ndarray) -> np.ndarray:
        """Horizontal coordinates (e1, e2) at ``height`` along up -> world points."""
        u = unit_up(up)
        e1, e2 = horizontal_basis(u)
        return poly[:, :1] * e1 + poly[:, 1:2] * e2 + height * u

    def _match(self, seg: Segmentation) -> list[int]:
        """Ids for the new rooms: each previous room goes to the new room holding most of its cells (when that
        is at least a third of either), largest overlaps first; the others get new ids."""
        ids: list[int | None] = [None] * len(seg.room_cells)
        pairs = []
        for rid, old in self._cells.items():
            for k, new in enumerate(seg.room_cells):
                n = int(np.isin(new, old, assume_unique=True).sum())
                if n and (n >= len(old) / 3 or n >= len(new) / 3):
                    pairs.append((n, rid, k))
        used: set[int] = set()
        for _, rid, k in sorted(pairs, reverse=True):
            if ids[k] is None and rid not in used:
                ids[k] = rid
                used.add(rid)
        out = []
        for i in ids:
            if i is None:
                i = self._next_id
            self._next_id = max(self._next_id, i + 1)
            out.append(i)
        return out

    def assign_objects(self, objects: Mapping[int, tuple[np.ndarray, str]], up: np.ndarray) -> None:
        """Each object node goes into the room that holds most of its points (none when no room does)."""
        self.object_room = {}
        for r in self.rooms.values():
            r.objects = []
        if not self.rooms or not objects:
            return
        room_list = [self.rooms[i] for i in sorted(self.rooms)]
        order = sorted(objects)
        pts = [np.asarray(objects[i][0], dtype=np.float64).reshape(-1, 3) for i in order]
        which = assign_rooms(np.concatenate(pts), up, self.floors, room_list, self.config.assign_radius)
        start = 0
        for i, p in zip(order, pts):
            w = which[start : start + len(p)]
            start += len(p)
            w = w[w >= 0]
            if len(w):
                vals, counts = np.unique(w, return_counts=True)
                rid = int(vals[np.argmax(counts)])
                self.object_room[i] = rid
                self.rooms[rid].objects.append(i)
        self._tags = {i: objects[i][1] for i in order}
        self._sizes = {
            i: int(objects[i][2]) if len(objects[i]) > 2 else len(pts[k]) for k, i in enumerate(order)
        }

    def _type(self, ask_model: bool = True) -> None:
        for r in self.rooms.values():
            names = [self._tags.get(i, "") for i in r.objects]
            sizes = [self._sizes.get(i, FULL_WEIGHT_GAUSSIANS) for i in r.objects]
            r.type_scores = RuleRoomTyper.scores(names, sizes)[0]
            if isinstance(self.typer, LLMRoomTyper) and ask_model:
                r.type, r.type_reason, r.type_source = self.typer.describe_with_source(names, sizes)
            elif isinstance(self.typer, LLMRoomTyper) and r.type_source == "llm":
                continue  # between the updates that ask the model, its type stays
            elif isinstance(self.typer, LLMRoomTyper):
                r.type, r.type_reason = self.typer.fallback.describe(names, sizes)
                r.type_source = "rule"
            else:
                r.type, r.type_reason = self.typer.describe(names, sizes)
                r.type_source = self.typer.name

    def to_dict(self) -> dict:
        """``{"floors": [...], "rooms": [...]}`` for graph.json."""
        return {
            "floors": [f.to_dict() for f in self.floors],
            "rooms": [self.rooms[i].to_dict() for i in sorted(self.rooms)],
        }

    def load(self, doc: Mapping[str, Any], source: str, up: np.ndarray) -> None:
        """Take the floors and rooms of a graph.json document (absent in files written before rooms: none);
        the rooms' cells (which the next update matches its rooms with) come from their outlines."""
        floors, rooms = doc.get("floors", []), doc.get("rooms", [])
        if not isinstance(floors, list) or not isinstance(rooms, list):
            raise DataError(f"{source}: 'floors' and 'rooms' must be lists")
        try:
            self.floors = [
                Floor(int(f["id"]), float(f["height"]), None if f.get("top") is None else float(f["top"]))
                for f in floors
            ]
        except (KeyError, TypeError, ValueError) as e:
            raise DataError(f"{source}: a floor is malformed ({type(e).__name__}: {e})") from None
        self.rooms = {}
        for k, d in enumerate(rooms):
            r = RoomNode.from_dict(d, source, k)
            self.rooms[r.id] = r
        self.object_room = {i: r.id for r in self.rooms.values() for i in r.objects}
        self._next_id = max(self.rooms, default=0) + 1
        self._cells = {r.id: _outline_cells(r, up, self.config.cell_size) for r in self.rooms.values()}
