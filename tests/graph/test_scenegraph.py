"""SceneGraph: update schedule, selective node/edge updates, observation sets, graph.json, export, query."""

import json
import threading
import time

import numpy as np
import pytest
from graph_scenes import blob_map

from ogscene3d import Frame
from ogscene3d.config import GraphConfig, RoomsConfig, load_config
from ogscene3d.errors import DataError
from ogscene3d.graph import (
    Description,
    GeometricRelations,
    GroundTruthCaptioner,
    HeuristicCaptioner,
    MeanConfidence,
    SceneGraph,
)


class SpyCaptioner:
    """Captions "thing <id> v<call>" and records which nodes each call received."""

    def __init__(self, fail_on: set[int] | None = None, delay: float = 0.0):
        self.calls: list[list[int]] = []
        self.fail_on = fail_on or set()
        self.delay = delay

    def describe(self, requests):
        time.sleep(self.delay)
        self.calls.append([r.node.id for r in requests])
        if len(self.calls) in self.fail_on:
            raise RuntimeError("captioner exploded")
        return {
            r.node.id: Description(f"thing {r.node.id} v{len(self.calls)}", f"thing{r.node.id}", "vlm")
            for r in requests
        }


class TableConfidence:
    """C_i from a lookup table (default 0.9)."""

    def __init__(self, table):
        self.table = table

    def score(self, requests):
        return {r.node.id: self.table.get(r.node.id, 0.9) for r in requests}


class SpyRelations:
    def __init__(self, fail: bool = False):
        self.inner = GeometricRelations()
        self.pairs: list[list[tuple[int, int]]] = []
        self.fail = fail

    def predict(self, pairs):
        self.pairs.append([(a.id, b.id) for a, b in pairs])
        if self.fail:
            raise ConnectionError("LLM down")
        return self.inner.predict(pairs)


def test_update_schedule_and_selective_updates(tmp_path):
    cfg = GraphConfig(rooms=RoomsConfig(enabled=False))  # the graph's own schedule (rooms have theirs)
    cap = SpyCaptioner()
    rel = SpyRelations()
    conf = TableConfidence({1: 0.1})  # node 1 stays uncertain: re-captioned at every update
    out = tmp_path / "graph.json"
    g = SceneGraph(cfg, captioner=cap, relations=rel, node_confidence=conf, out_path=out)
    ran = []
    for kf in range(50):
        present = [0, 1, 2, 3] if kf < 20 else [0, 1, 2, 3, 4, 5]  # nodes 4, 5 appear at keyframe 20
        if kf >= 40:
            present = [0, 1, 2, 3, 4]  # node 5 merged away by refinement
        due = g.is_due(kf)
        did = g.update(kf, *blob_map(present, seed=kf))
        assert did == due
        if did:
            ran.append(kf)
    assert ran == [11, 23, 35, 47]  # init after 12 keyframes, then every 12
    assert cap.calls[0] == [0, 1, 2, 3]  # initialisation: every node
    assert cap.calls[1] == [1, 4, 5]  # low-confidence node 1 and the new nodes
    assert cap.calls[2] == [1]
    assert cap.calls[3] == [1]
    # edges re-evaluated only for updated/new nodes (each pair touches one of them)
    assert sorted(rel.pairs[0]) == [(0, 1), (1, 2), (2, 3)]
    assert all(1 in p or 4 in p or 5 in p for p in rel.pairs[1])
    assert (3, 4) in rel.pairs[1] and (4, 5) in rel.pairs[1]
    assert all(1 in p for p in rel.pairs[2])
    assert set(g.nodes) == {0, 1, 2, 3, 4}
    assert all(5 not in k for k in g.edges)  # the vanished node took its edges along
    assert g.nodes[0].caption == "thing 0 v1" and g.nodes[0].last_updated == 11
    assert g.nodes[1].caption == "thing 1 v4" and g.nodes[1].last_updated == 47
    assert g.nodes[4].first_seen == 23 and g.nodes[4].confidence == pytest.approx(0.9)
    doc = json.loads(out.read_text())
    assert doc["version"] == 1 and [n["id"] for n in doc["nodes"]] == [0, 1, 2, 3, 4]
    needed = {
        "id",
        "label",
        "caption",
        "tag",
        "confidence",
        "center",
        "bbox_min",
        "bbox_max",
        "num_gaussians",
        "first_seen",
        "last_updated",
    }
    assert all(needed <= set(n) for n in doc["nodes"])
    assert all({"source", "target", "relation", "score"} <= set(e) for e in doc["edges"])
    assert all(e["score"] > cfg.tau_e for e in doc["edges"])
    n0 = doc["nodes"][0]
    assert np.allclose(n0["bbox_min"], [0, 0, 0], atol=0.01) and np.allclose(
        n0["bbox_max"], [0.3] * 3, atol=0.01
    )
    assert n0["num_gaussians"] == 400


