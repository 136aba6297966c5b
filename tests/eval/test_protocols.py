"""HOV-SG / ConceptGraphs protocols and 2D rendered-view metrics on toy data with hand-checked results."""

import numpy as np
import pytest
import torch

from ogscene3d.eval.protocols import (
    CONCEPTGRAPHS_VOXEL_SIZE,
    conceptgraphs_protocol,
    evaluate_semantic_3d,
    hovsg_protocol,
    label_lookup,
    majority_vote,
    nearest_neighbors,
    novel_view_metrics,
    rendered_view_metrics,
    voxel_resample,
)


def _line(xs):
    xs = np.asarray(xs, dtype=np.float64)
    return np.stack([xs, np.zeros_like(xs), np.zeros_like(xs)], axis=1)


# GT: 10 points on a line, x = 0..9; chair (0) at x < 5, table (1) at x >= 5.
GT_PTS = _line(np.arange(10))
GT_CLS = np.array([0] * 5 + [1] * 5)
NAMES = ["chair", "table"]
# Predictions at x = i + 0.1 (no distance ties), the one at 4.1 wrongly says table.
PRED_PTS = _line(np.arange(10) + 0.1)
PRED_CLS = np.array([0] * 4 + [1] * 6)


def test_hovsg_toy_line():
    # The 5 nearest predictions of GT x=4 are x=2..6 (0,0,1,1,1) -> table: one chair point lost.
    m = hovsg_protocol(PRED_PTS, PRED_CLS, GT_PTS, GT_CLS, NAMES, ignore=())
    np.testing.assert_allclose(m.iou, [4 / 5, 5 / 6])
    assert m.macc == pytest.approx((4 / 5 + 1) / 2)
    assert m.support.tolist() == [5, 5]  # counted on GT points
    assert m.protocol.startswith("hovsg")


def test_protocols_differ_on_a_cluster_of_wrong_points():
    # Three extra chair predictions just right of x = 9.
    pts = np.concatenate([PRED_PTS, _line([9.2, 9.3, 9.4])])
    cls = np.concatenate([PRED_CLS, [0, 0, 0]])
    # HOV-SG: GT x=9 now sees (9.1:table, 9.2, 9.3, 9.4: chair, 8.1: table) -> chair; x=4 as before.
    h = hovsg_protocol(pts, cls, GT_PTS, GT_CLS, NAMES, ignore=())
    np.testing.assert_allclose(h.iou, [4 / 6, 4 / 6])
    assert h.miou == pytest.approx(2 / 3) and h.macc == pytest.approx(0.8)
    # ConceptGraphs: each prediction vs its nearest GT point: 13 predicted points are counted.
    c = conceptgraphs_protocol(pts, cls, GT_PTS, GT_CLS, NAMES, ignore=())
    # chair: TP 4, FN 1 (4.1), FP 3 (cluster); table: TP 5, FN 3, FP 1.
    np.testing.assert_allclose(c.iou, [4 / 8, 5 / 9])
    assert c.support.sum() == 13
    assert c.protocol.startswith("conceptgraphs")


def test_background_ignore_handling_per_protocol():
    names = ["chair", "wall"]
    gt_pts = _line([0, 1, 5, 6])
    gt_cls = np.array([0, 0, 1, 1])
    pred_pts = _line([0.1, 1.1, 5.1, 6.1])
    pred_cls = np.array([0, 0, 0, 1])  # one wall point predicted as chair
    h = hovsg_protocol(pred_pts, pred_cls, gt_pts, gt_cls, names, ignore=["wall"], k=1)
    assert h.iou[0] == pytest.approx(2 / 3) and h.miou == pytest.approx(2 / 3)  # kept as a false positive
    c = conceptgraphs_protocol(pred_pts, pred_cls, gt_pts, gt_cls, names, ignore=["wall"])
    assert c.miou == 1.0  # dropped
    d = evaluate_semantic_3d(pred_pts, pred_cls, gt_pts, gt_cls, names, protocol="hovsg", k=1)
    assert d.ignored == ["wall"]  # HOV-SG default background list


