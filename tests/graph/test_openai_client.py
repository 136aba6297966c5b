"""OpenAI-compatible endpoints against a real HTTP server on 127.0.0.1 (no network beyond loopback).

Covers: ONE batched chat-completions call for all candidate edges, the edge / caption / tag prompt
contents, parsing of good and malformed replies with geometric fallback, timeouts, retries with backoff,
non-retried client errors, and that the API key is sent but never logged or written.
"""

import base64
import json
import logging
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import cv2
import numpy as np
import pytest
from fake_llm import FakeServer
from graph_scenes import box_surface, plane, table, to_world

from ogscene3d import Frame
from ogscene3d.config import EndpointConfig, GraphConfig, RelationsConfig
from ogscene3d.errors import ModelError
from ogscene3d.graph import (
    ChatClient,
    GeometricRelations,
    LLMRelations,
    MeanConfidence,
    OpenAICaptioner,
    SceneGraph,
    SceneNode,
)
from ogscene3d.graph.openai_client import EndpointUnreachable

UP = (0.0, -1.0, 0.0)
SECRET = "sk-test-DO-NOT-LEAK-123456"


@pytest.fixture
def server_factory():
    servers = []

    def make(respond):
        s = FakeServer(respond)
        servers.append(s)
        return s

    yield make
    for s in servers:
        s.close()


def _client(server, **kw):
    args = dict(api_key_env="OGS_TEST_KEY", timeout_s=2.0, max_retries=2)
    args.update(kw)
    return ChatClient(server.base_url, "test-model", **args)


def _scene():
    """cup on table, picture on wall, chair next to table (tags set as a captioner would)."""
    rng = np.random.default_rng(0)

    def node(i, pts, tag):
        n = SceneNode.from_points(i, to_world(pts, UP))
        n.tag = tag
        return n

    t = node(1, table(rng), "table")
    cup = node(2, box_surface([0.5, 0.35, 0.75], [0.58, 0.43, 0.85], rng), "cup")
    wall = node(3, plane([2.0, -2, 0], [2.0, 2, 2.5], rng), "wall")
    pic = node(4, box_surface([1.96, -0.3, 1.2], [1.99, 0.3, 1.6], rng), "picture")
    chair = node(5, box_surface([1.25, 0.2, 0.0], [1.7, 0.65, 0.9], rng), "chair")
    return [(cup, t), (wall, pic), (t, chair)]


def _edge_reply(entries):
    return json.dumps({"relations": entries})


def test_one_batched_call_for_all_edges_with_synonyms(server_factory, monkeypatch):
    monkeypatch.setenv("OGS_TEST_KEY", SECRET)
    reply = _edge_reply(
        [
            {"pair": 0, "subject": 2, "relation": "resting on", "object": 1},
            {"pair": 1, "subject": 4, "relation": "mounted on", "object": 3},  # reversed w.r.t. the pair
            {"pair": 2, "subject": 1, "relation": "beside", "object": 5},
        ]
    )
    srv = server_factory(lambda body, n: (200, "```json\n" + reply + "\n```", 0))
    pairs = _scene()
    rels = LLMRelations(_client(srv), GeometricRelations(RelationsConfig(), UP), UP).predict(pairs)
    assert len(srv.requests) == 1  # ONE request for all three pairs
    req = srv.requests[0]
    assert req["path"] == "/v1/chat/completions" and req["body"]["model"] == "test-model"
    prompt = req["body"]["messages"][-1]["content"]
    for tag in ("table", "cup", "wall", "picture", "chair"):
        assert f'"{tag}"' in prompt
    for rel in ("on", "under", "above", "below", "next to", "in", "attached to"):
        assert f'"{rel}"' in prompt
    cup, tbl = pairs[0]
    c, v = cup.center, tbl.center - cup.center
    assert f"[{c[0]:.2f}, {c[1]:.2f}, {c[2]:.2f}]" in prompt  # centres
    assert f"vector [{v[0]:.2f}, {v[1]:.2f}, {v[2]:.2f}]" in prompt  # centre-to-centre vector
    assert "[0.00, -1.00, 0.00]" in prompt  # the configured up axis
    assert [(r.source, r.relation, r.target, r.predictor) for r in rels] == [
        (2, "on", 1, "llm"),
        (4, "attached to", 3, "llm"),
        (1, "next to", 5, "llm"),
    ]
    assert srv.headers[0]["Authorization"] == f"Bearer {SECRET}"