def test_finalize_updates_pending_nodes_and_failures_never_raise(tmp_path, caplog):
    cap = SpyCaptioner(fail_on={2})
    g = SceneGraph(
        GraphConfig(), captioner=cap, relations=SpyRelations(fail=True), node_confidence=TableConfidence({})
    )
    for kf in range(12):
        g.update(kf, *blob_map([0, 1]))
    assert g.nodes[0].caption == "thing 0 v1"
    assert all(e.predictor == "geometric" for e in g.edges.values()) and g.edges  # fell back to geometry
    # a new node at the end: captioner fails -> heuristic caption for the new node, old captions kept
    assert g.finalize(13, *blob_map([0, 1, 2]))
    assert g.nodes[0].caption == "thing 0 v1"
    assert g.nodes[2].caption_source == "heuristic" and "heuristic" in g.nodes[2].caption
    assert "captioner failed" in caplog.text


def test_bad_inputs_raise_clear_errors():
    g = SceneGraph(GraphConfig(), node_confidence=MeanConfidence())
    m, lab, conf, col = blob_map([0])
    with pytest.raises(ValueError, match="means"):
        g.update(11, m[:, :2], lab, conf, col)
    with pytest.raises(ValueError, match="labels"):
        g.update(11, m, lab[:-1], conf, col)
    with pytest.raises(ValueError, match="colors"):
        g.update(11, m, lab, conf, col[:, :2])
    m[:5] = np.nan  # non-finite Gaussians are skipped, not fatal
    assert g.update(11, m, lab, conf, col)
    assert g.nodes[0].num_gaussians == 395


def test_background_update_defers_while_busy():
    """update() hands the work to the worker and returns; a due update is deferred while one runs."""
    release = threading.Event()

    class BlockingCaptioner(SpyCaptioner):
        def describe(self, requests):
            assert release.wait(10), "test never released the captioner"
            return super().describe(requests)

    cfg = GraphConfig(background=True)
    cap = BlockingCaptioner()
    g = SceneGraph(cfg, captioner=cap, relations=SpyRelations(), node_confidence=TableConfidence({1: 0.0}))
    assert g.update(11, *blob_map([0, 1]))  # returns while the captioner is still blocked
    try:
        assert cap.calls == []
        assert not g.update(23, *blob_map([0, 1, 2]))  # previous update still running: deferred
        assert g.is_due(23)
    finally:
        release.set()
    g.wait()
    assert g.nodes[1].caption == "thing 1 v1"
    assert g.update(24, *blob_map([0, 1, 2]))  # the deferred update runs at the next keyframe
    g.finalize(36, *blob_map([0, 1, 2]))
    assert cap.calls == [[0, 1], [1, 2], [1]]