def test_unlabelled_predictions_do_not_vote_in_hovsg_but_miss_in_conceptgraphs():
    pred_cls = PRED_CLS.copy()
    pred_cls[:] = -1
    pred_cls[0] = 0  # only one labelled prediction: every GT point gets chair
    h = hovsg_protocol(PRED_PTS, pred_cls, GT_PTS, GT_CLS, NAMES, ignore=())
    np.testing.assert_allclose(h.iou, [5 / 10, 0.0])
    c = conceptgraphs_protocol(PRED_PTS, pred_cls, GT_PTS, GT_CLS, NAMES, ignore=())
    np.testing.assert_allclose(c.iou, [1 / 5, 0.0])
    assert c.to_dict()["unassigned_predictions"] == 9
    none = hovsg_protocol(PRED_PTS, np.full(10, -1), GT_PTS, GT_CLS, NAMES, ignore=())
    assert none.miou == 0.0


def test_hovsg_unnamed_labels_vote_no_class_and_unlabelled_do_not_vote():
    # x = 0..4 chair, 5..8 a scene label the mapping could not name (class -1), 9 table.
    pred_cls = np.array([0] * 5 + [-1] * 4 + [1])
    labelled = np.ones(10, dtype=bool)
    m = hovsg_protocol(PRED_PTS, pred_cls, GT_PTS, GT_CLS, NAMES, ignore=(), k=1, pred_labelled=labelled)
    # Each GT point takes its own prediction: GT 5..8 get "no class" (misses), not the chair/table
    # classes of farther neighbours.
    np.testing.assert_allclose(m.iou, [1.0, 1 / 5])
    assert m.miou == pytest.approx(0.6) and m.to_dict()["unassigned_predictions"] == 4
    # The same points left unlabelled (no scene label) do not vote: their neighbours fill the gap.
    gap = hovsg_protocol(
        PRED_PTS, pred_cls, GT_PTS, GT_CLS, NAMES, ignore=(), k=1, pred_labelled=pred_cls >= 0
    )
    assert gap.to_dict()["unassigned_predictions"] == 0
    np.testing.assert_array_equal(
        gap.confusion, hovsg_protocol(PRED_PTS, pred_cls, GT_PTS, GT_CLS, NAMES, (), k=1).confusion
    )
    # The unlabelled mask goes through evaluate_semantic_3d to HOV-SG.
    d = evaluate_semantic_3d(
        PRED_PTS, pred_cls, GT_PTS, GT_CLS, NAMES, protocol="hovsg", ignore=(), k=1, pred_labelled=labelled
    )
    np.testing.assert_array_equal(d.confusion, m.confusion)
    with pytest.raises(ValueError, match="pred_labelled"):
        hovsg_protocol(PRED_PTS, PRED_CLS, GT_PTS, GT_CLS, NAMES, pred_labelled=np.zeros(10, dtype=bool))


def test_hovsg_no_class_wins_only_a_strict_majority():
    gt_pts = _line([0.0])
    pred_pts = _line([0.1, -0.2, 0.3, -0.4])
    names = ["chair", "table"]
    labelled = np.ones(4, dtype=bool)
    # Two "no class" votes against two chair votes: a real class wins the tie.
    tie = hovsg_protocol(
        pred_pts, np.array([-1, 0, -1, 0]), gt_pts, [0], names, (), k=4, pred_labelled=labelled
    )
    assert tie.iou[0] == 1.0
    lost = hovsg_protocol(
        pred_pts, np.array([-1, -1, -1, 0]), gt_pts, [0], names, (), k=4, pred_labelled=labelled
    )
    assert lost.iou[0] == 0.0 and lost.confusion[0, -1] == 1


