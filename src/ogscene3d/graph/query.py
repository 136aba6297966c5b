"""Queries over objects, their relations and their rooms: "pillow on the bed", "chair in the kitchen",
"the mug on the desk in the office".

Offline (:func:`parse_query`, :func:`rank`): the text is read as a *target*, then optionally a *relation*
and an *anchor*, then optionally *in* a *room*: object terms are the graph's tags and the offline synonyms
(:mod:`.terms`), relation phrases those the relation vocabulary knows ("on top of", "next to", "inside",
...), room terms the room types and their synonyms ("lounge", "study") or "room 3". Each node matching the
target is scored by how well its tag or caption names it, times how well the relation holds with a node
matching the anchor (an edge of the graph with that relation, its inverse or a close one; else the nodes'
boxes), times whether it lies in a room of that type; every hit says why it matched.

Through an LLM (:class:`LLMQuery`, ``graph.query.kind: llm``): the query and a compact graph (objects with
their tags and rooms, relations, rooms with their types) go to the OpenAI-compatible endpoint, node ids come
back; ids that are not in the graph are dropped, and a failed request or an answer with no valid id falls
back to the offline reading (the answer says so).

Bad queries (empty, no known term) get a :class:`QueryAnswer` with a message and no hits, never an exception.
"""

from __future__ import annotations

import json
import logging
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..config import EndpointConfig, QueryConfig
from ..up_axis import unit_up
from .geometry import horizontal_basis
from .openai_client import ChatClient, extract_json
from .relations import RELATION_PHRASES, normalize_relation
from .rooms import ROOM_SYNONYMS, ROOM_TYPE_CUES, UNKNOWN_ROOM, RoomNode, room_type_of
from .terms import known_terms
from .types import SceneEdge, SceneNode

log = logging.getLogger(__name__)

#: Words that stand for "any object" ("something on the table").
WILDCARDS = frozenset(
    {"object", "objects", "thing", "things", "something", "anything", "item", "items", "stuff"}
)
#: Words a query may hold that carry no term.
FILLERS = frozenset(
    """a an the find show me where is are was there any some my please get bring fetch look for locate
    what which that this those these it of to can you i want need see give one we do does have has with
    and or room rooms""".split()
)
_INVERSE = {"on": "under", "under": "on", "above": "below", "below": "above"}
# a relation asked for, and the edge relations that come close to it (weight)
_CLOSE = {
    "on": {"in": 0.8, "above": 0.6},
    "in": {"on": 0.8},
    "above": {"on": 0.8},
    "below": {"under": 0.8},
    "under": {"below": 0.8},
    "next to": {"on": 0.5, "under": 0.5, "above": 0.5, "below": 0.5, "in": 0.5, "attached to": 0.5},
    "attached to": {"on": 0.6},
}
_ROOM_PREPOSITIONS = ("in", "inside", "at", "of", "within", "from")


@dataclass
class ParsedQuery:
    """The terms found in a query: ``target`` (object term or "*" for any object, None for a room-only
    query), ``relation`` (canonical, read "target relation anchor") and ``anchor``, ``room`` (a room type) or
    ``room_id``, ``floor``; ``ignored``: the words that are no term."""

    text: str
    target: str | None = None
    relation: str | None = None
    anchor: str | None = None
    room: str | None = None
    room_id: int | None = None
    floor: int | None = None
    ignored: list[str] = field(default_factory=list)

    def describe(self) -> str:
        parts = []
        if self.target:
            parts.append("any object" if self.target == "*" else f"object {self.target!r}")
        if self.relation:
            parts.append(f"{self.relation} {'any object' if self.anchor == '*' else repr(self.anchor)}")
        if self.room:
            parts.append(f"in a {self.room}")
        if self.room_id is not None:
            parts.append(f"in room #{self.room_id}")
        if self.floor is not None:
            parts.append(f"on floor {self.floor}")
        return ", ".join(parts)

    def to_dict(self) -> dict:
        return {
            k: getattr(self, k)
            for k in ("target", "relation", "anchor", "room", "room_id", "floor", "ignored")
        }