def test_observation_sets_keep_largest_views():
    cfg = GraphConfig(crop_max_side=32, min_obs_pixels=4)
    g = SceneGraph(cfg, node_confidence=MeanConfidence())
    H, W = 60, 80
    rgb = np.zeros((H, W, 3), np.uint8)
    rgb[..., 0] = 200
    rgb[..., 1] = np.arange(W, dtype=np.uint8)[None]
    gt_cls = np.full((H, W), 3, np.int32)
    for kf, side in enumerate([10, 30, 20, 40, 5, 25]):
        lm = np.full((H, W), -1, np.int32)
        lm[5 : 5 + side, 10 : 10 + side] = 7
        gt = gt_cls.copy()
        gt[5:8, 10:12] = 9  # a minority class inside the region
        frame = Frame(kf, rgb, np.ones((H, W), np.float32), np.eye(3), gt_classes=gt)
        g.observe(kf, frame, lm)
    obs = g.observations(7)
    assert obs.context.keyframe == 3 and obs.context.area == 1600
    assert [m.keyframe for m in obs.masked] == [3, 1, 5]  # 3 largest, distinct keyframes
    assert max(obs.context.image.shape[:2]) <= 32 and max(obs.masked[0].image.shape[:2]) <= 32
    # the context crop keeps surroundings; the masked crop of the region itself has no black pixels
    # (the region fills its bbox), while a context crop is larger than the masked one at the same scale
    assert obs.masked[0].image[..., 0].min() > 0
    assert g.majority_gt("class") == {7: 3}
    with pytest.raises(ValueError, match="label_map shape"):
        g.observe(6, Frame(6, rgb, np.ones((H, W), np.float32), np.eye(3)), np.zeros((H, W - 1), np.int32))


def test_masked_view_blacks_out_other_pixels():
    g = SceneGraph(GraphConfig(min_obs_pixels=1), node_confidence=MeanConfidence())
    rgb = np.full((20, 20, 3), 255, np.uint8)
    lm = np.full((20, 20), -1, np.int32)
    lm[2:12, 2:12] = 1
    lm[2:7, 2:7] = 2  # label 2 takes the top-left quarter of label 1's box
    g.observe(0, Frame(0, rgb, np.ones((20, 20), np.float32), np.eye(3)), lm)
    m = g.observations(1).masked[0].image
    assert m.shape == (10, 10, 3)
    assert (m[:5, :5] == 0).all() and (m[5:, 5:] == 255).all()
    ctx = g.observations(1).context.image
    assert ctx.shape[0] > 10 and (ctx == 255).all()


def test_groundtruth_captioner_from_votes_and_names():
    cap = GroundTruthCaptioner(label_names={0: "sofa"}, class_names={3: "chair"})
    g = SceneGraph(GraphConfig(min_obs_pixels=1), captioner=cap, node_confidence=MeanConfidence())
    H, W = 10, 10
    lm = np.full((H, W), -1, np.int32)
    lm[:, :5] = 1
    gt = np.full((H, W), 3, np.int32)
    g.observe(
        0, Frame(0, np.zeros((H, W, 3), np.uint8), np.ones((H, W), np.float32), np.eye(3), gt_classes=gt), lm
    )
    g.update(11, *blob_map([0, 1, 2]))
    assert g.nodes[0].tag == "sofa" and g.nodes[1].tag == "chair"
    assert g.nodes[1].caption_source == "groundtruth"
    assert g.nodes[2].caption_source == "heuristic"  # no ground truth seen: fallback


def test_json_roundtrip_networkx_graphml_and_query(tmp_path):
    g = SceneGraph(GraphConfig(), captioner=HeuristicCaptioner(), node_confidence=MeanConfidence())
    g.update(11, *blob_map([0, 1, 2]))
    g.nodes[0].tag, g.nodes[0].caption = "couch", "a grey fabric couch with two cushions"
    g.nodes[1].tag, g.nodes[1].caption = "coffee table", "a low wooden coffee table"
    g.nodes[2].tag, g.nodes[2].caption = "mug", "a white mug on the table"
    for n in g.nodes.values():
        n.caption_source = "vlm"  # (a model's captions: their words count in queries)
    path = tmp_path / "graph.json"
    g.save(path)
    h = SceneGraph.load(path)
    assert h.to_json() == g.to_json()
    assert [n.id for n in h.query("sofa")] == [0]  # synonym
    assert [n.id for n in h.query("table")] == [1, 2]  # tag beats caption
    assert [n.id for n in h.query("cushion")] == [0]  # caption, plural-tolerant
    assert h.query("giraffe") == []
    assert [n.id for n in h.query("#2")] == [2] and h.query("#7") == []  # a node by id
    G = h.to_networkx()
    assert set(G.nodes) == {0, 1, 2} and G.nodes[1]["tag"] == "coffee table"
    assert all("relation" in d for _, _, d in G.edges(data=True)) and G.number_of_edges() == len(h.edges)
    gml = tmp_path / "graph.graphml"
    h.save_graphml(gml)
    import networkx as nx

    assert nx.read_graphml(gml).number_of_nodes() == 3