def test_malformed_replies_fall_back_per_pair(server_factory, caplog):
    pairs = _scene()
    geo = GeometricRelations(RelationsConfig(), UP)
    expected_geo = geo.predict(pairs)
    # partially good: one unknown relation, one missing pair, one bad index
    reply = _edge_reply(
        [
            {"pair": 0, "subject": 2, "relation": "on top of", "object": 1},
            {"pair": 1, "subject": 4, "relation": "dances with", "object": 3},
            {"pair": 9, "relation": "on"},
            "garbage",
        ]
    )
    srv = server_factory(lambda body, n: (200, reply, 0))
    with caplog.at_level(logging.WARNING):
        rels = LLMRelations(_client(srv), geo, UP).predict(pairs)
    assert len(srv.requests) == 1
    assert (rels[0].relation, rels[0].predictor) == ("on", "llm")
    assert rels[1] == expected_geo[1] and rels[2] == expected_geo[2]
    assert "dances with" in caplog.text and "bad pair index" in caplog.text
    # entirely malformed: not JSON at all -> every pair from geometry, no retry for a bad reply
    srv2 = server_factory(lambda body, n: (200, "Sure! The cup is on the table.", 0))
    rels2 = LLMRelations(_client(srv2), geo, UP).predict(pairs)
    assert rels2 == expected_geo and len(srv2.requests) == 1


def test_timeout_then_success_is_retried(server_factory):
    ok = _edge_reply([{"pair": 0, "subject": 2, "relation": "on", "object": 1}])
    srv = server_factory(lambda body, n: (200, ok, 1.5 if n == 1 else 0))
    client = _client(srv, timeout_s=0.3, max_retries=2)
    rels = LLMRelations(client, GeometricRelations(RelationsConfig(), UP), UP).predict(_scene()[:1])
    assert client.calls == 2 and len(srv.requests) == 2
    assert rels[0].predictor == "llm"


def test_server_errors_retried_then_fallback_and_key_never_logged(server_factory, monkeypatch, caplog):
    monkeypatch.setenv("OGS_TEST_KEY", SECRET)
    srv = server_factory(lambda body, n: (503, '{"error": "overloaded"}', 0))
    client = _client(srv, max_retries=2)
    with caplog.at_level(logging.DEBUG):
        with pytest.raises(ModelError, match="HTTP 503") as exc:
            client.chat([{"role": "user", "content": "hi"}])
        assert len(srv.requests) == 3  # 1 + max_retries
        rels = LLMRelations(client, GeometricRelations(RelationsConfig(), UP), UP).predict(_scene())
    assert all(r.predictor == "geometric" for r in rels)
    assert SECRET not in caplog.text and SECRET not in str(exc.value) and SECRET not in repr(client)
    # 429 with Retry-After is retried; a 400 is a caller error and is not
    seq = iter([(429, "slow down", 0), (200, "fine", 0)])
    srv2 = server_factory(lambda body, n: next(seq))
    assert _client(srv2).chat([{"role": "user", "content": "x"}]) == "fine" and len(srv2.requests) == 2
    srv3 = server_factory(lambda body, n: (400, '{"error": "bad model"}', 0))
    with pytest.raises(ModelError, match="HTTP 400"):
        _client(srv3).chat([{"role": "user", "content": "x"}])
    assert len(srv3.requests) == 1


def test_connection_refused_is_bounded():
    import socket

    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # nothing listens there now
    client = ChatClient(f"http://127.0.0.1:{port}/v1", "m", timeout_s=0.5, max_retries=1)
    with pytest.raises(ModelError, match="connection failed"):
        client.chat([{"role": "user", "content": "x"}])
    assert client.calls == 2


def _caption_responder(fail_captions=False):
    def respond(body, n):
        content = body["messages"][-1]["content"]
        if isinstance(content, list):  # caption request with images
            if fail_captions:
                return 500, "boom", 0
            n_img = sum(1 for p in content if p.get("type") == "image_url")
            return 200, json.dumps({"caption": f"a red box seen in {n_img} images"}), 0
        ids = [line.split(":")[0] for line in content.splitlines() if line[:1].isdigit()]
        return 200, json.dumps({"tags": {i: "red box" for i in ids}}), 0

    return respond