def test_conceptgraphs_averages_gt_classes_the_map_never_reached():
    # ConceptGraphs' eval_replica_semseg.py keeps the classes present in the GT cloud (minus
    # excluded ones): a lamp the map has no point near scores IoU 0 and recall 0.
    names = ["other", "chair", "table", "lamp"]
    gt_pts = _line([0, 0.1, 10, 10.1, 20, 20.1])
    gt_cls = np.array([1, 1, 2, 2, 3, 3])
    pred_pts = _line([0, 0.05, 10, 10.05])
    pred_cls = np.array([1, 1, 2, 2])
    c = conceptgraphs_protocol(pred_pts, pred_cls, gt_pts, gt_cls, names)  # default ignore: other
    assert [n for n, e in zip(names, c.evaluated) if e] == ["chair", "table", "lamp"]
    assert c.iou[3] == 0.0 and c.acc[3] == 0.0 and c.support[3] == 0
    # The reference figures of ConceptGraphs' compute_metrics on this scene.
    assert c.miou == pytest.approx(2 / 3) and c.macc == pytest.approx(2 / 3) and c.fmiou == pytest.approx(1.0)
    # "other" has GT points here but stays ignored.
    c2 = conceptgraphs_protocol(pred_pts, pred_cls, gt_pts, np.array([0, 1, 2, 2, 3, 3]), names)
    assert not c2.evaluated[0] and c2.num_evaluated == 3
    # Classes absent from the GT cloud stay out even when predicted.
    c3 = conceptgraphs_protocol(pred_pts, np.array([1, 3, 2, 2]), gt_pts[:4], gt_cls[:4], names)
    assert not c3.evaluated[3] and c3.predicted[3] == 1 and c3.num_evaluated == 2


def test_hovsg_evaluates_every_gt_class_not_ignored():
    # Counted on GT points, HOV-SG already averages every GT class with points, predicted or not.
    names = ["other", "chair", "table", "lamp"]
    gt_pts = _line([0, 0.1, 10, 10.1, 20, 20.1])
    gt_cls = np.array([1, 1, 2, 2, 3, 3])
    h = hovsg_protocol(
        _line([0, 0.05, 10, 10.05]), np.array([1, 1, 2, 2]), gt_pts, gt_cls, names, ["other"], k=1
    )
    assert [n for n, e in zip(names, h.evaluated) if e] == ["chair", "table", "lamp"]
    # The lamp's GT points take the table's vote: lamp IoU 0, table IoU 2/4.
    np.testing.assert_allclose(h.iou[1:], [1.0, 0.5, 0.0])
    assert h.miou == pytest.approx(0.5)


def test_majority_vote_ties_and_validity():
    votes = np.array([[2, 2, 1, 1, 5], [3, 3, 3, 0, 0], [4, 9, 9, 9, 9], [1, 1, 1, 1, 1]])
    valid = np.ones_like(votes, dtype=bool)
    valid[2, 1:] = False
    valid[3, :] = False
    np.testing.assert_array_equal(majority_vote(votes, valid), [1, 3, 4, -1])


def test_majority_vote_matches_bincount_reference():
    rng = np.random.default_rng(0)
    votes = rng.integers(0, 6, size=(500, 5))
    ref = np.array([np.bincount(r).argmax() for r in votes])
    np.testing.assert_array_equal(majority_vote(votes), ref)


def test_nearest_neighbors_matches_brute_force_and_radius():
    rng = np.random.default_rng(1)
    ref = rng.random((300, 3))
    qry = rng.random((200, 3))
    d, i = nearest_neighbors(ref, qry, k=3)
    full = np.linalg.norm(qry[:, None] - ref[None], axis=2)
    np.testing.assert_allclose(d, np.sort(full, axis=1)[:, :3])
    _, i1 = nearest_neighbors(ref, qry + 10.0, k=1, max_distance=0.5)
    assert (i1 == -1).all()


@pytest.mark.parametrize("bad", [np.zeros((3, 2)), np.array([[0.0, np.nan, 0.0]])])
def test_bad_points_rejected(bad):
    with pytest.raises(ValueError, match="pred_points"):
        hovsg_protocol(bad, np.zeros(len(bad), int), GT_PTS, GT_CLS, NAMES)