def test_load_accepts_a_run_directory_and_nodes_have_labels(tmp_path):
    """``SceneGraph.load`` takes the run directory the CLI takes; nodes carry graph.json's ``label``."""
    g = SceneGraph(GraphConfig(), captioner=HeuristicCaptioner(), node_confidence=MeanConfidence())
    g.update(11, *blob_map([0, 3]))
    g.save(tmp_path / "graph.json")
    h = SceneGraph.load(tmp_path)
    assert sorted(h.nodes) == [0, 3]
    doc = json.loads((tmp_path / "graph.json").read_text())
    assert [n.label for n in h.nodes.values()] == [d["label"] for d in doc["nodes"]] == [0, 3]
    (tmp_path / "unfinished").mkdir()
    with pytest.raises(DataError, match="has no graph.json"):
        SceneGraph.load(tmp_path / "unfinished")


def test_graphml_has_the_node_boxes(tmp_path):
    """GraphML keeps each node's axis-aligned and oriented box, not only its centre."""
    import networkx as nx

    g = SceneGraph(GraphConfig(), captioner=HeuristicCaptioner(), node_confidence=MeanConfidence())
    g.update(11, *blob_map([0, 1]))
    g.save_graphml(tmp_path / "g.graphml")
    G = nx.read_graphml(tmp_path / "g.graphml", node_type=int)
    for i, n in g.nodes.items():
        d = G.nodes[i]
        assert d["label"] == i
        assert np.allclose([d[f"bbox_min_{a}"] for a in "xyz"], n.bbox_min)
        assert np.allclose([d[f"bbox_max_{a}"] for a in "xyz"], n.bbox_max)
        assert np.allclose([d[f"obb_extent_{a}"] for a in "xyz"], n.obb_extent)
        assert np.allclose(np.reshape(json.loads(d["obb_axes"]), (3, 3)), n.obb_axes, atol=1e-6)


def test_state_resumes_captions_and_schedule():
    """A graph restored from ``state()`` (through JSON, as in a checkpoint) keeps the captions and the update
    schedule: the next update is the one the original would make, and captions only what it would."""
    cfg = GraphConfig(rooms=RoomsConfig(enabled=False))  # the graph's own schedule (rooms have theirs)
    first, second = SpyCaptioner(), SpyCaptioner()
    g = SceneGraph(cfg, captioner=first, node_confidence=TableConfidence({1: 0.1}))
    for kf in range(15):
        g.update(kf, *blob_map([0, 1, 2]))
    h = SceneGraph(cfg, captioner=second, node_confidence=TableConfidence({1: 0.1}))
    h.load_state(json.loads(json.dumps(g.state())))
    assert h.to_json() == g.to_json() and h.nodes[0].caption == "thing 0 v1"
    assert (
        [kf for kf in range(15, 24) if h.is_due(kf)] == [kf for kf in range(15, 24) if g.is_due(kf)] == [23]
    )
    h.update(23, *blob_map([0, 1, 2, 3]))
    assert second.calls == [[1, 3]]  # the uncertain node and the new one; nodes 0 and 2 keep their captions
    assert h.nodes[0].caption == "thing 0 v1" and h.nodes[3].first_seen == 23
    with pytest.raises(DataError, match="schedule"):
        h.load_state({"graph": g.to_json()})
    with pytest.raises(DataError, match="not a scene graph state"):
        h.load_state([])


