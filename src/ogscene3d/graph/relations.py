"""Spatial relations between scene-graph nodes (paper Eq. 22, the edge prompt P_edge).

Two predictors behind the :class:`RelationPredictor` protocol:

* :class:`GeometricRelations` (default, offline, deterministic) decides from the nodes' points, robust
  bounds and the configured world up vector.
* :class:`LLMRelations` sends ONE chat-completions request for all candidate pairs (node tags, centres and
  the 3D vector between them), maps the answers onto :data:`RELATIONS` (synonyms such as "on top of" or
  "resting on" become "on"; inverse verbs such as "supports" swap the pair), and falls back to the
  geometric predictor for every pair it could not get a valid answer for.

Edges are directed: ``Relation(source, target, "on")`` reads "source on target".

Deviation from the paper (Sec. III-D, after Eq. 23): its edge prompt *prioritises* common spatial
relations "while retaining moderate open-set flexibility for uncommon cases". Here the vocabulary is closed:
the prompt asks for a relation from :data:`RELATIONS`, and an answer that :func:`normalize_relation` cannot
map onto it is logged and that pair takes the geometric relation. Reason: the paper's own argument for a
standard vocabulary (one spelling per relation for query matching) applied all the way, so that every edge,
whichever predictor made it, uses the vocabulary the geometric fallback, the synthetic ground truth and the
relation-recall metric share.
"""

from __future__ import annotations

import json
import logging
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from ..config import EndpointConfig, RelationsConfig, check_section
from ..errors import ConfigError
from ..up_axis import unit_up
from .geometry import Shape
from .openai_client import ChatClient, extract_json
from .types import SceneNode

log = logging.getLogger(__name__)

#: The relation vocabulary (canonical spellings).
RELATIONS: tuple[str, ...] = ("on", "under", "above", "below", "next to", "in", "attached to")

# phrase -> (canonical relation, swapped): swapped means "A <phrase> B" is "B <relation> A".
_SYNONYMS: dict[str, tuple[str, bool]] = {}
for _rel, _words in {
    "on": [
        "on",
        "on top of",
        "onto",
        "upon",
        "atop",
        "resting on",
        "rests on",
        "placed on",
        "sitting on",
        "sits on",
        "standing on",
        "stands on",
        "lying on",
        "lies on",
        "laid on",
        "supported by",
        "set on",
        "on the top of",
        "located on",
    ],
    "under": ["under", "underneath", "beneath", "under neath", "tucked under"],
    "above": [
        "above",
        "over",
        "hanging above",
        "hangs above",
        "higher than",
        "hovering over",
        "suspended above",
    ],
    "below": ["below", "lower than", "down from"],
    "next to": [
        "next to",
        "beside",
        "besides",
        "near",
        "nearby",
        "adjacent to",
        "adjacent",
        "by",
        "close to",
        "alongside",
        "next",
        "near to",
        "neighbouring",
        "neighboring",
        "against",
        "leaning against",
        "in front of",
        "behind",
        "to the left of",
        "to the right of",
        "left of",
        "right of",
        "touching",
    ],
    "in": [
        "in",
        "inside",
        "inside of",
        "within",
        "contained in",
        "enclosed in",
        "stored in",
        "placed in",
        "into",
    ],
    "attached to": [
        "attached to",
        "attached on",
        "mounted on",
        "mounted to",
        "hanging on",
        "hangs on",
        "hung on",
        "fixed to",
        "fixed on",
        "affixed to",
        "fastened to",
        "hanging from",
        "hangs from",
        "part of",
        "embedded in",
        "installed on",
        "installed in",
    ],
}.items():
    for _w in _words:
        _SYNONYMS[_w] = (_rel, False)
for _w, _rel in {
    "supports": "on",
    "supporting": "on",
    "holds": "on",
    "holding": "on",
    "carries": "on",
    "has on top": "on",
    "contains": "in",
    "containing": "in",
    "encloses": "in",
    "houses": "in",
    "covers": "under",
    "covering": "under",
}.items():
    _SYNONYMS[_w] = (_rel, True)

#: Every phrase :func:`normalize_relation` knows, longest first (queries look for them in their text).
RELATION_PHRASES: tuple[str, ...] = tuple(sorted(_SYNONYMS, key=lambda w: (-len(w.split()), w)))