def test_openai_captioner_in_scene_graph(server_factory, tmp_path, monkeypatch):
    monkeypatch.setenv("OGS_TEST_KEY", SECRET)
    srv = server_factory(_caption_responder())
    cap = OpenAICaptioner(_client(srv), concurrency=2)
    out = tmp_path / "graph.json"
    g = SceneGraph(
        GraphConfig(min_obs_pixels=4), captioner=cap, node_confidence=MeanConfidence(), out_path=out
    )
    H, W = 48, 64
    rgb = np.zeros((H, W, 3), np.uint8)
    rgb[..., 0] = 220
    for kf in range(4):
        lm = np.full((H, W), -1, np.int32)
        lm[4 : 12 + 4 * kf, 4 : 20 + 4 * kf] = 0
        lm[30:40, 40:60] = 1
        g.observe(kf, Frame(kf, rgb, np.ones((H, W), np.float32), np.eye(3)), lm)
    rng = np.random.default_rng(0)
    means = np.concatenate(
        [
            rng.uniform(0, 0.3, (100, 3)),
            rng.uniform(0, 0.3, (100, 3)) + [0.3, 0, 0],
            rng.uniform(0, 0.3, (100, 3)) + [0.6, 0, 0],
        ]
    )
    labels = np.repeat(np.array([0, 1, 2], np.int32), 100)
    g.update(11, means, labels, np.full(300, 0.2, np.float32))
    cap_reqs = [r for r in srv.requests if isinstance(r["body"]["messages"][-1]["content"], list)]
    tag_reqs = [r for r in srv.requests if not isinstance(r["body"]["messages"][-1]["content"], list)]
    assert len(cap_reqs) == 2  # nodes 0 and 1 were observed; node 2 never was
    assert len(tag_reqs) == 1  # tags for all captions in ONE call
    parts = cap_reqs[0]["body"]["messages"][-1]["content"]
    assert "masked" in parts[0]["text"] and "context" in parts[0]["text"]
    urls = [p["image_url"]["url"] for p in parts[1:]]
    assert 2 <= len(urls) <= 4 and all(u.startswith("data:image/jpeg;base64,") for u in urls)
    img = cv2.imdecode(np.frombuffer(base64.b64decode(urls[0].split(",", 1)[1]), np.uint8), cv2.IMREAD_COLOR)
    assert img is not None and img.shape[2] == 3 and img[..., 2].mean() > 150  # red survives (BGR)
    assert g.nodes[0].tag == "red box" and g.nodes[0].caption_source == "vlm"
    assert g.nodes[2].caption_source == "heuristic"  # nothing to show the VLM: offline fallback
    before = {i: n.caption for i, n in g.nodes.items()}
    # the endpoint now fails: captions are kept, the update still completes
    srv.respond = _caption_responder(fail_captions=True)
    g.update(23, means, labels, np.full(300, 0.2, np.float32))
    assert {i: n.caption for i, n in g.nodes.items()} == before
    assert SECRET not in out.read_text()


@pytest.mark.parametrize(
    "reply,expected",
    [
        ('{"caption": "a  red\\n mug"}', "a red mug"),
        ('```json\n{"caption": "a lamp"}\n```', "a lamp"),
        ("A wooden chair with four legs.", "A wooden chair with four legs."),  # plain prose accepted
        ('{"description": "no caption key"}', None),
        ('{"caption": 42}', None),
        ("[1, 2]", None),
        ("   ", None),
        ("x" * 2000, None),
        # JSON cut off (max_tokens) is malformed, not prose: no JSON debris stored as a caption
        ('{"caption": "a red wooden ch', None),
        ('```json\n{"caption": "a lamp', None),
        ('Here it is: {"caption": "a lamp with', None),
        ('[{"caption": "a mug"', None),
    ],
)
def test_parse_caption_reply(reply, expected):
    from ogscene3d.graph.captioner import parse_caption_reply

    assert parse_caption_reply(reply) == expected


def test_parse_tag_reply_ignores_bad_entries():
    from ogscene3d.graph.captioner import parse_tag_reply, tag_from_caption

    reply = '{"tags": {"1": "Coffee  Table", "2": 7, "3": "", "x": "chair", "9": "not asked"}}'
    assert parse_tag_reply(reply, [1, 2, 3]) == {1: "coffee table"}
    assert parse_tag_reply('[{"id": 4, "tag": "lamp"}]', [4]) == {4: "lamp"}
    assert parse_tag_reply("no json here", [1]) == {}
    assert tag_from_caption("A grey fabric couch, with cushions.") == "grey fabric couch"