@pytest.mark.parametrize(
    "content,match",
    [
        ("{", "not valid JSON"),
        ('{"version": 2, "nodes": [], "edges": []}', "version-1"),
        ('{"version": 1, "nodes": [{"id": 1, "center": [0, 0]}], "edges": []}', "center"),
        (
            '{"version": 1, "nodes": [], "edges": [{"source": 1, "target": 2, "relation": "on"}]}',
            "not in the graph",
        ),
    ],
)
def test_load_rejects_bad_files(tmp_path, content, match):
    p = tmp_path / "graph.json"
    p.write_text(content)
    with pytest.raises(DataError, match=match):
        SceneGraph.load(p)
    with pytest.raises(DataError, match="does not exist"):
        SceneGraph.load(tmp_path / "missing.json")


def test_config_keys_select_implementations():
    cfg = load_config(
        None,
        [
            "graph.captioner.kind=groundtruth",
            "graph.relations.kind=llm",
            "graph.relations.model=m",
            "graph.up_axis=[0,0,1]",
        ],
    )
    g = SceneGraph(cfg.graph)
    assert type(g.captioner).__name__ == "GroundTruthCaptioner"
    assert type(g.relations).__name__ == "LLMRelations"
    from ogscene3d.errors import ConfigError, ModelError

    with pytest.raises(ConfigError, match="captioner.kind"):
        SceneGraph(load_config(None, ["graph.captioner.kind=magic"]).graph)
    with pytest.raises(ModelError, match="no model name"):
        SceneGraph(load_config(None, ["graph.captioner.kind=openai"]).graph)
    with pytest.raises(ConfigError, match="up_axis"):
        SceneGraph(load_config(None, ["graph.up_axis=[0,0,0]"]).graph)


def test_observe_concurrent_with_background_update():
    """observe() from the mapping thread while a background update reads the observation sets."""
    g = SceneGraph(
        GraphConfig(background=True, min_obs_pixels=1),
        captioner=SpyCaptioner(delay=0.05),
        node_confidence=MeanConfidence(),
    )
    rgb = np.full((16, 16, 3), 100, np.uint8)
    errors = []

    def feed():
        try:
            for kf in range(30):
                lm = np.full((16, 16), -1, np.int32)
                lm[: 1 + kf % 16, :8] = kf % 3
                g.observe(kf, Frame(kf, rgb, np.ones((16, 16), np.float32), np.eye(3)), lm)
        except Exception as e:  # pragma: no cover - reported below
            errors.append(e)

    t = threading.Thread(target=feed)
    t.start()
    g.update(11, *blob_map([0, 1, 2]))
    t.join()
    g.finalize(30, *blob_map([0, 1, 2]))
    assert not errors and len(g.nodes) == 3


def test_networkx_missing_gives_clear_error(monkeypatch):
    import sys

    from ogscene3d.errors import OGSceneError

    g = SceneGraph(GraphConfig(), node_confidence=MeanConfidence())
    monkeypatch.setitem(sys.modules, "networkx", None)
    with pytest.raises(OGSceneError, match="pip install networkx"):
        g.to_networkx()


def test_cli_graph_query_and_graphml(tmp_path, capsys):
    from ogscene3d.cli import main

    g = SceneGraph(GraphConfig(), captioner=HeuristicCaptioner(), node_confidence=MeanConfidence())
    g.update(11, *blob_map([0, 1]))
    g.nodes[0].tag, g.nodes[0].caption = "couch", "a grey couch"
    g.save(tmp_path / "graph.json")
    assert (
        main(["graph", str(tmp_path), "-q", "sofa", "--edges", "--graphml", str(tmp_path / "g.graphml")]) == 0
    )
    out = capsys.readouterr().out
    assert "2 nodes, 1 edges" in out and "#0 'couch'" in out and (tmp_path / "g.graphml").is_file()
    assert main(["graph", str(tmp_path / "missing")]) == 2