def normalize_relation(text: str) -> tuple[str, bool] | None:
    """Map a free-form relation phrase onto the vocabulary: ``(relation, swapped)`` or None if unknown.

    ``swapped`` is True for inverse phrasings ("A supports B" means "B on A").
    """
    if not isinstance(text, str):
        return None
    t = text.strip().lower().replace("_", " ").replace("-", " ")
    t = re.sub(r"[^a-z ]+", " ", t)
    t = re.sub(r"\s+", " ", t).strip()
    # Simplify step by step and look the phrase up after each step: some phrases contain the words a
    # later step drops ("to the left of" would become "to left of").
    for simplify in (
        lambda s: s,
        lambda s: re.sub(r"^(is|are|be|being|sits|it is|object is)\s+", "", s),
        lambda s: re.sub(r"\s+(the|a|an)$", "", s),
        lambda s: re.sub(r"\s+(the|a|an)\s+", " ", s),
    ):
        t = simplify(t)
        if t in _SYNONYMS:
            return _SYNONYMS[t]
    return None


@dataclass
class Relation:
    """A predicted directed relation "source relation target" and which predictor produced it."""

    source: int
    target: int
    relation: str
    predictor: str


@runtime_checkable
class RelationPredictor(Protocol):
    """Predicts one relation per candidate pair (the pairs are proximate by Eqs. 20-21)."""

    def predict(self, pairs: Sequence[tuple[SceneNode, SceneNode]]) -> list[Relation]:
        """One :class:`Relation` per pair, in order; the predictor chooses the direction."""
        ...


@dataclass
class _Columns:
    keys: np.ndarray  # sorted unique horizontal cell keys
    lo: np.ndarray  # min height per cell
    hi: np.ndarray  # max height per cell


def _columns(points: np.ndarray, shape: Shape, cell: float) -> _Columns:
    hp = shape.horizontal(points)
    h = points @ shape.up
    ij = np.floor(hp / cell).astype(np.int64)
    keys = ij[:, 0] * 2_000_003 + ij[:, 1]  # 2D hash, exact for |i|,|j| < 1e6 cells
    ukeys, inv = np.unique(keys, return_inverse=True)
    lo = np.full(len(ukeys), np.inf)
    hi = np.full(len(ukeys), -np.inf)
    np.minimum.at(lo, inv, h)
    np.maximum.at(hi, inv, h)
    return _Columns(ukeys, lo, hi)