def test_query_with_openai_embeddings(server_factory):
    vocab = {"sofa": [1.0, 0.0], "couch": [0.9, 0.1], "lamp": [0.0, 1.0]}

    def respond(body, n):
        vecs = [
            [sum(v[k] for w, v in vocab.items() if w in t.lower()) + 1e-3 for k in range(2)]
            for t in body["input"]
        ]
        return 200, {"data": [{"index": i, "embedding": v} for i, v in enumerate(vecs)]}, 0

    srv = server_factory(respond)
    cfg = GraphConfig(query_embedding="openai", embedding_model="emb", query_min_similarity=0.8)
    cfg.endpoint.base_url = srv.base_url
    g = SceneGraph(cfg, node_confidence=MeanConfidence())
    for i, (tag, cap) in enumerate([("seat", "a big couch"), ("light", "a floor lamp")]):
        n = SceneNode.from_points(i, np.zeros((3, 3)))
        n.tag, n.caption = tag, cap
        g.nodes[i] = n
    hits = g.query_scored("sofa")  # no word overlap with node 0: only the embedding finds it
    assert [n.id for n, _ in hits] == [0] and hits[0][1] > 0.9
    assert srv.requests[0]["path"] == "/v1/embeddings" and srv.requests[0]["body"]["model"] == "emb"
    n_req = len(srv.requests)
    g.query_scored("lamp")  # node embeddings are cached: one request for the query only
    assert len(srv.requests) == n_req + 1


# ------------------------------------------------------------------ API key, deadlines, circuit breaker


def test_unset_api_key_is_warned_once_and_named_in_auth_errors(server_factory, monkeypatch, caplog):
    monkeypatch.delenv("OGS_TEST_UNSET_KEY", raising=False)
    srv = server_factory(lambda body, n: (401, '{"error": "invalid api key"}', 0))
    client = _client(srv, api_key_env="OGS_TEST_UNSET_KEY")
    with caplog.at_level(logging.WARNING, logger="ogscene3d.graph.openai_client"):
        for _ in range(2):
            with pytest.raises(ModelError, match=r"HTTP 401.*\(API key from \$OGS_TEST_UNSET_KEY: not set\)"):
                client.chat([{"role": "user", "content": "x"}])
    warnings = [r.message for r in caplog.records if "OGS_TEST_UNSET_KEY" in r.message]
    assert len(warnings) == 1 and "not set" in warnings[0]
    assert "Authorization" not in srv.headers[0]  # local servers need none: still sent without
    # a key that is set: no warning, the error names the variable but never the key
    monkeypatch.setenv("OGS_TEST_KEY", SECRET)
    caplog.clear()
    with pytest.raises(ModelError, match=r"\(API key from \$OGS_TEST_KEY\)") as exc:
        _client(srv).chat([{"role": "user", "content": "x"}])
    assert SECRET not in str(exc.value) and "not set" not in caplog.text
    # api_key_env "" says "no key": nothing to warn about
    srv2 = server_factory(lambda body, n: (200, "fine", 0))
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        assert _client(srv2, api_key_env="").chat([{"role": "user", "content": "x"}]) == "fine"
    assert caplog.text == ""


class DripServer:
    """Answers every POST slowly: the headers (``drip_headers``) or the body one byte every ``step`` s."""

    def __init__(self, step: float = 0.05, drip_headers: bool = False):
        body = json.dumps({"choices": [{"message": {"content": '{"caption": "slow drip caption"}'}}]})

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args):
                pass

            def do_POST(self):
                self.rfile.read(int(self.headers["Content-Length"]))
                head = (
                    "HTTP/1.1 200 OK\r\nContent-Type: application/json\r\n"
                    f"Content-Length: {len(body)}\r\n\r\n"
                )
                slow, fast = (head + body, "") if drip_headers else (body, head)
                try:
                    self.wfile.write(fast.encode())
                    for ch in slow:
                        self.wfile.write(ch.encode())
                        self.wfile.flush()
                        time.sleep(step)
                except (BrokenPipeError, ConnectionResetError):
                    pass  # the client gave up, as it should

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        threading.Thread(target=self.httpd.serve_forever, args=(0.05,), daemon=True).start()
        self.base_url = f"http://127.0.0.1:{self.httpd.server_address[1]}/v1"

    def close(self):
        self.httpd.shutdown()
        self.httpd.server_close()


