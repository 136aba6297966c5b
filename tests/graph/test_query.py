"""Queries over objects, relations and rooms: the offline parser, the ranking with its reasons, bad queries,
``ogscene3d graph -q --json``, and the LLM path end to end against a local fake endpoint."""

import contextlib
import json

import numpy as np
import pytest
from fake_llm import FakeServer
from graph_scenes import box_surface, to_world

from ogscene3d.cli import main
from ogscene3d.config import GraphConfig
from ogscene3d.graph import MeanConfidence, SceneEdge, SceneGraph, SceneNode
from ogscene3d.graph.captioner import HeuristicCaptioner
from ogscene3d.graph.query import parse_query
from ogscene3d.graph.rooms import RoomNode
from ogscene3d.graph.terms import known_terms

UP = (0.0, -1.0, 0.0)
OBJECTS = known_terms(["pillow", "bed", "chair", "table", "cup", "sofa", "book", "bookshelf", "trash can"])


@pytest.mark.parametrize(
    "text,want",
    [
        ("pillow on the bed", dict(target="pillow", relation="on", anchor="bed")),
        ("chair in the kitchen", dict(target="chair", room="kitchen", relation=None)),
        (
            "the mug on the desk in the office",
            dict(target="mug", relation="on", anchor="desk", room="office"),
        ),
        ("Is there a chair in the kitchen?", dict(target="chair", room="kitchen")),
        ("book in the bookshelf", dict(target="book", relation="in", anchor="bookshelf")),
        ("books inside the shelf", dict(target="books", relation="in", anchor="shelf")),
        ("something on the table", dict(target="*", relation="on", anchor="table")),
        ("on the table", dict(target="*", relation="on", anchor="table")),
        ("trash can next to the sofa", dict(target="trash can", relation="next to", anchor="sofa")),
        (
            "cup beside the couch in the lounge",
            dict(target="cup", relation="next to", anchor="couch", room="living room"),
        ),
        ("kitchen", dict(target=None, room="kitchen")),
        ("chair in room 2", dict(target="chair", room_id=2)),
        ("blue chair", dict(target="chair", ignored=["blue"])),
        ("the table that holds a cup", dict(target="table", relation="under", anchor="cup")),
        ("piano next to the sofa", dict(target="piano", relation="next to", anchor="sofa")),  # no such term
        ("piano in the kitchen", dict(target="piano", room="kitchen")),  # not the kitchen itself
        ("kitchen area", dict(target=None, room="kitchen", ignored=["area"])),
    ],
)
def test_parser_reads_objects_relations_and_rooms(text, want):
    q = parse_query(text, OBJECTS)
    assert not isinstance(q, str), q
    for k, v in want.items():
        assert getattr(q, k) == v, (text, k, getattr(q, k))


@pytest.mark.parametrize("text", ["", "   ", "?!", "xyzzy plugh", "the and of"])
def test_parser_names_what_is_wrong_with_a_bad_query(text):
    msg = parse_query(text, OBJECTS)
    assert isinstance(msg, str) and ("empty" in msg or "no known object, relation or room term" in msg)


def _node(i, lo, hi, tag, rng, room=None):
    n = SceneNode.from_points(i, to_world(box_surface(lo, hi, rng, 3000.0), UP))
    n.tag, n.caption, n.room = tag, f"a {tag}", room
    return n


def _room(i, kind, lo, hi):
    corners = to_world(
        np.array([[lo[0], lo[1], 0], [hi[0], lo[1], 0], [hi[0], hi[1], 0], [lo[0], hi[1], 0]]), UP
    )
    c = corners.mean(0)
    return RoomNode(i, 0, [corners], (hi[0] - lo[0]) * (hi[1] - lo[1]), c, corners.min(0), corners.max(0),
                    type=kind, type_source="rule", type_reason="test")  # fmt: skip


def apartment_graph() -> SceneGraph:
    """A bedroom (room 1: bed with a pillow, a chair) and a living room (room 2: sofa with a pillow, a table
    with a cup, a chair), with the edges a graph update would make (the chair next to the table has none)."""
    rng = np.random.default_rng(0)
    g = SceneGraph(GraphConfig(), captioner=HeuristicCaptioner(), node_confidence=MeanConfidence())
    nodes = [
        _node(1, [0.2, 0.2, 0.0], [1.8, 2.2, 0.5], "bed", rng, 1),
        _node(2, [0.6, 1.6, 0.5], [1.0, 1.8, 0.8], "pillow", rng, 1),
        _node(3, [3.0, 0.2, 0.0], [3.45, 0.65, 0.9], "chair", rng, 1),
        _node(4, [4.3, 0.2, 0.0], [6.3, 1.0, 0.85], "sofa", rng, 2),
        _node(5, [5.0, 0.5, 0.42], [5.4, 0.65, 0.76], "pillow", rng, 2),
        _node(6, [5.0, 2.5, 0.0], [6.2, 3.3, 0.75], "table", rng, 2),
        _node(7, [5.5, 2.8, 0.75], [5.58, 2.88, 0.85], "cup", rng, 2),
        _node(8, [6.3, 2.6, 0.0], [6.75, 3.05, 0.9], "chair", rng, 2),
    ]
    for n in nodes:
        g.nodes[n.id] = n
    for s, t, r in ((2, 1, "on"), (5, 4, "on"), (7, 6, "on"), (1, 3, "next to")):
        g.edges[(min(s, t), max(s, t))] = SceneEdge(s, t, r, 0.5)
    g.room_map.rooms = {1: _room(1, "bedroom", (0, 0), (4, 4)), 2: _room(2, "living room", (4.1, 0), (8, 4))}
    return g