class GeometricRelations:
    """Deterministic relations from geometry and the configured up vector (``graph.up_axis``).

    For a pair (A, B) the first rule that fires wins:

    1. *attached to*: B is a vertical sheet (wall-like, larger than A), A touches B's plane
       (within ``contact_tol``) over B's extent, and A is either a sheet parallel to B (a door) or its
       bottom is at least ``attach_elevation`` above B's bottom (a picture; not a chair against the
       wall); or B is a horizontal sheet and A hangs below it, touching it (a lamp on the ceiling).
    2. *in*: B is at least twice A's volume, ``inside_ratio`` of A's points lie inside B's up-aligned box
       and, over A's footprint, B has points both below A's bottom and above A's top (a book between
       shelf boards, not a cup on a table).
    3. Vertical stacking, tested per horizontal column (grid ``cell_size``, widened to 1.5x the sample
       spacing of sparsely sampled nodes) shared by both nodes; shared columns must cover
       ``overlap_ratio`` of the smaller node's columns. If A lies over B in most shared columns, then
       "A on B" when the smallest gap is within ``contact_tol``; else "A above B" when A is the smaller
       (largest extent, then volume); else "B under A" (gap <= ``under_gap``) or "B below A".
    4. Otherwise *next to*, with the smaller node as the source.
    """

    name = "geometric"

    def __init__(self, config: RelationsConfig | None = None, up: Sequence[float] = (0.0, -1.0, 0.0)) -> None:
        self.config = config or RelationsConfig()
        self.up = unit_up(up)
        check_section(self.config, "graph.relations")  # the rules on the fields (a config built in Python)

    def predict(self, pairs: Sequence[tuple[SceneNode, SceneNode]]) -> list[Relation]:
        return [self.predict_pair(a, b) for a, b in pairs]

    def predict_pair(self, a: SceneNode, b: SceneNode) -> Relation:
        """The relation of one pair (see the class docstring for the rules)."""
        pa = _pts(a)
        pb = _pts(b)
        sa, sb = a.shape(self.up), b.shape(self.up)
        for x, y, px, py, sx, sy in ((a, b, pa, pb, sa, sb), (b, a, pb, pa, sb, sa)):
            if self._attached(px, sx, py, sy):
                return Relation(x.id, y.id, "attached to", self.name)
        for x, y, px, py, sx, sy in ((a, b, pa, pb, sa, sb), (b, a, pb, pa, sb, sa)):
            if self._inside(px, sx, py, sy):
                return Relation(x.id, y.id, "in", self.name)
        # Columns must be wider than the sample spacing of sparse (subsampled, large) nodes, or two
        # nodes stacked on each other would share few occupied columns.
        cell = max(self.config.cell_size, 1.5 * _spacing(pa, sa), 1.5 * _spacing(pb, sb))
        ca = _columns(pa, sa, cell)
        cb = _columns(pb, sb, cell)
        stack = self._stacking(ca, cb)
        if stack is not None:
            a_upper, gap = stack
            upper, lower = (a, b) if a_upper else (b, a)
            su, sl = (sa, sb) if a_upper else (sb, sa)
            if gap <= self.config.contact_tol:
                return Relation(upper.id, lower.id, "on", self.name)
            if _not_larger(su, sl):
                return Relation(upper.id, lower.id, "above", self.name)
            rel = "under" if gap <= self.config.under_gap else "below"
            return Relation(lower.id, upper.id, rel, self.name)
        small, big = (a, b) if _not_larger(sa, sb) else (b, a)
        return Relation(small.id, big.id, "next to", self.name)

    def _attached(self, px: np.ndarray, sx: Shape, py: np.ndarray, sy: Shape) -> bool:
        tol = self.config.contact_tol
        if sy.size < 1.2 * sx.size:
            return False
        if sy.is_vertical_plane:
            n = sy.normal
            plane_c = py.mean(axis=0)
            d = (px - plane_c) @ n
            if np.min(np.abs(d)) > tol + sy.thickness / 2:
                return False
            # A must lie over the wall's surface, not beyond its ends.
            in_plane_axes = np.stack([np.cross(n, sy.up), sy.up])
            in_plane_axes[0] /= max(np.linalg.norm(in_plane_axes[0]), 1e-12)
            ly, lx = (py - plane_c) @ in_plane_axes.T, (px - plane_c) @ in_plane_axes.T
            lo, hi = np.percentile(ly, [2, 98], axis=0)
            over = np.all((lx >= lo - tol) & (lx <= hi + tol), axis=1).mean()
            if over < 0.5:
                return False
            # elevated (picture, shelf board, wall cabinet), or itself a sheet parallel to the wall (door)
            coplanar = sx.planar and abs(float(sx.normal @ n)) > 0.9
            return bool(coplanar or sx.h_lo >= sy.h_lo + self.config.attach_elevation)
        if sy.is_horizontal_plane:
            # hanging from a ceiling-like sheet: A lies below the sheet, some of A (a cord, a mount) touches
            # its underside, and A is under its footprint
            hx = px @ sy.up
            return bool(
                sx.h_hi <= sy.h_lo + tol
                and hx.max() >= sy.h_lo - tol
                and sx.h_lo < sy.h_lo - tol
                and sy.in_footprint(px, tol).mean() >= 0.5
            )
        return False

    def _inside(self, px: np.ndarray, sx: Shape, py: np.ndarray, sy: Shape) -> bool:
        tol = self.config.contact_tol
        if sy.volume < 2.0 * sx.volume:
            return False
        h = px @ sy.up
        in_box = sy.in_footprint(px, tol / 2) & (h >= sy.h_lo - tol / 2) & (h <= sy.h_hi + tol / 2)
        if in_box.mean() < self.config.inside_ratio:
            return False
        # Enclosure: over A's footprint, B has points both under A's bottom and over A's top (shelf boards
        # below and above a book), unlike a table under a cup or a shelf top under a book lying on it.
        # (footprint grown by contact_tol: B is a subsample, few of its points lie over a small A)
        over = sx.in_footprint(py, tol)
        hy = py[over] @ sy.up
        return bool(np.sum(hy <= sx.h_lo + tol) >= 2 and np.sum(hy > sx.h_hi) >= 2)

    def _stacking(self, ca: _Columns, cb: _Columns) -> tuple[bool, float] | None:
        """(A is the upper node, smallest vertical gap) when one node lies over the other, else None."""
        tol = self.config.contact_tol
        _, ia, ib = np.intersect1d(ca.keys, cb.keys, return_indices=True)
        if len(ia) < self.config.overlap_ratio * min(len(ca.keys), len(cb.keys)) or len(ia) == 0:
            return None
        a_over = ca.lo[ia] >= cb.hi[ib] - tol
        b_over = cb.lo[ib] >= ca.hi[ia] - tol
        if a_over.mean() > 0.5 and a_over.mean() >= b_over.mean():
            return True, float(max(0.0, np.min(ca.lo[ia][a_over] - cb.hi[ib][a_over])))
        if b_over.mean() > 0.5:
            return False, float(max(0.0, np.min(cb.lo[ib][b_over] - ca.hi[ia][b_over])))
        return None