@dataclass
class QueryHit:
    """One result: a node (``kind`` "object") or a room (``kind`` "room"), its score in (0, 1] and why it
    matched."""

    kind: str
    id: int
    score: float
    reason: str
    node: Any = field(repr=False, default=None)

    def to_dict(self) -> dict:
        n = self.node
        out = {
            "kind": self.kind,
            "id": int(self.id),
            "score": round(float(self.score), 4),
            "reason": self.reason,
        }
        if self.kind == "object" and n is not None:
            out.update(tag=n.tag, caption=n.caption, center=[float(v) for v in n.center])
        elif n is not None:
            out.update(type=n.type, floor=int(n.floor), center=[float(v) for v in n.center])
        return out


@dataclass
class QueryAnswer:
    """A query's ranked hits, best first; ``message``: why there is no hit, or what the answer could not use
    ("" when nothing to say); ``source``: "offline" or "llm"."""

    text: str
    hits: list[QueryHit]
    message: str = ""
    parsed: ParsedQuery | None = None
    source: str = "offline"

    def to_dict(self) -> dict:
        return {
            "query": self.text,
            "source": self.source,
            "message": self.message,
            "parsed": self.parsed.to_dict() if self.parsed is not None else None,
            "hits": [h.to_dict() for h in self.hits],
        }


@dataclass
class QueryContext:
    """What a query reads of a scene graph: its nodes, edges, rooms, the room of each object node, the up
    vector, and ``term_scores(term) -> {node id: score}`` (tag / caption matching, and embeddings when
    configured)."""

    nodes: dict[int, SceneNode]
    edges: dict[tuple[int, int], SceneEdge]
    rooms: dict[int, RoomNode]
    object_room: dict[int, int]
    up: np.ndarray
    term_scores: Callable[[str], dict[int, float]]


# --------------------------------------------------------------------------------------- parsing

_ROOM_PHRASES = tuple(sorted({*ROOM_TYPE_CUES, *ROOM_SYNONYMS}, key=lambda w: -len(w.split())))


def _normalize(text: str) -> list[str]:
    t = str(text).lower().replace("'s", " ").replace("-", " ")
    return re.sub(r"[^a-z0-9# ]+", " ", t).split()


def _singular(word: str, terms: set[str]) -> str | None:
    for cut in ("es", "s"):
        if word.endswith(cut) and word[: -len(cut)] in terms:
            return word[: -len(cut)]
    return None


def _items(words: list[str], objects: set[str]) -> tuple[list[tuple[str, Any]], list[str]]:
    """The query's words as a sequence of (kind, value): "object", "room", "room_id", "floor", "relation"
    ((relation, swapped, phrase)); and the words that are no term."""
    multi_obj = sorted((t for t in objects if " " in t), key=lambda w: -len(w.split()))
    items: list[tuple[str, Any]] = []
    ignored: list[str] = []
    i = 0
    while i < len(words):
        rest = words[i:]

        def starts(phrase: str, rest: list[str] = rest) -> int:
            p = phrase.split()
            return len(p) if rest[: len(p)] == p else 0

        if (
            len(rest) > 1
            and rest[0] in ("room", "floor", "storey", "level")
            and rest[1].lstrip("#").isdigit()
        ):
            items.append(("room_id" if rest[0] == "room" else "floor", int(rest[1].lstrip("#"))))
            i += 2
            continue
        if starts("ground floor"):
            items.append(("floor", 0))
            i += 2
            continue
        best: tuple[int, str, Any] = (0, "", None)
        for phrase in _ROOM_PHRASES:
            n = starts(phrase)
            if n > best[0]:
                best = (n, "room", room_type_of(phrase))
        for phrase in multi_obj:
            n = starts(phrase)
            if n > best[0]:
                best = (n, "object", phrase)
        word = rest[0]
        if best[0] < 1 and (word in objects or _singular(word, objects)):
            best = (1, "object", word if word in objects else _singular(word, objects))
        if best[0] < 1 and word in WILDCARDS:
            best = (1, "object", "*")
        for phrase in RELATION_PHRASES:
            n = starts(phrase)
            if n > best[0]:
                rel = normalize_relation(phrase)
                if rel is not None:
                    best = (n, "relation", (rel[0], rel[1], phrase))
        if best[0]:
            items.append((best[1], best[2]))
            i += best[0]
            continue
        if word not in FILLERS:
            ignored.append(word)
            items.append(("unknown", word))
        i += 1
    return items, ignored