def test_unknown_protocol():
    with pytest.raises(ValueError, match="unknown protocol"):
        evaluate_semantic_3d(PRED_PTS, PRED_CLS, GT_PTS, GT_CLS, NAMES, protocol="openscene")


def test_label_lookup_dict_and_array():
    labels = np.array([[5, 7], [-1, 9]])
    np.testing.assert_array_equal(label_lookup({5: 0, 9: 2}, labels), [[0, -1], [-1, 2]])
    np.testing.assert_array_equal(label_lookup(np.array([3, 3, 3, 3, 3, 1]), labels), [[1, -1], [-1, -1]])
    np.testing.assert_array_equal(label_lookup({}, labels), -np.ones((2, 2)))


def test_rendered_view_metrics_two_views():
    r1 = np.array([[10, 10], [11, -1]])
    g1 = np.array([[0, 0], [1, 1]])
    r2 = torch.tensor([[12, 11], [10, 10]], dtype=torch.int32)  # 12 has no class
    g2 = np.array([[1, 1], [0, -1]])
    m = rendered_view_metrics([r1, r2], [g1, g2], {10: 0, 11: 1}, ["chair", "table"])
    # chair: 3 TP; table: 2 TP, 2 misses (-1 and unmapped 12); the void pixel is skipped.
    np.testing.assert_allclose(m.iou, [1.0, 0.5])
    assert m.miou == pytest.approx(0.75) and m.macc == pytest.approx(0.75)
    assert m.support.sum() == 7
    # The views are frames of the mapped sequence: the protocol must not claim novel views.
    assert m.protocol.startswith("rendered-view-2d") and "not held-out novel views" in m.protocol
    assert novel_view_metrics is rendered_view_metrics  # the former name still imports
    with pytest.raises(ValueError, match="view 0"):
        rendered_view_metrics([r1], [np.zeros((3, 2), int)], {10: 0}, ["chair", "table"])


def _brute_force_confusions(pred_pts, pred_cls, gt_pts, gt_cls, c, k):
    d = np.linalg.norm(gt_pts[:, None] - pred_pts[None], axis=2)
    lab = pred_cls >= 0
    nn = np.argsort(d[:, lab], axis=1, kind="stable")[:, :k]
    votes = np.array([np.bincount(row, minlength=c).argmax() for row in pred_cls[lab][nn]])
    h = np.zeros((c, c + 1), int)
    np.add.at(h, (gt_cls, votes), 1)
    ref = gt_cls[np.argmin(np.linalg.norm(pred_pts[:, None] - gt_pts[None], axis=2), axis=1)]
    cg = np.zeros((c, c + 1), int)
    np.add.at(cg, (ref, np.where(pred_cls < 0, c, pred_cls)), 1)
    return h, cg


def test_protocols_match_brute_force_with_small_chunks(monkeypatch):
    import ogscene3d.eval.protocols as protocols

    monkeypatch.setattr(protocols, "_CHUNK", 7)  # exercise the chunked KD-tree queries and votes
    rng = np.random.default_rng(5)
    gt_pts, pred_pts = rng.random((120, 3)), rng.random((90, 3))
    gt_cls = (gt_pts[:, 0] * 4).astype(int)  # 4 slabs along x
    pred_cls = np.where(rng.random(90) < 0.8, (pred_pts[:, 0] * 4).astype(int), rng.integers(-1, 4, 90))
    names = ["a", "b", "c", "d"]
    h_ref, cg_ref = _brute_force_confusions(pred_pts, pred_cls, gt_pts, gt_cls, 4, 5)
    h = protocols.hovsg_protocol(pred_pts, pred_cls, gt_pts, gt_cls, names, ignore=())
    np.testing.assert_array_equal(h.confusion, h_ref)
    cg = protocols.conceptgraphs_protocol(pred_pts, pred_cls, gt_pts, gt_cls, names, ignore=(), voxel_size=0)
    np.testing.assert_array_equal(cg.confusion, cg_ref)