def _not_larger(sa: Shape, sb: Shape) -> bool:
    """Whether A is not the larger node: by largest extent, by volume when the extents are within 10%."""
    if abs(sa.size - sb.size) > 0.1 * max(sa.size, sb.size):
        return sa.size < sb.size
    return sa.volume <= sb.volume


def _spacing(points: np.ndarray, shape: Shape) -> float:
    """Mean horizontal sample spacing of a node: sqrt(footprint area / number of points)."""
    area = 4.0 * float(shape.footprint_half[0]) * float(shape.footprint_half[1])
    return float(np.sqrt(area / max(len(points), 1)))


def _pts(n: SceneNode) -> np.ndarray:
    return np.asarray(n.points if len(n.points) else n.center[None], dtype=np.float64)


EDGE_SYSTEM_PROMPT = (
    "You are a spatial reasoning assistant for 3D indoor scene graphs. You receive objects of one scene "
    "with their semantic tag and 3D center, and candidate pairs of objects that are physically close. "
    "For each pair, decide the spatial relationship between the two objects."
)


def _vec(v: np.ndarray) -> str:
    return "[" + ", ".join(f"{float(x):.2f}" for x in v) + "]"


def edge_prompt(pairs: Sequence[tuple[SceneNode, SceneNode]], up: np.ndarray) -> str:
    """The edge prompt P_edge for a batch of pairs: nodes (tag, centre), pair vectors, vocabulary, format."""
    nodes: dict[int, SceneNode] = {}
    for a, b in pairs:
        nodes[a.id], nodes[b.id] = a, b
    lines = [
        "Objects (id: tag, center [x, y, z] in metres):",
        *(
            f"- {n.id}: {json.dumps(n.tag or 'object')}, center {_vec(n.center)}"
            for n in (nodes[k] for k in sorted(nodes))
        ),
        "",
        f"The world up direction is {_vec(up)} (heights grow along it).",
        "Candidate pairs (the vector goes from the first object's center to the second's, in metres):",
    ]
    for k, (a, b) in enumerate(pairs):
        r = b.center - a.center
        lines.append(
            f"{k}. subject {a.id} ({a.tag or 'object'}), object {b.id} ({b.tag or 'object'}), "
            f"vector {_vec(r)}"
        )
    lines += [
        "",
        "Choose each relationship from this list: " + ", ".join(f'"{r}"' for r in RELATIONS) + ".",
        'Read it as "<subject> <relation> <object>"; if it reads better the other way round, swap subject '
        "and object in your answer.",
        'Answer with JSON only, one entry per pair: {"relations": [{"pair": 0, "subject": <id>, '
        '"relation": "<relation>", "object": <id>}, ...]}',
    ]
    return "\n".join(lines)


_BAD_ID = object()  # an id field that is present but not an integer


def _entry_id(item: dict, key: str) -> object:
    """An entry's ``subject``/``object`` id: int, None when absent, ``_BAD_ID`` when not an integer."""
    v = item.get(key)
    if v is None:
        return None
    if isinstance(v, str) and v.strip().lstrip("-").isdigit():
        return int(v)
    if isinstance(v, int) and not isinstance(v, bool):
        return v
    if isinstance(v, float) and v.is_integer():  # 3.0 from a model that writes every number as float
        return int(v)
    return _BAD_ID


def _direction(item: dict, a: int, b: int) -> tuple[int, int] | None:
    """(source, target) of an entry for the pair (a, b) from its ``subject``/``object`` ids (pair order
    when both are absent); None when an id is not one of the pair's or both name the same node."""
    subj, obj = _entry_id(item, "subject"), _entry_id(item, "object")
    given = [v for v in (subj, obj) if v is not None]
    if any(v not in (a, b) for v in given) or (len(given) == 2 and subj == obj):
        return None
    if subj is not None:
        return subj, (b if subj == a else a)
    if obj is not None:
        return (b if obj == a else a), obj
    return a, b