@pytest.mark.parametrize("drip_headers", [False, True])
def test_timeout_bounds_the_whole_request_not_each_read(drip_headers):
    """A server trickling a byte every 50 ms never trips a per-read timeout; the request must still end
    after timeout_s (the reply takes several seconds to arrive in full)."""
    srv = DripServer(step=0.05, drip_headers=drip_headers)
    try:
        client = ChatClient(srv.base_url, "m", api_key_env="", timeout_s=0.5, max_retries=1)
        t0 = time.monotonic()
        with pytest.raises(EndpointUnreachable, match="timed out after 0.5 s"):
            client.chat([{"role": "user", "content": "x"}])
        elapsed = time.monotonic() - t0
    finally:
        srv.close()
    assert client.calls == 2 and elapsed < 2.0  # (max_retries + 1) * timeout_s, plus slack


def _observed_graph(n_nodes: int, captioner) -> tuple[SceneGraph, tuple]:
    """A scene graph with ``n_nodes`` observed nodes (red boxes) and the arrays of one update."""
    g = SceneGraph(GraphConfig(min_obs_pixels=4), captioner=captioner, node_confidence=MeanConfidence())
    H, W = 48, 16 * n_nodes
    rgb = np.full((H, W, 3), 200, np.uint8)
    lm = np.full((H, W), -1, np.int32)
    for k in range(n_nodes):
        lm[8:40, 16 * k + 2 : 16 * k + 14] = k
    g.observe(0, Frame(0, rgb, np.ones((H, W), np.float32), np.eye(3)), lm)
    rng = np.random.default_rng(0)
    means = np.concatenate([rng.uniform(0, 0.3, (50, 3)) + [0.5 * k, 0, 0] for k in range(n_nodes)])
    labels = np.repeat(np.arange(n_nodes, dtype=np.int32), 50)
    return g, (means, labels, np.full(len(means), 0.9, np.float32))


def test_circuit_breaker_skips_the_rest_of_an_update_when_the_endpoint_is_down(caplog):
    import socket

    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # nothing listens there: every request fails to connect
    client = ChatClient(f"http://127.0.0.1:{port}/v1", "m", api_key_env="", max_retries=1)
    g, arrays = _observed_graph(6, OpenAICaptioner(client, concurrency=1))
    with caplog.at_level(logging.WARNING):
        g.update(11, *arrays)
    assert client.calls == 3 * 2  # three nodes' requests (with one retry each), then the rest skipped
    skips = [r.message for r in caplog.records if "skipped the other" in r.message]
    assert len(skips) == 1 and "3 caption request(s)" in skips[0]
    assert all(n.caption_source == "heuristic" for n in g.nodes.values())


def test_server_errors_trip_the_circuit_breaker(server_factory, caplog):
    """HTTP 500 after the retries is a server that does not serve: three nodes in a row, then the rest of
    the update is skipped instead of every node waiting out its own retries while mapping waits."""
    srv = server_factory(_caption_responder(fail_captions=True))
    g, arrays = _observed_graph(6, OpenAICaptioner(_client(srv, max_retries=1), concurrency=1))
    with caplog.at_level(logging.WARNING):
        g.update(11, *arrays)
    assert len(srv.requests) == 3 * 2  # three nodes (one retry each), then the rest skipped
    skips = [r.message for r in caplog.records if "skipped the other" in r.message]
    assert len(skips) == 1 and "3 caption request(s)" in skips[0]
    assert all(n.caption_source == "heuristic" for n in g.nodes.values())


def test_client_errors_do_not_trip_the_circuit_breaker(server_factory):
    srv = server_factory(lambda body, n: (400, '{"error": "image too large"}', 0))
    g, arrays = _observed_graph(5, OpenAICaptioner(_client(srv, max_retries=2), concurrency=1))
    g.update(11, *arrays)
    assert len(srv.requests) == 5  # a 4xx is that request's fault, not retried: every node is asked


