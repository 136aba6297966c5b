"""Relation recall on a toy scene graph with nodes matched by 3D overlap."""

import math

import numpy as np
import pytest

from ogscene3d.eval.graph_metrics import match_nodes_by_overlap, node_overlap_iou, relation_recall

# Paired points: GT instance per point and the predicted scene label of the same point.
GT_INST = np.array([1, 1, 1, 2, 2, 2, 2, 3, 3, -1])
PRED_LAB = np.array([10, 10, 10, 20, 20, 20, 20, 30, 30, 30])


def test_node_overlap_iou_and_matching():
    labels, insts, iou = node_overlap_iou(PRED_LAB, GT_INST)
    assert labels.tolist() == [10, 20, 30] and insts.tolist() == [1, 2, 3]
    assert iou[2, 2] == pytest.approx(2 / 3)  # label 30 has one point on void
    assert match_nodes_by_overlap(PRED_LAB, GT_INST) == {1: 10, 2: 20, 3: 30}
    assert match_nodes_by_overlap(PRED_LAB, GT_INST, min_iou=0.7) == {1: 10, 2: 20}


def test_matching_is_one_to_one():
    # label 5 covers instances 1 (3 points) and 2 (2 points); label 6 touches instance 2 once.
    gt = np.array([1, 1, 1, 2, 2, 2])
    pred = np.array([5, 5, 5, 5, 5, 6])
    m = match_nodes_by_overlap(gt_instances=gt, pred_labels=pred, min_iou=0.0)
    assert m == {1: 5, 2: 6}


def test_relation_recall_toy_graph():
    matches = match_nodes_by_overlap(PRED_LAB, GT_INST)
    gt_triplets = [
        (3, "on", 2),  # edge (30, 20, on)                     -> recalled
        (1, "next to", 2),  # edge (20, 10, next_to), symmetric  -> recalled
        (2, "under", 3),  # inverse of on(30, 20)               -> recalled
        (4, "on", 2),  # instance 4 has no points                -> unmatched endpoint
        (1, "above", 2),  # only "near"/"next to" between them    -> wrong relation
        (1, "on", 3),  # no edge between 10 and 30                -> no edge
    ]
    edges = [
        {"source": 30, "target": 20, "relation": "on", "score": 0.9},
        {"source": 20, "target": 10, "relation": "Next_To", "score": 0.8},
        (10, 20, "near"),
    ]
    r = relation_recall(gt_triplets, edges, matches)
    assert r.num_gt == 6 and r.num_recalled == 3
    assert r.recall == pytest.approx(0.5) and r.edge_recall == pytest.approx(4 / 6)
    assert (r.num_unmatched_endpoint, r.num_no_edge, r.num_wrong_relation) == (1, 1, 1)
    assert r.per_relation["on"] == {"gt": 3, "recalled": 1}
    d = r.to_dict()
    assert "relation" in d["protocol"] and d["num_matched_nodes"] == 3


def test_relation_recall_direction_matters_for_asymmetric_relations():
    r = relation_recall([(1, "on", 2)], [(20, 10, "on")], {1: 10, 2: 20})
    assert r.num_recalled == 0 and r.num_wrong_relation == 1


def test_relation_recall_empty_and_bad_input():
    assert math.isnan(relation_recall([], [], {}).recall)
    with pytest.raises(ValueError, match="lacks key"):
        relation_recall([(1, "on", 2)], [{"source": 1, "target": 2}], {1: 1, 2: 2})