def parse_edge_reply(text: str, pairs: Sequence[tuple[SceneNode, SceneNode]]) -> dict[int, Relation]:
    """Parse an edge-prompt reply into ``{pair index: Relation}``; malformed entries are logged, skipped
    (those pairs fall back to geometry). An entry must name the pair's own nodes as subject/object."""
    try:
        data = extract_json(text)
    except ValueError as e:
        log.warning("relations LLM: %s", e)
        return {}
    items = data.get("relations") if isinstance(data, dict) else data
    if not isinstance(items, list):
        log.warning("relations LLM: reply has no 'relations' list")
        return {}
    out: dict[int, Relation] = {}
    for item in items:
        if not isinstance(item, dict):
            log.warning("relations LLM: ignoring non-object entry %r", item)
            continue
        k = item.get("pair")
        if isinstance(k, str) and k.strip().isdigit():
            k = int(k)
        if not isinstance(k, int) or isinstance(k, bool) or not 0 <= k < len(pairs):
            log.warning("relations LLM: ignoring entry with bad pair index %r", item.get("pair"))
            continue
        norm = normalize_relation(item.get("relation", ""))
        if norm is None:
            log.warning(
                "relations LLM: relation %r for pair %d is not in the vocabulary", item.get("relation"), k
            )
            continue
        rel, swapped = norm
        a, b = pairs[k]
        direction = _direction(item, a.id, b.id)
        if direction is None:
            log.warning(
                "relations LLM: entry for pair %d names subject %r / object %r, not the pair's nodes %d, %d",
                k,
                item.get("subject"),
                item.get("object"),
                a.id,
                b.id,
            )
            continue
        src, dst = direction
        if swapped:
            src, dst = dst, src
        out[k] = Relation(src, dst, rel, "llm")
    return out


class LLMRelations:
    """Relations from an LLM through an OpenAI-compatible endpoint: one request for all pairs.

    Pairs the reply leaves out, or answers outside the vocabulary, fall back to ``fallback``
    (the geometric predictor); a failed request falls back for every pair. Never raises on model failures.
    """

    name = "llm"

    def __init__(
        self,
        client: ChatClient,
        fallback: RelationPredictor,
        up: Sequence[float] = (0.0, -1.0, 0.0),
        max_tokens: int = 2000,
    ) -> None:
        self.client = client
        self.fallback = fallback
        self.up = unit_up(up)
        self.max_tokens = max_tokens

    @classmethod
    def from_config(
        cls, config: RelationsConfig, up: Sequence[float], endpoint: EndpointConfig | None = None
    ) -> LLMRelations:
        """From ``graph.relations`` and the endpoint it calls (``graph.endpoint``; None: the defaults)."""
        client = ChatClient.from_config(endpoint or EndpointConfig(), config.model, "graph.relations.model")
        return cls(client, GeometricRelations(config, up), up, config.max_tokens)

    def predict(self, pairs: Sequence[tuple[SceneNode, SceneNode]]) -> list[Relation]:
        if not pairs:
            return []
        answers: dict[int, Relation] = {}
        try:
            reply = self.client.chat(
                [
                    {"role": "system", "content": EDGE_SYSTEM_PROMPT},
                    {"role": "user", "content": edge_prompt(pairs, self.up)},
                ],
                max_tokens=self.max_tokens,
            )
            answers = parse_edge_reply(reply, pairs)
        except Exception as e:  # any failure of the model call must not stop mapping
            log.warning(
                "relations LLM request failed (%s); using the geometric fallback for %d pairs", e, len(pairs)
            )
        missing = [k for k in range(len(pairs)) if k not in answers]
        if missing:
            if answers:
                log.info("relations LLM: %d of %d pairs fall back to geometry", len(missing), len(pairs))
            for k, rel in zip(missing, self.fallback.predict([pairs[k] for k in missing])):
                answers[k] = rel
        return [answers[k] for k in range(len(pairs))]


def build_relations(
    config: RelationsConfig, up: Sequence[float], endpoint: EndpointConfig | None = None
) -> RelationPredictor:
    """The predictor selected by ``graph.relations.kind`` (geometric | llm); ``endpoint``: the one ``llm``
    calls (``graph.endpoint``; None: the defaults)."""
    if config.kind == "geometric":
        return GeometricRelations(config, up)
    if config.kind == "llm":
        return LLMRelations.from_config(config, up, endpoint)

    raise ConfigError(f"graph.relations.kind must be 'geometric' or 'llm', got {config.kind!r}")
