"""Room segmentation scores (HOV-SG's bird's-eye precision / recall), queries generated from the ground truth
and their top-1 accuracy, and both blocks of ``ogscene3d eval`` on a hand-built two-room apartment."""

import json

import numpy as np
import pytest
from eval_runs import GAUSSIAN_DTYPE
from graph_scenes import box_surface, plane, to_world, walls_with_doors
from plyfile import PlyData, PlyElement

from ogscene3d.cli import main
from ogscene3d.config import GraphConfig
from ogscene3d.eval.queries import GTQuery, generate_queries, query_accuracy
from ogscene3d.eval.rooms import room_scores
from ogscene3d.graph import GroundTruthCaptioner, MeanConfidence, SceneGraph

UP = np.array([0.0, -1.0, 0.0])


def _square(x0, x1, n=12000, rng=None):
    rng = rng or np.random.default_rng(0)
    return to_world(plane([x0, 0, 0], [x1, 4, 0], rng, n / (4 * (x1 - x0))), UP)


def test_room_scores_of_a_perfect_a_merged_and_a_split_segmentation():
    rng = np.random.default_rng(0)
    a, b = _square(0, 4, rng=rng), _square(4.1, 8, rng=rng)
    pts = np.concatenate([a, b])
    gt = np.r_[np.full(len(a), 1), np.full(len(b), 2)]
    s = room_scores(pts, gt, pts, np.where(gt == 1, 11, 12), UP)
    assert (s.precision, s.recall, s.num_gt, s.num_pred) == (pytest.approx(1.0), pytest.approx(1.0), 2, 2)
    assert s.per_room[1]["pred_room"] == 11 and s.per_room[2]["recall"] == pytest.approx(1.0)
    merged = room_scores(pts, gt, pts, np.full(len(pts), 5), UP)  # one predicted room for both
    assert merged.recall == pytest.approx(1.0) and merged.precision == pytest.approx(0.5, abs=0.05)
    assert merged.per_room[2]["pred_room"] is None or merged.per_room[1]["pred_room"] is None
    split = room_scores(pts, gt, pts, np.where(pts[:, 0] < 2, 1, np.where(gt == 1, 2, 3)), UP)
    assert split.precision == pytest.approx(1.0) and split.recall == pytest.approx((0.5 + 1.0) / 2, abs=0.05)
    # a room's outline counts as its extent where it holds few Gaussians (a far floor)
    sparse = np.where(gt == 2, 12, np.where(pts[:, 0] < 1.0, 11, -1))
    corners = to_world(np.array([[0.0, 0, 0], [4, 0, 0], [4, 4, 0], [0, 4, 0]]), UP)
    assert room_scores(pts, gt, pts, sparse, UP).per_room[1]["recall"] < 0.3
    filled = room_scores(pts, gt, pts, sparse, UP, outlines={11: [corners]})
    assert filled.per_room[1]["recall"] > 0.97 and filled.per_room[1]["precision"] > 0.97
    none = room_scores(pts, gt, pts, np.full(len(pts), -1), UP)
    assert none.num_pred == 0 and none.recall == 0.0 and np.isnan(none.precision)
    settled = room_scores(pts, gt, pts, np.where(gt == 1, 11, 12), UP, entered={1: 0, 2: 40},
                          first_seen={11: 4, 12: 52})  # fmt: skip
    assert settled.per_room[1]["settle_frames"] == 4 and settled.per_room[2]["settle_frames"] == 12
    assert settled.to_dict()["settle_frames_max"] == 12