def test_relation_and_room_decide_between_nodes_with_the_same_tag():
    g = apartment_graph()
    a = g.ask("pillow on the bed")
    assert [h.id for h in a.hits][:2] == [2, 5] and a.hits[0].score > 2 * a.hits[1].score
    assert "on #1 'bed' (edge 'on')" in a.hits[0].reason and "room #1 'bedroom'" in a.hits[0].reason
    assert g.ask("pillow on the sofa").hits[0].id == 5
    assert g.ask("pillow on the couch").hits[0].id == 5  # synonym of the anchor
    assert g.ask("chair in the bedroom").hits[0].id == 3
    assert g.ask("chair in the living room").hits[0].id == 8
    a = g.ask("the mug on the table in the lounge")
    assert a.hits[0].id == 7 and "tag 'cup'" in a.hits[0].reason
    # no edge between the chair and the table: their boxes say "next to"
    a = g.ask("chair next to the table")
    assert a.hits[0].id == 8 and "(boxes)" in a.hits[0].reason
    # the inverse: "the table under the cup"
    assert g.ask("table under the cup").hits[0].id == 6
    assert g.query("pillow on the bed")[0].id == 2 and g.query_scored("cup")[0][0].id == 7


def test_room_queries_and_what_the_answer_cannot_use():
    g = apartment_graph()
    a = g.ask("bedroom")
    assert [(h.kind, h.id) for h in a.hits] == [("room", 1)]
    a = g.ask("chair in the kitchen")  # no kitchen: the chairs, and a message saying so
    assert {h.id for h in a.hits} == {3, 8} and "no room" in a.message and "kitchen" in a.message
    a = g.ask("pillow on the piano")  # an unknown anchor word: ignored, said so
    assert a.hits[0].kind == "object" and "piano" in a.message
    a = g.ask("lamp on the table")  # a known term nothing in the map matches
    assert a.hits == [] and "nothing in the map matches 'lamp'" in a.message
    for bad in ("", "  ", "xyzzy"):
        a = g.ask(bad)
        assert a.hits == [] and a.message
    assert "objects in this map: bed, chair, cup" in g.ask("xyzzy").message
    assert g.ask("#4").hits[0].id == 4 and g.ask("#99").hits == []