def parse_query(text: str, objects: set[str]) -> ParsedQuery | str:
    """Read ``text`` with the object terms ``objects`` (normalised): the :class:`ParsedQuery`, or a message
    saying why it holds no term."""
    words = _normalize(text)
    q = ParsedQuery(text=str(text))
    if not words:
        return "the query is empty"
    items, q.ignored = _items(words, objects)
    pending_rel: tuple[str, bool, str] | None = None
    objs: list[tuple[str, tuple[str, bool, str] | None]] = []  # (term, relation phrase before it)
    unknown_target: str | None = None  # a word that is no term where the target would stand
    seen_term = False
    for kind, value in items:
        if kind == "unknown":
            if not seen_term and unknown_target is None:
                unknown_target = value
            continue
        seen_term = True
        if kind == "room":
            if q.room is None:
                q.room = value
            pending_rel = None  # "in" before a room is the room's preposition, not a relation
        elif kind == "room_id":
            q.room_id = value
            pending_rel = None
        elif kind == "floor":
            q.floor = value
            pending_rel = None
        elif kind == "relation":
            pending_rel = value
        else:
            objs.append((value, pending_rel))
            pending_rel = None
    if objs and objs[0][1] is not None:  # "on the table": anything on the table; "toilet next to the
        # trash can" without a toilet term: the unknown word, which nothing in the map matches
        objs.insert(0, (unknown_target or "*", None))
    if objs:
        q.target = objs[0][0]
    if len(objs) > 1:
        rel = objs[1][1]
        if rel is None:  # two objects without a relation between them: "table chair" -> the first
            q.ignored.append(objs[1][0])
        else:
            name, swapped, _ = rel
            q.relation, q.anchor = name, objs[1][0]
            if swapped:  # "the shelf that holds a book": the book in the shelf -> inverse of "in" is kept
                q.relation = _INVERSE.get(name, name)
        q.ignored += [o for o, _ in objs[2:]]
    if (
        q.target is None
        and unknown_target is not None
        and (q.room or q.room_id is not None or q.floor is not None)
    ):
        q.target = unknown_target  # "toilet in the bathroom" without a toilet term: not the bathroom itself
    if q.target is None and q.room is None and q.room_id is None:
        return f"no known object, relation or room term in {text!r}"
    return q


# --------------------------------------------------------------------------------------- ranking