def test_queries_from_the_ground_truth():
    cls = {1: "floor", 2: "bed", 3: "pillow", 4: "pillow", 5: "sofa", 6: "chair", 7: "chair", 8: "table"}
    rels = [(3, "on", 2), (4, "on", 5), (6, "next to", 8), (2, "on", 1), (8, "next to", 7)]
    rooms = {2: 1, 3: 1, 6: 1, 4: 2, 5: 2, 7: 2, 8: 2}
    qs = {
        (q.kind, q.text): q.answers
        for q in generate_queries(cls, rels, rooms, {1: "bedroom", 2: "living room"})
    }
    assert qs[("object", "pillow")] == {3, 4} and ("object", "floor") not in qs
    assert qs[("relation", "pillow on the bed")] == {3} and qs[("relation", "pillow on the sofa")] == {4}
    assert qs[("relation", "chair next to the table")] == {6, 7}  # symmetric: both ways
    assert qs[("relation", "table next to the chair")] == {8}
    assert not any("floor" in t for _, t in qs)  # structural classes neither answer nor anchor
    assert qs[("room", "chair in the bedroom")] == {6} and qs[("room", "pillow in the living room")] == {4}
    only = generate_queries(cls, rels, present={2, 3})
    assert {q.text for q in only} == {"bed", "pillow", "pillow on the bed"}


def test_query_accuracy_counts_top1_per_kind():
    qs = [GTQuery("object", "a", frozenset({1})), GTQuery("object", "b", frozenset({2})),
          GTQuery("relation", "c", frozenset({3}))]  # fmt: skip
    top = {"a": 10, "b": 11, "c": None}
    iou = {(10, 1): 0.8, (11, 2): 0.05}
    out = query_accuracy(qs, top.get, lambda n, ans: max(iou.get((n, i), 0.0) for i in ans), 0.1)
    assert out["per_kind"]["object"]["top1"] == 1 and out["per_kind"]["object"]["top1_accuracy"] == 0.5
    assert out["per_kind"]["relation"]["no_hit"] == 1 and out["per_kind"]["room"]["queries"] == 0
    assert {f["query"] for f in out["failures"]} == {"b", "c"}


def _apartment(tmp_path):
    """A bedroom and a kitchen joined by a doorway: GT points with instances and rooms, and a run whose
    Gaussians are the GT points (label = instance + 100) with the graph SceneGraph makes of them."""
    rng = np.random.default_rng(7)
    parts = {  # instance: (class, room, z-up points)
        1: ("floor", 1, plane([0, 0, 0], [4, 4, 0], rng, 600.0)),
        2: ("wall", 1, walls_with_doors(0, 4, 0, 4, 2.6, rng, [("+x", 2.0)], density=500.0)),
        3: ("bed", 1, box_surface([0.3, 2.4, 0], [1.8, 3.9, 0.5], rng, 900.0)),
        4: ("pillow", 1, box_surface([0.6, 3.4, 0.5], [1.0, 3.8, 0.65], rng, 4000.0)),
        5: ("floor", 2, plane([4.1, 0, 0], [8, 4, 0], rng, 600.0)),
        6: ("wall", 2, walls_with_doors(4.1, 8, 0, 4, 2.6, rng, [("-x", 2.0)], density=500.0)),
        7: ("refrigerator", 2, box_surface([7.2, 3.2, 0], [7.9, 3.9, 1.8], rng, 900.0)),
        8: ("table", 2, box_surface([5.5, 1.5, 0.7], [6.7, 2.3, 0.75], rng, 2000.0)),
        9: ("cup", 2, box_surface([6.0, 1.8, 0.75], [6.08, 1.88, 0.85], rng, 20000.0)),
        10: ("chair", 2, box_surface([6.8, 1.6, 0.0], [7.25, 2.05, 0.9], rng, 1500.0)),
    }
    classes = sorted({c for c, _, _ in parts.values()})
    pts = np.concatenate([to_world(p, UP) for _, _, p in parts.values()])
    inst = np.concatenate([np.full(len(p), i) for i, (_, _, p) in parts.items()])
    gt = tmp_path / "scene" / "gt"
    gt.mkdir(parents=True)
    v = np.zeros(
        len(pts), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("instance", "<i4"), ("class", "<i4")]
    )
    v["x"], v["y"], v["z"] = pts.T
    v["instance"] = inst
    v["class"] = [classes.index(parts[i][0]) + 1 for i in inst]
    PlyData([PlyElement.describe(v, "vertex")], byte_order="<").write(str(gt / "points.ply"))
    doc = {
        "version": 1,
        "classes": {str(k + 1): c for k, c in enumerate(classes)},
        "instances": {
            str(i): {"class": c, "class_id": classes.index(c) + 1, "room": r}
            for i, (c, r, _) in parts.items()
        },
        "relations": [[4, "on", 3], [9, "on", 8], [10, "next to", 8]],
        "symmetric_relations": ["next to"],
        "rooms": {
            "1": {"type": "bedroom", "floor": 0, "first_frame": 0},
            "2": {"type": "kitchen", "floor": 0, "first_frame": 30},
        },
    }
    (gt / "instances.json").write_text(json.dumps(doc))
    run = tmp_path / "run"
    run.mkdir()
    g = np.zeros(len(pts), dtype=GAUSSIAN_DTYPE)
    g["x"], g["y"], g["z"] = pts.T
    g["opacity"], g["rot_0"], g["label"], g["confidence"] = 4.0, 1.0, inst + 100, 0.9
    PlyData([PlyElement.describe(g, "vertex")], byte_order="<").write(str(run / "gaussians.ply"))
    names = {i + 100: c for i, (c, _, _) in parts.items()}
    graph = SceneGraph(GraphConfig(), captioner=GroundTruthCaptioner(names), node_confidence=MeanConfidence())
    graph.observe(2, _frame(20), np.full((4, 4), -1, np.int32))  # keyframe 2 is frame 20
    graph.update(2, pts, inst + 100, np.full(len(pts), 0.9), force=True)
    graph.save(run / "graph.json")
    return run, tmp_path / "scene", graph