def test_cli_graph_lists_nodes(tmp_path, capsys):
    from ogscene3d.cli import main

    g = SceneGraph(GraphConfig(), captioner=HeuristicCaptioner(), node_confidence=MeanConfidence())
    g.update(11, *blob_map([0, 1]))
    g.nodes[0].tag, g.nodes[0].caption = "couch", "a grey fabric couch " + "with many cushions " * 10
    g.nodes[0].confidence = 0.875
    g.nodes[1].tag, g.nodes[1].caption = "", ""
    g.save(tmp_path / "graph.json")
    assert main(["graph", str(tmp_path)]) == 0
    assert len(capsys.readouterr().out.splitlines()) == 1  # the summary line only, as before
    assert main(["graph", str(tmp_path), "--nodes"]) == 0
    summary, first, second = capsys.readouterr().out.splitlines()
    assert "2 nodes" in summary
    c = g.nodes[0].center
    assert first.startswith(
        f"  #0 'couch' 400 Gaussians, confidence 0.88 at [{c[0]:.2f}, {c[1]:.2f}, {c[2]:.2f}]: a grey fabric"
    )
    assert first.endswith("...") and len(first) < 160  # the long caption is shortened
    assert second.startswith("  #1 (untagged) 400 Gaussians, confidence") and not second.endswith(": ")


def test_cli_graph_rejects_an_empty_query(tmp_path, capsys):
    from ogscene3d.cli import main
    from ogscene3d.errors import ConfigError

    g = SceneGraph(GraphConfig(), captioner=HeuristicCaptioner(), node_confidence=MeanConfidence())
    g.update(11, *blob_map([0]))
    g.save(tmp_path / "graph.json")
    for bad in (["-q", ""], ["-q", "  "], ["--top-k", "0"]):
        with pytest.raises(SystemExit) as e:
            main(["graph", str(tmp_path), *bad])
        assert e.value.code == 2
    err = capsys.readouterr().err
    assert "the query text is empty" in err and "Traceback" not in err
    with pytest.raises(ConfigError, match="query text is empty"):
        g.query(" ")


def test_heuristic_captions_follow_growing_geometry():
    """A confident node first seen as a small patch is re-described by the (free) heuristic captioner once
    the map shows it is a wall, without a selective re-caption (last_updated unchanged)."""
    rng = np.random.default_rng(3)
    up = np.array([0.0, -1.0, 0.0])

    def wall(height):  # vertical sheet x = 2 (world up = -y), floor patch as label 1
        pts = np.stack([np.full(3000, 2.0), -rng.uniform(0, height, 3000), rng.uniform(-2, 2, 3000)], 1)
        floor = np.stack([rng.uniform(-2, 2, 3000), np.zeros(3000), rng.uniform(-2, 2, 3000)], 1)
        means = np.concatenate([pts, floor])
        return means, np.repeat(np.array([0, 1], np.int32), 3000), np.full(6000, 0.9, np.float32)

    g = SceneGraph(
        GraphConfig(up_axis=up.tolist()), captioner=HeuristicCaptioner(), node_confidence=MeanConfidence()
    )
    g.update(11, *wall(0.5))
    assert g.nodes[0].tag != "wall" and g.nodes[1].tag == "floor"
    g.update(23, *wall(2.5))
    assert g.nodes[0].tag == "wall" and g.nodes[0].last_updated == 11


class FlakyCaptioner(SpyCaptioner):
    """Like SpyCaptioner but leaves the nodes in ``down[call]`` out (their request failed) on that call."""

    def __init__(self, down: dict[int, set[int]]):
        super().__init__()
        self.down = down

    def describe(self, requests):
        out = super().describe(requests)
        for i in self.down.get(len(self.calls), set()):
            out.pop(i, None)
        return out