def _hovsg_reference(pred, gt, ignore):
    """HOV-SG's metric.py formulas (mean_IU, frequency_weighted_IU, mean_accuracy, pixel_accuracy), restated
    on 1-D label arrays; ``ignore`` holds -1 (void) like HOV-SG's list."""
    gt_cls = [c for c in np.unique(gt) if c not in ignore]
    iou = {}
    for c in np.union1d(np.unique(pred), np.unique(gt)):
        n_pred, n_gt = (pred == c).sum(), (gt == c).sum()
        if c in ignore or n_pred == 0 or n_gt == 0:
            continue
        tp = ((pred == c) & (gt == c)).sum()
        iou[c] = tp / (n_gt + n_pred - tp)  # n_pred counts every point, void and ignored ones included
    miou = sum(iou.values()) / len(gt_cls)
    n_scored = gt.size - sum((gt == c).sum() for c in ignore)
    fmiou = sum((gt == c).sum() * v for c, v in iou.items()) / n_scored
    recall = [((pred == c) & (gt == c)).sum() / (gt == c).sum() for c in gt_cls]
    oacc = sum(((pred == c) & (gt == c)).sum() for c in gt_cls) / sum((gt == c).sum() for c in gt_cls)
    return miou, fmiou, np.mean(recall), oacc


def test_hovsg_matches_its_metric_code_with_void_and_ignored_points():
    # k = 1 and each GT point's own prediction right beside it: the vote is the prediction itself.
    rng = np.random.default_rng(7)
    gt_pts = _line(np.arange(400))
    gt_cls = rng.integers(-1, 5, 400)  # -1 = void; class 4 = wall, ignored
    pred_cls = np.where(rng.random(400) < 0.6, gt_cls, rng.integers(0, 6, 400))  # 5 never in the GT
    pred_cls[gt_cls == -1] = rng.integers(0, 5, (gt_cls == -1).sum())  # void points get a class
    names = ["chair", "table", "lamp", "sofa", "wall", "bed"]
    m = hovsg_protocol(gt_pts + [0.1, 0, 0], pred_cls, gt_pts, gt_cls, names, ignore=["wall"], k=1)
    ref = _hovsg_reference(pred_cls, gt_cls, ignore=[-1, 4])
    np.testing.assert_allclose([m.miou, m.fmiou, m.macc, m.overall_acc], ref)
    assert m.to_dict()["void_false_positives"] == (gt_cls == -1).sum()


def test_hovsg_void_gt_points_are_false_positives_unless_dropped():
    gt_pts = _line([0, 1, 2, 3])
    gt_cls = np.array([0, 0, -1, 1])  # x = 2 is void
    pred_cls = np.array([0, 0, 0, 1])  # its nearest prediction says chair
    fp = hovsg_protocol(gt_pts + [0.1, 0, 0], pred_cls, gt_pts, gt_cls, NAMES, ignore=(), k=1)
    np.testing.assert_allclose(fp.iou, [2 / 3, 1.0])
    assert fp.predicted.tolist() == [3, 1] and fp.support.tolist() == [2, 1]
    drop = hovsg_protocol(
        gt_pts + [0.1, 0, 0], pred_cls, gt_pts, gt_cls, NAMES, ignore=(), k=1, ignored_gt_points="drop"
    )
    assert drop.miou == 1.0 and drop.predicted.tolist() == [2, 1]


