"""Confusion-matrix metrics on hand-made cases with hand-computed answers."""

import math

import numpy as np
import pytest

from ogscene3d.eval.metrics import (
    confusion_matrix,
    format_metrics_table,
    segmentation_metrics,
    void_predictions,
    warn_unknown_ignore,
)

NAMES = ["a", "b", "c"]


def test_confusion_matrix_counts_and_no_class_column():
    gt = np.array([0, 0, 1, 2, -1, 2])
    pred = np.array([0, 1, 1, -1, 0, 2])
    cm = confusion_matrix(gt, pred, 3)
    expected = np.array([[1, 1, 0, 0], [0, 1, 0, 0], [0, 0, 1, 1]])
    np.testing.assert_array_equal(cm, expected)  # the void GT point (-1) is not counted


def test_perfect_prediction():
    gt = np.array([0, 0, 1, 2, 2, 2])
    m = segmentation_metrics(confusion_matrix(gt, gt, 3), NAMES)
    assert m.miou == m.fmiou == m.macc == m.overall_acc == 1.0
    np.testing.assert_array_equal(m.iou, [1.0, 1.0, 1.0])


def test_all_wrong():
    gt = np.array([0, 0, 1, 1])
    pred = np.array([1, 1, 0, 0])
    m = segmentation_metrics(confusion_matrix(gt, pred, 2), ["a", "b"])
    assert m.miou == 0.0 and m.fmiou == 0.0 and m.macc == 0.0


def test_partial_hand_computed():
    # rows (GT) a: 3 right, 1 -> b;  b: 2 right;  c: 2 right, 1 -> a, 1 -> no class
    gt = np.array([0, 0, 0, 0, 1, 1, 2, 2, 2, 2])
    pred = np.array([0, 0, 0, 1, 1, 1, 2, 2, 0, -1])
    m = segmentation_metrics(confusion_matrix(gt, pred, 3), NAMES, protocol="toy")
    # IoU_a = 3/(3+1+1), IoU_b = 2/(2+1+0), IoU_c = 2/(2+0+2)
    iou = [3 / 5, 2 / 3, 2 / 4]
    np.testing.assert_allclose(m.iou, iou)
    assert m.miou == pytest.approx(sum(iou) / 3)
    assert m.fmiou == pytest.approx((4 * iou[0] + 2 * iou[1] + 4 * iou[2]) / 10)
    assert m.macc == pytest.approx((3 / 4 + 2 / 2 + 2 / 4) / 3)
    assert m.overall_acc == pytest.approx(7 / 10)
    d = m.to_dict()
    assert d["protocol"] == "toy" and d["unassigned_predictions"] == 1
    assert "toy" in format_metrics_table(m)


def test_class_absent_from_gt_is_not_averaged_but_its_false_positives_count():
    gt = np.array([0, 0, 1, 1])
    pred = np.array([0, 2, 1, 1])  # class c predicted but never in GT
    m = segmentation_metrics(confusion_matrix(gt, pred, 3), NAMES)
    assert math.isnan(m.iou[2]) and not m.evaluated[2]
    assert m.iou[0] == pytest.approx(0.5) and m.iou[1] == 1.0
    assert m.miou == pytest.approx(0.75)
    assert m.predicted[2] == 1


def test_ignore_drop_versus_false_positive():
    names = ["chair", "table", "wall"]
    gt = np.array([0, 0, 1, 1, 2, 2])
    pred = np.array([0, 0, 1, 1, 0, 0])  # both wall points predicted as chair
    cm = confusion_matrix(gt, pred, 3)
    drop = segmentation_metrics(cm, names, ignore=["Wall"], ignored_gt_points="drop")
    assert drop.miou == 1.0 and drop.ignored == ["wall"] and not drop.evaluated[2]
    fp = segmentation_metrics(cm, names, ignore=["wall"], ignored_gt_points="false_positive")
    assert fp.iou[0] == pytest.approx(2 / 4) and fp.iou[1] == 1.0
    assert fp.miou == pytest.approx(0.75)
    assert fp.fmiou == pytest.approx((2 * 0.5 + 2 * 1.0) / 4)
    assert fp.macc == 1.0  # recall is unaffected by false positives


def test_void_predictions_are_false_positives_only_where_ignored_points_are():
    names = ["chair", "table"]
    gt = np.array([0, 0, 1, 1, -1, -1, -1])
    pred = np.array([0, 0, 1, 1, 0, 1, -1])  # void points predicted chair, table, no class
    cm = confusion_matrix(gt, pred, 2)
    void = void_predictions(gt, pred, 2)
    assert void.tolist() == [1, 1]
    fp = segmentation_metrics(cm, names, ignored_gt_points="false_positive", void_predicted=void)
    np.testing.assert_allclose(fp.iou, [2 / 3, 2 / 3])
    assert fp.predicted.tolist() == [3, 3] and fp.support.tolist() == [2, 2]
    assert fp.macc == 1.0 and fp.fmiou == pytest.approx(2 / 3)
    assert fp.to_dict()["void_false_positives"] == 2
    assert "void GT points predicted as a class (false positives): 2" in format_metrics_table(fp)
    drop = segmentation_metrics(cm, names, ignored_gt_points="drop", void_predicted=void)
    assert drop.miou == 1.0 and drop.to_dict()["void_false_positives"] == 0
    with pytest.raises(ValueError, match="void_predicted"):
        segmentation_metrics(cm, names, void_predicted=np.array([1, 2, 3]))