class EchoAuthServer:
    """Answers every POST with HTTP 401 whose body and headers echo the request's Authorization header,
    as some proxies do."""

    def __init__(self):
        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args):
                pass

            def do_POST(self):
                self.rfile.read(int(self.headers["Content-Length"]))
                auth = self.headers.get("Authorization", "")
                body = json.dumps({"error": f"invalid credentials: Authorization: {auth}"}).encode()
                self.send_response(401, f"Unauthorized ({auth})")
                self.send_header("Content-Type", "application/json")
                self.send_header("X-Request-Id", auth)
                self.send_header("WWW-Authenticate", auth)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        threading.Thread(target=self.httpd.serve_forever, args=(0.05,), daemon=True).start()
        self.base_url = f"http://127.0.0.1:{self.httpd.server_address[1]}/v1"

    def close(self):
        self.httpd.shutdown()
        self.httpd.server_close()


def test_key_echoed_by_a_401_reply_is_redacted_everywhere(monkeypatch, caplog, capsys):
    monkeypatch.setenv("OGS_TEST_KEY", SECRET)
    srv = EchoAuthServer()
    try:
        client = ChatClient(srv.base_url, "m", api_key_env="OGS_TEST_KEY", timeout_s=2.0, max_retries=1)
        with caplog.at_level(logging.DEBUG):
            with pytest.raises(ModelError, match=r"HTTP 401") as exc:
                client.chat([{"role": "user", "content": "x"}])
            g, arrays = _observed_graph(4, OpenAICaptioner(client, concurrency=2))
            g.update(11, *arrays)  # the captioner logs each node's failure
            rels = LLMRelations(client, GeometricRelations(RelationsConfig(), UP), UP).predict(_scene())
    finally:
        srv.close()
    assert all(r.predictor == "geometric" for r in rels)
    assert "[REDACTED]" in str(exc.value)  # the echo is reported, the key is not
    chained = [exc.value.__cause__, exc.value.__context__]
    assert all(c is None or SECRET not in repr(c) for c in chained)
    out = capsys.readouterr()
    texts = [str(exc.value), repr(exc.value), caplog.text, out.out, out.err]
    texts += [logging.Formatter().format(r) for r in caplog.records]
    assert "failed" in caplog.text and not any(SECRET in t for t in texts)


def test_failed_captions_are_retried_at_the_next_update(server_factory):
    srv = server_factory(_caption_responder(fail_captions=True))
    g, arrays = _observed_graph(2, OpenAICaptioner(_client(srv, max_retries=0), concurrency=1))
    g.update(11, *arrays)
    assert [n.caption_source for n in g.nodes.values()] == ["heuristic", "heuristic"]
    srv.respond = _caption_responder()
    g.update(23, *arrays)
    assert [n.caption_source for n in g.nodes.values()] == ["vlm", "vlm"]
    assert g.nodes[0].tag == "red box"


def test_truncated_json_caption_is_a_logged_skip_and_asked_again(server_factory, caplog):
    truncated = {"on": True}

    def respond(body, n):
        content = body["messages"][-1]["content"]
        if isinstance(content, list):
            text = '{"caption": "a red box with a lid and' if truncated["on"] else '{"caption": "a red box"}'
            return 200, text, 0
        ids = [line.split(":")[0] for line in content.splitlines() if line[:1].isdigit()]
        return 200, json.dumps({"tags": {i: "red box" for i in ids}}), 0

    srv = server_factory(respond)
    g, arrays = _observed_graph(2, OpenAICaptioner(_client(srv), concurrency=1))
    with caplog.at_level(logging.WARNING):
        g.update(11, *arrays)
    assert [n.caption_source for n in g.nodes.values()] == ["heuristic", "heuristic"]
    assert not any("{" in n.caption for n in g.nodes.values())
    assert "malformed caption reply" in caplog.text and g.stats()["vlm_captioned"] == 0
    truncated["on"] = False
    g.update(23, *arrays)
    assert [(n.caption, n.caption_source) for n in g.nodes.values()] == [("a red box", "vlm")] * 2


# ------------------------------------------------------------------ prose caption replies