def _up_box(node: SceneNode, up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The node's box as ([h_lo, e1_lo, e2_lo], [h_hi, e1_hi, e2_hi]) in (up, e1, e2) coordinates."""
    e1, e2 = horizontal_basis(up)
    lo, hi = np.asarray(node.bbox_min, float), np.asarray(node.bbox_max, float)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    c = corners @ np.stack([up, e1, e2], axis=1)
    return c.min(0), c.max(0)


def _box_relation(a: SceneNode, b: SceneNode, relation: str, up: np.ndarray) -> float:
    """Whether "a relation b" holds for the nodes' boxes (no edge between them): 0.4-0.7, or 0; "on" and "next
    to" weigh less as the boxes lie farther apart (of two candidates, the closer answers first)."""
    (alo, ahi), (blo, bhi) = _up_box(a, up), _up_box(b, up)
    gap = np.maximum(np.maximum(alo[1:] - bhi[1:], blo[1:] - ahi[1:]), 0.0)
    overlap = bool(np.all(gap <= 0.1))  # boxes of mapped Gaussians fall a little short of the surfaces
    if relation == "on":
        # a's bottom near b's top (b's box may reach higher: what else stands on it), a above b's middle
        lift = float(alo[0] - bhi[0])
        above = (alo[0] + ahi[0]) / 2 > (blo[0] + bhi[0]) / 2
        return 0.7 - min(abs(lift), 0.3) if overlap and above and -0.3 <= lift <= 0.1 else 0.0
    if relation in ("under", "below"):
        return 0.6 if overlap and ahi[0] <= blo[0] + 0.1 else 0.0
    if relation == "above":
        return 0.6 if overlap and alo[0] >= bhi[0] - 0.05 else 0.0
    if relation == "in":
        c = (alo + ahi) / 2
        return 0.6 if bool(np.all((c >= blo) & (c <= bhi))) else 0.0
    if relation == "next to":
        vertical = alo[0] < bhi[0] and blo[0] < ahi[0]
        d = float(np.linalg.norm(gap))
        return 0.7 - 0.6 * d if vertical and d < 0.5 else 0.0
    if relation == "attached to":
        return 0.5 if float(np.linalg.norm(gap)) < 0.05 else 0.0
    return 0.0


def _edge_relation(ctx: QueryContext, a: int, b: int, relation: str) -> tuple[float, str]:
    """How well the graph's edge between ``a`` and ``b`` says "a relation b": (weight, the edge as text)."""
    e = ctx.edges.get((min(a, b), max(a, b)))
    if e is None:
        return 0.0, ""
    forward = (
        e.relation
        if e.source == a
        else _INVERSE.get(e.relation, "" if e.relation != "next to" else "next to")
    )
    text = f"edge '{e.relation}'"
    if forward == relation or (relation == "next to" and e.relation == "next to"):
        return 1.0, text
    return _CLOSE.get(relation, {}).get(forward, 0.0), text


def _room_text(r: RoomNode) -> str:
    return f"room #{r.id} '{r.type}'"


def _room_reason(r: RoomNode) -> str:
    return f"{_room_text(r)} ({r.type_source or 'no'} type: {r.type_reason})"


def _room_weights(q: ParsedQuery, ctx: QueryContext, notes: list[str]) -> dict[int, tuple[float, str]] | None:
    """{room id: (weight, why)} of the rooms a query's room terms ask for (None: no room term, or no room
    the terms could mean). A room typed as asked weighs 1; when none is, an untyped room ("room": its
    objects named no type) weighs 0.6 to 1 by how much its objects point to the type asked for; a room typed
    otherwise whose objects point to it too 0.4 (0.25 beside a room typed as asked); any other 0.15."""
    if q.room is None and q.room_id is None and q.floor is None:
        return None
    place = [
        r
        for r in ctx.rooms.values()
        if (q.room_id is None or r.id == q.room_id) and (q.floor is None or r.floor == q.floor)
    ]
    have = ", ".join(sorted({f"{r.type} (#{r.id})" for r in ctx.rooms.values()})) or "none yet"
    if not place:
        notes.append(f"no room {q.describe().split(', ')[-1]} in the map (rooms: {have}); rooms not used")
        return None
    out = {r.id: (0.15, "") for r in ctx.rooms.values()}
    if q.room is None:
        out.update({r.id: (1.0, "") for r in place})
        return out
    cue = {r.id: r.type_scores.get(q.room, 0.0) for r in place}
    typed = [r for r in place if r.type == q.room]
    untyped = [r for r in place if r.type == UNKNOWN_ROOM]
    best = max((cue[r.id] for r in untyped), default=0.0)
    for r in place:
        if r.type == q.room:
            out[r.id] = (1.0, "")
        elif r.type == UNKNOWN_ROOM and not typed:
            out[r.id] = (
                0.6 + 0.4 * (cue[r.id] / best if best > 0 else 0.0),
                f", untyped, maybe the {q.room}",
            )
        elif r.type == UNKNOWN_ROOM:
            out[r.id] = (0.4 if cue[r.id] > 0 else 0.3, ", untyped")
        elif cue[r.id] > 0:
            out[r.id] = (0.25 if typed else 0.4, f", which holds {q.room} objects too")
    if not typed:
        notes.append(f"no room typed {q.room!r} in the map (rooms: {have}): untyped rooms and rooms holding "
                     f"{q.room} objects answer instead")  # fmt: skip
    return out


def rank(q: ParsedQuery, ctx: QueryContext, top_k: int | None = None) -> QueryAnswer:
    """Score every node against a parsed query (see the module docstring)."""
    up = unit_up(ctx.up)
    notes: list[str] = []
    if q.ignored:
        notes.append(f"ignored: {', '.join(q.ignored)}")
    weights = _room_weights(q, ctx, notes)
    if q.target is None:  # a room query: the rooms, best first
        w = weights or {}
        hits = [
            QueryHit("room", i, w[i][0], _room_reason(ctx.rooms[i]), ctx.rooms[i])
            for i in sorted(w, key=lambda i: (-w[i][0], i))
            if w[i][0] > 0.15
        ]
        return QueryAnswer(q.text, hits[:top_k], "; ".join(notes), q)

    def scores(term: str) -> dict[int, float]:
        if term == "*":
            return {i: 0.5 for i in ctx.nodes}
        return {i: s for i, s in ctx.term_scores(term).items() if i in ctx.nodes and s > 0}

    def room_factor(i: int) -> tuple[float, str]:
        rid = ctx.object_room.get(i)
        room = ctx.rooms.get(rid) if rid is not None else None
        if weights is None:
            return 1.0, (f"in {_room_text(room)}" if room is not None else "")
        if room is None:
            return 0.35, "in no room"
        w, why = weights.get(rid, (0.15, ""))
        return w, f"in {_room_text(room)}{why}" if w >= 0.15 else f"but in {_room_text(room)}"

    targets = scores(q.target)
    if not targets:
        notes.insert(0, f"nothing in the map matches {q.target!r}")
        return QueryAnswer(q.text, [], "; ".join(notes), q)
    anchors: dict[int, float] = {}
    if q.relation is not None:
        anchors = scores(q.anchor or "*")
        if not anchors:
            notes.append(f"nothing in the map matches {q.anchor!r}: the relation is not used")
    hits = []
    for i, ts in targets.items():
        node = ctx.nodes[i]
        why = [f"tag {node.tag!r}" if node.tag else f"caption {node.caption[:40]!r}"]
        score = ts
        if anchors:
            best, best_why = 0.0, "no anchor related"
            for a, s_a in anchors.items():
                if a == i:
                    continue
                w, text = _edge_relation(ctx, i, a, q.relation)
                if w == 0.0:
                    w, text = _box_relation(node, ctx.nodes[a], q.relation, up), "boxes"
                w *= s_a * (room_factor(a)[0] if weights is not None else 1.0)
                if w > best:
                    best, best_why = w, f"{q.relation} #{a} {ctx.nodes[a].tag!r} ({text})"
            score *= 0.25 + 0.75 * best
            why.append(best_why)
        f, text = room_factor(i)
        score *= f
        if text:
            why.append(text)
        hits.append(QueryHit("object", i, float(score), "; ".join(why), node))
    # of nodes that answer alike, the larger first: more likely the object than a fragment named so
    hits.sort(key=lambda h: (-round(h.score, 6), -int(h.node.num_gaussians), h.id))
    return QueryAnswer(q.text, hits[:top_k] if top_k else hits, "; ".join(notes), q)


def answer_offline(text: str, ctx: QueryContext, top_k: int | None = None) -> QueryAnswer:
    """Parse and rank ``text`` offline (never raises on a bad query: the answer carries the message)."""
    parsed = parse_query(text, known_terms(n.tag for n in ctx.nodes.values()))
    if isinstance(parsed, str):
        tags = sorted({n.tag for n in ctx.nodes.values() if n.tag})
        shown = ", ".join(tags[:12]) + (", ..." if len(tags) > 12 else "")
        rooms = sorted({r.type for r in ctx.rooms.values() if r.type != UNKNOWN_ROOM})
        hint = f" (objects in this map: {shown or 'none yet'}" + (
            f"; rooms: {', '.join(rooms)})" if rooms else ")"
        )
        return QueryAnswer(str(text), [], parsed + ("" if parsed == "the query is empty" else hint), None)
    return rank(parsed, ctx, top_k)


# --------------------------------------------------------------------------------------- the LLM path

QUERY_SYSTEM_PROMPT = (
    "You answer queries about an indoor 3D scene graph: objects with a tag and the room they are in, spatial "
    "relations between objects, and rooms with a type. Pick the objects (or rooms) the query asks for."
)


def compact_graph(ctx: QueryContext, max_nodes: int = 500) -> dict:
    """The graph as the LLM sees it: objects {id, tag, room}, relations [subject, relation, object], rooms
    {id, type, floor}; at most ``max_nodes`` objects (the largest first)."""
    order = sorted(ctx.nodes.values(), key=lambda n: (-int(n.num_gaussians), n.id))[:max_nodes]
    keep = {n.id for n in order}
    return {
        "objects": [
            {"id": n.id, "tag": n.tag or "object", "room": ctx.object_room.get(n.id)}
            for n in sorted(order, key=lambda n: n.id)
        ],
        "relations": [
            [e.source, e.relation, e.target]
            for e in ctx.edges.values()
            if e.source in keep and e.target in keep
        ],
        "rooms": [
            {"id": r.id, "type": r.type, "floor": r.floor}
            for r in sorted(ctx.rooms.values(), key=lambda r: r.id)
        ],
    }


def query_prompt(text: str, ctx: QueryContext, max_nodes: int = 500) -> str:
    return "\n".join(
        [
            "Scene graph (JSON):",
            json.dumps(compact_graph(ctx, max_nodes), separators=(",", ":")),
            "",
            f"Query: {json.dumps(str(text))}",
            'Answer with JSON only: {"ids": [<object ids, best match first>], "rooms": [<room ids, only when '
            'the query asks for a room>], "reason": "<a few words>"}. Use only ids from the graph; empty '
            "lists when nothing matches.",
        ]
    )


def _ids(value: Any) -> list[int] | None:
    """A reply's id list as ints (None when it is not a list of integers)."""
    if value is None:
        return []
    if not isinstance(value, list):
        return None
    out = []
    for v in value:
        if isinstance(v, bool):
            return None
        if isinstance(v, int):
            out.append(v)
        elif isinstance(v, float) and v.is_integer():
            out.append(int(v))
        elif isinstance(v, str) and v.strip().lstrip("#").isdigit():
            out.append(int(v.strip().lstrip("#")))
        else:
            return None
    return out


def parse_query_reply(reply: str, ctx: QueryContext, text: str) -> QueryAnswer | str:
    """Validate an LLM reply against the graph: the answer, or what is wrong with the reply."""
    try:
        data = extract_json(reply)
    except ValueError as e:
        return str(e)
    if not isinstance(data, dict):
        return "the reply is not a JSON object"
    ids, rooms = _ids(data.get("ids")), _ids(data.get("rooms"))
    if ids is None or rooms is None:
        return f"'ids' / 'rooms' must be lists of integers, got {data.get('ids')!r} / {data.get('rooms')!r}"
    reason = str(data.get("reason", "")).strip()[:200] or "chosen by the LLM"
    unknown = [i for i in ids if i not in ctx.nodes] + [i for i in rooms if i not in ctx.rooms]
    hits: list[QueryHit] = []
    seen: set[tuple[str, int]] = set()
    for kind, pool, values in (("object", ctx.nodes, ids), ("room", ctx.rooms, rooms)):
        for i in values:
            if i in pool and (kind, i) not in seen:
                seen.add((kind, i))
                hits.append(QueryHit(kind, i, 1.0 / (1 + len(hits)), f"LLM: {reason}", pool[i]))
    if not hits and (ids or rooms):
        return f"none of the ids {ids + rooms} is in the graph"
    msg = f"the LLM named ids that are not in the graph: {unknown}" if unknown else ""
    if not hits:
        msg = f"the LLM found nothing for this query ({reason})"
    return QueryAnswer(text, hits, msg, None, "llm")


class LLMQuery:
    """Queries answered by a language model at an OpenAI-compatible endpoint (see the module docstring)."""

    def __init__(self, client, max_tokens: int = 500, max_nodes: int = 500) -> None:
        self.client = client
        self.max_tokens = max_tokens
        self.max_nodes = max_nodes

    @classmethod
    def from_config(cls, config: QueryConfig, endpoint: EndpointConfig | None = None) -> LLMQuery:
        """From ``graph.query`` and the endpoint it calls (``graph.endpoint``; None: the defaults)."""
        client = ChatClient.from_config(endpoint or EndpointConfig(), config.model, "graph.query.model")
        return cls(client, config.max_tokens, config.max_nodes)

    def answer(self, text: str, ctx: QueryContext, top_k: int | None = None) -> QueryAnswer:
        if not str(text).strip():
            return QueryAnswer(str(text), [], "the query is empty", None, "llm")
        try:
            reply = self.client.chat(
                [
                    {"role": "system", "content": QUERY_SYSTEM_PROMPT},
                    {"role": "user", "content": query_prompt(text, ctx, self.max_nodes)},
                ],
                max_tokens=self.max_tokens,
            )
            out = parse_query_reply(reply, ctx, str(text))
        except Exception as e:  # the endpoint failed: answer offline
            out = f"the request failed ({e})"
        if isinstance(out, str):
            log.warning("query LLM: %s; answering offline", out)
            offline = answer_offline(text, ctx, top_k)
            offline.message = "; ".join(
                m for m in (f"LLM answer unusable: {out}; offline answer", offline.message) if m
            )
            return offline
        out.hits = out.hits[:top_k] if top_k else out.hits
        return out