def test_fallback_captions_are_asked_for_again_at_the_next_update_and_finalize(caplog):
    """A node whose VLM caption failed gets the heuristic caption, and is queued again at every update
    (and at finalize) until the captioner answers, although its confidence is above tau_update."""
    cap = FlakyCaptioner(down={1: {1, 2}, 2: {2}})
    g = SceneGraph(
        GraphConfig(), captioner=cap, relations=SpyRelations(), node_confidence=TableConfidence({})
    )
    g.update(11, *blob_map([0, 1, 2]))
    assert [g.nodes[i].caption_source for i in (0, 1, 2)] == ["vlm", "heuristic", "heuristic"]
    assert "heuristic" in g.nodes[1].caption
    g.update(23, *blob_map([0, 1, 2]))
    assert cap.calls[1] == [1, 2]  # the confident VLM-captioned node 0 is not asked again
    assert g.nodes[1].caption == "thing 1 v2" and g.nodes[1].caption_source == "vlm"
    assert g.nodes[2].caption_source == "heuristic" and g.nodes[2].last_updated == 23
    with caplog.at_level("INFO", logger="ogscene3d.graph.scenegraph"):
        g.finalize(30, *blob_map([0, 1, 2]))
    assert cap.calls[2] == [2]
    assert all(n.caption_source == "vlm" for n in g.nodes.values())
    assert "3 of 3 nodes captioned by the VLM" in caplog.text


def test_heuristic_captioner_does_not_requeue_its_own_captions():
    class SpyHeuristic(HeuristicCaptioner):
        def __init__(self):
            super().__init__()
            self.calls = []

        def describe(self, requests):
            self.calls.append([r.node.id for r in requests])
            return super().describe(requests)

    cap = SpyHeuristic()
    g = SceneGraph(GraphConfig(), captioner=cap, node_confidence=TableConfidence({}))
    g.update(11, *blob_map([0, 1]))
    g.update(23, *blob_map([0, 1]))
    g.finalize(30, *blob_map([0, 1]))
    assert cap.calls == [[0, 1]]


def test_stats_count_vlm_captions_and_finalize_warns_when_none(caplog):
    cap = FlakyCaptioner(down={1: {0, 1}, 2: {0, 1}})
    g = SceneGraph(GraphConfig(), captioner=cap, node_confidence=TableConfidence({}))
    g.update(11, *blob_map([0, 1]))
    with caplog.at_level("INFO", logger="ogscene3d.graph.scenegraph"):
        g.finalize(12, *blob_map([0, 1]))
    assert "0 of 2 nodes captioned by the VLM" in caplog.text
    assert any(r.levelname == "WARNING" and "captioned by the VLM" in r.message for r in caplog.records)
    doc = g.to_json()
    assert doc["stats"]["vlm_captioned"] == 0 and doc["stats"]["caption_sources"] == {"heuristic": 2}
    g.nodes[0].caption_source = "vlm-text"  # prose replies count as VLM captions
    assert g.stats()["vlm_captioned"] == 1 and g.stats()["nodes"] == 2


def test_graph_help_override_examples_are_valid_keys(capsys):
    """The --set example of `ogscene3d graph --help` names real config keys."""
    import re

    from ogscene3d.cli import build_parser

    with pytest.raises(SystemExit):
        build_parser().parse_args(["graph", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    examples = re.findall(r"--set ([a-z_]+\.[\w.]+=[^\s)]+)", text)  # not the usage's KEY=VALUE
    assert examples
    load_config(None, [e.replace("MODEL", "text-embedding-3-small") for e in examples])


def test_graph_json_extent_is_the_size_the_heuristic_caption_gives(tmp_path):
    """A node's caption says "about <size>"; graph.json's ``extent`` (shown as the viewer's size) holds that
    size as its first value, and it survives a save and load."""
    from ogscene3d.graph.geometry import format_length

    g = SceneGraph(GraphConfig(), captioner=HeuristicCaptioner(), node_confidence=MeanConfidence())
    means, labels, conf, colors = blob_map([0, 1, 2])
    means[labels == 1] *= np.array([3.0, 1.0, 0.5])  # an elongated node
    g.update(11, means, labels, conf, colors)
    doc = g.to_json()
    for n in doc["nodes"]:
        assert len(n["extent"]) == 3
        assert f"about {format_length(n['extent'][0])}" in n["caption"], n["caption"]
    g.save(tmp_path / "graph.json")
    h = SceneGraph.load(tmp_path / "graph.json")
    assert [n["extent"] for n in h.to_json()["nodes"]] == [n["extent"] for n in doc["nodes"]]