def test_prose_caption_replies_are_kept_marked_and_warned_once(server_factory, caplog):
    from ogscene3d.graph.captioner import read_caption_reply

    assert read_caption_reply('{"caption": "a mug"}') == ("a mug", True)
    assert read_caption_reply("I'm sorry, I can't help.") == ("I'm sorry, I can't help.", False)
    assert read_caption_reply('{"error": "bad image"}') == (None, True)

    def respond(body, n):
        content = body["messages"][-1]["content"]
        if isinstance(content, list):
            return 200, "A red box on the floor.", 0
        return 200, json.dumps({"tags": {}}), 0

    srv = server_factory(respond)
    g, arrays = _observed_graph(3, OpenAICaptioner(_client(srv), concurrency=2))
    with caplog.at_level(logging.WARNING):
        g.update(11, *arrays)
    assert [n.caption_source for n in g.nodes.values()] == ["vlm-text"] * 3
    assert g.nodes[0].caption == "A red box on the floor." and g.nodes[0].tag == "red box on the"
    prose = [r.message for r in caplog.records if "not the JSON" in r.message]
    assert len(prose) == 1 and "vlm-text" in prose[0]
    assert g.stats()["vlm_captioned"] == 3


# ------------------------------------------------------------------ relation replies


def test_edge_reply_direction_comes_from_subject_or_object():
    from ogscene3d.graph.relations import parse_edge_reply

    pairs = _scene()[:2]  # (cup 2, table 1), (wall 3, picture 4)

    def parse(entries):
        return {
            k: (r.source, r.relation, r.target)
            for k, r in parse_edge_reply(_edge_reply(entries), pairs).items()
        }

    # only the object given, and it is the pair's first node: the other one is the subject
    assert parse([{"pair": 0, "relation": "on", "object": 2}]) == {0: (1, "on", 2)}
    assert parse([{"pair": 0, "relation": "on", "object": "1"}]) == {0: (2, "on", 1)}
    assert parse([{"pair": 1, "relation": "supports", "subject": 3}]) == {1: (4, "on", 3)}
    assert parse([{"pair": 1, "relation": "on"}]) == {1: (3, "on", 4)}  # no ids: pair order


@pytest.mark.parametrize(
    "entry",
    [
        {"pair": 0, "subject": 99, "relation": "on", "object": 98},  # ids of no node of the pair
        {"pair": 0, "subject": 2, "relation": "on", "object": 3},  # object from another pair
        {"pair": 0, "subject": 2, "relation": "on", "object": 2},  # a node related to itself
        {"pair": 0, "subject": "cup", "relation": "on", "object": 1},  # not an id
    ],
)
def test_edge_entries_naming_other_nodes_fall_back_to_geometry(entry, caplog):
    from ogscene3d.graph.relations import parse_edge_reply

    pairs = _scene()[:1]
    with caplog.at_level(logging.WARNING):
        assert parse_edge_reply(_edge_reply([entry]), pairs) == {}
    assert "not the pair's nodes" in caplog.text


def test_query_embedding_without_a_model_names_its_key(caplog):
    """The query embeddings read graph.embedding_model (else the captioner's model, else the endpoint's): the
    error says so, not the captioner's / relations' keys."""
    with pytest.raises(ModelError, match=r"set graph\.embedding_model\)"):
        ChatClient("http://127.0.0.1:9/v1", "", model_setting="graph.embedding_model")
    with pytest.raises(ModelError, match=r"set graph\.embedding_model or graph\.endpoint\.model\)"):
        ChatClient.from_config(EndpointConfig(), "", "graph.embedding_model")
    with pytest.raises(ModelError, match=r"\(set graph\.endpoint\.model\)"):
        ChatClient("http://127.0.0.1:9/v1", "")
    g = SceneGraph(GraphConfig(query_embedding="openai"), node_confidence=MeanConfidence())
    n = SceneNode.from_points(0, np.zeros((3, 3)))
    n.tag, n.caption = "sofa", "a sofa"
    g.nodes[0] = n
    with caplog.at_level(logging.WARNING, logger="ogscene3d.graph.scenegraph"):
        assert [m.id for m in g.query("sofa")] == [0]  # text matching still answers
    assert "graph.embedding_model" in caplog.text and "graph.captioner.model" not in caplog.text


def test_missing_openai_package_names_what_to_install(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "openai", None)
    client = ChatClient("http://127.0.0.1:9/v1", "m", api_key_env="")
    with pytest.raises(ModelError, match=r"pip install openai \(or pip install 'ogscene3d\[llm\]'\)"):
        client.chat([{"role": "user", "content": "x"}])