def _frame(index):
    from ogscene3d import Frame

    return Frame(index, np.zeros((4, 4, 3), np.uint8), np.ones((4, 4), np.float32), np.eye(3))


def test_eval_scores_rooms_and_queries(tmp_path, capsys):
    run, scene, graph = _apartment(tmp_path)
    assert {r.type for r in graph.rooms.values()} == {"bedroom", "kitchen"}
    assert main(["eval", str(run), "--gt", str(scene), "--no-plots"]) == 0
    out = capsys.readouterr().out
    report = json.loads((run / "metrics.json").read_text())
    r = report["rooms"]
    assert r["num_gt_rooms"] == 2 and r["num_pred_rooms"] == 2
    assert r["precision"] > 0.97 and r["recall"] > 0.97 and r["matched_recall"] > 0.97
    assert {row["settle_frames"] for row in r["per_room"].values()} == {20, -10}  # first seen at frame 20
    assert r["types_correct"] == 2 and r["per_room"]["2"]["pred_type"] == "kitchen"
    q = report["queries"]["per_kind"]
    assert q["object"]["top1_accuracy"] == 1.0 and q["object"]["queries"] == 6
    assert q["relation"]["top1_accuracy"] == 1.0 and q["relation"]["queries"] == 4
    assert q["room"]["top1_accuracy"] == 1.0 and q["room"]["queries"] == 6
    assert "room precision" in out and "top-1   object 100.00 (6/6" in out
    # an older run without rooms: the rooms are not scored, the queries are, a note says why
    doc = json.loads((run / "graph.json").read_text())
    del doc["rooms"], doc["floors"]
    (run / "graph.json").write_text(json.dumps(doc))
    assert main(["eval", str(run), "--gt", str(scene), "--no-plots"]) == 0
    report = json.loads((run / "metrics.json").read_text())
    assert report["rooms"] is None and report["queries"]["per_kind"]["object"]["queries"] == 6
    assert any("graph.json has no rooms" in n for n in report["notes"])