def test_voxel_resample_groups_by_label_and_voxel():
    v = 0.1
    pts = np.array([[0.0, 0, 0], [0.02, 0, 0], [0.04, 0, 0], [0.01, 0.01, 0], [0.5, 0, 0], [0.52, 0, 0]])
    cls = np.array([0, 0, 1, -1, -1, -1])
    labels = np.array([3, 3, 4, -1, -1, -1])  # labels 3 and 4 share the first voxel
    out_pts, out_cls = voxel_resample(pts, cls, labels, voxel_size=v)
    rows = sorted(zip(out_cls.tolist(), out_pts.round(6).tolist()))
    # label 3: one point at its mean; label 4: its own point; unlabelled: one per voxel.
    assert rows == [
        (-1, [0.01, 0.01, 0.0]),
        (-1, [0.51, 0.0, 0.0]),
        (0, [0.01, 0.0, 0.0]),
        (1, [0.04, 0.0, 0.0]),
    ]
    # Without labels the class stands for the label.
    assert voxel_resample(pts, cls, None, voxel_size=v)[0].shape == (4, 3)
    # A key space too large for one int64 per row (km apart at 0.1 mm) takes the row-wise path.
    far = np.array([[0.0, 0, 0], [2e-5, 0, 0], [1e5, 1e5, 1e5]])
    far_pts, far_cls = voxel_resample(far, np.array([0, 0, 1]), np.array([5, 5, 6]), voxel_size=1e-4)
    np.testing.assert_allclose(far_pts, [[1e-5, 0, 0], [1e5, 1e5, 1e5]])
    assert far_cls.tolist() == [0, 1]
    with pytest.raises(ValueError, match="voxel_size"):
        voxel_resample(pts, cls, labels, voxel_size=0.0)


def test_conceptgraphs_resampling_makes_the_score_density_invariant():
    # A wrong "chair" blob at the table end of the line; then 40 more Gaussians in its voxel.
    pts = np.concatenate([PRED_PTS, _line([8.5])])
    cls = np.concatenate([PRED_CLS, [0]])
    labels = np.where(cls == 0, 10, 11)
    dense_pts = np.concatenate([pts, _line(8.5 + np.linspace(0, 0.01, 40))])
    dense_cls = np.concatenate([cls, np.zeros(40, int)])
    dense_labels = np.concatenate([labels, np.full(40, 10)])
    sparse = conceptgraphs_protocol(pts, cls, GT_PTS, GT_CLS, NAMES, ignore=(), pred_labels=labels)
    dense = conceptgraphs_protocol(
        dense_pts, dense_cls, GT_PTS, GT_CLS, NAMES, ignore=(), pred_labels=dense_labels
    )
    np.testing.assert_array_equal(dense.confusion, sparse.confusion)
    # chair: TP 4, FN 1 (4.1), FP 1 (8.5); table: TP 5, FN 1, FP 1.
    np.testing.assert_allclose(sparse.iou, [4 / 6, 5 / 7])
    assert f"{CONCEPTGRAPHS_VOXEL_SIZE:g} m voxel" in sparse.protocol
    # voxel_size 0: every point counts, as before: the blob's 41 points are 41 false positives.
    raw = conceptgraphs_protocol(
        dense_pts, dense_cls, GT_PTS, GT_CLS, NAMES, ignore=(), pred_labels=dense_labels, voxel_size=0
    )
    np.testing.assert_allclose(raw.iou, [4 / 46, 5 / 47])
    assert "not resampled" in raw.protocol
    via = evaluate_semantic_3d(
        dense_pts, dense_cls, GT_PTS, GT_CLS, NAMES, protocol="conceptgraphs", ignore=(),
        pred_labels=dense_labels, voxel_size=0,
    )  # fmt: skip
    np.testing.assert_array_equal(via.confusion, raw.confusion)
    with pytest.raises(ValueError, match="voxel_size"):
        conceptgraphs_protocol(pts, cls, GT_PTS, GT_CLS, NAMES, voxel_size=-1.0)


def test_conceptgraphs_resampling_keeps_labels_apart_in_one_voxel():
    # Two scene labels on the same spot (both named chair) stay two points, as two ConceptGraphs
    # objects keep their own clouds; the same points under one label make one.
    pts = _line([0.0, 0.001, 5.0])
    cls = np.array([0, 0, 1])
    two = conceptgraphs_protocol(pts, cls, GT_PTS, GT_CLS, NAMES, ignore=(), pred_labels=np.array([1, 2, 3]))
    one = conceptgraphs_protocol(pts, cls, GT_PTS, GT_CLS, NAMES, ignore=(), pred_labels=np.array([1, 1, 3]))
    assert two.support.sum() == 3 and one.support.sum() == 2