def test_ignore_by_index_and_unknown_names_tolerated():
    gt = np.array([0, 1, 2])
    m = segmentation_metrics(confusion_matrix(gt, gt, 3), NAMES, ignore=[1, "ceiling"])
    assert m.num_evaluated == 2


def test_hovsg_ignore_presets():
    """HOV-SG's own lists: substring rule on Replica (wall-plug, and indoor-plant through 'door'), names on
    ScanNet."""
    from ogscene3d.eval.metrics import resolve_ignore

    replica = ["wall", "wall-cabinet", "wall-plug", "indoor-plant", "door", "window", "floor", "ceiling",
               "chair", "table", "blinds"]  # fmt: skip
    idx, unknown = resolve_ignore(["preset:hovsg-replica"], replica)
    assert [replica[i] for i in idx] == replica[:8] and unknown == []
    scannet = ["wall", "floor", "cabinet", "door", "window", "curtain", "background", "wall-plug"]
    idx, _ = resolve_ignore(["preset:HOVSG-ScanNet", "curtain"], scannet)
    assert [scannet[i] for i in idx] == ["wall", "floor", "door", "window", "curtain", "background"]
    with pytest.raises(ValueError, match="unknown preset 'hovsg'; presets: hovsg-replica, hovsg-scannet"):
        resolve_ignore(["preset:hovsg"], scannet)


def test_unknown_ignore_names_are_reported_and_warned(caplog):
    gt = np.array([0, 1, 2])
    m = segmentation_metrics(confusion_matrix(gt, gt, 3), NAMES, ignore=["b", "ceilng"])
    assert m.ignored == ["b"] and m.to_dict()["ignore_unknown"] == ["ceilng"]
    assert segmentation_metrics(confusion_matrix(gt, gt, 3), NAMES).to_dict()["ignore_unknown"] == []
    with caplog.at_level("WARNING", logger="ogscene3d.eval.metrics"):
        assert warn_unknown_ignore(["b", "ceilng"], NAMES) == ["ceilng"]
    assert "'ceilng'" in caplog.text and "a, b, c" in caplog.text
    many = [f"class{i}" for i in range(20)]
    caplog.clear()
    with caplog.at_level("WARNING", logger="ogscene3d.eval.metrics"):
        warn_unknown_ignore(["x"], many)
    assert "class7, ..." in caplog.text and "class8" not in caplog.text and "20 in all" in caplog.text
    caplog.clear()
    assert warn_unknown_ignore(["a", 2], NAMES) == [] and not caplog.text


def test_gt_present_evaluates_classes_without_counted_points():
    # Rows count predicted points (ConceptGraphs): class c is in the GT cloud but no point reached it.
    cm = confusion_matrix(np.array([0, 0, 1]), np.array([0, 0, 1]), 3)
    present = np.array([True, True, True])
    m = segmentation_metrics(cm, NAMES, gt_present=present)
    assert m.num_evaluated == 3 and m.iou[2] == 0.0 and m.acc[2] == 0.0
    assert m.miou == pytest.approx(2 / 3) and m.macc == pytest.approx(2 / 3)
    assert m.fmiou == 1.0 and m.overall_acc == 1.0  # weighted by counted points: c weighs nothing
    # Ignored classes stay out; a class absent from the GT stays out even with counted points.
    ign = segmentation_metrics(cm, NAMES, ignore=["c"], gt_present=present)
    assert ign.num_evaluated == 2 and ign.miou == 1.0
    absent = segmentation_metrics(cm, NAMES, gt_present=np.array([True, False, True]))
    assert absent.evaluated.tolist() == [True, False, True] and math.isnan(absent.iou[1])
    with pytest.raises(ValueError, match="gt_present"):
        segmentation_metrics(cm, NAMES, gt_present=np.array([1, 1, 1]))
    with pytest.raises(ValueError, match="no evaluated class"):
        segmentation_metrics(cm, NAMES, gt_present=np.array([False, False, True]))


def test_square_matrix_accepted():
    m = segmentation_metrics(np.array([[2, 0], [1, 1]]), ["a", "b"])
    assert m.iou[0] == pytest.approx(2 / 3) and m.iou[1] == pytest.approx(1 / 2)


@pytest.mark.parametrize(
    "gt,pred,msg",
    [
        (np.array([0, 1]), np.array([0]), "differ in size"),
        (np.array([0, 3]), np.array([0, 1]), "gt has class 3"),
        (np.array([0, 1]), np.array([0, 5]), "pred has class 5"),
        (np.array([0.0, np.nan]), np.array([0, 1]), "NaN"),
        (np.array([0.5, 1.0]), np.array([0, 1]), "whole numbers"),
    ],
)
def test_confusion_matrix_rejects_bad_input(gt, pred, msg):
    with pytest.raises(ValueError, match=msg):
        confusion_matrix(gt, pred, 3)


def test_no_evaluated_class_is_an_error():
    cm = confusion_matrix(np.array([2, 2]), np.array([2, 2]), 3)
    with pytest.raises(ValueError, match="no evaluated class"):
        segmentation_metrics(cm, NAMES, ignore=["c"])
    with pytest.raises(ValueError, match="class_names has 2"):
        segmentation_metrics(cm, ["a", "b"])