def test_graph_command_prints_reasons_and_json(tmp_path, capsys):
    g = apartment_graph()
    g.save(tmp_path / "graph.json")
    assert main(["graph", str(tmp_path), "-q", "pillow on the bed", "-q", "xyzzy", "--rooms"]) == 0
    out = capsys.readouterr().out
    assert "query 'pillow on the bed': 2 match(es)" in out and "#2 'pillow'" in out and "edge 'on'" in out
    assert "note: no known object, relation or room term in 'xyzzy'" in out
    assert "room #1 'bedroom'" in out
    assert main(["graph", str(tmp_path), "-q", "chair in the living room", "--json", "--top-k", "1"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc[0]["hits"][0]["id"] == 8 and doc[0]["parsed"]["room"] == "living room"
    assert set(doc[0]["hits"][0]) >= {"kind", "id", "score", "reason", "tag", "center"}


@pytest.fixture
def fake_llm():
    """``make(respond)`` -> a running :class:`FakeServer` (helpers/fake_llm.py), closed after the test."""
    with contextlib.ExitStack() as stack:

        def make(respond):
            server = FakeServer(respond)
            stack.callback(server.close)
            return server

        yield make


def _llm_graph(url) -> SceneGraph:
    g = apartment_graph()
    cfg = GraphConfig()
    cfg.query.kind, cfg.endpoint.base_url, cfg.query.model, cfg.endpoint.api_key_env = "llm", url, "m", ""
    cfg.endpoint.max_retries = 0
    h = SceneGraph.from_json(g.to_json(), cfg)
    return h


def test_llm_query_end_to_end_and_reply_validation(fake_llm):
    replies = iter(
        [
            '```json\n{"ids": [5, 2], "reason": "pillows on seats"}\n```',
            '{"ids": [99, 2], "reason": "x"}',  # an id that is not in the graph is dropped, said so
            '{"ids": [], "rooms": [1], "reason": "the bedroom"}',
            "I think it is the pillow.",  # no JSON: the offline answer
            '{"ids": ["a"]}',  # not integers: the offline answer
            '{"ids": [123]}',  # no valid id: the offline answer
        ]
    )
    srv = fake_llm(lambda body, n: (200, next(replies), 0))
    g = _llm_graph(srv.base_url)
    a = g.ask("pillow on the sofa")
    assert a.source == "llm" and [h.id for h in a.hits] == [5, 2] and "pillows on seats" in a.hits[0].reason
    prompt = srv.requests[0]["body"]["messages"][-1]["content"]
    graph = json.loads(prompt.split("\n")[1])
    assert {"id": 5, "tag": "pillow", "room": 2} in graph["objects"] and [5, "on", 4] in graph["relations"]
    assert {"id": 1, "type": "bedroom", "floor": 0} in graph["rooms"] and '"pillow on the sofa"' in prompt
    a = g.ask("pillow")
    assert [h.id for h in a.hits] == [2] and "99" in a.message
    assert [(h.kind, h.id) for h in g.ask("where do I sleep").hits] == [("room", 1)]
    for _ in range(3):
        a = g.ask("pillow on the bed")
        assert a.source == "offline" and a.hits[0].id == 2 and a.message.startswith("LLM answer unusable")
    srv.close()  # the endpoint is gone: offline, no exception
    a = g.ask("chair in the bedroom")
    assert a.source == "offline" and a.hits[0].id == 3 and "request failed" in a.message


def test_llm_room_types_with_the_rule_as_fallback(fake_llm):
    from ogscene3d.config import EndpointConfig, RoomsConfig
    from ogscene3d.graph.rooms import LLMRoomTyper

    replies = iter(['{"type": "Study", "reason": "a desk"}', '{"type": "garage"}', '{"type": "room"}'])
    srv = fake_llm(lambda body, n: (200, next(replies), 0))
    cfg = RoomsConfig(typer="llm", model="m")
    t = LLMRoomTyper.from_config(cfg, EndpointConfig(base_url=srv.base_url, api_key_env=""))
    assert t.describe_with_source(["desk", "chair"]) == ("office", "a desk", "llm")
    assert t.describe_with_source(["desk", "chair"])[2] == "llm" and len(srv.requests) == 1  # cached
    kind, _, source = t.describe_with_source(["bed", "pillow"])  # "garage": the rule answers
    assert (kind, source) == ("bedroom", "rule")
    assert t.describe_with_source(["plant"]) == ("room", "", "llm")
    assert len(srv.requests) == 3 and '"bed"' in srv.requests[1]["body"]["messages"][0]["content"]


def test_graph_command_answers_through_the_configured_endpoint(fake_llm, tmp_path, capsys):
    srv = fake_llm(lambda body, n: (200, '{"ids": [8], "reason": "the living room chair"}', 0))
    apartment_graph().save(tmp_path / "graph.json")
    argv = ["graph", str(tmp_path), "-q", "chair where I watch TV", "--json", "--set", "graph.query.kind=llm",
            "--set", f"graph.endpoint.base_url={srv.base_url}", "--set", "graph.query.model=m"]  # fmt: skip
    assert main(argv) == 0
    (answer,) = json.loads(capsys.readouterr().out)
    assert answer["source"] == "llm" and answer["hits"][0]["id"] == 8
    assert "the living room chair" in answer["hits"][0]["reason"] and len(srv.requests) == 1


def test_a_room_type_no_room_has_goes_to_the_untyped_rooms_first():
    g = apartment_graph()
    office = _room(3, "room", (8.1, 0), (11, 4))
    office.type_reason, office.type_scores = "too few cues (monitor)", {"office": 0.5}
    g.room_map.rooms[3] = office
    g.room_map.rooms[2].type_scores = {"living room": 5.0, "office": 0.3}  # a stray cue in the living room
    chair = _node(9, [9.0, 1.0, 0.0], [9.45, 1.45, 0.9], "chair", np.random.default_rng(1), 3)
    g.nodes[9] = chair
    a = g.ask("chair in the office")
    assert a.hits[0].id == 9 and "untyped, maybe the office" in a.hits[0].reason
    assert "no room typed 'office'" in a.message
    assert [h.id for h in g.ask("office").hits] == [3, 2]  # the untyped room, then the cued one
    assert g.ask("chair in the bedroom").hits[0].id == 3  # a typed room still comes first


def test_synonyms_name_whole_tags_only():
    from ogscene3d.graph.terms import text_score

    assert text_score("sofa", "couch", "") == pytest.approx(0.9) and text_score("lamp", "light", "") == 0.9
    assert text_score("lamp", "light switch", "") == 0.0  # "light" is a lamp, a light switch is not
    assert text_score("lamp", "gray object", "small light gray object") == 0.0
    assert text_score("lamp", "floor lamp", "") == 0.9 and text_score("cup", "cups", "") == 0.9
    assert text_score("cushion", "thing", "a sofa with two cushions") == 0.6
    g = apartment_graph()
    a = g.ask("piano next to the sofa")  # not "anything next to the sofa"
    assert a.hits == [] and "nothing in the map matches 'piano'" in a.message
